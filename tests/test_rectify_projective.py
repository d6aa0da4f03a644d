"""Tests of Klehm 2014's projective rectification (warpscatter.scattering.rectify; Sec. 4.2, Eq. 12)."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
import trimesh
import warp as wp

from warpscatter.raster import rasterizer as raster
from warpscatter.raster.raycast import build_mesh, ray_hit
from warpscatter.runtime.device import default_device, module_options
from warpscatter.scattering.rectify import projective, reference_rays
from warpscatter.scattering.rectify.projective import ProjectiveRectification
from warpscatter.scene.camera import Camera

module_options()

GUARD = 0.1
DEPTH_MARGIN = 0.5 * GUARD / (1.0 + GUARD)  # frustum depths lie in [m, 1 - m] with the guard band


# ---- random cameras with the light (and its flip) well outside the view -------------------------------------


def _unit(rng) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _camera(rng) -> Camera:
    pos = rng.uniform(-20.0, 20.0, 3)
    fwd = _unit(rng)
    up = _unit(rng)
    while np.linalg.norm(np.cross(fwd, up)) < 0.1:
        up = _unit(rng)
    return Camera(position=pos, look_at=pos + fwd * rng.uniform(1.0, 5.0), up=up, fov_y=rng.uniform(10.0, 100.0),
                  width=int(rng.integers(8, 64)), height=int(rng.integers(8, 64)), near=rng.uniform(0.05, 1.0),
                  far=rng.uniform(5.0, 200.0))


def _side_cases(n: int, seed: int):
    """(rng, camera, light) with every epipole at least 0.05 half image heights outside the image."""
    rng = np.random.default_rng(seed)
    made = 0
    while made < n:
        cam = _camera(rng)
        light = _unit(rng)
        if projective.epipole_distance(cam, light)[0] < 0.05:
            continue
        made += 1
        yield rng, cam, light


def _frustum_points(cam: Camera, rng, n: int) -> np.ndarray:
    """Points of the view frustum between the near and the far plane, a quarter on side planes, a quarter on the
    far plane, some on the near plane."""
    right, up, fwd = cam.basis
    t = math.tan(math.radians(cam.fov_y) / 2.0)
    sx, sy = rng.uniform(-1.0, 1.0, n), rng.uniform(-1.0, 1.0, n)
    sx[: n // 8] = np.sign(sx[: n // 8])
    sy[n // 8 : n // 4] = np.sign(sy[n // 8 : n // 4])
    d = fwd + sx[:, None] * t * cam.aspect * right + sy[:, None] * t * up
    depth = cam.near + (cam.far - cam.near) * rng.uniform(0.0, 1.0, n) ** 2
    depth[n // 2 : 3 * n // 4] = cam.far
    depth[3 * n // 4 : 3 * n // 4 + n // 16] = cam.near
    return cam.position + depth[:, None] * d


# ---- coordinates ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("regions", [1, 5])
def test_round_trip_world_rectified_world(regions):
    worst = 0.0
    for rng, cam, light in _side_cases(80, 1):
        rect = ProjectiveRectification.from_camera(cam, light, rows=64, cols=120, regions=regions)
        p = _frustum_points(cam, rng, 400)
        back = rect.rectified_to_world(rect.world_to_rectified(p))
        err = np.linalg.norm(back - p, axis=1) / np.linalg.norm(p - cam.position, axis=1)
        worst = max(worst, err.max())
    assert worst < 1e-9  # measured 9.1e-12 (regions 1) and 1.4e-14 (regions 5), float64


def test_view_rays_keep_row_and_depth():
    """Every pixel's view ray lies in one row with one depth and runs left to right (u grows with t)."""
    worst_v = worst_z = 0.0
    min_du = np.inf
    for _rng, cam, light in _side_cases(60, 2):
        rect = ProjectiveRectification.from_camera(cam, light, rows=64, cols=96, regions=3)
        dirs = cam.ray_directions().reshape(-1, 3)
        t_near = cam.near / (dirs @ cam.forward)
        t = t_near[:, None] + np.linspace(0.0, 1.0, 25)[None, :] * (cam.far_distance(dirs) - t_near)[:, None]
        c = rect.world_to_rectified(cam.position + t[..., None] * dirs[:, None, :])
        worst_v = max(worst_v, np.abs(c[..., 1] - c[:, :1, 1]).max())
        worst_z = max(worst_z, np.abs(c[..., 2] - c[:, :1, 2]).max())
        min_du = min(min_du, np.diff(c[..., 0], axis=1).min())
        # the depth of the ray from its direction alone (rectified_ray_depth's formula)
        q = dirs @ rect.to_light.T
        z_dir = (q[:, 2] / q[:, 0] - rect.zeta_lo) / (rect.zeta_hi - rect.zeta_lo)
        worst_z = max(worst_z, np.abs(c[:, 0, 2] - z_dir).max())
    assert worst_v < 1e-9  # measured 6.2e-14
    assert worst_z < 1e-9  # measured 8.6e-14
    assert min_du > 0.0  # measured 5.7e-4: strictly increasing along every ray


