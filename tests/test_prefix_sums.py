"""Tests of the Fourier and moment prefix sums and their look-ups (warpscatter.scattering.prefix_sums,
filtered_lookups; Klehm 2014 Sec. 3, Eq. 8-11, App. A)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp

from warpscatter.scattering import filtered_lookups as fl
from warpscatter.scattering import prefix_sums as pf
from warpscatter.scattering.rectify_nonlinear import NonlinearRectification, reference_ray
from warpscatter.scene.camera import Camera
from warpscatter.wpinit import default_device, module_options

module_options()

MARGIN = 0.5 * 0.1 / 1.1  # frustum rays have rectified depth in [MARGIN, 1 - MARGIN] (10 % guard band)


# ---- float64 references ----------------------------------------------------------------------------------


def _np_basis(z: np.ndarray, m: int) -> np.ndarray:
    """B_k(z) of Klehm 2014 Eq. 8, 0-based k, shape z.shape + (m,)."""
    c = np.pi * (2 * (np.arange(m) // 2) + 1)
    ang = c * np.asarray(z, np.float64)[..., None]
    return np.where(np.arange(m) % 2 == 0, np.sin(ang), np.cos(ang))


def _np_coefficients(z: np.ndarray, m: int) -> np.ndarray:
    c = np.pi * (2 * (np.arange(m) // 2) + 1)
    ang = c * np.asarray(z, np.float64)[..., None]
    return np.where(np.arange(m) % 2 == 0, 2.0 / c * np.cos(ang), -2.0 / c * np.sin(ang))


def _np_prefix(depth: np.ndarray, m: int, tau: np.ndarray) -> np.ndarray:
    """cumsum(w B) / cumsum(w) per row, w_i = exp(-(i-1) tau) - exp(-i tau) (Eq. 11) or 1 when tau = 0."""
    b = _np_basis(depth, m)
    i = np.arange(1, depth.shape[1] + 1, dtype=np.float64)
    out = np.empty_like(b)
    for j, t in enumerate(np.asarray(tau, np.float64)):
        w = np.ones_like(i) if t == 0.0 else np.exp(-(i - 1) * t) - np.exp(-i * t)
        out[j] = np.cumsum(w[:, None] * b[j], axis=0) / np.cumsum(w)[:, None]
    return out


# ---- basis functions -----------------------------------------------------------------------------------------


def test_fourier_funcs_in_user_kernel():
    """A user kernel calls the public @wp.funcs; Eq. 9 converges to the step H away from the jump."""

    @wp.kernel
    def user_kernel(
        zr: wp.array(dtype=float),
        zi: wp.array(dtype=float),
        m: int,
        a: wp.array2d(dtype=float),
        b: wp.array2d(dtype=float),
        step: wp.array(dtype=float),
    ):
        n = wp.tid()
        for k in range(m):
            a[n, k] = pf.fourier_coefficient(k, zr[n])
            b[n, k] = pf.fourier_basis(k, zi[n])
        step[n] = pf.fourier_step(m, zr[n], zi[n])

    device = default_device()
    rng = np.random.default_rng(0)
    zr, zi = rng.uniform(0.0, 1.0, 2000), rng.uniform(0.0, 1.0, 2000)
    m = 128
    a = wp.empty((2000, m), dtype=float, device=device)
    b = wp.empty((2000, m), dtype=float, device=device)
    step = wp.empty(2000, dtype=float, device=device)
    wp.launch(
        user_kernel,
        2000,
        [wp.array(zr, dtype=float, device=device), wp.array(zi, dtype=float, device=device), m, a, b, step],
        device=device,
    )
    assert np.abs(a.numpy() - _np_coefficients(zr, m)).max() < 1e-5  # measured 2.9e-7
    assert np.abs(b.numpy() - _np_basis(zi, m)).max() < 2e-4  # measured 4.5e-5 (float32 arguments c z, c <= 128 pi)
    far = np.abs(zr - zi) > 0.05
    h = (zr <= zi).astype(float)  # V = 1 when the ray depth is not behind the blocker
    assert np.abs(step.numpy() - h)[far].max() < 0.04  # measured 0.018 for M = 128 (Gibbs tail 0.05 from the jump)


# ---- prefix sums ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("m, tol", [(4, 3e-6), (32, 3e-5), (128, 1.5e-4)])  # measured 6.9e-7, 6.6e-6, 3.6e-5
def test_prefix_sums_match_float64(m, tol):
    """Fused (Listing 3) and two-pass (Listings 1-2) filters equal cumsum(w B) / cumsum(w) in float64."""
    rng = np.random.default_rng(m)
    rows, cols = 12, 384
    depth = rng.uniform(0.0, 1.0, (rows, cols)).astype(np.float32)
    depth[3, 100:] = 1.0  # empty texels
    tau = np.array([0.0, 0.0, 1e-4, 3e-3, 0.01, 0.02, 0.05, 0.2, 1.0, 5.0, 30.0, 100.0], np.float32)
    ref = _np_prefix(depth, m, tau)
    fused = pf.prefilter_depth(depth, m, tau).numpy()
    assert fused.shape == (rows, cols, m) and fused.dtype == np.float32
    two_pass = pf.prefix_filter(pf.fourier_basis_textures(depth, m), tau, bases_per_thread=2).numpy()
    assert np.abs(fused - ref).max() < tol
    assert np.abs(two_pass - ref).max() < tol
    # basis grouping of the two-pass filter does not change the result
    grouped = pf.prefix_filter(pf.fourier_basis_textures(depth, m), tau, bases_per_thread=min(m, 6)).numpy()
    assert np.array_equal(grouped, two_pass)
    # no weights (optical_step None) is the plain average of Listing 1
    avg = pf.prefilter_depth(depth, m).numpy()
    assert np.abs(avg - _np_prefix(depth, m, np.zeros(rows))).max() < tol


def test_eight_bit_storage():
    """bits=8 stores every filtered value on the RGBA8 grid, within half a step of the float value."""
    rng = np.random.default_rng(3)
    depth = rng.uniform(0.0, 1.0, (6, 200)).astype(np.float32)
    tau = np.full(6, 0.01, np.float32)
    full = pf.prefilter_depth(depth, 32, tau).numpy()
    q8 = pf.prefilter_depth(depth, 32, tau, bits=8).numpy()
    code = (q8 + 1.0) * 0.5 * 255.0
    assert np.abs(code - np.round(code)).max() < 1e-4  # measured 3.8e-6 (float32 mapping)
    assert np.abs(q8 - full).max() <= 1.0 / 255.0 + 1e-6  # half a step of 2/255
    b8 = pf.fourier_basis_textures(depth, 32, bits=8).numpy()
    code = (b8 + 1.0) * 0.5 * 255.0
    assert np.abs(code - np.round(code)).max() < 1e-4
    # visibility from 8-bit textures stays close to float storage (Klehm 2014 Sec. 3.3)
    q = np.stack([rng.uniform(0.0, 1.0, 3000), rng.uniform(0.0, 1.0, 3000), rng.uniform(MARGIN, 1 - MARGIN, 3000)], 1)
    diff = np.abs(fl.evaluate_visibility(q8, q) - fl.evaluate_visibility(full, q))
    assert diff.max() < 0.015  # measured 0.0046


# ---- evaluation ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("m, worst, mean", [(4, 0.35, 0.06), (32, 0.06, 0.01), (128, 0.02, 0.003)])
def test_no_occluder_average_visibility_is_one(m, worst, mean):
    """All blockers at the far end: average visibility 1 up to the truncated series' ringing."""
    rng = np.random.default_rng(4)
    fb = pf.prefilter_depth(np.ones((8, 256), np.float32), m)
    q = np.stack([rng.uniform(0.0, 1.0, 4000), rng.uniform(0.0, 1.0, 4000), rng.uniform(MARGIN, 1 - MARGIN, 4000)], 1)
    f = fl.evaluate_visibility(fb, q)
    assert f.max() <= 1.0
    # measured 1 - min: 0.32 (M=4), 0.049 (32), 0.017 (128); mean 0.047, 0.0061, 0.0016
    assert 1.0 - f.min() < worst and np.mean(1.0 - f) < mean


