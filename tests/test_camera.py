"""Camera conventions: pixel-ray directions, row order, matrices (CONVENTIONS.md)."""

import numpy as np
import pytest
import warp as wp

from warpscatter.scene.camera import Camera, CameraParams, orthographic_matrix, pixel_ray_direction


def conventions_ray(cam, i, j):
    """The CONVENTIONS formula, written out independently."""
    t = np.tan(np.radians(cam.fov_y) / 2)
    a = cam.width / cam.height
    fwd = np.asarray(cam.look_at, float) - cam.position
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, cam.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    x = (2 * (i + 0.5) / cam.width - 1) * t * a
    y = (1 - 2 * (j + 0.5) / cam.height) * t
    d = x * right + y * up + fwd
    return d / np.linalg.norm(d)


@pytest.fixture
def cam():
    return Camera(position=[1, 2, 3], look_at=[-2, 1, -4], up=[0, 1, 0], fov_y=47, width=17, height=9, near=0.2,
                  far=80)


def test_ray_directions_follow_conventions(cam):
    dirs = cam.ray_directions()
    assert dirs.shape == (9, 17, 3)
    for i, j in [(0, 0), (16, 0), (0, 8), (16, 8), (8, 4), (3, 7)]:
        np.testing.assert_allclose(dirs[j, i], conventions_ray(cam, i, j), atol=1e-12)


def test_row_zero_is_top(cam):
    dirs = cam.ray_directions()
    up = cam.basis[1]
    assert dirs[0, 8] @ up > 0 > dirs[-1, 8] @ up
    right = cam.basis[0]
    assert dirs[4, 0] @ right < 0 < dirs[4, -1] @ right


@wp.kernel
def _dirs_kernel(cam: CameraParams, out: wp.array2d(dtype=wp.vec3)):
    j, i = wp.tid()
    out[j, i] = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)


def test_kernel_ray_directions_match_host(cam):
    out = wp.zeros((cam.height, cam.width), dtype=wp.vec3, device="cpu")
    wp.launch(_dirs_kernel, dim=out.shape, inputs=[cam.params(), out], device="cpu")
    np.testing.assert_allclose(out.numpy(), cam.ray_directions(), atol=2e-6)  # float32 kernel


def test_view_projection_maps_pixel_rays_to_pixel_centres(cam):
    vp = cam.view_projection()
    dirs = cam.ray_directions()
    for i, j in [(0, 0), (16, 8), (5, 2)]:
        for dist in (0.5, 7.0, 60.0):
            p = cam.position + dist * dirs[j, i]
            c = vp @ np.append(p, 1.0)
            ndc = c[:3] / c[3]
            assert ndc[0] == pytest.approx(2 * (i + 0.5) / cam.width - 1, abs=1e-9)
            assert ndc[1] == pytest.approx(1 - 2 * (j + 0.5) / cam.height, abs=1e-9)
            assert -1 <= ndc[2] <= 1


def test_near_far_map_to_ndc_bounds(cam):
    vp = cam.view_projection()
    for d, z in ((cam.near, -1.0), (cam.far, 1.0)):
        c = vp @ np.append(cam.position + d * cam.forward, 1.0)
        assert c[2] / c[3] == pytest.approx(z, abs=1e-9)
    o = orthographic_matrix(-1, 3, -2, 2, 1, 5)
    assert (o @ [3, 2, -5, 1])[:3] == pytest.approx([1, 1, 1])


def test_far_distance(cam):
    d = cam.ray_directions()
    t = cam.far_distance(d)
    np.testing.assert_allclose(((cam.position + t[..., None] * d) - cam.position) @ cam.forward, cam.far)


@pytest.mark.parametrize("kwargs, msg", [
    ({"near": 5, "far": 1}, "near"),
    ({"width": 0}, "width"),
    ({"fov_y": 180}, "fov_y"),
    ({"up": [-3, -1, -7]}, "parallel"),
])
def test_bad_cameras_raise(kwargs, msg):
    base = {"position": [1, 2, 3], "look_at": [-2, 1, -4], "up": [0, 1, 0], "fov_y": 47, "width": 17, "height": 9,
            "near": 0.2, "far": 80}
    with pytest.raises(ValueError, match=msg):
        Camera(**{**base, **kwargs})


def test_strided_ray_directions_are_a_subset(cam):
    full = cam.ray_directions()
    for s in (2, 3, 4):
        np.testing.assert_array_equal(cam.ray_directions(s), full[s // 2::s, s // 2::s])
