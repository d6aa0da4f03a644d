"""Prefiltered single scattering on a rectified shadow map: the ``fourier`` (Klehm 2014), ``moments4`` and
``moments6`` (Peters 2017 Sec. 5) render methods. They share the rectification, the transmittance-weighted
per-row prefix sums, the per-pixel look-up and the epipole fallback; only the per-texel visibility
representation differs: M Fourier coefficients (Klehm Eq. 8) or 4 / 6 moments of the signed rectified depth
with Algorithm 1 and adaptive overestimation at evaluation (Peters Sec. 5.3-5.4).

Stages (names as they appear in timings):

1. ``rectify``   — the rectification for this camera and light, chosen per frame (``rectification``):
   * ``projective`` (Klehm 2014 Sec. 4.2): one 4x4 matrix per light-frustum region, the scene is
     rasterized STRAIGHT into the rectified map with depth clamping (:mod:`.rectify_projective`);
   * ``nonlinear`` (Peters 2017 Sec. 5.1.1, App. A): bounds in spherical light coordinates and
     resampling of the light's shadow map into them (:mod:`.rectify_nonlinear`);
   * ``auto``: projective unless the light's epipole (or anti-epipole) lies in the image or within
     ``epipole_margin`` half image heights of its border — Klehm's criterion for (close to) degenerate
     cases, :func:`~.rectification.build_rectification`; the reason is logged on the ``warpscatter``
     logger and returned in the info dict;
   then ``caster_culling`` (by default for the moment methods; not in the papers): every texel whose
   blocker shadows none of the pixels' look-ups is emptied (depth 1), :mod:`.caster_culling`. No hard
   visibility changes (up to a depth tolerance against discretisation acne), but the depths of surfaces
   that only receive — a ground plane under the rays that end on it — leave the representation, where they
   sat just behind the rays' fragment depths: the worst case of moment bounds;
2. ``prefilter`` — Fourier basis of the rectified depth fused into per-row prefix sums, plain
   (Klehm Listing 1) or transmittance-weighted with the per-slice reference ray (Listing 2/3); the
   projective map's columns are uneven, so its weights are per texel (Eq. 12: exact column lengths, or
   the paper's constant growth factor d with ``projective_weights: cross_ratio``); rows may be split
   into ``splits`` regions filtered independently (Sec. 3.3). The texture is stored as configured:
   float32, the paper's RGBA8 (``fourier.storage_bits: 8``, uint8 codes), or the moment storage modes
   (``moments.storage_bits``: 16-bit codes of Theta* in uint16, six 10-bit codes packed in one uint64 per
   texel, or float32); with ``mip_levels`` > 1 the texture's row mip levels follow, stacked along its rows
   (Peters 2017 D.5, :mod:`.row_mips`); ``filtered_map_bytes`` in the info dict is the memory really allocated;
3. ``evaluate``  — per pixel: the G-buffer hit -> rectified (u, v, z_r) (one @wp.func dispatching on the
   rectification kind) -> the row mip level of the pixel's footprint (level 0 without mips) -> bilinear fetch of
   the filtered-basis vector (one look-up per split region in
   front of the hit plus the hit's own) -> dot with a(z_r) + 0.5, clamped -> times
   sigma_s f E (1 - e^{-sigma_t s}) / sigma_t (Klehm Listing 4); the cost per pixel is constant whatever the scene.
   By default the look-up runs on a grid of every second pixel and on the pixels between them that their grid
   cell cannot interpolate (``evaluate_stride``, :mod:`.sparse_evaluation`); the coordinates and the lit-end
   test are computed in the same launches where nothing else needs every pixel's.
   A ray ending in shadow (:func:`lit_ray_ends`) whose whole extent lies within its end surface's own zone
   (``end_offset``; looking almost straight into the light) has nothing to look up: its texels are those of the
   surface it ends on. Such pixels (a few dozen around the sun) are ray-marched as the disc marches (stage
   ``epipole``, ``epipole_steps`` strata, :func:`~.epipole_fallback.march_flagged_pixels`; stats ``end_zone_pixels``).
   Any other ray ending in shadow under a directional light ahead of the camera (more than
   :data:`~.settings.END_SAMPLES_MIN_DEG` from the light, its stretch carrying at least
   :data:`~.settings.END_STRETCH_MIN_WEIGHT` of its weight) takes the visibility of the stretch its look-up leaves out
   (its ``end_offset`` texels before the end point, a long stretch near the sun) from the shadow map, sampled along
   the ray (``end_samples``, :func:`~.marching.stretch_visibility`; the marcher's bias guard behind surfaces facing
   away from the light), each part weighted by its share of the ray's transmittance weight
   (:func:`with_left_out_stretch`);
4. ``epipole``   — when the light (or its flip) projects into the view, the non-linear rectification's
   slices all meet there and precision is low: light bleeds into a ring around the epipole (Klehm 2014
   Sec. 5, Fig. 8). The pixels whose view ray lies within ``epipole_angle_deg`` of the light direction (or its
   flip) — at least Klehm's block of ``epipole_block`` pixels — are ray-marched with shadow-map visibility
   instead, blended linearly in the angle with the prefiltered result over a band of ``EPIPOLE_BLEND`` times
   that radius (:mod:`.epipole_fallback`). An angle rather than a pixel count keeps the region the same at every
   resolution; the stats report the fraction of pixels marched (``epipole_raymarched_fraction``).

Directional and spot lights: a spot light (Klehm 2014 Sec. 3.2, local lights) has its own non-linear map with
angles at the light as columns and its cone and texture as texel weights (:mod:`.rectify_local`,
:mod:`.prefiltered_spot`); the projective rectification, ``splits`` > 1 and adaptive overestimation need a
directional light.

Settings: :class:`~warpscatter.scattering.settings.ScatteringSettings` — ``render.scattering.prefiltered`` for
what the three methods share, ``fourier`` and ``moments`` for the representation, ``prefiltered.epipole_steps`` /
``seed`` / ``jitter`` / ``shadow_map`` for the ray-marched epipole region (the keys, defaults and ranges are documented
there and in the README's config reference).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from ..parallel import launch_rows
from ..scene.camera import CameraParams, pixel_ray_direction
from ..scene.lights import DirectionalLight, LightParams, SpotLight, faces_away_from_light, light_params, light_sample
from ..scene.medium import MediumParams, coloured_scattering, phase_eval, transmittance_integral
from ..shadows import moments as mm
from ..shadows import translucency
from ..stages import StageTimer
from ..wpinit import default_device, module_options
from . import rectify_nonlinear
from .caster_culling import cull_unseen_casters, end_faces_away
from .epipole_fallback import (
    MarchedCones,
    epipole_pixel_fraction,
    epipole_regions,
    epipole_weights,
    march_epipole_regions,
    march_flagged_pixels,
    marched_cones,
    wholly_marched,
)
from .filtered_lookups import (
    RAY_END_IN_SHADOW,
    RAY_END_LIT,
    RAY_END_UNKNOWN,
    DepthBounds,
    depth_bounds_of,
    fourier_visibility,
    mix_row_answers,
    moments_visibility,
    row_bounds,
    rows_undecided,
)
from .filtered_textures import (
    FilteredBasis,
    FilteredBasisArrays,
    FilteredMomentArrays,
    FilteredMoments,
)
from .marching import Visibility, end_surface_at, point_visibility, stretch_visibility, visibility_params
from .prefix_sums import (
    prefilter_moments,
    prefilter_weighted,
)
from .ray_weights import ChannelRayWeights, RayWeights, inside_map_fraction, looked_up_share, ray_weights
from .rectification import RectificationParams, build_rectification, rectification_params, rectified_coords, wrap_rows
from .rectify_nonlinear import NonlinearRectification, reference_ray, resample_shadow_map
from .rectify_projective import (
    ProjectiveRectification,
    column_lengths,
    cross_ratio_factors,
    rasterize_rectified,
    reference_rays,
)
from .row_mips import RowMips, level_window, pixel_mip_level, pixel_mip_levels, row_mip_chain
from .settings import (
    END_SAMPLES_MIN_DEG,
    END_STRETCH_MIN_WEIGHT,
    EVALUATE_DEPTH_TOLERANCE,
    MAX_RESAMPLE_FILTER_PX,
    PrefilteredSettings,
    ScatteringSettings,
)
from .sparse_evaluation import (
    PIXELS_ALL,
    PIXELS_GRID,
    PixelSet,
    SparseEvaluation,
    evaluate_sparse,
    grid_size,
    pixel_set,
    set_pixel,
)

module_options()


# ---- the per-pixel look-up of either representation ------------------------------------------------


@wp.func
def representation_visibility(texels: FilteredBasisArrays, weights: RayWeights, u: float, v: float, z_r: float,
                              window: wp.vec3i, beta: wp.vec4, light_direction: wp.vec3,
                              view_direction: wp.vec3) -> float:
    """The look-up's reconstruction from a Fourier texture (Klehm 2014 Listing 4) in the row ``window``; ``beta`` and
    the directions unused."""
    return fourier_visibility(texels, weights, u, v, z_r, window)


@wp.func
def representation_visibility(texels: FilteredMomentArrays, weights: RayWeights, u: float, v: float,  # noqa: F811
                              z_r: float, window: wp.vec3i, beta: wp.vec4, light_direction: wp.vec3,
                              view_direction: wp.vec3) -> float:
    """The look-up's reconstruction from a moment map (Peters 2017 D.5) with the overestimation weight
    ``beta[0] + (beta[1] - beta[0]) clamp((omega_l . omega_p - beta[3]) / (1 - beta[3]), 0, 1)``
    (:meth:`~.settings.MomentsSettings.beta_range`, ``beta[3]``: ``overestimation_rise_cos``);
    ``beta[0]`` < 0: Peters' adaptive weight of the light and view directions (Sec. 5.3.1). Within the epipole
    taper (``beta[2]`` = 1 - cos of its angle, > 0) the weight falls to 0 looking straight into the light:
    times (1 + omega_l . omega_p) / beta[2]."""
    cos_l = wp.dot(light_direction, view_direction)
    b = beta[0]
    if b < 0.0:
        b = mm.adaptive_overestimation_weight(light_direction, view_direction)
    elif beta[1] != beta[0]:
        b += (beta[1] - beta[0]) * wp.clamp((cos_l - beta[3]) / (1.0 - beta[3]), 0.0, 1.0)
    if 1.0 + cos_l < beta[2]:
        b *= (1.0 + cos_l) / beta[2]
    return moments_visibility(texels, weights, u, v, z_r, window, b)


@wp.func
def map_visibility(texels: Any, weights: RayWeights, bounds: DepthBounds, c: wp.vec3, window: wp.vec3i, beta: wp.vec4,
                   light_direction: wp.vec3, view_direction: wp.vec3, ray_end: int) -> float:
    """Visible fraction of the view ray ending at rectified c = (u, v, z_r) from a Fourier texture or a moment map
    (:func:`representation_visibility`) read in the row ``window`` (a mip level, :func:`~.row_mips.level_window`),
    its texels weighted as ``weights`` says (:mod:`.ray_weights`), those beyond the map lit; a ray wholly lit or
    wholly shadowed by the ``bounds`` is answered without the reconstruction (``ray_end``: what is known of the
    ray's end point, :func:`~.filtered_lookups.row_bounds`)."""
    inside = inside_map_fraction(weights, c[0], c[2])
    u = c[0]
    if inside < 1.0:
        u = 1.0 + weights.end_offset / float(weights.cols)  # the look-up through the whole map
    # each bilinear row the bounds decide keeps their exact answer, an undecided one takes the reconstruction, mixed
    # by the rows' weights (reconstructing both whenever they disagreed lost the dark room's exact rows)
    b = row_bounds(bounds, u - weights.end_offset / float(bounds.bounds.shape[1]), c[1], c[2], window, ray_end)
    r = float(0.0)
    if rows_undecided(b):
        r = representation_visibility(texels, weights, u, c[1], c[2], window, beta, light_direction, view_direction)
    f = mix_row_answers(b, r, b[2])
    if inside < 1.0:
        return inside * f + (1.0 - inside)
    return f


@wp.func
def mipped_visibility(texels: Any, weights: RayWeights, bounds: DepthBounds, mips: RowMips, level: wp.vec2,
                      c: wp.vec3, beta: wp.vec4, light_direction: wp.vec3, view_direction: wp.vec3,
                      ray_end: int) -> float:
    """:func:`map_visibility` at a pixel's mip ``level`` (:func:`~.row_mips.pixel_mip_level`: level, share of the
    next): the two levels' visibilities blended (trilinear filtering, Peters 2017 D.5; :mod:`.row_mips`)."""
    lv = int(level[0])
    f = map_visibility(texels, weights, bounds, c, level_window(mips, lv), beta, light_direction, view_direction,
                       ray_end)
    if level[1] > 0.0:
        f1 = map_visibility(texels, weights, bounds, c, level_window(mips, lv + 1), beta, light_direction,
                            view_direction, ray_end)
        f = f + level[1] * (f1 - f)
    return f


# ---- kernels ---------------------------------------------------------------------------------------


@wp.kernel
def pixel_coords_kernel(
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    rect: RectificationParams,
    out: wp.array2d(dtype=wp.vec3),
    pixels: PixelSet,
    offset: int,
):
    # the rectified (u, v, z_r) of the view-ray end (its G-buffer hit) of every pixel of the set: what caster
    # culling and the evaluation look up
    a, b = wp.tid()
    j, i, listed = set_pixel(pixels, cam.height, cam.width, a + offset, b)
    if not listed:
        return
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    out[j, i] = rectified_coords(rect, cam.position + d * distance[j, i])


@wp.func
def left_out_start(weights: RayWeights, u: float, s: float) -> float:
    """Distance from the camera at which the look-up of a view ray ending at column coordinate u, distance s, stops:
    ``end_offset`` texels before its end (a non-linear map's columns are equal steps along a ray)."""
    return s * wp.max(1.0 - weights.end_offset / (u * float(weights.cols)), 0.0)


@wp.func
def with_left_out_stretch(f: float, share: float, v_end: float) -> float:
    """Visible fraction of a view ray whose look-up gave f over ``share`` of its own transmittance weight
    (:func:`~.ray_weights.looked_up_share`) and whose left-out end stretch (:func:`left_out_start`) has visibility
    v_end."""
    return f * share + (1.0 - share) * v_end


#: :data:`~.settings.END_STRETCH_MIN_WEIGHT` for the kernel.
STRETCH_MIN_WEIGHT = wp.constant(END_STRETCH_MIN_WEIGHT)


@wp.kernel
def evaluate_prefiltered_kernel(
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    coords: wp.array2d(dtype=wp.vec3),  # pixel_coords_kernel's output, read if coords_known
    coords_known: int,  # 0: each pixel's rectified coordinates are computed here (rect)
    rect: RectificationParams,
    texels: Any,  # FilteredBasisArrays or FilteredMomentArrays: one compiled kernel per representation
    weights: RayWeights,  # how a ray weights its texels (reference ray or per-ray segments)
    channel_weights: ChannelRayWeights,  # coloured media: each channel's own (grey: unused)
    bounds: DepthBounds,  # per-row prefix depth bounds: wholly lit / shadowed rays skip the reconstruction
    mips: RowMips,  # the texture's row mip levels and whether its rows wrap around (wrap_rows)
    beta: wp.vec4,  # moment overestimation weight towards / along the light (beta_range), or < 0: adaptive;
    # 1 - cos of the epipole taper's angle (MomentsSettings.epipole_taper), and the cosine beta rises from
    # (MomentsSettings.overestimation_rise_cos)
    light: LightParams,
    med: MediumParams,
    lit_end_test: int,  # 1: each ray's end is tested lit or in shadow (ray_ends_lit; a directional light ahead of
    # the camera)
    faces_away: wp.array2d(dtype=wp.int32),  # caster_culling.end_faces_away, read if faces_away_known
    faces_away_known: int,
    normal: wp.array2d(dtype=wp.vec3),  # the G-buffer's camera-facing normals (the end surface's bias guard)
    end_vis: Visibility,  # the light's shadow map: the left-out end stretches' visibility
    end_samples: int,  # most samples of a left-out end stretch (0: it takes the look-up's visibility)
    end_cos_max: float,  # cos END_SAMPLES_MIN_DEG: rays looking closer into the light keep the look-up's
    lit_end_shift: float,  # u by which the look-up of a ray ending lit ends later than weights.end_offset says
    # (end_offsets_for: the difference of the two offsets, in u)
    out: wp.array2d(dtype=wp.vec3),
    end_zone: wp.array2d(dtype=wp.int32),  # out: 1 where the look-up is left to the marcher (module doc), else 0
    end_zone_any: wp.array(dtype=wp.int32),  # out: [0] set to 1 when any pixel is (a plain store: no race to lose)
    marched: MarchedCones,  # the epipole discs ray-marched afterwards: no look-up there (epipole_fallback)
    pixels: PixelSet,  # the pixels to evaluate (sparse_evaluation)
    offset: int,
):
    # Klehm 2014 Listing 4 / Peters 2017 D.5: one filtered look-up and one reconstruction per pixel
    a, b = wp.tid()
    j, i, listed = set_pixel(pixels, cam.height, cam.width, a + offset, b)
    if not listed:
        return
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    if wholly_marched(marched, d, i, j):  # the disc's march replaces whatever is here
        out[j, i] = wp.vec3(0.0, 0.0, 0.0)
        end_zone[j, i] = 0
        return
    s = distance[j, i]
    phase = phase_eval(med.phase_id, med.g, wp.dot(light.direction, -d))
    lv = pixel_mip_level(mips, coords, j, i)
    x_end = cam.position + d * s  # the ray's end point
    c = wp.vec3()
    if coords_known != 0:
        c = coords[j, i]
    else:
        c = rectified_coords(rect, x_end)
    in_end_zone = int(0)
    ray_end = int(RAY_END_UNKNOWN)  # what the depth bounds may assume of the ray's end (row_bounds)
    if lit_end_test != 0:
        if ray_ends_lit(x_end, normal[j, i], faces_away, faces_away_known, j, i, light, end_vis):
            c = wp.vec3(c[0] + lit_end_shift, c[1], c[2])
            ray_end = RAY_END_LIT
        else:
            ray_end = RAY_END_IN_SHADOW
        if ray_end == RAY_END_IN_SHADOW and c[0] * float(weights.cols) <= weights.end_offset:
            # a ray ending in shadow whose whole extent lies within its end surface's own zone (looking almost straight
            # into the light): the look-up reads nothing; the marcher takes it (march_flagged_pixels)
            in_end_zone = 1
            end_zone_any[0] = 1
    ends_in_shadow = ray_end == RAY_END_IN_SHADOW
    end_zone[j, i] = in_end_zone
    if in_end_zone != 0:
        out[j, i] = wp.vec3(0.0, 0.0, 0.0)
    else:
        # a ray ending in shadow: the end_offset texels its look-up leaves out (the end surface is its own blocker
        # there) take the shadow map's visibility, sampled along the ray (module doc)
        march_end = (end_samples > 0 and ends_in_shadow and c[0] <= 1.0 and weights.end_offset > 0.0
                     and -wp.dot(light.direction, d) < end_cos_max)
        v_end = float(0.0)
        share = float(1.0)
        if march_end:  # ... when the stretch carries enough of the ray's weight to matter
            share = looked_up_share(weights, c[0], c[2])
            march_end = share < 1.0 - STRETCH_MIN_WEIGHT
        if march_end:
            end = end_surface_at(end_vis, light, x_end, normal[j, i])
            v_end = stretch_visibility(end_vis, end, cam.position, d, left_out_start(weights, c[0], s), s,
                                       med.sigma_t, end_samples)
        if med.coloured == 0:
            f = mipped_visibility(texels, weights, bounds, mips, lv, c, beta, light.direction, d, ray_end)
            if march_end:
                f = with_left_out_stretch(f, share, v_end)
            out[j, i] = light.radiance * (med.sigma_s * phase * f * transmittance_integral(med.sigma_t, 0.0, s))
        else:  # one look-up per channel, each with the channel's own ray weights (module doc)
            f_rgb = wp.vec3(
                mipped_visibility(texels, channel_weights.r, bounds, mips, lv, c, beta, light.direction, d,
                                  ray_end),
                mipped_visibility(texels, channel_weights.g, bounds, mips, lv, c, beta, light.direction, d,
                                  ray_end),
                mipped_visibility(texels, channel_weights.b, bounds, mips, lv, c, beta, light.direction, d,
                                  ray_end))
            if march_end:
                f_rgb = wp.vec3(
                    with_left_out_stretch(f_rgb[0], looked_up_share(channel_weights.r, c[0], c[2]), v_end),
                    with_left_out_stretch(f_rgb[1], looked_up_share(channel_weights.g, c[0], c[2]), v_end),
                    with_left_out_stretch(f_rgb[2], looked_up_share(channel_weights.b, c[0], c[2]), v_end))
            out[j, i] = wp.cw_mul(coloured_scattering(med, light.radiance, 0.0, s), f_rgb) * phase


@wp.func
def ray_ends_lit(x: wp.vec3, n: wp.vec3, faces_away: wp.array2d(dtype=wp.int32), faces_away_known: int, j: int,
                 i: int, light: LightParams, vis: Visibility) -> int:
    """1 where the view ray of pixel (i, j) ending at x (G-buffer normal n) ends lit: on no surface, or on one facing
    the light (caster_culling.end_faces_away: read from ``faces_away`` when ``faces_away_known``, else tested here
    as end_faces_away_kernel does) whose point, moved one shadow-map texel off it, the shadow map sees (hard, with the
    marcher's bias)."""
    away = int(0)
    if faces_away_known != 0:
        away = faces_away[j, i]
    else:
        away = int(faces_away_from_light(light, x, n))
    lit = int(0)
    if away == 0:
        _e, omega, dist = light_sample(light, x)
        lit = int(point_visibility(vis, x + n * vis.sm.texel_world, omega, dist) > 0.5)
    return lit


@wp.kernel
def lit_ray_ends_kernel(cam: CameraParams, distance: wp.array2d(dtype=wp.float32), normal: wp.array2d(dtype=wp.vec3),
                        faces_away: wp.array2d(dtype=wp.int32), faces_away_known: int, light: LightParams,
                        vis: Visibility, out: wp.array2d(dtype=wp.int32), offset: int):
    # ray_ends_lit of every pixel
    j, i = wp.tid()
    j += offset
    x = cam.position + pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5) * distance[j, i]
    out[j, i] = ray_ends_lit(x, normal[j, i], faces_away, faces_away_known, j, i, light, vis)


