"""Area and linear lights of the CSM renderer (Ritschel 2007 Sec. 4.2, 5.1): irradiance against the analytic
rectangle form factor and numpy quadratures, one- and two-sided emission, power, textured lights sampled by
radiance, and cube-CSM visibility against wp.Mesh shadow rays."""

import numpy as np
import pytest
import trimesh

from warpscatter.csm import build_csm, build_cube_csm
from warpscatter.csm.direct_lighting import DirectLighting
from warpscatter.csm.local_lights import check_light_csm, shade_local_light
from warpscatter.raster.raycast import build_mesh
from warpscatter.scene.lights import AreaLight, LinearLight

UP = np.array([0.0, 1.0, 0.0])


def corner_form_factor(a, b, h):
    """Form factor from a point to an a x b rectangle in a parallel plane at height h, the point below a corner."""
    x, y = a / h, b / h
    sx, sy = np.sqrt(1 + x * x), np.sqrt(1 + y * y)
    return (x / sx * np.arctan(y / sx) + y / sy * np.arctan(x / sy)) / (2.0 * np.pi)


def quad_area(light, p, n=300):
    """Irradiance / L_e at p (normal +Y) from a one- or two-sided parallelogram, midpoint rule n x n."""
    s = (np.arange(n) + 0.5) / n
    S, T = np.meshgrid(s, s)
    y = light.corner + S[..., None] * light.u + T[..., None] * light.v
    w = y - p
    d2 = (w * w).sum(-1)
    d = np.sqrt(d2)
    ci = np.maximum(w[..., 1] / d, 0.0)
    cl = -(w @ light.normal) / d  # > 0 where the front side faces p
    cl = np.abs(cl) if light.two_sided else np.maximum(cl, 0.0)
    return (ci * cl / d2).mean() * light.area


def quad_linear(light, p, n=4000):
    s = (np.arange(n) + 0.5) / n
    y = light.start + s[:, None] * (light.end - light.start)
    w = y - p
    d2 = (w * w).sum(-1)
    return (np.maximum(w[:, 1] / np.sqrt(d2), 0.0) / d2).mean() * light.length


def test_rectangle_light_matches_the_analytic_form_factor():
    a, b, h = 2.0, 1.0, 1.5
    light = AreaLight([0.0, h, 0.0], [a, 0.0, 0.0], [0.0, 0.0, b], [3.0, 3.0, 3.0])  # u x v = -Y: faces down
    assert np.allclose(light.normal, [0, -1, 0])
    pts = np.repeat(np.array([[0.0, 0.0, 0.0], [a / 2, 0.0, b / 2]]), 2000, axis=0)  # under a corner, the centre
    nrm = np.tile(UP, (len(pts), 1))
    out = shade_local_light(pts, nrm, [0.8, 0.8, 0.8], light, samples=16, seed=4)[:, 0]
    want = 0.8 / np.pi * 3.0 * np.pi * np.array([corner_form_factor(a, b, h), 4 * corner_form_factor(a / 2, b / 2, h)])
    for k in range(2):
        got = out[k * 2000:(k + 1) * 2000]
        sigma = got.std() / np.sqrt(len(got))
        assert abs(got.mean() - want[k]) < 4.0 * sigma + 1e-5  # measured 0.10 and 0.52 sigma
        assert abs(got.mean() / want[k] - 1.0) < 2e-3  # measured 8.6e-5 and 6.6e-4
    # the light's back side emits nothing (one-sided), both sides when two_sided
    above = np.tile([a / 2, 2 * h, b / 2], (500, 1))
    assert np.all(shade_local_light(above, nrm[:500] * -1, [0.8] * 3, light, samples=4) == 0.0)
    two = AreaLight(light.corner, light.u, light.v, light.radiance, two_sided=True)
    back = shade_local_light(above, -nrm[:500], [0.8] * 3, two, samples=16, seed=1)[:, 0].mean()
    want_back = 0.8 * 3.0 * 4 * corner_form_factor(a / 2, b / 2, h)
    assert abs(back / want_back - 1.0) < 1e-2  # measured 2.1e-3 (Monte-Carlo noise)
    p = AreaLight.from_power([0, 0, 0], [2, 0, 0], [0, 0, 1], [6.0, 6.0, 6.0])
    assert np.allclose(p.radiance, 6.0 / (np.pi * 2.0))


