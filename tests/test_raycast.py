"""Tests of warpscatter.raster.raycast: BVH ray queries as @wp.func building blocks, and the per-pixel
depth references (NDC depth through any matrix, camera hit distances) against analytic planes."""

import numpy as np
import pytest
import warp as wp

from warpscatter.raster import rasterizer as raster
from warpscatter.raster import raycast
from warpscatter.scene.camera import Camera, look_at_basis, orthographic_matrix, view_matrix


def quad(center, u, v):
    """Two triangles spanning center +- u +- v."""
    c, u, v = (np.asarray(x, float) for x in (center, u, v))
    verts = np.array([c - u - v, c + u - v, c + u + v, c - u + v])
    return verts, np.array([[0, 1, 2], [0, 2, 3]], np.int32)


# ---- @wp.func building blocks from a user kernel ------------------------------------------------------------


@wp.kernel
def _query_kernel(
    mesh: wp.uint64,
    origins: wp.array(dtype=wp.vec3),
    dirs: wp.array(dtype=wp.vec3),
    t_max: float,
    t_out: wp.array(dtype=float),
    face_out: wp.array(dtype=int),
    dist_out: wp.array(dtype=float),
    occ_out: wp.array(dtype=int),
):
    i = wp.tid()
    t, face = raycast.ray_hit(mesh, origins[i], dirs[i], t_max)
    t_out[i] = t
    face_out[i] = face
    dist_out[i] = raycast.ray_hit_distance(mesh, origins[i], dirs[i], t_max)
    occ_out[i] = wp.where(raycast.occluded(mesh, origins[i], dirs[i], t_max), 1, 0)


def test_ray_helpers_against_a_plane():
    v, f = quad([0, 0, -2.0], [1, 0, 0], [0, 1, 0])  # z = -2, |x|, |y| <= 1
    mesh = raycast.build_mesh(v, f)
    rng = np.random.default_rng(42)
    n = 500
    origins = np.column_stack([rng.uniform(-1.5, 1.5, (n, 2)), rng.uniform(-1.0, 1.0, n)])
    dirs = np.column_stack([rng.normal(0, 0.2, (n, 2)), -np.ones(n)])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t_max = 2.5
    outs = [wp.zeros(n, dtype=float), wp.zeros(n, dtype=int), wp.zeros(n, dtype=float), wp.zeros(n, dtype=int)]
    wp.launch(
        _query_kernel,
        dim=n,
        inputs=[mesh.id, wp.array(origins, dtype=wp.vec3), wp.array(dirs, dtype=wp.vec3), t_max, *outs],
    )
    t, face, dist, occ = (o.numpy() for o in outs)
    # analytic: plane z = -2 at s = (origin_z + 2) / -dir_z, inside the square, s <= t_max
    s = (origins[:, 2] + 2.0) / -dirs[:, 2]
    p = origins + s[:, None] * dirs
    # skip rays within 1e-4 of the square's border or of the diagonal shared by its two triangles
    border = np.minimum(1.0 - np.abs(p[:, :2]).max(axis=1), np.abs(p[:, 0] - p[:, 1]) / np.sqrt(2))
    clear = np.abs(border) > 1e-4
    hit = (np.abs(p[:, :2]).max(axis=1) < 1.0) & (s <= t_max)
    assert hit[clear].sum() > 100 and (~hit[clear]).sum() > 100
    assert np.array_equal(face[clear & ~hit], np.full((clear & ~hit).sum(), -1))
    assert np.all(np.isinf(t[clear & ~hit])) and np.all(np.isinf(dist[clear & ~hit]))
    assert np.allclose(t[clear & hit], s[clear & hit], rtol=1e-5)  # measured 1.9e-7
    assert np.array_equal(dist, t)
    expected_face = np.where(p[:, 1] < p[:, 0], 0, 1)  # triangle (0, 1, 2) lies below the diagonal y = x
    assert np.array_equal(face[clear & hit], expected_face[clear & hit])
    assert np.array_equal(occ[clear].astype(bool), hit[clear])


