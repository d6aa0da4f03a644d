"""Prefiltered single scattering: the per-row prefix sums of the Fourier and moment bases of a rectified depth map
(Klehm 2014; Peters 2017 Sec. 5); the textures they fill are defined in :mod:`.textures`, the per-pixel
look-ups in :mod:`.filtered_lookups`.

The input is a rectified blocker-depth map z (rows x cols, values in [0, 1]; see :mod:`..rectify`): every
camera view ray runs along one row from column 0 with one constant depth z_r. Visibility of a ray sample
against texel i is the step V = H(z_r - z_i) (1 when z_r <= z_i), expanded in M Fourier terms
(Klehm 2014 Eq. 8-9, 0-based index k, pair m = k // 2, c = pi (2 m + 1)):

    V(z_r, z_i) ~ 0.5 + sum_k a_k(z_r) B_k(z_i),
    a_2m = 2/c cos(c z_r),  a_2m+1 = -2/c sin(c z_r),  B_2m = sin(c z_i),  B_2m+1 = cos(c z_i).

Along a row the ray-independent basis values are prefix-filtered with weights w_i (Klehm 2014 Eq. 11,
Listings 1-3): w_i = 1 gives the average visibility (Listing 1); w_i = exp(-(i-1) tau) - exp(-i tau) with
the row's optical step tau = sigma_t Delta_ref weights by transmittance (Listing 2). When the world step
varies along the row (projective rectification, Klehm 2014 Sec. 4.2) the weights become per texel
(Eq. 12): texel i of row j has optical thickness tau_ji = tau_j l_i, with tau_j the row's optical step
per unit column length and l_i the column's relative length (``column_length``; Eq. 12's Delta d^i, or
the exact lengths), and

    w'_i = T_i (1 - exp(-tau_ji)),   T_i = exp(-sum_{i'<i} tau_ji'),

used as T_i l_i phi(tau_ji) = w'_i / tau_j with phi(x) = (1 - e^-x) / x (a row factor cancels in the
normalised means; it tends to the length l_i as sigma_t -> 0, the average-visibility weight of uneven texels).
As in Klehm 2014 App. A the stored values are NORMALISED: B_bar_k(i) = sum_{i'<=i} w_i' B_k(z_i') / sum_{i'<=i} w_i', in
[-1, 1]; a ray ending at column s sees the visible fraction

    F = clamp(0.5 + sum_k a_k(z_r) B_bar_k(s), 0, 1),

and the scattering integral is F * integral_0^s exp(-sigma_t t) dt (= F * s for average visibility).

Data layout: a filtered-basis texture is ONE array of shape (rows, cols, M), C-contiguous, so the M-vector of a
texel is contiguous and the two columns a bilinear fetch reads in a row are one run of 2 M values. The inclusive
prefix of column i belongs to the right edge of its texel, so a hit point at continuous column position
p = u * cols is read at texel-index coordinate p - 1 (linear between columns, clamped); rows are read at their
centres, wrapping around when the rectification covers the full azimuth circle.

Storage (:class:`~.textures.FilteredBasisArrays`): ``bits = 0`` keeps float32 values (4 M bytes per texel);
``bits = 8`` is the paper's RGBA8 storage (Klehm 2014 App. A, M bytes per texel): a uint8 array of codes round((0.5 x
+ 0.5) 255) (:func:`~.textures.signed_unorm_code`), decoded at look-up time to 2 code / 255 - 1 through a
256-entry table (:func:`~.textures.signed_unorm_value`, :class:`~.textures.FourierTables`). The
running filter itself keeps full precision, as registers do on the GPU; only what is written is quantized. The moment
maps (:func:`prefilter_moments`, :class:`FilteredMomentArrays`) store the modes of Peters 2017 Sec. 2.4 / 5.4.3 the
same way: float32, 16-bit codes of Theta*(b) in a uint16 array, or six 10-bit codes packed in one uint64 per texel
(:data:`MOMENT_TEXEL_LAYOUT`; the codes are those of :mod:`warpscatter.shadows.moment_storage`). Decoding gives
exactly the float32 values of the storage emulation (:func:`unorm_roundtrip`, :func:`requantize_moments`), so images
do not depend on the packing.

Split regions (Klehm 2014 Sec. 3.3, end): with ``splits`` = S > 1 each row is cut uniformly into S
regions filtered independently (S times more parallel threads). The normalised values of a region do
not know the weight of the regions before it, so the filter also stores the region-local running weight
sum W_loc(j, i) (shape (rows, cols)) and the host the reference-ray transmittance R(j, k) at each region
start (shape (rows, S)); the global weight sum of region k up to column i is R(j, k) W_loc(j, i). A ray
ending in region K needs one look-up per region in front of it (at the region's last column) and one at
its own column:

    B_bar(i) = [sum_{k<K} R_k W_loc(end_k) B_bar_k(end_k) + R_K W_loc(i) B_bar_K(i)] / [same weights],

which equals the unsplit filter up to float rounding.

Two depths per texel (filtering during resampling, Peters 2017 Sec. 5.2): the prefilters also accept a
:class:`~..rectify.SparseRectifiedDepth` (z_1, z_2, w_2). The filtered value of a texel is then the weighted
combination (1 - w_2) B_k(z_1) + w_2 B_k(z_2) of the basis (Fourier values, or the canonical moments before
storage); a plain depth map is the same code path with w_2 = 0 (:func:`texel_depths`).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ...runtime.device import default_device, module_options
from ...runtime.parallel import launch_rows
from ...shadows import moments as mm
from ..rectify.taps import SparseRectifiedDepth
from ..settings import MAX_COEFFICIENTS, MAX_SPLITS, MIN_COEFFICIENTS
from .textures import (
    FOURIER_UNORM_BITS,
    MOMENT_STORAGE,
    FilteredBasis,
    FilteredBasisArrays,
    FilteredMomentArrays,
    FilteredMoments,
    as_device_array,
    basis_arrays,
    basis_shape,
    basis_texel,
    basis_texture,
    check_depth_warp,
    fourier_basis,
    moment_texture,
    store_basis,
    store_moment_texel,
    warped_depth,
)

module_options()


# ---- filter weights --------------------------------------------------------------------------------------


@wp.func
def split_columns(parts: int, cols: int, k: int):
    """First column and column count of region k when ``cols`` columns are cut uniformly into ``parts`` regions."""
    c0 = (k * cols) // parts
    return c0, ((k + 1) * cols) // parts - c0


@wp.func
def texel_weight(transmittance: float, length: float, optical_thickness: float):
    """Transmittance weight of one texel, Klehm 2014 Eq. 12 divided by the row's optical step tau_j.

    w'_i = T_i (1 - exp(-tau_i)) is evaluated as T_i l_i phi(tau_i), phi(x) = (1 - e^-x) / x (series below
    x = 0.01, no cancellation; phi(0) = 1, so sigma_t = 0 weights by the texel length l_i).

    Args:
        transmittance: T_i, transmittance of the reference ray from the region start to the texel.
        length: l_i, relative world length of the texel along the reference ray (> 0).
        optical_thickness: tau_j l_i = sigma_t times the texel's world length, >= 0.

    Returns:
        (weight, T_(i+1)).
    """
    e = wp.exp(-optical_thickness)
    phi = float(0.0)
    if optical_thickness < 0.01:
        x = optical_thickness
        phi = 1.0 - x * (0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0)))
    else:
        phi = (1.0 - e) / optical_thickness
    return transmittance * length * phi, transmittance * e


@wp.func
def next_texel_weight(transmittance: float, uniform: bool, w_first: float, step: float,
                      column_length: wp.array(dtype=wp.float32), i: int, tau: float):
    """Weight of texel i and the transmittance after it (:func:`texel_weight`); ``uniform`` columns (one length
    for all) reuse the first texel's weight ``w_first`` and step transmittance ``step``.

    Returns:
        (weight, T_(i+1)).
    """
    if uniform:
        return transmittance * w_first, transmittance * step
    length = column_length[i]
    return texel_weight(transmittance, length, tau * length)


@wp.func
def advance_filter_weight(weight: float, sum_weights: float, step_transmittance: float):
    """One column of the normalised running filter (Klehm 2014 Listing 2).

    Weights u_i = exp(-i tau) are proportional to w_i of Eq. 11; the blend factor u_i / sum u makes
    filtered = mix(filtered, basis, alpha) the normalised weighted prefix mean (alpha = 1/(i+1) for tau = 0,
    Listing 1). Returns (alpha, next weight, new weight sum).
    """
    s = sum_weights + weight
    return weight / s, weight * step_transmittance, s


@wp.struct
class RectifiedTexels:
    """A rectified depth map as the prefilters read it: one depth per texel, or the sparse two-depth representation
    of Peters 2017 Sec. 5.2 (z_1, z_2, w_2) when ``two_depths`` != 0 (:func:`rectified_texels`)."""

    depth: wp.array2d(dtype=wp.float32)  # (rows, cols) rectified depth z_1 in [0, 1]
    depth2: wp.array2d(dtype=wp.float32)  # (rows, cols) second depth z_2 (two_depths != 0), else a 1x1 placeholder
    weight2: wp.array2d(dtype=wp.float32)  # (rows, cols) weight w_2 of z_2 (two_depths != 0), else a placeholder
    two_depths: int
    depth_warp: float  # the representations' depth warp c (filtered_textures.warped_depth; 0: none)


@wp.func
def texel_depths(rd: RectifiedTexels, j: int, i: int):
    """(z_1, z_2, w_2) of rectified texel (j, i): the sparse two-depth representation of Peters 2017 Sec. 5.2 when
    ``rd.two_depths`` != 0, else the single depth (z_1, z_1, 0)."""
    z1 = rd.depth[j, i]
    if rd.two_depths == 0:
        return z1, z1, 0.0
    return z1, rd.depth2[j, i], rd.weight2[j, i]


# ---- kernels -------------------------------------------------------------------------------------------


@wp.kernel
def depth_bounds_kernel(
    rd: RectifiedTexels,
    out: wp.array2d(dtype=wp.vec2),  # (rows, cols) (least, greatest) rectified depth of columns 0..i of the row
    offset: int,
):
    # the per-row prefix min / max of the texels' depths (both depths of a two-depth texel): one thread per row
    j = wp.tid() + offset
    lo = float(1.0e30)
    hi = float(-1.0e30)
    for i in range(rd.depth.shape[1]):
        z1, z2, w2 = texel_depths(rd, j, i)
        lo = wp.min(lo, z1)
        hi = wp.max(hi, z1)
        if w2 > 0.0:
            lo = wp.min(lo, z2)
            hi = wp.max(hi, z2)
        out[j, i] = wp.vec2(lo, hi)


@wp.kernel
def basis_transform_kernel(
    depth: wp.array2d(dtype=wp.float32),  # (rows, cols) rectified depth in [0, 1]
    out: FilteredBasisArrays,  # (rows, cols, M) basis textures B_k(z_i), float32 or RGBA8
    offset: int,
):
    j, i = wp.tid()
    j += offset
    z = depth[j, i]
    rows, cols, num = basis_shape(out)
    for k in range(num):
        store_basis(out, j, i, k, fourier_basis(k, z))


@wp.kernel
def prefix_filter_kernel(
    basis: FilteredBasisArrays,  # (rows, cols, M) basis textures
    optical_step: wp.array(dtype=wp.float32),  # (rows,) tau = sigma_t Delta_ref per row (0 = average)
    pairs_per_thread: int,  # basis pairs (sin, cos) filtered by one thread
    out: FilteredBasisArrays,  # (rows, cols, M) normalised filtered basis
    offset: int,
):
    # Klehm 2014 Listings 1-2: one thread per (row, group of bases) walks the row left to right.
    j, g = wp.tid()
    j += offset
    rows, cols, num = basis_shape(basis)
    q = wp.exp(-optical_step[j])  # transmittance of one texel step
    m_end = wp.min((g + 1) * pairs_per_thread, num // 2)
    for m in range(g * pairs_per_thread, m_end):
        k = 2 * m
        f0 = float(0.0)
        f1 = float(0.0)
        weight = float(1.0)
        sum_w = float(0.0)
        for i in range(cols):
            alpha, weight, sum_w = advance_filter_weight(weight, sum_w, q)
            f0 = f0 + alpha * (basis_texel(basis, j, i, k) - f0)
            f1 = f1 + alpha * (basis_texel(basis, j, i, k + 1) - f1)
            store_basis(out, j, i, k, f0)
            store_basis(out, j, i, k + 1, f1)


@wp.func
def group_rotation(z: float, m0: int):
    """(sin, cos) of (2 m0 + 1) pi z, the first pair of a basis group, and of the step 2 pi z between pairs, from one
    sine and one cosine: the step by the double-angle formulas, the group's start by m0 steps of angle addition."""
    s1 = wp.sin(wp.pi * z)
    c1 = wp.cos(wp.pi * z)
    step_s = 2.0 * s1 * c1
    step_c = c1 * c1 - s1 * s1
    sn = s1
    cs = c1
    for _m in range(m0):
        sn_next = sn * step_c + cs * step_s
        cs = cs * step_c - sn * step_s
        sn = sn_next
    return sn, cs, step_s, step_c