def test_tilted_area_and_linear_lights_match_quadrature():
    rng = np.random.default_rng(3)
    pts = np.stack([rng.uniform(-2, 2, 64), np.zeros(64), rng.uniform(-2, 2, 64)], 1)
    nrm = np.tile(UP, (64, 1))
    light = AreaLight([-0.7, 1.2, -0.3], [1.2, 0.5, 0.0], [0.2, -0.1, 0.9], [1.0, 2.0, 0.5], two_sided=True)
    got = np.mean([shade_local_light(pts, nrm, [0.5, 0.5, 0.5], light, samples=64, seed=s) for s in range(8)], 0)
    want = np.array([0.5 / np.pi * quad_area(light, p, 600) for p in pts])[:, None] * light.radiance
    rel = np.abs(got - want).max() / want.max()
    assert rel < 0.025  # measured 0.0115 (8 passes x 64 strata; 0.0045 with 8 x 256: Monte-Carlo noise)
    assert abs(got.sum() / want.sum() - 1.0) < 5e-3  # measured 1.3e-3
    line = LinearLight([-1.5, 1.0, 0.2], [1.0, 1.6, -0.4], [2.0, 1.0, 1.0])
    got = shade_local_light(pts, nrm, [0.5, 0.5, 0.5], line, samples=64, seed=2)
    want = np.array([0.5 / np.pi * quad_linear(line, p) for p in pts])[:, None] * line.intensity
    assert np.abs(got - want).max() / want.max() < 0.01  # measured 0.0023 (64 strata along the segment)


@pytest.fixture(scope="module")
def occluded_scene():
    s = trimesh.creation.icosphere(subdivisions=3, radius=0.4)
    v = (np.asarray(s.vertices) + [0.0, 0.9, 0.0]).astype(np.float32)
    t = np.asarray(s.faces, np.int32)
    g = np.linspace(-1.5, 1.5, 20)
    x, z = np.meshgrid(g, g)
    pts = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], 1).astype(np.float32)
    return v, t, pts, np.tile(UP.astype(np.float32), (len(pts), 1)), build_mesh(v, t)


@pytest.mark.parametrize("kind", ["area", "linear", "semi_local"])
def test_cube_csm_visibility_agrees_with_shadow_rays(occluded_scene, kind):
    v, t, pts, nrm, mesh = occluded_scene
    if kind != "linear":
        light = AreaLight([-0.6, 2.2, -0.4], [1.2, 0.0, 0.0], [0.0, 0.0, 0.8], [2.0, 2.0, 2.0], two_sided=True)
        samples = light.sample_points(8, 8)
    else:
        light = LinearLight([-0.8, 2.2, 0.0], [0.8, 2.2, 0.3], [2.0, 2.0, 2.0])
        samples = light.sample_points(16)
    if kind == "semi_local":  # Sec. 4.3: the lat-long CSM queried towards each light point (no light samples)
        csm = build_csm(v, t, maps=(32, 16), resolution=64)
    else:
        csm = build_cube_csm(v, t, samples, resolution=64)
    kw = {"samples": 16, "seed": 5}
    ref = shade_local_light(pts, nrm, [0.8] * 3, light, mesh=mesh, **kw)
    got = shade_local_light(pts, nrm, [0.8] * 3, light, csm=csm, filter="pcf", bias=0.01, **kw)
    free = shade_local_light(pts, nrm, [0.8] * 3, light, **kw)
    assert 1.0 - ref.mean() / free.mean() > 0.05  # the sphere shadows the plane: measured 22 % / 20 %
    rel = np.abs(got - ref).mean() / ref.mean()
    # same seed: same light points, so the difference is the CSM's visibility error (8 x 8 / 16 light samples:
    # a sample's nearest CSM point is up to half a cell away, which moves penumbrae; semi-local: the nearest of
    # 32 x 16 map directions is up to 5.6 degrees off the direction to the light point)
    bound = {"area": (0.04, 0.2), "linear": (0.04, 0.2), "semi_local": (0.08, 0.3)}[kind]
    assert rel < bound[0]  # measured 0.016 area, 0.012 linear, 0.052 semi_local
    assert np.abs(got - ref).mean() < bound[1] * np.abs(free - ref).mean()  # measured 0.058, 0.050, 0.19
    if kind == "semi_local":
        return
    with pytest.raises(ValueError, match="do not lie on this light"):
        other = AreaLight([-0.6, 2.4, -0.4], [1.2, 0.0, 0.0], [0.0, 0.0, 0.8], [1, 1, 1])
        check_light_csm(csm, other if kind == "area" else LinearLight([-0.8, 2.4, 0.0], [0.8, 2.2, 0.3], [1, 1, 1]))