@wp.kernel
def pixel_phase_kernel(cam: CameraParams, light: LightParams, med: MediumParams, out: wp.array2d(dtype=wp.float32),
                       pixels: PixelSet, offset: int):
    # the phase function of each pixel's view ray under a directional light (one angle along the whole ray): the
    # factor of the look-up's radiance that evaluate_sparse interpolates apart (kept above 0 for its division)
    a, b = wp.tid()
    j, i, listed = set_pixel(pixels, cam.height, cam.width, a + offset, b)
    if not listed:
        return
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    out[j, i] = wp.max(phase_eval(med.phase_id, med.g, wp.dot(light.direction, -d)), 1.0e-30)


# one kernel per representation: the look-ups of the other would slow a kernel's own (measured 3-5 %)
wp.overload(evaluate_prefiltered_kernel, {"texels": FilteredBasisArrays})
wp.overload(evaluate_prefiltered_kernel, {"texels": FilteredMomentArrays})


def pixel_coords(rect, camera, distance: wp.array, device=None, pixels: PixelSet | None = None,
                 dim: tuple[int, int] | None = None, out: wp.array | None = None) -> wp.array:
    """(H, W) vec3 Warp array: the rectified (u, v, z_r) of every pixel's view-ray end (distance: G-buffer).
    ``pixels`` and ``dim``: only the pixels of that :class:`~.sparse_evaluation.PixelSet` launch, written into
    ``out`` (default: every pixel, into a new array)."""
    device = default_device(device)
    if out is None:
        out = wp.empty((camera.height, camera.width), dtype=wp.vec3, device=device)
    if pixels is None:
        pixels, dim = pixel_set(PIXELS_ALL, device=device), (camera.height, camera.width)
    launch_rows(pixel_coords_kernel, dim, [camera.params(), distance, rectification_params(rect), out, pixels],
                device=device)
    return out


