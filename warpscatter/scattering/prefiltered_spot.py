"""Prefiltered single scattering under a spot light: the ``fourier``, ``moments4`` and ``moments6`` methods for a local
light (Klehm 2014 Sec. 3.2, "Local Lights" and "Angular-dependency for Sources").

The map is :mod:`.rectify_local`'s: rows are epipolar planes through the light and the camera, columns the angle psi
at the light, depth the view ray's inclination theta, and every texel carries the spot's emission filter tau (cone
and texture). A view ray of inclination theta meets the light ray psi at t = D sin(psi) / sin(theta - psi), at distance
D sin(theta) / sin(theta - psi) from the light, so its in-scattered radiance is

    L = sigma_s I_peak / (D sin(theta)) integral over psi of f(-cos(theta - psi)) exp(-sigma_t t(psi)) tau V dpsi

(CONVENTIONS: cos = dot(light travel, -view)): the 1 / d^2 fall-off and dt / dpsi cancel, so the weight per column is
smooth and bounded. It has no closed form:

* each ray integrates its own weight with LOCAL_PANELS 2-point Gauss-Legendre panels (:func:`ray_weight_table`):
  the unshadowed integral E and the cuts of its ``segments`` look-up segments at equal shares of it;
* each row's texels are weighted in the prefix sums by the density of the row's reference ray times tau
  (:func:`~.rectify_local.spot_texel_weights`: the ray of the slice, and its neighbours, with the largest
  inclination, which decays slowest; its phase function), and ``sums`` keeps the prefix sums
  of those weights without and with tau;
* a segment's visibility mean is then the tau-weighted one of the stored prefix means, its weight the ray's own
  share times the segment's mean tau, r_k Delta D_tau,k with r_k = Delta E_k / Delta D_k (the ray's weight per
  reference weight, as :mod:`.ray_weights` derives for directional lights); summation by parts gives taps
  D_tau,k (r_k - r_k+1) / E_tau on the stored prefix means (the visible share V);
* the filter factor E_tau / E, the unshadowed share of the emission, is summed the same way per panel of the weight
  table instead of per segment (:func:`filter_factors`): a segment is too coarse where the ray crosses the cone's
  edge or the texture's detail.

The radiance is sigma_s I_peak / (D sin(theta)) E (E_tau / E) V. A coloured texture has a map (and filter sums) per
channel; a coloured medium integrates each channel with its own extinction.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import warp as wp

from ..parallel import launch_rows
from ..scene.camera import CameraParams
from ..scene.lights import LightParams, light_params
from ..scene.medium import MediumParams, phase_eval
from ..stages import StageTimer
from ..wpinit import default_device, module_options
from .caster_culling import cull_unseen_casters, end_faces_away
from .epipole_fallback import epipole_pixel_fraction, epipole_regions, march_epipole_regions
from .filtered_lookups import (
    RAY_END_UNKNOWN,
    DepthBounds,
    depth_bounds_of,
    mix_row_answers,
    row_bounds,
    rows_undecided,
    taps_visibility,
    window_footprint,
)
from .filtered_textures import FilteredBasisArrays, FilteredMomentArrays
from .prefix_sums import prefilter_moments, prefilter_weighted
from .ray_weights import segment_columns, segment_sums
from .rectify_local import (
    coloured_emission,
    emission_peaks,
    resample_spot_shadow_map,
    spot_rectification,
    spot_texel_weights,
)
from .row_mips import RowMips, level_window, pixel_mip_level, row_mip_chain, stacked_row_means
from .settings import EVALUATE_DEPTH_TOLERANCE, SPOT_SEGMENTS
from .sparse_evaluation import PixelSet, evaluate_sparse, set_pixel

module_options()

#: Gauss-Legendre panels of a view ray's own weight table, uniform in psi.
LOCAL_PANELS = 16
local_table = wp.types.vector(length=LOCAL_PANELS + 1, dtype=wp.float32)
#: 2-point Gauss-Legendre nodes +-1/sqrt(3) on [-1, 1] (weights 1): 16 panels of two points measured as accurate as
#: 8 of four on the fence (the filter factor needs the finer panels, the density is smooth) at the same cost.
GL2_X = wp.constant(0.5773502691896258)


@wp.struct
class SpotRays:
    """How a spot light's look-ups weight a view ray (module doc)."""

    segments: int  # look-up segments per ray
    end_offset: float  # texels the look-up ends before the ray's end point
    theta_hi: float  # rectified depth 0 (radians)
    theta_len: float  # rectified depth range (radians)
    light_distance: float  # D, camera to light (world units)
    psi_lo: float  # angle at the light of column coordinate u = 0 (radians)
    psi_span: float  # angle span of u in [0, 1] (radians)
    # (rows, cols, 1 + maps) the rows' reference weights summed through each column: layer 0 plain, layer 1 + k times
    # map k's filter tau
    sums: wp.array3d(dtype=wp.float32)


