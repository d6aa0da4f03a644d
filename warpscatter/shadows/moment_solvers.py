"""Algorithms 1 and 2 of Peters et al. 2017 ("Improved Moment Shadow Maps ...", JCGT 6(1)): from biased moments to
shadow intensities, with four and six moments. Re-exported by :mod:`warpscatter.shadows.moments` (its docstring
states the conventions). Every function sanitizes its input and never returns NaN; the numerical guards (the FLOOR
constants, the single-Dirac fallback of Sec. 5.2) are described in docs/design/shadows-scene.md.
"""

from __future__ import annotations

import warp as wp

from ..runtime.device import module_options
from .moment_storage import (
    BIAS_VECTOR4_FLOAT32,
    _sanitize_moment,
    sanitize_depth,
    sanitize_moments4,
    sanitize_moments6,
    vec6,
)

module_options()

#: Over-darkening divisor against faint light leaking (Sec. 2.6, D.2): shadow' = clamp(shadow / 0.98, 0, 1).
OVERDARKENING_DIVISOR = wp.constant(0.98)

PIVOT_FLOOR = wp.constant(1.0e-12)  # smallest LDL^T pivot of a Hankel matrix used in a division
LEADING_COEFF_FLOOR = wp.constant(1.0e-7)  # |leading coefficient| >= this * |largest other coefficient|
DIVDIFF_FLOOR = wp.constant(1.0e-12)  # smallest |z_k - z_l| in a divided difference


@wp.func
def _finite_or(x: wp.float32, fallback: wp.float32) -> wp.float32:
    if wp.isfinite(x):
        return x
    return fallback


@wp.func
def _away_from_zero(x: wp.float32, floor: wp.float32) -> wp.float32:
    # |x| raised to at least floor, keeping its sign (0 -> +floor; NaN passes)
    if wp.abs(x) < floor:
        if x < 0.0:
            return -floor
        return floor
    return x


@wp.func
def _dirac_shadow(mean: wp.float32, z_f: wp.float32) -> wp.float32:
    # Z(z < z_f) of the single Dirac delta at b_1 (Peters 2017, Sec. 5.2 fallback)
    if mean < z_f:
        return 1.0
    return 0.0


@wp.func
def _dirac_distribution4(mean: wp.float32, z_f: wp.float32):
    # the single Dirac delta at b_1 as msm4_distribution returns it (weight at z_0 when b_1 == z_f)
    if mean == z_f:
        return wp.vec3(z_f, mean, mean), wp.vec3(1.0, 0.0, 0.0)
    return wp.vec3(z_f, mean, mean), wp.vec3(0.0, 1.0, 0.0)



@wp.func
def quadratic_roots(c: wp.vec3) -> wp.vec2:
    """Real roots (ascending) of c_0 + c_1 z + c_2 z^2 without cancellation (Algorithm 1 Step 3, Algorithm 2 Step 4);
    a negative discriminant counts as zero, a vanishing c_2 gives one far root; the output is always finite."""
    c0 = c[0]
    c1 = c[1]
    c2 = _away_from_zero(c[2], LEADING_COEFF_FLOOR * wp.max(wp.abs(c0), wp.abs(c1)))
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
    """Roots (ascending) of c_0 + c_1 z + c_2 z^2 + c_3 z^3, assumed all real: Blinn 2007 (IEEE CG&A 27(3)), one
    branch for all three (Peters 2017, Sec. 5.4.1). Guards as :func:`quadratic_roots`; the output is always finite."""
    c3 = _away_from_zero(c[3], LEADING_COEFF_FLOOR * wp.max(wp.abs(c[0]), wp.max(wp.abs(c[1]), wp.abs(c[2]))))
    if c3 == 0.0:
        return wp.vec3(0.0, 0.0, 0.0)
    # Blinn's notation: z^3 + 3 B z^2 + 3 C z + D = 0
    inv_c3 = 1.0 / c3
    d = c[0] * inv_c3
    cc = c[1] * inv_c3 / 3.0
    bb = c[2] * inv_c3 / 3.0
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
    lo = wp.min(r0, wp.min(r1, r2))
    hi = wp.max(r0, wp.max(r1, r2))
    mid = r0 + r1 + r2 - lo - hi
    return wp.vec3(lo, mid, hi)



@wp.func
def hankel_pivots4(b: wp.vec4) -> wp.vec2:
    """Unclamped LDL^T pivots (D_11, D_22) of B(1, b_1..b_4): positive definite iff both > 0 (Algorithm 1 Step 1)."""
    d11 = b[1] - b[0] * b[0]
    l21d11 = b[2] - b[0] * b[1]
    d22 = b[3] - b[1] * b[1]
    if d11 != 0.0:
        d22 = d22 - l21d11 * l21d11 / d11
    return wp.vec2(d11, d22)