def coords_of_every_pixel(settings: ScatteringSettings, aovs) -> bool:
    """Whether a prefiltered render needs the rectified coordinates of every pixel before its look-up: caster culling
    reads them all, the row mip levels read each pixel's neighbours, the ``rectified`` and ``mip_level`` debug outputs
    show them. Otherwise the look-up kernel computes them at the pixels it evaluates (sparse_evaluation)."""
    return (settings.culls_casters or settings.prefiltered.mip_levels > 1
            or bool({"rectified", "mip_level"} & set(aovs)))


def lit_ray_ends(scene, gbuffer, shadow_map, bias_texels: float, faces_away: wp.array | None = None,
                 device=None) -> wp.array:
    """(H, W) int32 Warp array: 1 where the pixel's view ray ends lit (on no surface, or on a surface facing the light
    that the shadow map sees, ``bias_texels`` of depth bias), 0 where it ends in shadow. A look-up of a ray ending lit
    may end nearer its end (``prefiltered.end_offset``, :data:`~.settings.END_OFFSET_LIT`): a lit surface shadows its
    own ray only through the texel's filtering. ``faces_away``: :func:`~.caster_culling.end_faces_away` of the frame
    if already made (else the kernel tests it). The look-up kernel makes the same test (:func:`ray_ends_lit`) at the
    pixels it evaluates; this is the every-pixel form."""
    device = default_device(device)
    cam = scene.camera
    known = faces_away is not None
    if not known:
        faces_away = wp.zeros((1, 1), dtype=wp.int32, device=device)
    out = wp.empty((cam.height, cam.width), dtype=wp.int32, device=device)
    launch_rows(lit_ray_ends_kernel, (cam.height, cam.width),
                [cam.params(), gbuffer.distance, gbuffer.normal, faces_away, int(known),
                 light_params(scene.light, device),
                 visibility_params(scene, "shadow_map", shadow_map=shadow_map, shadow_bias_texels=bias_texels,
                                   device=device), out], device=device)
    return out