# ---- per-pixel references -----------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["perspective", "orthographic"])
def test_raycast_depth_matches_analytic_plane(kind):
    w, h = 48, 36
    v, f = quad([0.2, -0.1, -4.0], [3.0, 0.0, 0.8], [0.0, 3.0, 0.0])  # tilted plane covering the view
    if kind == "perspective":
        cam = Camera([0, 0, 0], [0, 0, -1], [0, 1, 0], 40.0, w, h, 0.5, 20.0)
        vp = cam.view_projection()
    else:
        vp = orthographic_matrix(-1.5, 1.5, -1.0, 1.0, 0.5, 20.0) @ view_matrix(
            [0, 0, 0], *look_at_basis([0, 0, 0], [0, 0, -1], [0, 1, 0])
        )
    res = raycast.raycast_depth(raycast.build_mesh(v, f), vp, w, h)
    assert res.ndc_depth.shape == (1, h, w) and res.tri_id.shape == (1, h, w)
    assert np.all(res.tri_id >= 0)
    # analytic: pixel-centre segment from NDC z = -1 to +1 meets the plane
    normal = np.cross(v[1] - v[0], v[3] - v[0])
    pn = raster.unproject(np.full((h, w), -1.0), vp)
    pf = raster.unproject(np.full((h, w), 1.0), vp)
    s = ((v[0] - pn) @ normal) / ((pf - pn) @ normal)
    p = pn + (pf - pn) * s[..., None]
    c = np.concatenate([p, np.ones((h, w, 1))], -1) @ vp.T
    err = np.abs(res.ndc_depth[0] - c[..., 2] / c[..., 3])
    assert err.max() < 1e-6  # measured 8.2e-8 (both)


def test_raycast_camera_distance_and_empty_pixels():
    w, h = 40, 30
    cam = Camera([0.1, 0.2, 0.0], [0.1, 0.2, -1.0], [0, 1, 0], 60.0, w, h, 0.1, 5.0)
    near_quad = quad([0.1, 0.2, -3.0], [0.5, 0, 0], [0, 0.5, 0])  # a small quad at distance 3
    far_quad = quad([0.1, 0.2, -8.0], [50, 0, 0], [0, 50, 0])  # beyond the far plane: never hit
    v = np.concatenate([near_quad[0], far_quad[0]])
    f = np.concatenate([near_quad[1], far_quad[1] + 4])
    t, tid = raycast.raycast_camera(raycast.build_mesh(v, f), cam)
    assert t.shape == (h, w) and tid.shape == (h, w)
    dirs = cam.ray_directions()
    s = 3.0 / -dirs[..., 2]  # distance along the unit ray to z = -3
    p = cam.position + dirs * s[..., None]
    inside = np.all(np.abs(p[..., :2] - [0.1, 0.2]) < 0.5, axis=-1)
    border = np.abs(np.abs(p[..., :2] - [0.1, 0.2]).max(axis=-1) - 0.5) < 1e-3
    assert inside.sum() > 50 and (~inside).sum() > 500
    assert np.all(tid[inside & ~border] >= 0) and np.all(tid[inside & ~border] <= 1)
    assert np.allclose(t[inside & ~border], s[inside & ~border], rtol=1e-5)  # measured 1.8e-7
    assert np.all(tid[~inside & ~border] == -1) and np.all(np.isinf(t[~inside & ~border]))


def test_raycast_depth_uses_the_camera_pixel_centres():
    # the world point of a ray-cast NDC depth lies on the CONVENTIONS ray of its pixel at the camera distance
    cam = Camera([0.3, 0.5, 2.0], [0, 0, -2.0], [0, 1, 0], 55.0, 32, 24, 0.2, 30.0)
    v, f = quad([0, 0, -3.0], [8.0, 0.0, 2.0], [0.0, 8.0, 1.0])
    mesh = raycast.build_mesh(v, f)
    res = raycast.raycast_depth(mesh, cam.view_projection(), cam.width, cam.height)
    t, tid = raycast.raycast_camera(mesh, cam)
    assert np.all(tid >= 0)
    pts = raster.unproject(res.ndc_depth[0], cam.view_projection())
    expected = cam.position + cam.ray_directions() * t[..., None]
    assert np.max(np.linalg.norm(pts - expected, axis=-1)) < 1e-4  # measured 6.7e-6 scene units, distances <= 10.3


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: raycast.build_mesh(np.zeros((3, 2)), [[0, 1, 2]]), "vertices"),
        (lambda: raycast.build_mesh(np.zeros((3, 3)), [[0, 1, 5]]), "triangles"),
        (lambda: raycast.build_mesh(np.zeros((3, 3)), np.zeros((0, 3), int)), "triangles"),
        (lambda: raycast.raycast_depth("mesh", np.eye(4), 8, 8), "mesh"),
        (
            lambda: raycast.raycast_depth(
                raycast.build_mesh(*quad([0, 0, 0], [1, 0, 0], [0, 1, 0])), np.zeros((4, 4)), 8, 8
            ),
            "view_proj",
        ),
        (
            lambda: raycast.raycast_depth(raycast.build_mesh(*quad([0, 0, 0], [1, 0, 0], [0, 1, 0])), np.eye(4), 0, 8),
            "width",
        ),
        (lambda: raycast.raycast_camera(raycast.build_mesh(*quad([0, 0, 0], [1, 0, 0], [0, 1, 0])), None), "camera"),
    ],
)
def test_bad_input_raises(call, match):
    with pytest.raises(ValueError, match=match):
        call()
