"""Moment vectors, their storage and their biasing (Peters et al. 2017, "Improved Moment Shadow Maps ...", JCGT 6(1)).

Part of the moment shadow mapping math re-exported by :mod:`warpscatter.shadows.moments` (use that module; its
docstring states the conventions). Here, in the paper's terms:

* ``moments4_from_depth`` / ``moments6_from_depth``: b(z) = (z^j)_j (Sec. 2.2.1, Sec. 5.4).
* Quantization (Sec. 2.4, Eq. 3; Sec. 5.4.3): ``quantization_transform4/6`` (Theta_4*, Theta_6*) and inverses,
  ``unorm_round`` / ``unorm_round4`` (n-bit fixed point and back), ``store_moments4/6`` and ``load_moments4/6``
  emulating the storage modes below.
* Texel codes (what a texture of a fixed-point mode really holds; underscored until the :mod:`.moments` facade
  re-exports them): ``unorm_encode`` / ``unorm_decode`` (one n-bit code and its float32 value, ``unorm_round`` =
  decode o encode), ``pack_unorm10x6`` / ``unpack_unorm10`` (the six 10-bit codes of a 64-bit STORAGE6_UNORM10
  texel). The prefiltered scattering textures (:mod:`warpscatter.scattering.prefix_sums`) store these codes.
* Biasing (Sec. 2.5, Sec. 5.4.3): ``bias_moments4/6`` with the worst-case bias vectors b* and the moment bias
  alpha_b of each storage mode (module constants), ``load_biased_moments4/6``.
* Sanitizing: ``sanitize_moments4/6`` and ``sanitize_depth``, applied by every shadow function of
  :mod:`.moment_solvers` before Algorithm 1 (a NaN moment becomes the float32 bias vector's component, moments are
  clamped to the range of moments of depths in [-1, 1], a NaN depth becomes 0, infinite ones +-DEPTH_LIMIT).

Storage modes (bits per texel as in the paper):

=====================  ===========================================================  =========  ===================
mode                   texel contents                                               alpha_b    b* (b_1..b_m)
=====================  ===========================================================  =========  ===================
STORAGE4_UNORM16       64 bits: Theta_4*(b) in 4 x 16-bit unorm (Sec. 2.4, 2.5)     6e-5       (0,.628,0,.628)
STORAGE4_FLOAT32       128 bits: canonical b in 4 x float32 (Sec. 2.3, 2.5)          3e-7       (0,.375,0,.375)
(summed-area table)    Theta_4*(b) as uint32 sums, n_t = 784 texels (Sec. 4.2, D.4)  6e-7       (0,.628,0,.628)
STORAGE6_UNORM10       64 bits (60 used): Theta_6*(b) in 6 x 10-bit unorm            4e-3       BIAS_VECTOR6
STORAGE6_UNORM16       96 bits: Theta_6*(b) in 6 x 16-bit unorm                      8e-5       BIAS_VECTOR6
STORAGE6_FLOAT32       192 bits: canonical b in 6 x float32                          5e-6       BIAS_VECTOR6
=====================  ===========================================================  =========  ===================

Sec. 5.4.3 does not say whether the 192-bit mode applies Theta_6*; following Sec. 2.3 (a quantization transform
gains nothing when the moments are transformed back in float32 anyway) it stores canonical moments here.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ..wpinit import module_options

module_options()

#: Six float32 moments (b_1, ..., b_6), the 6-moment analogue of ``wp.vec4``.
vec6 = wp.types.vector(length=6, dtype=wp.float32)

# ---- Storage modes ----
STORAGE4_UNORM16 = wp.constant(0)  # 64 bits per texel: Theta_4*(b) in four 16-bit unorm channels
STORAGE4_FLOAT32 = wp.constant(1)  # 128 bits per texel: canonical moments in four float32 channels
STORAGE6_UNORM10 = wp.constant(0)  # 64 bits per texel (60 used): Theta_6*(b) in six 10-bit unorm channels
STORAGE6_UNORM16 = wp.constant(1)  # 96 bits per texel: Theta_6*(b) in six 16-bit unorm channels
STORAGE6_FLOAT32 = wp.constant(2)  # 192 bits per texel: canonical moments in six float32 channels

#: Bits per fixed-point channel of each fixed-point storage mode.
UNORM_BITS_STORAGE4_UNORM16 = wp.constant(16)
UNORM_BITS_STORAGE6_UNORM10 = wp.constant(10)
UNORM_BITS_STORAGE6_UNORM16 = wp.constant(16)

# ---- Moment bias alpha_b per storage mode (Peters 2017 Sec. 2.5, 4.2, 5.4.3) ----
MOMENT_BIAS4_UNORM16 = wp.constant(6.0e-5)  # Sec. 2.5, 64-bit MSM with Theta_4*
MOMENT_BIAS4_FLOAT32 = wp.constant(3.0e-7)  # Sec. 2.5, 128-bit MSM, signed depth, no transform
MOMENT_BIAS4_SAT_UINT32 = wp.constant(6.0e-7)  # Sec. 4.2 / D.4, uint32 summed-area table, n_t = 784 texels
MOMENT_BIAS6_UNORM10 = wp.constant(4.0e-3)  # Sec. 5.4.3, 6 x 10 bits
MOMENT_BIAS6_UNORM16 = wp.constant(8.0e-5)  # Sec. 5.4.3, 6 x 16 bits
MOMENT_BIAS6_FLOAT32 = wp.constant(5.0e-6)  # Sec. 5.4.3, 6 x float32

# ---- Worst-case bias vectors b* (b_0* = 1 omitted) ----
#: Sec. 2.5, moments stored without quantization transform (float32): b* = (1, 0, 0.375, 0, 0.375).
BIAS_VECTOR4_FLOAT32 = wp.constant(wp.vec4(0.0, 0.375, 0.0, 0.375))
#: Sec. 2.5, moments stored through Theta_4* (64 bits, summed-area tables): b* = (1, 0, 0.628, 0, 0.628).
BIAS_VECTOR4_QUANTIZED = wp.constant(wp.vec4(0.0, 0.628, 0.0, 0.628))
#: Sec. 5.4.3, six moments (all storage modes): b* = (1, 0, 0.5566, 0, 0.489, 0, 0.47869382).
BIAS_VECTOR6 = wp.constant(vec6(0.0, 0.5566, 0.0, 0.489, 0.0, 0.47869382))

# ---- Numerical guard (sanitize_depth) ----
DEPTH_LIMIT = wp.constant(1.0e3)  # fragment depths are clamped to +-DEPTH_LIMIT (overflow guard)

# ---- Quantization transforms (host-side float64 definitions, float32 constants for kernels) ----
_SQRT3 = math.sqrt(3.0)
#: Theta_4* of Eq. (3): q = THETA4_MATRIX @ (b_1, b_2, b_3, b_4) + THETA4_OFFSET.
THETA4_MATRIX = np.array(
    [[1.5, 0.0, -2.0, 0.0], [0.0, 4.0, 0.0, -4.0], [0.5 * _SQRT3, 0.0, -2.0 / 9.0 * _SQRT3, 0.0], [0.0, 0.5, 0.0, 0.5]]
)
THETA4_OFFSET = np.array([0.5, 0.0, 0.5, 0.0])
#: Theta_6* of Sec. 5.4.3 as printed; it applies the TRANSPOSES: q_odd = THETA6_ODD_MATRIX.T @ (b_1, b_3, b_5)
#: + THETA6_ODD_OFFSET, q_even = THETA6_EVEN_MATRIX.T @ (b_2, b_4, b_6) + THETA6_EVEN_OFFSET. A 6-moment texel is
#: (q_odd, q_even), in this order.
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


# Theta_4* acts on odd and even moments separately (Fig. 3): 2x2 blocks and their float64 inverses.
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


# ---------------------------------------------------------------------------------------------------------------------
# Moment vectors
# ---------------------------------------------------------------------------------------------------------------------


@wp.func
def moments4_from_depth(z: wp.float32) -> wp.vec4:
    """b(z) = (z, z^2, z^3, z^4) for a signed depth z in [-1, 1]."""
    # Peters 2017, Sec. 2.2.1 (b_0 = 1 is not stored)
    z2 = z * z
    return wp.vec4(z, z2, z2 * z, z2 * z2)


@wp.func
def moments6_from_depth(z: wp.float32) -> vec6:
    """b(z) = (z, z^2, ..., z^6) for a signed depth z in [-1, 1]."""
    # Peters 2017, Sec. 2.2.1 with m = 6 (Sec. 5.4)
    z2 = z * z
    z3 = z2 * z
    z4 = z2 * z2
    return vec6(z, z2, z3, z4, z4 * z, z3 * z3)


# ---------------------------------------------------------------------------------------------------------------------
# Quantization and storage emulation
# ---------------------------------------------------------------------------------------------------------------------


@wp.func
def quantization_transform4(b: wp.vec4) -> wp.vec4:
    """Theta_4*(b): canonical moments -> values in [0, 1]^4 for 16-bit storage."""
    # Peters 2017, Eq. (3): odd and even moments are transformed separately
    odd = _T4_ODD @ wp.vec2(b[0], b[2]) + wp.vec2(0.5, 0.5)
    even = _T4_EVEN @ wp.vec2(b[1], b[3])
    return wp.vec4(odd[0], even[0], odd[1], even[1])


@wp.func
def inverse_quantization_transform4(q: wp.vec4) -> wp.vec4:
    """Theta_4*^-1(q): stored (transformed) moments -> canonical moments (b_1, ..., b_4)."""
    # Peters 2017, Eq. (3) inverted (D.2 "revert any quantization transform")
    odd = _T4_ODD_INV @ wp.vec2(q[0] - 0.5, q[2] - 0.5)
    even = _T4_EVEN_INV @ wp.vec2(q[1], q[3])
    return wp.vec4(odd[0], even[0], odd[1], even[1])


@wp.func
def quantization_transform6(b: vec6) -> vec6:
    """Theta_6*(b): canonical moments -> (q_odd, q_even) in [0, 1]^6 for fixed-point storage."""
    # Peters 2017, Sec. 5.4.3 (transposed 3x3 blocks on odd and even moments)
    odd = _T6_ODD @ wp.vec3(b[0], b[2], b[4]) + _T6_ODD_OFFSET
    even = _T6_EVEN @ wp.vec3(b[1], b[3], b[5]) + _T6_EVEN_OFFSET
    return vec6(odd[0], odd[1], odd[2], even[0], even[1], even[2])


@wp.func
def inverse_quantization_transform6(q: vec6) -> vec6:
    """Theta_6*^-1(q): a texel (q_odd, q_even) -> canonical moments (b_1, ..., b_6)."""
    # Peters 2017, Sec. 5.4.3 inverted
    odd = _T6_ODD_INV @ (wp.vec3(q[0], q[1], q[2]) - _T6_ODD_OFFSET)
    even = _T6_EVEN_INV @ (wp.vec3(q[3], q[4], q[5]) - _T6_EVEN_OFFSET)
    return vec6(odd[0], even[0], odd[1], even[1], odd[2], even[2])


@wp.func
def unorm_encode(x: wp.float32, bits: wp.int32) -> wp.int32:
    """Code of x in an n-bit unsigned normalized fixed-point channel: round(clamp(x, 0, 1) (2^n - 1)), in [0, 2^n - 1].

    NaN encodes as 0 (as a GPU stores NaN to unorm). ``bits`` in [1, 24] (at 24 bits the float32 scale rounds to
    2^24, and so may the largest code). The integer a texture of the fixed-point storage modes holds (Peters 2017
    Sec. 2.4, 5.4.3); :func:`unorm_decode` gives its value.
    """
    scale = wp.float32((1 << bits) - 1)
    xc = x
    if wp.isnan(xc):
        xc = 0.0
    xc = wp.clamp(xc, 0.0, 1.0)
    return int(wp.floor(xc * scale + 0.5))


@wp.func
def unorm_decode(code: wp.int32, bits: wp.int32) -> wp.float32:
    """Value in [0, 1] of an n-bit unorm code: code / (2^n - 1) correctly rounded to float32 (what a GPU's unorm fetch
    returns), bit for bit the float32 quotient.

    Computed as a float64 product with the reciprocal (a constant per format) instead of a float32 division: the
    float64 error (< 2^-52 relative) is far below the distance of code / (2^n - 1) (odd denominator < 2^24) from any
    float32 rounding midpoint (> 2^-49 relative) unless it is exact, so the rounding to float32 never differs (every
    code of the 8-, 10- and 16-bit formats is checked in the tests). A look-up decodes up to 24 codes per pixel.
    """
    return wp.float32(wp.float64(code) * (wp.float64(1.0) / wp.float64((1 << bits) - 1)))


@wp.func
def unorm_round(x: wp.float32, bits: wp.int32) -> wp.float32:
    """Value of x after storage in an n-bit unsigned normalized fixed-point channel: round(clamp(x,0,1)(2^n-1))/(2^n-1).

    NaN stores as 0 (as a GPU stores NaN to unorm). ``bits`` in [1, 24]. Equal, bit for bit, to
    ``unorm_decode(unorm_encode(x, bits), bits)`` (the code is an integer exact in float32).
    """
    return unorm_decode(unorm_encode(x, bits), bits)


@wp.func
def unorm_round4(q: wp.vec4, bits: wp.int32) -> wp.vec4:
    """``unorm_round`` of each component: the value of q after storage in four n-bit unorm channels."""
    return wp.vec4(unorm_round(q[0], bits), unorm_round(q[1], bits), unorm_round(q[2], bits), unorm_round(q[3], bits))


@wp.func
def store_moments4(b: wp.vec4, storage: wp.int32) -> wp.vec4:
    """Texel contents after writing canonical moments b in a 4-moment storage mode (STORAGE4_*)."""
    # Peters 2017, Sec. 2.4 (64 bits: Theta_4* then 16-bit unorm) / Sec. 2.3 (128 bits: float32)
    if storage == STORAGE4_UNORM16:
        return unorm_round4(quantization_transform4(b), UNORM_BITS_STORAGE4_UNORM16)
    return b


@wp.func
def load_moments4(texel: wp.vec4, storage: wp.int32) -> wp.vec4:
    """Canonical moments (unbiased) from a (possibly filtered) texel of a 4-moment storage mode."""
    # Peters 2017, D.2 "revert any quantization transform"
    if storage == STORAGE4_UNORM16:
        return inverse_quantization_transform4(texel)
    return texel


@wp.func
def store_moments6(b: vec6, storage: wp.int32) -> vec6:
    """Texel contents after writing canonical moments b in a 6-moment storage mode (STORAGE6_*)."""
    # Peters 2017, Sec. 5.4.3
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
    """Canonical moments (unbiased) from a (possibly filtered) texel of a 6-moment storage mode."""
    # Peters 2017, Sec. 5.4.3 / D.5
    if storage == STORAGE6_FLOAT32:
        return texel
    return inverse_quantization_transform6(texel)


# ---------------------------------------------------------------------------------------------------------------------
# Texel codes: what the textures of the fixed-point storage modes hold
# ---------------------------------------------------------------------------------------------------------------------
# STORAGE4_UNORM16 and STORAGE6_UNORM16 hold one 16-bit code per channel (a uint16 array, 4 or 6 channels, 64 or 96
# bits per texel). STORAGE6_UNORM10 packs its six 10-bit codes into ONE 64-bit word per texel (a uint64 array): the
# code of channel k in bits [10 k, 10 k + 10), bits 60-63 zero. Decoding a code gives exactly the float32 value of
# the emulated storage (unorm_round), so the look-ups reconstruct the same visibility bit for bit.

#: The code of one STORAGE6_UNORM10 channel in its 64-bit texel word.
UNORM10_MASK = wp.constant(wp.uint64(1023))


@wp.func
def pack_unorm10x6(q: vec6) -> wp.uint64:
    """A STORAGE6_UNORM10 texel: the six 10-bit codes of q (:func:`unorm_encode`) in one 64-bit word (60 bits used)."""
    # Peters 2017, Sec. 5.4.3: 6 x 10 bits
    word = wp.uint64(0)
    for k in range(6):
        word = word | (wp.uint64(unorm_encode(q[k], UNORM_BITS_STORAGE6_UNORM10)) << wp.uint64(10 * k))
    return word


@wp.func
def unpack_unorm10(word: wp.uint64, k: wp.int32) -> wp.float32:
    """Value of channel k (0..5) of a packed STORAGE6_UNORM10 texel (:func:`unorm_decode` of its 10-bit code)."""
    return unorm_decode(wp.int32((word >> wp.uint64(10 * k)) & UNORM10_MASK), UNORM_BITS_STORAGE6_UNORM10)


# ---------------------------------------------------------------------------------------------------------------------
# Biasing and sanitizing
# ---------------------------------------------------------------------------------------------------------------------


@wp.func
def bias_moments4(b: wp.vec4, alpha: wp.float32, b_star: wp.vec4) -> wp.vec4:
    """b' = (1 - alpha) b + alpha b* (b_0 = 1 stays 1). Use BIAS_VECTOR4_* and MOMENT_BIAS4_* of the storage mode."""
    # Peters 2017, Sec. 2.5
    return (1.0 - alpha) * b + alpha * b_star