#: (sin, cos) pairs one thread of the fused filter carries in registers (a compile-time constant so the
#: pair loop unrolls and the running state never leaves registers). 32: up to 64 coefficients in one thread, which
#: writes each texel's values in one pass and takes one sine and one cosine per texel; the rows still give every core
#: hundreds of threads (the timings: docs/benchmarks.md, "Fused prefilter registers").
PAIRS_PER_THREAD = 32
filter_state = wp.types.vector(length=2 * PAIRS_PER_THREAD, dtype=wp.float32)


@wp.kernel
def prefilter_depth_kernel(
    rd: RectifiedTexels,
    optical_step: wp.array(dtype=wp.float32),  # (rows,) tau_j: optical thickness per unit column length (0 = average)
    column_length: wp.array(dtype=wp.float32),  # (cols,) relative column length l_i, or (1,): uniform columns
    texel_weights: wp.array2d(dtype=wp.float32),  # (rows, cols) given weights (a spot light's), or (1, 1): Eq. 12's
    out: FilteredBasisArrays,  # normalised filtered basis per region (Klehm 2014 Sec. 3.3), weight sums if splits > 1
    offset: int,
):
    # Klehm 2014 Listing 3: the basis transform fused into the prefix filter (no basis textures), with the
    # per-texel weights of Eq. 12. Thread (row j, t) filters region t // groups, basis group t % groups:
    # it walks its region once and filters PAIRS_PER_THREAD (sin, cos) pairs; the values
    # sin/cos((2m + 1) pi z) of the group follow from sin/cos(pi z) by rotating through 2 pi z (angle
    # addition, group_rotation), so a texel costs two trigonometric calls whatever the group size.
    j, t = wp.tid()
    j += offset
    rows, cols, num = basis_shape(out)
    num_pairs = num // 2
    groups = (num_pairs + PAIRS_PER_THREAD - 1) // PAIRS_PER_THREAD
    region = t // groups
    g = t - region * groups
    c0, nc = split_columns(out.splits, cols, region)
    tau = optical_step[j]
    uniform = column_length.shape[0] == 1  # one length for all columns: the weight ratio is a constant
    w_first, step = texel_weight(1.0, column_length[0], tau * column_length[0])
    m0 = g * PAIRS_PER_THREAD
    state = filter_state()
    transmittance = float(1.0)  # T_i from the region start (the region's normalised values ignore the rest)
    sum_w = float(0.0)
    for i in range(c0, c0 + nc):
        z, z2, w2 = texel_depths(rd, j, i)
        if rd.depth_warp != 0.0:
            z = warped_depth(z, rd.depth_warp)
            z2 = warped_depth(z2, rd.depth_warp)
        w, transmittance = next_texel_weight(transmittance, uniform, w_first, step, column_length, i, tau)
        if texel_weights.shape[0] > 1:
            w = texel_weights[j, i]
        sum_w += w
        alpha = float(0.0)
        if sum_w > 0.0:
            alpha = w / sum_w
        if out.splits > 1 and g == 0:
            out.weight_sums[j, i] = sum_w
        sn, cs, step_s, step_c = group_rotation(z, m0)
        # the second depth's values (Peters 2017 Sec. 5.2); equal to the first's when w_2 = 0
        sn2, cs2, step_s2, step_c2 = sn, cs, step_s, step_c
        if w2 > 0.0:
            sn2, cs2, step_s2, step_c2 = group_rotation(z2, m0)
        for p in range(wp.static(PAIRS_PER_THREAD)):
            if m0 + p < num_pairs:
                b_s = sn + w2 * (sn2 - sn)  # (1 - w_2) B(z_1) + w_2 B(z_2)
                b_c = cs + w2 * (cs2 - cs)
                state[2 * p] = state[2 * p] + alpha * (b_s - state[2 * p])
                state[2 * p + 1] = state[2 * p + 1] + alpha * (b_c - state[2 * p + 1])
                k = 2 * (m0 + p)
                store_basis(out, j, i, k, state[2 * p])
                store_basis(out, j, i, k + 1, state[2 * p + 1])
                sn_next = sn * step_c + cs * step_s
                cs = cs * step_c - sn * step_s
                sn = sn_next
                sn2_next = sn2 * step_c2 + cs2 * step_s2
                cs2 = cs2 * step_c2 - sn2 * step_s2
                sn2 = sn2_next


