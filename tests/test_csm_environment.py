"""Monte-Carlo environment lighting with CSM visibility (Ritschel 2007 Sec. 5): environment-map importance sampling,
BRDF sampling densities, MIS convergence to analytic results, CSM vs. shadow-ray visibility, progressive passes."""

from pathlib import Path

import numpy as np
import pytest
import scipy.stats
import trimesh
import warp as wp

from warpscatter.csm import build_csm
from warpscatter.csm.brdf import brdf_eval, brdf_pdf, brdf_sample
from warpscatter.csm.depthmaps import latlong_param
from warpscatter.csm.direct_lighting import ProgressiveAccumulator
from warpscatter.csm.environment import shade_environment
from warpscatter.io.images import read_image
from warpscatter.raster.raycast import build_mesh
from warpscatter.scene.environment_map import (
    EnvData,
    EnvironmentMap,
    cdf_search,
    cdf_search_row,
    env_direction,
    env_lookup,
    env_lookup_uv,
    env_pdf,
    env_pdf_uv,
    env_sample,
    env_sample_uv,
    guided_search,
    guided_search_row,
)

SKY = Path(__file__).resolve().parents[1] / "assets" / "sky_small.exr"


@pytest.fixture(scope="module")
def sky():
    return EnvironmentMap(read_image(SKY))


@wp.kernel
def _env_sample_kernel(env: EnvData, seed: int, dirs: wp.array(dtype=wp.vec3), rad: wp.array(dtype=wp.vec3),
                       pdf: wp.array(dtype=wp.float32), pdf2: wp.array(dtype=wp.float32),
                       rad2: wp.array(dtype=wp.vec3)):
    k = wp.tid()
    rng = wp.rand_init(seed, k)
    d, r, p = env_sample(env, wp.vec2(wp.randf(rng), wp.randf(rng)))
    dirs[k] = d
    rad[k] = r
    pdf[k] = p
    pdf2[k] = env_pdf(env, d)
    rad2[k] = env_lookup(env, d)


@wp.kernel
def _env_pdf_kernel(env: EnvData, dirs: wp.array(dtype=wp.vec3), pdf: wp.array(dtype=wp.float32)):
    k = wp.tid()
    pdf[k] = env_pdf(env, dirs[k])


def _sample_env(env, n, seed=7):
    out = [wp.empty(n, dtype=t) for t in (wp.vec3, wp.vec3, wp.float32, wp.float32, wp.vec3)]
    wp.launch(_env_sample_kernel, dim=n, inputs=[env.device_data(), seed, *out], device="cpu")
    return [a.numpy() for a in out]


def _texel_of(d, w, h):
    theta = np.arccos(np.clip(d[:, 1], -1.0, 1.0))
    phi = np.mod(np.arctan2(d[:, 2], d[:, 0]), 2.0 * np.pi)
    j = np.minimum((theta / np.pi * h).astype(int), h - 1)
    i = np.minimum((phi / (2.0 * np.pi) * w).astype(int), w - 1)
    return j, i


def test_env_sample_histogram_matches_the_texel_probabilities(sky):
    n = 200_000
    d, rad, pdf, pdf2, rad2 = _sample_env(sky, n)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-5)
    j, i = _texel_of(d, sky.width, sky.height)
    # the returned radiance / pdf are those of the texel the direction lies in, as env_lookup / env_pdf say
    same = (rad == rad2).all(axis=1)
    assert same.mean() > 0.9999  # measured 1.0 (a texel-border rounding may differ)
    rel = np.abs(pdf - pdf2) / np.maximum(pdf2, 1e-30)
    assert rel.max() < 1e-4  # measured 3.4e-7 (sin theta from the direction, not sqrt(1 - y^2))
    counts = np.zeros((sky.height, sky.width))
    np.add.at(counts, (j, i), 1)
    expected = sky.texel_pdf.astype(np.float64) / (sky.width * sky.height) * n
    assert counts[expected == 0].sum() == 0
    big = expected >= 5.0
    obs = np.append(counts[big], counts[~big].sum())
    exp = np.append(expected[big], expected[~big].sum())
    chi2 = ((obs - exp) ** 2 / np.maximum(exp, 1e-12)).sum()
    p_value = scipy.stats.chi2.sf(chi2, len(obs) - 1)
    assert p_value > 1e-3  # measured p = 0.34 (chi2 2010 over 1984 dof)
    # row marginal: luminance x sin(theta)-weighted rows get their share
    rows = counts.sum(axis=1) / n
    assert np.abs(rows - np.diff(sky.marginal_cdf)).max() < 0.004  # measured 0.0012


