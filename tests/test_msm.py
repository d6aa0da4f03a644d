"""Tests of warpscatter.shadows.msm: moment shadow map generation, filtering, hard-shadow lookups, translucency.

Maps are built in a fixed top-down orthographic light view (eye at y = 10 looking down, near 1, far 11, so a plane at
height y has linear depth 10 - y and signed depth (10 - y - 1) / 5 - 1). References are numpy float64
re-computations from the same rasterized samples. Tolerances are measured maxima with a margin; the measured value
is in a comment next to each bound.
"""

import dataclasses

import numpy as np
import pytest
import warp as wp
from conftest import make_scene, quad
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from warpscatter.raster.rasterizer import linearize_depth, rasterize
from warpscatter.runtime.device import module_options
from warpscatter.scene.camera import Camera, CameraParams, look_at_basis, orthographic_matrix, view_matrix
from warpscatter.shading import pixel_footprint
from warpscatter.shadows import moments as mm
from warpscatter.shadows import msm, translucency
from warpscatter.shadows.shadow_map import ShadowMap, ShadowMapParams, shadow_pcf

module_options()

EYE_Y, NEAR, FAR = 10.0, 1.0, 11.0


def signed(y):
    """Signed depth of height y in the top-down map."""
    return 2.0 * (EYE_Y - np.asarray(y, np.float64) - NEAR) / (FAR - NEAR) - 1.0


def top_down_map(vertices, triangles, res, half=2.0):
    """Orthographic top-down ShadowMap over [-half, half]^2 in x, z with its plain linear depth (+inf empty)."""
    eye = np.array([0.0, EYE_Y, 0.0])
    right, up, fwd = look_at_basis(eye, eye + np.array([0.0, -1.0, 0.0]), [0.0, 0.0, -1.0])
    view = view_matrix(eye, right, up, fwd)
    proj = orthographic_matrix(-half, half, -half, half, NEAR, FAR)
    r = rasterize(vertices, triangles, proj @ view, res, res, clamp_depth=True)
    depth = linearize_depth(r.ndc_depth[0], proj).astype(np.float32)
    depth[r.tri_id[0] < 0] = np.inf
    return ShadowMap(depth=depth, view=view, projection=proj, perspective=False, texel_world=2.0 * half / res)


def sample_signed_depths(scene, sm, s):
    """Signed depths of the s x s supersampled light view (numpy float64, +1 where empty)."""
    r = rasterize(scene.vertices, scene.triangles, sm.view_projection, s * sm.shape[1], s * sm.shape[0],
                  clamp_depth=True)
    d = linearize_depth(r.ndc_depth[0], sm.projection)
    z = 2.0 * (d - NEAR) / (FAR - NEAR) - 1.0
    return np.where(r.tri_id[0] >= 0, np.clip(z, -1.0, 1.0), 1.0)


def horizontal_plane(y, half=3.0):
    return quad([-half, y, -half], [half, y, -half], [half, y, half], [-half, y, half])


def layered_scene(planes, opacities, albedos=None):
    """Scene of horizontal planes (list of (vertices, triangles)), one material per plane."""
    verts, tris, mats = [], [], []
    base = 0
    for k, (v, t) in enumerate(planes):
        verts.append(v)
        tris.append(t + base)
        mats.append(np.full(len(t), k, np.int32))
        base += len(v)
    scene = make_scene(np.concatenate(verts), np.concatenate(tris))
    albedo = np.full((len(planes), 3), 0.5, np.float32) if albedos is None else np.asarray(albedos, np.float32)
    return dataclasses.replace(scene, tri_material=np.concatenate(mats), albedo=albedo,
                               opacity=np.asarray(opacities, np.float32))


def ref_moments(z):
    z = np.asarray(z, np.float64)
    return np.stack([z, z**2, z**3, z**4], axis=-1)