# ---- host side ------------------------------------------------------------------------------------


def row_weights(rect, settings: PrefilteredSettings, sigma_t: float, camera=None,
                segments: int = 1) -> tuple[np.ndarray, np.ndarray | None, dict]:
    """Per-row optical steps and per-column lengths of the prefilter weights (Klehm 2014 Sec. 3.2, Eq. 11-12).

    Non-linear rectification: uniform columns, tau_j = sigma_t Delta_ref of the row's reference ray. Projective:
    column lengths l_i = dX_i / dX_0 (exact, or Eq. 12's Delta d^i per region) and tau_j = sigma_t times the
    reference ray's world length of column 0 (dX_0 sqrt(1 + s^2 + zeta_ref^2)). ``camera`` is needed by the
    ``"pixels"`` reference ray; ``segments``, the per-ray segments of the look-ups, picks the auto reference ray
    (:meth:`~.settings.PrefilteredSettings.reference_for`).

    Returns:
        (optical_step (rows,) float32, column_length (cols,) float64 or None, info dict).
    """
    transmittance = settings.weighting == "transmittance"
    reference = settings.reference_for(segments)
    if isinstance(rect, NonlinearRectification):
        tau = reference_ray(rect, reference, camera).optical_steps(sigma_t) if transmittance else None
        return tau, None, {"reference_ray": reference}
    lengths = column_lengths(rect, "exact" if settings.projective_weights == "exact" else "cross_ratio")
    info = {"reference_ray": reference, "projective_weights": settings.projective_weights}
    if settings.projective_weights == "cross_ratio":
        info["cross_ratio_d"] = [round(float(d), 6) for d in cross_ratio_factors(rect)[0]]
    tau = np.zeros(rect.rows, np.float32)
    if transmittance:
        scale = reference_rays(rect, reference, camera).length_scale
        tau = (sigma_t * lengths[0] * scale).astype(np.float32)
    return tau, lengths / lengths[0], info


