"""Benchmark suites (:data:`SUITES`): ``warpscatter bench [SUITE]``.

Every suite times library stages the way a render runs them: a warm-up run first (kernel compile measured apart, as
``compile``), then the median of ``repeats`` runs per stage, each case rendered once per run. Rows carry the error
against the exact reference where one applies (relative L1 = sum|a - b| / sum|b| and RMSE over all pixels and
channels) and the speed-up over the brute-force ray marcher measured in the SAME run. Scenes: :mod:`.scenes`.

Output: a terminal table (:meth:`BenchReport.table`), ``bench-<suite>.json`` and ``bench-<suite>.csv`` (layouts:
:mod:`.report`) and, with matplotlib (the ``plot`` extra), charts; :func:`compare_reports` (:mod:`.compare`) sets two
bench JSONs side by side. ``quick=True`` shrinks every size (smoke tests and CI); figures come from full runs.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ..runtime.device import init
from ..runtime.stages import ProgressFn
from .compare import compare_reports, load_bench_json
from .report import BenchReport, errors, machine_meta, measure, thread_limit
from .scenes import bench_light_texture, bench_scene_config, render_timed, scattering_rows
from .suites_core import suite_parallel, suite_raster, suite_reference
from .suites_csm import suite_csm
from .suites_fidelity import suite_fidelity
from .suites_papers import suite_papers
from .suites_pareto import suite_pareto
from .suites_scaleout import suite_scaleout
from .suites_scattering import suite_epipolar, suite_moments, suite_prefiltered
from .suites_shadows import suite_filterable


@dataclass(frozen=True)
class Suite:
    """A bench suite: ``run(report, repeats, warmup, quick, progress)`` adds its rows to a :class:`BenchReport`."""

    name: str
    description: str
    run: Callable[[BenchReport, int, int, bool, ProgressFn | None], None]


#: The suites, in the order ``bench all`` runs them.
SUITES: dict[str, Suite] = {s.name: s for s in (
    Suite("raster", "1024^2 depth map of a >=1M-triangle mesh: Warp rasterizer vs wp.Mesh ray casting vs Embree",
          suite_raster),
    Suite("reference", "ray marching at 1920x1080, 128 steps: shadow-map vs exact (ray-cast) visibility",
          suite_reference),
    Suite("parallel", "1 thread vs all cores: the rasterizer and every stage of the marcher, fourier, moments6, "
          "epipolar renders at 1920x1080",
          suite_parallel),
    Suite("prefiltered", "fourier method (Klehm 2014): stage times vs map size, output size, basis count; error vs "
                         "exact; scene-complexity sweep", suite_prefiltered),
    Suite("moments", "fourier, moments4, moments6 (Peters 2017) and the marcher on colonnade, canopy, window "
                     "(colonnade and canopy also with a receiver-only ground): time, bits per texel, error vs exact; "
                     "moment soft shadows vs PCSS", suite_moments),
    Suite("epipolar", "epipolar sampling (Engelhardt 2010) on the colonnade under a textured spot: fraction "
                      "ray-marched, stage times, errors (vs per-pixel marching, exact, converged) for 256-1024 lines "
                      "and 8-32 initial samples; per_pixel and fixed step patterns", suite_epipolar),
    Suite("csm", "coherent shadow maps (Ritschel 2007): compression ratio, precompute time and memory vs N and "
                 "enumeration; visibility queries/s (random, coherent) against BVH shadow rays; the csm render "
                 "method's time per pass and error against raytrace", suite_csm),
    Suite("fidelity", "every fast method's error on every bundled sunlit scene (its light ahead, behind and beside "
                      "the view) at 960x540 against the exact reference, beside the 128-step shadow-map marcher "
                      "(issue #13's bar; ~15 min)",
          suite_fidelity),
    Suite("pareto", "quality per time at 1920x1080: the shadow-map marcher's error/time curve (8-256 steps, both "
                    "step patterns, on to 1024 while a method is more accurate) against the exact reference, and "
                    "each fast method's equal-error speed-up over it, on colonnade, canopy and window (takes long: "
                    "~14 min with --repeats 1, 16 measured with --repeats 3)", suite_pareto),
    Suite("papers", "the four papers' checkable claims (Klehm Fig. 3 and Table 1, Peters Sec. 5 and Figs. 19-20, "
                    "Engelhardt Fig. 10, Ritschel Table 1), each measured and marked holds / does not hold "
                    "(~10 min)", suite_papers),
    Suite("filterable", "light leaking of the filterable shadow maps (msm, msm2015, vsm, evsm at their storages) "
                        "against PCF on a fence / wall / sign scene after Peters 2017 Fig. 4 (~1 min)",
          suite_filterable),
    Suite("scaleout", "a 60-frame 640x360 animation (colonnade_sunset) through each executor: plain loop, 1 and 2 "
                      "local worker processes, a 2-worker Dask LocalCluster: frames/s, overhead per task (~4 min)",
          suite_scaleout),
)}


def run(suite: str = "reference", *, repeats: int = 5, warmup: int = 1, out_dir: Path | None = None,
        quick: bool = False, progress: ProgressFn | None = None) -> BenchReport:
    """Run one suite (or ``"all"``: each) and write its JSON, CSV and charts into ``out_dir`` (default
    ``bench-out``); returns the report (``"all"``: the rows of every suite, names prefixed with the suite).

    Raises:
        ValueError: unknown suite name, or repeats < 1 / warmup < 0.
    """
    names = list(SUITES) if suite == "all" else [suite]
    for s in names:
        if s not in SUITES:
            raise ValueError(f"unknown bench suite {s!r} (choose from {', '.join(SUITES)}, all)")
    if repeats < 1 or warmup < 0:
        raise ValueError("repeats must be >= 1 and warmup >= 0")
    init()
    out_dir = Path(out_dir) if out_dir is not None else Path("bench-out")
    reports = []
    for s in names:
        report = BenchReport(suite=s, meta={**machine_meta(), "suite": s, "repeats": repeats, "warmup": warmup,
                                            "quick": quick, "argv": list(sys.argv)})
        SUITES[s].run(report, repeats, warmup, quick, progress)
        report.write(out_dir)
        reports.append(report)
    if len(reports) == 1:
        return reports[0]
    merged = BenchReport(suite="all", meta={**reports[0].meta, "suite": "all"})
    for r in reports:
        merged.rows += [{**row, "name": f"{r.suite}: {row['name']}"} for row in r.rows]
        merged.files += r.files
    return merged


__all__ = ["SUITES", "BenchReport", "Suite", "bench_light_texture", "bench_scene_config", "compare_reports",
           "errors", "load_bench_json", "machine_meta", "measure", "render_timed", "run", "scattering_rows",
           "thread_limit"]