# ---------------------------------------------------------------------------------------------------------------------
# Generation
# ---------------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("y", [3.0, 8.5])
def test_single_plane_gives_its_moments(y):
    v, t = horizontal_plane(y)
    scene = make_scene(v, t)
    sm = top_down_map(scene.vertices, scene.triangles, 8)
    z = signed(y)  # 0.2 and -0.9
    m128 = msm.generate_moment_shadow_map(scene, sm, supersampling=2, bits=128)
    assert m128.numpy().shape == (1, 8, 8, 4)
    expect = np.broadcast_to(ref_moments(z), (1, 8, 8, 4))
    np.testing.assert_allclose(m128.numpy(), expect, atol=1e-6)  # measured 8.7e-8
    m64 = msm.generate_moment_shadow_map(scene, sm, supersampling=2, bits=64)
    expect = mm.quantize4(ref_moments(z).astype(np.float32), mm.STORAGE4_UNORM16)
    step = 1.0 / 65535.0
    assert np.max(np.abs(m64.numpy() - expect)) <= step + 1e-7  # measured 0 (same 16-bit value)
    assert m64.nbytes == 8 * 64 and m128.nbytes == 16 * 64


def random_soup(rng, count=24):
    centres = rng.uniform([-2.0, 0.5, -2.0], [2.0, 9.0, 2.0], (count, 1, 3))
    verts = (centres + rng.normal(0.0, 0.8, (count, 3, 3))).reshape(-1, 3).astype(np.float32)
    return verts, np.arange(3 * count, dtype=np.int32).reshape(-1, 3)


def test_supersampling_averages_sample_moments():
    rng = np.random.default_rng(5)
    v, t = random_soup(rng)
    gv, gt = horizontal_plane(0.0)
    scene = make_scene(np.concatenate([v, gv]), np.concatenate([t, gt + len(v)]))
    res, s = 16, 3
    sm = top_down_map(scene.vertices, scene.triangles, res)
    z = sample_signed_depths(scene, sm, s)
    blocks = ref_moments(z).reshape(res, s, res, s, 4).mean(axis=(1, 3))
    got = msm.generate_moment_shadow_map(scene, sm, supersampling=s, bits=128).numpy()[0]
    assert np.max(np.abs(got - blocks)) < 1e-6  # measured 1.1e-7
    mixed = np.ptp(z.reshape(res, s, res, s), axis=(1, 3)) > 0.05
    assert mixed.mean() > 0.2  # many texels really average several depths (measured 0.48)


def test_64_bit_round_trip_within_quantization():
    rng = np.random.default_rng(8)
    v, t = random_soup(rng)
    scene = make_scene(v, t)
    sm = top_down_map(scene.vertices, scene.triangles, 16)
    exact = msm.generate_moment_shadow_map(scene, sm, supersampling=2, bits=128).numpy()
    m64 = msm.generate_moment_shadow_map(scene, sm, supersampling=2, bits=64)
    texels = m64.numpy()
    step = 1.0 / 65535.0
    np.testing.assert_allclose(texels / step, np.round(texels / step), atol=2e-3)  # on the 16-bit grid
    back = mm.dequantize4(texels, mm.STORAGE4_UNORM16).astype(np.float64)
    bound = np.abs(np.linalg.inv(mm.THETA4_MATRIX)).sum(axis=1) * 0.5 * step + 2e-6
    assert np.all(np.abs(back - exact) <= bound)
    assert np.max(np.abs(back - exact) / bound) > 0.1  # the rounding is really there (measured 0.82)


def test_gaussian_weights_and_filter_match_numpy():
    w = msm.gaussian_weights(5)
    assert w.shape == (5,) and abs(w.sum() - 1.0) < 1e-6 and np.all(np.diff(w[:3]) > 0)
    np.testing.assert_array_equal(msm.gaussian_weights(1), [1.0])
    rng = np.random.default_rng(3)
    v, t = random_soup(rng)
    scene = make_scene(v, t)
    sm = top_down_map(scene.vertices, scene.triangles, 12)
    raw = msm.generate_moment_shadow_map(scene, sm, supersampling=1, bits=128)
    got = msm.filter_moment_shadow_map(raw, 5).numpy()[0]
    ref = blur(raw.numpy()[0].astype(np.float64), w.astype(np.float64))
    assert np.max(np.abs(got - ref)) < 1e-6  # measured 1.1e-7
    assert msm.filter_moment_shadow_map(raw, 1) is raw