def test_bad_lights_raise():
    with pytest.raises(ValueError, match="parallelogram"):
        AreaLight([0, 0, 0], [1, 0, 0], [2, 0, 0], [1, 1, 1])
    with pytest.raises(ValueError, match="differ"):
        LinearLight([0, 0, 0], [0, 0, 0], [1, 1, 1])
    with pytest.raises(ValueError, match="radiance"):
        AreaLight([0, 0, 0], [1, 0, 0], [0, 0, 1], [-1, 1, 1])
    with pytest.raises(ValueError, match="light must be"):
        shade_local_light(np.zeros((1, 3)), [[0, 1, 0]], [0.5] * 3, "sun", samples=4)
    with pytest.raises(ValueError, match="perfect square"):
        shade_local_light(np.zeros((1, 3)), [[0, 1, 0]], [0.5] * 3, LinearLight([0, 1, 0], [1, 1, 0], [1] * 3),
                          samples=3)


@pytest.mark.parametrize("kind", ["area", "linear"])
def test_one_setup_shades_every_pass_like_shade_local_light(occluded_scene, kind):
    """DirectLighting (what the pipeline builds once per render) gives shade_local_light's pass bit for bit for any
    seed and thread count, with the roulette filter of the cube CSM and with shadow rays."""
    v, t, pts, nrm, mesh = occluded_scene
    if kind == "area":
        light = AreaLight([-0.6, 2.2, -0.4], [1.2, 0.0, 0.0], [0.0, 0.0, 0.8], [2.0, 2.0, 2.0], two_sided=True)
        csm = build_cube_csm(v, t, light.sample_points(4, 4), resolution=32)
    else:
        light = LinearLight([-0.8, 2.2, 0.0], [0.8, 2.2, 0.3], [2.0, 2.0, 2.0])
        csm = build_cube_csm(v, t, light.sample_points(8), resolution=32)
    for vis in ({"csm": csm, "filter": "roulette", "bias": 0.01}, {"mesh": mesh}):
        kw = {"samples": 9, "specular": [0.3, 0.3, 0.3], "exponent": 12.0, **vis}
        lighting = DirectLighting(pts, nrm, [0.6] * 3, light, **kw)
        single = DirectLighting(pts, nrm, [0.6] * 3, light, threads=1, **kw)
        for seed in (3, 4):
            got = lighting.shade(seed)
            assert np.array_equal(got, shade_local_light(pts, nrm, [0.6] * 3, light, seed=seed, **kw))
            assert np.array_equal(got, single.shade(seed)) and got.mean() > 0.0


def _bilinear_texture(tex, s, t):
    """numpy twin of the kernels' bilinear look-up at (s, 1 - t): row 0 = the edge t = 1, clamped."""
    h, w = tex.shape[:2]
    x = np.clip(s * w - 0.5, 0.0, w - 1)
    y = np.clip((1.0 - t) * h - 0.5, 0.0, h - 1)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    top = tex[y0, x0] * (1 - fx) + tex[y0, x1] * fx
    return top * (1 - fy) + (tex[y1, x0] * (1 - fx) + tex[y1, x1] * fx) * fy


def test_textured_area_light_matches_quadrature_and_keeps_its_power():
    """Ritschel 2007's "varying intensity": a 4 x 6 RGB texture (a black band) over a tilted two-sided light, sampled
    by radiance, against a midpoint quadrature of L_e tex(s, t) cos cos / d^2 (the kernels' bilinear look-up in
    numpy); from_power divides by the texture's mean, so the emitted power stays P."""
    rng = np.random.default_rng(5)
    tex = rng.uniform(0.0, 1.0, (4, 6, 3)).astype(np.float32)
    tex[:, :2] = 0.0  # a black band: no light from there
    light = AreaLight([-0.7, 1.2, -0.3], [1.2, 0.5, 0.0], [0.2, -0.1, 0.9], [1.0, 2.0, 0.5], two_sided=True,
                      texture=tex)
    pts = np.stack([rng.uniform(-2, 2, 48), np.zeros(48), rng.uniform(-2, 2, 48)], 1)
    nrm = np.tile(UP, (48, 1))
    got = np.mean([shade_local_light(pts, nrm, [0.5, 0.5, 0.5], light, samples=64, seed=s) for s in range(16)], 0)
    n = 400
    s = (np.arange(n) + 0.5) / n
    S, T = np.meshgrid(s, s)
    y = light.corner + S[..., None] * light.u + T[..., None] * light.v
    lt = _bilinear_texture(tex, S, T) * light.radiance
    want = []
    for p in pts:
        w = y - p
        d2 = (w * w).sum(-1)
        d = np.sqrt(d2)
        g = np.maximum(w[..., 1] / d, 0.0) * np.abs(w @ light.normal) / d / d2
        want.append(0.5 / np.pi * (g[..., None] * lt).reshape(-1, 3).mean(0) * light.area)
    want = np.array(want)
    assert np.abs(got - want).max() / want.max() < 0.02  # measured 0.0073 (16 passes x 64 strata; 0.0061 with 48)
    assert abs(got.sum() / want.sum() - 1.0) < 5e-3  # measured 1.9e-3 (0.87e-3 with 48 passes: no bias)
    p = AreaLight.from_power([0, 0, 0], [2, 0, 0], [0, 0, 1], [6.0, 6.0, 6.0], texture=tex)
    mean = tex.reshape(-1, 3).mean(0)
    assert np.allclose(p.radiance * mean, 6.0 / (np.pi * 2.0))
    with pytest.raises(ValueError, match="black"):
        AreaLight([0, 0, 0], [1, 0, 0], [0, 0, 1], [1, 1, 1], texture=np.zeros((2, 2, 3)))