# ---- moments as the basis (Peters 2017 Sec. 5.3-5.4) ---------------------------------------------------


@wp.func
def stored_moments(depth01: float, depth01_2: float, weight2: float, num_moments: int, storage: int) -> mm.vec6:
    """Texel of a rectified MOMENT map: the moments of (1 - w_2) delta_{z_1} + w_2 delta_{z_2}, z = 2 depth01 - 1,
    as the storage mode holds them (Theta* and fixed point for the quantized modes; Peters 2017 Sec. 5.2-5.4.3:
    "convert both values to vectors of moments via Theta_m* o b and linearly combine them"). w_2 = 0 is the
    single depth. 4 moments use slots 0-3."""
    z1 = 2.0 * depth01 - 1.0
    z2 = 2.0 * depth01_2 - 1.0
    if num_moments == 4:
        b = mm.moments4_from_depth(z1)
        if weight2 > 0.0:
            b = b + weight2 * (mm.moments4_from_depth(z2) - b)
        t = mm.store_moments4(b, storage)
        return mm.vec6(t[0], t[1], t[2], t[3], 0.0, 0.0)
    b6 = mm.moments6_from_depth(z1)
    if weight2 > 0.0:
        b6 = b6 + weight2 * (mm.moments6_from_depth(z2) - b6)
    return mm.store_moments6(b6, storage)