def test_env_sample_estimates_the_sphere_integral(sky):
    """E[L / pdf] over env samples = integral of L over the sphere = sum of texel radiance x texel solid angle."""
    d, rad, pdf, _, _ = _sample_env(sky, 50_000, seed=3)
    assert np.all(pdf > 0.0)
    est = (rad / pdf[:, None]).mean(axis=0)
    exact = (sky.image.astype(np.float64) * sky.texel_solid_angles()[:, :, None]).sum(axis=(0, 1))
    assert np.all(np.abs(est / exact - 1.0) < 0.01)  # measured 0.0010, 0.00002, 0.0014 (rgb)


def test_env_pdf_integrates_to_one(sky):
    """Midpoint quadrature over a grid 4x finer than the map with exact solid angles per cell."""
    h, w = 4 * sky.height, 4 * sky.width
    edges = np.pi * np.arange(h + 1) / h
    theta = 0.5 * (edges[:-1] + edges[1:])
    phi = 2.0 * np.pi * (np.arange(w) + 0.5) / w
    t, p = np.meshgrid(theta, phi, indexing="ij")
    dirs = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], -1).reshape(-1, 3).astype(np.float32)
    out = wp.empty(dirs.shape[0], dtype=wp.float32)
    wp.launch(_env_pdf_kernel, dim=dirs.shape[0], inputs=[sky.device_data(), wp.array(dirs, dtype=wp.vec3), out],
              device="cpu")
    d_omega = (np.cos(edges[:-1]) - np.cos(edges[1:]))[:, None] * (2.0 * np.pi / w)
    total = (out.numpy().reshape(h, w) * d_omega).sum()
    assert abs(total - 1.0) < 1e-3  # measured 2.5e-5
    # a black map is sampled uniformly on the sphere: pdf ~ 1 / (4 pi) away from the poles
    black = EnvironmentMap(np.zeros((8, 16, 3), np.float32))
    wp.launch(_env_pdf_kernel, dim=dirs.shape[0], inputs=[black.device_data(), wp.array(dirs, dtype=wp.vec3), out],
              device="cpu")
    assert abs((out.numpy().reshape(h, w) * d_omega).sum() - 1.0) < 1e-3  # measured 2.5e-5


@wp.kernel
def _brdf_kernel(n: wp.vec3, wo: wp.vec3, kd: wp.vec3, ks: wp.vec3, e: float, dirs: wp.array(dtype=wp.vec3),
                 pdf: wp.array(dtype=wp.float32), fcos: wp.array(dtype=wp.float32), seed: int,
                 samp_ratio: wp.array(dtype=wp.float32)):
    k = wp.tid()
    wi = dirs[k]
    pdf[k] = brdf_pdf(n, wo, wi, kd, ks, e)
    fcos[k] = brdf_eval(n, wo, wi, kd, ks, e)[0] * wp.max(wp.dot(n, wi), 0.0)
    rng = wp.rand_init(seed, k)
    xi = wp.vec2(wp.randf(rng), wp.randf(rng))
    s = brdf_sample(n, wo, kd, ks, e, xi, wp.randf(rng))
    p = brdf_pdf(n, wo, s, kd, ks, e)
    samp_ratio[k] = 0.0
    if p > 0.0:
        samp_ratio[k] = brdf_eval(n, wo, s, kd, ks, e)[0] * wp.max(wp.dot(n, s), 0.0) / p


def test_brdf_sampling_density_and_estimator():
    """brdf_pdf integrates to 1 (quadrature) and E[f cos / pdf] over brdf_sample equals the quadrature of f cos."""
    h, w = 400, 800
    edges = np.pi * np.arange(h + 1) / h
    theta = 0.5 * (edges[:-1] + edges[1:])
    phi = 2.0 * np.pi * (np.arange(w) + 0.5) / w
    t, p = np.meshgrid(theta, phi, indexing="ij")
    dirs = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], -1).reshape(-1, 3).astype(np.float32)
    d_omega = ((np.cos(edges[:-1]) - np.cos(edges[1:]))[:, None] * (2.0 * np.pi / w) * np.ones((1, w))).ravel()
    n = wp.vec3(0.0, 1.0, 0.0)
    wo = wp.vec3(*(np.array([0.6, 0.8, 0.0]) / 1.0))
    kd, ks = wp.vec3(0.4, 0.4, 0.4), wp.vec3(0.5, 0.5, 0.5)
    pdf, fcos, ratio = (wp.empty(dirs.shape[0], dtype=wp.float32) for _ in range(3))
    wp.launch(_brdf_kernel, dim=dirs.shape[0], inputs=[n, wo, kd, ks, 30.0, wp.array(dirs, dtype=wp.vec3), pdf,
                                                       fcos, 5, ratio], device="cpu")
    assert abs((pdf.numpy() * d_omega).sum() - 1.0) < 1e-3  # measured 2.4e-6 (mixture of cosine and n=30 lobe)
    albedo = (fcos.numpy() * d_omega).sum()  # directional albedo: 0.4 + 0.5 x (lobe's cos-weighted integral)
    assert abs(albedo - 0.8) < 0.01  # measured 0.800002 (= 0.4 + 0.5 cos 36.9 deg)
    assert abs(ratio.numpy().mean() / albedo - 1.0) < 0.005  # measured 0.00014 over 320k samples