@pytest.mark.parametrize("m, tol", [(32, 0.06), (128, 0.015)])  # measured 0.048 and 0.0082 (worst relative error)
def test_no_occluder_transmittance_integral(m, tol):
    """Per-pixel path from world end points: F * integral_0^s exp(-sigma_t t) dt equals the analytic integral."""
    cam = Camera(position=[1, 2, 10], look_at=[0, 1, 0], up=[0, 1, 0], fov_y=55, width=24, height=16, near=0.1, far=40)
    sigma_t = 0.15
    for light in ([-0.3, -0.8, -0.5], cam.forward, -cam.forward):
        rect = NonlinearRectification.from_camera(cam, light, rows=64, cols=128)
        tau = reference_ray(rect).optical_steps(sigma_t)
        fb = pf.prefilter_depth(np.ones((rect.rows, rect.cols), np.float32), m, tau)
        dirs = cam.ray_directions().reshape(-1, 3)
        s = np.random.default_rng(5).uniform(0.05, 1.0, len(dirs)) * cam.far_distance(dirs)
        frac, integral = fl.evaluate_points(fb, rect, cam.position + s[:, None] * dirs, sigma_t)
        exact = (1.0 - np.exp(-sigma_t * s)) / sigma_t
        assert np.abs(integral / exact - 1.0).max() < tol
        np.testing.assert_allclose(integral, frac * exact, rtol=1e-5)
        # sigma_t = 0: the integral is F * s (the average-visibility form of Eq. 2)
        _, lin = fl.evaluate_points(fb, rect, cam.position + s[:, None] * dirs, 0.0)
        np.testing.assert_allclose(lin, frac * s, rtol=1e-5)