def test_bounds_contain_and_touch_the_frustum():
    """Frustum points beyond the near plane map into [0, 1]^2 x [m, 1 - m]; the corners reach every bound."""
    worst = 0.0
    gaps = np.zeros(3)
    for rng, cam, light in _side_cases(300, 3):
        rect = ProjectiveRectification.from_camera(cam, light, guard_band=GUARD, rows=64, cols=64)
        assert 0.0 < rect.near < rect.far and rect.half_angle < 0.5 * math.pi
        assert abs(rect.s_lo + rect.s_hi) < 1e-9 * max(1.0, rect.s_hi)  # the bisectrix makes left = -right
        c = rect.world_to_rectified(_frustum_points(cam, rng, 2000))
        worst = max(worst, -c[:, 0].min(), c[:, 0].max() - 1.0, -c[:, 1].min(), c[:, 1].max() - 1.0,
                    DEPTH_MARGIN - c[:, 2].min(), c[:, 2].max() - (1.0 - DEPTH_MARGIN))
        k = rect.world_to_rectified(cam.frustum_corners())
        gaps = np.maximum(gaps, [min(k[:, 0].min(), 1.0 - k[:, 0].max()), min(k[:, 1].min(), 1.0 - k[:, 1].max()),
                                 max(k[:, 2].min() - DEPTH_MARGIN, 1.0 - DEPTH_MARGIN - k[:, 2].max())])
    assert worst < 1e-9  # measured 0.0
    assert gaps.max() < 1e-9  # measured 2.2e-16: the bounds are tight