@wp.func
def ray_density(rays: SpotRays, sigma_t: float, phase_id: int, g: float, theta: float, psi: float) -> float:
    """The ray theta's in-scattering per radian of psi, in units of sigma_s I / (D sin(theta)) (module doc)."""
    t = rays.light_distance * wp.sin(psi) / wp.max(wp.sin(theta - psi), 1.0e-12)
    return phase_eval(phase_id, g, -wp.cos(theta - psi)) * wp.exp(-sigma_t * t)


@wp.func
def ray_weight_table(rays: SpotRays, sigma_t: float, phase_id: int, g: float, theta: float, psi_a: float,
                     psi_b: float) -> local_table:
    """The ray theta's own weight from psi_a through the ends of LOCAL_PANELS equal panels up to psi_b (entry 0 is 0,
    the last the whole integral), 2-point Gauss-Legendre per panel."""
    h = (psi_b - psi_a) / float(LOCAL_PANELS)
    table = local_table()
    for p in range(LOCAL_PANELS):
        m = psi_a + (float(p) + 0.5) * h
        r = 0.5 * h
        table[p + 1] = table[p] + r * (ray_density(rays, sigma_t, phase_id, g, theta, m - GL2_X * r)
                                       + ray_density(rays, sigma_t, phase_id, g, theta, m + GL2_X * r))
    return table


@wp.func
def table_at(table: local_table, q: float) -> float:
    """The weight table at continuous panel position q in [0, LOCAL_PANELS] (linear inside a panel)."""
    p = wp.clamp(int(wp.floor(q)), 0, LOCAL_PANELS - 1)
    return table[p] + wp.clamp(q - float(p), 0.0, 1.0) * (table[p + 1] - table[p])


@wp.func
def table_share(table: local_table, share: float) -> float:
    """The continuous panel position where the weight table reaches ``share`` of its total."""
    target = share * table[LOCAL_PANELS]
    p = int(0)
    while p < LOCAL_PANELS - 1 and table[p + 1] < target:
        p += 1
    return float(p) + wp.clamp((target - table[p]) / wp.max(table[p + 1] - table[p], 1.0e-30), 0.0, 1.0)


@wp.func
def ray_cuts(rays: SpotRays, table: local_table, h: float, cols: int, i0: int):
    """The look-up's interior cuts at equal shares of the ray's own weight, snapped to whole columns before the end
    column i0: (cut columns, the ray's weight through each, m); entry m of the sums is the whole ray's."""
    dpsi = rays.psi_span / float(cols)
    cut = segment_columns()
    esum = segment_sums()
    m = int(0)
    last = int(-1)
    for k in range(1, rays.segments):
        q = table_share(table, float(k) / float(rays.segments))
        c = int(wp.floor(q * h / dpsi)) - 1
        if c > last and c < i0:
            cut[m] = c
            esum[m] = table_at(table, float(c + 1) * dpsi / h)
            last = c
            m += 1
    esum[m] = table[LOCAL_PANELS]
    return cut, esum, m


@wp.func
def prefix_position(cols: int, x: float):
    """Where continuous prefix column x reads a row of prefix sums: (i, i_next, a, head); the value is
    sums[i] + a (sums[i_next] - sums[i]), or with ``head`` (x inside the first column) a * sums[0]."""
    if x < 0.0:
        return 0, 0, wp.max(x + 1.0, 0.0), 1
    last = cols - 1
    i = wp.clamp(int(wp.floor(x)), 0, last)
    return i, wp.min(i + 1, last), wp.clamp(x - float(i), 0.0, 1.0), 0


@wp.func
def prefix_value(sums: wp.array3d(dtype=wp.float32), j: int, layer: int, i: int, i_next: int, a: float,
                 head: int) -> float:
    """Row j of a layer of per-column prefix sums at a :func:`prefix_position`."""
    if head != 0:
        return a * sums[j, 0, layer]
    return sums[j, i, layer] + a * (sums[j, i_next, layer] - sums[j, i, layer])


