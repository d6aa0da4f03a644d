"""``render()`` of the ``fourier``, ``moments4`` and ``moments6`` methods: the paper's steps as passes (package doc).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ...runtime.device import default_device
from ...runtime.stages import StageTimer
from ...scene.lights import DirectionalLight, SpotLight, light_params
from ..rectify.caster_culling import cull_unseen_casters, end_faces_away
from ..rectify.params import wrap_rows
from ..rectify.projective import ProjectiveRectification
from ..settings import ScatteringSettings
from .debug import add_debug_images
from .epipole import march_epipole
from .epipole_regions import epipole_pixel_fraction, epipole_regions
from .evaluate import Evaluation, coords_of_every_pixel, pixel_coords
from .prefilter import prefilter_map
from .rectify import map_depth, rectify_map
from .spot import render_spot


def render(frame, settings: ScatteringSettings, stage: StageTimer | None = None) -> tuple[wp.array, dict]:
    """Prefiltered single scattering: the ``fourier``, ``moments4`` and ``moments6`` methods (the package doc; the
    registry's call shape, :mod:`warpscatter.methods`).

    Args:
        frame: :class:`~warpscatter.pipeline.frame.Frame` with a directional or spot light (G-buffer, shadow map).
        settings: :class:`~warpscatter.scattering.settings.ScatteringSettings`; ``method`` selects the basis,
            ``shadow_map.resolution`` is also the rectified map's size (columns: texels along each view ray, rows:
            epipolar slices).
        stage: the :class:`~warpscatter.runtime.stages.StageTimer` (stages ``rectify``, ``resample_msm``,
            ``pixel_coords``, ``caster_culling``, ``prefilter``, ``evaluate``, ``epipole``).

    Returns:
        (L_scat, info): (H, W) vec3 wp.array and a dict describing the rectification and why it was chosen, the
        filtered textures and the epipole regions; the debug outputs in ``info["debug_images"]``
        (:func:`~.debug.add_debug_images`).

    Raises:
        ValueError: for a light that is neither directional nor spot.
    """
    stage = stage or StageTimer()
    device = default_device(frame.device)
    scene, gbuffer, cam, p = frame.scene, frame.gbuffer, frame.scene.camera, settings.prefiltered
    if isinstance(scene.light, SpotLight):
        return render_spot(frame, settings, stage)
    if not isinstance(scene.light, DirectionalLight):
        raise ValueError(f"the {settings.method} method needs a directional or spot light (render.scattering.method)")

    # ---- 1. rectify: the light's view in rectified coordinates (Klehm 2014 Sec. 4.2, Peters 2017 App. A) ----
    rectified = rectify_map(frame, p, settings.shadow_map.size, stage, device)
    coords = None  # every pixel's look-up coordinates, where a step needs them all
    if coords_of_every_pixel(settings, frame.aovs):
        with stage("pixel_coords"):
            coords = pixel_coords(rectified.rect, cam, gbuffer.distance, device=device)
    map_before_culling = map_depth(rectified.depth).copy() if "rectified_map" in frame.aovs else None
    culled = None
    if settings.culls_casters:  # not in the papers: empty the texels whose blockers shadow no look-up
        with stage("caster_culling"):
            faces_away = end_faces_away(cam, gbuffer, light_params(scene.light, device), device)
            culled = cull_unseen_casters(rectified.depth, rectified.rect, coords, bias=p.caster_culling_bias,
                                         device=device, mip_levels=p.mip_levels, faces_away=faces_away)

    # ---- 2. prefilter: basis or moments in per-row weighted prefix sums (Klehm 2014 Sec. 3, Peters 2017 Sec. 5) ----
    with stage("prefilter"):
        filtered = prefilter_map(rectified, settings, scene, device)

    # ---- 3. evaluate: one filtered look-up per pixel (Klehm 2014 Listing 4, Peters 2017 D.5) ----
    regions = (epipole_regions(cam, scene.light.direction, p.epipole_angle_deg, p.epipole_block)
               if settings.marches_epipole else [])
    with stage("evaluate"):
        evaluation = Evaluation(frame, settings, rectified.rect, filtered, coords, regions, device)
        radiance, sparse = evaluation.run()

    # ---- 4. epipole fallback: ray-march what the look-up cannot answer (Klehm 2014 Sec. 5) ----
    end_zone = evaluation.result.end_zone if evaluation.end_zone_any else None
    end_zone_pixels, marched_share = march_epipole(frame, settings, regions, radiance, end_zone, stage, device)

    info = _info(settings, cam, rectified, filtered, evaluation, sparse, regions, culled, end_zone_pixels,
                 marched_share)
    add_debug_images(info, frame, coords, regions, rectified.depth, map_before_culling,
                     filtered.chain.params(wrap_rows(rectified.rect)), sparse)
    return radiance, info


def _info(settings, cam, rectified, filtered, evaluation, sparse, regions, culled, end_zone_pixels: int,
          marched_share: float) -> dict:
    """The stats of a directional-light render (what each pass chose and measured)."""
    p, m, rect, choice = settings.prefiltered, settings.moments, rectified.rect, rectified.choice
    cols, rows = settings.shadow_map.size
    texture = filtered.texture
    info = {
        "rectification": choice.kind,
        "rectification_reason": choice.reason,
        "epipole_distance": round(choice.epipole_distance, 4) if np.isfinite(choice.epipole_distance) else None,
        "rectified_map": [cols, rows],
        "basis": settings.method,
        **({"coefficients": settings.fourier.coefficients, "splits": texture.splits} if settings.method == "fourier"
           else {"overestimation": m.overestimation if m.overestimation is not None else
                 [round(b, 4) for b in m.beta_range()],
                 "overestimation_rise_cos": m.overestimation_rise_cos,
                 "epipole_taper_deg": m.epipole_taper_deg}),
        "bits_per_texel": settings.filtered_bits_per_texel,
        "segments": filtered.segments,
        "segment_depth": filtered.segment_depth,
        "depth_bounds": p.depth_bounds,
        "depth_warp": filtered.depth_warp,
        "mip_levels": filtered.chain.levels,
        "end_zone_pixels": end_zone_pixels,
        "end_offset": evaluation.end_offsets[0],
        "end_offset_lit": evaluation.end_offsets[1],
        "end_samples": evaluation.end_samples,
        "evaluate_stride": sparse.stride,
        "evaluate_levels": sparse.levels,
        "evaluated_fraction": round(sparse.evaluated_fraction, 4),
        **rectified.info,
        "caster_culling": culled is not None,
        **({} if culled is None else {"culled_texel_fraction": round(culled, 4)}),
        "filtered_map_bytes": texture.nbytes,  # allocated: the texture (and a split filter's weight sums)
        "epipole_blocks": [[*r.rect, r.name] for r in regions],
        "epipole_angle_deg": round(regions[0].inner_deg, 3) if regions else None,
        "epipole_raymarched_fraction": round(epipole_pixel_fraction(cam, regions), 4),
        "epipole_marched_share": round(marched_share, 4),
    }
    info.update(filtered.info)
    if isinstance(rect, ProjectiveRectification):
        info.update({"regions": rect.regions, "near_far": [round(rect.near, 6), round(rect.far, 6)]})
    else:
        info["full_circle"] = rect.full_circle
        info["map_radius"] = round(rect.r_max, 4)  # world units from the camera's light axis
    return info


__all__ = ["render"]
