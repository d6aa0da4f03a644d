"""Moment vectors, their storage and their biasing (Peters et al. 2017, "Improved Moment Shadow Maps ...", JCGT 6(1)):
b(z) (Sec. 2.2.1, 5.4), the quantization transforms Theta_4*, Theta_6* and n-bit unorm storage (Sec. 2.4, Eq. 3,
Sec. 5.4.3), texel codes, biasing (Sec. 2.5) and sanitizing. Re-exported by :mod:`warpscatter.shadows.moments` (its
docstring states the conventions); the storage modes' table is in docs/design/shadows-scene.md.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ..runtime.device import module_options

module_options()

#: Six float32 moments (b_1, ..., b_6), the 6-moment analogue of ``wp.vec4``.
vec6 = wp.types.vector(length=6, dtype=wp.float32)

# storage modes: Theta* in n-bit unorm channels (UNORM*), or canonical moments (FLOAT32)
STORAGE4_UNORM16 = wp.constant(0)
STORAGE4_FLOAT32 = wp.constant(1)
STORAGE6_UNORM10 = wp.constant(0)
STORAGE6_UNORM16 = wp.constant(1)
STORAGE6_FLOAT32 = wp.constant(2)

UNORM_BITS_STORAGE4_UNORM16 = wp.constant(16)
UNORM_BITS_STORAGE6_UNORM10 = wp.constant(10)
UNORM_BITS_STORAGE6_UNORM16 = wp.constant(16)

# moment bias alpha_b per storage mode (Peters 2017 Sec. 2.5; SAT: Sec. 4.2, n_t = 784; six moments: Sec. 5.4.3)
MOMENT_BIAS4_UNORM16 = wp.constant(6.0e-5)
MOMENT_BIAS4_FLOAT32 = wp.constant(3.0e-7)
MOMENT_BIAS4_SAT_UINT32 = wp.constant(6.0e-7)
MOMENT_BIAS6_UNORM10 = wp.constant(4.0e-3)
MOMENT_BIAS6_UNORM16 = wp.constant(8.0e-5)
MOMENT_BIAS6_FLOAT32 = wp.constant(5.0e-6)

# worst-case bias vectors b* without b_0* = 1: Sec. 2.5 (float32; QUANTIZED: through Theta_4*), Sec. 5.4.3
BIAS_VECTOR4_FLOAT32 = wp.constant(wp.vec4(0.0, 0.375, 0.0, 0.375))
BIAS_VECTOR4_QUANTIZED = wp.constant(wp.vec4(0.0, 0.628, 0.0, 0.628))
BIAS_VECTOR6 = wp.constant(vec6(0.0, 0.5566, 0.0, 0.489, 0.0, 0.47869382))

DEPTH_LIMIT = wp.constant(1.0e3)  # fragment depths are clamped to +-DEPTH_LIMIT (overflow guard)

_SQRT3 = math.sqrt(3.0)
#: Theta_4* of Eq. (3): q = THETA4_MATRIX @ (b_1, b_2, b_3, b_4) + THETA4_OFFSET.
THETA4_MATRIX = np.array(
    [[1.5, 0.0, -2.0, 0.0], [0.0, 4.0, 0.0, -4.0], [0.5 * _SQRT3, 0.0, -2.0 / 9.0 * _SQRT3, 0.0], [0.0, 0.5, 0.0, 0.5]]
)
THETA4_OFFSET = np.array([0.5, 0.0, 0.5, 0.0])
#: Theta_6* of Sec. 5.4.3 as printed, applied TRANSPOSED: q_odd = THETA6_ODD_MATRIX.T @ (b_1, b_3, b_5) + offset;
#: likewise q_even. A 6-moment texel is (q_odd, q_even).
THETA6_ODD_MATRIX = np.array(
    [[2.5, -1.87499864, 1.26583039], [-10.0, 4.20757543, -1.47644883], [8.0, -1.83257679, 0.71061660]]
)
THETA6_ODD_OFFSET = np.array([0.5, 0.5, 0.5])
THETA6_EVEN_MATRIX = np.array(
    [[4.0, 9.0, -0.57759806], [-4.0, -24.0, 4.61936648], [0.0, 16.0, -3.07953907]]
)
THETA6_EVEN_OFFSET = np.array([0.0, 0.0, 0.018888946])


def _mat22(m: np.ndarray):
    return wp.constant(wp.mat22(*[float(x) for x in m.flatten()]))


def _mat33(m: np.ndarray):
    return wp.constant(wp.mat33(*[float(x) for x in m.flatten()]))


# Theta_4* acts on odd and even moments separately (Fig. 3)
_T4_ODD = _mat22(THETA4_MATRIX[np.ix_([0, 2], [0, 2])])
_T4_EVEN = _mat22(THETA4_MATRIX[np.ix_([1, 3], [1, 3])])
_T4_ODD_INV = _mat22(np.linalg.inv(THETA4_MATRIX[np.ix_([0, 2], [0, 2])]))
_T4_EVEN_INV = _mat22(np.linalg.inv(THETA4_MATRIX[np.ix_([1, 3], [1, 3])]))
_T6_ODD = _mat33(THETA6_ODD_MATRIX.T)
_T6_EVEN = _mat33(THETA6_EVEN_MATRIX.T)
_T6_ODD_INV = _mat33(np.linalg.inv(THETA6_ODD_MATRIX.T))
_T6_EVEN_INV = _mat33(np.linalg.inv(THETA6_EVEN_MATRIX.T))
_T6_ODD_OFFSET = wp.constant(wp.vec3(*[float(x) for x in THETA6_ODD_OFFSET]))
_T6_EVEN_OFFSET = wp.constant(wp.vec3(*[float(x) for x in THETA6_EVEN_OFFSET]))



@wp.func
def moments4_from_depth(z: wp.float32) -> wp.vec4:
    """b(z) = (z, z^2, z^3, z^4) for a signed depth z in [-1, 1] (Sec. 2.2.1; b_0 = 1 not stored)."""
    z2 = z * z
    return wp.vec4(z, z2, z2 * z, z2 * z2)


@wp.func
def moments6_from_depth(z: wp.float32) -> vec6:
    """b(z) = (z, z^2, ..., z^6) for a signed depth z in [-1, 1] (Sec. 5.4)."""
    z2 = z * z
    z3 = z2 * z
    z4 = z2 * z2
    return vec6(z, z2, z3, z4, z4 * z, z3 * z3)



@wp.func
def quantization_transform4(b: wp.vec4) -> wp.vec4:
    """Theta_4*(b) of Eq. (3): canonical moments -> values in [0, 1]^4 for 16-bit storage."""
    odd = _T4_ODD @ wp.vec2(b[0], b[2]) + wp.vec2(0.5, 0.5)
    even = _T4_EVEN @ wp.vec2(b[1], b[3])
    return wp.vec4(odd[0], even[0], odd[1], even[1])


@wp.func
def inverse_quantization_transform4(q: wp.vec4) -> wp.vec4:
    """Theta_4*^-1(q): stored moments -> canonical moments (b_1, ..., b_4) (Eq. 3, D.2)."""
    odd = _T4_ODD_INV @ wp.vec2(q[0] - 0.5, q[2] - 0.5)
    even = _T4_EVEN_INV @ wp.vec2(q[1], q[3])
    return wp.vec4(odd[0], even[0], odd[1], even[1])


@wp.func
def quantization_transform6(b: vec6) -> vec6:
    """Theta_6*(b) of Sec. 5.4.3: canonical moments -> (q_odd, q_even) in [0, 1]^6 for fixed-point storage."""
    odd = _T6_ODD @ wp.vec3(b[0], b[2], b[4]) + _T6_ODD_OFFSET
    even = _T6_EVEN @ wp.vec3(b[1], b[3], b[5]) + _T6_EVEN_OFFSET
    return vec6(odd[0], odd[1], odd[2], even[0], even[1], even[2])


@wp.func
def inverse_quantization_transform6(q: vec6) -> vec6:
    """Theta_6*^-1(q): a texel (q_odd, q_even) -> canonical moments (b_1, ..., b_6)."""
    odd = _T6_ODD_INV @ (wp.vec3(q[0], q[1], q[2]) - _T6_ODD_OFFSET)
    even = _T6_EVEN_INV @ (wp.vec3(q[3], q[4], q[5]) - _T6_EVEN_OFFSET)
    return vec6(odd[0], even[0], odd[1], even[1], odd[2], even[2])


@wp.func
def unorm_encode(x: wp.float32, bits: wp.int32) -> wp.int32:
    """n-bit unorm code of x: round(clamp(x, 0, 1) (2^n - 1)); NaN -> 0 as on a GPU. ``bits`` in [1, 24]."""
    scale = wp.float32((1 << bits) - 1)
    xc = x
    if wp.isnan(xc):
        xc = 0.0
    xc = wp.clamp(xc, 0.0, 1.0)
    return int(wp.floor(xc * scale + 0.5))


@wp.func
def unorm_decode(code: wp.int32, bits: wp.int32) -> wp.float32:
    """Value of an n-bit unorm code: code / (2^n - 1) correctly rounded to float32, as a GPU's unorm fetch (a float64
    product with the reciprocal instead of a division: its error never changes the float32 rounding)."""
    return wp.float32(wp.float64(code) * (wp.float64(1.0) / wp.float64((1 << bits) - 1)))


@wp.func
def unorm_round(x: wp.float32, bits: wp.int32) -> wp.float32:
    """Value of x after storage in an n-bit unorm channel: ``unorm_decode(unorm_encode(x, bits), bits)``."""
    return unorm_decode(unorm_encode(x, bits), bits)


@wp.func
def unorm_round4(q: wp.vec4, bits: wp.int32) -> wp.vec4:
    """``unorm_round`` of each component: the value of q after storage in four n-bit unorm channels."""
    return wp.vec4(unorm_round(q[0], bits), unorm_round(q[1], bits), unorm_round(q[2], bits), unorm_round(q[3], bits))


@wp.func
def store_moments4(b: wp.vec4, storage: wp.int32) -> wp.vec4:
    """Texel contents after writing canonical moments b in a 4-moment storage mode (Sec. 2.3, 2.4)."""
    if storage == STORAGE4_UNORM16:
        return unorm_round4(quantization_transform4(b), UNORM_BITS_STORAGE4_UNORM16)
    return b


@wp.func
def load_moments4(texel: wp.vec4, storage: wp.int32) -> wp.vec4:
    """Canonical moments (unbiased) from a (possibly filtered) texel of a 4-moment storage mode (D.2)."""
    if storage == STORAGE4_UNORM16:
        return inverse_quantization_transform4(texel)
    return texel


@wp.func
def store_moments6(b: vec6, storage: wp.int32) -> vec6:
    """Texel contents after writing canonical moments b in a 6-moment storage mode (Sec. 5.4.3)."""
    if storage == STORAGE6_FLOAT32:
        return b
    bits = UNORM_BITS_STORAGE6_UNORM16
    if storage == STORAGE6_UNORM10:
        bits = UNORM_BITS_STORAGE6_UNORM10
    q = quantization_transform6(b)
    return vec6(unorm_round(q[0], bits), unorm_round(q[1], bits), unorm_round(q[2], bits), unorm_round(q[3], bits),
                unorm_round(q[4], bits), unorm_round(q[5], bits))


@wp.func
def load_moments6(texel: vec6, storage: wp.int32) -> vec6:
    """Canonical moments (unbiased) from a (possibly filtered) texel of a 6-moment storage mode (D.5)."""
    if storage == STORAGE6_FLOAT32:
        return texel
    return inverse_quantization_transform6(texel)


# Texel codes (layout: design notes): decoding gives exactly the emulated storage's float32 value (unorm_round).
UNORM10_MASK = wp.constant(wp.uint64(1023))


@wp.func
def pack_unorm10x6(q: vec6) -> wp.uint64:
    """A STORAGE6_UNORM10 texel: the six 10-bit codes of q (:func:`unorm_encode`) in one 64-bit word (60 bits used)."""
    word = wp.uint64(0)
    for k in range(6):
        word = word | (wp.uint64(unorm_encode(q[k], UNORM_BITS_STORAGE6_UNORM10)) << wp.uint64(10 * k))
    return word


@wp.func
def unpack_unorm10(word: wp.uint64, k: wp.int32) -> wp.float32:
    """Value of channel k (0..5) of a packed STORAGE6_UNORM10 texel (:func:`unorm_decode` of its 10-bit code)."""
    return unorm_decode(wp.int32((word >> wp.uint64(10 * k)) & UNORM10_MASK), UNORM_BITS_STORAGE6_UNORM10)



@wp.func
def bias_moments4(b: wp.vec4, alpha: wp.float32, b_star: wp.vec4) -> wp.vec4:
    """b' = (1 - alpha) b + alpha b* (Sec. 2.5) with the storage mode's BIAS_VECTOR4_* and MOMENT_BIAS4_*."""
    return (1.0 - alpha) * b + alpha * b_star


@wp.func
def bias_moments6(b: vec6, alpha: wp.float32, b_star: vec6) -> vec6:
    """b' = (1 - alpha) b + alpha b* for six moments (Sec. 5.4.3) with BIAS_VECTOR6 and MOMENT_BIAS6_*."""
    return (1.0 - alpha) * b + alpha * b_star


