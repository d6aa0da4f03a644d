"""Per-pixel look-ups of prefiltered single scattering (Klehm 2014 Listing 4, App. A; Peters 2017 D.5): the
visible fraction of a camera view ray from the filtered textures of :mod:`.prefix_sums`.

A look-up reads a bilinear footprint (:func:`texel_footprint`) in the storage the prefilter wrote, through functions
specialised per array type at compile time (no per-value branch), and reconstructs F = clamp(0.5 + a(z_r) . B_bar,
0, 1) (Fourier, :func:`prefiltered_visibility`) or the moment bound at z_f = 2 z_r - 1 (:func:`moments_visibility`).
The scattering integral is F * integral_0^s exp(-sigma_t t) dt (= F * s for average visibility).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from ...runtime.device import default_device, module_options
from ...runtime.parallel import launch_rows
from ...scene.medium import transmittance_integral
from ...shadows import moments as mm
from ..rectify.bounds import NonlinearRectification
from ..rectify.spherical import NonlinearRectParams, world_to_rectified
from ..settings import MAX_SPLITS
from .prefix_sums import depth_bounds, split_columns
from .ray_weights import (
    MAX_SEGMENTS,
    RayWeights,
    ray_cut,
    ray_end,
    ray_optical_step,
    segment_columns,
    segment_count,
    segment_sums,
    weight_sum,
)
from .textures import (
    CODE_BITS_UNORM10,
    FilteredBasis,
    FilteredBasisArrays,
    FilteredMomentArrays,
    FilteredMoments,
    FourierTables,
    basis_arrays,
    basis_shape,
    basis_value,
    moment_texel_values,
    warped_depth,
)

module_options()

#: What a look-up knows of its ray's end point (:func:`row_bounds`' ``ray_end``): nothing (no lit-end test, a spot
#: light), in the surface shadow map's shadow, or lit.
RAY_END_UNKNOWN = wp.constant(0)
RAY_END_IN_SHADOW = wp.constant(1)
RAY_END_LIT = wp.constant(2)
#: A ray with a known end shorter than GUARD_COLUMN_TEXELS texels answers "wholly shadowed" from the depth bounds
#: (:func:`row_bounds`) only when no texel through the guard column (the first whose centre follows its end) lies behind
#: it by more than GUARD_COLUMN_DEPTH_TOLERANCE (rectified depth): short rays near the epipole whose next sample is
#: already behind them drew dark notches (docs/benchmarks.md, "Guard column"; docs/design/prefiltered.md).
GUARD_COLUMN_TEXELS = wp.constant(32.0)
GUARD_COLUMN_DEPTH_TOLERANCE = wp.constant(0.002)

#: Filtered-basis look-ups of one pixel: per row (two), one per region (or segment cut) in front plus two columns.
MAX_TAPS = 2 * (max(MAX_SPLITS, MAX_SEGMENTS) + 1)
tap_weights = wp.types.vector(length=MAX_TAPS, dtype=wp.float32)
tap_indices = wp.types.vector(length=MAX_TAPS, dtype=wp.int32)


@wp.func
def texel_footprint(rows: int, cols: int, u: float, v: float, wrap_rows: int):
    """(j0, j1, ay, i0, i1, ax): rows and the weight of j1, columns and the weight of i1, of the bilinear footprint of
    rectified (u, v) in a (rows, cols) texture. The inclusive prefix of column i belongs to its texel's right edge, so
    u is read at texel coordinate u * cols - 1 (clamped); rows at their centres, wrapping when ``wrap_rows`` != 0."""
    x = wp.clamp(u * float(cols) - 1.0, 0.0, float(cols - 1))
    i0 = wp.min(int(wp.floor(x)), cols - 1)
    i1 = wp.min(i0 + 1, cols - 1)
    ax = x - float(i0)
    y = v * float(rows) - 0.5
    j0 = int(0)
    j1 = int(0)
    ay = float(0.0)
    if wrap_rows != 0:
        fy = wp.floor(y)
        ay = y - fy
        j0 = int(fy)
        j0 = j0 - rows * int(wp.floor(float(j0) / float(rows)))
        j1 = j0 + 1
        if j1 >= rows:
            j1 = j1 - rows
    else:
        y = wp.clamp(y, 0.0, float(rows - 1))
        j0 = wp.min(int(wp.floor(y)), rows - 1)
        j1 = wp.min(j0 + 1, rows - 1)
        ay = y - float(j0)
    return j0, j1, ay, i0, i1, ax


@wp.func
def window_footprint(window: wp.vec3i, cols: int, u: float, v: float):
    """:func:`texel_footprint` in a row window (first row, rows, wrap) of a texture: a level of its row mips
    (:func:`~.row_mips.level_window`), or (0, rows, wrap) for the whole texture. Rows come back as texture rows."""
    j0, j1, ay, i0, i1, ax = texel_footprint(window[1], cols, u, v, window[2])
    return j0 + window[0], j1 + window[0], ay, i0, i1, ax


@wp.func
def whole_rows(rows: int, wrap_rows: int) -> wp.vec3i:
    """The row window of a texture without mips: all its ``rows`` (wrapping when ``wrap_rows`` != 0)."""
    return wp.vec3i(0, rows, wrap_rows)


@wp.struct
class DepthBounds:
    """Per-row prefix bounds of the rectified depths (:func:`~.prefix_sums.depth_bounds`); ``enabled`` 0: none (a
    1x1 placeholder, every look-up reconstructs)."""

    bounds: wp.array2d(dtype=wp.vec2)
    enabled: int


def depth_bounds_of(rectified, enabled: bool, device=None) -> DepthBounds:
    """:class:`DepthBounds` of a rectified map, or the disabled placeholder."""
    b = DepthBounds()
    b.enabled = int(bool(enabled))
    b.bounds = (depth_bounds(rectified, device=device) if enabled else
                wp.zeros((1, 1), dtype=wp.vec2, device=default_device(device)))
    return b


@wp.func
def row_bound(whole: wp.vec2, partial: wp.vec2, guard: wp.vec2, guard_tolerance: float, z_r: float) -> float:
    """One row's answer from prefix bounds (nearest, farthest blocker depth): 0 when z_r is behind every blocker of
    ``whole`` and (``guard_tolerance`` >= 0) none of ``guard`` lies behind it by more than the tolerance, 1 when in
    front of every one of ``partial`` (what the lit answer must clear), else -1."""
    if z_r >= whole[1] and (guard_tolerance < 0.0 or z_r + guard_tolerance >= guard[1]):
        return 0.0
    if z_r < partial[0]:
        return 1.0
    return -1.0


@wp.func
def row_bounds(db: DepthBounds, u_end: float, v: float, z_r: float, window: wp.vec3i, ray_end: int) -> wp.vec3:
    """The depth bounds' answer per row of a look-up ending at (u_end, v): (row j0's, row j1's, ay = row j1's bilinear
    weight). A row answers 1 when every texel it reads lies behind depth z_r (wholly lit), 0 when every one lies in
    front (wholly shadowed), else -1 (reconstruct); a row of zero weight takes the other's answer; (-1, -1, 0) without
    bounds. ``ray_end``: what is known of the ray's end (RAY_END_UNKNOWN, RAY_END_IN_SHADOW, RAY_END_LIT).

    The texels are the whole ones through the footprint's left column. The partial texel after it is the end
    surface's own blocker (``end_offset``'s zone) and is left out, except that a ray ending in shadow must clear the
    lit answer through it; a short ray with a known end must also clear the shadowed answer through the guard column
    (:data:`GUARD_COLUMN_TEXELS`). Why: docs/design/prefiltered.md."""
    if db.enabled == 0:
        return wp.vec3(-1.0, -1.0, 0.0)
    cols = db.bounds.shape[1]
    j0, j1, ay, i0, i1, ax = window_footprint(window, cols, u_end, v)
    ip = i0  # the lit answer's texels
    if ray_end == RAY_END_IN_SHADOW and ax > 0.0:
        ip = i1
    iw = i0  # the guard column (GUARD_COLUMN_TEXELS) and how far behind the ray it may lie; < 0: not asked
    guard_tolerance = float(-1.0)
    texels = u_end * float(cols)
    if ray_end != RAY_END_UNKNOWN and texels < GUARD_COLUMN_TEXELS:
        guard_tolerance = GUARD_COLUMN_DEPTH_TOLERANCE
        iw = wp.clamp(int(wp.ceil(texels - 0.5)), i0, cols - 1)
    b0 = float(-1.0)
    b1 = float(-1.0)
    if ay < 1.0:
        b0 = row_bound(db.bounds[j0, i0], db.bounds[j0, ip], db.bounds[j0, iw], guard_tolerance, z_r)
    if ay > 0.0:
        b1 = row_bound(db.bounds[j1, i0], db.bounds[j1, ip], db.bounds[j1, iw], guard_tolerance, z_r)
    if ay <= 0.0:
        b1 = b0
    if ay >= 1.0:
        b0 = b1
    return wp.vec3(b0, b1, ay)


@wp.func
def rows_undecided(b: wp.vec3) -> bool:
    """Whether a look-up's :func:`row_bounds` leave a row of non-zero weight to the reconstruction."""
    return b[0] < 0.0 or b[1] < 0.0