@wp.kernel
def prefilter_moments_kernel(
    rd: RectifiedTexels,
    optical_step: wp.array(dtype=wp.float32),  # (rows,) tau_j per unit column length (0 = average)
    column_length: wp.array(dtype=wp.float32),  # (cols,) relative column lengths, or (1,): uniform columns
    texel_weights: wp.array2d(dtype=wp.float32),  # (rows, cols) given weights, or (1, 1): Eq. 12's
    out: FilteredMomentArrays,  # (rows, cols) normalised filtered stored moments in the map's storage mode
    offset: int,
):
    # Peters 2017 Sec. 5.1.1 and D.5: transmittance-weighted prefix sums of the stored moments, with the
    # same per-texel weights as the Fourier filter (Klehm 2014 Eq. 11-12); one thread per row.
    j = wp.tid() + offset
    cols = rd.depth.shape[1]
    tau = optical_step[j]
    uniform = column_length.shape[0] == 1
    w_first, step = texel_weight(1.0, column_length[0], tau * column_length[0])
    state = mm.vec6()
    transmittance = float(1.0)
    sum_w = float(0.0)
    for i in range(cols):
        w, transmittance = next_texel_weight(transmittance, uniform, w_first, step, column_length, i, tau)
        if texel_weights.shape[0] > 1:
            w = texel_weights[j, i]
        sum_w += w
        if sum_w > 0.0:
            z1, z2, w2 = texel_depths(rd, j, i)
            if rd.depth_warp != 0.0:
                z1 = warped_depth(z1, rd.depth_warp)
                z2 = warped_depth(z2, rd.depth_warp)
            state = state + (w / sum_w) * (stored_moments(z1, z2, w2, out.num_moments, out.storage) - state)
        store_moment_texel(out, j, i, state)  # fixed point: rounded once more, as the emulation requantize_moments