# ---------------------------------------------------------------------------------------------------------------------
# Filtered hard shadows
# ---------------------------------------------------------------------------------------------------------------------


def blur(img, w):
    """Separable clamp-to-edge blur of (H, W, ...) with taps w (numpy reference of the two-pass filter)."""
    r = len(w) // 2
    h, wd = img.shape[:2]
    pad = np.pad(img, [(0, 0), (r, r)] + [(0, 0)] * (img.ndim - 2), mode="edge")
    rows = sum(w[k] * pad[:, k : k + wd] for k in range(2 * r + 1))
    pad = np.pad(rows, [(r, r), (0, 0)] + [(0, 0)] * (img.ndim - 2), mode="edge")
    return sum(w[k] * pad[k : k + h] for k in range(2 * r + 1))


def bilinear(img, u, v):
    h, w = img.shape
    fx, fy = u * w - 0.5, v * h - 0.5
    x0, y0 = np.floor(fx).astype(int), np.floor(fy).astype(int)
    ax, ay = fx - x0, fy - y0

    def at(i, j):
        return img[np.clip(j, 0, h - 1), np.clip(i, 0, w - 1)]

    return (1 - ay) * ((1 - ax) * at(x0, y0) + ax * at(x0 + 1, y0)) + ay * ((1 - ax) * at(x0, y0 + 1) +
                                                                            ax * at(x0 + 1, y0 + 1))


@wp.kernel
def pcf_points_kernel(sm: ShadowMapParams, depth: wp.array2d(dtype=wp.float32), points: wp.array(dtype=wp.vec3),
                      bias: float, filter_px: int, out: wp.array(dtype=wp.float32)):
    k = wp.tid()
    out[k] = shadow_pcf(sm, depth, points[k], bias, filter_px)


@wp.kernel
def user_msm_kernel(p: msm.MomentShadowParams, texels: wp.array3d(dtype=wp.vec4), points: wp.array(dtype=wp.vec3),
                    out: wp.array(dtype=wp.float32)):
    k = wp.tid()
    out[k] = msm.msm_visibility(p, texels, points[k], wp.vec3(0.0, 1.0, 0.0))


def edge_scene():
    """Ground at y = 0 and an opaque occluder at y = 5 covering x < 0.1 (a sharp shadow edge)."""
    gv, gt = horizontal_plane(0.0)
    ov, ot = quad([-3.0, 5.0, -3.0], [0.1, 5.0, -3.0], [0.1, 5.0, 3.0], [-3.0, 5.0, 3.0])
    return make_scene(np.concatenate([gv, ov]), np.concatenate([gt, ot + 4]))


