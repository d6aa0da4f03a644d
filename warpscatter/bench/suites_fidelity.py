"""Bench suite ``fidelity``: every fast method's error on every bundled sunlit scene, its light in and out of view.

Issue #13's bar at 960x540 with 1024^2 maps (``--quick``: 240x135, 256^2): each scene of :data:`SCENES` under its
own light, the light turned half-way round the vertical and a quarter (:data:`LIGHTS`), plus the spot-lit
:data:`SPOT_SCENES`. Per case: the exact reference (:func:`~.suites_pareto.exact_reference`), the 128-step shadow-map
marcher and each fast method at its defaults, with time and rel. L1; the bar is a method's error against twice the
marcher's (issue #13).
"""

from __future__ import annotations

from pathlib import Path

from ..runtime.stages import ProgressFn
from .report import BenchReport, chart_title, log_ticks, pyplot, save_figure
from .scenes import bench_scene_config, render_timed
from .suites_pareto import REFERENCE_SEEDS, exact_reference, rel_l1, technique_ms

#: The bundled sunlit scenes (:data:`~.scenes.SCENES` keys).
SCENES = ("colonnade", "canopy", "window", "quickstart", "terrain", "gate", "gate_translucent")
#: The spot-lit scenes (their own light only).
SPOT_SCENES = ("spot_fence", "colonnade_spot")
#: The quarter turn of the "light beside" variant (clockwise from above; the window room's harder one).
BESIDE_DEG = -90.0
#: The light variants: the config's own, turned half-way round the vertical, and a quarter of the way (degrees).
LIGHTS = {"own light": 0.0, "mirrored light": 180.0, "light beside": BESIDE_DEG}
#: The methods at their defaults; the first is the bar's baseline.
MARCHER = "raymarch shadow_map 128"
METHODS = {
    MARCHER: {"method": "raymarch", "visibility": "shadow_map", "steps": 128},
    "fourier": {"method": "fourier"},
    "moments4": {"method": "moments4"},
    "moments6": {"method": "moments6"},
    "epipolar": {"method": "epipolar", "visibility": "shadow_map"},
}
REFERENCE_STEPS = 1024
REFERENCE_STRIDE = 3


def light_turn(degrees: float) -> dict:
    """The :func:`~.scenes.bench_scene_config` keys that turn a scene's light ``degrees`` about the vertical (180: the
    exact mirror, ``mirror_light``)."""
    return {"mirror_light": True} if degrees == 180.0 else {"turn_light_deg": degrees}


def suite_fidelity(report: BenchReport, repeats: int, warmup: int, quick: bool, progress: ProgressFn | None):
    """Errors and times of every method on every case (see the module doc)."""
    w, h = (240, 135) if quick else (960, 540)
    smap = 256 if quick else 1024
    ref_steps = 256 if quick else REFERENCE_STEPS
    stride = 2 if quick else REFERENCE_STRIDE
    first = stride // 2
    scenes = SCENES[:2] if quick else SCENES
    spots = SPOT_SCENES[:1] if quick else SPOT_SCENES
    cases = [(s, light) for s in scenes for light in LIGHTS] + [(s, "own light") for s in spots]
    report.meta.update(size=f"{w}x{h}", map=smap, reference_steps=ref_steps, reference_seeds=list(REFERENCE_SEEDS),
                       reference_stride=stride, time="G-buffer + maps + scattering (compile, scene, write apart)")
    summary: dict = {}
    for k, (scene_name, light) in enumerate(cases):
        title = f"{scene_name}, {light}"
        if progress:
            progress(f"{title}: exact reference", k / len(cases))
        turn = light_turn(LIGHTS[light])
        reference, own_error, ref_s = exact_reference(scene_name, w, h, ref_steps, stride, **turn)
        report.add(name=f"{title}: exact reference", params={"steps": ref_steps, "stride": stride},
                   median_ms=1e3 * ref_s, extra={"own_rel_l1": round(own_error, 5)})
        case = {"reference_own_rel_l1": round(own_error, 5)}
        for label, sc in METHODS.items():
            if progress:
                progress(f"{title}: {label}", (k + 0.5) / len(cases))
            cfg = bench_scene_config(scene_name, w, h, **turn, surfaces={"enabled": False},
                                     scattering={**sc, "shadow_map": {"resolution": smap}})
            stages, images, compile_s, _, _ = render_timed(cfg, repeats, warmup)
            total, own = technique_ms(stages)
            err = rel_l1(images["scattering"][first::stride, first::stride], reference)
            row = report.add(name=f"{title}: {label}", params={"map": smap}, median_ms=total, stages_ms=own,
                             rel_l1=err, extra={"compile_s": round(compile_s, 2)})
            case[label] = {"ms": round(total, 1), "rel_l1": round(err, 5)}
            if label != MARCHER:
                base = case[MARCHER]
                row["speedup"] = base["ms"] / total
                row["extra"].update(vs_marcher_error=round(err / max(base["rel_l1"], 1e-12), 2),
                                    within_2x_marcher=err <= 2.0 * base["rel_l1"])
                case[label].update(within_2x_marcher=err <= 2.0 * base["rel_l1"],
                                   time_vs_marcher=round(total / base["ms"], 3))
        case["reference_ok"] = own_error < min(v["rel_l1"] for v in case.values() if isinstance(v, dict)) / 5.0
        summary[title] = case
    report.meta["cases"] = summary
    report.chart = chart_fidelity
    if progress:
        progress("fidelity", 1.0)


def chart_fidelity(report: BenchReport, path: Path) -> Path | None:
    """Rel. L1 per case (log scale): each fast method's marker, the marcher's error and its double (the bar)."""
    plt = pyplot()
    if plt is None:
        return None
    cases = list(report.meta.get("cases", {}))
    if not cases:
        return None
    fig, ax = plt.subplots(figsize=(max(8.0, 1.1 * len(cases)) + 2.5, 4.6))
    x = range(len(cases))
    data = report.meta["cases"]
    marcher = [data[c][MARCHER]["rel_l1"] for c in cases]
    ax.plot(x, marcher, "_", markersize=18, color="0.3", label=f"{MARCHER}")
    ax.plot(x, [2.0 * e for e in marcher], "_", markersize=18, color="0.6", label="2x the marcher (the bar)")
    markers = {"fourier": "o", "moments4": "s", "moments6": "D", "epipolar": "^"}
    for n, (label, marker) in enumerate(markers.items()):
        ax.plot([i + 0.08 * (n - 1.5) for i in x], [data[c][label]["rel_l1"] for c in cases], marker, markersize=6,
                linestyle="none", label=label)
    ax.set_xticks(list(x), [c.replace("_", " ").replace(", ", "\n") for c in cases], fontsize=7)
    ax.set_yscale("log")
    shown = [data[c][m]["rel_l1"] for c in cases for m in (MARCHER, *markers)]
    log_ticks(ax.yaxis, [v for v in shown if v > 0.0] + [2.0 * e for e in marcher if e > 0.0] or [1.0])
    ax.set_ylabel("rel. L1 vs exact reference")
    ax.set_title(chart_title(report, f"error per case at {report.meta.get('size', '')}, map "
                                     f"{report.meta.get('map', '')}"), fontsize=9)
    ax.grid(True, axis="y", which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)  # beside the data
    return save_figure(fig, path)


__all__ = ["BESIDE_DEG", "LIGHTS", "METHODS", "SCENES", "SPOT_SCENES", "chart_fidelity", "light_turn", "suite_fidelity"]
