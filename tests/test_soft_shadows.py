"""Tests of warpscatter.shadows.soft: integer summed-area tables and moment soft shadows against brute-force PCSS.

Maps use fixed light views: a top-down orthographic view (eye at y = 10 looking down, near 1, far 11) and a
top-down perspective view for the spot-light case. Tolerances are measured maxima with a margin; the measured value
is in a comment next to each bound.
"""

import dataclasses

import numpy as np
import pytest
import warp as wp
from conftest import make_scene, quad
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from warpscatter.raster.rasterizer import linearize_depth, rasterize
from warpscatter.runtime.device import module_options
from warpscatter.scene.camera import look_at_basis, orthographic_matrix, perspective_matrix, view_matrix
from warpscatter.shadows import msm, soft
from warpscatter.shadows.shadow_map import ShadowMap

module_options()

EYE_Y, NEAR, FAR = 10.0, 1.0, 11.0


def top_down_map(vertices, triangles, res, half=2.0, perspective=False):
    """Top-down ShadowMap over [-half, half]^2 (orthographic) or a 2 atan(half / 10) frustum (perspective)."""
    eye = np.array([0.0, EYE_Y, 0.0])
    right, up, fwd = look_at_basis(eye, eye + np.array([0.0, -1.0, 0.0]), [0.0, 0.0, -1.0])
    view = view_matrix(eye, right, up, fwd)
    if perspective:
        proj = perspective_matrix(2.0 * np.degrees(np.arctan(half / EYE_Y)), 1.0, NEAR, FAR)
        texel = 2.0 * half / EYE_Y / res
    else:
        proj = orthographic_matrix(-half, half, -half, half, NEAR, FAR)
        texel = 2.0 * half / res
    r = rasterize(vertices, triangles, proj @ view, res, res, clamp_depth=not perspective)
    depth = linearize_depth(r.ndc_depth[0], proj).astype(np.float32)
    depth[r.tri_id[0] < 0] = np.inf
    return ShadowMap(depth=depth, view=view, projection=proj, perspective=perspective, texel_world=texel)


def plane(y, half=5.0):
    return quad([-half, y, -half], [half, y, -half], [half, y, half], [-half, y, half])


def occluder_scene(size=1.0, height=1.0):
    """Ground at y = 0 and an opaque square |x|, |z| <= size at the given height."""
    gv, gt = plane(0.0)
    ov, ot = quad([-size, height, -size], [size, height, -size], [size, height, size], [-size, height, size])
    return make_scene(np.concatenate([gv, ov]), np.concatenate([gt, ot + 4]))


# ---------------------------------------------------------------------------------------------------------------------
# Summed-area table
# ---------------------------------------------------------------------------------------------------------------------


@wp.kernel
def user_box_kernel(sat: wp.array3d(dtype=wp.vec4ui), boxes: wp.array(dtype=wp.vec4i), out: wp.array(dtype=wp.vec4ui)):
    k = wp.tid()
    b = boxes[k]
    out[k] = soft.sat_box_sum(sat, 0, b[0], b[1], b[2], b[3])


@wp.kernel
def user_rect_kernel(sat: wp.array3d(dtype=wp.vec4ui), rects: wp.array(dtype=wp.vec4), scale: wp.float64,
                     out: wp.array(dtype=wp.vec4)):
    k = wp.tid()
    r = rects[k]
    out[k] = soft.sat_rectangle_average(sat, 0, r[0], r[1], r[2], r[3], scale)


def random_map(rng, w=48, h=40):
    count = 30
    centres = rng.uniform([-2.0, 0.5, -2.0], [2.0, 9.0, 2.0], (count, 1, 3))
    verts = (centres + rng.normal(0.0, 0.8, (count, 3, 3))).reshape(-1, 3).astype(np.float32)
    scene = make_scene(verts, np.arange(3 * count, dtype=np.int32).reshape(-1, 3))
    sm = top_down_map(scene.vertices, scene.triangles, w)
    sm = dataclasses.replace(sm, depth=np.zeros((h, w), np.float32))  # a non-square map (h rows)
    sm = dataclasses.replace(sm, projection=orthographic_matrix(-2.0, 2.0, -2.0 * h / w, 2.0 * h / w, NEAR, FAR))
    return msm.generate_moment_shadow_map(scene, sm, supersampling=2, bits=128)