@wp.func
def prefix_at(sums: wp.array3d(dtype=wp.float32), layer: int, j: int, x: float) -> float:
    """Row j of a layer of per-column prefix sums at continuous prefix column x (linear between whole columns; inside
    the first column, its share of it)."""
    i, i_next, a, head = prefix_position(sums.shape[1], x)
    return prefix_value(sums, j, layer, i, i_next, a, head)


@wp.func
def spot_row_weights(rays: SpotRays, k: int, j: int, x: float, cut: segment_columns, esum: segment_sums, m: int):
    """Row j's tap weights of map k for the cuts (and the end at continuous prefix column x), and the row's filter
    factor E_tau / E (module doc). A row the ray sees no light in gets factor 0 (its weights then read the end)."""
    w = segment_sums()
    d_prev = float(0.0)
    f_prev = float(0.0)
    e_prev = float(0.0)
    r_prev = float(0.0)
    e_tau = float(0.0)
    for s in range(m + 1):
        d = float(0.0)
        f = float(0.0)
        if s < m:
            d = prefix_at(rays.sums, 0, j, float(cut[s]))
            f = prefix_at(rays.sums, 1 + k, j, float(cut[s]))
        else:
            d = prefix_at(rays.sums, 0, j, x)
            f = prefix_at(rays.sums, 1 + k, j, x)
        r = (esum[s] - e_prev) / wp.max(d - d_prev, 1.0e-30)
        e_tau += r * (f - f_prev)
        if s > 0:
            w[s - 1] = f_prev * (r_prev - r)
        r_prev = r
        d_prev = d
        f_prev = f
        e_prev = esum[s]
    w[m] = f_prev * r_prev
    if e_tau <= 1.0e-30:
        w = segment_sums()
        w[m] = 1.0
        return w, 0.0
    return w / e_tau, e_tau / wp.max(esum[m], 1.0e-30)


@wp.func
def filter_factors(rays: SpotRays, k0: int, maps: int, j: int, table: local_table, h: float,
                   x_end: float) -> wp.vec3:
    """Row j's filter factors E_tau / E of maps k0 .. k0 + maps - 1 (components 0 .. maps - 1) for the ray's weight
    table: per panel of the table, the tau-weighted reference mean times the ray's own weight in it. The look-up
    segments of :func:`spot_row_weights` are too coarse for this: where a ray crosses the cone's edge or a textured
    spot's detail its density falls differently from the reference's inside a segment (the unshadowed textured
    fence at 320x180: 0.96 % rel. L1 per segment, 0.29 % per panel; splitting the panels further with the table
    interpolated linearly was worse, 0.79 %). ``x_end``: the prefix column of the ray's end (psi_end)."""
    dpsi = rays.psi_span / float(rays.sums.shape[1])
    d_prev = float(0.0)
    f_prev = wp.vec3(0.0, 0.0, 0.0)
    e_tau = wp.vec3(0.0, 0.0, 0.0)
    for p in range(1, LOCAL_PANELS + 1):
        x = x_end
        if p < LOCAL_PANELS:
            x = float(p) * h / dpsi - 1.0
        i, i_next, a, head = prefix_position(rays.sums.shape[1], x)
        d = prefix_value(rays.sums, j, 0, i, i_next, a, head)
        f = wp.vec3(0.0, 0.0, 0.0)
        for c in range(wp.static(3)):  # unrolled: f stays in registers
            if c < maps:
                f[c] = prefix_value(rays.sums, j, 1 + k0 + c, i, i_next, a, head)
        if d > d_prev:
            e_tau += (table[p] - table[p - 1]) / (d - d_prev) * (f - f_prev)
        d_prev = d
        f_prev = f
    return e_tau / wp.max(table[LOCAL_PANELS], 1.0e-30)


@wp.func
def spot_lookup(rays: SpotRays, bounds: DepthBounds, c: wp.vec3, window: wp.vec3i, table: local_table, h: float):
    """What every map's look-up of the view ray ending at rectified c shares in the row ``window`` (a mip level,
    :func:`~.row_mips.level_window`): the bilinear footprint (j0, j1, ay, i0, i1, ax), the end's continuous prefix
    column x, the cuts (cut, esum, m) and the depth bounds' answers per row (:func:`~.filtered_lookups.row_bounds`)."""
    cols = rays.sums.shape[1]
    u = c[0] - rays.end_offset / float(cols)
    j0, j1, ay, i0, i1, ax = window_footprint(window, cols, u, c[1])
    cut, esum, m = ray_cuts(rays, table, h, cols, i0)
    bounds_answer = row_bounds(bounds, u, c[1], c[2], window, RAY_END_UNKNOWN)
    return j0, j1, ay, i0, i1, ax, float(i0) + ax, cut, esum, m, bounds_answer