# ---- host side ------------------------------------------------------------------------------------------


def _check_coefficients(num_coefficients) -> int:
    m = int(num_coefficients)
    if m != num_coefficients or m % 2 or not (MIN_COEFFICIENTS <= m <= MAX_COEFFICIENTS):
        raise ValueError(f"num_coefficients must be an even integer in [{MIN_COEFFICIENTS}, {MAX_COEFFICIENTS}], "
                         f"got {num_coefficients}")
    return m


def _check_bits(bits) -> int:
    if isinstance(bits, bool) or bits not in (0, FOURIER_UNORM_BITS):
        raise ValueError(f"bits must be 0 (float32 storage) or {FOURIER_UNORM_BITS} (the paper's RGBA8 storage, "
                         f"Klehm 2014 App. A), got {bits}")
    return int(bits)


def _pairs_per_thread(bases_per_thread) -> int:
    if int(bases_per_thread) != bases_per_thread or bases_per_thread < 2 or bases_per_thread % 2:
        raise ValueError(f"bases_per_thread must be an even integer >= 2, got {bases_per_thread}")
    return int(bases_per_thread) // 2


def rectified_texels(rectified_depth, device=None, depth_warp: float = 0.0) -> RectifiedTexels:
    """:class:`RectifiedTexels` of a (rows, cols) depth map (numpy or Warp) or a :class:`SparseRectifiedDepth`; the
    prefilters warp its depths by ``depth_warp`` (:func:`~.textures.warped_depth`)."""
    device = default_device(device)
    rd = RectifiedTexels()
    rd.depth_warp = check_depth_warp(depth_warp)
    if isinstance(rectified_depth, SparseRectifiedDepth):
        arrs = [as_device_array(a, wp.float32, 2, f"rectified_depth.{n}", device)
                for a, n in ((rectified_depth.z1, "z1"), (rectified_depth.z2, "z2"), (rectified_depth.w2, "w2"))]
        if not arrs[0].shape == arrs[1].shape == arrs[2].shape:
            raise ValueError(f"rectified_depth: z1, z2 and w2 must have one shape, got "
                             f"{arrs[0].shape}, {arrs[1].shape}, {arrs[2].shape}")
        rd.depth, rd.depth2, rd.weight2 = arrs
        rd.two_depths = 1
        return rd
    rd.depth = as_device_array(rectified_depth, wp.float32, 2, "rectified_depth", device)
    rd.depth2 = rd.weight2 = wp.zeros((1, 1), dtype=wp.float32, device=device)
    rd.two_depths = 0
    return rd


