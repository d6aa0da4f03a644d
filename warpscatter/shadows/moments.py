"""Moment shadow mapping math of Peters et al. 2017 ("Improved Moment Shadow Maps ...", JCGT 6(1)).

Public ``@wp.func`` building blocks (float32, callable from any user kernel) and thin numpy host wrappers.

Conventions (Peters 2017 Sec. 2.3): depth is SIGNED, z in [-1, 1] (-1 at the near plane, +1 at the far plane of the
shadow map). A moment vector omits b_0 = 1: four moments are a ``wp.vec4`` (b_1, b_2, b_3, b_4), six moments a
:data:`vec6` (b_1, ..., b_6). "Shadow intensity" is the fraction Z(z < z_f) of the filtered depth distribution Z in
front of the fragment depth z_f (0 = lit, 1 = fully shadowed); visibility is 1 - shadow intensity.

What is here, in the paper's terms:

* ``moments4_from_depth`` / ``moments6_from_depth``: b(z) = (z^j)_j (Sec. 2.2.1, Sec. 5.4).
* Algorithm 1 with four moments (Hamburger 4MSM): ``msm4_kernel_polynomial`` (Steps 1-2, LDL^T Cholesky of the
  3x3 Hankel matrix), ``quadratic_roots`` (Step 3), ``msm4_distribution`` (Steps 4-6), ``msm4_bounds`` (the sharp
  lower and upper bounds of Fig. 2), ``msm4_shadow_intensity`` (the lower bound, Eq. 1: what the paper renders hard
  shadows with) and ``msm4_interpolated_shadow_intensity`` (bounds blended with the overestimation weight beta of
  Sec. 5.3.1, for single scattering).
* Algorithm 1 with six moments: ``msm6_kernel_polynomial`` (4x4 Hankel Cholesky), ``cubic_roots`` (Blinn 2007, the
  single-branch variant of Sec. 5.4.1), ``msm6_visibility`` (Newton divided differences, Sec. 5.4.2),
  ``msm6_bounds``, ``msm6_shadow_intensity``, ``msm6_interpolated_shadow_intensity``, ``msm6_distribution``.
* Algorithm 2 (Sec. 5.2, Appendix B): ``two_depth_distribution``.
* Quantization (Sec. 2.4, Eq. 3; Sec. 5.4.3): ``quantization_transform4/6`` (Theta_4*, Theta_6*) and inverses,
  ``unorm_round`` (n-bit fixed point and back), ``store_moments4/6`` and ``load_moments4/6`` emulating the storage
  modes below.
* Biasing (Sec. 2.5, Sec. 5.4.3): ``bias_moments4/6`` with the worst-case bias vectors b* and the moment bias
  alpha_b of each storage mode (module constants).

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

Robustness (the paper's functions assume valid, biased moments; ours must never return NaN):

* Every shadow function first sanitizes its input: a NaN moment is replaced by the float32 bias vector's component,
  moments are clamped to the range of moments of depths in [-1, 1] (|b_j| <= 1, even b_j >= 0), a NaN fragment
  depth becomes 0 and infinite ones are clamped to +-DEPTH_LIMIT. Valid inputs pass unchanged.
* The LDL^T pivots of the Hankel matrix are floored at PIVOT_FLOOR. If the first pivot (the variance b_2 - b_1^2)
  is not above PIVOT_FLOOR the distribution is taken to be the single Dirac delta at b_1 (the fallback that
  Sec. 5.2 uses in Algorithm 2). Floored later pivots make Algorithm 1 degrade continuously into the determinate
  distribution with fewer depths that the singular Hankel matrix describes (its weight at z_f tends to zero).
* Square roots of discriminants take max(., 0); polynomial leading coefficients and divided-difference denominators
  are kept away from zero; the weight at z_f is 1 / max(Q(z_f), 1) (see ``msm4_distribution``).
* Returned intensities are clamped to [0, 1]; a non-finite intermediate result falls back to the single-Dirac
  answer above.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ..parallel import launch_rows
from ..wpinit import default_device, module_options

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

#: Over-darkening divisor against faint light leaking (Sec. 2.6, D.2): shadow' = clamp(shadow / 0.98, 0, 1).
OVERDARKENING_DIVISOR = wp.constant(0.98)

# ---- Numerical guards (documented in the module docstring) ----
PIVOT_FLOOR = wp.constant(1.0e-12)  # smallest LDL^T pivot of a Hankel matrix used in a division
LEADING_COEFF_FLOOR = wp.constant(1.0e-7)  # |leading coefficient| >= this * |largest other coefficient|
DIVDIFF_FLOOR = wp.constant(1.0e-12)  # smallest |z_k - z_l| in a divided difference
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
def unorm_round(x: wp.float32, bits: wp.int32) -> wp.float32:
    """Value of x after storage in an n-bit unsigned normalized fixed-point channel: round(clamp(x,0,1)(2^n-1))/(2^n-1).

    NaN stores as 0 (as a GPU stores NaN to unorm). ``bits`` in [1, 24].
    """
    scale = wp.float32((1 << bits) - 1)
    xc = x
    if wp.isnan(xc):
        xc = 0.0
    xc = wp.clamp(xc, 0.0, 1.0)
    return wp.floor(xc * scale + 0.5) / scale


@wp.func
def store_moments4(b: wp.vec4, storage: wp.int32) -> wp.vec4:
    """Texel contents after writing canonical moments b in a 4-moment storage mode (STORAGE4_*)."""
    # Peters 2017, Sec. 2.4 (64 bits: Theta_4* then 16-bit unorm) / Sec. 2.3 (128 bits: float32)
    if storage == STORAGE4_UNORM16:
        q = quantization_transform4(b)
        bits = UNORM_BITS_STORAGE4_UNORM16
        return wp.vec4(unorm_round(q[0], bits), unorm_round(q[1], bits), unorm_round(q[2], bits),
                       unorm_round(q[3], bits))
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


@wp.func
def _finite_or(x: wp.float32, fallback: wp.float32) -> wp.float32:
    if wp.isfinite(x):
        return x
    return fallback


@wp.func
def _dirac_shadow(mean: wp.float32, z_f: wp.float32) -> wp.float32:
    # Z(z < z_f) of the single Dirac delta at the mean depth b_1 (the fallback of Peters 2017, Sec. 5.2)
    if mean < z_f:
        return 1.0
    return 0.0


# ---------------------------------------------------------------------------------------------------------------------
# Polynomial roots
# ---------------------------------------------------------------------------------------------------------------------


@wp.func
def quadratic_roots(c: wp.vec3) -> wp.vec2:
    """Real roots (ascending) of c_0 + c_1 z + c_2 z^2, computed without cancellation.

    A negative discriminant counts as zero (double root at the vertex). |c_2| is kept >= LEADING_COEFF_FLOOR *
    max(|c_0|, |c_1|), so a vanishing leading coefficient yields one finite root and one far root (<= ~1e7 times the
    other coefficients' scale) instead of infinity. All-zero input returns (0, 0); a root that overflows (non-finite
    coefficients) is returned as 0, so the output is always finite.
    """
    # Peters 2017, Algorithm 1 Step 3 (m = 4) and Algorithm 2 Step 4
    c0 = c[0]
    c1 = c[1]
    c2 = c[2]
    floor_c2 = LEADING_COEFF_FLOOR * wp.max(wp.abs(c0), wp.abs(c1))
    if wp.abs(c2) < floor_c2:
        if c2 < 0.0:
            c2 = -floor_c2
        else:
            c2 = floor_c2
    if c2 == 0.0:
        return wp.vec2(0.0, 0.0)
    disc = wp.max(c1 * c1 - 4.0 * c0 * c2, 0.0)
    sq = wp.sqrt(disc)
    t = c1 + sq
    if c1 < 0.0:
        t = c1 - sq
    t = -0.5 * t
    r_far = t / c2
    r_near = r_far
    if t != 0.0:
        r_near = c0 / t
    r_near = _finite_or(r_near, 0.0)
    r_far = _finite_or(r_far, 0.0)
    return wp.vec2(wp.min(r_near, r_far), wp.max(r_near, r_far))


@wp.func
def cubic_roots(c: wp.vec4) -> wp.vec3:
    """Roots (ascending) of c_0 + c_1 z + c_2 z^2 + c_3 z^3 assumed to have three real roots.

    Blinn's closed form (IEEE CG&A 27(3), 2007) with ONE branch for all three roots (Peters 2017, Sec. 5.4.1): the
    cubic is normalized by its leading coefficient, depressed, and solved trigonometrically. Guards: |c_3| >=
    LEADING_COEFF_FLOOR * max(|c_0|, |c_1|, |c_2|) (a vanishing c_3 moves one root far away, ~1e7 x scale, instead of
    to infinity); negative discriminants or depressed slopes count as zero (a cubic without three real roots gets
    real approximations). All-zero input returns (0, 0, 0); a root that overflows (non-finite coefficients) is
    returned as 0, so the output is always finite.
    """
    # Peters 2017, Sec. 5.4.1 (Blinn 2007, single branch)
    c3 = c[3]
    floor_c3 = LEADING_COEFF_FLOOR * wp.max(wp.abs(c[0]), wp.max(wp.abs(c[1]), wp.abs(c[2])))
    if wp.abs(c3) < floor_c3:
        if c3 < 0.0:
            c3 = -floor_c3
        else:
            c3 = floor_c3
    if c3 == 0.0:
        return wp.vec3(0.0, 0.0, 0.0)
    # Blinn's notation: z^3 + 3 B z^2 + 3 C z + D = 0
    inv_c3 = 1.0 / c3
    d = c[0] * inv_c3
    cc = c[1] * inv_c3 / 3.0
    bb = c[2] * inv_c3 / 3.0
    # Hessian coefficients delta_1..3 and discriminant
    delta1 = cc - bb * bb
    delta2 = d - bb * cc
    delta3 = bb * d - cc * cc
    discriminant = 4.0 * delta1 * delta3 - delta2 * delta2
    # Depressed cubic t^3 + 3 C' t + D' = 0 with z = t - B
    d_dep = delta2 - 2.0 * bb * delta1
    c_dep = delta1
    theta = wp.atan2(wp.sqrt(wp.max(discriminant, 0.0)), -d_dep) / 3.0
    cos_t = wp.cos(theta)
    sin_t = wp.sin(theta)
    half_sqrt3 = 0.5 * wp.sqrt(3.0)
    scale = 2.0 * wp.sqrt(wp.max(-c_dep, 0.0))
    r0 = scale * cos_t - bb
    r1 = scale * (-0.5 * cos_t - half_sqrt3 * sin_t) - bb
    r2 = scale * (-0.5 * cos_t + half_sqrt3 * sin_t) - bb
    r0 = _finite_or(r0, 0.0)
    r1 = _finite_or(r1, 0.0)
    r2 = _finite_or(r2, 0.0)
    # sort ascending
    lo = wp.min(r0, wp.min(r1, r2))
    hi = wp.max(r0, wp.max(r1, r2))
    mid = r0 + r1 + r2 - lo - hi
    return wp.vec3(lo, mid, hi)


# ---------------------------------------------------------------------------------------------------------------------
# Hankel matrices (Algorithm 1, Steps 1-2)
# ---------------------------------------------------------------------------------------------------------------------


@wp.func
def hankel_pivots4(b: wp.vec4) -> wp.vec2:
    """LDL^T pivots (D_11, D_22) of the Hankel matrix B(1, b_1..b_4), unclamped: B is positive definite iff both > 0."""
    # Peters 2017, Algorithm 1 Step 1 (m = 4)
    d11 = b[1] - b[0] * b[0]
    l21d11 = b[2] - b[0] * b[1]
    d22 = b[3] - b[1] * b[1]
    if d11 != 0.0:
        d22 = d22 - l21d11 * l21d11 / d11
    return wp.vec2(d11, d22)


@wp.func
def hankel_pivots6(b: vec6) -> wp.vec3:
    """LDL^T pivots (D_11, D_22, D_33) of the 4x4 Hankel matrix B(1, b_1..b_6), unclamped (all > 0 iff PD)."""
    # Peters 2017, Sec. 5.4.1 (Cholesky of the 4x4 Hankel matrix)
    d11 = b[1] - b[0] * b[0]
    l21 = b[2] - b[0] * b[1]
    l31 = b[3] - b[0] * b[2]
    d22 = b[3] - b[1] * b[1]
    l32d22 = b[4] - b[1] * b[2]
    d33 = b[5] - b[2] * b[2]
    if d11 != 0.0:
        l21 = l21 / d11
        l31 = l31 / d11
        d22 = d22 - l21 * l21 * d11
        l32d22 = l32d22 - l21 * l31 * d11
        d33 = d33 - l31 * l31 * d11
    if d22 != 0.0:
        d33 = d33 - l32d22 * l32d22 / d22
    return wp.vec3(d11, d22, d33)


@wp.func
def msm4_kernel_polynomial(b: wp.vec4, z_f: wp.float32) -> wp.vec3:
    """q = B(b)^-1 (1, z_f, z_f^2): coefficients (q_0, q_1, q_2) of the kernel polynomial whose roots are z_1, z_2.

    Solved with an LDL^T (square-root-free Cholesky) factorization; pivots are floored at PIVOT_FLOOR. Expects
    biased moments with b_2 - b_1^2 > 0 (``msm4_distribution`` handles the other case).
    """
    # Peters 2017, Algorithm 1 Steps 1-2 (m = 4)
    d11 = wp.max(b[1] - b[0] * b[0], PIVOT_FLOOR)
    l21 = (b[2] - b[0] * b[1]) / d11
    d22 = wp.max(b[3] - b[1] * b[1] - l21 * l21 * d11, PIVOT_FLOOR)
    # forward substitution L y = (1, z, z^2)
    y1 = z_f - b[0]
    y2 = z_f * z_f - b[1] - l21 * y1
    # diagonal scaling
    y1 = y1 / d11
    y2 = y2 / d22
    # backward substitution L^T q = y
    q2 = y2
    q1 = y1 - l21 * q2
    q0 = 1.0 - b[0] * q1 - b[1] * q2
    return wp.vec3(q0, q1, q2)


@wp.func
def msm6_kernel_polynomial(b: vec6, z_f: wp.float32) -> wp.vec4:
    """q = B(b)^-1 (1, z_f, z_f^2, z_f^3) for the 4x4 Hankel matrix: the cubic whose roots are z_1, z_2, z_3.

    LDL^T factorization with pivots floored at PIVOT_FLOOR; expects biased moments with b_2 - b_1^2 > 0.
    """
    # Peters 2017, Algorithm 1 Steps 1-2 with m = 6 (Sec. 5.4.1)
    d11 = wp.max(b[1] - b[0] * b[0], PIVOT_FLOOR)
    l21 = (b[2] - b[0] * b[1]) / d11
    l31 = (b[3] - b[0] * b[2]) / d11
    d22 = wp.max(b[3] - b[1] * b[1] - l21 * l21 * d11, PIVOT_FLOOR)
    l32 = (b[4] - b[1] * b[2] - l21 * l31 * d11) / d22
    d33 = wp.max(b[5] - b[2] * b[2] - l31 * l31 * d11 - l32 * l32 * d22, PIVOT_FLOOR)
    # forward substitution L y = (1, z, z^2, z^3)
    z2 = z_f * z_f
    y1 = z_f - b[0]
    y2 = z2 - b[1] - l21 * y1
    y3 = z2 * z_f - b[2] - l31 * y1 - l32 * y2
    # diagonal scaling
    y1 = y1 / d11
    y2 = y2 / d22
    y3 = y3 / d33
    # backward substitution L^T q = y
    q3 = y3
    q2 = y2 - l32 * q3
    q1 = y1 - l21 * q2 - l31 * q3
    q0 = 1.0 - b[0] * q1 - b[1] * q2 - b[2] * q3
    return wp.vec4(q0, q1, q2, q3)


# ---------------------------------------------------------------------------------------------------------------------
# Algorithm 1, four moments
# ---------------------------------------------------------------------------------------------------------------------


@wp.func
def msm4_distribution(b: wp.vec4, z_f: wp.float32):
    """Algorithm 1 (m = 4): the distribution S = sum_l w_l delta_{z_l} minimizing Eq. (1).

    Args:
        b: biased canonical moments (b_1, ..., b_4) of depths in [-1, 1] (sanitized here).
        z_f: fragment depth (signed, [-1, 1]).

    Returns:
        (depths, weights) as two ``wp.vec3``: depths = (z_0 = z_f, z_1, z_2) with z_1 <= z_2, weights (w_0, w_1, w_2)
        >= 0 summing to 1. Step 5 (A w = (b_0, b_1, b_2)) is solved in closed form: w_0 = 1 / Q(z_f) where
        Q(z) = sum_j q_j z^j (Q vanishes at z_1, z_2, so E_S(Q(z) z^k) = z_f^k gives w_0 Q(z_f) = 1; Q(z_f) =
        v^T B^-1 v >= 1 for valid moments, and unlike the Lagrange form it stays well-conditioned when z_1 or z_2
        approach z_f), then w_1 + w_2 = 1 - w_0 and w_1 z_1 + w_2 z_2 = b_1 - w_0 z_f.
        Degenerate input (b_2 - b_1^2 <= 0) gives the single Dirac delta at b_1.
    """
    # Peters 2017, Algorithm 1 (Hamburger 4MSM)
    bs = sanitize_moments4(b)
    z0 = sanitize_depth(z_f)
    if bs[1] - bs[0] * bs[0] <= PIVOT_FLOOR:
        # single Dirac delta at the mean (Sec. 5.2 fallback)
        if bs[0] == z0:
            return wp.vec3(z0, bs[0], bs[0]), wp.vec3(1.0, 0.0, 0.0)
        return wp.vec3(z0, bs[0], bs[0]), wp.vec3(0.0, 1.0, 0.0)
    # Steps 1-2
    q = msm4_kernel_polynomial(bs, z0)
    # Step 3
    roots = quadratic_roots(q)
    z1 = roots[0]
    z2 = roots[1]
    if not (wp.isfinite(q[0]) and wp.isfinite(q[1]) and wp.isfinite(q[2])):
        # overflow (only for garbage input): single Dirac delta at the mean
        if bs[0] == z0:
            return wp.vec3(z0, bs[0], bs[0]), wp.vec3(1.0, 0.0, 0.0)
        return wp.vec3(z0, bs[0], bs[0]), wp.vec3(0.0, 1.0, 0.0)
    # Steps 4-5 (closed form, see docstring)
    kernel_at_zf = q[0] + z0 * (q[1] + z0 * q[2])
    w0 = 1.0 / wp.max(_finite_or(kernel_at_zf, 1.0), 1.0)
    rest = 1.0 - w0
    w2 = 0.5 * rest
    if z2 - z1 > DIVDIFF_FLOOR:
        w2 = (bs[0] - w0 * z0 - rest * z1) / (z2 - z1)
    w2 = wp.clamp(_finite_or(w2, 0.5 * rest), 0.0, rest)
    w1 = rest - w2
    return wp.vec3(z0, z1, z2), wp.vec3(w0, w1, w2)


@wp.func
def msm4_bounds(b: wp.vec4, z_f: wp.float32) -> wp.vec2:
    """Sharp (lower, upper) bounds of Z(z < z_f) over all distributions with moments b (Fig. 2).

    lower = sum of w_l (l >= 1) with z_l < z_f (Eq. 1); upper = lower + w_0 (Sec. 5.3). Both in [0, 1].
    """
    # Peters 2017, Algorithm 1 + Sec. 5.3
    depths, weights = msm4_distribution(b, z_f)
    z0 = depths[0]
    lower = float(0.0)
    if depths[1] < z0:
        lower += weights[1]
    if depths[2] < z0:
        lower += weights[2]
    lower = wp.clamp(lower, 0.0, 1.0)
    upper = wp.clamp(lower + weights[0], lower, 1.0)
    return wp.vec2(lower, upper)


@wp.func
def msm4_shadow_intensity(b: wp.vec4, z_f: wp.float32) -> wp.float32:
    """Hard-shadow intensity in [0, 1]: the LOWER bound of Eq. (1), the paper's choice against surface acne.

    ``b`` must already be biased (``load_biased_moments4`` / ``bias_moments4``); apply a depth bias to z_f yourself.
    """
    # Peters 2017, Eq. (1) / Algorithm 1
    return msm4_bounds(b, z_f)[0]


@wp.func
def msm4_interpolated_shadow_intensity(b: wp.vec4, z_f: wp.float32, beta: wp.float32) -> wp.float32:
    """Shadow intensity upper - beta (upper - lower) with the overestimation weight beta in [0, 1].

    beta is the single-scattering weight of Sec. 5.3.1: beta = 0 underestimates visibility (upper shadow bound), beta
    = 1 overestimates it (lower bound, as for hard shadows). See ``adaptive_overestimation_weight``.
    """
    # Peters 2017, Sec. 5.3 / 5.3.1
    bounds = msm4_bounds(b, z_f)
    bt = wp.clamp(_finite_or(beta, 0.5), 0.0, 1.0)
    return wp.clamp(bounds[1] - bt * (bounds[1] - bounds[0]), 0.0, 1.0)


# ---------------------------------------------------------------------------------------------------------------------
# Algorithm 1, six moments
# ---------------------------------------------------------------------------------------------------------------------


@wp.func
def _divided_difference(f_hi: wp.float32, f_lo: wp.float32, z_hi: wp.float32, z_lo: wp.float32) -> wp.float32:
    # Peters 2017, Sec. 5.4.2: one Newton divided difference, |z_hi - z_lo| kept >= DIVDIFF_FLOOR
    dz = z_hi - z_lo
    if wp.abs(dz) < DIVDIFF_FLOOR:
        if dz < 0.0:
            dz = -DIVDIFF_FLOOR
        else:
            dz = DIVDIFF_FLOOR
    return (f_hi - f_lo) / dz


@wp.func
def interpolation_dot(z: wp.vec4, v: wp.vec4, m: wp.vec4) -> wp.float32:
    """sum_j u_j m_j where u is the cubic interpolating (z_l, v_l), l = 0..3 (Newton divided differences).

    With m = (b_0, .., b_3) and z the support of a distribution matching those moments this is sum_l w_l v_l.
    """
    # Peters 2017, Sec. 5.4.2 (Newton form, then the canonical basis)
    f01 = _divided_difference(v[1], v[0], z[1], z[0])
    f12 = _divided_difference(v[2], v[1], z[2], z[1])
    f23 = _divided_difference(v[3], v[2], z[3], z[2])
    f012 = _divided_difference(f12, f01, z[2], z[0])
    f123 = _divided_difference(f23, f12, z[3], z[1])
    f0123 = _divided_difference(f123, f012, z[3], z[0])
    # u(z) = f0 + (z - z0) (f01 + (z - z1) (f012 + (z - z2) f0123)), expanded innermost first
    p0 = f012 - f0123 * z[2]
    p1 = f0123
    # * (z - z1) + f01
    p2 = p1
    p1 = p0 - p1 * z[1]
    p0 = f01 - p0 * z[1]
    # * (z - z0) + f0
    p3 = p2
    p2 = p1 - p2 * z[0]
    p1 = p0 - p1 * z[0]
    p0 = v[0] - p0 * z[0]
    return p0 * m[0] + p1 * m[1] + p2 * m[2] + p3 * m[3]


@wp.func
def _msm6_support(b: vec6, z_f: wp.float32) -> wp.vec4:
    # Algorithm 1 Steps 1-4 with m = 6: (z_0 = z_f, z_1, z_2, z_3); assumes sanitized input with positive variance
    q = msm6_kernel_polynomial(b, z_f)
    roots = cubic_roots(q)
    return wp.vec4(z_f, roots[0], roots[1], roots[2])


@wp.func
def msm6_visibility(b: vec6, z_f: wp.float32, beta: wp.float32) -> wp.float32:
    """Average visibility sum_l w_l v_l with v_0 = beta, v_l = [z_f <= z_l] (l >= 1), clamped to [0, 1].

    beta = 0: lower visibility bound (1 - upper shadow bound); beta = 1: upper visibility bound; the adaptive
    overestimation of Sec. 5.3.1 sets beta per view ray. ``b`` must already be biased.
    """
    # Peters 2017, Sec. 5.4.2 (Algorithm 1 with m = 6, weights folded into a Newton interpolation)
    bs = sanitize_moments6(b)
    z0 = sanitize_depth(z_f)
    bt = wp.clamp(_finite_or(beta, 0.5), 0.0, 1.0)
    # single Dirac delta at the mean (Sec. 5.2 fallback); at z_f itself it counts with weight beta
    fallback = 1.0 - _dirac_shadow(bs[0], z0)
    if bs[0] == z0:
        fallback = bt
    if bs[1] - bs[0] * bs[0] <= PIVOT_FLOOR:
        return fallback
    z = _msm6_support(bs, z0)
    v = wp.vec4(bt, 0.0, 0.0, 0.0)
    for k in range(1, 4):
        if z0 <= z[k]:
            v[k] = 1.0
    vis = interpolation_dot(z, v, wp.vec4(1.0, bs[0], bs[1], bs[2]))
    return wp.clamp(_finite_or(vis, fallback), 0.0, 1.0)


@wp.func
def msm6_bounds(b: vec6, z_f: wp.float32) -> wp.vec2:
    """Sharp (lower, upper) bounds of Z(z < z_f) from six biased moments: 1 - visibility(beta = 1), 1 - vis(0)."""
    # Peters 2017, Sec. 5.4.2
    lower = 1.0 - msm6_visibility(b, z_f, 1.0)
    upper = 1.0 - msm6_visibility(b, z_f, 0.0)
    return wp.vec2(wp.min(lower, upper), wp.max(lower, upper))


@wp.func
def msm6_shadow_intensity(b: vec6, z_f: wp.float32) -> wp.float32:
    """Lower bound of Z(z < z_f) from six biased moments (Eq. 1 with m = 6), in [0, 1]."""
    # Peters 2017, Eq. (1), Algorithm 1 with m = 6
    return 1.0 - msm6_visibility(b, z_f, 1.0)


@wp.func
def msm6_interpolated_shadow_intensity(b: vec6, z_f: wp.float32, beta: wp.float32) -> wp.float32:
    """1 - msm6_visibility(b, z_f, beta): upper - beta (upper - lower), the single-scattering estimate of Sec. 5.4."""
    # Peters 2017, Sec. 5.4.2 with the overestimation weight of Sec. 5.3.1
    return 1.0 - msm6_visibility(b, z_f, beta)


@wp.func
def msm6_distribution(b: vec6, z_f: wp.float32):
    """Algorithm 1 (m = 6): (depths, weights) as two ``wp.vec4``, depths (z_f, z_1 <= z_2 <= z_3).

    Weights come from the same Newton interpolation as ``msm6_visibility`` (w_l = value for v = e_l), clamped to >= 0
    and renormalized. Degenerate input (b_2 - b_1^2 <= 0) gives the single Dirac delta at b_1.
    """
    # Peters 2017, Algorithm 1 with m = 6, Step 5 via Sec. 5.4.2
    bs = sanitize_moments6(b)
    z0 = sanitize_depth(z_f)
    if bs[1] - bs[0] * bs[0] <= PIVOT_FLOOR:
        if bs[0] == z0:
            return wp.vec4(z0, bs[0], bs[0], bs[0]), wp.vec4(1.0, 0.0, 0.0, 0.0)
        return wp.vec4(z0, bs[0], bs[0], bs[0]), wp.vec4(0.0, 1.0, 0.0, 0.0)
    z = _msm6_support(bs, z0)
    m = wp.vec4(1.0, bs[0], bs[1], bs[2])
    w = wp.vec4(0.0, 0.0, 0.0, 0.0)
    total = float(0.0)
    for k in range(4):
        e = wp.vec4(0.0, 0.0, 0.0, 0.0)
        e[k] = 1.0
        wk = wp.max(_finite_or(interpolation_dot(z, e, m), 0.0), 0.0)
        w[k] = wk
        total += wk
    if total > 0.0:
        w = w / total
    else:
        w = wp.vec4(0.0, 1.0, 0.0, 0.0)
        z = wp.vec4(z0, bs[0], bs[0], bs[0])
    return z, w


# ---------------------------------------------------------------------------------------------------------------------
# Algorithm 2 and helpers for single scattering
# ---------------------------------------------------------------------------------------------------------------------


@wp.func
def two_depth_distribution(b: wp.vec3):
    """Algorithm 2: the distribution w_1 delta_{z_1} + w_2 delta_{z_2} with moments (1, b_1, b_2, b_3).

    Args:
        b: (b_1, b_2, b_3), e.g. the first three of a filtered 4-moment vector.

    Returns:
        (depths, weights) as two ``wp.vec2`` with z_1 <= z_2, w_1 + w_2 = 1, w in [0, 1]. The input is sanitized like
        ``sanitize_moments4``. Non-positive variance b_2 - b_1^2 (or non-finite intermediates) gives delta_{b_1}:
        depths (b_1, b_1), weights (1, 0). Depths are not clamped further: map them and clamp to your range afterwards
        as Sec. 5.2 does.
    """
    # Peters 2017, Algorithm 2 (Sec. 5.2, Appendix B)
    s = BIAS_VECTOR4_FLOAT32
    b1 = _sanitize_moment(b[0], s[0], False)
    b2 = _sanitize_moment(b[1], s[1], True)
    b3 = _sanitize_moment(b[2], s[2], False)
    q2 = b2 - b1 * b1
    dirac_z = wp.vec2(b1, b1)
    dirac_w = wp.vec2(1.0, 0.0)
    if not (q2 > 0.0):
        return dirac_z, dirac_w
    q1 = b1 * b2 - b3
    q0 = -b1 * q1 - b2 * q2
    roots = quadratic_roots(wp.vec3(q0, q1, q2))
    z1 = roots[0]
    z2 = roots[1]
    w2 = float(0.0)
    if z2 - z1 > DIVDIFF_FLOOR:
        w2 = (b1 - z1) / (z2 - z1)
    w2 = wp.clamp(w2, 0.0, 1.0)
    if not (wp.isfinite(z1) and wp.isfinite(z2) and wp.isfinite(w2)):
        return dirac_z, dirac_w
    return wp.vec2(z1, z2), wp.vec2(1.0 - w2, w2)


@wp.func
def adaptive_overestimation_weight(light_direction: wp.vec3, ray_direction: wp.vec3) -> wp.float32:
    """beta = (1 + omega_l . omega_p) / 2 for unit vectors in warpscatter's conventions.

    ``light_direction`` is the direction light TRAVELS and ``ray_direction`` points from the camera into the scene
    (CONVENTIONS.md). The paper's omega_l (towards the light) and omega_p (towards the camera) are their negatives, so
    omega_l . omega_p = light_direction . ray_direction: beta = 0 looking into the light, 1 looking away from it.
    """
    # Peters 2017, Sec. 5.3.1
    return wp.clamp(0.5 * (1.0 + wp.dot(light_direction, ray_direction)), 0.0, 1.0)


@wp.func
def scale_shadow_intensity(shadow: wp.float32, divisor: wp.float32) -> wp.float32:
    """Over-darkening: clamp(shadow / divisor, 0, 1), e.g. divisor OVERDARKENING_DIVISOR = 0.98 (<= 0: no scaling)."""
    # Peters 2017, Sec. 2.6 / D.2 (after Annen et al. 2007)
    s = _finite_or(shadow, 0.0)
    if divisor > 0.0:
        s = s / divisor
    return wp.clamp(_finite_or(s, 1.0), 0.0, 1.0)


# ---------------------------------------------------------------------------------------------------------------------
# Kernels (the last input of each is the row offset used by parallel.launch_rows)
# ---------------------------------------------------------------------------------------------------------------------


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


@wp.kernel
def _transform4_kernel(b: wp.array(dtype=wp.vec4), op: int, storage: int, out: wp.array(dtype=wp.vec4), offset: int):
    i = wp.tid() + offset
    if op == 0:
        out[i] = quantization_transform4(b[i])
    elif op == 1:
        out[i] = inverse_quantization_transform4(b[i])
    elif op == 2:
        out[i] = store_moments4(b[i], storage)
    else:
        out[i] = load_moments4(b[i], storage)


@wp.kernel
def _transform6_kernel(b: wp.array(dtype=vec6), op: int, storage: int, out: wp.array(dtype=vec6), offset: int):
    i = wp.tid() + offset
    if op == 0:
        out[i] = quantization_transform6(b[i])
    elif op == 1:
        out[i] = inverse_quantization_transform6(b[i])
    elif op == 2:
        out[i] = store_moments6(b[i], storage)
    else:
        out[i] = load_moments6(b[i], storage)


@wp.kernel
def _cubic_kernel(c: wp.array(dtype=wp.vec4), out: wp.array(dtype=wp.vec3), offset: int):
    i = wp.tid() + offset
    out[i] = cubic_roots(c[i])


# ---------------------------------------------------------------------------------------------------------------------
# Host wrappers (numpy in, numpy out)
# ---------------------------------------------------------------------------------------------------------------------

_MIN_CHUNK = 4096
_STORAGE4 = {int(STORAGE4_UNORM16): "STORAGE4_UNORM16", int(STORAGE4_FLOAT32): "STORAGE4_FLOAT32"}
_STORAGE6 = {int(STORAGE6_UNORM10): "STORAGE6_UNORM10", int(STORAGE6_UNORM16): "STORAGE6_UNORM16",
             int(STORAGE6_FLOAT32): "STORAGE6_FLOAT32"}


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
    """Validate a weight in [0, 1] (within tol, e.g. float32 rounding of (1 + l.d) / 2) and return it clipped."""
    a = np.asarray(value, dtype=np.float64)
    if a.ndim and not allow_array:
        raise ValueError(f"{name}: expected a scalar, got shape {a.shape}")
    if not np.all(np.isfinite(a)) or np.any(a < -tol) or np.any(a > 1.0 + tol):
        raise ValueError(f"{name}: must lie in [0, 1], got {value!r}")
    return np.clip(a, 0.0, 1.0)


def _launch(kernel, n: int, inputs: list, device) -> None:
    launch_rows(kernel, n, inputs, device=device, min_chunk=_MIN_CHUNK)


def moments4(z, device=None) -> np.ndarray:
    """b(z) = (z, z^2, z^3, z^4) of signed depths z (any shape) -> float32 array of shape z.shape + (4,)."""
    device = default_device(device)
    zz = np.ascontiguousarray(np.asarray(z, dtype=np.float32))
    n = zz.size
    out = wp.zeros(n, dtype=wp.vec4, device=device)
    _launch(_moments4_kernel, n, [wp.array(zz.reshape(-1), dtype=wp.float32, device=device), out], device)
    return out.numpy().reshape(zz.shape + (4,))


def moments6(z, device=None) -> np.ndarray:
    """b(z) = (z, ..., z^6) of signed depths z (any shape) -> float32 array of shape z.shape + (6,)."""
    device = default_device(device)
    zz = np.ascontiguousarray(np.asarray(z, dtype=np.float32))
    n = zz.size
    out = wp.zeros(n, dtype=vec6, device=device)
    _launch(_moments6_kernel, n, [wp.array(zz.reshape(-1), dtype=wp.float32, device=device), out], device)
    return out.numpy().reshape(zz.shape + (6,))


def _msm4(b, z_f, alpha, bias_vector, beta, device) -> np.ndarray:
    device = default_device(device)
    bb = _vectors(b, 4, "b")
    _fraction(alpha, "alpha")
    beta = _fraction(beta, "beta", allow_array=True, tol=1e-6)
    bstar = _vectors(bias_vector, 4, "bias_vector").reshape(-1)
    if bstar.size != 4:
        raise ValueError(f"bias_vector: expected 4 values (b*_1..b*_4), got {bstar.size}")
    shape = bb.shape[:-1]
    n = int(np.prod(shape, dtype=np.int64))
    zf = _per_item(z_f, shape, "z_f")
    bt = _per_item(beta, shape, "beta")
    out = wp.zeros(n, dtype=wp.vec3, device=device)
    _launch(_msm4_kernel, n, [wp.array(bb.reshape(-1, 4), dtype=wp.vec4, device=device),
                              wp.array(zf, dtype=wp.float32, device=device),
                              wp.array(bt, dtype=wp.float32, device=device), float(alpha), wp.vec4(*bstar), out],
            device)
    return out.numpy().reshape(shape + (3,))


def shadow_intensity4(b, z_f, alpha=MOMENT_BIAS4_FLOAT32, bias_vector=BIAS_VECTOR4_FLOAT32, beta=1.0,
                      device=None) -> np.ndarray:
    """Four-moment shadow intensity Z(z < z_f) in [0, 1] (Algorithm 1), after biasing (Sec. 2.5).

    Args:
        b: canonical moments (..., 4) = (b_1, .., b_4) of signed depths (e.g. ``dequantize4`` output), unbiased.
        z_f: fragment depths, broadcastable to b.shape[:-1].
        alpha: moment bias alpha_b in [0, 1] (MOMENT_BIAS4_*; 0 disables biasing).
        bias_vector: b*_1..b*_4 (BIAS_VECTOR4_FLOAT32 for float32 storage, BIAS_VECTOR4_QUANTIZED after Theta_4*).
        beta: overestimation weight(s) in [0, 1] broadcastable to b.shape[:-1]; the default 1 returns the lower bound
            (Eq. 1, hard shadows), 0 the upper bound, (1 + l.d)/2 the adaptive choice of Sec. 5.3.1.
        device: Warp device (default ``default_device()``).

    Returns:
        float32 array of shape b.shape[:-1].

    Raises:
        ValueError: wrong shapes, alpha or beta outside [0, 1].
    """
    return _msm4(b, z_f, alpha, bias_vector, beta, device)[..., 2]


def bounds4(b, z_f, alpha=0.0, bias_vector=BIAS_VECTOR4_FLOAT32, device=None) -> np.ndarray:
    """Sharp (lower, upper) bounds of Z(z < z_f) from four moments: float32 array b.shape[:-1] + (2,).

    ``b`` is taken as given (alpha = 0, the default) or biased first with alpha and bias_vector (see
    :func:`shadow_intensity4`).
    """
    return _msm4(b, z_f, alpha, bias_vector, 1.0, device)[..., :2]


def _msm6(b, z_f, alpha, bias_vector, beta, device) -> np.ndarray:
    device = default_device(device)
    bb = _vectors(b, 6, "b")
    _fraction(alpha, "alpha")
    beta = _fraction(beta, "beta", allow_array=True, tol=1e-6)
    bstar = _vectors(bias_vector, 6, "bias_vector").reshape(-1)
    if bstar.size != 6:
        raise ValueError(f"bias_vector: expected 6 values (b*_1..b*_6), got {bstar.size}")
    shape = bb.shape[:-1]
    n = int(np.prod(shape, dtype=np.int64))
    zf = _per_item(z_f, shape, "z_f")
    bt = _per_item(beta, shape, "beta")
    out = wp.zeros(n, dtype=wp.vec3, device=device)
    _launch(_msm6_kernel, n, [wp.array(bb.reshape(-1, 6), dtype=vec6, device=device),
                              wp.array(zf, dtype=wp.float32, device=device),
                              wp.array(bt, dtype=wp.float32, device=device), float(alpha), vec6(*bstar), out], device)
    return out.numpy().reshape(shape + (3,))


def shadow_intensity6(b, z_f, alpha=MOMENT_BIAS6_FLOAT32, bias_vector=BIAS_VECTOR6, beta=1.0,
                      device=None) -> np.ndarray:
    """Six-moment shadow intensity in [0, 1]: 1 - visibility of Sec. 5.4.2, after biasing.

    Args:
        b: canonical moments (..., 6) = (b_1, .., b_6) of signed depths, unbiased.
        z_f: fragment depths, broadcastable to b.shape[:-1].
        alpha: moment bias in [0, 1] (MOMENT_BIAS6_* of the storage mode; 0 disables biasing).
        bias_vector: b*_1..b*_6 (BIAS_VECTOR6).
        beta: overestimation weight(s) of Sec. 5.3.1 in [0, 1]; 1 (default) gives the lower bound, 0 the upper one.
        device: Warp device.

    Returns:
        float32 array of shape b.shape[:-1].

    Raises:
        ValueError: wrong shapes, alpha or beta outside [0, 1].
    """
    return _msm6(b, z_f, alpha, bias_vector, beta, device)[..., 2]


def bounds6(b, z_f, alpha=0.0, bias_vector=BIAS_VECTOR6, device=None) -> np.ndarray:
    """Sharp (lower, upper) bounds of Z(z < z_f) from six moments: float32 array b.shape[:-1] + (2,)."""
    return _msm6(b, z_f, alpha, bias_vector, 1.0, device)[..., :2]


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
    return _transform(b, 4, _transform4_kernel, wp.vec4, 1 if inverse else 0, 0, device)


def quantize4(b, storage=STORAGE4_UNORM16, device=None) -> np.ndarray:
    """Texel values (..., 4) float32 after storing canonical moments in ``storage`` (STORAGE4_*).

    STORAGE4_UNORM16: Theta_4*(b) rounded to multiples of 1/65535 in [0, 1]; STORAGE4_FLOAT32: b itself.
    """
    return _transform(b, 4, _transform4_kernel, wp.vec4, 2, _storage(storage, _STORAGE4, "4-moment"), device)


def dequantize4(texels, storage=STORAGE4_UNORM16, device=None) -> np.ndarray:
    """Canonical (unbiased) moments (..., 4) from texel values of ``storage`` (inverse of :func:`quantize4`)."""
    return _transform(texels, 4, _transform4_kernel, wp.vec4, 3, _storage(storage, _STORAGE4, "4-moment"), device)


def apply_quantization_transform6(b, inverse: bool = False, device=None) -> np.ndarray:
    """Theta_6* of Sec. 5.4.3 (or its inverse) on (..., 6) arrays; texel order (q_odd, q_even); float32."""
    return _transform(b, 6, _transform6_kernel, vec6, 1 if inverse else 0, 0, device)


def quantize6(b, storage=STORAGE6_UNORM16, device=None) -> np.ndarray:
    """Texel values (..., 6) float32 after storing canonical six moments in ``storage`` (STORAGE6_*)."""
    return _transform(b, 6, _transform6_kernel, vec6, 2, _storage(storage, _STORAGE6, "6-moment"), device)


def dequantize6(texels, storage=STORAGE6_UNORM16, device=None) -> np.ndarray:
    """Canonical (unbiased) six moments (..., 6) from texel values of ``storage`` (inverse of :func:`quantize6`)."""
    return _transform(texels, 6, _transform6_kernel, vec6, 3, _storage(storage, _STORAGE6, "6-moment"), device)


def solve_cubic(coeffs, device=None) -> np.ndarray:
    """Roots (ascending, float32 (..., 3)) of c_0 + c_1 z + c_2 z^2 + c_3 z^3 for coeffs (..., 4) in ASCENDING order.

    Same ``@wp.func`` as the 6-moment shadows (Blinn, single branch, Sec. 5.4.1); intended for cubics with three
    real roots (others get real approximations).
    """
    device = default_device(device)
    c = _vectors(coeffs, 4, "coeffs")
    flat = c.reshape(-1, 4)
    n = flat.shape[0]
    out = wp.zeros(n, dtype=wp.vec3, device=device)
    _launch(_cubic_kernel, n, [wp.array(flat, dtype=wp.vec4, device=device), out], device)
    return out.numpy().reshape(c.shape[:-1] + (3,))
