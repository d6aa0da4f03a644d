"""The ``epipole`` pass: the pixels a look-up cannot answer well are ray-marched with shadow-map visibility: the disc
around an epipole in view (Klehm 2014 Sec. 5, Fig. 8; :mod:`.epipole_regions`) and the rays ending in shadow whose
whole look-up lies within their end surface's own zone (``end_offset``; flagged by :mod:`.evaluate`).
"""

from __future__ import annotations

import warp as wp

from ...runtime.stages import StageTimer
from .epipole_regions import march_epipole_regions, march_flagged_pixels


def march_epipole(frame, settings, regions: list, radiance: wp.array, end_zone: wp.array | None,
                  stage: StageTimer, device) -> tuple[int, float]:
    """March the flagged end-zone pixels (``end_zone``; None: none flagged) and the epipole ``regions`` into
    ``radiance`` (stage ``epipole``). Returns (end-zone pixels marched, the regions' marched share; 1 without)."""
    scene, gbuffer, shadow_map, p = frame.scene, frame.gbuffer, frame.shadow_map, settings.prefiltered
    march = {"steps": p.epipole_steps, "seed": settings.seed, "shadow_bias_texels": settings.shadow_map.bias,
             "jitter": settings.march_jitter, "device": device}
    end_zone_pixels = 0
    if end_zone is not None:
        with stage("epipole"):
            end_zone_pixels = march_flagged_pixels(scene, gbuffer, shadow_map, end_zone, radiance, **march)
    marched_share = 1.0
    if regions:
        with stage("epipole"):
            marched_share = march_epipole_regions(scene, gbuffer, shadow_map, regions, radiance,
                                                  stride=p.epipole_stride, tolerance=p.evaluate_tolerance, **march)
    return end_zone_pixels, marched_share


__all__ = ["march_epipole"]