def _step_map(rows, cols, z_block):
    """A planar occluder in the rectified map: columns >= start[j] of row j hold blocker depth z_block."""
    start = np.linspace(0.1, 0.9, rows) * cols
    start = start.astype(int)
    depth = np.ones((rows, cols), np.float32)
    for j in range(rows):
        depth[j, start[j] :] = z_block
    return depth, start


def _exact_step_fraction(u, z_r, start, z_block, cols, tau):
    """Weighted lit fraction of a ray ending at column position u * cols (continuous, weights exp(-tau x))."""
    p = u * cols
    if tau == 0.0:
        total, lit_block = p, np.minimum(p, start)
    else:
        total = -np.expm1(-tau * p) / tau
        lit_block = -np.expm1(-tau * np.minimum(p, start)) / tau
    return np.where(z_r <= z_block, 1.0, lit_block / total)


@pytest.mark.parametrize("tau", [0.0, 0.02])
def test_step_occluder_ringing_decreases_with_m(tau):
    rows, cols, z_block = 8, 256, 0.5
    depth, start = _step_map(rows, cols, z_block)
    rng = np.random.default_rng(6)
    n = 4000
    row = rng.integers(0, rows, n)
    q = np.stack([rng.uniform(0.01, 1.0, n), (row + 0.5) / rows, rng.uniform(MARGIN, 1 - MARGIN, n)], 1)
    exact = _exact_step_fraction(q[:, 0], q[:, 2], start[row], z_block, cols, tau)
    errors = []
    for m in (4, 32, 128):
        f = fl.evaluate_visibility(pf.prefilter_depth(depth, m, np.full(rows, tau, np.float32)), q)
        errors.append(np.mean(np.abs(f - exact)))
    # measured mean |error| (tau 0 / 0.02): M=4 0.053 / 0.048, M=32 0.0088 / 0.0075, M=128 0.0024 / 0.0020
    assert errors[0] > 2.0 * errors[1] > 4.0 * errors[2]
    assert errors[2] < 0.004


def test_row_wrap_for_full_circle():
    """With wrap_rows the rows at v = 0 and v = 1 are neighbours; without it the edge row is clamped."""
    depth = np.ones((8, 64), np.float32)
    depth[-1, :] = 0.0  # last row fully blocked for every ray
    fb = pf.prefilter_depth(depth, 32)
    q = np.array([[0.5, 0.0, 0.5], [0.5, 1.0, 0.5], [0.5, 0.5 / 8, 0.5]])
    wrapped = fl.evaluate_visibility(fb, q, wrap_rows=True)
    clamped = fl.evaluate_visibility(fb, q, wrap_rows=False)
    assert wrapped[0] == pytest.approx(0.5, abs=0.02)  # measured 0.5: halfway between row 0 and the last row
    assert wrapped[1] == pytest.approx(0.5, abs=0.02)
    assert clamped[0] == pytest.approx(1.0, abs=0.02) and clamped[1] == pytest.approx(0.0, abs=0.02)
    assert wrapped[2] == pytest.approx(1.0, abs=0.02)  # a row centre reads that row alone (measured 0.990, ringing)


# ---- end to end against exact visibility ------------------------------------------------------------------


def _analytic_rectified_map(rect, spheres):
    """Rectified blocker depth straight from the geometry: each texel's light ray is intersected with the spheres."""
    u = (np.arange(rect.cols) + 0.5) / rect.cols
    v = (np.arange(rect.rows) + 0.5) / rect.rows
    r = u[None, :] * rect.r_max
    phi = rect.phi_mid + (v[:, None] - 0.5) * rect.phi_span
    x, y = r * np.cos(phi), r * np.sin(phi)
    base = rect.position + np.stack([x, y, np.zeros_like(x)], -1) @ rect.to_light  # light-view z = 0
    light = rect.light_direction
    z_hit = np.full(base.shape[:2], np.inf)  # light-view z of the first caster on each texel's light ray
    for c, rad in spheres:
        oc = base - c
        b = oc @ light
        disc = b * b - (np.sum(oc * oc, -1) - rad * rad)
        z_hit = np.where(disc >= 0.0, np.minimum(z_hit, -b - np.sqrt(np.maximum(disc, 0.0))), z_hit)
    theta = np.arctan2(np.broadcast_to(r, z_hit.shape), z_hit)
    depth = np.where(np.isfinite(z_hit), np.clip((rect.theta_hi - theta) / rect.theta_len, 0.0, 1.0), 1.0)
    return depth.astype(np.float32)