def depth_bounds(rectified_depth, device=None) -> wp.array:
    """Per-row prefix bounds of a rectified map's blocker depths: (rows, cols) vec2 (least, greatest depth among
    columns 0..i of row j; both depths of a two-depth texel). A view ray at depth z_r whose texels all lie in
    front of it (z_r >= greatest) is wholly shadowed, one whose texels all lie behind it (z_r < least) wholly lit:
    the look-ups answer those exactly, per bilinear row (:func:`~.filtered_lookups.row_bounds`), where a truncated
    Fourier series rings and moment bounds leak (the 1D min-max idea of Chen et al. 2011, on prefix sums)."""
    device = default_device(device)
    rd = rectified_texels(rectified_depth, device)
    out = wp.empty(rd.depth.shape, dtype=wp.vec2, device=device)
    launch_rows(depth_bounds_kernel, (rd.depth.shape[0],), [rd, out], device=device)
    return out


def _optical_steps(optical_step, rows: int, device) -> wp.array:
    if optical_step is None:
        tau = np.zeros(rows, np.float32)
    else:
        tau = np.asarray(optical_step.numpy() if isinstance(optical_step, wp.array) else optical_step, np.float32)
        tau = np.broadcast_to(tau, (rows,)) if tau.ndim == 0 else tau
        if tau.shape != (rows,):
            raise ValueError(f"optical_step must be a scalar or have shape ({rows},), got {tau.shape}")
        if not np.all(np.isfinite(tau) & (tau >= 0.0)):
            raise ValueError("optical_step must be finite and >= 0 (sigma_t * Delta_ref per row)")
    return wp.array(np.ascontiguousarray(tau), dtype=wp.float32, device=device)


def fourier_basis_textures(rectified_depth, num_coefficients: int, *, bits: int = 0, device=None) -> wp.array:
    """Basis textures B_k(z_i) of a rectified depth map (Klehm 2014 Eq. 8, Sec. 3.3).

    Args:
        rectified_depth: (rows, cols) float32 numpy or Warp array, depth in [0, 1].
        num_coefficients: M, even, 4..128.
        bits: 0 for float32 storage, 8 for the paper's RGBA8 basis textures (uint8 codes).
        device: Warp device.

    Returns:
        (rows, cols, M) Warp array: float32 values, or uint8 codes (:class:`FilteredBasis`, ``basis``).
    """
    device = default_device(device)
    m = _check_coefficients(num_coefficients)
    bits = _check_bits(bits)
    depth = as_device_array(rectified_depth, wp.float32, 2, "rectified_depth", device)
    rows, cols = depth.shape
    out = FilteredBasis(basis=basis_texture(rows, cols, m, bits, device), weight_sums=None, region_weights=None,
                        splits=1)
    launch_rows(basis_transform_kernel, (rows, cols), [depth, out.arrays()], device=device)
    return out.basis


