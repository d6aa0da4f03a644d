"""Prefiltered single scattering under a spot light: the look-ups of the ``fourier``, ``moments4`` and ``moments6``
methods for a local light (Klehm 2014 Sec. 3.2, "Local Lights" and "Angular-dependency for Sources").

Map (:mod:`..rectify`): rows are epipolar planes through the light and the camera, columns the angle psi at the light,
depth the view ray's inclination theta; every texel carries the spot's emission filter tau (cone and texture). A view
ray meets the light ray psi at t = D sin(psi) / sin(theta - psi), so its in-scattered radiance is

    L = sigma_s I_peak / (D sin(theta)) integral over psi of f(-cos(theta - psi)) exp(-sigma_t t(psi)) tau V dpsi

(CONVENTIONS: cos = dot(light travel, -view); the 1 / d^2 fall-off and dt / dpsi cancel). Each ray integrates its own
weight E with LOCAL_PANELS Gauss-Legendre panels (:func:`ray_weight_table`) and cuts its look-up segments at equal
shares of it; the texels are prefiltered with the row reference ray's density times tau, and ``sums`` holds the
prefix sums of those weights without and with tau. The radiance is sigma_s I_peak / (D sin(theta)) E (E_tau / E) V:
the visible share V from segment taps as :mod:`.ray_weights` derives them (:func:`spot_visibility`), the unshadowed
share E_tau / E per panel (:func:`filter_factors`). A coloured texture has a map per channel, a coloured medium one
extinction per channel. Details: docs/design/prefiltered.md.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from ...runtime.device import module_options
from ...scene.lights import LightParams
from ...scene.medium import MediumParams, phase_eval
from ..settings import SPOT_SEGMENTS
from .filtered_lookups import (
    RAY_END_UNKNOWN,
    DepthBounds,
    mix_row_answers,
    row_bounds,
    rows_undecided,
    taps_visibility,
    window_footprint,
)
from .ray_weights import segment_columns, segment_sums
from .row_mips import RowMips

module_options()

#: Gauss-Legendre panels of a view ray's own weight table, uniform in psi.
LOCAL_PANELS = 16
local_table = wp.types.vector(length=LOCAL_PANELS + 1, dtype=wp.float32)
#: 2-point Gauss-Legendre nodes +-1/sqrt(3) on [-1, 1] (weights 1): many low-order panels for the filter factor
#: (docs/benchmarks.md, "Spot look-up quadrature").
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
    # (rows, cols, 1 + maps) rows' reference weights summed through each column: layer 0 plain, 1 + k times map k's tau
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
    for p in range(int(LOCAL_PANELS)):  # int(): a loop, not 16 unrolled copies (CUDA compile time)
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
    """Row j's filter factors E_tau / E of maps k0 .. k0 + maps - 1 (components 0 .. maps - 1): per panel of the ray's
    weight table, the tau-weighted reference mean times the ray's own weight in it (segments are too coarse where a
    ray crosses the cone's edge or a texture's detail). ``x_end``: the prefix column of the ray's end (psi_end)."""
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
    """Visible share of a look-up (:func:`spot_lookup`) on map k: its taps weighted by the segments' tau-weighted
    reference weights, normalised (0 where they see no light); a row the depth bounds decide (``bounded``) takes their
    answer, mixed by the rows' shares of the weight (as :func:`~warpscatter.scattering.prefiltered.map_visibility`)."""
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


@wp.struct
class SpotLookUp:
    """A spot light's filtered maps and how a view ray reads them (the evaluate kernel's argument)."""

    rays: SpotRays
    bounds: DepthBounds  # per-row prefix depth bounds of map 0
    mips: RowMips  # the maps' row mip levels and whether their rows wrap around
    beta: float  # moment overestimation weight (0 for Fourier)
    maps: int  # filtered maps: 1, or 3 for a coloured spot texture (one per channel)


@wp.func
def ray_span(rays: SpotRays, theta: float, psi_end: float):
    """(panel width h in psi, the prefix column of psi_end, sigma_s I -> radiance scale 1 / (D sin(theta))) of the view
    ray of inclination theta whose look-up ends at psi_end."""
    h = (psi_end - rays.psi_lo) / float(LOCAL_PANELS)
    xe = (psi_end - rays.psi_lo) * float(rays.sums.shape[1]) / rays.psi_span - 1.0
    scale = 1.0 / (rays.light_distance * wp.max(wp.sin(theta), 1.0e-6))
    return h, xe, scale