def _exact_integral(cam, dirs, s, light, spheres, sigma_t, steps=2000):
    """integral_0^s exp(-sigma_t t) V(x_t) dt by midpoint quadrature with analytic sphere visibility."""
    total = np.zeros(len(dirs))
    for k in range(steps):
        t = (k + 0.5) / steps * s
        x = cam.position + t[:, None] * dirs
        lit = np.ones(len(dirs), bool)
        for c, rad in spheres:
            oc = x - c
            b = oc @ (-light)
            disc = b * b - (np.sum(oc * oc, 1) - rad * rad)
            lit &= ~((disc >= 0.0) & (-b + np.sqrt(np.maximum(disc, 0.0)) > 0.0))
        total += lit * np.exp(-sigma_t * t) * s / steps
    return total


def test_end_to_end_against_exact_visibility():
    """Prefiltered F * integral against quadrature with exact visibility along pixel rays ending on the far plane."""
    light = np.array([-0.3, -0.8, -0.5])
    light /= np.linalg.norm(light)
    cam = Camera(position=[0, 2, 12], look_at=[0, 1, 0], up=[0, 1, 0], fov_y=60, width=24, height=16, near=0.1, far=25)
    spheres = [(np.array([0.0, 2.0, 0.0]), 3.0), (np.array([3.0, 1.0, 4.0]), 1.5), (np.array([-2.0, 3.5, 7.0]), 1.2)]
    sigma_t = 0.08
    rect = NonlinearRectification.from_camera(cam, light, rows=256, cols=512)
    depth = _analytic_rectified_map(rect, spheres)
    dirs = cam.ray_directions().reshape(-1, 3)
    s = cam.far_distance(dirs)
    exact = _exact_integral(cam, dirs, s, light, spheres, sigma_t)
    unocc = (1.0 - np.exp(-sigma_t * s)) / sigma_t
    assert 0.05 < 1.0 - exact.sum() / unocc.sum()  # the rays see shadows (measured 0.078 of the light blocked)
    tau = reference_ray(rect).optical_steps(sigma_t)
    rel = {}
    for m in (4, 32, 128):
        _, integral = fl.evaluate_points(
            pf.prefilter_depth(depth, m, tau), rect, cam.position + s[:, None] * dirs, sigma_t
        )
        rel[m] = np.abs(integral - exact).sum() / exact.sum()
    # average visibility (Eq. 2) for comparison: transmittance weighting must be at least as good
    _, avg = fl.evaluate_points(pf.prefilter_depth(depth, 32), rect, cam.position + s[:, None] * dirs, sigma_t)
    rel_avg = np.abs(avg - exact).sum() / exact.sum()
    # measured relative L1: M=4 0.043, M=32 0.0106, M=128 0.0071; average visibility (M=32) 0.029
    assert rel[32] < 0.02 and rel[128] < 0.015
    assert rel[4] > rel[32] > rel[128]
    assert rel[32] < rel_avg


def test_bad_input_raises():
    depth = np.zeros((4, 8), np.float32)
    for m in (3, 2, 130, 6.5):
        with pytest.raises(ValueError, match="num_coefficients"):
            pf.prefilter_depth(depth, m)
    with pytest.raises(ValueError, match="bits"):
        pf.prefilter_depth(depth, 8, bits=20)
    with pytest.raises(ValueError, match="bases_per_thread"):
        pf.prefix_filter(np.zeros((4, 8, 8), np.float32), bases_per_thread=3)
    with pytest.raises(ValueError, match="optical_step"):
        pf.prefilter_depth(depth, 8, np.full(4, -1.0))
    with pytest.raises(ValueError, match="optical_step"):
        pf.prefilter_depth(depth, 8, np.zeros(5))
    with pytest.raises(ValueError, match="rectified_depth"):
        pf.prefilter_depth(np.zeros(8, np.float32), 8)
    with pytest.raises(ValueError, match="coords"):
        fl.evaluate_visibility(pf.prefilter_depth(depth, 8), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="sigma_t"):
        cam = Camera(
            position=[0, 2, 10], look_at=[0, 1, 0], up=[0, 1, 0], fov_y=50, width=16, height=9, near=0.1, far=20
        )
        rect = NonlinearRectification.from_camera(cam, [0, -1, 0], rows=4, cols=8)
        fl.evaluate_points(pf.prefilter_depth(depth, 8), rect, np.zeros((2, 3)), sigma_t=-1.0)
    assert math.isfinite(float(fl.evaluate_visibility(pf.prefilter_depth(depth, 8), np.zeros((1, 3)))[0]))