def weights_extinction(medium, segments: int) -> float:
    """The extinction of the prefix sums' transmittance weights (1/unit): a grey medium's own. A coloured medium's
    least channel extinction with per-ray segments (each channel then weights its rays with its own extinction, and
    every channel decays at least as fast as the reference: convex taps, :mod:`.ray_weights`), else the channels'
    mean (one weighting for all channels: the approximation of the projective map and of ``segments: 1``)."""
    if medium.coloured and segments > 1:
        return float(min(medium.sigma_t_rgb))
    return medium.extinction


def resample_filtered(scene, rect: NonlinearRectification, shadow_map, settings: PrefilteredSettings,
                      stage: StageTimer, device) -> tuple:
    """Filtering during resampling (Peters 2017 Sec. 5.2): stage ``resample_msm`` generates the light view's
    128-bit 4-moment map (2x2 supersampled, :func:`~warpscatter.shadows.msm.generate_moment_shadow_map`) and
    Gaussian-filters it (``resample_filter_px``, default the radial rectified texel footprint); stage ``rectify``
    resamples it with Algorithm 2 (:func:`~.rectify_nonlinear.resample_moment_shadow_map`).

    Returns:
        (:class:`~.rectify_nonlinear.SparseRectifiedDepth`, the Gaussian width used in shadow-map texels).
    """
    from ..shadows import msm as msm_maps

    filter_px = settings.resample_filter_px
    if filter_px is None:
        filter_px = int(np.clip(round(rectify_nonlinear.resample_footprint_texels(rect, shadow_map.texel_world)), 1,
                                MAX_RESAMPLE_FILTER_PX))
    with stage("resample_msm"):
        moments = msm_maps.filter_moment_shadow_map(
            msm_maps.generate_moment_shadow_map(scene, shadow_map, supersampling=2, bits=128, device=device),
            filter_px, device=device)
    with stage("rectify"):
        depth = shadow_map.depth.numpy() if isinstance(shadow_map.depth, wp.array) else np.asarray(shadow_map.depth)
        finite = depth[np.isfinite(depth)]
        farthest = float(finite.max()) if finite.size else None  # the map's farthest caster (linear light depth)
        return (rectify_nonlinear.resample_moment_shadow_map(rect, moments, farthest_caster=farthest, device=device),
                int(filter_px))