def test_summed_area_table_box_sums_are_exact_despite_wrap_around():
    rng = np.random.default_rng(11)
    m = random_map(rng)
    kpx = 28  # n_t = 784, the paper's (22.4 bits per texel)
    table = soft.build_summed_area_table(m, kpx)
    ints = soft.sat_texel_integers(m, kpx)[0].astype(np.float64)  # (H, W, 4)
    h, w = m.shape
    assert table.table.shape == (1, h + 1, w + 1) and table.n_t == 784
    # the integers are Theta_4* of the texels scaled by (2^32 - 1) / n_t
    q = ints / table.scale
    np.testing.assert_allclose(q, msm.mm.apply_quantization_transform4(m.numpy()[0]), atol=2e-7)  # measured 9.1e-8
    # the table wraps around: 1920 texels hold up to 2.45 x 2^32 per channel (measured 1.66 x 2^32)
    assert ints.sum(axis=(0, 1)).max() > 1.5 * 2.0**32
    # random boxes of up to n_t texels: the modular sums are exact
    n = 400
    bw, bh = rng.integers(1, kpx + 1, n), rng.integers(1, kpx + 1, n)
    x0, y0 = rng.integers(0, w - bw + 1), rng.integers(0, h - bh + 1)
    boxes = np.stack([x0, y0, x0 + bw, y0 + bh], axis=1).astype(np.int32)
    out = wp.zeros(n, dtype=wp.vec4ui)
    wp.launch(user_box_kernel, n, inputs=[table.table, wp.array(boxes, dtype=wp.vec4i), out])
    ref = np.array([ints[b[1] : b[3], b[0] : b[2]].sum(axis=(0, 1)) for b in boxes])
    np.testing.assert_array_equal(out.numpy().astype(np.float64), ref)
    # the nine sub-rectangles of Fig. 7b give the exact area-weighted average over fractional rectangles
    rects = np.stack([rng.uniform(0, w - kpx, n), rng.uniform(0, h - kpx, n)], axis=1)
    rects = np.concatenate([rects, rects + rng.uniform(0.05, kpx, (n, 2))], axis=1).astype(np.float32)
    avg = wp.zeros(n, dtype=wp.vec4)
    wp.launch(user_rect_kernel, n, inputs=[table.table, wp.array(rects, dtype=wp.vec4), wp.float64(table.scale), avg])
    xe, ye = np.arange(w + 1), np.arange(h + 1)
    ref = []
    for x0_, y0_, x1_, y1_ in rects.astype(np.float64):
        cx = np.clip(np.minimum(xe[1:], x1_) - np.maximum(xe[:-1], x0_), 0, None)
        cy = np.clip(np.minimum(ye[1:], y1_) - np.maximum(ye[:-1], y0_), 0, None)
        ref.append(np.einsum("j,i,jic->c", cy, cx, q) / ((x1_ - x0_) * (y1_ - y0_)))
    assert np.max(np.abs(avg.numpy() - np.array(ref))) < 1e-6  # measured 1.0e-7


# ---------------------------------------------------------------------------------------------------------------------
# Moment soft shadows
# ---------------------------------------------------------------------------------------------------------------------


def profile(x0, x1, n=81, z=0.0):
    xs = np.linspace(x0, x1, n)
    return xs, np.stack([xs, np.zeros_like(xs), np.full_like(xs, z)], axis=-1).astype(np.float32)


def penumbra_width(xs, v, lo=0.05, hi=0.95):
    return np.sum((v > lo) & (v < hi)) * (xs[1] - xs[0])


def test_soft_shadows_umbra_lit_penumbra_and_pcss_agreement():
    scene = occluder_scene()
    res = 64  # texel 1/16
    sm = top_down_map(scene.vertices, scene.triangles, res)
    sat = soft.render_soft_shadow_map(scene, sm, supersampling=1, max_kernel_px=28)
    normal = np.array([0.0, 1.0, 0.0])
    kw = {"depth_bias": 0.01, "normal_offset_texels": 1.0}
    centre = [[0.0, 0.0, 0.0], [0.3, 0.0, -0.4]]
    lit = [[1.8, 0.0, 1.8], [-1.9, 0.0, 0.0]]
    xs, pts = profile(0.5, 1.5)
    widths, errs = [], []
    for angle in (5.0, 15.0, 30.0):
        # umbra (the early-out) and fully lit
        assert np.all(soft.moment_soft_visibility_at(sat, centre, normal, light_angle_deg=angle, **kw) == 0.0)
        lit_vis = soft.moment_soft_visibility_at(sat, lit, normal, light_angle_deg=angle, **kw)
        assert np.all(lit_vis > 0.999)  # measured 0.9999998
        v = soft.moment_soft_visibility_at(sat, pts, normal, light_angle_deg=angle, **kw)[:, 0]
        ref = soft.pcss_visibility_at(sm, pts, normal, light_angle_deg=angle, **kw)
        assert np.all(np.diff(v) >= -1e-6)  # monotonic out of the shadow
        widths.append(penumbra_width(xs, v))
        errs.append(np.abs(v - ref))
    # the penumbra widens with the light: 2 tan(theta/2) x (1 unit between occluder and ground) = 0.087, 0.26, 0.54
    # (measured 5-95% widths 0.0625, 0.2125, 0.45; PCSS 0.0625, 0.2125, 0.4625)
    assert widths[0] < widths[1] < widths[2]
    assert widths[2] > 4.0 * widths[0]
    assert abs(widths[2] - 0.9 * 2.0 * np.tan(np.radians(15.0))) < 0.1
    # against brute-force PCSS with the same kernel (two depths per region: exact up to over-darkening and bias)
    assert max(e.max() for e in errs) < 0.025  # measured 0.016
    assert max(e.mean() for e in errs) < 0.006  # measured 0.0031