def test_sampling_by_radiance_lowers_the_noise_of_a_sparse_texture():
    """One bright texel in a dark 8 x 8 texture: sampled by radiance, the per-point spread of the estimates is far
    below uniform sampling's (same light, same budget), and both agree on the mean."""
    tex = np.full((8, 8, 3), 1e-3, np.float32)
    tex[2, 5] = 50.0
    light = AreaLight([-1.0, 1.5, -1.0], [2.0, 0.0, 0.0], [0.0, 0.0, 2.0], [1.0, 1.0, 1.0], two_sided=True,
                      texture=tex)
    pts = np.zeros((4000, 3))
    nrm = np.tile(UP, (4000, 1))
    by_radiance = shade_local_light(pts, nrm, [0.5] * 3, light, samples=4, seed=3)[:, 0]
    light_uniform = AreaLight(light.corner, light.u, light.v, light.radiance, True, texture=tex)
    uniform_tables = (np.array([0.0, 1.0], np.float32), np.array([[0.0, 1.0]], np.float32),
                      np.ones((1, 1), np.float32))
    object.__setattr__(light_uniform, "sampling_tables", lambda: uniform_tables)
    uniform = shade_local_light(pts, nrm, [0.5] * 3, light_uniform, samples=4, seed=3)[:, 0]
    assert by_radiance.std() < 0.6 * uniform.std()  # measured ratio 0.40 (0.147 against 0.372)
    se = np.hypot(by_radiance.std(), uniform.std()) / np.sqrt(len(pts))
    assert abs(by_radiance.mean() - uniform.mean()) < 5.0 * se


def test_volume_light_matches_quadrature_and_its_power():
    """Ritschel 2007's volumetric lights (d = 3): a tilted box emitting I per unit volume, against a midpoint
    quadrature of I cos / d^2 dV; from_power gives I = P / (4 pi V)."""
    from warpscatter.scene.lights import VolumeLight

    rng = np.random.default_rng(7)
    light = VolumeLight([-0.6, 1.0, -0.4], [1.0, 0.3, 0.0], [0.0, 0.2, 0.8], [0.1, 0.6, 0.1], [2.0, 1.0, 0.5])
    pts = np.stack([rng.uniform(-2, 2, 48), np.zeros(48), rng.uniform(-2, 2, 48)], 1)
    nrm = np.tile(UP, (48, 1))
    got = np.mean([shade_local_light(pts, nrm, [0.5] * 3, light, samples=64, seed=s) for s in range(16)], 0)
    n = 48
    g = (np.arange(n) + 0.5) / n
    S, T, R = np.meshgrid(g, g, g, indexing="ij")
    y = light.corner + S[..., None] * light.u + T[..., None] * light.v + R[..., None] * light.w
    want = []
    for p in pts:
        w = y - p
        d2 = (w * w).sum(-1)
        want.append(0.5 / np.pi * (np.maximum(w[..., 1] / np.sqrt(d2), 0.0) / d2).mean() * light.volume)
    want = np.array(want)[:, None] * light.intensity
    assert np.abs(got - want).max() / want.max() < 0.02  # measured 0.0066 (16 passes x 64 strata; 0.015 with 4)
    assert abs(got.sum() / want.sum() - 1.0) < 5e-3  # measured 1.4e-3
    p = VolumeLight.from_power([0, 0, 0], [2, 0, 0], [0, 1, 0], [0, 0, 0.5], [4.0, 4.0, 4.0])
    assert np.allclose(p.intensity, 4.0 / (4.0 * np.pi * 1.0))
    with pytest.raises(ValueError, match="volume"):
        VolumeLight([0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [1, 1, 1])