def _plane(k=1000, seed=0):
    pts = np.random.default_rng(seed).uniform(-1.0, 1.0, (k, 3)).astype(np.float32)
    pts[:, 1] = 0.0
    return pts, np.tile(np.float32([0.0, 1.0, 0.0]), (k, 1))


def test_lambertian_plane_under_constant_sky_converges_to_albedo_times_radiance():
    env = EnvironmentMap(np.full((16, 32, 3), 2.0, np.float32))
    pts, nrm = _plane()
    # irradiance pi L_env, Lambert f = rho / pi: radiance = rho L_env = 0.5 x 2 = 1
    r16 = shade_environment(pts, nrm, [0.5, 0.5, 0.5], env, samples=16, seed=1)
    r64 = shade_environment(pts, nrm, [0.5, 0.5, 0.5], env, samples=64, seed=1)
    assert abs(r16.mean() - 1.0) < 0.005  # measured 0.0006
    rms16 = np.sqrt(((r16 - 1.0) ** 2).mean())
    rms64 = np.sqrt(((r64 - 1.0) ** 2).mean())
    assert rms16 < 0.05 and np.abs(r16 - 1.0).max() < 0.2  # measured rms 0.028, max 0.094
    assert rms64 < 0.02 and rms64 < rms16 / 2.0  # measured 0.0093 (stratified: faster than 1/sqrt(S))
    # normalized Phong seen along the normal reflects k_s L_env; k_d + k_s mixes additively
    ph = shade_environment(pts, nrm, [0.0, 0.0, 0.0], env, samples=16, seed=2, specular=[0.5, 0.5, 0.5],
                           exponent=20.0)
    assert abs(ph.mean() - 1.0) < 0.01  # measured 0.0017
    mix = shade_environment(pts, nrm, [0.3, 0.3, 0.3], env, samples=16, seed=2, specular=[0.5, 0.5, 0.5],
                            exponent=20.0)
    assert abs(mix.mean() - 1.6) < 0.016  # measured 0.0022


def test_progressive_accumulation_converges():
    env = EnvironmentMap(np.full((16, 32, 3), 2.0, np.float32))
    pts, nrm = _plane(500)
    acc = ProgressiveAccumulator()
    errs = []
    for k in range(8):
        mean = acc.add(shade_environment(pts, nrm, [0.5, 0.5, 0.5], env, samples=4, seed=100 + k))
        errs.append(np.sqrt(((mean - 1.0) ** 2).mean()))
    assert acc.passes == 8 and mean.shape == (500, 3)
    assert errs[-1] < errs[0] / 2.0  # measured 0.080 -> 0.028 (1/sqrt(8))
    with pytest.raises(ValueError, match="shape"):
        acc.add(np.zeros((3, 3)))
    acc.reset()
    with pytest.raises(ValueError, match="no pass"):
        _ = acc.mean


@pytest.fixture(scope="module")
def sphere_over_plane():
    s = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    v = (np.asarray(s.vertices) + [0.0, 0.8, 0.0]).astype(np.float32)
    t = np.asarray(s.faces, np.int32)
    csm = build_csm(v, t, maps=(32, 16), resolution=64)
    g = np.linspace(-1.5, 1.5, 24)
    x, z = np.meshgrid(g, g)
    pts = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], 1).astype(np.float32)
    return csm, build_mesh(v, t), pts, np.tile(np.float32([0.0, 1.0, 0.0]), (len(pts), 1)), s, v


