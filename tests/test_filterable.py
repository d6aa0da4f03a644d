"""The filterable baselines of Peters 2017 (warpscatter.shadows.filterable): original moment shadow maps
(msm2015), variance (vsm) and exponential variance (evsm) shadow maps, through msm's pipeline.

The scenes and the top-down light view are test_msm's. Closed forms: with two depths in a filter region and the
receiver at the farther one, Cantelli's bound (VSM, each warp of EVSM) and Algorithm 1 are exact, so every format
matches the exactly filtered shadow test (and PCF away from the edge); with three depths they leak light (never
darken), by amounts the paper orders (Sec. 2.6, Fig. 4). Tolerances are measured maxima with margins.
"""

import numpy as np
import pytest
import warp as wp
from test_msm import (
    FAR,
    NEAR,
    bilinear,
    blur,
    edge_scene,
    horizontal_plane,
    layered_scene,
    pcf_points_kernel,
    sample_signed_depths,
    signed,
    top_down_map,
)

from warpscatter.config import ConfigError, load_config
from warpscatter.shadows import filterable, msm
from warpscatter.shadows import moments as mm

FORMATS = [("msm", 64), ("msm", 128), ("msm2015", 64), ("msm2015", 128), ("vsm", 32), ("vsm", 64), ("evsm", 64),
           ("evsm", 128)]


def test_texels_hold_b_of_z_in_their_format():
    z = np.linspace(-1.0, 1.0, 9).astype(np.float32)
    out = wp.zeros((len(FORMATS), len(z)), dtype=wp.vec4)
    wp.launch(_store_kernel, (len(FORMATS), len(z)), inputs=[wp.array(z), wp.array([filterable.FORMATS[f] for f in
                                                                                    FORMATS], dtype=int), out])
    got = out.numpy()
    z64 = z.astype(np.float64)
    u = 0.5 * z64 + 0.5
    moments_u = np.stack([u, u**2, u**3, u**4], -1)
    q2015 = moments_u @ filterable.QUANTIZATION_2015 + [filterable.QUANTIZATION_OFFSET_2015, 0, 0, 0]
    assert np.all((q2015 >= 0.0) & (q2015 <= 1.0))  # the 2015 transform keeps valid moments in [0, 1]^4
    np.testing.assert_allclose(got[FORMATS.index(("msm2015", 64))], q2015, atol=0.5 / 65535 + 1e-6)
    np.testing.assert_allclose(got[FORMATS.index(("msm2015", 128))], moments_u, atol=1e-7)
    vsm = np.stack([z64, z64**2, 0 * z64, 0 * z64], -1)
    np.testing.assert_allclose(got[FORMATS.index(("vsm", 64))], vsm, atol=1e-7)
    np.testing.assert_allclose(got[FORMATS.index(("vsm", 32))], vsm, rtol=2**-11, atol=2**-24)  # float16
    for bits in (64, 128):
        cp, cn = filterable.EVSM_EXPONENTS[bits]
        e = np.stack([np.exp(cp * z64), np.exp(2 * cp * z64), -np.exp(-cn * z64), np.exp(-2 * cn * z64)], -1)
        np.testing.assert_allclose(got[FORMATS.index(("evsm", bits))], e, rtol=2**-11 if bits == 64 else 1e-6,
                                   atol=2**-24)  # float16 subnormals: steps of 2^-24
    assert np.all(np.isfinite(got))  # float16 EVSM at c = 5.54: exp(2c) = 65,000 fits


@wp.kernel
def _store_kernel(z: wp.array(dtype=float), formats: wp.array(dtype=int), out: wp.array2d(dtype=wp.vec4)):
    f, k = wp.tid()
    fmt = formats[f]
    c = wp.vec2(0.0, 0.0)
    if fmt == filterable.FORMAT_EVSM_FLOAT16:
        c = wp.vec2(5.54, 5.54)
    if fmt == filterable.FORMAT_EVSM_FLOAT32:
        c = wp.vec2(40.0, 5.54)
    t = filterable.store_texel(filterable.texel_from_depth(z[k], fmt, c), fmt)
    if fmt == filterable.FORMAT_MSM2015_UNORM16:  # the stored (quantized) value, not decoded
        out[f, k] = t
    else:
        out[f, k] = filterable.load_texel(t, fmt)