@wp.func
def hankel_pivots6(b: vec6) -> wp.vec3:
    """Unclamped LDL^T pivots (D_11, D_22, D_33) of the 4x4 Hankel matrix B(1, b_1..b_6) (Sec. 5.4.1)."""
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
    """q = B(b)^-1 (1, z_f, z_f^2), the kernel polynomial with roots z_1, z_2 (Algorithm 1 Steps 1-2), by LDL^T;
    ``b``: biased moments with b_2 - b_1^2 > 0."""
    d11 = wp.max(b[1] - b[0] * b[0], PIVOT_FLOOR)
    l21 = (b[2] - b[0] * b[1]) / d11
    d22 = wp.max(b[3] - b[1] * b[1] - l21 * l21 * d11, PIVOT_FLOOR)
    # L y = (1, z, z^2), D scaling, L^T q = y
    y1 = z_f - b[0]
    y2 = z_f * z_f - b[1] - l21 * y1
    y1 = y1 / d11
    y2 = y2 / d22
    q2 = y2
    q1 = y1 - l21 * q2
    q0 = 1.0 - b[0] * q1 - b[1] * q2
    return wp.vec3(q0, q1, q2)


@wp.func
def msm6_kernel_polynomial(b: vec6, z_f: wp.float32) -> wp.vec4:
    """q = B(b)^-1 (1, z_f, z_f^2, z_f^3), the cubic with roots z_1..z_3 (Algorithm 1 Steps 1-2, m = 6), by LDL^T."""
    d11 = wp.max(b[1] - b[0] * b[0], PIVOT_FLOOR)
    l21 = (b[2] - b[0] * b[1]) / d11
    l31 = (b[3] - b[0] * b[2]) / d11
    d22 = wp.max(b[3] - b[1] * b[1] - l21 * l21 * d11, PIVOT_FLOOR)
    l32 = (b[4] - b[1] * b[2] - l21 * l31 * d11) / d22
    d33 = wp.max(b[5] - b[2] * b[2] - l31 * l31 * d11 - l32 * l32 * d22, PIVOT_FLOOR)
    # L y = (1, z, z^2, z^3), D scaling, L^T q = y
    z2 = z_f * z_f
    y1 = z_f - b[0]
    y2 = z2 - b[1] - l21 * y1
    y3 = z2 * z_f - b[2] - l31 * y1 - l32 * y2
    y1 = y1 / d11
    y2 = y2 / d22
    y3 = y3 / d33
    q3 = y3
    q2 = y2 - l32 * q3
    q1 = y1 - l21 * q2 - l31 * q3
    q0 = 1.0 - b[0] * q1 - b[1] * q2 - b[2] * q3
    return wp.vec4(q0, q1, q2, q3)



@wp.func
def msm4_distribution(b: wp.vec4, z_f: wp.float32):
    """Algorithm 1 (m = 4): the distribution S = sum_l w_l delta_{z_l} minimizing Eq. (1).

    Args:
        b: biased canonical moments (b_1, ..., b_4) of depths in [-1, 1] (sanitized here).
        z_f: fragment depth (signed, [-1, 1]).

    Returns:
        (depths, weights) as two ``wp.vec3``: (z_0 = z_f, z_1 <= z_2) and weights >= 0 summing to 1; b_2 - b_1^2 <= 0
        gives the single Dirac delta at b_1.
    """
    bs = sanitize_moments4(b)
    z0 = sanitize_depth(z_f)
    if bs[1] - bs[0] * bs[0] <= PIVOT_FLOOR:
        return _dirac_distribution4(bs[0], z0)
    q = msm4_kernel_polynomial(bs, z0)
    roots = quadratic_roots(q)
    z1 = roots[0]
    z2 = roots[1]
    if not (wp.isfinite(q[0]) and wp.isfinite(q[1]) and wp.isfinite(q[2])):
        return _dirac_distribution4(bs[0], z0)
    # Step 5 in closed form, w_0 = 1 / Q(z_f): well-conditioned as z_1 or z_2 approach z_f, unlike Lagrange's
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
    """Sharp (lower, upper) bounds of Z(z < z_f) over distributions with moments b (Eq. 1, Sec. 5.3, Fig. 2)."""
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
    """Hard-shadow intensity in [0, 1]: the lower bound of Eq. (1) (against acne). ``b`` biased; z_f not."""
    return msm4_bounds(b, z_f)[0]


@wp.func
def msm4_interpolated_shadow_intensity(b: wp.vec4, z_f: wp.float32, beta: wp.float32) -> wp.float32:
    """upper - beta (upper - lower) with the overestimation weight beta in [0, 1] (Sec. 5.3.1; 1: lower bound)."""
    bounds = msm4_bounds(b, z_f)
    bt = wp.clamp(_finite_or(beta, 0.5), 0.0, 1.0)
    return wp.clamp(bounds[1] - bt * (bounds[1] - bounds[0]), 0.0, 1.0)



@wp.func
def _divided_difference(f_hi: wp.float32, f_lo: wp.float32, z_hi: wp.float32, z_lo: wp.float32) -> wp.float32:
    # Peters 2017, Sec. 5.4.2
    return (f_hi - f_lo) / _away_from_zero(z_hi - z_lo, DIVDIFF_FLOOR)