def render(frame, settings: ScatteringSettings, stage: StageTimer | None = None) -> tuple[wp.array, dict]:
    """Prefiltered single scattering: the ``fourier``, ``moments4`` and ``moments6`` methods (see the module doc;
    the registry's call shape, :mod:`warpscatter.methods`).

    Args:
        frame: :class:`~warpscatter.pipeline.frame.Frame` (directional or spot light): the rasterized G-buffer and
            the light's shadow map (resampled by the non-linear rectification and ray-marched in the
            epipole regions).
        settings: :class:`~warpscatter.scattering.settings.ScatteringSettings`; ``method`` selects the basis,
            ``shadow_map.resolution`` is also the rectified map's size (columns: texels along each view ray, rows:
            epipolar slices).
        stage: the :class:`~warpscatter.stages.StageTimer` (stages ``rectify``, ``resample_msm``, ``pixel_coords``,
            ``caster_culling``, ``prefilter``, ``evaluate``, ``epipole``).

    Debug outputs (``frame.aovs``, in ``info["debug_images"]``): ``rectified`` the (H, W, 3) look-up coordinates
    (u, v, z_r) per pixel, ``epipole_mask`` the (H, W) weight of the ray-marched epipole region, ``rectified_map``
    the (rows, cols, 2) rectified depth the prefilter read and 1 where caster culling emptied the texel.

    Returns:
        (L_scat, info): (H, W) vec3 wp.array and a dict describing the rectification (kind and the reason it
        was chosen), the filtered textures and the epipole regions.

    Raises:
        ValueError: for a light that is neither directional nor spot.
    """
    stage = stage or StageTimer()
    device = default_device(frame.device)
    scene, gbuffer, shadow_map = frame.scene, frame.gbuffer, frame.shadow_map
    p = settings.prefiltered
    if isinstance(scene.light, SpotLight):
        from .prefiltered_spot import render_spot

        return render_spot(frame, settings, stage)
    if not isinstance(scene.light, DirectionalLight):
        raise ValueError(f"the {settings.method} method needs a directional or spot light (render.scattering.method)")
    cam = scene.camera
    lparams = light_params(scene.light, device)
    cols, rows = settings.shadow_map.size
    with stage("rectify"):
        rect, choice = build_rectification(scene, p, rows, cols)
        filtered_resampling = isinstance(rect, NonlinearRectification) and p.resample_filter == "moments"
        if isinstance(rect, ProjectiveRectification):
            casters = scene.casters()
            rectified = rasterize_rectified(rect, casters.vertices, casters.triangles,
                                            opacity=translucency.triangle_opacity(casters), device=device)
        elif not filtered_resampling:
            samples = 0
            if isinstance(rect, NonlinearRectification) and p.resample_filter == "supersample":
                samples = rectify_nonlinear.radial_samples_for(rect, shadow_map.texel_world)
            rectified = resample_shadow_map(
                rect, shadow_map.depth, shadow_map.view_projection, depth="linear", world_to_view=shadow_map.view,
                radial_samples=samples, device=device,
                translucency=(shadow_map.opaque_depth, shadow_map.transmittance) if shadow_map.translucent else None)
    resample_info = {"resample_filter": p.resample_filter if isinstance(rect, NonlinearRectification) else "none"}
    if isinstance(rect, NonlinearRectification) and p.resample_filter == "supersample":
        resample_info["resample_samples"] = samples
    if filtered_resampling:
        rectified, resample_info["resample_filter_px"] = resample_filtered(scene, rect, shadow_map, p, stage, device)
    every_pixel = coords_of_every_pixel(settings, frame.aovs)
    with stage("pixel_coords"):
        coords = (pixel_coords(rect, cam, gbuffer.distance, device=device) if every_pixel else
                  wp.empty((1, 1), dtype=wp.vec3, device=device))
    culled, faces_away = None, None
    map_before_culling = map_depth(rectified).copy() if "rectified_map" in frame.aovs else None
    if settings.culls_casters:
        with stage("caster_culling"):
            faces_away = end_faces_away(cam, gbuffer, lparams, device)  # the lit-end test below reads it too
            culled = cull_unseen_casters(rectified, rect, coords, bias=p.caster_culling_bias, device=device,
                                         mip_levels=p.mip_levels, faces_away=faces_away)
    # the light travels the way the camera looks (the sun behind it): the moment methods' segments are adaptive
    light_behind = bool(np.dot(scene.light.direction, cam.forward) > 0.0)
    segments = p.segments_for(isinstance(rect, NonlinearRectification), scene.medium.coloured, settings.method,
                              light_behind)
    segment_depth = (p.segment_depth_for(settings.method, light_behind, scene.medium.coloured) if segments > 1
                     else 0.0)
    depth_warp = p.depth_warp_for(settings.method, cols)
    with stage("prefilter"):
        sigma_ref = weights_extinction(scene.medium, segments)
        tau, lengths, weight_info = row_weights(rect, p, sigma_ref, cam, segments)
        if settings.method == "fourier":
            fb: FilteredBasis | FilteredMoments = prefilter_weighted(
                rectified, settings.fourier.coefficients, tau, lengths, splits=p.splits,
                bits=settings.fourier.storage_bits, depth_warp=depth_warp, device=device)
        else:
            fb = prefilter_moments(rectified, settings.num_moments, tau, lengths,
                                   storage_bits=settings.moment_storage_bits, depth_warp=depth_warp, device=device)
        bounds = depth_bounds_of(rectified, p.depth_bounds, device)
        chain = row_mip_chain(fb, tau, bounds.bounds, p.mip_levels, device)
        fb, bounds.bounds = chain.texture, chain.bounds
    regions = (epipole_regions(cam, scene.light.direction, p.epipole_angle_deg, p.epipole_block)
               if settings.marches_epipole else [])
    with stage("evaluate"):
        overestimation = settings.moments.overestimation
        beta = wp.vec4(*settings.moments.beta_range(), settings.moments.epipole_taper(),
                       settings.moments.overestimation_rise_cos)
        # end_offset counts texels of a map reaching the view (a fixed world distance along the rays: the surface a
        # ray ends on is its own blocker over a stretch set by the depth precision, not by the column width)
        # (rays ending in shadow, rays ending lit): the look-up takes the first, a ray ending lit (ray_ends_lit) moves
        # its end by the difference
        end_offsets = p.end_offsets_for(light_behind)
        column_scale = rect.column_scale if isinstance(rect, NonlinearRectification) else 1.0
        end_offset = end_offsets[0] * column_scale
        lit_end_shift = (end_offsets[0] - end_offsets[1]) * column_scale / cols
        # the shadow map's visibility: the lit-end test, and the stretch a look-up leaves out before a ray ending in
        # shadow (sampled on non-linear maps, whose columns are equal steps along a ray: left_out_start)
        end_vis = visibility_params(scene, "shadow_map", shadow_map=shadow_map,
                                    shadow_bias_texels=settings.shadow_map.bias, device=device)
        # the lit-end test, for the shift and for the rays looking into the light that end in shadow (the kernel)
        lit_end_test = not light_behind
        nonlinear = rect if isinstance(rect, NonlinearRectification) else None
        end_samples = p.end_samples if lit_end_test and nonlinear is not None else 0
        weights = ray_weights(segments, chain.optical_step, nonlinear, sigma_ref, end_offset, device=device,
                              cols=cols, segment_depth=segment_depth)
        channels = ChannelRayWeights()
        channels.r = channels.g = channels.b = weights
        if scene.medium.coloured and segments > 1:
            channels.r, channels.g, channels.b = (ray_weights(segments, chain.optical_step, nonlinear, sigma,
                                                              end_offset, device=device, cols=cols,
                                                              segment_depth=segment_depth)
                                                  for sigma in scene.medium.sigma_t_rgb)
        out = wp.empty((cam.height, cam.width), dtype=wp.vec3, device=device)
        end_zone = wp.zeros((cam.height, cam.width), dtype=wp.int32, device=device)
        end_zone_any = wp.zeros(1, dtype=wp.int32, device=device)
        # without every pixel's coordinates the kernel computes them at the pixels it evaluates, as it does the lit-end
        # test (one pass: as two kernels before it, 24 of the 130 ms of the window room's 1080p look-up)
        inputs = [cam.params(), gbuffer.distance, coords, int(every_pixel), rectification_params(rect), fb.arrays(),
                  weights, channels, bounds, chain.params(wrap_rows(rect)), beta, lparams, scene.medium.params(),
                  int(lit_end_test), faces_away if faces_away is not None else wp.zeros((1, 1), dtype=wp.int32,
                                                                                       device=device),
                  int(faces_away is not None), gbuffer.normal, end_vis, end_samples,
                  float(np.cos(np.radians(END_SAMPLES_MIN_DEG))), lit_end_shift, out, end_zone, end_zone_any,
                  marched_cones(regions)]

        def look_up(pixels: PixelSet, dim: tuple[int, int]) -> None:
            launch_rows(evaluate_prefiltered_kernel, dim, [*inputs, pixels], device=device)

        levels = p.evaluate_levels_for(cam.height)
        phase = None
        if p.evaluate_stride > 1 and levels > 1:
            # A pixel's look-up is radiance x its view ray's phase function (one angle along the whole ray under a
            # directional light), so the coarser levels interpolate the radiance divided by it (sparse_evaluation,
            # ``scale``), read at the 2-pixel grid's nodes only: the sun's forward peak is not flattened over a coarse
            # cell. 1080p, two levels, without -> with: fourier / moments6 / moments4 colonnade 2.5553 -> 2.5546 % /
            # 4.7559 -> 4.7554 % / 6.3523 -> 6.3515 %, canopy 0.6206 -> 0.6201 % / 0.6074 -> 0.6069 % / 0.6391 ->
            # 0.6386 %, window room 1.4944 -> 1.4983 % / 4.8340 -> 4.8324 % / 7.4062 -> 7.4058 %; the look-up at 0.27
            # -> 0.23, 0.20 -> 0.17, 0.165 -> 0.163 of the pixels; the phase costs about 3 ms. Divided out at the
            # last level too: the same errors to 0.00001 %, 0.005-0.01 fewer look-ups, the phase at every pixel 10 ms.
            phase = wp.empty((cam.height, cam.width), dtype=wp.float32, device=device)
            grid = (grid_size(cam.height, p.evaluate_stride), grid_size(cam.width, p.evaluate_stride))
            launch_rows(pixel_phase_kernel, grid, [cam.params(), lparams, scene.medium.params(), phase,
                                                   pixel_set(PIXELS_GRID, p.evaluate_stride, device=device)],
                        device=device)
        sparse = evaluate_sparse(look_up, gbuffer.distance, out, p.evaluate_stride, p.evaluate_tolerance,
                                 EVALUATE_DEPTH_TOLERANCE, end_zone=end_zone,
                                 levels=levels, scale=phase, device=device)
    end_zone_pixels = 0
    if end_zone_any.numpy()[0]:  # rays looking into the light that lie wholly within their end zone (rare)
        with stage("epipole"):
            end_zone_pixels = march_flagged_pixels(scene, gbuffer, shadow_map, end_zone, out, steps=p.epipole_steps,
                                                   seed=settings.seed, shadow_bias_texels=settings.shadow_map.bias,
                                                   jitter=settings.march_jitter, device=device)
    epipole_marched = 1.0
    if regions:
        with stage("epipole"):
            epipole_marched = march_epipole_regions(
                scene, gbuffer, shadow_map, regions, out, steps=p.epipole_steps, seed=settings.seed,
                shadow_bias_texels=settings.shadow_map.bias, jitter=settings.march_jitter, stride=p.epipole_stride,
                tolerance=p.evaluate_tolerance, device=device)
    info = {
        "rectification": choice.kind,
        "rectification_reason": choice.reason,
        "epipole_distance": round(choice.epipole_distance, 4) if np.isfinite(choice.epipole_distance) else None,
        "rectified_map": [cols, rows],
        "basis": settings.method,
        **({"coefficients": settings.fourier.coefficients, "splits": fb.splits} if settings.method == "fourier" else
           {"overestimation": overestimation if overestimation is not None else
            [round(b, 4) for b in settings.moments.beta_range()],
            "overestimation_rise_cos": settings.moments.overestimation_rise_cos,
            "epipole_taper_deg": settings.moments.epipole_taper_deg}),
        "bits_per_texel": settings.filtered_bits_per_texel,
        "segments": segments,
        "segment_depth": segment_depth,
        "depth_bounds": p.depth_bounds,
        "depth_warp": depth_warp,
        "mip_levels": chain.levels,
        "end_zone_pixels": end_zone_pixels,
        "end_offset": end_offsets[0],
        "end_offset_lit": end_offsets[1],
        "end_samples": end_samples,
        "evaluate_stride": sparse.stride,
        "evaluate_levels": sparse.levels,
        "evaluated_fraction": round(sparse.evaluated_fraction, 4),
        **resample_info,
        "caster_culling": culled is not None,
        **({} if culled is None else {"culled_texel_fraction": round(culled, 4)}),
        "filtered_map_bytes": fb.nbytes,  # allocated: the texture (and a split filter's weight sums)
        "epipole_blocks": [[*r.rect, r.name] for r in regions],
        "epipole_angle_deg": round(regions[0].inner_deg, 3) if regions else None,
        "epipole_raymarched_fraction": round(epipole_pixel_fraction(cam, regions), 4),
        "epipole_marched_share": round(epipole_marched, 4),
    }
    info.update(weight_info)
    if isinstance(rect, ProjectiveRectification):
        info.update({"regions": rect.regions, "near_far": [round(rect.near, 6), round(rect.far, 6)]})
    else:
        info["full_circle"] = rect.full_circle
        info["map_radius"] = round(rect.r_max, 4)  # world units from the camera's light axis covered by the columns
    add_debug_images(info, frame, coords, regions, rectified, map_before_culling, chain.params(wrap_rows(rect)),
                     sparse)
    return out, info