@wp.func
def spot_visibility(texels: Any, rays: SpotRays, k: int, j0: int, j1: int, ay: float, i0: int, i1: int, ax: float,
                    x: float, cut: segment_columns, esum: segment_sums, m: int, bounded: wp.vec3, z_r: float,
                    beta: float) -> float:
    """Visible share of a look-up (:func:`spot_lookup`) on map k (module doc): its taps weighted by the segments'
    tau-weighted reference weights, normalised by their sum (the radiance takes the unshadowed share from the finer
    :func:`filter_factors`); 0 where the segments see no light. A row the depth bounds decide (``bounded``,
    :func:`~.filtered_lookups.row_bounds`) takes their answer, the other the reconstruction, mixed by the rows'
    shares of the weight (as :func:`~.prefiltered.map_visibility`)."""
    w0, f0 = spot_row_weights(rays, k, j0, x, cut, esum, m)
    w1, f1 = spot_row_weights(rays, k, j1, x, cut, esum, m)
    tex = (1.0 - ay) * f0 + ay * f1
    if tex <= 0.0:
        return float(0.0)
    r = float(0.0)
    if rows_undecided(bounded):
        r = taps_visibility(texels, j0, j1, cut, m, i0, i1, ax, w0 * ((1.0 - ay) * f0 / tex),
                            w1 * (ay * f1 / tex), z_r, beta)
    return mix_row_answers(bounded, r, ay * f1 / tex)  # row j1's share of the look-up's weight


@wp.func
def spot_radiance(texels_r: Any, texels_g: Any, texels_b: Any, maps: int, rays: SpotRays, bounds: DepthBounds,
                  window: wp.vec3i, beta: float, light: LightParams, med: MediumParams, cl: wp.vec3, theta: float,
                  psi_end: float) -> wp.vec3:
    """In-scattered radiance of the view ray of inclination theta whose look-up ends at rectified ``cl`` (its psi at
    ``psi_end``), read in the row ``window`` (module doc; a coloured medium: each channel with its own extinction,
    weight table and cuts)."""
    h = (psi_end - rays.psi_lo) / float(LOCAL_PANELS)
    xe = (psi_end - rays.psi_lo) * float(rays.sums.shape[1]) / rays.psi_span - 1.0  # prefix column of psi_end
    scale = 1.0 / (rays.light_distance * wp.max(wp.sin(theta), 1.0e-6))
    z_r = cl[2]
    if med.coloured == 0:
        table = ray_weight_table(rays, med.sigma_t, med.phase_id, med.g, theta, rays.psi_lo, psi_end)
        j0, j1, ay, i0, i1, ax, x, cut, esum, m, bnd = spot_lookup(rays, bounds, cl, window, table, h)
        fac = ((1.0 - ay) * filter_factors(rays, 0, maps, j0, table, h, xe)
               + ay * filter_factors(rays, 0, maps, j1, table, h, xe))
        v = spot_visibility(texels_r, rays, 0, j0, j1, ay, i0, i1, ax, x, cut, esum, m, bnd, z_r, beta)
        e = wp.vec3(v * fac[0], v * fac[0], v * fac[0])
        if maps == 3:
            vg = spot_visibility(texels_g, rays, 1, j0, j1, ay, i0, i1, ax, x, cut, esum, m, bnd, z_r, beta)
            vb = spot_visibility(texels_b, rays, 2, j0, j1, ay, i0, i1, ax, x, cut, esum, m, bnd, z_r, beta)
            e = wp.vec3(v * fac[0], vg * fac[1], vb * fac[2])
        return wp.cw_mul(light.radiance * (med.sigma_s * table[LOCAL_PANELS] * scale), e)
    kg = int(0)
    kb = int(0)
    if maps == 3:
        kg = 1
        kb = 2
    e = wp.vec3(0.0, 0.0, 0.0)
    for ch in range(3):
        table = ray_weight_table(rays, med.sigma_t_rgb[ch], med.phase_id, med.g, theta, rays.psi_lo, psi_end)
        j0, j1, ay, i0, i1, ax, x, cut, esum, m, bnd = spot_lookup(rays, bounds, cl, window, table, h)
        v = float(0.0)
        if ch == 0:
            v = spot_visibility(texels_r, rays, 0, j0, j1, ay, i0, i1, ax, x, cut, esum, m, bnd, z_r, beta)
        elif ch == 1:
            v = spot_visibility(texels_g, rays, kg, j0, j1, ay, i0, i1, ax, x, cut, esum, m, bnd, z_r, beta)
        else:
            v = spot_visibility(texels_b, rays, kb, j0, j1, ay, i0, i1, ax, x, cut, esum, m, bnd, z_r, beta)
        k = ch * kg  # this channel's map: its own, or map 0 of a grey texture
        fc = ((1.0 - ay) * filter_factors(rays, k, 1, j0, table, h, xe)
              + ay * filter_factors(rays, k, 1, j1, table, h, xe))
        e[ch] = table[LOCAL_PANELS] * v * fc[0]
    return wp.cw_mul(light.radiance, wp.cw_mul(med.sigma_s_rgb, e)) * scale