def test_soft_shadows_contact_hardening_and_spot_light():
    # a slanted occluder: low edge (y = 0.5) at x = -1, high edge (y = 3) at x = 0.3; the shadow of the low edge is
    # harder (contact hardening), that of the high edge softer
    gv, gt = plane(0.0)
    ov, ot = quad([-1.0, 0.5, -1.0], [0.3, 3.0, -1.0], [0.3, 3.0, 1.0], [-1.0, 0.5, 1.0])
    scene = make_scene(np.concatenate([gv, ov]), np.concatenate([gt, ot + 4]))
    normal = np.array([0.0, 1.0, 0.0])
    xs, pts = profile(-1.6, 1.4, 241)
    low = xs < -0.5
    for perspective, light in ((False, {"light_angle_deg": 20.0}), (True, {"light_size": 1.0})):
        sm = top_down_map(scene.vertices, scene.triangles, 64, half=2.5, perspective=perspective)
        sat = soft.render_soft_shadow_map(scene, sm, supersampling=1, max_kernel_px=32)
        v = soft.moment_soft_visibility_at(sat, pts, normal, depth_bias=0.01, **light)[:, 0]
        ref = soft.pcss_visibility_at(sm, pts, normal, max_kernel_px=32, depth_bias=0.01, **light)
        assert v[0] > 0.99 and v[120] == 0.0 and v[-1] > 0.99  # lit, umbra, lit (measured 1 - 3e-7, 0, 1 - 4e-7)
        # the low edge's filter regions hold a continuum of occluder depths close to the receiver: Algorithm 1 leaks
        # light there (measured max 0.11 at x = -0.925 orthographic, 0.025 perspective)
        assert np.max(np.abs(v - ref)) < 0.15
        assert np.mean(np.abs(v - ref)) < 0.025  # measured 0.013 (orthographic), 0.0016 (perspective)
        # contact hardening, as PCSS (measured 5-95% widths 0.51 vs 0.62 orthographic, 0.19 vs 0.24 perspective)
        assert penumbra_width(xs[low], v[low]) < penumbra_width(xs[~low], v[~low])
        big = soft.moment_soft_visibility_at(sat, pts, normal, depth_bias=0.01,
                                             **{k: 2.0 * val for k, val in light.items()})[:, 0]
        assert penumbra_width(xs, big) > 1.6 * penumbra_width(xs, v)  # measured ratio 2.2 (ortho), 2.0 (persp)


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31), angle=st.floats(0.0, 60.0), bias=st.floats(0.0, 5.0))
def test_garbage_tables_and_points_never_give_nan(seed, angle, bias):
    rng = np.random.default_rng(seed)
    scene = occluder_scene()
    sm = top_down_map(scene.vertices, scene.triangles, 6)
    m = msm.generate_moment_shadow_map(scene, sm, supersampling=1, bits=128)
    table = wp.array(rng.integers(0, 2**32, (1, 7, 7, 4), dtype=np.uint64).astype(np.uint32), dtype=wp.vec4ui)
    sat = soft.SummedAreaTable(table=table, max_kernel_px=8, msm=m)
    pts = rng.choice([np.nan, np.inf, -np.inf, 0.0, 1e30], (12, 3)).astype(np.float32)
    pts = np.concatenate([pts, rng.uniform(-3.0, 3.0, (20, 3)).astype(np.float32)])
    v = soft.moment_soft_visibility_at(sat, pts, np.ones_like(pts), light_angle_deg=angle, depth_bias=bias,
                                       normal_offset_texels=1.0)
    r = soft.pcss_visibility_at(sm, pts, None, light_angle_deg=angle, depth_bias=bias, max_kernel_px=8)
    for a in (v, r):
        assert np.all(np.isfinite(a)) and np.all((a >= 0.0) & (a <= 1.0))


def test_invalid_arguments_raise():
    scene = occluder_scene()
    sm = top_down_map(scene.vertices, scene.triangles, 8)
    m = msm.generate_moment_shadow_map(scene, sm, bits=128)
    with pytest.raises(ValueError, match="max_kernel_px"):
        soft.build_summed_area_table(m, 2)
    sat = soft.build_summed_area_table(m, 8)
    with pytest.raises(ValueError, match="light_angle_deg"):
        sat.params(light_size=1.0)
    with pytest.raises(ValueError, match="light_angle_deg"):
        sat.params(light_angle_deg=200.0)
    with pytest.raises(ValueError, match="light_angle_deg"):
        sat.params(light_angle_deg=-1.0)
    psm = top_down_map(scene.vertices, scene.triangles, 8, perspective=True)
    with pytest.raises(ValueError, match="light_size"):
        soft.soft_shadow_params(psm, light_angle_deg=3.0)
    assert soft.sat_moment_bias(28) == pytest.approx(6e-7) and soft.sat_moment_bias(56) == pytest.approx(2.4e-6)