@pytest.mark.parametrize("method, bits", FORMATS)
def test_two_depths_match_the_exactly_filtered_shadow_test_and_pcf(method, bits):
    scene = edge_scene()  # ground at y = 0, occluder at y = 5 over x < 0.1
    res, s, fpx = 32, 2, 5
    sm = top_down_map(scene.vertices, scene.triangles, res)
    m = msm.render_moment_shadow_map(scene, sm, supersampling=s, bits=bits, filter_px=fpx, method=method)
    assert m.storage == filterable.FORMATS[(method, bits)] and m.nbytes == res * res * bits // 8
    xs = np.linspace(-1.5, 1.5, 193)
    pts = np.stack([xs, np.zeros_like(xs), np.full_like(xs, 0.3)], axis=-1).astype(np.float32)
    bias = 0.05
    raw = msm.msm_visibility_at(m, pts, depth_bias=bias, overdarkening=0.0)[:, 0]
    z = sample_signed_depths(scene, sm, s)
    z_f = signed(0.0) - bias * 2.0 / (FAR - NEAR)
    lit = (z >= z_f).reshape(res, s, res, s).mean(axis=(1, 3))
    truth = bilinear(blur(lit, msm.gaussian_weights(fpx).astype(np.float64)), (xs + 2.0) / 4.0, (0.3 + 2.0) / 4.0)
    # two depths: Algorithm 1 and the Cantelli bounds of EVSM's warps are exact but for the depth bias and the
    # rounding (measured max |raw - truth|: msm 2.4e-4 / 6.5e-7, msm2015 1.7e-4 / 3.0e-5, evsm 7.8e-4 / 4.4e-4)
    tol = {"msm": (5e-4, 1e-5), "msm2015": (5e-4, 1e-4), "evsm": (2e-3, 1e-3), "vsm": (0.025, 0.025)}[method]
    assert np.max(np.abs(raw - truth)) < tol[0 if bits == filterable.BITS_OF_METHOD[method][0] else 1]
    if method == "vsm":  # Cantelli with the bias d: p = w(1-w)D^2 / (w(1-w)D^2 + (wD - d)^2) (measured 1.8e-2 vs truth)
        w, d_z, d = 1.0 - truth, signed(0.0) - signed(5.0), bias * 2.0 / (FAR - NEAR)
        var = np.maximum(w * (1 - w) * d_z**2, 1e-6)
        closed = np.where(w * d_z > d, 1.0 - (1.0 - var / (var + (w * d_z - d) ** 2)), 1.0)
        closed = np.where(w >= 1.0 - 1e-9, 0.0, closed)
        # measured 1.0e-4 / 1.0e-6: the variance floor in the umbra (1e-4 with float16 channels, 1e-6 with float32)
        assert np.max(np.abs(raw - closed)) < (2e-4 if bits == 32 else 2e-6)
    out = wp.zeros(len(xs), dtype=wp.float32)
    wp.launch(pcf_points_kernel, len(xs), inputs=[sm.params(), sm.device_depth(), wp.array(pts, dtype=wp.vec3),
                                                  bias, fpx, out])
    far_from_edge = np.abs(xs - 0.1) > 4 * 0.125
    got = msm.msm_visibility_at(m, pts, depth_bias=bias)[:, 0]
    assert np.max(np.abs(got - out.numpy())[far_from_edge]) < 1e-3  # umbra 0, lit 1: measured <= 2.5e-4
    assert np.all(np.diff(got) >= -1e-4)  # monotonic from shadow to light


def three_depth_scene():
    """Ground at y = 0, a fence plane at y = 6 over x < 0 and a thin wall at y = 0.6 over 0 < x < 0.5: the ground
    under the wall is in its short-range shadow while the filter region also holds the fence's depth and the lit
    ground beyond the wall (Peters 2017 Fig. 4: the cyan and orange insets, two and three depths)."""

    def strip(x0, x1, y):
        return (np.array([[x0, y, -3], [x1, y, -3], [x1, y, 3], [x0, y, 3]], np.float32),
                np.array([[0, 1, 2], [0, 2, 3]], np.int32))

    return layered_scene([horizontal_plane(0.0), strip(-3.0, 0.0, 6.0), strip(0.0, 0.5, 0.6)], [1.0, 1.0, 1.0])