@wp.kernel
def evaluate_spot_kernel(
    cam: CameraParams,
    coords: wp.array2d(dtype=wp.vec3),  # the rectified (u, v, z_r) of every pixel's view-ray end
    texels_r: Any,  # FilteredBasisArrays or FilteredMomentArrays of map 0
    texels_g: Any,  # map 1 (a coloured texture) or map 0 again
    texels_b: Any,
    maps: int,  # 1 or 3
    rays: SpotRays,
    bounds: DepthBounds,
    mips: RowMips,  # the maps' row mip levels and whether their rows wrap around
    beta: float,
    light: LightParams,  # radiance: the emission peak per channel
    med: MediumParams,
    out: wp.array2d(dtype=wp.vec3),
    pixels: PixelSet,  # the pixels to evaluate (sparse_evaluation)
    offset: int,
):
    a, b = wp.tid()
    j, i, listed = set_pixel(pixels, cam.height, cam.width, a + offset, b)
    if not listed:
        return
    c = coords[j, i]
    theta = rays.theta_hi - c[2] * rays.theta_len
    u_end = wp.min(c[0], 1.0)  # past the map's last column the spot's cone has ended
    psi_end = wp.min(rays.psi_lo + u_end * rays.psi_span, theta - 1.0e-6)
    result = wp.vec3(0.0, 0.0, 0.0)
    if psi_end > rays.psi_lo:
        cl = wp.vec3(u_end, c[1], c[2])
        lv = pixel_mip_level(mips, coords, j, i)
        level = int(lv[0])
        result = spot_radiance(texels_r, texels_g, texels_b, maps, rays, bounds, level_window(mips, level), beta,
                               light, med, cl, theta, psi_end)
        if lv[1] > 0.0:  # between two levels: blend (row_mips)
            upper = spot_radiance(texels_r, texels_g, texels_b, maps, rays, bounds, level_window(mips, level + 1),
                                  beta, light, med, cl, theta, psi_end)
            result = result + lv[1] * (upper - result)
    out[j, i] = result


wp.overload(evaluate_spot_kernel, {"texels_r": FilteredBasisArrays, "texels_g": FilteredBasisArrays,
                                   "texels_b": FilteredBasisArrays})
wp.overload(evaluate_spot_kernel, {"texels_r": FilteredMomentArrays, "texels_g": FilteredMomentArrays,
                                   "texels_b": FilteredMomentArrays})


def spot_rays(rect, settings, sums: np.ndarray, device) -> SpotRays:
    """Kernel-side :class:`SpotRays` of a rectification, the ``prefiltered`` settings and the (1 + maps, rows, cols)
    prefix sums of the texel weights (layer 0 plain, then times each map's filter)."""
    r = SpotRays()
    r.segments = int(settings.segments if settings.segments is not None else SPOT_SEGMENTS)
    r.end_offset = settings.end_offsets_for(light_behind=False, directional=False)[0]
    r.theta_hi, r.theta_len = float(rect.theta_hi), float(rect.theta_len)
    r.light_distance, r.psi_lo, r.psi_span = float(rect.light_distance), float(rect.psi_lo), float(rect.r_max)
    # (rows, cols, 1 + maps): a column's layers side by side, one cache line per prefix read of every map
    r.sums = wp.array(np.ascontiguousarray(np.moveaxis(sums, 0, -1), np.float32), dtype=wp.float32, device=device)
    return r


