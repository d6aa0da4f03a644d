"""Tests of warpscatter.shadows.moments (Peters et al. 2017) against float64 numpy references of the same algorithms.

The references below (``ref_*``) re-implement Algorithm 1 (Cholesky of the Hankel matrix, kernel polynomial, roots,
Vandermonde solve for the weights), Blinn's single-branch cubic solver of Sec. 5.4.1, the Newton divided differences
of Sec. 5.4.2 and Algorithm 2 in float64; the library runs the same algorithms in float32 Warp kernels. Tolerances
are measured maxima over the seeded inputs (several seeds tried) with a margin; the measured value is in a comment.
"""

import numpy as np
import pytest
import warp as wp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy.linalg import solve_triangular

from warpscatter.runtime.device import module_options
from warpscatter.shadows import moments

module_options()

# ---------------------------------------------------------------------------------------------------------------------
# float64 references
# ---------------------------------------------------------------------------------------------------------------------


def ref_moments(z, m):
    """b(z) = (z^1, ..., z^m) in float64."""
    z = np.asarray(z, dtype=np.float64)
    return np.stack([z**j for j in range(1, m + 1)], axis=-1)


def dist_moments(depths, weights, m):
    """Moments b_1..b_m of sum_l w_l delta_{z_l}."""
    return np.asarray(weights, np.float64) @ ref_moments(depths, m)


def shadow_truth(depths, weights, z_f):
    """Z(z < z_f), the percentage-closer result."""
    return float(np.sum(np.asarray(weights)[np.asarray(depths) < z_f]))


def ref_bias(b, alpha, b_star):
    """Peters 2017 Sec. 2.5: b' = (1 - alpha) b + alpha b*."""
    return (1.0 - alpha) * np.asarray(b, np.float64) + alpha * np.asarray(b_star, np.float64)


def ref_hankel(b):
    """B(b) = (b_{j+k}) with b_0 = 1, size m/2 + 1."""
    full = np.concatenate([[1.0], np.asarray(b, np.float64)])
    n = len(b) // 2 + 1
    return np.array([[full[j + k] for k in range(n)] for j in range(n)])


def ref_pivots(b):
    """LDL^T pivots D_11.. of B(b) (all positive iff B is positive definite); Gaussian elimination in float64."""
    a = ref_hankel(b).copy()
    n = a.shape[0]
    piv = []
    for k in range(n):
        piv.append(a[k, k])
        if k + 1 < n and a[k, k] != 0:
            a[k + 1 :, k + 1 :] -= np.outer(a[k + 1 :, k], a[k, k + 1 :]) / a[k, k]
    return np.array(piv[1:])


def ref_kernel_polynomial(b, z_f):
    """Algorithm 1 Steps 1-2: Cholesky B = L L^T, q = B^-1 (1, z_f, .., z_f^{m/2})."""
    big_b = ref_hankel(b)
    lower = np.linalg.cholesky(big_b)
    v = z_f ** np.arange(big_b.shape[0], dtype=np.float64)
    return solve_triangular(lower.T, solve_triangular(lower, v, lower=True), lower=False)


def ref_cubic_blinn(c):
    """Blinn 2007 with one branch for all roots (Peters 2017 Sec. 5.4.1), float64; roots ascending."""
    c = np.asarray(c, np.float64)
    d, cc, bb = c[0] / c[3], c[1] / c[3] / 3.0, c[2] / c[3] / 3.0
    delta1, delta2, delta3 = cc - bb * bb, d - bb * cc, bb * d - cc * cc
    disc = 4.0 * delta1 * delta3 - delta2 * delta2
    d_dep = delta2 - 2.0 * bb * delta1
    theta = np.arctan2(np.sqrt(max(disc, 0.0)), -d_dep) / 3.0
    scale = 2.0 * np.sqrt(max(-delta1, 0.0))
    roots = scale * np.cos(theta + np.array([0.0, 2.0, -2.0]) * np.pi / 3.0) - bb
    return np.sort(roots)