def add_debug_images(info: dict, frame, coords: wp.array, regions, rectified, map_before_culling,
                     mips: RowMips | None = None, sparse: SparseEvaluation | None = None) -> None:
    """The debug outputs a frame asked for, into ``info["debug_images"]``: ``rectified`` the (H, W, 3) look-up
    coordinates, ``epipole_mask`` the ray-marched epipole regions' weight, ``rectified_map`` the (rows, cols, 2) map
    the prefilter read and 1 where caster culling emptied a texel (``map_before_culling``: its depths before),
    ``mip_level`` the row mip level of each pixel's look-up (``mips``; None: level 0 everywhere),
    ``evaluated_pixels`` 1 where the look-up ran and 0 where the pixel was interpolated (``sparse``)."""
    debug = {}
    if "evaluated_pixels" in frame.aovs and sparse is not None:
        debug["evaluated_pixels"] = sparse.mask()
    if "mip_level" in frame.aovs:
        debug["mip_level"] = (pixel_mip_levels(mips, coords) if mips is not None else
                              np.zeros(coords.shape, np.float32))
    if "rectified" in frame.aovs:
        debug["rectified"] = coords.numpy()
    if "epipole_mask" in frame.aovs:
        debug["epipole_mask"] = epipole_weights(frame.scene.camera, regions)
    if map_before_culling is not None:
        depth = map_depth(rectified)
        debug["rectified_map"] = np.stack([depth, (depth != map_before_culling).astype(np.float32)], axis=-1)
    if debug:
        info["debug_images"] = debug


def map_depth(rectified) -> np.ndarray:
    """(rows, cols) float32 rectified depth of a map (its first depth when it holds two)."""
    depth = rectified.z1 if isinstance(rectified, rectify_nonlinear.SparseRectifiedDepth) else rectified
    return depth.numpy()


__all__ = [
    "add_debug_images",
    "left_out_start",
    "with_left_out_stretch",
    "evaluate_prefiltered_kernel",
    "map_visibility",
    "representation_visibility",
    "coords_of_every_pixel",
    "pixel_coords",
    "pixel_coords_kernel",
    "render",
    "map_depth",
    "resample_filtered",
    "row_weights",
]
