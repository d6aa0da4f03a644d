"""Moment shadow mapping math of Peters et al. 2017 ("Improved Moment Shadow Maps ...", JCGT 6(1)).

Public float32 ``@wp.func`` building blocks, callable from any kernel as ``moments.<name>``, re-exported from
:mod:`.moment_storage` (moment vectors, quantization transforms, storage modes, biasing) and :mod:`.moment_solvers`
(Algorithms 1 and 2, bounds, over-darkening), and numpy host wrappers (``moments4``, ``shadow_intensity4``, ...).

Conventions (Sec. 2.3): depth is SIGNED, z in [-1, 1] (-1 at the shadow map's near plane, +1 at its far plane). A
moment vector omits b_0 = 1: ``wp.vec4`` (b_1..b_4) or :data:`vec6` (b_1..b_6). "Shadow intensity" is the fraction
Z(z < z_f) of the depth distribution in front of the fragment depth z_f (0 = lit); visibility is 1 - it.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..runtime.device import default_device, module_options
from ..runtime.parallel import launch_rows
from .moment_solvers import (
    DIVDIFF_FLOOR,
    LEADING_COEFF_FLOOR,
    OVERDARKENING_DIVISOR,
    PIVOT_FLOOR,
    adaptive_overestimation_weight,
    cubic_roots,
    hankel_pivots4,
    hankel_pivots6,
    interpolation_dot,
    msm4_bounds,
    msm4_distribution,
    msm4_interpolated_shadow_intensity,
    msm4_kernel_polynomial,
    msm4_shadow_intensity,
    msm6_bounds,
    msm6_distribution,
    msm6_interpolated_shadow_intensity,
    msm6_kernel_polynomial,
    msm6_shadow_intensity,
    msm6_visibility,
    quadratic_roots,
    scale_shadow_intensity,
    two_depth_distribution,
)
from .moment_storage import (
    BIAS_VECTOR4_FLOAT32,
    BIAS_VECTOR4_QUANTIZED,
    BIAS_VECTOR6,
    DEPTH_LIMIT,
    MOMENT_BIAS4_FLOAT32,
    MOMENT_BIAS4_SAT_UINT32,
    MOMENT_BIAS4_UNORM16,
    MOMENT_BIAS6_FLOAT32,
    MOMENT_BIAS6_UNORM10,
    MOMENT_BIAS6_UNORM16,
    STORAGE4_FLOAT32,
    STORAGE4_UNORM16,
    STORAGE6_FLOAT32,
    STORAGE6_UNORM10,
    STORAGE6_UNORM16,
    THETA4_MATRIX,
    THETA4_OFFSET,
    THETA6_EVEN_MATRIX,
    THETA6_EVEN_OFFSET,
    THETA6_ODD_MATRIX,
    THETA6_ODD_OFFSET,
    UNORM10_MASK,
    UNORM_BITS_STORAGE4_UNORM16,
    UNORM_BITS_STORAGE6_UNORM10,
    UNORM_BITS_STORAGE6_UNORM16,
    bias_moments4,
    bias_moments6,
    bias_vector4,
    inverse_quantization_transform4,
    inverse_quantization_transform6,
    load_biased_moments4,
    load_biased_moments6,
    load_moments4,
    load_moments6,
    moment_bias4,
    moment_bias6,
    moments4_from_depth,
    moments6_from_depth,
    pack_unorm10x6,
    quantization_transform4,
    quantization_transform6,
    sanitize_depth,
    sanitize_moments4,
    sanitize_moments6,
    store_moments4,
    store_moments6,
    unorm_decode,
    unorm_encode,
    unorm_round,
    unorm_round4,
    unpack_unorm10,
    vec6,
)

module_options()

__all__ = [
    "vec6", "STORAGE4_UNORM16", "STORAGE4_FLOAT32", "STORAGE6_UNORM10", "STORAGE6_UNORM16", "STORAGE6_FLOAT32",
    "UNORM_BITS_STORAGE4_UNORM16", "UNORM_BITS_STORAGE6_UNORM10", "UNORM_BITS_STORAGE6_UNORM16",
    "MOMENT_BIAS4_UNORM16", "MOMENT_BIAS4_FLOAT32", "MOMENT_BIAS4_SAT_UINT32", "MOMENT_BIAS6_UNORM10",
    "MOMENT_BIAS6_UNORM16", "MOMENT_BIAS6_FLOAT32", "BIAS_VECTOR4_FLOAT32", "BIAS_VECTOR4_QUANTIZED",
    "BIAS_VECTOR6", "DEPTH_LIMIT", "THETA4_MATRIX", "THETA4_OFFSET", "THETA6_ODD_MATRIX", "THETA6_ODD_OFFSET",
    "THETA6_EVEN_MATRIX", "THETA6_EVEN_OFFSET", "moments4_from_depth", "moments6_from_depth",
    "quantization_transform4", "inverse_quantization_transform4", "quantization_transform6",
    "inverse_quantization_transform6", "unorm_round", "unorm_round4", "unorm_encode", "unorm_decode",
    "pack_unorm10x6", "unpack_unorm10", "UNORM10_MASK", "store_moments4", "load_moments4",
    "store_moments6", "load_moments6", "bias_moments4", "bias_moments6", "moment_bias4", "bias_vector4",
    "moment_bias6", "load_biased_moments4", "load_biased_moments6", "sanitize_moments4", "sanitize_moments6",
    "sanitize_depth",
    "OVERDARKENING_DIVISOR", "PIVOT_FLOOR", "LEADING_COEFF_FLOOR", "DIVDIFF_FLOOR", "quadratic_roots",
    "cubic_roots", "hankel_pivots4", "hankel_pivots6", "msm4_kernel_polynomial", "msm6_kernel_polynomial",
    "msm4_distribution", "msm4_bounds", "msm4_shadow_intensity", "msm4_interpolated_shadow_intensity",
    "interpolation_dot", "msm6_visibility", "msm6_bounds", "msm6_shadow_intensity",
    "msm6_interpolated_shadow_intensity", "msm6_distribution", "two_depth_distribution",
    "adaptive_overestimation_weight", "scale_shadow_intensity",
    "moments4", "moments6", "shadow_intensity4", "bounds4", "shadow_intensity6", "bounds6",
    "two_depths_from_moments3", "apply_quantization_transform4", "quantize4", "dequantize4",
    "apply_quantization_transform6", "quantize6", "dequantize6", "solve_cubic",
]




@wp.kernel
def _moments4_kernel(z: wp.array(dtype=wp.float32), out: wp.array(dtype=wp.vec4), offset: int):
    i = wp.tid() + offset
    out[i] = moments4_from_depth(z[i])


@wp.kernel
def _moments6_kernel(z: wp.array(dtype=wp.float32), out: wp.array(dtype=vec6), offset: int):
    i = wp.tid() + offset
    out[i] = moments6_from_depth(z[i])


@wp.kernel
def _msm4_kernel(b: wp.array(dtype=wp.vec4), z_f: wp.array(dtype=wp.float32), beta: wp.array(dtype=wp.float32),
                 alpha: float, b_star: wp.vec4, out: wp.array(dtype=wp.vec3), offset: int):
    i = wp.tid() + offset
    bb = bias_moments4(b[i], alpha, b_star)
    bounds = msm4_bounds(bb, z_f[i])
    out[i] = wp.vec3(bounds[0], bounds[1], msm4_interpolated_shadow_intensity(bb, z_f[i], beta[i]))


@wp.kernel
def _msm6_kernel(b: wp.array(dtype=vec6), z_f: wp.array(dtype=wp.float32), beta: wp.array(dtype=wp.float32),
                 alpha: float, b_star: vec6, out: wp.array(dtype=wp.vec3), offset: int):
    i = wp.tid() + offset
    bb = bias_moments6(b[i], alpha, b_star)
    bounds = msm6_bounds(bb, z_f[i])
    out[i] = wp.vec3(bounds[0], bounds[1], msm6_interpolated_shadow_intensity(bb, z_f[i], beta[i]))


@wp.kernel
def _two_depths_kernel(b: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec4), offset: int):
    i = wp.tid() + offset
    depths, weights = two_depth_distribution(b[i])
    out[i] = wp.vec4(depths[0], depths[1], weights[0], weights[1])


_OP_THETA = wp.constant(0)
_OP_THETA_INVERSE = wp.constant(1)
_OP_STORE = wp.constant(2)
_OP_LOAD = wp.constant(3)


@wp.kernel
def _transform4_kernel(b: wp.array(dtype=wp.vec4), op: int, storage: int, out: wp.array(dtype=wp.vec4), offset: int):
    i = wp.tid() + offset
    if op == _OP_THETA:
        out[i] = quantization_transform4(b[i])
    elif op == _OP_THETA_INVERSE:
        out[i] = inverse_quantization_transform4(b[i])
    elif op == _OP_STORE:
        out[i] = store_moments4(b[i], storage)
    else:
        out[i] = load_moments4(b[i], storage)


@wp.kernel
def _transform6_kernel(b: wp.array(dtype=vec6), op: int, storage: int, out: wp.array(dtype=vec6), offset: int):
    i = wp.tid() + offset
    if op == _OP_THETA:
        out[i] = quantization_transform6(b[i])
    elif op == _OP_THETA_INVERSE:
        out[i] = inverse_quantization_transform6(b[i])
    elif op == _OP_STORE:
        out[i] = store_moments6(b[i], storage)
    else:
        out[i] = load_moments6(b[i], storage)


@wp.kernel
def _cubic_kernel(c: wp.array(dtype=wp.vec4), out: wp.array(dtype=wp.vec3), offset: int):
    i = wp.tid() + offset
    out[i] = cubic_roots(c[i])



_MIN_CHUNK = 4096
_STORAGE4 = {int(STORAGE4_UNORM16): "STORAGE4_UNORM16", int(STORAGE4_FLOAT32): "STORAGE4_FLOAT32"}
_STORAGE6 = {int(STORAGE6_UNORM10): "STORAGE6_UNORM10", int(STORAGE6_UNORM16): "STORAGE6_UNORM16",
             int(STORAGE6_FLOAT32): "STORAGE6_FLOAT32"}
_MOMENT_KERNELS = {4: (wp.vec4, _moments4_kernel), 6: (vec6, _moments6_kernel)}
_SHADOW_KERNELS = {4: (wp.vec4, _msm4_kernel), 6: (vec6, _msm6_kernel)}


def _vectors(x, length: int, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float32)
    if a.ndim == 0 or a.shape[-1] != length:
        raise ValueError(f"{name}: expected an array whose last axis has length {length}, got shape {a.shape}")
    return np.ascontiguousarray(a)


def _per_item(x, shape: tuple, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float32)
    try:
        return np.ascontiguousarray(np.broadcast_to(a, shape)).reshape(-1)
    except ValueError:
        raise ValueError(f"{name}: shape {a.shape} does not broadcast to {shape}") from None


def _fraction(value, name: str, allow_array: bool = False, tol: float = 0.0):
    """A weight in [0, 1] (within tol of float32 rounding), clipped."""
    a = np.asarray(value, dtype=np.float64)
    if a.ndim and not allow_array:
        raise ValueError(f"{name}: expected a scalar, got shape {a.shape}")
    if not np.all(np.isfinite(a)) or np.any(a < -tol) or np.any(a > 1.0 + tol):
        raise ValueError(f"{name}: must lie in [0, 1], got {value!r}")
    return np.clip(a, 0.0, 1.0)


def _launch(kernel, n: int, inputs: list, device) -> None:
    launch_rows(kernel, n, inputs, device=device, min_chunk=_MIN_CHUNK)


def _moments(z, m: int, device) -> np.ndarray:
    device = default_device(device)
    dtype, kernel = _MOMENT_KERNELS[m]
    zz = np.ascontiguousarray(np.asarray(z, dtype=np.float32))
    n = zz.size
    out = wp.zeros(n, dtype=dtype, device=device)
    _launch(kernel, n, [wp.array(zz.reshape(-1), dtype=wp.float32, device=device), out], device)
    return out.numpy().reshape(zz.shape + (m,))


def moments4(z, device=None) -> np.ndarray:
    """b(z) = (z, z^2, z^3, z^4) of signed depths z (any shape) -> float32 array of shape z.shape + (4,)."""
    return _moments(z, 4, device)


def moments6(z, device=None) -> np.ndarray:
    """b(z) = (z, ..., z^6) of signed depths z (any shape) -> float32 array of shape z.shape + (6,)."""
    return _moments(z, 6, device)


def _msm(b, z_f, alpha, bias_vector, beta, m: int, device) -> np.ndarray:
    """(lower bound, upper bound, interpolated intensity) of Algorithm 1 with m in {4, 6} moments, after biasing."""
    device = default_device(device)
    dtype, kernel = _SHADOW_KERNELS[m]
    bb = _vectors(b, m, "b")
    _fraction(alpha, "alpha")
    beta = _fraction(beta, "beta", allow_array=True, tol=1e-6)
    bstar = _vectors(bias_vector, m, "bias_vector").reshape(-1)
    if bstar.size != m:
        raise ValueError(f"bias_vector: expected {m} values (b*_1..b*_{m}), got {bstar.size}")
    shape = bb.shape[:-1]
    n = int(np.prod(shape, dtype=np.int64))
    zf = _per_item(z_f, shape, "z_f")
    bt = _per_item(beta, shape, "beta")
    out = wp.zeros(n, dtype=wp.vec3, device=device)
    _launch(kernel, n, [wp.array(bb.reshape(-1, m), dtype=dtype, device=device),
                        wp.array(zf, dtype=wp.float32, device=device),
                        wp.array(bt, dtype=wp.float32, device=device), float(alpha), dtype(*bstar), out], device)
    return out.numpy().reshape(shape + (3,))


def shadow_intensity4(b, z_f, alpha=MOMENT_BIAS4_FLOAT32, bias_vector=BIAS_VECTOR4_FLOAT32, beta=1.0,
                      device=None) -> np.ndarray:
    """Four-moment shadow intensity Z(z < z_f) in [0, 1] (Algorithm 1), after biasing (Sec. 2.5).

    Args:
        b: unbiased canonical moments (..., 4) of signed depths.
        z_f: fragment depths, broadcastable to b.shape[:-1].
        alpha: moment bias alpha_b in [0, 1] (MOMENT_BIAS4_*; 0: none).
        bias_vector: b* (BIAS_VECTOR4_FLOAT32, or BIAS_VECTOR4_QUANTIZED after Theta_4*).
        beta: overestimation weight(s) in [0, 1]: 1 the lower bound (Eq. 1), 0 the upper, Sec. 5.3.1 between.
        device: Warp device.

    Returns:
        float32 array of shape b.shape[:-1].

    Raises:
        ValueError: wrong shapes, alpha or beta outside [0, 1].
    """
    return _msm(b, z_f, alpha, bias_vector, beta, 4, device)[..., 2]


def bounds4(b, z_f, alpha=0.0, bias_vector=BIAS_VECTOR4_FLOAT32, device=None) -> np.ndarray:
    """Sharp (lower, upper) bounds of Z(z < z_f) from four moments (biased first when alpha > 0): (..., 2)."""
    return _msm(b, z_f, alpha, bias_vector, 1.0, 4, device)[..., :2]


def shadow_intensity6(b, z_f, alpha=MOMENT_BIAS6_FLOAT32, bias_vector=BIAS_VECTOR6, beta=1.0,
                      device=None) -> np.ndarray:
    """Six-moment shadow intensity in [0, 1]: 1 - visibility of Sec. 5.4.2, after biasing.

    Args:
        b, z_f, alpha, bias_vector, beta, device: as :func:`shadow_intensity4`, with six moments (MOMENT_BIAS6_*,
            BIAS_VECTOR6).
    """
    return _msm(b, z_f, alpha, bias_vector, beta, 6, device)[..., 2]


def bounds6(b, z_f, alpha=0.0, bias_vector=BIAS_VECTOR6, device=None) -> np.ndarray:
    """Sharp (lower, upper) bounds of Z(z < z_f) from six moments: float32 array b.shape[:-1] + (2,)."""
    return _msm(b, z_f, alpha, bias_vector, 1.0, 6, device)[..., :2]


def two_depths_from_moments3(b, device=None) -> tuple[np.ndarray, np.ndarray]:
    """Algorithm 2 on moments (..., k), k in {3, 4, 6}, using (b_1, b_2, b_3).

    Returns:
        (depths, weights), float32 arrays of shape b.shape[:-1] + (2,), depths ascending, weights summing to 1.
    """
    device = default_device(device)
    a = np.asarray(b, dtype=np.float32)
    if a.ndim == 0 or a.shape[-1] not in (3, 4, 6):
        raise ValueError(f"b: expected moments with last axis 3, 4 or 6 (b_1, b_2, b_3 first), got shape {a.shape}")
    shape = a.shape[:-1]
    b3 = np.ascontiguousarray(a[..., :3]).reshape(-1, 3)
    n = b3.shape[0]
    out = wp.zeros(n, dtype=wp.vec4, device=device)
    _launch(_two_depths_kernel, n, [wp.array(b3, dtype=wp.vec3, device=device), out], device)
    res = out.numpy().reshape(shape + (4,))
    return res[..., :2].copy(), res[..., 2:].copy()


def _storage(storage, table: dict, name: str) -> int:
    if int(storage) not in table:
        raise ValueError(f"storage: unknown {name} storage mode {storage!r}; use one of {sorted(table.values())}")
    return int(storage)


def _transform(b, length: int, kernel, dtype, op: int, storage: int, device) -> np.ndarray:
    device = default_device(device)
    bb = _vectors(b, length, "b" if op in (0, 2) else "texels")
    flat = bb.reshape(-1, length)
    n = flat.shape[0]
    out = wp.zeros(n, dtype=dtype, device=device)
    _launch(kernel, n, [wp.array(flat, dtype=dtype, device=device), op, storage, out], device)
    return out.numpy().reshape(bb.shape)


def apply_quantization_transform4(b, inverse: bool = False, device=None) -> np.ndarray:
    """Theta_4* of Eq. (3) (or its inverse) applied to (..., 4) arrays; float32."""
    return _transform(b, 4, _transform4_kernel, wp.vec4, _OP_THETA_INVERSE if inverse else _OP_THETA, 0, device)


def quantize4(b, storage=STORAGE4_UNORM16, device=None) -> np.ndarray:
    """Texel values (..., 4) float32 after storing canonical moments in ``storage`` (STORAGE4_*)."""
    return _transform(b, 4, _transform4_kernel, wp.vec4, _OP_STORE, _storage(storage, _STORAGE4, "4-moment"), device)


def dequantize4(texels, storage=STORAGE4_UNORM16, device=None) -> np.ndarray:
    """Canonical (unbiased) moments (..., 4) from texel values of ``storage`` (inverse of :func:`quantize4`)."""
    storage = _storage(storage, _STORAGE4, "4-moment")
    return _transform(texels, 4, _transform4_kernel, wp.vec4, _OP_LOAD, storage, device)


def apply_quantization_transform6(b, inverse: bool = False, device=None) -> np.ndarray:
    """Theta_6* of Sec. 5.4.3 (or its inverse) on (..., 6) arrays; texel order (q_odd, q_even); float32."""
    return _transform(b, 6, _transform6_kernel, vec6, _OP_THETA_INVERSE if inverse else _OP_THETA, 0, device)


def quantize6(b, storage=STORAGE6_UNORM16, device=None) -> np.ndarray:
    """Texel values (..., 6) float32 after storing canonical six moments in ``storage`` (STORAGE6_*)."""
    return _transform(b, 6, _transform6_kernel, vec6, _OP_STORE, _storage(storage, _STORAGE6, "6-moment"), device)


def dequantize6(texels, storage=STORAGE6_UNORM16, device=None) -> np.ndarray:
    """Canonical (unbiased) six moments (..., 6) from texel values of ``storage`` (inverse of :func:`quantize6`)."""
    return _transform(texels, 6, _transform6_kernel, vec6, _OP_LOAD, _storage(storage, _STORAGE6, "6-moment"), device)


def solve_cubic(coeffs, device=None) -> np.ndarray:
    """Roots (ascending, (..., 3)) of c_0 + c_1 z + c_2 z^2 + c_3 z^3, coeffs (..., 4) (:func:`cubic_roots`)."""
    device = default_device(device)
    c = _vectors(coeffs, 4, "coeffs")
    flat = c.reshape(-1, 4)
    n = flat.shape[0]
    out = wp.zeros(n, dtype=wp.vec3, device=device)
    _launch(_cubic_kernel, n, [wp.array(flat, dtype=wp.vec4, device=device), out], device)
    return out.numpy().reshape(c.shape[:-1] + (3,))
