"""Prefiltered single scattering: Fourier basis, per-row prefix sums and one dot product per pixel (Klehm 2014).

The input is a rectified blocker-depth map z (rows x cols, values in [0, 1]; see :mod:`.rectify`): every
camera view ray runs along one row from column 0 with one constant depth z_r. Visibility of a ray sample
against texel i is the step V = H(z_r - z_i) (1 when z_r <= z_i), expanded in M Fourier terms
(Klehm 2014 Eq. 8-9, 0-based index k, pair m = k // 2, c = pi (2 m + 1)):

    V(z_r, z_i) ~ 0.5 + sum_k a_k(z_r) B_k(z_i),
    a_2m = 2/c cos(c z_r),  a_2m+1 = -2/c sin(c z_r),  B_2m = sin(c z_i),  B_2m+1 = cos(c z_i).

Along a row the ray-independent basis values are prefix-filtered with weights w_i (Klehm 2014 Eq. 11,
Listings 1-3): w_i = 1 gives the average visibility (Listing 1); w_i = exp(-(i-1) tau) - exp(-i tau) with
the row's optical step tau = sigma_t Delta_ref weights by transmittance (Listing 2). As in Klehm 2014
App. A the stored values are NORMALISED: B_bar_k(i) = sum_{i'<=i} w_i' B_k(z_i') / sum_{i'<=i} w_i', in
[-1, 1]; a ray ending at column s sees the visible fraction

    F = clamp(0.5 + sum_k a_k(z_r) B_bar_k(s), 0, 1),

and the scattering integral is F * integral_0^s exp(-sigma_t t) dt (= F * s for average visibility).

Data layout: filtered-basis textures are ONE float32 array of shape (rows, cols, M), C-contiguous, so the
M-vector of a texel is contiguous and a bilinear fetch reads four contiguous runs. The inclusive prefix of
column i belongs to the right edge of its texel, so a hit point at continuous column position p = u * cols
is read at texel-index coordinate p - 1 (linear between columns, clamped); rows are read at their centres,
wrapping around when the rectification covers the full azimuth circle. ``bits = 8`` emulates the paper's
RGBA8 textures: each stored value is mapped to [0, 1], rounded to 8 bits and mapped back (the running
filter itself keeps full precision, as registers do on the GPU).

Not implemented: splitting rows into several regions (Klehm 2014 Sec. 3.3, multiple look-ups per pixel);
the launch parallelises over rows and groups of bases instead.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..parallel import launch_rows
from ..scene.medium import transmittance_integral
from ..wpinit import default_device, module_options
from .rectify import NonlinearRectification, NonlinearRectParams, world_to_rectified

module_options()

MIN_COEFFICIENTS = 4
MAX_COEFFICIENTS = 128


# ---- Fourier basis (Klehm 2014 Eq. 8-9) ------------------------------------------------------------------


@wp.func
def fourier_frequency(k: int) -> float:
    """c of the 0-based coefficient k: pair m = k // 2 uses c_(m+1) = pi (2 (m + 1) - 1) (Klehm 2014 Eq. 8)."""
    return wp.pi * float(2 * (k // 2) + 1)


@wp.func
def fourier_coefficient(k: int, z_r: float) -> float:
    """Ray coefficient a_k(z_r) of Klehm 2014 Eq. 8 (0-based k): 2/c cos(c z_r) for even k, -2/c sin(c z_r) odd."""
    c = fourier_frequency(k)
    if k % 2 == 0:
        return 2.0 / c * wp.cos(c * z_r)
    return -2.0 / c * wp.sin(c * z_r)


@wp.func
def fourier_basis(k: int, z_i: float) -> float:
    """Basis value B_k(z_i) of Klehm 2014 Eq. 8 (0-based k): sin(c z_i) for even k, cos(c z_i) odd; in [-1, 1]."""
    c = fourier_frequency(k)
    if k % 2 == 0:
        return wp.sin(c * z_i)
    return wp.cos(c * z_i)


@wp.func
def fourier_step(num_coefficients: int, z_r: float, z_i: float) -> float:
    """Truncated Fourier visibility of one texel, 0.5 + sum_k a_k(z_r) B_k(z_i) (Klehm 2014 Eq. 9), unclamped."""
    acc = float(0.5)
    for k in range(num_coefficients):
        acc += fourier_coefficient(k, z_r) * fourier_basis(k, z_i)
    return acc


@wp.func
def unorm_roundtrip(x: float, levels: float) -> float:
    """x in [-1, 1] after storage as a [0, 1] unorm with ``levels`` = 2^bits - 1 steps (Klehm 2014 App. A).

    ``levels <= 0`` stores full float precision (x unchanged).
    """
    if levels <= 0.0:
        return x
    q = wp.round(wp.clamp(0.5 * x + 0.5, 0.0, 1.0) * levels) / levels
    return 2.0 * q - 1.0


@wp.func
def advance_filter_weight(weight: float, sum_weights: float, step_transmittance: float):
    """One column of the normalised running filter (Klehm 2014 Listing 2).

    Weights u_i = exp(-i tau) are proportional to w_i of Eq. 11; the blend factor u_i / sum u makes
    filtered = mix(filtered, basis, alpha) the normalised weighted prefix mean (alpha = 1/(i+1) for tau = 0,
    Listing 1). Returns (alpha, next weight, new weight sum).
    """
    s = sum_weights + weight
    return weight / s, weight * step_transmittance, s


# ---- per-pixel evaluation -------------------------------------------------------------------------------


@wp.func
def prefiltered_visibility(filtered_basis: wp.array3d(dtype=wp.float32), u: float, v: float, z_r: float,
                           wrap_rows: int) -> float:
    """Visible fraction of the view ray ending at rectified (u, v) with depth z_r (Klehm 2014 Listing 4, App. A).

    Bilinear fetch of the normalised filtered-basis vector, dot product with a(z_r), + 0.5, clamped to
    [0, 1]. For average-visibility textures this is V-bar (Eq. 4); for transmittance-weighted ones
    multiply by integral_0^s exp(-sigma_t t) dt to get the visibility-weighted transmittance integral.

    Args:
        filtered_basis: (rows, cols, M) normalised prefix-filtered basis (module layout).
        u: column coordinate of the ray's end point in [0, 1] (r / r_max).
        v: row coordinate in [0, 1].
        z_r: rectified depth of the view ray.
        wrap_rows: 1 when rows wrap around (full azimuth circle), else 0 (clamp).
    """
    rows = filtered_basis.shape[0]
    cols = filtered_basis.shape[1]
    num = filtered_basis.shape[2]
    # columns: the inclusive prefix of column i is read at its right edge
    x = wp.clamp(u * float(cols) - 1.0, 0.0, float(cols - 1))
    i0 = wp.min(int(wp.floor(x)), cols - 1)
    i1 = wp.min(i0 + 1, cols - 1)
    ax = x - float(i0)
    # rows: texel centres
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
    w00 = (1.0 - ax) * (1.0 - ay)
    w01 = ax * (1.0 - ay)
    w10 = (1.0 - ax) * ay
    w11 = ax * ay
    # a_k(z_r) of Eq. 8 for pair m: (2/c cos(c z_r), -2/c sin(c z_r)), c = pi (2m + 1); cos/sin of c z_r
    # advance by angle addition through 2 pi z_r (two trigonometric calls per pixel)
    cs = wp.cos(wp.pi * z_r)
    sn = wp.sin(wp.pi * z_r)
    step_c = wp.cos(2.0 * wp.pi * z_r)
    step_s = wp.sin(2.0 * wp.pi * z_r)
    acc = float(0.5)
    for m in range(num // 2):
        k = 2 * m
        b0 = (w00 * filtered_basis[j0, i0, k] + w01 * filtered_basis[j0, i1, k]
              + w10 * filtered_basis[j1, i0, k] + w11 * filtered_basis[j1, i1, k])
        b1 = (w00 * filtered_basis[j0, i0, k + 1] + w01 * filtered_basis[j0, i1, k + 1]
              + w10 * filtered_basis[j1, i0, k + 1] + w11 * filtered_basis[j1, i1, k + 1])
        acc += 2.0 / fourier_frequency(k) * (cs * b0 - sn * b1)
        cs_next = cs * step_c - sn * step_s
        sn = sn * step_c + cs * step_s
        cs = cs_next
    return wp.clamp(acc, 0.0, 1.0)


# ---- kernels --------------------------------------------------------------------------------------------


@wp.kernel
def basis_transform_kernel(
    depth: wp.array2d(dtype=wp.float32),  # (rows, cols) rectified depth in [0, 1]
    levels: float,  # unorm steps of the stored basis (0 = float)
    out: wp.array3d(dtype=wp.float32),  # (rows, cols, M) basis textures B_k(z_i)
    offset: int,
):
    j, i = wp.tid()
    j += offset
    z = depth[j, i]
    for k in range(out.shape[2]):
        out[j, i, k] = unorm_roundtrip(fourier_basis(k, z), levels)


@wp.kernel
def prefix_filter_kernel(
    basis: wp.array3d(dtype=wp.float32),  # (rows, cols, M) basis textures
    optical_step: wp.array(dtype=wp.float32),  # (rows,) tau = sigma_t Delta_ref per row (0 = average)
    pairs_per_thread: int,  # basis pairs (sin, cos) filtered by one thread
    levels: float,  # unorm steps of the stored filtered values (0 = float)
    out: wp.array3d(dtype=wp.float32),  # (rows, cols, M) normalised filtered basis
    offset: int,
):
    # Klehm 2014 Listings 1-2: one thread per (row, group of bases) walks the row left to right.
    j, g = wp.tid()
    j += offset
    cols = basis.shape[1]
    q = wp.exp(-optical_step[j])  # transmittance of one texel step
    m_end = wp.min((g + 1) * pairs_per_thread, basis.shape[2] // 2)
    for m in range(g * pairs_per_thread, m_end):
        k = 2 * m
        f0 = float(0.0)
        f1 = float(0.0)
        weight = float(1.0)
        sum_w = float(0.0)
        for i in range(cols):
            alpha, weight, sum_w = advance_filter_weight(weight, sum_w, q)
            f0 = f0 + alpha * (basis[j, i, k] - f0)
            f1 = f1 + alpha * (basis[j, i, k + 1] - f1)
            out[j, i, k] = unorm_roundtrip(f0, levels)
            out[j, i, k + 1] = unorm_roundtrip(f1, levels)


#: (sin, cos) pairs one thread of the fused filter carries in registers (a compile-time constant so the
#: pair loop unrolls and the running state never leaves registers: 2.8x faster than a dynamic loop).
PAIRS_PER_THREAD = 8
filter_state = wp.types.vector(length=2 * PAIRS_PER_THREAD, dtype=wp.float32)


@wp.kernel
def prefilter_depth_kernel(
    depth: wp.array2d(dtype=wp.float32),  # (rows, cols) rectified depth in [0, 1]
    optical_step: wp.array(dtype=wp.float32),  # (rows,) tau = sigma_t Delta_ref per row (0 = average)
    levels: float,
    out: wp.array3d(dtype=wp.float32),  # (rows, cols, M) normalised filtered basis
    offset: int,
):
    # Klehm 2014 Listing 3: the basis transform fused into the prefix filter (no basis textures).
    # Each thread walks its row once and filters a group of PAIRS_PER_THREAD (sin, cos) pairs; the
    # values sin/cos((2m + 1) pi z) of the group follow from its first pair by rotating through
    # 2 pi z (angle addition), so a texel costs four trigonometric calls whatever the group size.
    j, g = wp.tid()
    j += offset
    cols = depth.shape[1]
    num_pairs = out.shape[2] // 2
    q = wp.exp(-optical_step[j])
    m0 = g * PAIRS_PER_THREAD
    state = filter_state()
    weight = float(1.0)
    sum_w = float(0.0)
    for i in range(cols):
        z = depth[j, i]
        alpha, weight, sum_w = advance_filter_weight(weight, sum_w, q)
        sn = wp.sin(fourier_frequency(2 * m0) * z)
        cs = wp.cos(fourier_frequency(2 * m0) * z)
        step_s = wp.sin(2.0 * wp.pi * z)
        step_c = wp.cos(2.0 * wp.pi * z)
        for p in range(wp.static(PAIRS_PER_THREAD)):
            if m0 + p < num_pairs:
                state[2 * p] = state[2 * p] + alpha * (sn - state[2 * p])
                state[2 * p + 1] = state[2 * p + 1] + alpha * (cs - state[2 * p + 1])
                k = 2 * (m0 + p)
                out[j, i, k] = unorm_roundtrip(state[2 * p], levels)
                out[j, i, k + 1] = unorm_roundtrip(state[2 * p + 1], levels)
                sn_next = sn * step_c + cs * step_s
                cs = cs * step_c - sn * step_s
                sn = sn_next


@wp.kernel
def evaluate_coords_kernel(
    filtered_basis: wp.array3d(dtype=wp.float32),
    coords: wp.array(dtype=wp.vec3),  # (u, v, z_r) per query
    wrap_rows: int,
    out: wp.array(dtype=wp.float32),
    offset: int,
):
    n = wp.tid() + offset
    c = coords[n]
    out[n] = prefiltered_visibility(filtered_basis, c[0], c[1], c[2], wrap_rows)


@wp.kernel
def evaluate_points_kernel(
    filtered_basis: wp.array3d(dtype=wp.float32),
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
    f = prefiltered_visibility(filtered_basis, c[0], c[1], c[2], rect.full_circle)
    fraction[n] = f
    integral[n] = f * transmittance_integral(sigma_t, 0.0, wp.length(x - rect.origin))


# ---- host side ------------------------------------------------------------------------------------------


def _check_coefficients(num_coefficients) -> int:
    m = int(num_coefficients)
    if m != num_coefficients or m % 2 or not (MIN_COEFFICIENTS <= m <= MAX_COEFFICIENTS):
        raise ValueError(f"num_coefficients must be an even integer in [{MIN_COEFFICIENTS}, {MAX_COEFFICIENTS}], "
                         f"got {num_coefficients}")
    return m


def _levels(bits) -> float:
    if int(bits) != bits or not (bits == 0 or 1 <= bits <= 16):
        raise ValueError(f"bits must be 0 (float storage) or an integer in [1, 16], got {bits}")
    return float(2 ** int(bits) - 1) if bits else 0.0


def _pairs_per_thread(bases_per_thread) -> int:
    if int(bases_per_thread) != bases_per_thread or bases_per_thread < 2 or bases_per_thread % 2:
        raise ValueError(f"bases_per_thread must be an even integer >= 2, got {bases_per_thread}")
    return int(bases_per_thread) // 2


def _as_array(a, dtype, ndim: int, name: str, device) -> wp.array:
    if isinstance(a, wp.array):
        arr = a if a.device == wp.get_device(device) else a.to(device)
        if arr.dtype != dtype:
            raise ValueError(f"{name} must hold {dtype.__name__}, got {arr.dtype.__name__}")
    else:
        arr = wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=dtype, device=device)
    if arr.ndim != ndim:
        raise ValueError(f"{name} must be a {ndim}D array, got shape {arr.shape}")
    return arr


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
        bits: 0 for float storage, 8 to emulate RGBA8 basis textures.
        device: Warp device.

    Returns:
        (rows, cols, M) float32 Warp array.
    """
    device = default_device(device)
    m = _check_coefficients(num_coefficients)
    levels = _levels(bits)
    depth = _as_array(rectified_depth, wp.float32, 2, "rectified_depth", device)
    rows, cols = depth.shape
    out = wp.empty((rows, cols, m), dtype=wp.float32, device=device)
    launch_rows(basis_transform_kernel, (rows, cols), [depth, levels, out], device=device)
    return out


def prefix_filter(basis, optical_step=None, *, bases_per_thread: int = 8, bits: int = 0, device=None) -> wp.array:
    """Normalised per-row prefix filtering of basis textures (Klehm 2014 Listing 1, or Listing 2 with weights).

    Args:
        basis: (rows, cols, M) basis textures (e.g. from :func:`fourier_basis_textures`).
        optical_step: None or 0 for average visibility (Listing 1); else per-row tau = sigma_t * Delta_ref
            (scalar or (rows,), e.g. :meth:`~.rectify.ReferenceRays.optical_steps`) for the
            transmittance weights w_i = exp(-(i-1) tau) - exp(-i tau) of Eq. 11 (Listing 2).
        bases_per_thread: bases filtered by one thread (even); launch is rows x ceil(M / bases_per_thread).
        bits: 0 for float storage, 8 to emulate the paper's RGBA8 filtered-basis textures.
        device: Warp device.

    Returns:
        (rows, cols, M) float32 Warp array of normalised filtered basis values in [-1, 1].
    """
    device = default_device(device)
    b = _as_array(basis, wp.float32, 3, "basis", device)
    rows, cols, m = b.shape
    _check_coefficients(m)
    ppt = _pairs_per_thread(bases_per_thread)
    tau = _optical_steps(optical_step, rows, device)
    out = wp.empty((rows, cols, m), dtype=wp.float32, device=device)
    groups = -(-(m // 2) // ppt)
    launch_rows(prefix_filter_kernel, (rows, groups), [b, tau, ppt, _levels(bits), out], device=device)
    return out


def prefilter_depth(rectified_depth, num_coefficients: int, optical_step=None, *, bits: int = 0,
                    device=None) -> wp.array:
    """Filtered-basis textures straight from a rectified depth map (Klehm 2014 Listing 3 fused with Listing 1/2).

    Same result as ``prefix_filter(fourier_basis_textures(depth, M), optical_step)`` without the
    intermediate basis textures.

    Args:
        rectified_depth: (rows, cols) float32 numpy or Warp array, depth in [0, 1].
        num_coefficients: M, even, 4..128.
        optical_step: as in :func:`prefix_filter`.
        bits: 0 for float storage, 8 to emulate RGBA8 storage.
        device: Warp device.

    Returns:
        (rows, cols, M) float32 Warp array of normalised filtered basis values in [-1, 1]; the launch is
        rows x ceil(M / (2 PAIRS_PER_THREAD)) threads.
    """
    device = default_device(device)
    m = _check_coefficients(num_coefficients)
    depth = _as_array(rectified_depth, wp.float32, 2, "rectified_depth", device)
    rows, cols = depth.shape
    tau = _optical_steps(optical_step, rows, device)
    out = wp.empty((rows, cols, m), dtype=wp.float32, device=device)
    groups = -(-(m // 2) // PAIRS_PER_THREAD)
    launch_rows(prefilter_depth_kernel, (rows, groups), [depth, tau, _levels(bits), out], device=device)
    return out


def evaluate_visibility(filtered_basis, coords, *, wrap_rows: bool = False, device=None) -> np.ndarray:
    """Visible fraction for a batch of view rays given by rectified end-point coordinates (tests, debugging).

    Args:
        filtered_basis: (rows, cols, M) normalised filtered basis.
        coords: (N, 3) rectified (u, v, z_r) of the rays' end points.
        wrap_rows: rows wrap around (full azimuth circle).
        device: Warp device.

    Returns:
        (N,) float32 numpy array in [0, 1] (see :func:`prefiltered_visibility`).
    """
    device = default_device(device)
    fb = _as_array(filtered_basis, wp.float32, 3, "filtered_basis", device)
    c = np.ascontiguousarray(coords, dtype=np.float32)
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValueError(f"coords must have shape (N, 3), got {c.shape}")
    out = wp.empty(len(c), dtype=wp.float32, device=device)
    launch_rows(evaluate_coords_kernel, len(c), [fb, wp.array(c, dtype=wp.vec3, device=device), int(wrap_rows), out],
                device=device)
    return out.numpy()


def evaluate_points(filtered_basis, rect: NonlinearRectification, points, sigma_t: float = 0.0,
                    device=None) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel evaluation for world end points of camera view rays (G-buffer hits or far-plane points).

    Args:
        filtered_basis: (rows, cols, M) normalised filtered basis built on ``rect``'s rectified map.
        rect: the rectification.
        points: (N, 3) world points x_s = position + s d.
        sigma_t: extinction (1/unit) for the transmittance integral.
        device: Warp device.

    Returns:
        (fraction, integral): (N,) float32 numpy arrays; fraction F in [0, 1] and
        F * integral_0^s exp(-sigma_t t) dt (world units; F * s when sigma_t = 0). Multiply the integral
        by sigma_s f E for L_scat (CONVENTIONS.md).
    """
    device = default_device(device)
    if not (np.isfinite(sigma_t) and sigma_t >= 0.0):
        raise ValueError(f"sigma_t must be finite and >= 0, got {sigma_t}")
    fb = _as_array(filtered_basis, wp.float32, 3, "filtered_basis", device)
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