@pytest.mark.parametrize("filt", ["nearest", "pcf", "roulette"])
def test_csm_visibility_agrees_with_shadow_rays(sky, sphere_over_plane, filt):
    csm, mesh, pts, nrm, _, _ = sphere_over_plane
    kw = {"samples": 16, "seed": 3}
    ref = shade_environment(pts, nrm, [0.8, 0.8, 0.8], sky, mesh=mesh, **kw)
    got = shade_environment(pts, nrm, [0.8, 0.8, 0.8], sky, csm=csm, filter=filt, **kw)
    free = shade_environment(pts, nrm, [0.8, 0.8, 0.8], sky, **kw)
    assert 1.0 - ref.mean() / free.mean() > 0.05  # the sphere shadows the plane: measured 10 % of the light
    # same seed: same directions, so the difference is the CSM's visibility error alone
    rel = np.abs(got - ref).mean() / ref.mean()
    assert rel < 0.03  # measured 0.017 nearest, 0.017 pcf, 0.021 roulette
    assert abs(got.mean() / ref.mean() - 1.0) < 0.01  # measured 0.0008 nearest, 0.0020 pcf, 0.0014 roulette
    assert np.abs(got - ref).max() < 0.2  # measured 0.11 nearest, 0.075 pcf, 0.089 roulette
    assert np.abs(got - ref).mean() < 0.25 * np.abs(free - ref).mean()  # measured 0.15, 0.15, 0.19


def test_csm_self_shadowing_on_the_sphere(sky, sphere_over_plane):
    csm, mesh, _, _, s, v = sphere_over_plane
    nrm = np.asarray(s.vertex_normals, np.float32)
    ref = shade_environment(v, nrm, [0.8, 0.8, 0.8], sky, samples=16, seed=3, mesh=mesh, ray_eps=1e-3)
    got = shade_environment(v, nrm, [0.8, 0.8, 0.8], sky, samples=16, seed=3, csm=csm, bias=0.02)
    assert np.abs(got - ref).mean() / ref.mean() < 0.005  # measured 9e-5 (7.7e-4 with bias 0)
    assert np.isfinite(got).all() and (got >= 0.0).all()


def test_bad_input_raises(sky, sphere_over_plane):
    csm, mesh, pts, nrm, _, _ = sphere_over_plane
    with pytest.raises(ValueError, match="perfect square"):
        shade_environment(pts, nrm, [0.5] * 3, sky, samples=8)
    with pytest.raises(ValueError, match="samples"):
        shade_environment(pts, nrm, [0.5] * 3, sky, samples=0)
    with pytest.raises(ValueError, match="at most one"):
        shade_environment(pts, nrm, [0.5] * 3, sky, samples=4, csm=csm, mesh=mesh)
    with pytest.raises(ValueError, match="normals"):
        shade_environment(pts, np.zeros_like(nrm), [0.5] * 3, sky, samples=4)
    with pytest.raises(ValueError, match="albedo"):
        shade_environment(pts, nrm, np.ones((2, 3)), sky, samples=4)
    with pytest.raises(ValueError, match="filter"):
        shade_environment(pts, nrm, [0.5] * 3, sky, samples=4, csm=csm, filter="box")
    with pytest.raises(ValueError, match="exponent"):
        shade_environment(pts, nrm, [0.5] * 3, sky, samples=4, exponent=-1.0)
    with pytest.raises(ValueError, match="negative"):
        EnvironmentMap(-np.ones((4, 8, 3)))
    with pytest.raises(ValueError, match="shape"):
        EnvironmentMap(np.ones((4, 8)))
    with pytest.raises(ValueError, match="non-finite"):
        EnvironmentMap(np.full((4, 8, 3), np.nan))


@wp.kernel
def _search_kernel(cdf: wp.array2d(dtype=wp.float32), guide: wp.array2d(dtype=wp.int32), row: int, n: int,
                   xs: wp.array(dtype=wp.float32), out: wp.array2d(dtype=wp.int32)):
    k = wp.tid()
    out[k, 0] = cdf_search_row(cdf, row, n, xs[k])
    out[k, 1] = guided_search_row(cdf, guide, row, n, xs[k])


@wp.kernel
def _search1_kernel(cdf: wp.array(dtype=wp.float32), guide: wp.array(dtype=wp.int32), n: int,
                    xs: wp.array(dtype=wp.float32), out: wp.array2d(dtype=wp.int32)):
    k = wp.tid()
    out[k, 0] = cdf_search(cdf, n, xs[k])
    out[k, 1] = guided_search(cdf, guide, n, xs[k])


def _probe_points(cdf, buckets, rng):
    """Uniform numbers plus every CDF value and guide-bucket edge and their float32 neighbours, clamped as
    env_sample clamps them."""
    edges = (np.arange(buckets + 1) / buckets).astype(np.float32)
    c = np.asarray(cdf, np.float32)
    xs = np.concatenate([rng.random(4000).astype(np.float32), c, edges]).astype(np.float32)
    xs = np.concatenate([xs, np.nextafter(xs, np.float32(-1.0)), np.nextafter(xs, np.float32(2.0))])
    return np.clip(xs, 0.0, 0.99999994).astype(np.float32)


