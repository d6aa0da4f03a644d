"""Bench suite ``pareto``: quality per unit of time, the fast methods against the simple shadow-map marcher.

On the bundled colonnade, canopy and window configs at 1920x1080 (``--quick``: 320x180): the exact reference (two
seeds on a pixel subset, its own error estimated as half their distance), the shadow-map marcher's error/time curve
(8 ... 256 steps, extended while a fast method beats it) and each fast method's point. Times are medians of
interleaved rounds, so a slow phase of a shared machine hits all configurations alike. A method's equal-error
speed-up is the marcher's time interpolated log-log at its error over its own time (``>=`` / ``<=`` bounds outside
the curve).
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import numpy as np

from ..runtime.stages import ProgressFn
from .report import BenchReport, hbar_chart
from .scenes import bench_scene_config, median_stages, render_timed

#: The scenes (bundled configs) and the fast methods at their defaults.
SCENES = ("colonnade", "canopy", "window")
METHODS = {
    "fourier": {"method": "fourier"},
    "moments4": {"method": "moments4"},
    "moments6": {"method": "moments6"},
    "epipolar": {"method": "epipolar", "visibility": "shadow_map"},
    # Peters 2017 Sec. 6: no special case at the epipole by default; this point shows what the disc costs and buys
    "moments6 with disc": {"method": "moments6", "prefiltered": {"epipole_fallback": True}},
}
#: The shadow-map marcher's curve: steps, step patterns, and the steps it extends to (not with ``--quick``).
MARCH_STEPS = (8, 16, 32, 64, 128, 256)
EXTENDED_STEPS = (512, 1024)
JITTERS = ("per_pixel", "fixed")
#: The exact reference: steps per ray (its own error stays under a fifth of the marcher's best), seeds, pixel subset.
REFERENCE_STEPS = 2048
REFERENCE_SEEDS = (101, 202)
#: (3, from pixel 1: coprime to the sparse look-up's grids, so the subset holds their nodes and interpolated pixels)
REFERENCE_STRIDE = 3
#: Stages that are not the technique's own time.
APART = ("compile", "upload", "shading")


def rel_l1(a: np.ndarray, b: np.ndarray) -> float:
    """sum |a - b| / sum |b| in float64."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    return float(np.abs(a - b).sum() / max(np.abs(b).sum(), 1e-300))