def ref_algorithm1(b, z_f):
    """Algorithm 1 in float64: (depths, weights, lower, upper); Step 5 by a dense Vandermonde solve."""
    b = np.asarray(b, np.float64)
    m = len(b)
    q = ref_kernel_polynomial(b, z_f)
    if m == 4:
        roots = np.sort(np.roots(q[::-1]).real)  # Step 3: quadratic
    else:
        roots = ref_cubic_blinn(q)  # Step 3: cubic, Sec. 5.4.1
    depths = np.concatenate([[z_f], roots])
    vander = np.vander(depths, increasing=True).T  # A = (z_l^j)
    full = np.concatenate([[1.0], b])
    weights = np.linalg.solve(vander, full[: m // 2 + 1])
    lower = float(np.sum(weights[1:][roots < z_f]))
    return depths, weights, lower, lower + weights[0]


def ref_visibility6(b, z_f, beta):
    """Sec. 5.4.2 in float64: Newton divided differences of v = (beta, [z_f <= z_l]) dotted with (1, b_1, b_2, b_3)."""
    b = np.asarray(b, np.float64)
    z = np.concatenate([[z_f], ref_cubic_blinn(ref_kernel_polynomial(b, z_f))])
    v = np.array([beta] + [1.0 if z_f <= zl else 0.0 for zl in z[1:]])
    coef = v.copy()  # divided differences f_0, f_01, f_012, f_0123 (in place, right-hand sides use old values)
    for k in range(1, 4):
        coef[k:] = (coef[k:] - coef[k - 1 : -1]) / (z[k:] - z[: 4 - k])
    poly = np.array([coef[3]])  # Newton form -> canonical basis: poly <- poly * (z - z_k) + f_0..k
    for k in (2, 1, 0):
        poly = np.concatenate([[0.0], poly]) - z[k] * np.concatenate([poly, [0.0]])
        poly[0] += coef[k]
    return float(poly @ np.concatenate([[1.0], b[:3]]))


def ref_algorithm2(b):
    """Algorithm 2 in float64: depths (ascending) and weights of the two-depth distribution."""
    b1, b2, b3 = (float(x) for x in b[:3])
    q2 = b2 - b1 * b1
    if q2 <= 0.0:
        return np.array([b1, b1]), np.array([1.0, 0.0])
    q1 = b1 * b2 - b3
    q0 = -b1 * q1 - b2 * q2
    z1, z2 = np.sort(np.roots([q2, q1, q0]).real)
    w2 = (b1 - z1) / (z2 - z1)
    return np.array([z1, z2]), np.array([1.0 - w2, w2])


def random_distribution(rng, n_min=1, n_max=8, clamp_fraction=0.2):
    """Random depth distribution on [-1, 1]: depths (some clamped to +-1, as in Sec. 2.5) and Dirichlet weights."""
    n = int(rng.integers(n_min, n_max + 1))
    depths = rng.uniform(-1.0, 1.0, n)
    clamped = rng.random(n) < clamp_fraction
    depths[clamped] = np.sign(depths[clamped])
    return depths, rng.dirichlet(np.ones(n))


def random_cases(seed, count, n_min, n_max, m, clamp_fraction=0.2):
    """count distributions, their float32 moments (m of them) and fragment depths in [-1.1, 1.1] off the support."""
    rng = np.random.default_rng(seed)
    dists, bs, zfs = [], [], []
    for _ in range(count):
        d, w = random_distribution(rng, n_min, n_max, clamp_fraction)
        z_f = rng.uniform(-1.1, 1.1)
        while np.min(np.abs(d - z_f)) < 1e-3:
            z_f = rng.uniform(-1.1, 1.1)
        dists.append((d, w))
        bs.append(dist_moments(d, w, m))
        zfs.append(z_f)
    return dists, np.array(bs, np.float32), np.array(zfs, np.float32)


# ---------------------------------------------------------------------------------------------------------------------
# A user kernel calling the public @wp.funcs (DESIGN.md: the library's functions are public API)
# ---------------------------------------------------------------------------------------------------------------------


@wp.kernel
def user_shading_kernel(
    texels4: wp.array(dtype=wp.vec4),
    texels6: wp.array(dtype=moments.vec6),
    z_f: wp.array(dtype=float),
    light_direction: wp.vec3,
    rays: wp.array(dtype=wp.vec3),
    out: wp.array(dtype=float, ndim=2),
):
    i = wp.tid()
    b4 = moments.load_biased_moments4(texels4[i], moments.STORAGE4_UNORM16)
    out[i, 0] = moments.msm4_shadow_intensity(b4, z_f[i])
    beta = moments.adaptive_overestimation_weight(light_direction, rays[i])
    out[i, 1] = beta
    b6 = moments.load_biased_moments6(texels6[i], moments.STORAGE6_UNORM16)
    out[i, 2] = moments.msm6_interpolated_shadow_intensity(b6, z_f[i], beta)
    depths, weights = moments.two_depth_distribution(wp.vec3(b4[0], b4[1], b4[2]))
    out[i, 3] = depths[0]
    out[i, 4] = weights[1]
    out[i, 5] = moments.scale_shadow_intensity(out[i, 0], moments.OVERDARKENING_DIVISOR)
    bounds = moments.msm4_bounds(b4, z_f[i])
    out[i, 6] = moments.msm4_interpolated_shadow_intensity(b4, z_f[i], beta) - (
        bounds[1] - beta * (bounds[1] - bounds[0])
    )


@wp.kernel
def user_distribution_kernel(
    b4: wp.array(dtype=wp.vec4),
    b6: wp.array(dtype=moments.vec6),
    z_f: wp.array(dtype=float),
    out4: wp.array(dtype=float, ndim=2),
    out6: wp.array(dtype=float, ndim=2),
):
    i = wp.tid()
    d4, w4 = moments.msm4_distribution(b4[i], z_f[i])
    for k in range(3):
        out4[i, k] = d4[k]
        out4[i, 3 + k] = w4[k]
    d6, w6 = moments.msm6_distribution(b6[i], z_f[i])
    for k in range(4):
        out6[i, k] = d6[k]
        out6[i, 4 + k] = w6[k]


@wp.kernel
def user_pivots_kernel(
    b4: wp.array(dtype=wp.vec4),
    storage4: int,
    b6: wp.array(dtype=moments.vec6),
    storage6: int,
    out4: wp.array(dtype=wp.vec2),
    out6: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    out4[i] = moments.hankel_pivots4(moments.load_biased_moments4(moments.store_moments4(b4[i], storage4), storage4))
    out6[i] = moments.hankel_pivots6(moments.load_biased_moments6(moments.store_moments6(b6[i], storage6), storage6))


# ---------------------------------------------------------------------------------------------------------------------
# Tests
# ---------------------------------------------------------------------------------------------------------------------


def test_moment_vectors_are_powers_of_depth():
    z = np.linspace(-1.0, 1.0, 41)
    np.testing.assert_allclose(moments.moments4(z), ref_moments(z, 4), rtol=0, atol=2e-7)
    np.testing.assert_allclose(moments.moments6(z.reshape(41, 1)), ref_moments(z, 6).reshape(41, 1, 6), atol=2e-7)


def test_references_agree_with_independent_solvers():
    """The float64 references themselves: Blinn's roots = numpy.roots, Newton weights = Vandermonde weights."""
    dists, _, zf = random_cases(7, 60, 1, 8, 6)
    for (d, w), z_f in zip(dists, zf.astype(np.float64), strict=True):
        b = ref_bias(dist_moments(d, w, 6), 1e-6, moments.BIAS_VECTOR6)
        q = ref_kernel_polynomial(b, z_f)
        np.testing.assert_allclose(ref_cubic_blinn(q), np.sort(np.roots(q[::-1]).real), atol=1e-9)
        _, _, lower, upper = ref_algorithm1(b, z_f)
        assert abs((1.0 - ref_visibility6(b, z_f, 1.0)) - lower) < 1e-8
        assert abs((1.0 - ref_visibility6(b, z_f, 0.0)) - upper) < 1e-8


def test_algorithm2_reconstructs_two_diracs():
    rng = np.random.default_rng(3)
    n = 300
    depths = np.empty((n, 2))
    for k in range(n):
        depths[k] = np.sort(rng.uniform(-1.0, 1.0, 2))
        while depths[k, 1] - depths[k, 0] < 0.1:
            depths[k] = np.sort(rng.uniform(-1.0, 1.0, 2))
    depths[:20] = [-1.0, 1.0]  # clamped depths (Sec. 2.5 worst case)
    weights = rng.uniform(0.05, 0.95, n)
    weights = np.stack([weights, 1.0 - weights], 1)
    b = np.array([dist_moments(d, w, 4) for d, w in zip(depths, weights, strict=True)])
    for k in range(0, n, 10):  # the algorithm is exact in float64
        rd, rw = ref_algorithm2(b[k])
        np.testing.assert_allclose(rd, depths[k], atol=1e-9)
        np.testing.assert_allclose(rw, weights[k], atol=1e-9)
    got_d, got_w = moments.two_depths_from_moments3(b.astype(np.float32))
    assert np.max(np.abs(got_d - depths)) < 1e-3  # measured 2.0e-5 (seeds 3-6: up to 9.2e-5; float32 moments)
    assert np.max(np.abs(got_w - weights)) < 1e-3  # measured 6.0e-5 (seeds 3-6: up to 2.4e-4)
    np.testing.assert_allclose(got_w.sum(1), 1.0, atol=1e-6)
    # non-positive variance: the single Dirac delta at b_1 (Sec. 5.2)
    d, w = moments.two_depths_from_moments3(np.array([[0.3, 0.09, 0.027], [0.3, 0.05, 0.0]], np.float32))
    np.testing.assert_allclose(d, [[0.3, 0.3], [0.3, 0.3]], atol=1e-7)
    np.testing.assert_allclose(w, [[1.0, 0.0], [1.0, 0.0]])


def test_bounds4_are_sharp_for_two_diracs():
    """Four moments determine a two-depth distribution: lower = Z(z < z_f) and upper = Z(z <= z_f) (Fig. 2).

    Exact in the unbiased limit (float64, alpha = 1e-12). With the float32 storage bias alpha_b = 3e-7 the bounds
    stay sharp on the two depths and away from them, but within ~0.05 of a depth they are smeared (0.27 max error at
    distance 0.02 even in float64): the light leaking that biasing costs (Sec. 2.5).
    """
    rng = np.random.default_rng(11)
    rows = []  # (depths, weights, z_f, distance of z_f to the support); all float32-representable
    for _ in range(200):
        d = np.sort(rng.uniform(-1.0, 1.0, 2)).astype(np.float32).astype(np.float64)
        w = rng.dirichlet([1.0, 1.0])
        for z_f in (d[0], d[1], d[0] - 0.02, d[1] + 0.02, d[0] - 0.1, d[1] + 0.1, rng.uniform(-1.1, 1.1)):
            z_f = float(np.float32(z_f))
            rows.append((d, w, z_f, np.min(np.abs(d - z_f))))
    truth_lo = np.array([shadow_truth(d, w, z_f) for d, w, z_f, _ in rows])
    truth_hi = np.array([np.sum(w[d <= z_f]) for d, w, z_f, _ in rows])
    dist = np.array([r[3] for r in rows])
    err64_on, err64_off = 0.0, 0.0
    for k in range(0, len(rows), 3):
        d, w, z_f, _ = rows[k]  # float64 moments: float32 rounding would dwarf alpha = 1e-12
        _, _, lo, hi = ref_algorithm1(ref_bias(dist_moments(d, w, 4), 1e-12, moments.BIAS_VECTOR4_FLOAT32), z_f)
        err = max(abs(lo - truth_lo[k]), abs(hi - truth_hi[k]))
        if dist[k] == 0.0:
            err64_on = max(err64_on, err)
        elif dist[k] > 0.0199:
            err64_off = max(err64_off, err)
    assert err64_on < 1e-6  # measured 1.5e-8 (seeds 11-13: up to 1.5e-8)
    assert err64_off < 1e-4  # measured 1.3e-5
    b = np.array([dist_moments(d, w, 4) for d, w, _, _ in rows], np.float32)
    zf = np.array([r[2] for r in rows], np.float32)
    got = moments.bounds4(b, zf, alpha=moments.MOMENT_BIAS4_FLOAT32)
    err = np.maximum(np.abs(got[:, 0] - truth_lo), np.abs(got[:, 1] - truth_hi))
    assert np.max(err[dist == 0.0]) < 1e-2  # measured 4.4e-3 (seeds 11-13: 0.9e-3 - 4.4e-3)
    assert np.max(err[dist > 0.0999]) < 1e-2  # measured 3.0e-3 (seeds 11-13: up to 3.9e-3)


@pytest.mark.parametrize("m", [4, 6])
def test_bounds_bracket_the_true_shadow(m):
    """lower <= Z(z < z_f) <= upper for random 1-8 Dirac distributions (biasing moves the truth by <= alpha)."""
    dists, b, zf = random_cases(100 + m, 400, 1, 8, m)
    truth = np.array([shadow_truth(d, w, z) for (d, w), z in zip(dists, zf, strict=True)])
    # float64 reference: alpha = 1e-6 (B is singular for <= m/2 Diracs) -> the bracket holds up to alpha
    alpha64 = 1e-6
    b_star = moments.BIAS_VECTOR4_FLOAT32 if m == 4 else moments.BIAS_VECTOR6
    for k in range(0, len(zf), 4):
        _, _, lo, hi = ref_algorithm1(ref_bias(b[k], alpha64, b_star), float(zf[k]))
        assert lo <= truth[k] + alpha64 + 1e-9 and hi >= truth[k] - alpha64 - 1e-9
    # float32 kernels with the float32 storage mode's bias
    if m == 4:
        got = moments.bounds4(b, zf, alpha=moments.MOMENT_BIAS4_FLOAT32)
        slack = 1e-5  # measured max violation 1.8e-7 (seeds 1-3, 104: up to 2.4e-7; alpha = 3e-7 moves the truth)
    else:
        got = moments.bounds6(b, zf, alpha=moments.MOMENT_BIAS6_FLOAT32)
        slack = 5e-5  # measured max violation 2.9e-6 (seeds 1-3, 106: up to 3.2e-6; alpha = 5e-6)
    assert np.all(got[:, 0] <= truth + slack)
    assert np.all(got[:, 1] >= truth - slack)
    assert np.all(got[:, 0] <= got[:, 1])


def test_six_moment_bounds_are_tighter_than_four():
    dists, b6, zf = random_cases(5, 300, 3, 8, 6, clamp_fraction=0.0)
    w4 = np.diff(moments.bounds4(b6[:, :4], zf, alpha=moments.MOMENT_BIAS4_FLOAT32), axis=-1)
    w6 = np.diff(moments.bounds6(b6, zf, alpha=moments.MOMENT_BIAS6_FLOAT32), axis=-1)
    assert np.mean(w6) < 0.8 * np.mean(w4)  # measured mean width 0.11 (6) vs 0.21 (4)


def _kernel_vs_reference(m, seed, alpha, count=300):
    """Max |kernel - float64 reference| over random 3-8 Dirac distributions for lower, upper and a random beta."""
    dists, b, zf = random_cases(seed, count, 3, 8, m)
    beta = np.random.default_rng(seed + 1).random(count).astype(np.float32)
    if m == 4:
        b_star = moments.BIAS_VECTOR4_FLOAT32
        got = moments.bounds4(b, zf, alpha=alpha, bias_vector=b_star)
        got_beta = moments.shadow_intensity4(b, zf, alpha=alpha, bias_vector=b_star, beta=beta)
    else:
        b_star = moments.BIAS_VECTOR6
        got = moments.bounds6(b, zf, alpha=alpha, bias_vector=b_star)
        got_beta = moments.shadow_intensity6(b, zf, alpha=alpha, bias_vector=b_star, beta=beta)
    ref = np.empty((count, 3))
    for k in range(count):
        bb = ref_bias(b[k], alpha, b_star)
        _, _, lo, hi = ref_algorithm1(bb, float(zf[k]))
        interp = hi - beta[k] * (hi - lo) if m == 4 else 1.0 - ref_visibility6(bb, float(zf[k]), float(beta[k]))
        ref[k] = (np.clip(lo, 0, 1), np.clip(hi, 0, 1), np.clip(interp, 0, 1))
    return np.abs(np.column_stack([got, got_beta]) - ref)


def test_four_moment_kernels_match_float64_reference():
    err = _kernel_vs_reference(4, 21, moments.MOMENT_BIAS4_UNORM16)
    assert np.max(err) < 5e-4  # measured 4.5e-5 (5 seeds: up to 5.7e-5; alpha = 6e-5)
    err = _kernel_vs_reference(4, 22, moments.MOMENT_BIAS4_FLOAT32)
    assert np.max(err) < 2e-2  # measured 5.2e-4 (5 seeds: up to 8.1e-3, alpha = 3e-7: nearly singular matrices)
    assert np.percentile(err, 99) < 5e-5  # measured 4.1e-6


def test_six_moment_kernels_match_float64_reference():
    err = _kernel_vs_reference(6, 31, moments.MOMENT_BIAS6_UNORM16)
    assert np.max(err) < 3e-3  # measured 5.8e-5 (5 seeds: up to 6.1e-4; alpha = 8e-5)
    err = _kernel_vs_reference(6, 32, moments.MOMENT_BIAS6_UNORM10)
    assert np.max(err) < 3e-4  # measured 1.4e-5 (5 seeds: up to 3.0e-5; alpha = 4e-3)
    err = _kernel_vs_reference(6, 33, moments.MOMENT_BIAS6_FLOAT32)
    assert np.max(err) < 1e-2  # measured 1.6e-4 (6 seeds: up to 1.8e-3; alpha = 5e-6)
    assert np.percentile(err, 99) < 5e-4  # measured 5.2e-5 (up to 9.6e-5)


def test_distributions_match_float64_reference():
    """msm4_distribution / msm6_distribution (called from a user kernel) reproduce Algorithm 1's depths and weights."""
    count = 200
    dists, b6, zf = random_cases(41, count, 4, 8, 6, clamp_fraction=0.0)
    alpha4, alpha6 = moments.MOMENT_BIAS4_UNORM16, moments.MOMENT_BIAS6_UNORM16
    b4 = ref_bias(b6[:, :4], alpha4, moments.BIAS_VECTOR4_FLOAT32).astype(np.float32)
    b6b = ref_bias(b6, alpha6, moments.BIAS_VECTOR6).astype(np.float32)
    out4 = wp.zeros((count, 6), dtype=float, device="cpu")
    out6 = wp.zeros((count, 8), dtype=float, device="cpu")
    wp.launch(
        user_distribution_kernel,
        count,
        inputs=[wp.array(b4, dtype=wp.vec4), wp.array(b6b, dtype=moments.vec6), wp.array(zf), out4, out6],
        device="cpu",
    )
    out4, out6 = out4.numpy(), out6.numpy()
    err4_d, err4_w, err6_w = [], [], []
    for k in range(count):
        d, w, _, _ = ref_algorithm1(b4[k].astype(np.float64), float(zf[k]))
        err4_d.append(np.max(np.abs(out4[k, :3] - d) * np.minimum(w, 1.0)))  # a depth matters by its weight
        err4_w.append(np.max(np.abs(out4[k, 3:] - w)))
        d, w, _, _ = ref_algorithm1(b6b[k].astype(np.float64), float(zf[k]))
        err6_w.append(np.max(np.abs(out6[k, 4:] - w)))
        assert abs(out6[k, 4:].sum() - 1.0) < 1e-6 and abs(out4[k, 3:].sum() - 1.0) < 1e-6
    assert max(err4_d) < 1e-5  # measured 2.9e-7 (seeds 41-43: up to 6.5e-7)
    assert max(err4_w) < 1e-4  # measured 2.6e-6 (seeds 41-43: up to 6.9e-6)
    assert max(err6_w) < 2e-3  # measured 4.0e-5 (seeds 41-43: up to 2.4e-4)


def test_cubic_solver_matches_numpy_roots():
    rng = np.random.default_rng(17)
    n = 400
    roots = np.sort(rng.uniform(-1.0, 1.0, (n, 3)), axis=1)
    while np.any(close := np.min(np.diff(roots, axis=1), axis=1) < 0.05):  # double roots are ill-conditioned
        roots[close] = np.sort(rng.uniform(-1.0, 1.0, (int(close.sum()), 3)), axis=1)
    far = np.zeros(n, bool)
    far[n // 2 :] = True  # |q_3| << 1: one root far away (the case Sec. 5.4.1 targets)
    roots[far, 2] = rng.choice([-1.0, 1.0], far.sum()) * 10.0 ** rng.uniform(1.0, 4.0, far.sum())
    roots = np.sort(roots, axis=1)
    coeffs = np.array([np.poly(r)[::-1] for r in roots])  # ascending c_0..c_3, c_3 = 1
    coeffs /= np.max(np.abs(coeffs), axis=1, keepdims=True) * rng.choice([-1.0, 1.0], (n, 1))
    assert np.min(np.abs(coeffs[far, 3])) < 1e-3  # the near-degenerate leading coefficients are there
    got = moments.solve_cubic(coeffs.astype(np.float32)).astype(np.float64)
    ref = np.array([np.sort(np.roots(c[::-1]).real) for c in coeffs.astype(np.float32).astype(np.float64)])
    err = np.abs(got - ref)
    # three roots in [-1, 1]: float32 accuracy
    assert np.max(err[~far]) < 2e-4  # measured 2.9e-6 (seeds 17-20: up to 6.0e-5)
    # one root at 10..1e4: the two roots in [-1, 1] lose precision by cancellation against B = c_2 / (3 c_3) of the
    # single branch; the far root keeps its relative precision
    assert np.max(err[far, :][np.abs(ref[far]) <= 1.0]) < 3e-3  # measured 6.6e-4 (up to 8.1e-4)
    assert np.max((err / np.abs(ref))[far, :][np.abs(ref[far]) > 1.0]) < 2e-6  # measured 1.6e-7 (up to 1.7e-7)
    # the float64 single-branch reference is exact in double precision
    for c, r in zip(coeffs[::20], roots[::20], strict=True):
        np.testing.assert_allclose(ref_cubic_blinn(c), r, rtol=1e-7, atol=1e-9)


def test_quantization_transforms_are_the_papers_and_invertible():
    z = np.linspace(-1.0, 1.0, 2001)
    b4, b6 = ref_moments(z, 4), ref_moments(z, 6)
    theta4 = b4 @ moments.THETA4_MATRIX.T + moments.THETA4_OFFSET
    theta6 = np.concatenate(
        [
            b6[:, 0::2] @ moments.THETA6_ODD_MATRIX + moments.THETA6_ODD_OFFSET,
            b6[:, 1::2] @ moments.THETA6_EVEN_MATRIX + moments.THETA6_EVEN_OFFSET,
        ],
        axis=1,
    )
    # both map b([-1, 1]) into the unit cube (Fig. 3), up to the 8-digit constants of Sec. 5.4.3
    assert theta4.min() > -1e-9 and theta4.max() < 1.0 + 1e-9
    assert theta6.min() > -1e-8 and theta6.max() < 1.0 + 1e-7
    # entropy gains over storing (b_odd + 1) / 2 and b_even directly: 4.21 bits (Sec. 2.4) and 12.5 bits (Sec. 5.4.3)
    gain4 = np.log2(abs(np.linalg.det(moments.THETA4_MATRIX)) * 4.0)
    gain6 = np.log2(abs(np.linalg.det(moments.THETA6_ODD_MATRIX) * np.linalg.det(moments.THETA6_EVEN_MATRIX)) * 8.0)
    assert abs(gain4 - 4.21) < 0.005 and abs(gain6 - 12.5) < 0.05
    # the kernels apply the same transforms and invert them
    got4 = moments.apply_quantization_transform4(b4.astype(np.float32))
    got6 = moments.apply_quantization_transform6(b6.astype(np.float32))
    assert np.max(np.abs(got4 - theta4)) < 1e-6  # measured 2.3e-7
    assert np.max(np.abs(got6 - theta6)) < 5e-6  # measured 1.9e-6 (float32 cancellation in 9 b2 - 24 b4 + 16 b6)
    assert np.max(np.abs(moments.apply_quantization_transform4(got4, inverse=True) - b4)) < 1e-6  # measured 2.1e-7
    assert np.max(np.abs(moments.apply_quantization_transform6(got6, inverse=True) - b6)) < 2e-6  # measured 6.1e-7


@pytest.mark.parametrize(
    ("m", "storage", "bits"),
    [
        (4, moments.STORAGE4_UNORM16, 16),
        (4, moments.STORAGE4_FLOAT32, 0),
        (6, moments.STORAGE6_UNORM10, 10),
        (6, moments.STORAGE6_UNORM16, 16),
        (6, moments.STORAGE6_FLOAT32, 0),
    ],
)
def test_quantization_round_trip_within_resolution(m, storage, bits):
    rng = np.random.default_rng(9)
    b = np.array([dist_moments(*random_distribution(rng), m) for _ in range(500)], np.float32)
    quant, dequant = (moments.quantize4, moments.dequantize4) if m == 4 else (moments.quantize6, moments.dequantize6)
    texels = quant(b, storage)
    back = dequant(texels, storage)
    if bits == 0:  # float32 storage holds the moments themselves
        np.testing.assert_array_equal(texels, b)
        np.testing.assert_array_equal(back, b)
        return
    step = 1.0 / (2**bits - 1)
    assert np.all((texels >= 0.0) & (texels <= 1.0))
    np.testing.assert_allclose(texels / step, np.round(texels / step), atol=1e-3)  # on the n-bit grid
    exact = (moments.apply_quantization_transform4 if m == 4 else moments.apply_quantization_transform6)(b)
    assert np.max(np.abs(texels - exact)) <= 0.5 * step + 1e-6
    if m == 4:
        inv = np.linalg.inv(moments.THETA4_MATRIX)
    else:
        inv = np.zeros((6, 6))
        inv[np.ix_([0, 2, 4], [0, 1, 2])] = np.linalg.inv(moments.THETA6_ODD_MATRIX.T)
        inv[np.ix_([1, 3, 5], [3, 4, 5])] = np.linalg.inv(moments.THETA6_EVEN_MATRIX.T)
    bound = np.abs(inv).sum(axis=1) * 0.5 * step + 2e-6  # |Theta^-1| times half a quantization step, per moment
    assert np.all(np.abs(back - b) <= bound)


def test_bias_vectors_are_valid_moments_on_the_unit_interval():
    """b* lies in conv b([-1, 1]) (Sec. 2.5): Hankel matrix PD and (1 - z^2)-localizing matrix PSD."""
    for b_star in (moments.BIAS_VECTOR4_FLOAT32, moments.BIAS_VECTOR4_QUANTIZED, moments.BIAS_VECTOR6):
        b = np.array(b_star, np.float64)
        assert np.all(ref_pivots(b) > 0.0)
        full = np.concatenate([[1.0], b])
        n = len(b) // 2
        loc = np.array([[full[j + k] - full[j + k + 2] for k in range(n)] for j in range(n)])
        assert np.min(np.linalg.eigvalsh(loc)) > -1e-9
    # b*_4 = 0.375 is the distribution 0.625 delta_0 + 0.1875 (delta_-1 + delta_1)
    np.testing.assert_allclose(
        dist_moments([-1.0, 0.0, 1.0], [0.1875, 0.625, 0.1875], 4), np.array(moments.BIAS_VECTOR4_FLOAT32), atol=1e-12
    )


@pytest.mark.parametrize(
    ("storage4", "storage6"),
    [
        (moments.STORAGE4_UNORM16, moments.STORAGE6_UNORM10),
        (moments.STORAGE4_FLOAT32, moments.STORAGE6_UNORM16),
        (moments.STORAGE4_UNORM16, moments.STORAGE6_FLOAT32),
    ],
)
def test_bias_of_each_storage_mode_restores_valid_moments(storage4, storage6):
    """Stored moments of (worst-case) distributions can be invalid; the mode's alpha_b and b* make them PD."""
    rng = np.random.default_rng(13)
    dists = [random_distribution(rng, 1, 3, clamp_fraction=0.5) for _ in range(400)]
    w = rng.random(100)
    dists += [(np.array([-1.0, 1.0]), np.array([1.0 - x, x])) for x in w]  # Sec. 2.5: clamped depths only
    b4 = np.array([dist_moments(d, w, 4) for d, w in dists], np.float32)
    b6 = np.array([dist_moments(d, w, 6) for d, w in dists], np.float32)
    n = len(dists)
    piv4 = wp.zeros(n, dtype=wp.vec2, device="cpu")
    piv6 = wp.zeros(n, dtype=wp.vec3, device="cpu")
    wp.launch(
        user_pivots_kernel,
        n,
        inputs=[
            wp.array(b4, dtype=wp.vec4),
            int(storage4),
            wp.array(b6, dtype=moments.vec6),
            int(storage6),
            piv4,
            piv6,
        ],
        device="cpu",
    )
    # without bias many stored vectors are not positive definite (float64 check of the float32 values)
    stored4 = moments.dequantize4(moments.quantize4(b4, storage4), storage4).astype(np.float64)
    stored6 = moments.dequantize6(moments.quantize6(b6, storage6), storage6).astype(np.float64)
    assert np.mean([np.any(ref_pivots(b) <= 0.0) for b in stored4]) > 0.2  # measured 0.66-0.67 per mode
    assert np.mean([np.any(ref_pivots(b) <= 0.0) for b in stored6]) > 0.2  # measured 0.85-0.90
    # with the mode's bias: positive definite (float64 pivots of the float32 biased moments)
    a4 = moments.MOMENT_BIAS4_UNORM16 if storage4 == moments.STORAGE4_UNORM16 else moments.MOMENT_BIAS4_FLOAT32
    s4 = moments.BIAS_VECTOR4_QUANTIZED if storage4 == moments.STORAGE4_UNORM16 else moments.BIAS_VECTOR4_FLOAT32
    a6 = {
        int(moments.STORAGE6_UNORM10): moments.MOMENT_BIAS6_UNORM10,
        int(moments.STORAGE6_UNORM16): moments.MOMENT_BIAS6_UNORM16,
        int(moments.STORAGE6_FLOAT32): moments.MOMENT_BIAS6_FLOAT32,
    }[int(storage6)]
    assert all(np.all(ref_pivots(ref_bias(b, a4, s4)) > 0.0) for b in stored4)
    assert all(np.all(ref_pivots(ref_bias(b, a6, moments.BIAS_VECTOR6)) > 0.0) for b in stored6)
    # the float32 kernel's own LDL^T agrees except where alpha_b = 3e-7 leaves pivots at float32 rounding level
    # (there PIVOT_FLOOR takes over); measured: 1 of 500 vectors for STORAGE4_FLOAT32, none for the other modes
    bad4 = np.any(piv4.numpy() <= 0.0, axis=1)
    assert np.all(piv6.numpy() > 0.0)
    if storage4 == moments.STORAGE4_FLOAT32:
        assert np.mean(bad4) <= 0.01
    else:
        assert not np.any(bad4)


def test_biasing_and_beta_semantics():
    dists, b, zf = random_cases(61, 100, 2, 6, 4)
    alpha, b_star = 0.01, moments.BIAS_VECTOR4_QUANTIZED
    biased = ref_bias(b, alpha, b_star).astype(np.float32)
    np.testing.assert_allclose(
        moments.shadow_intensity4(b, zf, alpha=alpha, bias_vector=b_star),
        moments.shadow_intensity4(biased, zf, alpha=0.0),
        atol=1e-5,
    )
    bounds = moments.bounds4(biased, zf)
    np.testing.assert_allclose(moments.shadow_intensity4(biased, zf, alpha=0.0, beta=1.0), bounds[:, 0], atol=1e-7)
    np.testing.assert_allclose(moments.shadow_intensity4(biased, zf, alpha=0.0, beta=0.0), bounds[:, 1], atol=1e-7)
    np.testing.assert_allclose(
        moments.shadow_intensity4(biased, zf, alpha=0.0, beta=0.25),
        0.25 * bounds[:, 0] + 0.75 * bounds[:, 1],
        atol=1e-6,
    )
    b6 = np.array([dist_moments(d, w, 6) for d, w in dists], np.float32)
    bounds6 = moments.bounds6(b6, zf, alpha=0.01)
    np.testing.assert_allclose(moments.shadow_intensity6(b6, zf, alpha=0.01, beta=0.5), bounds6.mean(1), atol=1e-5)


def test_user_kernel_calls_public_functions():
    rng = np.random.default_rng(71)
    count = 64
    dists, b6, zf = random_cases(72, count, 1, 5, 6)
    texels4 = moments.quantize4(b6[:, :4], moments.STORAGE4_UNORM16)
    texels6 = moments.quantize6(b6, moments.STORAGE6_UNORM16)
    light = np.array([0.3, -0.9, 0.2], np.float32)
    light /= np.linalg.norm(light)
    rays = rng.normal(size=(count, 3)).astype(np.float32)
    rays[0], rays[1] = -light, light  # looking into the light, looking along it
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    out = wp.zeros((count, 7), dtype=float, device="cpu")
    wp.launch(
        user_shading_kernel,
        count,
        inputs=[
            wp.array(texels4, dtype=wp.vec4),
            wp.array(texels6, dtype=moments.vec6),
            wp.array(zf),
            wp.vec3(*light),
            wp.array(rays, dtype=wp.vec3),
            out,
        ],
        device="cpu",
    )
    out = out.numpy()
    beta = 0.5 * (1.0 + rays @ light)
    np.testing.assert_allclose(out[:, 1], beta, atol=1e-6)
    assert out[0, 1] < 1e-6 and out[1, 1] > 1.0 - 1e-6  # Sec. 5.3.1: 0 looking into the light
    b4 = moments.dequantize4(texels4, moments.STORAGE4_UNORM16)
    s4 = moments.shadow_intensity4(
        b4, zf, alpha=moments.MOMENT_BIAS4_UNORM16, bias_vector=moments.BIAS_VECTOR4_QUANTIZED
    )
    np.testing.assert_allclose(out[:, 0], s4, atol=1e-6)
    np.testing.assert_allclose(out[:, 5], np.clip(s4 / moments.OVERDARKENING_DIVISOR, 0.0, 1.0), atol=1e-6)
    b6q = moments.dequantize6(texels6, moments.STORAGE6_UNORM16)
    s6 = moments.shadow_intensity6(b6q, zf, alpha=moments.MOMENT_BIAS6_UNORM16, beta=beta.astype(np.float32))
    np.testing.assert_allclose(out[:, 2], s6, atol=1e-5)
    biased4 = (1.0 - moments.MOMENT_BIAS4_UNORM16) * b4 + moments.MOMENT_BIAS4_UNORM16 * np.array(
        moments.BIAS_VECTOR4_QUANTIZED, np.float32
    )
    d, w = moments.two_depths_from_moments3(biased4)
    np.testing.assert_allclose(out[:, 3], d[:, 0], atol=1e-5)
    np.testing.assert_allclose(out[:, 4], w[:, 1], atol=1e-5)
    np.testing.assert_allclose(out[:, 6], 0.0, atol=1e-6)
    truth = np.array([shadow_truth(dd, ww, z) for (dd, ww), z in zip(dists, zf, strict=True)])
    assert np.mean(np.abs(out[:, 0] - truth)) < 0.1  # measured 0.064: 64-bit hard shadows approximate PCF


def test_facade_reexports_both_math_modules():
    """``moments`` re-exports every public name of moment_storage and moment_solvers (the very same objects)."""
    import inspect

    from warpscatter.shadows import moment_solvers, moment_storage

    for mod in (moment_storage, moment_solvers):
        public = [n for n, v in vars(mod).items()
                  if not n.startswith("_") and not inspect.ismodule(v) and n not in ("annotations", "module_options")]
        assert len(public) > 20
        for name in public:
            assert getattr(moments, name) is getattr(mod, name), name
            assert name in moments.__all__, name
    assert all(hasattr(moments, name) for name in moments.__all__)


def test_docs_kernel_through_the_facade_matches_the_host_wrapper(tmp_path, monkeypatch):
    """The user kernel of the docs' example (``my_shadows``, run verbatim from the page: functions and constants
    re-exported by the moments facade) gives bitwise the lower bound of ``moments.bounds4``."""
    import doc_examples

    (_, ns), *_ = doc_examples.run_examples("def my_shadows", tmp_path, monkeypatch)
    dists, b4, zf = random_cases(73, 64, 1, 5, 4)
    out = wp.zeros(len(zf), dtype=float, device="cpu")
    wp.launch(ns["my_shadows"], len(zf), inputs=[wp.array(b4, dtype=wp.vec4), wp.array(zf), out], device="cpu")
    want = moments.bounds4(b4, zf, alpha=moments.MOMENT_BIAS4_FLOAT32, bias_vector=moments.BIAS_VECTOR4_FLOAT32)
    np.testing.assert_array_equal(out.numpy(), want[:, 0])
    truth = np.array([shadow_truth(d, w, z) for (d, w), z in zip(dists, zf, strict=True)])
    assert np.mean(np.abs(out.numpy() - truth)) < 0.08  # measured 0.042: the lower bound approximates PCF


_garbage = st.one_of(st.floats(width=32), st.floats(-2.0, 2.0, width=32), st.sampled_from([0.0, 1.0, -1.0]))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    b4=hnp.arrays(np.float32, (32, 4), elements=_garbage),
    b6=hnp.arrays(np.float32, (32, 6), elements=_garbage),
    zf=hnp.arrays(np.float32, (32,), elements=_garbage),
    beta=st.floats(0.0, 1.0),
    alpha=st.sampled_from([0.0, 6e-5, 0.5]),
)
def test_garbage_moments_never_give_nan(b4, b6, zf, beta, alpha):
    for res in (
        moments.bounds4(b4, zf, alpha=alpha),
        moments.bounds6(b6, zf, alpha=alpha),
        moments.shadow_intensity4(b4, zf, alpha=alpha, beta=beta),
        moments.shadow_intensity6(b6, zf, alpha=alpha, beta=beta),
    ):
        assert np.all(np.isfinite(res)) and np.all((res >= 0.0) & (res <= 1.0))
    lo_hi = moments.bounds4(b4, zf)
    assert np.all(lo_hi[:, 0] <= lo_hi[:, 1])
    d, w = moments.two_depths_from_moments3(b4)
    assert np.all(np.isfinite(d)) and np.all((w >= 0.0) & (w <= 1.0))
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-6)
    assert np.all(np.isfinite(moments.solve_cubic(b4)))
    assert np.all(np.isfinite(moments.dequantize6(moments.quantize6(b6))))


def test_degenerate_moments_use_the_documented_fallbacks():
    """Zero variance (a single depth, unbiased): the single Dirac delta at b_1; NaN moments are sanitized."""
    mu = np.array([0.3, -0.6], np.float32)
    b4, b6 = moments.moments4(mu), moments.moments6(mu)
    for z_f, expect in ((-0.9, [0.0, 0.0]), (0.95, [1.0, 1.0]), (mu, [0.0, 1.0])):
        np.testing.assert_array_equal(moments.bounds4(b4, z_f), [expect, expect])
        np.testing.assert_array_equal(moments.bounds6(b6, z_f), [expect, expect])
    np.testing.assert_array_equal(moments.shadow_intensity6(b6, mu, alpha=0.0, beta=0.25), [0.75, 0.75])
    nan4 = np.full((1, 4), np.nan, np.float32)
    np.testing.assert_allclose(moments.bounds4(nan4, 0.5), moments.bounds4(np.array(moments.BIAS_VECTOR4_FLOAT32)[None],
                                                                           0.5))


def test_invalid_arguments_raise():
    b = np.zeros((3, 4), np.float32)
    with pytest.raises(ValueError, match="b: expected"):
        moments.shadow_intensity4(np.zeros((3, 5)), 0.0)
    with pytest.raises(ValueError, match="alpha"):
        moments.shadow_intensity4(b, 0.0, alpha=1.5)
    with pytest.raises(ValueError, match="beta"):
        moments.shadow_intensity6(np.zeros((3, 6)), 0.0, beta=-0.1)
    with pytest.raises(ValueError, match="z_f"):
        moments.bounds4(b, np.zeros(4))
    with pytest.raises(ValueError, match="storage"):
        moments.quantize4(b, storage=7)
    with pytest.raises(ValueError, match="b: expected moments"):
        moments.two_depths_from_moments3(np.zeros((2, 5)))
    with pytest.raises(ValueError, match="coeffs"):
        moments.solve_cubic(np.zeros(3))
