"""Per-row prefix sums of the Fourier and moment bases of a rectified depth map (Klehm 2014 Sec. 3, Listings 1-3,
Eq. 11-12, App. A; Peters 2017 Sec. 5). The textures are defined in :mod:`.textures`, read by :mod:`.filtered_lookups`.

Input: a rectified blocker-depth map z (rows x cols, values in [0, 1]; every camera view ray runs along one row from
column 0 at one depth z_r), or a :class:`~..rectify.SparseRectifiedDepth` (z_1, z_2, w_2), whose texels filter the
mix (1 - w_2) B(z_1) + w_2 B(z_2) (Peters 2017 Sec. 5.2). Stored are the NORMALISED weighted prefix means

    B_bar_k(i) = sum_{i'<=i} w_i' B_k(z_i') / sum_{i'<=i} w_i'  in [-1, 1],   w'_i = T_i (1 - exp(-tau_j l_i))

(Eq. 12: tau_j the row's optical step per unit column length, l_i the column's relative length, T_i the reference
ray's transmittance before texel i; used divided by tau_j, so sigma_t = 0 weights by l_i). A ray ending at column s
sees the visible fraction F = clamp(0.5 + sum_k a_k(z_r) B_bar_k(s), 0, 1). With ``splits`` S > 1 each row is cut
into S regions filtered independently (Sec. 3.3), with their local weight sums. Derivations and storage:
docs/design/prefiltered.md.
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
    """(weight, T_(i+1)) of one texel: Klehm 2014 Eq. 12 over the row's optical step tau_j, T_i l_i phi(tau_j l_i)
    with phi(x) = (1 - e^-x) / x (a series below 0.01; phi(0) = 1 weights by length). ``transmittance``: T_i from the
    region start; ``length``: l_i > 0 along the reference ray; ``optical_thickness``: tau_j l_i >= 0."""
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
    """(weight, T_(i+1)) of texel i (:func:`texel_weight`); ``uniform`` columns (one length for all) reuse the first
    texel's weight ``w_first`` and step transmittance ``step``."""
    if uniform:
        return transmittance * w_first, transmittance * step
    length = column_length[i]
    return texel_weight(transmittance, length, tau * length)


@wp.func
def advance_filter_weight(weight: float, sum_weights: float, step_transmittance: float):
    """(alpha, next weight, new weight sum) of one column of the normalised running filter (Klehm 2014 Listing 2):
    u_i = exp(-i tau) is proportional to Eq. 11's w_i, and filtered = mix(filtered, basis, alpha = u_i / sum u) is the
    weighted prefix mean (alpha = 1/(i+1) for tau = 0, Listing 1)."""
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
    """(z_1, z_2, w_2) of rectified texel (j, i); (z_1, z_1, 0) for a single-depth map."""
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


#: (sin, cos) pairs one thread of the fused filter carries in registers: a compile-time constant, so the pair loop
#: unrolls (docs/benchmarks.md, "Fused prefilter registers"; the choice: docs/design/prefiltered.md).
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
    # Klehm 2014 Listing 3 with Eq. 12's weights: thread (row j, t) walks region t // groups once and filters basis
    # group t % groups, its sin/cos((2m + 1) pi z) by angle addition (group_rotation): two trig calls per texel
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
    """Moments of (1 - w_2) delta_{z_1} + w_2 delta_{z_2}, z = 2 depth01 - 1, as the storage mode holds them (Theta*
    and fixed point for the quantized modes; Peters 2017 Sec. 5.2-5.4.3); 4 moments use slots 0-3."""
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
    # Peters 2017 Sec. 5.1.1, D.5 with the Fourier filter's texel weights (Klehm 2014 Eq. 11-12); one thread per row
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
    """(rows, cols) vec2: the least and greatest blocker depth among columns 0..i of row j (both depths of a two-depth
    texel), from which the look-ups answer wholly lit or shadowed rays exactly (:func:`~.filtered_lookups.row_bounds`;
    the 1D min-max maps of Chen et al. 2011, on prefix sums)."""
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
    """(rows, cols, M) basis textures B_k(z_i) (Klehm 2014 Eq. 8, Sec. 3.3) of a (rows, cols) depth map in [0, 1]:
    float32 values (``bits`` 0) or the paper's RGBA8 uint8 codes (8); M even, 4..128."""
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
    """(rows, cols, M) normalised per-row prefix filter of basis textures (:func:`fourier_basis_textures`; Klehm 2014
    Listing 1, or Listing 2 with weights), values in [-1, 1] stored as ``bits`` says (0: float32, 8: RGBA8 codes).

    Args:
        basis: (rows, cols, M) float32 values or uint8 RGBA8 codes.
        optical_step: None or 0 for average visibility; else tau = sigma_t Delta_ref per row (scalar or (rows,),
            e.g. :meth:`~..rectify.ReferenceRays.optical_steps`): Eq. 11's w_i = exp(-(i-1) tau) - exp(-i tau).
        bases_per_thread: bases one thread filters (even); the launch is rows x ceil(M / bases_per_thread).
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
    """Fused basis transform and prefix filter with Eq. 12's per-texel weights (:func:`texel_weight`) and split
    regions (Klehm 2014 Listing 3, Eq. 11-12, Sec. 3.3); a launch of rows x splits x ceil(M / (2 PAIRS_PER_THREAD)).

    Args:
        rectified_depth: (rows, cols) float32 depth in [0, 1], or a :class:`~..rectify.SparseRectifiedDepth`.
        num_coefficients: M, even, 4..128.
        optical_step: None or 0: no transmittance (weights l_i); else tau_j per row (scalar or (rows,)), the
            optical thickness per unit of ``column_length``.
        column_length: None (uniform) or (cols,) relative world lengths l_i > 0 of the columns along the reference
            rays (Eq. 12's Delta d^i, or a projective rectification's exact lengths).
        texel_weights: None, or (rows, cols) weights >= 0 replacing Eq. 12's (:func:`~..rectify.spot_texel_weights`).
        depth_warp: the depth warp c the basis sees (:func:`~.textures.warped_depth`; 0: none), recorded in the
            texture so that its look-ups warp z_r alike.
        splits: regions per row filtered independently (1..MAX_SPLITS).
        bits: 0: float32 (4 M bytes per texel); 8: the paper's RGBA8 codes (M bytes, Klehm 2014 App. A).

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
        # reference-ray transmittance from the row start to each region start (float64)
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
    """:class:`FilteredMoments`: transmittance-weighted normalised prefix sums of 4 or 6 moments of the rectified
    depth (Peters 2017 Sec. 5.1.1, 5.3-5.4, D.5), the other arguments as in :func:`prefilter_weighted`.
    ``storage_bits`` per texel: 64 or 128 (4 moments), 64 (60 used), 96 or 192 (6); None: 64. The fixed-point modes
    store codes of Theta*(b) (:data:`~.textures.MOMENT_TEXEL_LAYOUT`)."""
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
    """``prefix_filter(fourier_basis_textures(depth, M), optical_step)`` without the intermediate basis textures
    (Klehm 2014 Listing 3; :func:`prefilter_weighted`'s ``basis`` with uniform columns and no splits)."""
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
