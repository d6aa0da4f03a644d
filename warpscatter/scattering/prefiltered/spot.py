"""The prefiltered methods under a spot light (Klehm 2014 Sec. 3.2, "Local Lights"): the same steps on
:mod:`..rectify`'s map (rows: epipolar planes through the light and the camera, columns: the angle psi at the
light, texels weighted by the spot's cone and texture), the look-up's mathematics in :mod:`.spot_lookups`.
The projective rectification, ``splits`` > 1 and adaptive overestimation need a directional light.
"""

import functools
import math

import numpy as np
import warp as wp

from ...runtime.device import MODULE_OPTIONS, default_device
from ...runtime.parallel import launch_rows
from ...runtime.stages import StageTimer
from ...scene.camera import CameraParams
from ...scene.lights import LightParams, light_params
from ...scene.medium import MediumParams
from ..rectify.caster_culling import cull_unseen_casters, end_faces_away
from ..rectify.local import (
    coloured_emission,
    emission_peaks,
    resample_spot_shadow_map,
    spot_rectification,
    spot_texel_weights,
)
from ..settings import EVALUATE_DEPTH_TOLERANCE
from ..sparse_evaluation import PixelSet, evaluate_sparse, set_pixel
from .debug import add_debug_images
from .epipole import march_epipole
from .epipole_regions import epipole_pixel_fraction, epipole_regions
from .evaluate import coords_of_every_pixel, pixel_coords
from .filtered_lookups import depth_bounds_of
from .prefix_sums import prefilter_moments, prefilter_weighted
from .rectify import map_depth
from .row_mips import level_window, pixel_mip_level, row_mip_chain, stacked_row_means
from .spot_lookups import SpotLookUp, spot_radiance, spot_radiance_rgb, spot_rays
from .textures import FilteredBasis, FilteredBasisArrays, FilteredMomentArrays


@functools.cache
def evaluate_spot_kernel(texels_type, coloured: bool) -> wp.Kernel:
    """The spot look-up kernel for a texture type (FilteredBasisArrays or FilteredMomentArrays) and a grey or
    ``coloured`` medium (a ``wp.static`` choice; compiled in a module of its own on first launch)."""
    Texels = texels_type  # noqa: N806 (a type)
    radiance = spot_radiance_rgb if coloured else spot_radiance

    def evaluate_spot(cam: CameraParams, coords: wp.array2d(dtype=wp.vec3), texels_r: Texels, texels_g: Texels,
                      texels_b: Texels, look: SpotLookUp, light: LightParams, med: MediumParams,
                      out: wp.array2d(dtype=wp.vec3), pixels: PixelSet, offset: int):
        # texels_g / texels_b: maps 1, 2 of a coloured spot texture, else map 0; light.radiance: the emission peak
        a, b = wp.tid()
        j, i, listed = set_pixel(pixels, cam.height, cam.width, a + offset, b)
        if not listed:
            return
        c = coords[j, i]
        rays = look.rays
        theta = rays.theta_hi - c[2] * rays.theta_len
        u_end = wp.min(c[0], 1.0)  # past the map's last column the spot's cone has ended
        psi_end = wp.min(rays.psi_lo + u_end * rays.psi_span, theta - 1.0e-6)
        result = wp.vec3(0.0, 0.0, 0.0)
        if psi_end > rays.psi_lo:
            cl = wp.vec3(u_end, c[1], c[2])
            lv = pixel_mip_level(look.mips, coords, j, i)
            level = int(lv[0])
            result = wp.static(radiance)(texels_r, texels_g, texels_b, look, level_window(look.mips, level), light,
                                         med, cl, theta, psi_end)
            if lv[1] > 0.0:  # between two levels: blend (row_mips)
                upper = wp.static(radiance)(texels_r, texels_g, texels_b, look, level_window(look.mips, level + 1),
                                            light, med, cl, theta, psi_end)
                result = result + lv[1] * (upper - result)
        out[j, i] = result

    return wp.kernel(evaluate_spot, module="unique", module_options=dict(MODULE_OPTIONS))