def test_guided_cdf_search_finds_the_binary_search_interval(sky):
    """env_sample's guide-table searches (the cutpoint method) return exactly cdf_search's interval, also for x on
    a CDF value, on a bucket edge and one float32 step either side, and for CDFs with empty intervals."""
    rng = np.random.default_rng(4)
    stepped = np.zeros((6, 40, 3), np.float32)
    stepped[:, ::7] = 1.0  # rows and columns of zero weight: empty intervals, repeated CDF values
    stepped[2, :, :] = 0.0
    for env in (sky, EnvironmentMap(stepped), EnvironmentMap(rng.random((9, 13, 3)) ** 8)):
        cdf = wp.array(env.conditional_cdf, dtype=wp.float32)
        guide = wp.array(env.conditional_guide, dtype=wp.int32)
        for row in range(env.height):
            xs = _probe_points(env.conditional_cdf[row], env.conditional_guide.shape[1], rng)
            out = wp.zeros((len(xs), 2), dtype=wp.int32)
            wp.launch(_search_kernel, dim=len(xs), inputs=[cdf, guide, row, env.width, wp.array(xs), out],
                      device="cpu")
            o = out.numpy()
            assert np.array_equal(o[:, 0], o[:, 1]), row
        xs = _probe_points(env.marginal_cdf, len(env.marginal_guide), rng)
        out = wp.zeros((len(xs), 2), dtype=wp.int32)
        wp.launch(_search1_kernel, dim=len(xs), inputs=[wp.array(env.marginal_cdf, dtype=wp.float32),
                                                        wp.array(env.marginal_guide, dtype=wp.int32), env.height,
                                                        wp.array(xs), out], device="cpu")
        o = out.numpy()
        assert np.array_equal(o[:, 0], o[:, 1])
        assert env.marginal_guide.dtype == np.int32 and env.conditional_guide.shape == (env.height, 2 * env.width)


@wp.kernel
def _uv_kernel(env: EnvData, seed: int, f: wp.array2d(dtype=wp.float32)):
    k = wp.tid()
    rng = wp.rand_init(seed, k)
    xi = wp.vec2(wp.randf(rng), wp.randf(rng))
    d, r, p = env_sample(env, xi)
    d2, r2, p2, uv = env_sample_uv(env, xi)
    e = env_direction(uv[0], uv[1])
    ll = latlong_param(d)
    w = wp.normalize(wp.vec3(wp.randf(rng) - 0.5, wp.randf(rng) - 0.5, wp.randf(rng) - 0.5))
    wuv = latlong_param(w)
    f[k, 0] = wp.length(d - d2) + wp.length(r - r2) + wp.abs(p - p2) + wp.length(d - e)  # exactly 0
    f[k, 1] = wp.length(env_lookup(env, w) - env_lookup_uv(env, wuv)) + wp.abs(env_pdf(env, w) - env_pdf_uv(env, w,
                                                                                                           wuv))
    f[k, 2] = wp.abs(ll[0] - uv[0])  # the sample's (u, v) against the ones recomputed from its direction
    f[k, 3] = wp.abs(ll[1] - uv[1])


def test_env_sample_uv_is_the_sample_and_its_lat_long_parameters(sky):
    """env_sample_uv draws env_sample's direction (which is env_direction of the returned (u, v)); the CSM query of
    an environment sample takes those (u, v) instead of latlong_param of the direction: they agree to float32
    rounding (away from the azimuth seam u = 0 = 1). The _uv look-ups equal the plain ones bit for bit."""
    n = 50_000
    f = wp.zeros((n, 4), dtype=wp.float32)
    wp.launch(_uv_kernel, dim=n, inputs=[sky.device_data(), 17, f], device="cpu")
    f = f.numpy()
    assert np.all(f[:, 0] == 0.0) and np.all(f[:, 1] == 0.0)
    du = np.minimum(f[:, 2], 1.0 - f[:, 2])  # the seam: u = 1 and u = 0 are the same direction
    assert du.max() < 2e-6  # measured 1.2e-7
    # acos of the float32 height loses digits towards the poles (the sample's own v is the exact one there)
    assert f[:, 3].max() < 1e-4 and np.quantile(f[:, 3], 0.999) < 1e-6  # measured 1.5e-5 and 2.6e-7