@wp.func
def mix_row_answers(b: wp.vec3, r: float, share1: float) -> float:
    """A look-up's visible fraction from its :func:`row_bounds` b: each decided row its exact answer, an undecided one
    the reconstruction r, mixed with row j1 weighing ``share1``. Exactly b's answer where both rows agree, exactly r
    where neither is decided."""
    v0 = b[0]
    v1 = b[1]
    if v0 < 0.0:
        v0 = r
    if v1 < 0.0:
        v1 = r
    return v0 + share1 * (v1 - v0)


@wp.func
def fourier_taps_visibility(filtered_basis: Any, tables: FourierTables, tap_row: tap_indices, tap_col: tap_indices,
                            tap_w: tap_weights, num_taps: int, z_r: float) -> float:
    """clamp(0.5 + a(z_r) . sum_t w_t B_bar(row_t, col_t), 0, 1) (Klehm 2014 Listing 4, App. A; Eq. 8's a_k, their
    cos/sin of c z_r advanced by angle addition through 2 pi z_r); arguments as in :func:`prefiltered_visibility`."""
    num = filtered_basis.shape[2]
    cs = wp.cos(wp.pi * z_r)
    sn = wp.sin(wp.pi * z_r)
    step_c = wp.cos(2.0 * wp.pi * z_r)
    step_s = wp.sin(2.0 * wp.pi * z_r)
    acc = float(0.5)
    for m in range(num // 2):
        k = 2 * m
        b0 = float(0.0)
        b1 = float(0.0)
        for t in range(num_taps):
            b0 += tap_w[t] * basis_value(filtered_basis, tables.code_values, tap_row[t], tap_col[t], k)
            b1 += tap_w[t] * basis_value(filtered_basis, tables.code_values, tap_row[t], tap_col[t], k + 1)
        acc += tables.pair_scales[m] * (cs * b0 - sn * b1)  # 2 / c (cos(c z_r) b0 - sin(c z_r) b1)
        cs_next = cs * step_c - sn * step_s
        sn = sn * step_c + cs * step_s
        cs = cs_next
    return wp.clamp(acc, 0.0, 1.0)


@wp.func
def prefiltered_visibility(filtered_basis: Any, tables: FourierTables, u: float, v: float, z_r: float,
                           window: wp.vec3i) -> float:
    """Visible fraction of the view ray ending at rectified (u, v) with depth z_r (Klehm 2014 Listing 4, App. A):
    clamp(0.5 + a(z_r) . bilinear B_bar, 0, 1); V-bar (Eq. 4) for average-visibility textures, else times
    integral_0^s exp(-sigma_t t) dt the visibility-weighted transmittance integral.

    Args:
        filtered_basis: (rows, cols, M) normalised prefix-filtered basis, one region per row: float32 values, or
            uint8 RGBA8 codes (Klehm 2014 App. A).
        tables: the device's :class:`~.textures.FourierTables` (decode table, factors 2 / c of the pairs).
        u: column coordinate of the ray's end in [0, 1] (texel i centre at (i + 0.5) / cols).
        v: row coordinate in [0, 1].
        z_r: rectified depth of the view ray.
        window: the rows read (:func:`window_footprint`): (first row, rows, 1 when they wrap around, else 0).
    """
    # fourier_taps_visibility's four-tap case written out: faster on the CPU (docs/benchmarks.md, "Fourier look-up")
    j0, j1, ay, i0, i1, ax = window_footprint(window, filtered_basis.shape[1], u, v)
    num = filtered_basis.shape[2]
    w00 = (1.0 - ax) * (1.0 - ay)
    w01 = ax * (1.0 - ay)
    w10 = (1.0 - ax) * ay
    w11 = ax * ay
    cv = tables.code_values
    cs = wp.cos(wp.pi * z_r)
    sn = wp.sin(wp.pi * z_r)
    step_c = wp.cos(2.0 * wp.pi * z_r)
    step_s = wp.sin(2.0 * wp.pi * z_r)
    acc = float(0.5)
    for m in range(num // 2):
        k = 2 * m
        b0 = (w00 * basis_value(filtered_basis, cv, j0, i0, k)
              + w01 * basis_value(filtered_basis, cv, j0, i1, k)
              + w10 * basis_value(filtered_basis, cv, j1, i0, k)
              + w11 * basis_value(filtered_basis, cv, j1, i1, k))
        b1 = (w00 * basis_value(filtered_basis, cv, j0, i0, k + 1)
              + w01 * basis_value(filtered_basis, cv, j0, i1, k + 1)
              + w10 * basis_value(filtered_basis, cv, j1, i0, k + 1)
              + w11 * basis_value(filtered_basis, cv, j1, i1, k + 1))
        acc += tables.pair_scales[m] * (cs * b0 - sn * b1)  # 2 / c (cos(c z_r) b0 - sin(c z_r) b1)
        cs_next = cs * step_c - sn * step_s
        sn = sn * step_c + cs * step_s
        cs = cs_next
    return wp.clamp(acc, 0.0, 1.0)


@wp.func
def add_split_row_taps(fb: FilteredBasisArrays, j: int, i0: int, i1: int, ax: float, row_weight: float,
                       rows: tap_indices, cols: tap_indices, w: tap_weights, n: int):
    """Append row j's taps for split regions (Klehm 2014 Sec. 3.3): the global normalised value at columns i0, i1
    (blended (1 - ax) : ax, times ``row_weight``) from the regions' own. Returns the updated (rows, cols, w, n)."""
    weight_sums = fb.weight_sums
    region_weights = fb.region_weights
    splits = fb.splits
    cols_total = weight_sums.shape[1]
    k0 = int(0)
    for k in range(1, splits):
        c_k, n_k = split_columns(splits, cols_total, k)
        if i0 >= c_k:
            k0 = k
    # global weights: regions in front of k0 (at their last column), then the columns themselves
    den0 = float(0.0)
    first = n
    for k in range(k0):
        c_k, n_k = split_columns(splits, cols_total, k)
        wk = region_weights[j, k] * weight_sums[j, c_k + n_k - 1]
        rows[n] = j
        cols[n] = c_k + n_k - 1
        w[n] = wk
        den0 += wk
        n += 1
    w_i0 = region_weights[j, k0] * weight_sums[j, i0]
    den0 += w_i0
    c_k0, n_k0 = split_columns(splits, cols_total, k0)
    w_i1 = float(0.0)
    den1 = float(0.0)
    next_region = int(0)
    if i1 == i0:
        den1 = den0
    elif i1 < c_k0 + n_k0:
        w_i1 = region_weights[j, k0] * weight_sums[j, i1]
        den1 = den0 - w_i0 + w_i1
    else:
        next_region = 1  # i0 ends region k0, i1 starts region k0 + 1
        w_i1 = region_weights[j, k0 + 1] * weight_sums[j, i1]
        den1 = den0 + w_i1
    s0 = row_weight * (1.0 - ax) / den0
    s1 = row_weight * ax / den1
    for t in range(first, n):
        w[t] = w[t] * (s0 + s1)
    rows[n] = j
    cols[n] = i0
    w[n] = w_i0 * s0
    if i1 == i0:
        w[n] = w_i0 * (s0 + s1)
    elif next_region != 0:
        w[n] = w_i0 * (s0 + s1)
    n += 1
    if i1 != i0:
        rows[n] = j
        cols[n] = i1
        w[n] = w_i1 * s1
        n += 1
    return rows, cols, w, n


@wp.func
def split_visibility(fb: FilteredBasisArrays, texels: Any, u: float, v: float, z_r: float,
                     window: wp.vec3i) -> float:
    """:func:`prefiltered_visibility_split` on ``texels``, the array of ``fb``'s storage (float32 or uint8)."""
    if fb.splits <= 1:
        return prefiltered_visibility(texels, fb.tables, u, v, z_r, window)
    j0, j1, ay, i0, i1, ax = window_footprint(window, texels.shape[1], u, v)
    rows = tap_indices()
    cols = tap_indices()
    w = tap_weights()
    rows, cols, w, n = add_split_row_taps(fb, j0, i0, i1, ax, 1.0 - ay, rows, cols, w, 0)
    rows, cols, w, n = add_split_row_taps(fb, j1, i0, i1, ax, ay, rows, cols, w, n)
    return fourier_taps_visibility(texels, fb.tables, rows, cols, w, n, z_r)


@wp.func
def prefiltered_visibility_split(fb: FilteredBasisArrays, u: float, v: float, z_r: float,
                                 window: wp.vec3i) -> float:
    """:func:`prefiltered_visibility` of a Fourier texture in either storage, its rows filtered in ``fb.splits``
    independent regions (Klehm 2014 Sec. 3.3; ``u, v, z_r, window`` as there)."""
    if fb.code_bits == 0:
        return split_visibility(fb, fb.basis, u, v, z_r, window)
    return split_visibility(fb, fb.codes, u, v, z_r, window)


@wp.func
def segment_row_weights(weights: RayWeights, j: int, x: float, tau_ray: float, cut: segment_columns,
                        esum: segment_sums, m: int) -> segment_sums:
    """Row j's weights D_k (r_k - r_(k+1)) / E_end of a ray's m interior cuts ``cut`` and, in entry m, of its end at
    prefix column x (:mod:`.ray_weights`), given the ray's weight sums ``esum``; they sum to one. A ray decaying slower
    than the row's reference (a bilinear pair's other row) is weighted as if as fast, which keeps the mix convex."""
    tau_j = wp.min(weights.optical_step[j], tau_ray)
    w = segment_sums()
    scale = 1.0 / esum[m]
    d_prev = float(0.0)
    e_prev = float(0.0)
    r_prev = float(0.0)
    for k in range(m + 1):
        d = float(0.0)
        if k < m:
            d = weight_sum(tau_j, float(cut[k] + 1))
        else:
            d = weight_sum(tau_j, x + 1.0)
        r = (esum[k] - e_prev) / wp.max(d - d_prev, 1.0e-30)
        if k > 0:
            w[k - 1] = d_prev * (r_prev - r) * scale
        r_prev = r
        d_prev = d
        e_prev = esum[k]
    w[m] = d_prev * r_prev * scale
    return w


@wp.func
def segment_lookup(weights: RayWeights, window: wp.vec3i, cols: int, u: float, v: float, z_r: float):
    """(j0, j1, cut, m, i0, i1, ax, w0, w1): the look-up of the ray ending at (u, v, z_r) weighted by its own
    transmittance: rows, m interior cuts, the end's columns (i1's weight ax) and each row's weights
    (:func:`segment_row_weights`, bilinear row weight included)."""
    j0, j1, ay, i0, i1, ax = window_footprint(window, cols, u, v)
    x = float(i0) + ax
    tau_ray = ray_optical_step(weights, z_r)
    cut = segment_columns()
    esum = segment_sums()
    e_end, decay_end = ray_end(tau_ray, x)
    m = int(0)
    last = int(-1)
    count = segment_count(weights, tau_ray, j0, j1, x)
    for k in range(1, count):
        c, e_c = ray_cut(tau_ray, x, float(k) / float(count), decay_end)
        if c > last and c < i0:
            cut[m] = c
            esum[m] = e_c
            last = c
            m += 1
    esum[m] = e_end
    w0 = segment_row_weights(weights, j0, x, tau_ray, cut, esum, m)
    w1 = w0
    if weights.optical_step[j1] != weights.optical_step[j0]:  # rows of one reference step share the weights
        w1 = segment_row_weights(weights, j1, x, tau_ray, cut, esum, m)
    return j0, j1, cut, m, i0, i1, ax, w0 * (1.0 - ay), w1 * ay


@wp.func
def rows_value(filtered_basis: Any, code_values: wp.array(dtype=wp.float32), j0: int, j1: int, i: int, k: int,
               w: wp.vec2) -> float:
    """w[0] B_bar_k(j0, i) + w[1] B_bar_k(j1, i): basis k of column i in both rows of a look-up."""
    return (w[0] * basis_value(filtered_basis, code_values, j0, i, k)
            + w[1] * basis_value(filtered_basis, code_values, j1, i, k))


@wp.func
def fourier_four_columns(filtered_basis: Any, tables: FourierTables, j0: int, j1: int, ca: int, cb: int, i0: int,
                         i1: int, wa: wp.vec2, wb: wp.vec2, w0: wp.vec2, w1: wp.vec2, rotation: wp.vec4) -> float:
    """a(z_r) . the filtered-basis vectors of columns ca, cb, i0, i1 in rows (j0, j1) weighted by wa, wb, w0, w1: up
    to three segments in one pass over the coefficients. ``rotation``: cos, sin of pi z_r, cos, sin of 2 pi z_r."""
    num = filtered_basis.shape[2]
    cv = tables.code_values
    cs = rotation[0]
    sn = rotation[1]
    step_c = rotation[2]
    step_s = rotation[3]
    acc = float(0.0)
    for m in range(num // 2):
        k = 2 * m
        b0 = (rows_value(filtered_basis, cv, j0, j1, ca, k, wa) + rows_value(filtered_basis, cv, j0, j1, cb, k, wb)
              + rows_value(filtered_basis, cv, j0, j1, i0, k, w0) + rows_value(filtered_basis, cv, j0, j1, i1, k, w1))
        k1 = k + 1
        b1 = (rows_value(filtered_basis, cv, j0, j1, ca, k1, wa) + rows_value(filtered_basis, cv, j0, j1, cb, k1, wb)
              + rows_value(filtered_basis, cv, j0, j1, i0, k1, w0) + rows_value(filtered_basis, cv, j0, j1, i1, k1, w1))
        acc += tables.pair_scales[m] * (cs * b0 - sn * b1)
        cs_next = cs * step_c - sn * step_s
        sn = sn * step_c + cs * step_s
        cs = cs_next
    return acc


@wp.func
def segment_slot(cut: segment_columns, w0: segment_sums, w1: segment_sums, k: int, m: int, fallback: int):
    """Column and (row j0, row j1) weights of cut k of a look-up, or (``fallback``, 0) when it has only m cuts."""
    if k < m:
        return cut[k], wp.vec2(w0[k], w1[k])
    return fallback, wp.vec2(0.0, 0.0)


@wp.func
def fourier_segments_visibility(fb: FilteredBasisArrays, texels: Any, weights: RayWeights, u: float, v: float,
                                z_r: float, window: wp.vec3i) -> float:
    """Visible fraction of the ray's own-transmittance look-up (:func:`segment_lookup`) on ``texels``, the array of
    ``fb``'s storage: clamp(0.5 + a(z_r) . sum of the weighted filtered-basis vectors, 0, 1)."""
    j0, j1, cut, m, i0, i1, ax, w0, w1 = segment_lookup(weights, window, texels.shape[1], u, v, z_r)
    return fourier_taps(fb, texels, j0, j1, cut, m, i0, i1, ax, w0, w1, z_r)


@wp.func
def fourier_taps(fb: FilteredBasisArrays, texels: Any, j0: int, j1: int, cut: segment_columns, m: int, i0: int,
                 i1: int, ax: float, w0: segment_sums, w1: segment_sums, z_r: float) -> float:
    """clamp(0.5 + a(z_r) . the taps' weighted filtered-basis vectors, 0, 1): the reconstruction of a segment look-up
    (:func:`segment_lookup`'s outputs) on ``texels``, the array of ``fb``'s storage; z_r is warped as the texture's
    depths are (``fb.depth_warp``)."""
    z = z_r
    if fb.depth_warp != 0.0:
        z = warped_depth(z_r, fb.depth_warp)
    rot = wp.vec4(wp.cos(wp.pi * z), wp.sin(wp.pi * z), wp.cos(2.0 * wp.pi * z), wp.sin(2.0 * wp.pi * z))
    end0 = wp.vec2(w0[m] * (1.0 - ax), w1[m] * (1.0 - ax))
    end1 = wp.vec2(w0[m] * ax, w1[m] * ax)
    # the end and the first two cuts in one pass, further cuts four per pass (an absent cut: column i0, weight 0)
    ca, wa = segment_slot(cut, w0, w1, 0, m, i0)
    cb, wb = segment_slot(cut, w0, w1, 1, m, i0)
    acc = 0.5 + fourier_four_columns(texels, fb.tables, j0, j1, ca, cb, i0, i1, wa, wb, end0, end1, rot)
    for k in range(2, m, 4):
        c0, v0 = segment_slot(cut, w0, w1, k, m, i0)
        c1, v1 = segment_slot(cut, w0, w1, k + 1, m, i0)
        c2, v2 = segment_slot(cut, w0, w1, k + 2, m, i0)
        c3, v3 = segment_slot(cut, w0, w1, k + 3, m, i0)
        acc += fourier_four_columns(texels, fb.tables, j0, j1, c0, c1, c2, c3, v0, v1, v2, v3, rot)
    return wp.clamp(acc, 0.0, 1.0)


@wp.func
def fourier_visibility(fb: FilteredBasisArrays, weights: RayWeights, u: float, v: float, z_r: float,
                       window: wp.vec3i) -> float:
    """Visible fraction of the view ray ending at rectified (u, v) with depth z_r from a Fourier texture, its texels
    weighted as ``weights`` says (one segment: the reference ray's weights, :func:`prefiltered_visibility_split`;
    split regions always use those). ``weights.end_offset`` moves the end of the look-up towards the camera."""
    cols = int(0)
    if fb.code_bits == 0:
        cols = fb.basis.shape[1]
    else:
        cols = fb.codes.shape[1]
    u_end = u - weights.end_offset / float(cols)
    if weights.segments <= 1 or fb.splits > 1:
        z = z_r
        if fb.depth_warp != 0.0:
            z = warped_depth(z_r, fb.depth_warp)
        return prefiltered_visibility_split(fb, u_end, v, z, window)
    if fb.code_bits == 0:
        return fourier_segments_visibility(fb, fb.basis, weights, u_end, v, z_r, window)
    return fourier_segments_visibility(fb, fb.codes, weights, u_end, v, z_r, window)


@wp.func
def bilinear_moments(texels: Any, num: int, u: float, v: float, window: wp.vec3i) -> mm.vec6:
    """Bilinear fetch of the stored moments (slots 0..num-1) at rectified (u, v) from a moment map's array in any
    storage, each texel decoded once (:func:`~.textures.moment_texel_values`)."""
    j0, j1, ay, i0, i1, ax = window_footprint(window, texels.shape[1], u, v)
    w00 = (1.0 - ax) * (1.0 - ay)
    w01 = ax * (1.0 - ay)
    w10 = (1.0 - ax) * ay
    w11 = ax * ay
    t00 = moment_texel_values(texels, j0, i0, num)
    t01 = moment_texel_values(texels, j0, i1, num)
    t10 = moment_texel_values(texels, j1, i0, num)
    t11 = moment_texel_values(texels, j1, i1, num)
    return w00 * t00 + w01 * t01 + w10 * t10 + w11 * t11


@wp.func
def segment_moments(texels: Any, weights: RayWeights, num: int, u: float, v: float, z_r: float,
                    window: wp.vec3i) -> mm.vec6:
    """The ray's own-transmittance combination (:func:`segment_lookup`) of the stored moments of ``texels``."""
    j0, j1, cut, m, i0, i1, ax, w0, w1 = segment_lookup(weights, window, texels.shape[1], u, v, z_r)
    return moment_taps(texels, num, j0, j1, cut, m, i0, i1, ax, w0, w1)


@wp.func
def moment_taps(texels: Any, num: int, j0: int, j1: int, cut: segment_columns, m: int, i0: int, i1: int, ax: float,
                w0: segment_sums, w1: segment_sums) -> mm.vec6:
    """The weighted sum of the stored moments of a segment look-up's taps (:func:`segment_lookup`'s outputs)."""
    t = mm.vec6()
    for k in range(m):
        t += w0[k] * moment_texel_values(texels, j0, cut[k], num) + w1[k] * moment_texel_values(texels, j1, cut[k], num)
    t += (w0[m] * (1.0 - ax)) * moment_texel_values(texels, j0, i0, num)
    t += (w1[m] * (1.0 - ax)) * moment_texel_values(texels, j1, i0, num)
    if i1 != i0:
        t += (w0[m] * ax) * moment_texel_values(texels, j0, i1, num) + (w1[m] * ax) * moment_texel_values(texels, j1,
                                                                                                         i1, num)
    return t


@wp.func
def filtered_moments(texels: Any, weights: RayWeights, num: int, u: float, v: float, z_r: float,
                     window: wp.vec3i) -> mm.vec6:
    """Stored moments of the view ray ending at (u, v) (``weights.end_offset`` texels towards the camera): the
    bilinear fetch (one segment, Peters 2017 D.5) or the ray's own-transmittance combination."""
    u_end = u - weights.end_offset / float(texels.shape[1])
    if weights.segments <= 1:
        return bilinear_moments(texels, num, u_end, v, window)
    return segment_moments(texels, weights, num, u_end, v, z_r, window)


@wp.func
def moments_visibility(filtered: FilteredMomentArrays, weights: RayWeights, u: float, v: float, z_r: float,
                       window: wp.vec3i, beta: float) -> float:
    """Visible fraction of the view ray ending at rectified (u, v) with depth z_r from prefiltered moments: the
    filtered stored moments (:func:`filtered_moments`) through :func:`stored_moments_visibility`; ``beta`` between the
    sharp lower (0) and upper (1) visibility bounds (Peters 2017 Sec. 5.3.1)."""
    num = filtered.num_moments
    t = mm.vec6()
    if filtered.code_bits == 0:
        t = filtered_moments(filtered.values, weights, num, u, v, z_r, window)
    elif filtered.code_bits == CODE_BITS_UNORM10:
        t = filtered_moments(filtered.codes10, weights, num, u, v, z_r, window)
    else:
        t = filtered_moments(filtered.codes16, weights, num, u, v, z_r, window)
    return stored_moments_visibility(filtered, t, z_r, beta)


@wp.func
def stored_moments_visibility(filtered: FilteredMomentArrays, t: mm.vec6, z_r: float, beta: float) -> float:
    """Visibility at depth z_r from a weighted sum t of a moment map's stored moments: back to canonical moments,
    biased for the storage mode, then Algorithm 1 (4 moments) or Sec. 5.4 (6 moments) at z_f = 2 z_r - 1 with the
    overestimation weight ``beta`` (Peters 2017 Sec. 5.3.1); z_r is warped as the map's depths are."""
    z = z_r
    if filtered.depth_warp != 0.0:
        z = warped_depth(z_r, filtered.depth_warp)
    z_f = 2.0 * z - 1.0
    if filtered.num_moments == 4:
        b = mm.load_biased_moments4(wp.vec4(t[0], t[1], t[2], t[3]), filtered.storage)
        return 1.0 - mm.msm4_interpolated_shadow_intensity(b, z_f, beta)
    return mm.msm6_visibility(mm.load_biased_moments6(t, filtered.storage), z_f, beta)


@wp.func
def taps_visibility(fb: FilteredBasisArrays, j0: int, j1: int, cut: segment_columns, m: int, i0: int, i1: int,
                    ax: float, w0: segment_sums, w1: segment_sums, z_r: float, beta: float) -> float:
    """Visibility of a segment look-up's taps (:func:`segment_lookup`'s outputs) from a Fourier texture in any
    storage; ``beta`` unused."""
    if fb.code_bits == 0:
        return fourier_taps(fb, fb.basis, j0, j1, cut, m, i0, i1, ax, w0, w1, z_r)
    return fourier_taps(fb, fb.codes, j0, j1, cut, m, i0, i1, ax, w0, w1, z_r)


@wp.func
def taps_visibility(filtered: FilteredMomentArrays, j0: int, j1: int, cut: segment_columns, m: int,  # noqa: F811
                    i0: int, i1: int, ax: float, w0: segment_sums, w1: segment_sums, z_r: float, beta: float) -> float:
    """Visibility of a segment look-up's taps from a moment map in any storage (overestimation weight ``beta``)."""
    num = filtered.num_moments
    t = mm.vec6()
    if filtered.code_bits == 0:
        t = moment_taps(filtered.values, num, j0, j1, cut, m, i0, i1, ax, w0, w1)
    elif filtered.code_bits == CODE_BITS_UNORM10:
        t = moment_taps(filtered.codes10, num, j0, j1, cut, m, i0, i1, ax, w0, w1)
    else:
        t = moment_taps(filtered.codes16, num, j0, j1, cut, m, i0, i1, ax, w0, w1)
    return stored_moments_visibility(filtered, t, z_r, beta)


# ---- kernels -------------------------------------------------------------------------------------------


@wp.kernel
def evaluate_coords_kernel(
    fb: FilteredBasisArrays,
    coords: wp.array(dtype=wp.vec3),  # (u, v, z_r) per query
    wrap_rows: int,
    out: wp.array(dtype=wp.float32),
    offset: int,
):
    n = wp.tid() + offset
    c = coords[n]
    rows, cols, num = basis_shape(fb)
    out[n] = prefiltered_visibility_split(fb, c[0], c[1], c[2], whole_rows(rows, wrap_rows))


@wp.kernel
def evaluate_points_kernel(
    filtered_basis: FilteredBasisArrays,
    rect: NonlinearRectParams,
    points: wp.array(dtype=wp.vec3),  # world end points of camera view rays (G-buffer hits)
    sigma_t: float,
    fraction: wp.array(dtype=wp.float32),  # visible fraction F
    integral: wp.array(dtype=wp.float32),  # F * integral_0^s exp(-sigma_t t) dt (world units)
    offset: int,
):
    n = wp.tid() + offset
    x = points[n]
    c = world_to_rectified(rect, x)
    rows, cols, num = basis_shape(filtered_basis)
    f = prefiltered_visibility_split(filtered_basis, c[0], c[1], c[2], whole_rows(rows, rect.full_circle))
    fraction[n] = f
    integral[n] = f * transmittance_integral(sigma_t, 0.0, wp.length(x - rect.origin))


# ---- host side ------------------------------------------------------------------------------------------


def filtered_basis_arrays(filtered_basis, device=None) -> FilteredBasisArrays:
    """:class:`FilteredBasisArrays` of a :class:`~.textures.FilteredBasis` or a (rows, cols, M) float32 / uint8."""
    if isinstance(filtered_basis, FilteredBasis):
        return filtered_basis.arrays()
    return basis_arrays(filtered_basis, "filtered_basis", default_device(device))


def evaluate_visibility(filtered_basis, coords, *, wrap_rows: bool = False, device=None) -> np.ndarray:
    """(N,) float32 visible fractions (:func:`prefiltered_visibility_split`) of view rays ending at (N, 3) rectified
    ``coords`` (u, v, z_r) (tests); ``filtered_basis``: a (rows, cols, M) array or a :class:`FilteredBasis`."""
    device = default_device(device)
    fb = filtered_basis_arrays(filtered_basis, device)
    c = np.ascontiguousarray(coords, dtype=np.float32)
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValueError(f"coords must have shape (N, 3), got {c.shape}")
    out = wp.empty(len(c), dtype=wp.float32, device=device)
    launch_rows(evaluate_coords_kernel, len(c), [fb, wp.array(c, dtype=wp.vec3, device=device), int(wrap_rows), out],
                device=device)
    return out.numpy()


def evaluate_points(filtered_basis, rect: NonlinearRectification, points, sigma_t: float = 0.0,
                    device=None) -> tuple[np.ndarray, np.ndarray]:
    """(fraction F, F * integral_0^s exp(-sigma_t t) dt), (N,) float32 each, of the view rays ending at (N, 3) world
    ``points`` x_s = position + s d, from a filtered basis built on ``rect``'s map; ``sigma_t`` in 1/unit. Times
    sigma_s f E the integral is L_scat (CONVENTIONS.md)."""
    device = default_device(device)
    if not (np.isfinite(sigma_t) and sigma_t >= 0.0):
        raise ValueError(f"sigma_t must be finite and >= 0, got {sigma_t}")
    fb = filtered_basis_arrays(filtered_basis, device)
    p = np.ascontiguousarray(points, dtype=np.float32)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {p.shape}")
    n = len(p)
    frac = wp.empty(n, dtype=wp.float32, device=device)
    integ = wp.empty(n, dtype=wp.float32, device=device)
    launch_rows(evaluate_points_kernel, n,
                [fb, rect.params(), wp.array(p, dtype=wp.vec3, device=device), float(sigma_t), frac, integ],
                device=device)
    return frac.numpy(), integ.numpy()


__all__ = [
    "add_split_row_taps", "bilinear_moments", "DepthBounds", "evaluate_points", "evaluate_visibility",
    "filtered_basis_arrays", "FilteredBasisArrays", "FilteredMomentArrays", "FilteredMoments",
    "fourier_taps_visibility", "fourier_visibility", "FourierTables", "GUARD_COLUMN_DEPTH_TOLERANCE",
    "GUARD_COLUMN_TEXELS", "MAX_TAPS", "mix_row_answers", "moments_visibility", "prefiltered_visibility",
    "prefiltered_visibility_split", "RAY_END_IN_SHADOW", "RAY_END_LIT", "RAY_END_UNKNOWN", "row_bounds",
    "rows_undecided", "split_visibility", "texel_footprint", "whole_rows", "window_footprint",
]