def test_rejects_light_in_view_and_bad_arguments():
    cam = Camera(position=[0, 1, 0], look_at=[0, 1, -1], up=[0, 1, 0], fov_y=60, width=32, height=24, near=0.1,
                 far=50)
    for light in ([0.1, 0.05, 1.0], [0.05, -0.1, -1.0]):  # light travelling towards the camera / away along the view
        with pytest.raises(ValueError, match="impossible"):
            ProjectiveRectification.from_camera(cam, light)
    side = [1.0, -0.3, 0.1]
    with pytest.raises(ValueError, match="regions"):
        ProjectiveRectification.from_camera(cam, side, regions=0)
    with pytest.raises(ValueError, match="cols"):
        ProjectiveRectification.from_camera(cam, side, cols=8, regions=4)
    with pytest.raises(ValueError, match="light_direction"):
        ProjectiveRectification.from_camera(cam, [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="guard_band"):
        ProjectiveRectification.from_camera(cam, side, guard_band=-1.0)


def test_clip_matrices_agree_with_coordinates():
    """Each region's 4x4 matrix maps the points of its x range to (local u, v, depth) in NDC (Klehm 2014 Sec. 4.2:
    near/far from the corners' x, left/right and bottom/top from their slopes)."""
    worst = 0.0
    for rng, cam, light in _side_cases(30, 4):
        rect = ProjectiveRectification.from_camera(cam, light, rows=50, cols=90, regions=3)
        p = _frustum_points(cam, rng, 600)
        c = rect.world_to_rectified(p)
        col = c[:, 0] * rect.cols
        starts = rect.region_columns()
        for k in range(rect.regions):
            inside = (col >= starts[k]) & (col < starts[k + 1])
            h = np.concatenate([p[inside], np.ones((inside.sum(), 1))], axis=1) @ rect.world_to_clip(k).T
            ndc = h[:, :3] / h[:, 3:]
            local = (col[inside] - starts[k]) / (starts[k + 1] - starts[k])
            worst = max(worst, np.abs(0.5 * ndc[:, 0] + 0.5 - local).max(),
                        np.abs(0.5 - 0.5 * ndc[:, 1] - c[inside, 1]).max(),
                        np.abs(0.5 * ndc[:, 2] + 0.5 - c[inside, 2]).max())
    assert worst < 1e-9  # measured 6.9e-14


def test_kernel_funcs_match_host():
    """A user kernel calls the public @wp.funcs; float32 results match the float64 host transforms."""

    @wp.kernel
    def user_kernel(rect: projective.ProjectiveRectParams, pts: wp.array(dtype=wp.vec3), dirs: wp.array(dtype=wp.vec3),
                    coords: wp.array(dtype=wp.vec3), back: wp.array(dtype=wp.vec3), ray_depth: wp.array(dtype=float)):
        n = wp.tid()
        c = projective.world_to_rectified(rect, pts[n])
        coords[n] = c
        back[n] = projective.rectified_to_world(rect, c)
        ray_depth[n] = projective.rectified_ray_depth(rect, dirs[n])

    device = default_device()
    worst = np.zeros(3)
    for rng, cam, light in _side_cases(30, 5):
        rect = ProjectiveRectification.from_camera(cam, light, rows=64, cols=128, regions=int(rng.integers(1, 9)))
        p = _frustum_points(cam, rng, 256)
        n = len(p)
        dirs = (p - cam.position) / np.linalg.norm(p - cam.position, axis=1, keepdims=True)
        out = [wp.empty(n, dtype=wp.vec3, device=device) for _ in range(2)] + [wp.empty(n, dtype=float, device=device)]
        wp.launch(user_kernel, n, [rect.params(), wp.array(p, dtype=wp.vec3, device=device),
                                   wp.array(dirs, dtype=wp.vec3, device=device), *out], device=device)
        c_host = rect.world_to_rectified(p)
        c_dev, back, zdir = (a.numpy() for a in out)
        dist = np.linalg.norm(p - cam.position, axis=1)
        worst = np.maximum(worst, [np.abs(c_dev - c_host).max(), (np.linalg.norm(back - p, axis=1) / dist).max(),
                                   np.abs(zdir - c_host[:, 2]).max()])
    assert worst[0] < 2e-4  # measured 4.9e-5 (float32, points up to 200 units away)
    assert worst[1] < 2e-3  # measured 3.5e-4 relative to the distance from the camera
    assert worst[2] < 1e-5  # measured 7.1e-7


# ---- rasterization straight into the rectified map -------------------------------------------------------------


@wp.kernel
def _light_ray_depth_kernel(mesh: wp.uint64, rect: projective.ProjectiveRectParams, start: float,
                            out: wp.array2d(dtype=float)):
    # brute force: the light ray of texel (j, i) cast from far upstream along the light; first hit -> depth
    j, i = wp.tid()
    c = wp.vec3((float(i) + 0.5) / float(rect.cols), (float(j) + 0.5) / float(rect.rows), 0.0)
    p = projective.rectified_to_world(rect, c)  # depth 0: the texel's light ray at slope zeta_lo
    ez = wp.vec3(rect.to_light[2, 0], rect.to_light[2, 1], rect.to_light[2, 2])
    origin = p - ez * start
    t, tri = ray_hit(mesh, origin, ez, 1.0e6)
    result = float(1.0)
    if tri >= 0:
        result = wp.clamp(projective.world_to_rectified(rect, origin + ez * t)[2], 0.0, 1.0)
    out[j, i] = result


def _boxes(upstream):
    """Casters inside the frustum, a slab at ``upstream`` (between the light and the frustum), one behind the
    camera (x < 0), a ground plane."""
    parts = [trimesh.creation.box([0.5, 3.0, 0.5], trimesh.transformations.translation_matrix(c))
             for c in ([-1.0, 1.5, -6.0], [1.5, 1.0, -9.0], [0.0, 0.5, -14.0], [-3.0, 2.0, -20.0])]
    parts.append(trimesh.creation.box([6.0, 0.3, 6.0], trimesh.transformations.translation_matrix(upstream)))
    parts.append(trimesh.creation.box([2.0, 2.0, 2.0], trimesh.transformations.translation_matrix([0.0, 1.0, 6.0])))
    ground = trimesh.transformations.translation_matrix([0.0, -0.05, -20.0])
    parts.append(trimesh.creation.box([40.0, 0.1, 60.0], ground))
    m = trimesh.util.concatenate(parts)
    return np.asarray(m.vertices, np.float32), np.asarray(m.faces, np.int32)


def test_rasterized_map_matches_light_ray_casts():
    """The map rasterized with the region matrices (depth clamping, no near clipping) equals casting every
    texel's light ray against the mesh: casters upstream of the frustum clamp to depth 0 and stay in the map."""
    cam = Camera(position=[0.0, 1.6, 0.0], look_at=[0.3, 1.4, -10.0], up=[0, 1, 0], fov_y=55, width=64, height=36,
                 near=0.1, far=40.0)
    light = np.array([0.6, -0.5, 0.2])
    upstream = cam.position + 8.0 * cam.forward - 30.0 * light / np.linalg.norm(light)
    assert ProjectiveRectification.from_camera(cam, light).world_to_rectified(upstream)[2] < 0.0  # before depth 0
    v, f = _boxes(upstream)
    device = default_device()
    mesh = build_mesh(v, f, device)
    for regions in (1, 3):
        rect = ProjectiveRectification.from_camera(cam, light, rows=90, cols=120, regions=regions)
        got = projective.rasterize_rectified(rect, v, f, device=device).numpy()
        ref = wp.empty((rect.rows, rect.cols), dtype=float, device=device)
        wp.launch(_light_ray_depth_kernel, (rect.rows, rect.cols), [mesh.id, rect.params(), 100.0, ref],
                  device=device)
        ref = ref.numpy()
        diff = np.abs(got - ref)
        assert (diff > 1e-3).mean() < 0.005  # measured 0 for 1 and 3 regions (ties on edges would differ)
        assert np.median(diff[ref < 1.0]) < 1e-4  # measured 1.6e-5 (1 region), 6.6e-7 (3): float32, 1/1024-px snapping
        assert (got == 0.0).sum() >= (20 if regions == 1 else 300)  # upstream slab at depth 0: measured 34, 563 texels
        assert ((got == 0.0) != (ref == 0.0)).mean() < 0.005  # measured 0


def test_raster_clip_near_false_keeps_geometry_in_front_of_the_near_plane():
    """raster.rasterize(clip_near=False) with a perspective matrix keeps what lies between the centre of projection
    and the near plane (clamped to depth -1) and still drops everything behind the centre of projection."""
    cam = Camera(position=[0, 0, 0], look_at=[0, 0, -1], up=[0, 1, 0], fov_y=60, width=16, height=16, near=1.0,
                 far=10.0)
    vp = cam.view_projection()
    quad = lambda z: (np.array([[-5, -5, z], [5, -5, z], [5, 5, z], [-5, 5, z]], np.float32),  # noqa: E731
                      np.array([[0, 1, 2], [0, 2, 3]], np.int32))
    v, f = quad(-0.5)  # between the camera and its near plane
    assert np.isinf(raster.rasterize(v, f, vp, 16, 16, clamp_depth=True).ndc_depth).all()  # default: clipped
    kept = raster.rasterize(v, f, vp, 16, 16, clamp_depth=True, clip_near=False).ndc_depth
    assert (kept == -1.0).all()
    v, f = quad(0.5)  # behind the centre of projection
    assert np.isinf(raster.rasterize(v, f, vp, 16, 16, clamp_depth=True, clip_near=False).ndc_depth).all()
    # a quad crossing the camera plane: only its part in front is drawn
    v = np.array([[-5, -1, 3], [5, -1, 3], [5, -1, -6], [-5, -1, -6]], np.float32)
    crossing = raster.rasterize(v, np.array([[0, 1, 2], [0, 2, 3]], np.int32), vp, 16, 16, clamp_depth=True,
                                clip_near=False).ndc_depth[0]
    # the floor (y = -1, z in [-6, 3]) shows below the image row of its far edge (row 10.3) and nowhere above
    assert np.isinf(crossing[:10]).all() and np.isfinite(crossing[11:]).all()


# ---- reference rays and Eq. 12 -------------------------------------------------------------------------------


def _k(h, zeta):
    """k(omega) of Klehm 2014 Sec. 3.2 (cosine to the light-perpendicular) of direction (1, s, zeta), h = |(1, s)|."""
    return h / np.sqrt(h**2 + zeta**2)


def test_reference_rays_lie_in_their_slice():
    for _rng, cam, light in _side_cases(20, 7):
        rect = ProjectiveRectification.from_camera(cam, light, rows=48, cols=64)
        for method in ("optimal", "bisectrix", "mean", "pixels"):
            ref = reference_rays.reference_rays(rect, method, cam, pixel_stride=2)
            q = ref.direction @ rect.to_light.T
            np.testing.assert_allclose(q[:, 1] / q[:, 0], ref.slope, atol=1e-9)
            np.testing.assert_allclose(q[:, 2] / q[:, 0], ref.zeta_ref, atol=1e-9)
            np.testing.assert_allclose(1.0 / q[:, 0], ref.length_scale, rtol=1e-12)
            if method in ("optimal", "bisectrix"):
                assert np.all(ref.zeta_ref >= ref.zeta_lo - 1e-9) and np.all(ref.zeta_ref <= ref.zeta_hi + 1e-9)
            if method == "pixels":  # a pixel ray of the slice, within the slice's range up to the row's width
                width = 2.0 * (rect.zeta_max - rect.zeta_min) / rect.rows
                assert np.all(ref.zeta_ref >= ref.zeta_lo - width) and np.all(ref.zeta_ref <= ref.zeta_hi + width)
        # optimal: k_ref = sqrt(k(omega_min) k(omega_max)) (Klehm 2014 Sec. 3.2)
        ref = reference_rays.reference_rays(rect, "optimal")
        h = np.sqrt(1.0 + ref.slope**2)
        k_near = _k(h, np.clip(0.0, ref.zeta_lo, ref.zeta_hi))
        k_far = np.minimum(_k(h, ref.zeta_lo), _k(h, ref.zeta_hi))
        np.testing.assert_allclose(ref.k_ref, np.sqrt(k_near * k_far), rtol=1e-9)


def test_slice_depth_range_brute_force():
    """Per-row depth-slope range equals the range of the frustum's pixel rays falling into that row."""
    gap = 0.0
    for _rng, cam, light in _side_cases(8, 8):
        rect = ProjectiveRectification.from_camera(cam, light, rows=16, cols=64)
        right, up, fwd = cam.basis
        t = math.tan(math.radians(cam.fov_y) / 2.0)
        s = np.linspace(-1.0, 1.0, 801)
        sx, sy = np.meshgrid(s, s)
        q = (fwd + sx[..., None] * t * cam.aspect * right + sy[..., None] * t * up).reshape(-1, 3) @ rect.to_light.T
        slope, zeta = q[:, 1] / q[:, 0], q[:, 2] / q[:, 0]
        lo, hi = rect.slice_depth_slope_range(slope)
        assert np.all(zeta >= lo - 1e-9) and np.all(zeta <= hi + 1e-9)
        for s_row in rect.row_slopes()[::3]:
            near = np.abs(slope - s_row) < 2e-3 * (rect.s_hi - rect.s_lo)
            lo_r, hi_r = rect.slice_depth_slope_range(np.array(s_row))
            span = rect.zeta_max - rect.zeta_min
            gap = max(gap, abs(zeta[near].min() - float(lo_r)) / span, abs(zeta[near].max() - float(hi_r)) / span)
    assert gap < 0.03  # measured 0.013 of the depth-slope range (sampling of a thin slab of rays)


def test_cross_ratio_factor_and_column_lengths():
    """Eq. 12's d from the first three texel centres equals the projective map's step ratio there; the exact
    column widths sum to f - n, and Eq. 12's geometric series underestimates the far columns."""
    cam = Camera(position=[0, 1.7, 0], look_at=[0.5, 1.5, -10], up=[0, 1, 0], fov_y=50, width=64, height=36,
                 near=0.1, far=100.0)
    for regions in (1, 4, 16):
        rect = ProjectiveRectification.from_camera(cam, [0.6, -0.5, 0.2], rows=32, cols=1024, regions=regions)
        d, first = projective.cross_ratio_factors(rect)
        starts, b = rect.region_columns(), rect.region_bounds()
        for k in range(regions):
            x = rect.column_to_x(starts[k] + np.array([0.5, 1.5, 2.5]))
            assert d[k] == pytest.approx((x[2] - x[1]) / (x[1] - x[0]), rel=1e-9)
            assert first[k] == pytest.approx(x[1] - x[0], rel=1e-9)
            assert b[k + 1] / b[k] == pytest.approx((rect.far / rect.near) ** (1.0 / regions), rel=1e-9)
        exact = projective.column_lengths(rect, "exact")
        eq12 = projective.column_lengths(rect, "cross_ratio")
        assert exact.sum() == pytest.approx(rect.far - rect.near, rel=1e-9)
        assert np.all(exact > 0) and np.all(eq12 > 0)
        # the true growth factor increases along a region, so Eq. 12 covers less x: measured sum ratios
        # 0.0022 (1 region), 0.42 (4), 0.94 (16) for f/n = 1449
        ratio = eq12.sum() / exact.sum()
        assert ratio < 1.0
        if regions == 16:
            assert ratio > 0.9
    with pytest.raises(ValueError, match="model"):
        projective.column_lengths(rect, "linear")
    with pytest.raises(ValueError, match="camera"):
        reference_rays.reference_rays(rect, "pixels")


# ---- automatic choice ------------------------------------------------------------------------------------------


def test_auto_choice_follows_the_epipole(caplog):
    cam = Camera(position=[4.0, 1.7, -13.0], look_at=[0.0, 2.6, 0.0], up=[0, 1, 0], fov_y=50, width=160, height=90,
                 near=0.1, far=100.0)
    fwd = cam.forward
    with caplog.at_level(logging.INFO, logger="warpscatter"):
        into_view = projective.choose_rectification(cam, [0.35, -0.3, -1.0])  # light in front, travelling at the camera
        behind = projective.choose_rectification(cam, fwd + np.array([0.0, -0.2, 0.0]))  # light behind the camera
        side = projective.choose_rectification(cam, [0.6, -0.5, 0.2])
    assert into_view.kind == "nonlinear" and into_view.epipole_distance == 0.0
    assert "light epipole inside" in into_view.reason
    assert behind.kind == "nonlinear" and "anti-light" in behind.reason
    assert side.kind == "projective" and side.epipole_distance > 1.0
    assert sum("fourier rectification" in r.getMessage() for r in caplog.records) == 3
    # the threshold: an epipole just outside the image is too close for auto, still possible when requested
    right, up, _ = cam.basis
    t = math.tan(math.radians(cam.fov_y) / 2.0)
    edge = -(fwd + 1.3 * t * up)  # light epipole 0.3 half image heights above the image
    dist, which = projective.epipole_distance(cam, edge)
    assert which == "light" and dist == pytest.approx(0.3, rel=1e-9)
    assert projective.choose_rectification(cam, edge).kind == "nonlinear"
    assert projective.choose_rectification(cam, edge, margin=0.2).kind == "projective"
    assert projective.choose_rectification(cam, edge, "projective").kind == "projective"
    with caplog.at_level(logging.WARNING, logger="warpscatter"):
        forced = projective.choose_rectification(cam, [0.35, -0.3, -1.0], "projective")
    assert forced.kind == "nonlinear" and "impossible" in forced.reason
    assert projective.choose_rectification(cam, [0.6, -0.5, 0.2], "nonlinear").kind == "nonlinear"
    perpendicular = np.cross(fwd, up)
    assert projective.epipole_distance(cam, perpendicular) == (math.inf, "none")
    with pytest.raises(ValueError, match="rectification"):
        projective.choose_rectification(cam, [0.6, -0.5, 0.2], "linear")
    with pytest.raises(ValueError, match="margin"):
        projective.choose_rectification(cam, [0.6, -0.5, 0.2], margin=-1.0)