def render_spot(frame, settings, stage: StageTimer) -> tuple[wp.array, dict]:
    """The spot-light branch of :func:`.prefiltered.render` (its arguments, results and debug outputs). Stages
    ``rectify``, ``pixel_coords``, ``caster_culling``, ``prefilter``, ``evaluate``, ``epipole``.

    Raises:
        ValueError: for ``rectification: projective``, ``splits`` > 1 or ``overestimation: adaptive``, which need
            a directional light.
    """
    from .prefiltered import add_debug_images, coords_of_every_pixel, map_depth, pixel_coords

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
    with stage("rectify"):
        rect = spot_rectification(cam, light, rows=rows, cols=cols, guard_band=p.guard_band)
        rectified, emission = resample_spot_shadow_map(rect, shadow_map, light, lparams, device=device)
    lparams.radiance = wp.vec3(*emission_peaks(light).astype(np.float32))  # the filter is relative to the peak
    every_pixel = coords_of_every_pixel(settings, frame.aovs)
    with stage("pixel_coords"):
        coords = (pixel_coords(rect, cam, gbuffer.distance, device=device) if every_pixel else
                  wp.empty((cam.height, cam.width), dtype=wp.vec3, device=device))
    map_before_culling = map_depth(rectified).copy() if "rectified_map" in frame.aovs else None
    culled = None
    if settings.culls_casters:
        with stage("caster_culling"):
            culled = cull_unseen_casters(rectified, rect, coords, bias=p.caster_culling_bias, device=device,
                                         mip_levels=p.mip_levels,
                                         faces_away=end_faces_away(cam, gbuffer, lparams, device))
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
    with stage("evaluate"):
        overestimation = settings.moments.overestimation
        # the view rays' angle to a spot's light varies along them: one overestimation weight for all (settings)
        beta = 0.0 if settings.method == "fourier" else settings.moments.spot_beta(settings.num_moments)
        if beta < 0.0:
            raise ValueError("render.scattering.moments.overestimation: 'adaptive' needs a directional light (Peters "
                             "2017 Sec. 5.3.1 weighs the light and view directions); give a number for a spot light")
        sums = np.cumsum(np.concatenate([weights[None], filtered]), axis=2, dtype=np.float64)
        rays = spot_rays(rect, p, stacked_row_means(sums, mips.levels, axis=1), device)
        out = wp.empty((cam.height, cam.width), dtype=wp.vec3, device=device)
        arrays = [t.arrays() for t in textures]
        arrays += [arrays[0]] * (3 - len(arrays))
        inputs = [cam.params(), coords, *arrays, maps, rays, bounds, mips, beta, lparams, scene.medium.params(), out]

        def look_up(pixels: PixelSet, dim: tuple[int, int]) -> None:
            if not every_pixel:  # the coordinates of the same pixels first
                pixel_coords(rect, cam, gbuffer.distance, device, pixels=pixels, dim=dim, out=coords)
            launch_rows(evaluate_spot_kernel, dim, [*inputs, pixels], device=device)

        sparse = evaluate_sparse(look_up, gbuffer.distance, out, p.evaluate_stride, p.evaluate_tolerance,
                                 EVALUATE_DEPTH_TOLERANCE, levels=p.evaluate_levels_for(cam.height, spot=True),
                                 device=device)
    # auto marches no disc under a spot (settings: its light's 1/d^2 peak made the marched disc the noisier part)
    regions = (epipole_regions(cam, rect.light_direction, p.epipole_angle_deg, p.epipole_block)
               if p.epipole_fallback is True else [])
    epipole_marched = 1.0
    if regions:
        with stage("epipole"):
            epipole_marched = march_epipole_regions(
                scene, gbuffer, shadow_map, regions, out, steps=p.epipole_steps, seed=settings.seed,
                shadow_bias_texels=settings.shadow_map.bias, jitter=settings.march_jitter, stride=p.epipole_stride,
                tolerance=p.evaluate_tolerance, device=device)
    info = {
        "rectification": "nonlinear",
        "rectification_reason": "spot light: angles at the light as columns",
        "rectified_map": [cols, rows],
        "basis": settings.method,
        **({"coefficients": settings.fourier.coefficients} if settings.method == "fourier" else
           {"overestimation": overestimation if overestimation is not None else round(beta, 4)}),
        "bits_per_texel": settings.filtered_bits_per_texel,
        "segments": int(rays.segments),
        "depth_bounds": p.depth_bounds,
        "depth_warp": depth_warp,
        "mip_levels": mips.levels,
        "end_offset": float(rays.end_offset),
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


__all__ = ["SpotRays", "evaluate_spot_kernel", "render_spot", "spot_rays"]
