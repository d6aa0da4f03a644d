"""Bench suite ``papers``: the four papers' checkable claims, each measured here and marked holds / does not hold.

Each section adds its rows and one entry per claim to ``meta["claims"]`` (paper and place, claim, our numbers,
``holds``). Scenes are the bundled configs at 960x540 with 1024^2 maps (``--quick``: smoke only), against the
exact reference of :func:`.suites_pareto.exact_reference`. Claims: Klehm et al. 2014 Fig. 3 (transmittance weighting)
and Table 1 (regions per slice); Peters et al. 2017 Sec. 5 (moments outperform Fourier), Figs. 19-20; Engelhardt &
Dachsbacher 2010 Figs. 9-10 (against screen-space subsampling; line counts); Ritschel et al. 2007 Table 1
(compression, its growth with N, the enumerations).
"""

from __future__ import annotations

import math

from ..runtime.stages import ProgressFn
from .report import BenchReport
from .scenes import _bumpy_sphere, bench_scene_config, render_timed
from .suites_pareto import exact_reference, rel_l1, technique_ms

#: The exact reference: steps and pixel stride (quick: 256 steps, every 2nd pixel).
REFERENCE_STEPS, REFERENCE_STRIDE = 1024, 3


class Claims:
    """The claims of a run: ``add`` one (paper, claim, ours, holds) and they land in ``report.meta["claims"]``."""

    def __init__(self, report: BenchReport):
        self.items = report.meta.setdefault("claims", [])

    def add(self, paper: str, claim: str, ours: str, holds: bool, rule: str) -> None:
        self.items.append({"paper": paper, "claim": claim, "ours": ours, "holds": bool(holds), "rule": rule})


def _scattering_error(report, name, scene, w, h, smap, scattering, reference, stride, repeats, warmup, params=None,
                      **scene_kw):
    """Render ``scene`` with ``scattering`` (surfaces off), add a row with its technique time and rel. L1 against
    ``reference`` (every ``stride``-th pixel); return (ms, error, stages, the image on the reference's pixels)."""
    cfg = bench_scene_config(scene, w, h, surfaces={"enabled": False},
                             scattering={**scattering, "shadow_map": {"resolution": smap}}, **scene_kw)
    stages, images, _, _, stats = render_timed(cfg, repeats, warmup)
    total, own = technique_ms(stages)
    first = stride // 2
    sub = images["scattering"][first::stride, first::stride]
    err = rel_l1(sub, reference)
    report.add(name=name, params={"scene": scene, **(params or {})}, median_ms=total, stages_ms=own, rel_l1=err)
    return total, err, own, sub