@pytest.mark.parametrize("bits", [64, 128])
def test_filtered_hard_shadows_vs_pcf_and_exact_filter(bits):
    scene = edge_scene()
    res, s, fpx = 32, 2, 5
    sm = top_down_map(scene.vertices, scene.triangles, res)  # texel 0.125
    m = msm.render_moment_shadow_map(scene, sm, supersampling=s, bits=bits, filter_px=fpx)
    xs = np.linspace(-1.5, 1.5, 193)
    pts = np.stack([xs, np.zeros_like(xs), np.full_like(xs, 0.3)], axis=-1).astype(np.float32)
    bias = 0.05  # world units
    got = msm.msm_visibility_at(m, pts, depth_bias=bias)[:, 0]
    raw = msm.msm_visibility_at(m, pts, depth_bias=bias, overdarkening=0.0)[:, 0]
    # exact filtered visibility: the same Gaussian + bilinear weights applied to the per-sample shadow test
    z = sample_signed_depths(scene, sm, s)
    z_f = signed(0.0) - bias * 2.0 / (FAR - NEAR)
    lit = (z >= z_f).reshape(res, s, res, s).mean(axis=(1, 3))
    truth = bilinear(blur(lit, msm.gaussian_weights(fpx).astype(np.float64)), (xs + 2.0) / 4.0, (0.3 + 2.0) / 4.0)
    # two depths per filter region: Algorithm 1 is exact up to the bias (Peters and Klein 2015, Prop. 4)
    assert np.max(np.abs(raw - truth)) < (1e-5 if bits == 128 else 1e-3)  # measured 6.5e-7 (128), 2.4e-4 (64)
    # over-darkening darkens the penumbra by at most 2% of the shadow intensity
    assert np.all(got <= raw + 1e-6) and np.max(raw - got) < 0.021  # measured 0.0199
    # PCF (box of the same width, bilinear) on the plain map: equal away from the edge, both smooth across it
    out = wp.zeros(len(xs), dtype=wp.float32)
    wp.launch(pcf_points_kernel, len(xs), inputs=[sm.params(), sm.device_depth(), wp.array(pts, dtype=wp.vec3),
                                                  bias, fpx, out])
    pcf = out.numpy()
    far_from_edge = np.abs(xs - 0.1) > 4 * 0.125
    assert np.max(np.abs(got - pcf)[far_from_edge]) < 1e-4  # measured 1.2e-7 (128), 1.9e-5 (64)
    assert np.max(np.abs(got - pcf)) < 0.15  # measured 0.126: Gaussian vs box kernel in the penumbra
    assert np.max(np.abs(np.diff(got))) < 0.08  # smooth: samples 1/8 texel apart; measured 0.042
    assert np.all(np.diff(got) >= -1e-6)  # monotonic from shadow to light
    # penumbra wider than 2 texels (measured 4.4 texels, PCF 4.9)
    assert np.sum((got > 0.02) & (got < 0.98)) * (xs[1] - xs[0]) > 2 * 0.125
    # a user kernel calling the public @wp.func gives the same answer
    p = m.params(depth_bias=bias, normal_offset_texels=0.0)
    mine = wp.zeros(len(xs), dtype=wp.float32)
    wp.launch(user_msm_kernel, len(xs), inputs=[p, m.texels, wp.array(pts, dtype=wp.vec3), mine])
    np.testing.assert_allclose(mine.numpy(), got, atol=1e-6)


_garbage = st.one_of(st.floats(width=32), st.floats(-3.0, 3.0, width=32), st.sampled_from([0.0, 1.0, -1.0]))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(texels=hnp.arrays(np.float32, (3, 4, 5, 4), elements=_garbage),
       points=hnp.arrays(np.float32, (16, 3), elements=_garbage),
       bits=st.sampled_from([64, 128]), bias=st.floats(0.0, 10.0))
def test_garbage_never_gives_nan(texels, points, bits, bias):
    v, t = horizontal_plane(1.0)
    sm = top_down_map(v, t, 5)
    sm = dataclasses.replace(sm, depth=np.zeros((4, 5), np.float32))
    m = msm.MomentShadowMap(texels=wp.array(texels, dtype=wp.vec4), bits=bits, shadow_map=sm,
                            geometry=msm.map_geometry(sm), supersampling=1)
    pts = np.concatenate([points, np.array([[0.1, 2.0, -0.3], [1.9, 0.0, 1.9]], np.float32)])
    vis = msm.msm_visibility_at(m, pts, np.ones_like(pts), depth_bias=bias, normal_offset_texels=1.0)
    assert vis.shape == (18, 3)
    assert np.all(np.isfinite(vis)) and np.all((vis >= 0.0) & (vis <= 1.0))


# ---------------------------------------------------------------------------------------------------------------------
# Translucent occluders
# ---------------------------------------------------------------------------------------------------------------------


def stack_scene():
    """Opaque ground at y = 0 under translucent planes at y = 6, 4, 2 with opacities 0.3, 0.5, 0.2 (light first)."""
    planes = [horizontal_plane(0.0), horizontal_plane(6.0), horizontal_plane(4.0), horizontal_plane(2.0)]
    return layered_scene(planes, [1.0, 0.3, 0.5, 0.2])


