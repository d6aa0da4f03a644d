"""The ``epipole`` pass: the pixels a look-up cannot answer well are ray-marched with shadow-map visibility.

* When the light (or its flip) projects into the view, the non-linear rectification's slices all meet there and
  precision is low: light bleeds into a ring around the epipole (Klehm 2014 Sec. 5, Fig. 8). The pixels whose view
  ray lies within ``epipole_angle_deg`` of the light direction (or its flip), at least Klehm's block of
  ``epipole_block`` pixels, are marched and blended linearly in the angle with the look-up over a band of
  ``EPIPOLE_BLEND`` times that radius (:mod:`.epipole_regions`). An angle rather than a pixel count keeps the region
  the same at every resolution.
* Rays ending in shadow whose whole extent lies within their end surface's own zone (``end_offset``; flagged by the
  look-up, :mod:`.evaluate`) have nothing to look up: they are marched as the disc is.
"""

from __future__ import annotations

import warp as wp

from ...runtime.stages import StageTimer
from .epipole_regions import march_epipole_regions, march_flagged_pixels


def march_epipole(frame, settings, regions: list, radiance: wp.array, end_zone: wp.array | None,
                  stage: StageTimer, device) -> tuple[int, float]:
    """March the flagged end-zone pixels (``end_zone``: the look-up's flags, None when it flagged none) and the
    epipole ``regions`` into ``radiance`` (stage ``epipole``).

    Returns:
        (end-zone pixels marched, the marched share of the regions' pixels; 1 without regions).
    """
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