def suite_papers(report: BenchReport, repeats: int, warmup: int, quick: bool, progress: ProgressFn | None):
    w, h = (240, 135) if quick else (960, 540)
    smap = 256 if quick else 1024
    steps, stride = (256, 2) if quick else (REFERENCE_STEPS, REFERENCE_STRIDE)
    report.meta.update(size=f"{w}x{h}", map=smap, reference_steps=steps, reference_stride=stride)
    claims = Claims(report)
    refs: dict = {}

    def reference(scene, **kw):
        key = (scene, repr(sorted(kw.items())))
        if key not in refs:
            refs[key] = exact_reference(scene, w, h, steps, stride, **kw)[0]
        return refs[key]

    def step(label, fraction):
        if progress:
            progress(label, fraction)

    # ---- Klehm 2014 Fig. 3: transmittance weighting vs average visibility, thin to thick media ----
    gains = []
    for k, sigma in enumerate((0.02, 0.08, 0.3)):
        step(f"Klehm Fig. 3: sigma_t {sigma}", 0.05 + 0.05 * k)
        ref = reference("colonnade", medium={"sigma_t": sigma})
        errs = {}
        for weighting in ("transmittance", "average"):
            _, errs[weighting], _, _ = _scattering_error(
                report, f"Klehm Fig. 3: fourier {weighting}", "colonnade", w, h, smap,
                {"method": "fourier", "prefiltered": {"weighting": weighting}}, ref, stride, repeats, warmup,
                params={"sigma_t": sigma, "weighting": weighting}, medium={"sigma_t": sigma})
        gains.append((sigma, errs["average"], errs["transmittance"]))
    claims.add("Klehm 2014 Fig. 3", "transmittance weighting is closer to the reference than the average visibility, "
               "the more so the thicker the medium",
               "; ".join(f"sigma_t {s}: average {100 * a:.2f} % vs weighted {100 * t:.2f} %" for s, a, t in gains),
               all(t < a for _, a, t in gains) and (gains[-1][1] / gains[-1][2] >= gains[0][1] / gains[0][2]),
               "weighted error below average's at every sigma_t, and the ratio growing with sigma_t")

    # ---- Klehm 2014 Table 1: regions per slice trade prefix-sum time for evaluation time ----
    split_rows = {}
    for k, splits in enumerate((1, 2, 3, 4)):
        step(f"Klehm Table 1: {splits} regions", 0.2 + 0.03 * k)
        cfg = bench_scene_config("colonnade", w, h, surfaces={"enabled": False},
                                 scattering={"method": "fourier", "shadow_map": {"resolution": smap},
                                             "prefiltered": {"splits": splits, "rectification": "nonlinear"}})
        stages, _, _, _, _ = render_timed(cfg, repeats, warmup)
        total, own = technique_ms(stages)
        split_rows[splits] = own
        report.add(name="Klehm Table 1: fourier regions per slice", params={"regions": splits}, median_ms=total,
                   stages_ms=own)
    pre = {s: v.get("prefilter", 0.0) for s, v in split_rows.items()}
    ev = {s: v.get("evaluate", 0.0) for s, v in split_rows.items()}
    claims.add("Klehm 2014 Table 1", "splitting each row into regions moves work from the prefix sums to the "
               "evaluation (more regions: faster sums, slower look-ups)",
               "; ".join(f"{s} regions: sums {pre[s]:.0f} ms, evaluate {ev[s]:.0f} ms" for s in split_rows),
               pre[4] < pre[1] and ev[4] > ev[1], "with 4 regions the sums faster and the evaluation slower than "
               "with 1 (Klehm's GPU gains parallel threads per slice; on the CPU a thread already sums whole rows)")

    # ---- Peters 2017 Sec. 5: moments vs Fourier; Fig. 19: 96 vs 60 bits ----
    results = {}
    scenes = ("colonnade", "canopy", "window")
    for k, scene in enumerate(scenes):
        ref = reference(scene)
        for culling in (True, False):
            for method in ("fourier", "moments4", "moments6"):
                step(f"Peters Sec. 5: {scene} {method}", 0.35 + 0.1 * k)
                label = f"Peters Sec. 5: {method}" + ("" if culling else " unculled")
                ms, err, _, img = _scattering_error(
                    report, label, scene, w, h, smap,
                    {"method": method, "prefiltered": {"caster_culling": culling}}, ref, stride, repeats, warmup,
                    params={"caster_culling": culling})
                results[scene, method, culling] = (ms, err)
                if culling:  # Peters Figs. 15-16: the same scene for both bases, with their error images
                    report.comparisons.setdefault(scene, (ref, {}))[1][method] = img
    for culling in (True, False):
        wins = [s for s in scenes if results[s, "moments6", culling][1] < results[s, "fourier", culling][1]]
        claims.add("Peters 2017 Sec. 5", "moments (moments6) outperform Fourier"
                   + (" (with caster culling)" if culling else " (without caster culling)"),
                   "; ".join(f"{s}: moments6 {100 * results[s, 'moments6', culling][1]:.2f} % vs fourier "
                             f"{100 * results[s, 'fourier', culling][1]:.2f} %" for s in scenes),
                   len(wins) == len(scenes), f"moments6's error below fourier's on every scene (holds on: "
                                             f"{', '.join(wins) or 'none'})")
    ref = reference("window")
    bits = {}
    for b in (64, 96):
        step(f"Peters Fig. 19: moments6 {b} bits", 0.7)
        _, bits[b], _, _ = _scattering_error(report, "Peters Fig. 19: moments6", "window", w, h, smap,
                                          {"method": "moments6", "moments": {"storage_bits": b}}, ref, stride,
                                          repeats, warmup, params={"bits": b})
    claims.add("Peters 2017 Fig. 19", "96 bits of moments6 are slightly better than 60 (64) bits in an indoor scene",
               f"window room: 64 bits {100 * bits[64]:.2f} %, 96 bits {100 * bits[96]:.2f} %", bits[96] < bits[64],
               "the 96-bit error below the 64-bit one")

    # ---- Peters 2017 Fig. 20: time against map and output resolution ----
    sizes = ((120, 68), (240, 135)) if quick else ((480, 270), (960, 540), (1920, 1080))
    maps = (128, 256) if quick else (512, 1024, 2048)
    scaling = {}
    for method in ("fourier", "moments4", "moments6"):
        step(f"Peters Fig. 20: {method}", 0.75)
        for sw, sh in sizes:
            cfg = bench_scene_config("colonnade", sw, sh, surfaces={"enabled": False},
                                     scattering={"method": method, "shadow_map": {"resolution": smap}})
            total, own = technique_ms(render_timed(cfg, repeats, warmup)[0])
            report.add(name=f"Peters Fig. 20: {method} vs output", params={"size": f"{sw}x{sh}", "map": smap},
                       median_ms=total, stages_ms=own)
            scaling[method, "output", sw] = own.get("evaluate", 0.0)
        for m in maps:
            cfg = bench_scene_config("colonnade", w, h, surfaces={"enabled": False},
                                     scattering={"method": method, "shadow_map": {"resolution": m}})
            total, own = technique_ms(render_timed(cfg, repeats, warmup)[0])
            report.add(name=f"Peters Fig. 20: {method} vs map", params={"size": f"{w}x{h}", "map": m},
                       median_ms=total, stages_ms=own)
            scaling[method, "map", m] = sum(v for k, v in own.items() if k in ("rectify", "resample_msm",
                                                                               "caster_culling", "prefilter"))
    out_ratio = {m: scaling[m, "output", sizes[-1][0]] / max(scaling[m, "output", sizes[0][0]], 1e-9)
                 for m in ("fourier", "moments4", "moments6")}
    pixel_ratio = (sizes[-1][0] * sizes[-1][1]) / (sizes[0][0] * sizes[0][1])
    claims.add("Peters 2017 Fig. 20", "the evaluation cost grows with the output resolution (one look-up per pixel)",
               "; ".join(f"{m}: evaluate x{r:.1f} for x{pixel_ratio:.0f} pixels" for m, r in out_ratio.items()),
               all(r > 0.25 * pixel_ratio for r in out_ratio.values()),
               "evaluate time grows by more than a quarter of the pixel ratio")

    # ---- Engelhardt 2010 Fig. 10: epipolar line counts ----
    ref = reference("colonnade")
    lines = {}
    for n in (256, 512, 1024):
        step(f"Engelhardt Fig. 10: {n} lines", 0.85)
        lines[n] = _scattering_error(report, "Engelhardt Fig. 10: epipolar", "colonnade", w, h, smap,
                                     {"method": "epipolar", "visibility": "shadow_map", "epipolar": {"lines": n}},
                                     ref, stride, repeats, warmup, params={"lines": n})[:2]
    # Fig. 9: screen-space subsampling (the same marcher and bilateral upsampling on a regular grid) at equal time
    screen = {}
    for grid in (2, 3, 4, 6, 8):
        step(f"Engelhardt Fig. 9: screen-space every {grid} px", 0.87)
        screen[grid] = _scattering_error(report, "Engelhardt Fig. 9: screen-space subsampling", "colonnade", w, h,
                                         smap, {"method": "epipolar", "visibility": "shadow_map", "epipolar": {
                                             "sampling": "screen", "fallback_stride": grid}},
                                         ref, stride, repeats, warmup, params={"grid_px": grid})[:2]
    epi_ms, epi_err = lines[512]
    as_fast = [e for ms, e in screen.values() if ms <= epi_ms]  # the screen-space grids that cost no more
    claims.add("Engelhardt 2010 Fig. 9", "epipolar sampling beats naive screen-space subsampling at equal time",
               f"epipolar (512 lines) {100 * epi_err:.2f} % in {epi_ms:.0f} ms; screen-space: " + "; ".join(
                   f"every {s} px {100 * e:.2f} % in {ms:.0f} ms" for s, (ms, e) in screen.items()),
               all(epi_err < e for e in as_fast), "epipolar's error below that of every screen-space grid that costs "
               "no more time")
    claims.add("Engelhardt 2010 Fig. 10", "more epipolar lines give a lower error at a higher cost",
               "; ".join(f"{n} lines: {100 * e:.2f} % in {ms:.0f} ms" for n, (ms, e) in lines.items()),
               lines[1024][1] <= lines[256][1] and lines[1024][0] >= lines[256][0],
               "1024 lines: error at most and time at least 256 lines'")

    # ---- Ritschel 2007 Table 1: compression, its growth with N, enumerations ----
    from ..csm import build_csm
    from ..scene import procedural
    from ..scene.meshes import load_mesh
    from .scenes import bundled_asset

    gate = load_mesh(bundled_asset("gate.obj"))
    fence = procedural.fence(posts=4, slats=6)
    objects = {"gate": (gate.vertices, gate.triangles), "fence": (fence.vertices, fence.triangles),
               "bumpy sphere": _bumpy_sphere(40 if quick else 120)}
    res = 64 if quick else 128
    grids = (8, 16) if quick else (16, 32, 64)
    best, growth = {}, {}
    for k, (name, (v, t)) in enumerate(objects.items()):
        step(f"Ritschel Table 1: {name}", 0.9 + 0.03 * k)
        ratios = {}
        for n in grids:
            for enum in (("hilbert", "zigzag", "scanline") if n == grids[-1] else ("hilbert",)):
                st = build_csm(v, t, maps=(n, n), resolution=res, enumeration=enum).stats
                ratio4 = st.uncompressed_bytes / st.compressed_bytes
                report.add(name=f"Ritschel Table 1: {name}", params={"N": f"{n}x{n}", "M": res, "enumeration": enum},
                           median_ms=1e3 * (st.seconds_render + st.seconds_compress),
                           extra={"ratio_4byte": round(ratio4, 1), "ratio_2byte": round(ratio4 / 2, 1),
                                  "segments_per_texel": round(st.segments_per_texel, 2)})
                ratios[n, enum] = ratio4
        segs = {e: ratios[grids[-1], e] for e in ("hilbert", "zigzag", "scanline")}
        best[name] = max(segs, key=segs.get)
        growth[name] = ratios[grids[-1], "hilbert"] / ratios[grids[0], "hilbert"]
    n_ratio = (grids[-1] / grids[0]) ** 2
    claims.add("Ritschel 2007 Table 1", "the compression ratio grows roughly with the square root of the number of "
               "maps N", "; ".join(f"{o}: x{g:.1f} for N x{n_ratio:.0f} (sqrt: x{math.sqrt(n_ratio):.0f})"
                                  for o, g in growth.items()),
               all(0.5 * math.sqrt(n_ratio) <= g <= 2.0 * math.sqrt(n_ratio) for g in growth.values()),
               "growth within a factor 2 of sqrt(N ratio) for every object")
    claims.add("Ritschel 2007 Table 1", "the Hilbert enumeration compresses best",
               "; ".join(f"{o}: best {b}" for o, b in best.items()), all(b == "hilbert" for b in best.values()),
               "Hilbert the best of hilbert / zigzag / scanline on every object")
    step("papers", 1.0)


__all__ = ["Claims", "suite_papers"]