def exact_reference(name: str, width: int, height: int, steps: int, stride: int, seeds=REFERENCE_SEEDS,
                    **scene):
    """The exact marcher on every ``stride``-th pixel of a bench scene, twice; returns (mean reference (Hs, Ws, 3)
    float64, its estimated own rel. L1 error, seconds)."""
    from .. import methods
    from ..pipeline import compile_kernels
    from ..raster.gbuffer import gbuffer_raycast
    from ..scattering.marching import marcher_params, visibility_params
    from ..scattering.raymarch import march_pixel_subset
    from ..scene import DeviceGeometry, build_scene

    cfg = bench_scene_config(name, width, height, scattering={"method": "raymarch", "visibility": "exact"},
                             surfaces={"enabled": False}, **scene)
    compile_kernels(methods.CLASSIC_MODULES + methods.SCATTERING["raymarch"].modules)
    t0 = time.perf_counter()
    scene = build_scene(cfg)
    geometry = DeviceGeometry(scene)
    gbuffer = gbuffer_raycast(scene, geometry)
    vis = visibility_params(scene, "exact", geometry)
    runs = []
    for seed in seeds:
        m = marcher_params(scene, steps=steps, visibility=vis, seed=seed)
        runs.append(march_pixel_subset(scene.camera, gbuffer.distance, m, stride, stride // 2).numpy()
                    .astype(np.float64))
    reference = sum(runs) / len(runs)
    own = rel_l1(runs[0], runs[1]) / 2.0
    return reference, own, time.perf_counter() - t0


def _envelope(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """(time, error) points sorted by time, keeping those whose error is below every faster one's."""
    out: list[tuple[float, float]] = []
    for t, e in sorted(points):
        if e > 0.0 and (not out or e < out[-1][1]):
            out.append((t, e))
    return out


def equal_error_time(points: list[tuple[float, float]], error: float) -> tuple[float, str]:
    """The marcher's time at ``error`` interpolated log-log on its envelope, and the bound: ``""`` inside the curve,
    ``">="`` below its smallest error, ``"<="`` above its largest."""
    env = _envelope(points)
    if error <= env[-1][1]:
        return env[-1][0], ">=" if error < env[-1][1] else ""
    if error >= env[0][1]:
        return env[0][0], "<=" if error > env[0][1] else ""
    for (t0, e0), (t1, e1) in zip(env, env[1:], strict=False):
        if e1 <= error <= e0:
            f = (math.log(error) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(t0) + f * (math.log(t1) - math.log(t0))), ""
    return env[-1][0], ">="  # unreachable for a sorted envelope


def curve_too_short(marcher_errors, best_error: float) -> bool:
    """Whether the marcher's curves stop above ``best_error``, so the curve must take more steps."""
    return best_error < min(marcher_errors)


def technique_ms(stages: dict) -> tuple[float, dict]:
    """(total, stages) of the technique's own stages (ms): compile, upload and shading apart."""
    own = {k: v for k, v in stages.items() if k not in APART}
    return sum(own.values()), own


def interleaved_rounds(runs: dict[str, list], more: int, time_one) -> dict[str, list]:
    """``more`` further interleaved timing rounds of every configuration in ``runs``; returns ``runs``."""
    for _ in range(more):
        for key in runs:
            runs[key].append(time_one(key))
    return runs


def _seconds(stages_ms: dict) -> dict:
    """A run's stage timings in seconds, as :func:`~.scenes.median_stages` takes them."""
    return {k: v / 1e3 for k, v in stages_ms.items()}


def _write_seconds(images: dict) -> float:
    """Seconds to write one frame's outputs (every AOV, the default compression) into a temporary folder."""
    from ..io.images import write_outputs

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        write_outputs(Path(tmp), "frame", images, ["color", "scattering", "surface", "depth"], 1.0)
        return time.perf_counter() - t0


def suite_pareto(report: BenchReport, repeats: int, warmup: int, quick: bool, progress: ProgressFn | None):
    """The error/time curves and equal-error speed-ups (see the module doc)."""
    from ..scene import build_scene

    w, h = (320, 180) if quick else (1920, 1080)
    smap = 256 if quick else 1024
    ref_steps = 256 if quick else REFERENCE_STEPS
    stride = REFERENCE_STRIDE
    march_steps = MARCH_STEPS[:4] if quick else MARCH_STEPS
    extended_steps = () if quick else EXTENDED_STEPS
    first = stride // 2
    no_surf = {"enabled": False}
    cases = len(SCENES) * (1 + int(repeats > 1) + len(march_steps) * len(JITTERS) + len(METHODS))
    done = 0

    def step(label):
        nonlocal done
        if progress:
            progress(label, min(done / cases, 1.0))
        done += 1

    report.meta.update(size=f"{w}x{h}", map=smap, reference_steps=ref_steps, reference_seeds=list(REFERENCE_SEEDS),
                       reference_stride=stride, rounds=max(1, repeats),
                       time="G-buffer + maps + scattering (compile, scene, write apart)")
    summary = {}
    for scene_name in SCENES:
        step(f"{scene_name}: exact reference")
        reference, own_error, ref_s = exact_reference(scene_name, w, h, ref_steps, stride)
        report.add(name=f"{scene_name}: exact reference", params={"steps": ref_steps, "stride": stride},
                   median_ms=1e3 * ref_s, extra={"own_rel_l1": round(own_error, 5)})

        def error_of(images):
            return rel_l1(images["scattering"][first::stride, first::stride], reference)  # noqa: B023

        # the fast methods first: their errors decide how far the marcher's curve must reach
        configs, rounds = {}, {}
        measured = []
        for label, sc in METHODS.items():
            step(f"{scene_name}: {label}")
            cfg = bench_scene_config(scene_name, w, h, surfaces=no_surf,
                                     scattering={**sc, "shadow_map": {"resolution": smap}})
            t_scene = time.perf_counter()
            build_scene(cfg)
            scene_s = time.perf_counter() - t_scene
            stages, images, compile_s, _, stats = render_timed(cfg, 1, warmup)
            configs[label], rounds[label] = cfg, [_seconds(stages)]
            measured.append((label, error_of(images), stats,
                             {"compile_s": round(compile_s, 2), "scene_s": round(scene_s, 3),
                              "write_s": round(_write_seconds(images), 3)}))
        best_method = min(m[1] for m in measured)
        marched = {j: [] for j in JITTERS}  # (steps, configuration key, error, compile s) per step pattern
        for k, steps in enumerate(march_steps + extended_steps):
            if k >= len(march_steps) and not curve_too_short([e for m in marched.values() for _, _, e, _ in m],
                                                             best_method):
                break
            for jitter in JITTERS:
                step(f"{scene_name}: marcher {steps} {jitter}")
                key = f"marcher {steps} {jitter}"
                configs[key] = bench_scene_config(scene_name, w, h, surfaces=no_surf, scattering={
                    "method": "raymarch", "visibility": "shadow_map", "steps": steps, "jitter": jitter,
                    "shadow_map": {"resolution": smap}})
                stages, images, compile_s, _, _ = render_timed(configs[key], 1, warmup)
                rounds[key] = [_seconds(stages)]
                marched[jitter].append((steps, key, error_of(images), compile_s))
        if repeats > 1:
            step(f"{scene_name}: timing rounds")
        timings = {key: technique_ms(median_stages(runs)) for key, runs in interleaved_rounds(
            rounds, max(1, repeats) - 1, lambda key, c=configs: _seconds(render_timed(c[key], 1, 0)[0])).items()}
        curves: dict[str, list[tuple[float, float]]] = {j: [] for j in JITTERS}
        for jitter, points in marched.items():
            for steps, key, err, compile_s in points:
                total, own = timings[key]
                curves[jitter].append((total, err))
                report.add(name=f"{scene_name}: marcher shadow_map {jitter}", params={"steps": steps},
                           median_ms=total, stages_ms=own, rel_l1=err,
                           extra={"compile_s": round(compile_s, 2), "rounds": len(rounds[key])})
        envelope = curves["per_pixel"] + curves["fixed"]
        smallest = min([e for _, e in envelope] + [best_method])
        scene_summary = {"reference_own_rel_l1": round(own_error, 5), "reference_ok": own_error < smallest / 5.0,
                         "marcher_steps": list((march_steps + extended_steps)[:len(curves["fixed"])])}
        for label, err, stats, extra in measured:
            total, own = timings[label]
            extra["rounds"] = len(rounds[label])
            marcher_ms, bound = equal_error_time(envelope, err)
            per_jitter = {j: equal_error_time(curves[j], err) for j in JITTERS}
            row = report.add(name=f"{scene_name}: {label}", params={"map": smap}, median_ms=total, stages_ms=own,
                             rel_l1=err, speedup=marcher_ms / total,
                             extra={"speedup_bound": bound or "=", "marcher_ms_at_equal_error": round(marcher_ms, 1),
                                    **{f"speedup_vs_{j}": f"{t[1]}{t[0] / total:.2f}" for j, t in per_jitter.items()},
                                    **extra})
            if "epipole_raymarched_fraction" in stats:
                row["extra"]["epipole_pct"] = round(100 * stats["epipole_raymarched_fraction"], 2)
            if "evaluated_fraction" in stats:
                row["extra"]["evaluated_pct"] = round(100 * stats["evaluated_fraction"], 2)
            if "epipolar_raymarched_fraction" in stats:
                row["extra"]["raymarched_pct"] = round(100 * stats["epipolar_raymarched_fraction"], 2)
                row["extra"]["mean_sample_steps"] = round(stats["epipolar_mean_sample_steps"], 1)
            scene_summary[label] = {"ms": round(total, 1), "rel_l1": round(err, 5),
                                    "speedup": f"{bound}{marcher_ms / total:.2f}"}
        summary[scene_name] = scene_summary
    report.meta["bar"] = summary
    report.chart = chart_pareto
    if progress:
        progress("pareto", 1.0)


def chart_pareto(report: BenchReport, path: Path) -> Path | None:
    """Each fast method's equal-error speed-up over the marcher per scene, as horizontal bars with their bounds."""
    rows = [r for r in report.rows if "speedup_bound" in (r.get("extra") or {}) and r.get("speedup")]
    bounds = {"=": "", ">=": "≥", "<=": "≤"}
    texts = [f"{bounds.get(r['extra']['speedup_bound'], '')}{r['speedup']:.2f}x" for r in rows]
    return hbar_chart(report, path, rows, [r["speedup"] for r in rows], "equal-error speed-up over the marcher",
                      "speed-up: the marcher's time at the method's error / the method's time", texts=texts, line=1.0)


__all__ = ["chart_pareto", "equal_error_time", "exact_reference", "rel_l1", "suite_pareto", "technique_ms"]