@wp.func
def bias_moments6(b: vec6, alpha: wp.float32, b_star: vec6) -> vec6:
    """b' = (1 - alpha) b + alpha b* for six moments. Use BIAS_VECTOR6 and MOMENT_BIAS6_* of the storage mode."""
    # Peters 2017, Sec. 5.4.3 (biasing as in Sec. 2.5)
    return (1.0 - alpha) * b + alpha * b_star


@wp.func
def moment_bias4(storage: wp.int32) -> wp.float32:
    """alpha_b of a 4-moment storage mode (STORAGE4_UNORM16: 6e-5, STORAGE4_FLOAT32: 3e-7)."""
    # Peters 2017, Sec. 2.5
    if storage == STORAGE4_UNORM16:
        return MOMENT_BIAS4_UNORM16
    return MOMENT_BIAS4_FLOAT32


@wp.func
def bias_vector4(storage: wp.int32) -> wp.vec4:
    """Worst-case b* of a 4-moment storage mode (0.628 with Theta_4*, 0.375 without)."""
    # Peters 2017, Sec. 2.5
    if storage == STORAGE4_UNORM16:
        return BIAS_VECTOR4_QUANTIZED
    return BIAS_VECTOR4_FLOAT32


@wp.func
def moment_bias6(storage: wp.int32) -> wp.float32:
    """alpha_b of a 6-moment storage mode (UNORM10: 4e-3, UNORM16: 8e-5, FLOAT32: 5e-6)."""
    # Peters 2017, Sec. 5.4.3
    if storage == STORAGE6_UNORM10:
        return MOMENT_BIAS6_UNORM10
    if storage == STORAGE6_UNORM16:
        return MOMENT_BIAS6_UNORM16
    return MOMENT_BIAS6_FLOAT32


@wp.func
def load_biased_moments4(texel: wp.vec4, storage: wp.int32) -> wp.vec4:
    """Texel -> canonical moments biased with the storage mode's alpha_b and b*: ready for Algorithm 1."""
    # Peters 2017, D.2 "Retrieving moments"
    return bias_moments4(load_moments4(texel, storage), moment_bias4(storage), bias_vector4(storage))


@wp.func
def load_biased_moments6(texel: vec6, storage: wp.int32) -> vec6:
    """Texel -> canonical six moments biased with the storage mode's alpha_b and BIAS_VECTOR6."""
    # Peters 2017, Sec. 5.4.3 / D.5
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