@wp.func
def interpolation_dot(z: wp.vec4, v: wp.vec4, m: wp.vec4) -> wp.float32:
    """sum_j u_j m_j, u the cubic interpolating (z_l, v_l), l = 0..3: sum_l w_l v_l for m = (b_0..b_3) (Sec. 5.4.2)."""
    f01 = _divided_difference(v[1], v[0], z[1], z[0])
    f12 = _divided_difference(v[2], v[1], z[2], z[1])
    f23 = _divided_difference(v[3], v[2], z[3], z[2])
    f012 = _divided_difference(f12, f01, z[2], z[0])
    f123 = _divided_difference(f23, f12, z[3], z[1])
    f0123 = _divided_difference(f123, f012, z[3], z[0])
    # u(z) = f0 + (z - z0) (f01 + (z - z1) (f012 + (z - z2) f0123)), expanded innermost first
    p0 = f012 - f0123 * z[2]
    p1 = f0123
    p2 = p1
    p1 = p0 - p1 * z[1]
    p0 = f01 - p0 * z[1]
    p3 = p2
    p2 = p1 - p2 * z[0]
    p1 = p0 - p1 * z[0]
    p0 = v[0] - p0 * z[0]
    return p0 * m[0] + p1 * m[1] + p2 * m[2] + p3 * m[3]


@wp.func
def _msm6_support(b: vec6, z_f: wp.float32) -> wp.vec4:
    # Algorithm 1 Steps 1-4 with m = 6; sanitized input with positive variance
    q = msm6_kernel_polynomial(b, z_f)
    roots = cubic_roots(q)
    return wp.vec4(z_f, roots[0], roots[1], roots[2])


@wp.func
def msm6_visibility(b: vec6, z_f: wp.float32, beta: wp.float32) -> wp.float32:
    """Visibility sum_l w_l v_l, v_0 = beta, v_l = [z_f <= z_l], in [0, 1] (Sec. 5.4.2); beta 0 / 1: lower / upper
    bound. ``b`` biased."""
    bs = sanitize_moments6(b)
    z0 = sanitize_depth(z_f)
    bt = wp.clamp(_finite_or(beta, 0.5), 0.0, 1.0)
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
    """Sharp (lower, upper) bounds of Z(z < z_f) from six biased moments (Sec. 5.4.2)."""
    lower = 1.0 - msm6_visibility(b, z_f, 1.0)
    upper = 1.0 - msm6_visibility(b, z_f, 0.0)
    return wp.vec2(wp.min(lower, upper), wp.max(lower, upper))


@wp.func
def msm6_shadow_intensity(b: vec6, z_f: wp.float32) -> wp.float32:
    """Lower bound of Z(z < z_f) from six biased moments (Eq. 1 with m = 6), in [0, 1]."""
    return 1.0 - msm6_visibility(b, z_f, 1.0)


@wp.func
def msm6_interpolated_shadow_intensity(b: vec6, z_f: wp.float32, beta: wp.float32) -> wp.float32:
    """1 - msm6_visibility(b, z_f, beta): upper - beta (upper - lower), the single-scattering estimate of Sec. 5.4."""
    return 1.0 - msm6_visibility(b, z_f, beta)


@wp.func
def msm6_distribution(b: vec6, z_f: wp.float32):
    """Algorithm 1 (m = 6): (depths, weights) as two ``wp.vec4``, depths (z_f, z_1 <= z_2 <= z_3); weights by the
    Newton interpolation of Sec. 5.4.2, clamped and renormalized."""
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



@wp.func
def two_depth_distribution(b: wp.vec3):
    """Algorithm 2 (Sec. 5.2, Appendix B): w_1 delta_{z_1} + w_2 delta_{z_2} with moments (1, b_1, b_2, b_3).

    Args:
        b: (b_1, b_2, b_3), e.g. the first three of a filtered 4-moment vector.

    Returns:
        (depths, weights) as two ``wp.vec2``, z_1 <= z_2, w_1 + w_2 = 1; non-positive variance gives depths (b_1, b_1),
        weights (1, 0). Depths are not clamped (Sec. 5.2 clamps after mapping).
    """
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
    """beta = (1 + omega_l . omega_p) / 2 of Sec. 5.3.1 = (1 + light_direction . ray_direction) / 2 with the light's
    travel direction and the camera ray (both negated in the paper): 0 looking into the light."""
    return wp.clamp(0.5 * (1.0 + wp.dot(light_direction, ray_direction)), 0.0, 1.0)


@wp.func
def scale_shadow_intensity(shadow: wp.float32, divisor: wp.float32) -> wp.float32:
    """Over-darkening clamp(shadow / divisor, 0, 1) (Sec. 2.6, Annen et al. 2007); divisor <= 0: none."""
    s = _finite_or(shadow, 0.0)
    if divisor > 0.0:
        s = s / divisor
    return wp.clamp(_finite_or(s, 1.0), 0.0, 1.0)