@wp.func
def moment_bias4(storage: wp.int32) -> wp.float32:
    """alpha_b of a 4-moment storage mode (Sec. 2.5)."""
    if storage == STORAGE4_UNORM16:
        return MOMENT_BIAS4_UNORM16
    return MOMENT_BIAS4_FLOAT32


@wp.func
def bias_vector4(storage: wp.int32) -> wp.vec4:
    """Worst-case b* of a 4-moment storage mode (Sec. 2.5)."""
    if storage == STORAGE4_UNORM16:
        return BIAS_VECTOR4_QUANTIZED
    return BIAS_VECTOR4_FLOAT32


@wp.func
def moment_bias6(storage: wp.int32) -> wp.float32:
    """alpha_b of a 6-moment storage mode (Sec. 5.4.3)."""
    if storage == STORAGE6_UNORM10:
        return MOMENT_BIAS6_UNORM10
    if storage == STORAGE6_UNORM16:
        return MOMENT_BIAS6_UNORM16
    return MOMENT_BIAS6_FLOAT32


@wp.func
def load_biased_moments4(texel: wp.vec4, storage: wp.int32) -> wp.vec4:
    """Texel -> canonical moments biased with the storage mode's alpha_b and b*, ready for Algorithm 1 (D.2)."""
    return bias_moments4(load_moments4(texel, storage), moment_bias4(storage), bias_vector4(storage))