@pytest.mark.parametrize("bits", [64, 128])
def test_translucent_stack_gives_product_of_transmittances(bits):
    scene = stack_scene()
    sm = top_down_map(scene.vertices, scene.triangles, 8)
    m = msm.generate_moment_shadow_map(scene, sm, supersampling=2, bits=bits)
    assert m.translucent_layers == 3
    # the texels are the moments of Z = sum_j prod_{k<j}(1 - a_k) a_j delta_{z_j} (Sec. 3.2), exactly in float32
    weights = np.array([0.3, 0.7 * 0.5, 0.7 * 0.5 * 0.2, 0.7 * 0.5 * 0.8])
    b = weights @ ref_moments(signed([6.0, 4.0, 2.0, 0.0]))
    back = mm.dequantize4(m.numpy()[0], m.storage).reshape(-1, 4)
    assert np.max(np.abs(back - b)) < (1e-6 if bits == 128 else 5e-5)  # measured 3.2e-8 (128), 1.3e-5 (64)
    heights = np.array([0.0, 1.0, 2.5, 3.5, 4.5, 5.5, 7.0])
    expect = np.array([0.28, 0.28, 0.35, 0.35, 0.7, 0.7, 1.0])  # products of (1 - alpha) of the planes above
    pts = np.stack([np.full(len(heights), 0.3), heights, np.full(len(heights), -0.2)], axis=-1)
    raw = msm.msm_visibility_at(m, pts, depth_bias=0.01, overdarkening=0.0)[:, 0]
    err = raw - expect
    # the opaque receiver: depth bias and reconstruction error only (measured 0.0091 (64), 0.0090 (128))
    assert abs(err[0]) < 0.012
    # between the layers four depths share the filter region: Algorithm 1's lower bound leaks light there, never
    # darkens (measured err in [0, 0.30], largest just below the first plane, y = 5.5)
    assert np.all(err > -1e-3) and np.max(err) < 0.32
    # the truth lies between the sharp bounds of the stored moments (Fig. 2)
    bounds = mm.bounds4(np.broadcast_to(back[0], (len(heights), 4)), signed(heights).astype(np.float32),
                        alpha=0.0)
    assert np.all(1.0 - bounds[:, 1] <= expect + 1e-4) and np.all(expect <= 1.0 - bounds[:, 0] + 1e-4)


def test_alpha_test_depth_test_and_opaque_equivalence():
    gv, gt = horizontal_plane(0.0)
    base = layered_scene([horizontal_plane(0.0), horizontal_plane(5.0)], [1.0, 1.0])
    sm = top_down_map(base.vertices, base.triangles, 8)
    ref = msm.generate_moment_shadow_map(base, sm, bits=64).numpy()
    # alpha 0.005 < 1%: discarded; a translucent plane behind the opaque ground: depth-tested away
    for planes, ops in (([(gv, gt), horizontal_plane(5.0), horizontal_plane(3.0)], [1.0, 1.0, 0.005]),
                        ([(gv, gt), horizontal_plane(5.0), horizontal_plane(-1.0)], [1.0, 1.0, 0.6])):
        got = msm.generate_moment_shadow_map(layered_scene(planes, ops), sm, bits=64).numpy()
        np.testing.assert_array_equal(got, ref)
    # alpha 0.02 >= 1% is blended
    kept = layered_scene([(gv, gt), horizontal_plane(8.0)], [1.0, 0.02])
    got = msm.generate_moment_shadow_map(kept, sm, bits=128).numpy()[0, 0, 0]
    np.testing.assert_allclose(got, 0.02 * ref_moments(signed(8.0)) + 0.98 * ref_moments(signed(0.0)), atol=1e-6)


def test_translucent_row_bands_match_one_pass(monkeypatch):
    """Peeling in row bands (bounded memory) gives bitwise the same map as peeling the whole view at once."""
    rng = np.random.default_rng(21)
    v, t = random_soup(rng, 40)
    gv, gt = horizontal_plane(0.0)
    scene = make_scene(np.concatenate([v, gv]), np.concatenate([t, gt + len(v)]))
    albedo = np.array([[0.5, 0.5, 0.5], [0.9, 0.2, 0.1], [0.2, 0.8, 0.3], [0.5, 0.5, 0.9]], np.float32)
    scene = dataclasses.replace(scene, tri_material=np.concatenate([rng.integers(1, 4, len(t)), [0, 0]]).astype(
        np.int32), albedo=albedo, opacity=np.array([1.0, 0.3, 0.6, 0.45], np.float32))
    sm = top_down_map(scene.vertices, scene.triangles, 24)
    whole = msm.generate_moment_shadow_map(scene, sm, supersampling=3, bits=64, coloured=True)
    assert whole.translucent_layers == 7
    monkeypatch.setattr(translucency, "TRANSLUCENT_BAND_BYTES", 24 * 7 * 72 * 3 * 5)  # 5 map rows per band
    banded = msm.generate_moment_shadow_map(scene, sm, supersampling=3, bits=64, coloured=True)
    np.testing.assert_array_equal(banded.numpy(), whole.numpy())