def every_spot_kernel() -> list[wp.Kernel]:
    """The spot look-up kernel of every texture type and medium (what the CUDA compile check builds)."""
    return [evaluate_spot_kernel(texels, coloured) for texels in (FilteredBasisArrays, FilteredMomentArrays)
            for coloured in (False, True)]


def render_spot(frame, settings, stage: StageTimer) -> tuple[wp.array, dict]:
    """The spot-light branch of :func:`~.method.render` (same arguments, results and stages). Raises ValueError for
    ``rectification: projective``, ``splits`` > 1 or ``overestimation: adaptive``, which need a directional light."""
    device = default_device(frame.device)
    scene, gbuffer, shadow_map = frame.scene, frame.gbuffer, frame.shadow_map
    p = settings.prefiltered
    if p.rectification == "projective":
        raise ValueError("render.scattering.prefiltered.rectification: 'projective' needs a directional light; a spot "
                         "light uses the non-linear rectification (auto or nonlinear)")
    if p.splits > 1:
        raise ValueError("render.scattering.prefiltered.splits: a spot light's look-ups need whole rows (splits 1)")
    cam, light = scene.camera, scene.light
    cols, rows = settings.shadow_map.size
    lparams = light_params(light, device)

    # ---- 1. rectify: angles at the light as columns, the spot's emission per texel ----
    with stage("rectify"):
        rect = spot_rectification(cam, light, rows=rows, cols=cols, guard_band=p.guard_band)
        rectified, emission = resample_spot_shadow_map(rect, shadow_map, light, lparams, device=device)
    lparams.radiance = wp.vec3(*emission_peaks(light).astype(np.float32))  # the filter is relative to the peak
    every_pixel = coords_of_every_pixel(settings, frame.aovs)
    with stage("pixel_coords"):
        coords = (pixel_coords(rect, cam, gbuffer.distance, device=device) if every_pixel else
                  wp.empty((cam.height, cam.width), dtype=wp.vec3, device=device))  # filled per look-up launch
    map_before_culling = map_depth(rectified).copy() if "rectified_map" in frame.aovs else None
    culled = None
    if settings.culls_casters:
        with stage("caster_culling"):
            culled = cull_unseen_casters(rectified, rect, coords, bias=p.caster_culling_bias, device=device,
                                         mip_levels=p.mip_levels,
                                         faces_away=end_faces_away(cam, gbuffer, lparams, device))

    # ---- 2. prefilter: one texture per channel of a coloured spot texture, texels weighted by the emission ----
    maps = 3 if coloured_emission(light) else 1
    depth_warp = p.depth_warp_for(settings.method, cols)
    with stage("prefilter"):
        sigma_ref = float(min(scene.medium.sigma_t_rgb))  # the slowest decay of every channel
        weights = spot_texel_weights(rect, sigma_ref, scene.medium)
        filtered = emission[..., :maps].transpose(2, 0, 1) * weights[None]  # (maps, rows, cols)
        textures = []
        for k in range(maps):
            if settings.method == "fourier":
                textures.append(prefilter_weighted(rectified, settings.fourier.coefficients,
                                                   bits=settings.fourier.storage_bits, texel_weights=filtered[k],
                                                   depth_warp=depth_warp, device=device))
            else:
                textures.append(prefilter_moments(rectified, settings.num_moments,
                                                  storage_bits=settings.moment_storage_bits,
                                                  texel_weights=filtered[k], depth_warp=depth_warp, device=device))
        bounds = depth_bounds_of(rectified, p.depth_bounds, device)
        chains = [row_mip_chain(t, None, bounds.bounds if k == 0 else wp.zeros((1, 1), dtype=wp.vec2, device=device),
                                p.mip_levels, device) for k, t in enumerate(textures)]
        textures, bounds.bounds = [ch.texture for ch in chains], chains[0].bounds
        mips = chains[0].params(rect.full_circle)

    # ---- 3. evaluate: each ray's own weight table against the maps' prefix sums (prefiltered_spot) ----
    with stage("evaluate"):
        overestimation = settings.moments.overestimation
        # the view rays' angle to a spot's light varies along them: one overestimation weight for all (settings)
        beta = 0.0 if settings.method == "fourier" else settings.moments.spot_beta(settings.num_moments)
        if beta < 0.0:
            raise ValueError("render.scattering.moments.overestimation: 'adaptive' needs a directional light (Peters "
                             "2017 Sec. 5.3.1 weighs the light and view directions); give a number for a spot light")
        sums = np.cumsum(np.concatenate([weights[None], filtered]), axis=2, dtype=np.float64)
        look = SpotLookUp()
        look.rays = spot_rays(rect, p, stacked_row_means(sums, mips.levels, axis=1), device)
        look.bounds, look.mips, look.beta, look.maps = bounds, mips, beta, maps
        out = wp.empty((cam.height, cam.width), dtype=wp.vec3, device=device)
        arrays = [t.arrays() for t in textures]
        arrays += [arrays[0]] * (3 - len(arrays))
        texels = FilteredBasisArrays if isinstance(textures[0], FilteredBasis) else FilteredMomentArrays
        kernel = evaluate_spot_kernel(texels, bool(scene.medium.coloured))
        inputs = [cam.params(), coords, *arrays, look, lparams, scene.medium.params(), out]

        def look_up(pixels: PixelSet, dim: tuple[int, int]) -> None:
            if not every_pixel:  # the coordinates of the same pixels first
                pixel_coords(rect, cam, gbuffer.distance, device, pixels=pixels, dim=dim, out=coords)
            launch_rows(kernel, dim, [*inputs, pixels], device=device)

        sparse = evaluate_sparse(look_up, gbuffer.distance, out, p.evaluate_stride, p.evaluate_tolerance,
                                 EVALUATE_DEPTH_TOLERANCE, levels=p.evaluate_levels_for(cam.height, spot=True),
                                 device=device)

    # ---- 4. epipole fallback: auto marches no disc under a spot (its light's 1/d^2 peak made the disc noisier) ----
    regions = (epipole_regions(cam, rect.light_direction, p.epipole_angle_deg, p.epipole_block)
               if p.epipole_fallback is True else [])
    _, epipole_marched = march_epipole(frame, settings, regions, out, None, stage, device)
    info = {
        "rectification": "nonlinear",
        "rectification_reason": "spot light: angles at the light as columns",
        "rectified_map": [cols, rows],
        "basis": settings.method,
        **({"coefficients": settings.fourier.coefficients} if settings.method == "fourier" else
           {"overestimation": overestimation if overestimation is not None else round(beta, 4)}),
        "bits_per_texel": settings.filtered_bits_per_texel,
        "segments": int(look.rays.segments),
        "depth_bounds": p.depth_bounds,
        "depth_warp": depth_warp,
        "mip_levels": mips.levels,
        "end_offset": float(look.rays.end_offset),
        "evaluate_stride": sparse.stride,
        "evaluate_levels": sparse.levels,
        "evaluated_fraction": round(sparse.evaluated_fraction, 4),
        "resample_filter": "supersample",  # a spot's texels: bilinear spot-map taps along psi (rectify_local)
        "caster_culling": culled is not None,
        **({} if culled is None else {"culled_texel_fraction": round(culled, 4)}),
        "filtered_map_bytes": sum(t.nbytes for t in textures),
        "filtered_maps": maps,  # one per colour channel of a coloured spot texture
        "epipole_blocks": [[*r.rect, r.name] for r in regions],
        "epipole_angle_deg": round(regions[0].inner_deg, 3) if regions else None,
        "epipole_raymarched_fraction": round(epipole_pixel_fraction(cam, regions), 4),
        "epipole_marched_share": round(epipole_marched, 4),
        "full_circle": rect.full_circle,
        # the angles at the light (from the baseline towards the camera) the columns cover, and the baseline's length
        "map_angles_deg": [round(math.degrees(rect.psi_lo), 3), round(math.degrees(rect.psi_lo + rect.r_max), 3)],
        "light_distance": round(rect.light_distance, 4),
    }
    add_debug_images(info, frame, coords, regions, rectified, map_before_culling, mips, sparse)
    return out, info


__all__ = ["evaluate_spot_kernel", "render_spot"]