# ---- two depths per texel (filtering during resampling, Peters 2017 Sec. 5.2) -------------------------------


def _sparse(z1, z2, w2):
    from warpscatter.scattering.rectify_nonlinear import SparseRectifiedDepth

    dev = wp.get_device()
    return SparseRectifiedDepth(*(wp.array(np.ascontiguousarray(a, np.float32), dtype=wp.float32, device=dev)
                                  for a in (z1, z2, w2)))


def _weighted_prefix_mean(basis: np.ndarray, tau: float) -> np.ndarray:
    """Normalised transmittance-weighted prefix means along axis 1 of (rows, cols, K) values (float64)."""
    cols = basis.shape[1]
    w = np.exp(-tau * np.arange(cols)) * (-np.expm1(-tau) / tau)
    return np.cumsum(w[None, :, None] * basis, axis=1) / np.cumsum(w)[None, :, None]


def test_two_depth_texels_filter_the_weighted_basis_mix():
    """A texel (z_1, z_2, w_2) filters (1 - w_2) B(z_1) + w_2 B(z_2) for the Fourier basis and for the moments;
    w_2 = 0 is bitwise the plain depth map."""
    rng = np.random.default_rng(4)
    rows, cols, tau = 6, 40, 0.07
    z1, z2 = rng.uniform(0.0, 1.0, (2, rows, cols))
    w2 = rng.uniform(0.0, 1.0, (rows, cols))
    w2[:, ::5] = 0.0
    k = np.arange(8)
    c = np.pi * (2 * (k // 2) + 1)

    def fourier(z):
        return np.where(k % 2 == 0, np.sin(c * z[..., None]), np.cos(c * z[..., None]))

    got = pf.prefilter_weighted(_sparse(z1, z2, w2), 8, tau).basis.numpy()
    mix = (1.0 - w2[..., None]) * fourier(z1) + w2[..., None] * fourier(z2)
    assert np.abs(got - _weighted_prefix_mean(mix, tau)).max() < 2e-5  # measured 8.3e-7
    for m in (4, 6):
        bits = 128 if m == 4 else 192  # float32 storage: the canonical moments
        got = pf.prefilter_moments(_sparse(z1, z2, w2), m, tau, storage_bits=bits).numpy()
        p = np.arange(1, m + 1)
        s1, s2 = 2.0 * z1[..., None] - 1.0, 2.0 * z2[..., None] - 1.0
        mix = (1.0 - w2[..., None]) * s1**p + w2[..., None] * s2**p
        assert np.abs(got - _weighted_prefix_mean(mix, tau)).max() < 2e-5  # measured 1.0e-7 (4), 1.2e-7 (6)
    # the single-depth path is the w_2 = 0 case
    zero = np.zeros_like(w2)
    for a, b in ((pf.prefilter_weighted(_sparse(z1, z2, zero), 8, tau).basis, pf.prefilter_weighted(z1, 8, tau).basis),
                 (pf.prefilter_moments(_sparse(z1, z2, zero), 6, tau), pf.prefilter_moments(z1, 6, tau))):
        assert np.array_equal(a.numpy(), b.numpy())


def test_filtered_resampling_and_mipmapped_shadows_through_the_pipeline():
    """configs/canopy_moments.yaml turns on both: the stats report them and every image is finite."""
    from pathlib import Path

    from warpscatter.config import load_config
    from warpscatter.pipeline import render

    root = Path(__file__).resolve().parent.parent
    for method in ("moments6", "fourier"):
        cfg = load_config(root / "configs" / "canopy_moments.yaml",
                          ["camera.width=64", "camera.height=36", "render.scattering.shadow_map.resolution=128",
                           f"render.scattering.method={method}", "render.scattering.moments.storage_bits=null"])
        result = render(cfg, write=False)
        assert result.stats["resample_filter"] == "moments" and result.stats["resample_filter_px"] >= 1
        assert result.stats["msm_sampling"] == "mipmap" and result.stats["rectification"] == "nonlinear"
        for name, img in result.images.items():
            assert np.isfinite(img).all(), name
        assert result.images["scattering"].max() > 0.0