def test_channel_opacities_definition():
    op = np.array([0.5, 0.5, 1.0, 0.0, 0.4])
    albedo = np.array([[0.3, 0.3, 0.3], [0.9, 0.2, 0.1], [0.9, 0.2, 0.1], [0.9, 0.2, 0.1], [1.0, 1.0, 1.0]])
    mono = msm.channel_opacities(op, albedo)
    np.testing.assert_allclose(mono[:, 0], op, atol=1e-7)
    rgb = msm.channel_opacities(op, albedo, coloured=True).astype(np.float64)
    np.testing.assert_allclose(rgb[0], 0.5, atol=1e-7)  # grey: the monochrome opacity
    np.testing.assert_allclose(rgb[4], 0.4, atol=1e-7)  # white is grey too
    np.testing.assert_allclose(rgb[2], 1.0)  # opaque stays opaque
    np.testing.assert_allclose(rgb[3], 0.0)  # invisible stays invisible
    t = 1.0 - rgb[1]
    assert t[0] > t[1] > t[2]  # red material transmits red best
    np.testing.assert_allclose(np.prod(t) ** (1 / 3), 0.5, atol=1e-6)  # geometric mean = 1 - alpha
    with pytest.raises(ValueError, match="opacity"):
        msm.channel_opacities([1.5], [[0.5, 0.5, 0.5]])


def test_coloured_translucency_one_map_per_channel():
    albedo = [[0.5, 0.5, 0.5], [0.9, 0.3, 0.2]]
    scene = layered_scene([horizontal_plane(0.0), horizontal_plane(5.0)], [1.0, 0.6], albedo)
    sm = top_down_map(scene.vertices, scene.triangles, 8)
    m = msm.generate_moment_shadow_map(scene, sm, supersampling=1, bits=128, coloured=True)
    assert m.channels == 3
    transmittance = 1.0 - msm.channel_opacities([1.0, 0.6], albedo, coloured=True)[1]
    vis = msm.msm_visibility_at(m, [[0.2, 0.0, 0.4]], depth_bias=0.05, overdarkening=0.0)[0]
    # two depths per channel: exact up to the bias (measured 7.2e-7)
    np.testing.assert_allclose(vis, transmittance, atol=1e-4)
    assert vis[0] > vis[1] > vis[2]
    mono = msm.generate_moment_shadow_map(scene, sm, supersampling=1, bits=128)
    np.testing.assert_allclose(msm.msm_visibility_at(mono, [[0.2, 0.0, 0.4]], depth_bias=0.05,
                                                     overdarkening=0.0)[0], [0.4], atol=1e-4)  # measured 5.7e-7


def test_invalid_arguments_raise():
    scene = edge_scene()
    sm = top_down_map(scene.vertices, scene.triangles, 8)
    with pytest.raises(ValueError, match="bits"):
        msm.generate_moment_shadow_map(scene, sm, bits=32)
    with pytest.raises(ValueError, match="supersampling"):
        msm.generate_moment_shadow_map(scene, sm, supersampling=0)
    with pytest.raises(ValueError, match="filter_px"):
        msm.gaussian_weights(0)
    with pytest.raises(ValueError, match="depth_bias"):
        msm.moment_params(sm, depth_bias=-1.0)
    with pytest.raises(ValueError, match="overdarkening"):
        msm.moment_params(sm, overdarkening=1.5)
    with pytest.raises(ValueError, match="points"):
        msm.msm_visibility_at(msm.generate_moment_shadow_map(scene, sm), np.zeros((4, 2)))
    bad = dataclasses.replace(scene, opacity=np.array([-0.1], np.float32))
    with pytest.raises(ValueError, match="opacity"):
        msm.generate_moment_shadow_map(bad, sm)