@wp.func
def load_biased_moments6(texel: vec6, storage: wp.int32) -> vec6:
    """Texel -> canonical six moments biased with the storage mode's alpha_b and BIAS_VECTOR6 (D.5)."""
    return bias_moments6(load_moments6(texel, storage), moment_bias6(storage), BIAS_VECTOR6)


@wp.func
def _sanitize_moment(x: wp.float32, fallback: wp.float32, even: wp.bool) -> wp.float32:
    v = x
    if wp.isnan(v):
        v = fallback
    lo = -1.0
    if even:
        lo = 0.0
    return wp.clamp(v, lo, 1.0)


@wp.func
def sanitize_moments4(b: wp.vec4) -> wp.vec4:
    """NaN components -> BIAS_VECTOR4_FLOAT32's; clamp to the moment range of depths in [-1, 1]. Valid b unchanged."""
    s = BIAS_VECTOR4_FLOAT32
    return wp.vec4(_sanitize_moment(b[0], s[0], False), _sanitize_moment(b[1], s[1], True),
                   _sanitize_moment(b[2], s[2], False), _sanitize_moment(b[3], s[3], True))


@wp.func
def sanitize_moments6(b: vec6) -> vec6:
    """NaN components -> BIAS_VECTOR6's; clamp to the moment range of depths in [-1, 1]. Valid b unchanged."""
    s = BIAS_VECTOR6
    return vec6(_sanitize_moment(b[0], s[0], False), _sanitize_moment(b[1], s[1], True),
                _sanitize_moment(b[2], s[2], False), _sanitize_moment(b[3], s[3], True),
                _sanitize_moment(b[4], s[4], False), _sanitize_moment(b[5], s[5], True))


@wp.func
def sanitize_depth(z: wp.float32) -> wp.float32:
    """NaN -> 0; clamp to [-DEPTH_LIMIT, DEPTH_LIMIT] (an overflow guard; signed depths live in [-1, 1])."""
    if wp.isnan(z):
        return 0.0
    return wp.clamp(z, -DEPTH_LIMIT, DEPTH_LIMIT)