def light_leaking(method, bits, scene, sm, xs, bias=0.02, s=2, fpx=9):
    """The largest visibility above the exactly filtered shadow test along the ground at ``xs`` (z = 0.3)."""
    m = msm.render_moment_shadow_map(scene, sm, supersampling=s, bits=bits, filter_px=fpx, method=method)
    pts = np.stack([xs, np.zeros_like(xs), np.full_like(xs, 0.3)], axis=-1).astype(np.float32)
    v = msm.msm_visibility_at(m, pts, depth_bias=bias, overdarkening=0.0)[:, 0]
    assert np.all(np.isfinite(v)) and np.all((v >= 0.0) & (v <= 1.0))
    res = sm.shape[0]
    z = sample_signed_depths(scene, sm, s)
    lit = (z >= signed(0.0) - bias * 2.0 / (FAR - NEAR)).reshape(res, s, res, s).mean(axis=(1, 3))
    truth = bilinear(blur(lit, msm.gaussian_weights(fpx).astype(np.float64)), (xs + 2.0) / 4.0, (0.3 + 2.0) / 4.0)
    # the lower bounds never darken but for rounding (measured >= -1.2e-2 with float16 channels, -1.1e-3 else)
    assert np.min(v - truth) > (-0.02 if (method, bits) in (("vsm", 32), ("evsm", 64)) else -2e-3)
    return float(np.max(v - truth))


def test_more_depths_leak_light_in_the_papers_order():
    scene = three_depth_scene()
    sm = top_down_map(scene.vertices, scene.triangles, 64)  # texel 1/16
    xs = np.linspace(0.0, 0.5, 41)  # the ground in the wall's shadow
    leak = {f: light_leaking(*f, scene, sm, xs) for f in FORMATS}
    # measured (low / high bits): vsm 0.68 / 0.68, evsm 0.13 / 0.024, msm2015 0.036 / 0.031, msm 0.037 / 0.0066
    assert leak["vsm", 64] > 0.2  # variance shadow maps bleed light through the near wall (Fig. 5a)
    assert leak["evsm", 64] < leak["vsm", 64] and leak["evsm", 128] < leak["evsm", 64]  # the warps help (Fig. 4a, e)
    assert leak["msm", 64] < leak["evsm", 64]  # at 64 bits moments beat EVSM (Fig. 4a, b)
    assert leak["msm", 128] < 0.5 * leak["msm2015", 128]  # signed depth in [-1, 1] vs [0, 1] (Fig. 4d, f)
    assert leak["msm", 128] < leak["evsm", 128]  # at 128 bits moments leak least (Fig. 4e, f)


def test_translucent_occluders_in_every_format():
    """Peters 2017 Fig. 5: translucent occluders render into any filterable map with alpha blending."""
    planes = [horizontal_plane(0.0), horizontal_plane(4.0)]
    scene = layered_scene(planes, [1.0, 0.5])
    sm = top_down_map(scene.vertices, scene.triangles, 16)
    pts = np.array([[0.3, 0.0, -0.2], [0.1, 5.0, 0.4]], np.float32)
    for method, bits in FORMATS:
        m = msm.render_moment_shadow_map(scene, sm, supersampling=2, bits=bits, filter_px=3, method=method)
        v = msm.msm_visibility_at(m, pts, depth_bias=0.02, overdarkening=0.0)[:, 0]
        # half the light reaches the ground (two depths: exact up to rounding; measured |err| <= 3e-3), all above
        assert abs(v[0] - 0.5) < 0.01 and v[1] > 0.999, (method, bits, v)


def test_settings_name_the_key():
    base = ["camera.width=16", "camera.height=9"]
    cfg = "configs/gate.yaml"
    with pytest.raises(ConfigError, match=r"render.shadows: .*storage: vsm stores 32 or 64 bits per texel, not 128"):
        load_config(cfg, [*base, "render.shadows.method=vsm", "render.shadows.storage=128"])
    with pytest.raises(ConfigError, match=r"evsm_exponents: each must lie in \(0, 5.545\] at 64 bits"):
        load_config(cfg, [*base, "render.shadows.method=evsm", "render.shadows.evsm_exponents=[40, 5]"])
    with pytest.raises(ConfigError, match=r"evsm_exponents: used by method evsm only"):
        load_config(cfg, [*base, "render.shadows.evsm_exponents=[4, 4]"])
    ok = load_config(cfg, [*base, "render.shadows.method=evsm", "render.shadows.storage=128",
                           "render.shadows.evsm_exponents=[20, 5]"])
    assert ok.render.shadows.evsm_exponents == (20.0, 5.0)
    with pytest.raises(ValueError, match="storage: msm stores 64 or 128 bits per texel, not 32"):
        filterable.format_of("msm", 32)
    assert mm.STORAGE4_UNORM16 == filterable.FORMATS["msm", 64]  # msm's formats are the 4-moment storage modes
