"""Bench suite ``filterable``: light leaking of the filterable shadow maps, after Peters 2017 Fig. 4.

A bird's-eye view of a ground with a slatted fence, a thin wall behind it and a floating direction sign above it,
under a high sun (as the paper's, chosen to provoke artifacts: where their shadows meet, two or three occluder depths
share a filter region). Surface shadows from PCF (the reference) and from each format of :data:`FORMAT_CASES` with the
same Gaussian width; no medium. Per format: the shadow stages' time, the rel. L1 / RMSE of the surface image against
PCF's, and the light leaking: the visibility V = surface / unshadowed surface above PCF's where PCF is in umbra
(V_pcf < 0.02), its mean and 99th percentile (the paper's insets, in numbers).
"""

from __future__ import annotations

import numpy as np

from ..config import Config
from ..pipeline import render_images
from ..runtime.stages import ProgressFn
from ..scene import build_scene
from .report import BenchReport, errors
from .scenes import render_timed

#: (method, bits) of the rows, after PCF.
FORMAT_CASES = (("msm", 64), ("msm", 128), ("msm2015", 64), ("msm2015", 128), ("vsm", 32), ("vsm", 64),
                ("evsm", 64), ("evsm", 128))
#: Shadow stages timed per row.
SHADOW_STAGES = ("msm_generate", "msm_filter", "shading")


def leaking_scene(width: int, height: int, resolution: int, shadows: dict) -> Config:
    """The Fig. 4-like scene at a size, map resolution and ``render.shadows`` section."""
    board = {"posts": 2, "slats": 1, "gap": 0.01, "slat_thickness": 0.05, "rails": 0}
    return Config.from_dict({
        "scene": {"meshes": [
            {"procedural": "ground_plane", "params": {"size": 20}, "material": {"albedo": [0.6, 0.6, 0.6]}},
            {"procedural": "fence", "params": {"posts": 4, "slats": 6, "height": 1.8, "post_spacing": 1.5}},
            {"procedural": "fence", "params": {**board, "height": 1.0, "post_spacing": 3.0},  # the thin wall
             "transform": {"translate": [0.6, 0.0, 1.2]}},
            {"procedural": "fence", "params": {**board, "height": 0.6, "post_spacing": 1.4},  # the sign
             "transform": {"translate": [-1.2, 1.6, 0.4], "rotate_deg": [0, 25, 0]}},
        ]},
        "camera": {"position": [0.2, 9.0, 1.3], "look_at": [0.2, 0.0, 1.3], "up": [0, 0, 1], "fov_y": 38,
                   "width": width, "height": height},  # straight down: +z (away from the sun) is up in the image
        "light": {"type": "directional", "direction": [0.15, -0.8, 1.0], "irradiance": [3.0, 3.0, 3.0]},
        "medium": {"sigma_t": 0.0},
        "render": {"scattering": {"method": "raymarch", "visibility": "shadow_map", "steps": 1,
                                  "shadow_map": {"resolution": resolution}},
                   "shadows": shadows},
    })


def suite_filterable(report: BenchReport, repeats: int, warmup: int, quick: bool, progress: ProgressFn | None):
    w, h = (160, 90) if quick else (960, 540)
    smap = 256 if quick else 1024
    fpx = 5
    report.meta.update(scene="fence, thin wall and sign under a high sun (Peters 2017 Fig. 4)", size=f"{w}x{h}",
                       map=smap, filter_px=fpx)
    cases = [("pcf", None), *FORMAT_CASES]
    surfaces = {}
    unshadowed = render_images(build_scene(cfg := leaking_scene(w, h, smap, {"method": "none"})), cfg.render)[0]
    lit = unshadowed["surface"].sum(axis=2)
    for k, (method, bits) in enumerate(cases):
        if progress:
            progress(f"{method} {bits or ''}".strip(), k / len(cases))
        shadows = {"method": method, "filter_px": fpx, **({"storage": bits} if bits else {})}
        all_stages, images, _, _, stats = render_timed(leaking_scene(w, h, smap, shadows), repeats, warmup)
        stages = {k: v for k, v in all_stages.items() if k in SHADOW_STAGES}
        surfaces[method, bits] = images["surface"]
        label = f"{method} {bits}-bit" if bits else "pcf"
        row = report.add(name=label, params={"method": method, "bits": bits}, median_ms=sum(stages.values()),
                         stages_ms=stages, extra={k: v for k, v in stats.items() if k in ("msm_bytes",
                                                                                           "evsm_exponents")})
        if bits:
            row.update(errors(images["surface"], surfaces["pcf", None]))
            row["extra"].update(light_leaking(images["surface"], surfaces["pcf", None], lit))
    if progress:
        progress("filterable", 1.0)


def light_leaking(surface: np.ndarray, reference: np.ndarray, lit: np.ndarray) -> dict:
    """Mean and 99th percentile of the visibility above the reference's where the reference is in umbra."""
    ok = lit > 1e-4
    v = np.where(ok, surface.sum(axis=2) / np.where(ok, lit, 1.0), 0.0)
    v_ref = np.where(ok, reference.sum(axis=2) / np.where(ok, lit, 1.0), 0.0)
    umbra = ok & (v_ref < 0.02)
    excess = np.maximum(v - v_ref, 0.0)[umbra]
    if excess.size == 0:
        return {"umbra_px": 0}
    return {"umbra_px": int(umbra.sum()), "leak_mean": round(float(excess.mean()), 5),
            "leak_p99": round(float(np.percentile(excess, 99)), 4)}


__all__ = ["FORMAT_CASES", "leaking_scene", "light_leaking", "suite_filterable"]