# ---------------------------------------------------------------------------------------------------------------------
# Mip-mapped sampling (D.2 "generate a full mipmap hierarchy")
# ---------------------------------------------------------------------------------------------------------------------


def unpack_mips(m):
    """Levels of a packed mip chain as a list of (C, h, w, 4) float64 arrays."""
    h, w = m.shape
    flat = m.mips.numpy().reshape(m.channels, -1, 4).astype(np.float64)
    out, off = [], 0
    for level in range(m.mip_levels):
        lw, lh = max(w >> level, 1), max(h >> level, 1)
        out.append(flat[:, off : off + lw * lh].reshape(m.channels, lh, lw, 4))
        off += lw * lh
    assert off == flat.shape[1]
    return out


@pytest.mark.parametrize("bits", [64, 128])
def test_mip_chain_is_the_box_average_of_the_moments(bits):
    rng = np.random.default_rng(11)
    v, t = random_soup(rng)
    scene = make_scene(v, t)
    sm = top_down_map(scene.vertices, scene.triangles, 32)
    m = msm.build_mip_chain(msm.render_moment_shadow_map(scene, sm, supersampling=2, bits=bits, filter_px=3))
    assert m.mip_levels == 6 and m.nbytes == (32 * 32 + sum(4**k for k in range(6))) * bits // 8
    levels = unpack_mips(m)
    base = m.numpy()[0].astype(np.float64)
    np.testing.assert_array_equal(levels[0][0], base)
    lsb = 1.0 / 65535.0 if bits == 64 else 0.0
    for level in range(1, m.mip_levels):
        n = 1 << level
        box = base.reshape(32 // n, n, 32 // n, n, 4).mean(axis=(1, 3))
        # 64 bits: every level rounds to 16 bits again (at most half a step each)
        assert np.abs(levels[level][0] - box).max() <= 0.5 * lsb * level + 1e-6  # measured 1.6e-5 (64), 9.4e-8 (128)
    # a level of moments is a valid moment map: positive variance wherever depths differ in the block
    b = mm.dequantize4(levels[3][0], m.storage) if bits == 64 else levels[3][0]
    assert np.all(b[..., 1] - b[..., 0] ** 2 > -1e-4)


def test_trilinear_footprint_matches_pcf_over_the_footprint():
    """At level-k texel centres with a footprint of exactly 2^k texels the trilinear look-up reads level k alone: the
    box average of 2^k x 2^k texels. With two depths per block (ground and one occluder) Algorithm 1 is exact, so
    the visibility equals the lit fraction of the supersampled depth samples in the block (PCF over the footprint)."""
    scene = edge_scene()
    res, s = 32, 2
    sm = top_down_map(scene.vertices, scene.triangles, res)  # texel 0.125 over [-2, 2]^2
    m = msm.build_mip_chain(msm.render_moment_shadow_map(scene, sm, supersampling=s, bits=128, filter_px=1))
    z = sample_signed_depths(scene, sm, s)
    bias = 0.05
    z_f = signed(0.0) - bias * 2.0 / (FAR - NEAR)
    lit = (z >= z_f).astype(np.float64)  # (2 res, 2 res) samples; row 0 = map row 0
    for k in (0, 1, 2, 3):
        n = 1 << k
        cells = res // n
        centres = -2.0 + (np.arange(cells) + 0.5) * 4.0 / cells
        # map u runs along +x, v (down) along +z for this top-down view (see top_down_map)
        xx, zz = np.meshgrid(centres, centres)
        pts = np.stack([xx, np.zeros_like(xx), zz], axis=-1).reshape(-1, 3).astype(np.float32)
        foot = n * sm.texel_world
        got = msm.msm_visibility_footprint_at(m, pts, [foot, 0.0, 0.0], [0.0, 0.0, foot], depth_bias=bias,
                                              overdarkening=0.0)[:, 0].reshape(cells, cells)
        truth = lit.reshape(cells, s * n, cells, s * n).mean(axis=(1, 3))
        assert np.abs(got - truth).max() < 1e-4  # measured 6.6e-7 (levels 0-3)
        if k > 0:
            assert np.any((truth > 0.05) & (truth < 0.95))  # the footprint really straddles the edge
    # footprints below a texel are the bilinear look-up; without a chain the footprint look-up is bilinear too
    pts = np.stack([np.linspace(-1.5, 1.5, 37), np.zeros(37), np.full(37, 0.3)], axis=-1)
    bil = msm.msm_visibility_at(m, pts, depth_bias=bias)
    np.testing.assert_allclose(msm.msm_visibility_footprint_at(m, pts, [0.01, 0, 0], [0, 0, 0.01], depth_bias=bias),
                               bil, atol=1e-6)
    plain = dataclasses.replace(m, mips=None, mip_levels=0)
    np.testing.assert_allclose(msm.msm_visibility_footprint_at(plain, pts, [1.0, 0, 0], [0, 0, 1.0], depth_bias=bias),
                               bil, atol=1e-6)
    # degenerate footprints (zero, huge, non-finite) stay finite and in [0, 1]
    for f in (0.0, 1e30, np.inf, np.nan):
        vis = msm.msm_visibility_footprint_at(m, pts, [f, 0, 0], [0, 0, f], depth_bias=bias)
        assert np.all(np.isfinite(vis)) and np.all((vis >= 0.0) & (vis <= 1.0))


@wp.kernel
def footprint_kernel(cam: CameraParams, i: int, j: int, x: wp.vec3, n: wp.vec3, out: wp.array(dtype=wp.vec3)):
    dx, dy = pixel_footprint(cam, i, j, x, n)
    out[0] = dx
    out[1] = dy


def footprint_at(cam, i, j, x, n):
    out = wp.zeros(2, dtype=wp.vec3)
    wp.launch(footprint_kernel, 1, inputs=[cam.params(), i, j, wp.vec3(*x), wp.vec3(*n), out])
    return out.numpy()


def test_pixel_footprint_on_a_facing_and_a_grazing_plane():
    """The footprint of the mip-level selection: a plane facing the camera at distance D has footprint sides
    D * 2 tan(fov/2) / height (square pixels); on a plane seen at a grazing angle the sides are where the neighbouring
    pixels' rays meet it."""
    cam = Camera(position=[0, 0, -10], look_at=[0, 0, 0], up=[0, 1, 0], fov_y=60, width=64, height=48, near=0.1,
                 far=100)
    d = cam.ray_directions()[24, 32]  # pixel (32, 24)'s ray; x is where it meets the plane through the origin
    side = 10.0 * 2.0 * np.tan(np.radians(30.0)) / 48
    x = np.asarray(cam.position) + d * (10.0 / d[2])
    dx, dy = footprint_at(cam, 32, 24, x, [0.0, 0.0, -1.0])
    for e in (dx, dy):
        assert abs(np.linalg.norm(e) / side - 1.0) < 1e-3  # measured 1.0e-7
    tilt = np.radians(75.0)
    n = np.array([0.0, np.sin(tilt), -np.cos(tilt)])  # tilted 75 degrees about x: the vertical side stretches
    x = np.asarray(cam.position) + d * (np.dot(-np.asarray(cam.position), n) / np.dot(d, n))
    dx, dy = footprint_at(cam, 32, 24, x, n)
    rays = cam.ray_directions()
    for got, nb in ((dx, rays[24, 33]), (dy, rays[25, 32])):  # exact: the neighbouring rays meet the plane
        hit = np.asarray(cam.position) + nb * (np.dot(x - cam.position, n) / np.dot(nb, n))
        assert np.abs(got - (hit - x)).max() < 1e-4 * np.linalg.norm(hit - x)  # measured 9.7e-6
    assert np.linalg.norm(dy) > 2.0 * side  # the grazing side really stretches (measured 3.3x)
    # a plane containing the neighbouring pixel rays falls back to the facing footprint: finite
    dx, dy = footprint_at(cam, 32, 24, x, [1.0, 0.0, 0.0])
    assert np.all(np.isfinite(dx)) and np.all(np.isfinite(dy))