@wp.func(inline=False)  # inlined twice per kernel, it made NVRTC take minutes
def spot_radiance(texels_r: Any, texels_g: Any, texels_b: Any, look: SpotLookUp, window: wp.vec3i,
                  light: LightParams, med: MediumParams, cl: wp.vec3, theta: float, psi_end: float) -> wp.vec3:
    """In-scattered radiance in a grey medium of the view ray of inclination theta whose look-up ends at rectified
    ``cl`` (its psi at ``psi_end``), read in the row ``window`` (module doc)."""
    rays = look.rays
    h, xe, scale = ray_span(rays, theta, psi_end)
    z_r = cl[2]
    table = ray_weight_table(rays, med.sigma_t, med.phase_id, med.g, theta, rays.psi_lo, psi_end)
    j0, j1, ay, i0, i1, ax, x, cut, esum, m, bnd = spot_lookup(rays, look.bounds, cl, window, table, h)
    fac = ((1.0 - ay) * filter_factors(rays, 0, look.maps, j0, table, h, xe)
           + ay * filter_factors(rays, 0, look.maps, j1, table, h, xe))
    v = spot_visibility(texels_r, rays, 0, j0, j1, ay, i0, i1, ax, x, cut, esum, m, bnd, z_r, look.beta)
    e = wp.vec3(v * fac[0], v * fac[0], v * fac[0])
    if look.maps == 3:
        vg = spot_visibility(texels_g, rays, 1, j0, j1, ay, i0, i1, ax, x, cut, esum, m, bnd, z_r, look.beta)
        vb = spot_visibility(texels_b, rays, 2, j0, j1, ay, i0, i1, ax, x, cut, esum, m, bnd, z_r, look.beta)
        e = wp.vec3(v * fac[0], vg * fac[1], vb * fac[2])
    return wp.cw_mul(light.radiance * (med.sigma_s * table[LOCAL_PANELS] * scale), e)


@wp.func(inline=False)  # inlined twice per kernel, it made NVRTC take minutes
def spot_radiance_rgb(texels_r: Any, texels_g: Any, texels_b: Any, look: SpotLookUp, window: wp.vec3i,
                      light: LightParams, med: MediumParams, cl: wp.vec3, theta: float, psi_end: float) -> wp.vec3:
    """:func:`spot_radiance` in a coloured medium: each channel with its own extinction, weight table and cuts."""
    rays = look.rays
    h, xe, scale = ray_span(rays, theta, psi_end)
    z_r = cl[2]
    kg = int(0)
    kb = int(0)
    if look.maps == 3:
        kg = 1
        kb = 2
    e = wp.vec3(0.0, 0.0, 0.0)
    for ch in range(3):
        table = ray_weight_table(rays, med.sigma_t_rgb[ch], med.phase_id, med.g, theta, rays.psi_lo, psi_end)
        j0, j1, ay, i0, i1, ax, x, cut, esum, m, bnd = spot_lookup(rays, look.bounds, cl, window, table, h)
        v = float(0.0)
        if ch == 0:
            v = spot_visibility(texels_r, rays, 0, j0, j1, ay, i0, i1, ax, x, cut, esum, m, bnd, z_r, look.beta)
        elif ch == 1:
            v = spot_visibility(texels_g, rays, kg, j0, j1, ay, i0, i1, ax, x, cut, esum, m, bnd, z_r, look.beta)
        else:
            v = spot_visibility(texels_b, rays, kb, j0, j1, ay, i0, i1, ax, x, cut, esum, m, bnd, z_r, look.beta)
        k = ch * kg  # this channel's map: its own, or map 0 of a grey texture
        fc = ((1.0 - ay) * filter_factors(rays, k, 1, j0, table, h, xe)
              + ay * filter_factors(rays, k, 1, j1, table, h, xe))
        e[ch] = table[LOCAL_PANELS] * v * fc[0]
    return wp.cw_mul(light.radiance, wp.cw_mul(med.sigma_s_rgb, e)) * scale


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


def __getattr__(name: str):
    # the spot pass moved to warpscatter.scattering.prefiltered.spot; its names stay importable from here
    if name in ("render_spot", "evaluate_spot_kernel"):
        from . import spot

        return getattr(spot, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["LOCAL_PANELS", "SpotLookUp", "SpotRays", "ray_weight_table", "spot_radiance", "spot_radiance_rgb",
           "spot_rays"]