def prefix_filter(basis, optical_step=None, *, bases_per_thread: int = 8, bits: int = 0, device=None) -> wp.array:
    """Normalised per-row prefix filtering of basis textures (Klehm 2014 Listing 1, or Listing 2 with weights).

    Args:
        basis: (rows, cols, M) basis textures (e.g. from :func:`fourier_basis_textures`), float32 values or uint8
            RGBA8 codes.
        optical_step: None or 0 for average visibility (Listing 1); else per-row tau = sigma_t * Delta_ref
            (scalar or (rows,), e.g. :meth:`~..rectify.ReferenceRays.optical_steps`) for the
            transmittance weights w_i = exp(-(i-1) tau) - exp(-i tau) of Eq. 11 (Listing 2).
        bases_per_thread: bases filtered by one thread (even); launch is rows x ceil(M / bases_per_thread).
        bits: 0 for float32 storage, 8 for the paper's RGBA8 filtered-basis textures (uint8 codes).
        device: Warp device.

    Returns:
        (rows, cols, M) Warp array of normalised filtered basis values in [-1, 1]: float32, or uint8 codes.
    """
    device = default_device(device)
    inp = basis_arrays(basis, "basis", device)
    b = inp.codes if inp.code_bits else inp.basis
    rows, cols, m = b.shape
    _check_coefficients(m)
    ppt = _pairs_per_thread(bases_per_thread)
    tau = _optical_steps(optical_step, rows, device)
    out = FilteredBasis(basis=basis_texture(rows, cols, m, _check_bits(bits), device), weight_sums=None,
                        region_weights=None, splits=1)
    groups = -(-(m // 2) // ppt)
    launch_rows(prefix_filter_kernel, (rows, groups), [inp, tau, ppt, out.arrays()], device=device)
    return out.basis


def _column_lengths(column_length, cols: int) -> np.ndarray:
    if column_length is None:
        return np.ones(cols, np.float64)
    lengths = np.asarray(column_length.numpy() if isinstance(column_length, wp.array) else column_length, np.float64)
    if lengths.shape != (cols,):
        raise ValueError(f"column_length must have shape ({cols},), got {lengths.shape}")
    if not np.all(np.isfinite(lengths) & (lengths > 0.0)):
        raise ValueError("column_length must be finite and > 0 (relative world length of every column)")
    return lengths


def _check_splits(splits, cols: int) -> int:
    if isinstance(splits, bool) or int(splits) != splits or not 1 <= splits <= MAX_SPLITS:
        raise ValueError(f"splits must be an integer in [1, {MAX_SPLITS}], got {splits}")
    if cols < int(splits):
        raise ValueError(f"splits ({splits}) must not exceed the columns of the rectified map ({cols})")
    return int(splits)


def _kernel_lengths(lengths: np.ndarray, device) -> wp.array:
    """The column lengths as the prefilter kernels read them: (1,) when all are equal (uniform columns)."""
    uniform = bool(np.all(lengths == lengths[0]))
    return wp.array((lengths[:1] if uniform else lengths).astype(np.float32), dtype=wp.float32, device=device)


def _texel_weights(weights, rows: int, cols: int, device) -> wp.array:
    """The kernels' given per-texel weights: a (rows, cols) float32 array, or a (1, 1) placeholder for None."""
    if weights is None:
        return wp.zeros((1, 1), dtype=wp.float32, device=device)
    a = weights if isinstance(weights, wp.array) else wp.array(np.ascontiguousarray(weights, np.float32),
                                                               dtype=wp.float32, device=device)
    if tuple(a.shape) != (rows, cols):
        raise ValueError(f"texel_weights must have the map's shape {(rows, cols)}, got {tuple(a.shape)}")
    return a


def prefilter_weighted(rectified_depth, num_coefficients: int, optical_step=None, column_length=None, *,
                       texel_weights=None, depth_warp: float = 0.0,
                       splits: int = 1, bits: int = 0, device=None) -> FilteredBasis:
    """Fused basis transform and prefix filter with per-texel weights and split regions (Klehm 2014 Listing 3,
    Eq. 11-12, Sec. 3.3).

    Texel i of row j has optical thickness tau_j * l_i; its weight is Eq. 12's
    w'_i = T_i (1 - exp(-tau_j l_i)) (as T_i l_i phi(tau_j l_i), see :func:`texel_weight`). With
    ``column_length`` None (all l_i = 1) this is Listing 2 with tau_j = sigma_t Delta_ref.

    Args:
        rectified_depth: (rows, cols) float32 numpy or Warp array, depth in [0, 1], or a
            :class:`~..rectify.SparseRectifiedDepth` (two depths per texel: the weighted basis mix is
            filtered).
        num_coefficients: M, even, 4..128.
        optical_step: None or 0 for no transmittance (weights l_i: the length-weighted average visibility);
            else tau_j per row (scalar or (rows,)), the optical thickness per unit of ``column_length``.
        column_length: None (uniform) or (cols,) relative world lengths l_i > 0 of the columns along the
            reference rays (e.g. Eq. 12's Delta d^i, or the exact lengths of a projective rectification).
        texel_weights: None, or (rows, cols) weights >= 0 to use instead of Eq. 12's (a spot light's reference
            rays, :func:`~..rectify.spot_texel_weights`).
        depth_warp: the depth warp c the basis sees (:func:`~.textures.warped_depth`; 0: none); the
            texture records it and its look-ups warp the ray depth alike.
        splits: regions per row filtered independently (1..MAX_SPLITS); > 1 also stores the weight sums.
        bits: 0 for float32 storage (4 M bytes per texel), 8 for the paper's RGBA8 storage (M bytes per texel:
            uint8 codes, Klehm 2014 App. A).
        device: Warp device.

    Returns:
        :class:`FilteredBasis`; the launch is rows x splits x ceil(M / (2 PAIRS_PER_THREAD)) threads.

    Raises:
        ValueError: on bad sizes, negative or non-finite optical steps or lengths, or bad splits.
    """
    device = default_device(device)
    m = _check_coefficients(num_coefficients)
    rd = rectified_texels(rectified_depth, device, depth_warp)
    rows, cols = rd.depth.shape
    splits = _check_splits(splits, cols)
    bits = _check_bits(bits)
    tau = _optical_steps(optical_step, rows, device)
    lengths = _column_lengths(column_length, cols)
    if splits > 1:
        sums = wp.empty((rows, cols), dtype=wp.float32, device=device)
        # transmittance of the reference ray from the row start to each region start, in float64
        starts = (np.arange(splits) * cols) // splits
        before = np.concatenate([[0.0], np.cumsum(lengths)])[starts]
        region = np.exp(-tau.numpy().astype(np.float64)[:, None] * before[None, :]).astype(np.float32)
    else:
        sums = wp.zeros((1, 1), dtype=wp.float32, device=device)
        region = np.ones((rows, 1), np.float32)
    out = FilteredBasis(basis=basis_texture(rows, cols, m, bits, device), weight_sums=sums,
                        region_weights=wp.array(region, dtype=wp.float32, device=device), splits=splits,
                        depth_warp=rd.depth_warp)
    groups = -(-(m // 2) // PAIRS_PER_THREAD)
    launch_rows(prefilter_depth_kernel, (rows, splits * groups),
                [rd, tau, _kernel_lengths(lengths, device), _texel_weights(texel_weights, rows, cols, device),
                 out.arrays()], device=device)
    return out


def prefilter_moments(rectified_depth, num_moments: int, optical_step=None, column_length=None, *,
                      storage_bits: int | None = None, texel_weights=None, depth_warp: float = 0.0,
                      device=None) -> FilteredMoments:
    """Transmittance-weighted prefix sums of moments of the rectified depth (Peters 2017 Sec. 5.1.1, 5.3-5.4, D.5).

    Args:
        rectified_depth: (rows, cols) float32 depth in [0, 1], or a :class:`~..rectify.SparseRectifiedDepth`
            (two depths per texel: their weighted moment vectors are combined, Sec. 5.2).
        num_moments: 4 or 6.
        optical_step, column_length, texel_weights: the texel weights as in :func:`prefilter_weighted`.
        depth_warp: as in :func:`prefilter_weighted`.
        storage_bits: bits per texel, 64 or 128 (4 moments) / 64 (60 used), 96 or 192 (6 moments); None: the
            smallest (64) mode. The fixed-point modes store the codes of Theta*(b): 16-bit codes in a uint16 array
            (64 / 96 bits per texel) or six 10-bit codes packed in one uint64 per texel (64 bits).
        device: Warp device.

    Returns:
        :class:`FilteredMoments` of normalised filtered texels in the storage format.
    """
    device = default_device(device)
    if num_moments not in MOMENT_STORAGE:
        raise ValueError(f"num_moments must be 4 or 6, got {num_moments}")
    bits = 64 if storage_bits is None else storage_bits
    if bits not in MOMENT_STORAGE[num_moments]:
        raise ValueError(f"storage_bits for {num_moments} moments must be one of "
                         f"{sorted(MOMENT_STORAGE[num_moments])}, got {storage_bits}")
    storage = MOMENT_STORAGE[num_moments][bits]
    rd = rectified_texels(rectified_depth, device, depth_warp)
    rows, cols = rd.depth.shape
    tau = _optical_steps(optical_step, rows, device)
    lengths = _column_lengths(column_length, cols)
    out = moment_texture(rows, cols, num_moments, storage, device)
    out.depth_warp = rd.depth_warp
    launch_rows(prefilter_moments_kernel, rows, [rd, tau, _kernel_lengths(lengths, device),
                                                 _texel_weights(texel_weights, rows, cols, device), out.arrays()],
                device=device)
    return out


def prefilter_depth(rectified_depth, num_coefficients: int, optical_step=None, *, bits: int = 0,
                    device=None) -> wp.array:
    """Filtered-basis textures straight from a rectified depth map (Klehm 2014 Listing 3 fused with Listing 1/2).

    Same result as ``prefix_filter(fourier_basis_textures(depth, M), optical_step)`` without the
    intermediate basis textures (:func:`prefilter_weighted` with uniform columns and no splits).

    Args:
        rectified_depth: (rows, cols) float32 numpy or Warp array, depth in [0, 1].
        num_coefficients: M, even, 4..128.
        optical_step: as in :func:`prefix_filter`.
        bits: 0 for float32 storage, 8 for the paper's RGBA8 storage (uint8 codes).
        device: Warp device.

    Returns:
        (rows, cols, M) Warp array of normalised filtered basis values in [-1, 1] (float32, or uint8 codes); the
        launch is rows x ceil(M / (2 PAIRS_PER_THREAD)) threads.
    """
    return prefilter_weighted(rectified_depth, num_coefficients, optical_step, bits=bits, device=device).basis


__all__ = [
    "depth_bounds",
    "depth_bounds_kernel",
    "PAIRS_PER_THREAD",
    "RectifiedTexels",
    "advance_filter_weight",
    "fourier_basis_textures",
    "prefilter_depth",
    "prefilter_moments",
    "prefilter_weighted",
    "prefix_filter",
    "rectified_texels",
    "split_columns",
    "stored_moments",
    "texel_depths",
    "texel_weight",
]
