"""Tests of warpscatter.raster.rasterizer: agreement with BVH ray casting, watertightness of the fill rule,
clipping, depth clamping, depth peeling, pixel conventions and input validation."""

import numpy as np
import pytest
import trimesh
import warp as wp

from warpscatter.raster import rasterizer as raster
from warpscatter.raster import raycast
from warpscatter.scene.camera import Camera, look_at_basis, orthographic_matrix, perspective_matrix, view_matrix

# ---- scenes and helpers ------------------------------------------------------------------------------


def random_scene(seed: int = 42) -> tuple[np.ndarray, np.ndarray]:
    """Boxes and spheres at random positions/orientations around the origin (one mesh)."""
    rng = np.random.default_rng(seed)
    parts = []
    for k in range(10):
        if k % 2 == 0:
            m = trimesh.creation.box(extents=rng.uniform(0.3, 1.2, 3))
        else:
            m = trimesh.creation.icosphere(subdivisions=1, radius=rng.uniform(0.3, 0.7))
        rot = trimesh.transformations.random_rotation_matrix(rng.random(3))
        rot[:3, 3] = rng.uniform(-1.5, 1.5, 3)
        m.apply_transform(rot)
        parts.append(m)
    m = trimesh.util.concatenate(parts)
    return np.asarray(m.vertices), np.asarray(m.faces, dtype=np.int32)


def ortho_view_proj(position, look_at, up, half_w, half_h, near, far) -> np.ndarray:
    return orthographic_matrix(-half_w, half_w, -half_h, half_h, near, far) @ view_matrix(
        position, *look_at_basis(position, look_at, up)
    )


def silhouette_mask(*tri_images: np.ndarray) -> np.ndarray:
    """Texels whose 3x3 neighbourhood holds a different triangle id in any of the images."""
    out = np.zeros(tri_images[0].shape, dtype=bool)
    for t in tri_images:
        p = np.pad(t, 1, mode="edge")
        h, w = t.shape
        for dj in range(3):
            for di in range(3):
                out |= p[dj : dj + h, di : di + w] != t
    return out


def grid_plane(nx: int, ny: int, extent: float, rng, thin: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Tessellated square [-extent, extent]^2 in the z = 0 plane: random column positions (many very
    thin columns), per-vertex jitter in y, random diagonals and random winding per triangle."""
    if thin:
        gaps = rng.uniform(0.0, 1.0, nx) ** 4 + 1e-4  # heavy tail of tiny gaps -> slivers
        xs = np.concatenate([[0.0], np.cumsum(gaps)])
        xs = -extent + 2.0 * extent * xs / xs[-1]
    else:
        xs = np.linspace(-extent, extent, nx + 1)
    ys = np.linspace(-extent, extent, ny + 1)
    dy = ys[1] - ys[0]
    yy = ys[None, :] + rng.uniform(-0.35, 0.35, (nx + 1, ny + 1)) * dy
    yy[:, 0], yy[:, -1] = -extent, extent
    verts = np.stack([np.repeat(xs[:, None], ny + 1, 1), yy, np.zeros_like(yy)], -1).reshape(-1, 3)
    idx = np.arange((nx + 1) * (ny + 1)).reshape(nx + 1, ny + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    diag = rng.random(a.size) < 0.5
    t1 = np.where(diag[:, None], np.stack([a, b, c], 1), np.stack([a, b, d], 1))
    t2 = np.where(diag[:, None], np.stack([a, c, d], 1), np.stack([b, c, d], 1))
    tris = np.concatenate([t1, t2])
    flip = rng.random(len(tris)) < 0.5
    tris[flip] = tris[flip][:, ::-1]
    return verts, tris.astype(np.int32)


def rotation(axis, angle_deg) -> np.ndarray:
    return trimesh.transformations.rotation_matrix(np.radians(angle_deg), axis)[:3, :3]


# ---- agreement with the BVH ray-cast reference ------------------------------------------------------


@pytest.mark.parametrize("kind", ["perspective", "orthographic"])
def test_depth_matches_raycast(kind):
    v, f = random_scene()
    w, h = 128, 96
    if kind == "perspective":
        vp = Camera([0.8, 1.5, 4.5], [0, 0, 0], [0, 1, 0], 50.0, w, h, 0.5, 20.0).view_projection()
    else:
        vp = ortho_view_proj([4.0, 5.0, 3.0], [0, 0, 0], [0, 1, 0], 2.2, 1.65, 0.5, 15.0)
    r = raster.rasterize(v, f, vp, w, h)
    q = raycast.raycast_depth(raycast.build_mesh(v, f), vp, w, h)
    rt, qt = r.tri_id[0], q.tri_id[0]
    interior = ~silhouette_mask(rt, qt)
    assert interior.sum() > 0.6 * w * h  # measured 78 % (perspective), 72 % (orthographic)
    assert np.array_equal(rt[interior], qt[interior])
    assert np.all(np.isinf(r.ndc_depth[0][interior & (rt < 0)]))
    hit = interior & (rt >= 0)
    assert hit.sum() > 0.05 * w * h  # measured 7.8 %, 15 %
    zq = q.ndc_depth[0].astype(np.float64)
    err = np.abs(r.ndc_depth[0][hit] - zq[hit])
    # Depth slope per pixel (interior texels: one plane over the 3x3 neighbourhood). Snapping vertices
    # to 1/1024 px moves the rasterized plane by up to ~1e-3 px: measured err <= 6.6e-4 * slope + float32
    # rounding; max absolute error 2.5e-6 (perspective), 9.4e-6 (orthographic, steep faces).
    zp = np.pad(np.where(np.isfinite(zq), zq, 0.0), 1, mode="edge")
    slope = np.maximum(np.abs(zp[1:-1, 2:] - zp[1:-1, 1:-1]), np.abs(zp[2:, 1:-1] - zp[1:-1, 1:-1]))[hit]
    assert np.all(err <= 2e-3 * slope + 1e-6)
    assert err.max() < 3e-5


def test_pixel_hit_lies_on_camera_ray():
    v, f = random_scene(7)
    cam = Camera([0.5, 1.5, 6.0], [0, 0, 0], [0, 1, 0], 45.0, 64, 48, 0.5, 30.0)
    r = raster.rasterize(v, f, cam.view_projection(), cam.width, cam.height)
    pts = raster.unproject(r.ndc_depth[0], cam.view_projection())
    hit = r.tri_id[0] >= 0
    assert hit.sum() > 500
    assert np.all(np.isinf(pts[~hit]))
    rel = pts[hit] - cam.position
    dist = np.linalg.norm(rel, axis=-1)
    dirs = cam.ray_directions()[hit]
    # perpendicular distance of the unprojected hit from the pixel's CONVENTIONS ray, relative to its distance
    off = np.linalg.norm(np.cross(rel, dirs), axis=-1) / dist
    assert off.max() < 1e-9  # measured 4.0e-16: the pixel-centre conventions of raster and Camera agree
    assert np.all(np.einsum("ij,ij->i", rel, dirs) > 0)
    # ... and at the ray-cast distance away from silhouettes
    t, tid = raycast.raycast_camera(raycast.build_mesh(v, f), cam)
    interior = (~silhouette_mask(r.tri_id[0], tid)) & hit
    assert np.array_equal(tid[interior], r.tri_id[0][interior])
    assert np.max(np.abs(dist[interior[hit]] - t[interior]) / t[interior]) < 3e-5  # measured 5.6e-6


def test_row_zero_is_top_and_column_zero_is_left():
    # identity view_proj: world = NDC. Triangle in the upper-left quadrant (x < 0, y > 0).
    v = np.array([[-0.9, 0.1, 0.0], [-0.1, 0.1, 0.0], [-0.5, 0.9, 0.0]])
    r = raster.rasterize(v, [[0, 1, 2]], np.eye(4), 40, 30)
    rows, cols = np.nonzero(r.tri_id[0] == 0)
    assert rows.size > 20
    assert rows.max() < 15 and cols.max() < 20
    # the apex (y = 0.9) is at the top: the covered span shrinks with decreasing row index
    widths = [np.count_nonzero(r.tri_id[0][j] == 0) for j in range(rows.min(), rows.max() + 1)]
    assert widths[0] < widths[-1]
    # every covered pixel centre lies inside the triangle (x, y from the documented convention)
    xs, ys = raster.pixel_center_ndc_grid(40, 30)
    x, y = xs[cols], ys[rows]
    assert np.all(y >= 0.1) and np.all(y <= 0.9) and np.all(np.abs(x + 0.5) <= (0.9 - y) * 0.5 + 1e-12)


# ---- watertightness ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["perspective", "orthographic"])
@pytest.mark.parametrize("exact", [False, True])
def test_tessellated_plane_covers_every_pixel_once(kind, exact):
    rng = np.random.default_rng(3)
    v, f = grid_plane(70, 60, 2.0, rng)
    rot = rotation([1, 0.3, 0.2], 35.0)
    v = v @ rot.T
    normal = rot @ [0, 0, 1.0]
    w, h = 80, 64
    if kind == "perspective":
        cam = Camera(1.5 * normal, [0, 0, 0], [0, 1, 0], 60.0, w, h, 0.1, 50.0)
        vp = cam.view_projection()
    else:
        vp = ortho_view_proj(2.0 * normal + [0.1, 0.2, 0.0], [0.1, 0.2, 0.0], [0.3, 1, 0], 1.5, 1.2, 0.1, 10.0)
    counts = raster.coverage_count(v, f, vp, w, h, exact_edges=exact)
    assert counts.shape == (h, w)
    assert np.all(counts == 1), f"min {counts.min()} max {counts.max()}"
    # the depth pass sees the same coverage
    r = raster.rasterize(v, f, vp, w, h, exact_edges=exact)
    assert np.all(r.tri_id[0] >= 0)


def expected_plane_coverage(view_proj, width, height, point, normal, inside) -> np.ndarray:
    """Pixels whose centre's near-to-far segment meets the plane (point, normal) at a point accepted by
    ``inside`` (world points (..., 3) -> bool)."""
    pn = raster.unproject(np.full((height, width), -1.0), view_proj)
    pf = raster.unproject(np.full((height, width), 1.0), view_proj)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (np.subtract(point, pn) @ normal) / ((pf - pn) @ normal)
        p = pn + (pf - pn) * s[..., None]
        return (s >= 0) & (s <= 1) & inside(p)


@pytest.mark.parametrize("exact", [False, True])
def test_floor_clipped_at_near_plane_stays_watertight(exact):
    # A finely tessellated floor under a low camera: many small triangles cross the near plane, so
    # shared edges are clipped by both of their triangles.
    rng = np.random.default_rng(11)
    u = np.sort(np.concatenate([[-1.0, 1.0], rng.uniform(-1, 1, 60)]))
    xs = 2000.0 * np.sinh(12.0 * u) / np.sinh(12.0)  # ~0.01 units near the camera, ~500 units far away
    zs = 2000.0 * np.sinh(12.0 * np.linspace(-1, 1, 81)) / np.sinh(12.0)
    gx, gz = np.meshgrid(xs, zs, indexing="ij")
    gz = gz + rng.uniform(-0.3, 0.3, gz.shape) * np.gradient(zs)[None, :]
    v = np.stack([gx, np.zeros_like(gx), gz], -1).reshape(-1, 3)
    idx = np.arange(v.shape[0]).reshape(gx.shape)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    f = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    cam = Camera([0.003, 0.05, 0.002], [0.0, -1.0, -4.0], [0, 1, 0], 70.0, 64, 48, 0.1, 1e5)
    counts = raster.coverage_count(v, f, cam.view_projection(), cam.width, cam.height, exact_edges=exact)
    expected = expected_plane_coverage(
        cam.view_projection(),
        cam.width,
        cam.height,
        [0, 0, 0],
        [0, 1.0, 0],
        lambda p: np.all(np.abs(p) < 2000.0, axis=-1),
    )
    boundary = silhouette_mask(expected.astype(np.int32))
    assert expected.sum() > 500 and (~expected).sum() > 200  # the near cut is in view
    assert counts.max() == 1, f"double hits: {np.count_nonzero(counts > 1)}"
    assert np.array_equal(counts[~boundary], expected[~boundary].astype(np.int32))


@pytest.mark.parametrize("exact", [False, True])
def test_huge_fan_clipped_at_guard_band_stays_watertight(exact):
    # Orthographic view of a tilted plane tessellated as a fan whose outer vertices lie 1e5 units away:
    # the shared fan edges leave the guard band and cross the near plane, so both neighbours clip them.
    rng = np.random.default_rng(2)
    normal = np.array([0.1, 3.0, 1.0]) / np.linalg.norm([0.1, 3.0, 1.0])
    centre = np.array([0.05, -0.02, -3.0])
    e1 = np.cross(normal, [1.0, 0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    ang = np.sort(rng.uniform(0, 2 * np.pi, 9))
    inner = [centre + 0.3 * (np.cos(x) * e1 + np.sin(x) * e2) for x in ang]
    outer = [centre + 1e5 * (np.cos(x) * e1 + np.sin(x) * e2) for x in ang]
    v = np.array([centre, *inner, *outer])
    f = []
    for k in range(9):
        k1 = (k + 1) % 9
        f += [[0, 1 + k, 1 + k1], [1 + k, 10 + k, 10 + k1], [1 + k, 10 + k1, 1 + k1]]
    w, h = 64, 48
    vp = ortho_view_proj([0, 0, 0], [0, 0, -1], [0, 1, 0], 1.0, 0.75, 1.0, 5.0)
    clip = np.column_stack([v, np.ones(len(v))]) @ vp.T
    guard = 2.0 * raster.GUARD_BAND_PIXELS / w - 1.0
    assert np.sum(np.abs(clip[10:, 0]) > guard) >= 3  # outer vertices beyond the guard band
    assert np.sum(clip[10:, 2] < -1.0) >= 3  # ... and in front of the near plane
    counts = raster.coverage_count(v, f, vp, w, h, exact_edges=exact)
    radius = 1e5 * np.cos(np.pi / 9 * 1.5)  # well inside the outer polygon
    expected = expected_plane_coverage(vp, w, h, centre, normal, lambda p: np.linalg.norm(p - centre, axis=-1) < radius)
    boundary = silhouette_mask(expected.astype(np.int32))
    assert expected[~boundary].sum() > 1000 and (~expected).sum() > 200  # the near and far cuts are in view
    assert counts.max() == 1, f"double hits: {np.count_nonzero(counts > 1)}"
    assert np.array_equal(counts[~boundary], expected[~boundary].astype(np.int32))


@pytest.mark.parametrize("exact", [False, True])
def test_pixel_aligned_grid_ties_are_owned_once(exact):
    # Identity matrix (world = NDC), power-of-two image: every vertex and every axis-aligned edge lies
    # exactly on pixel centres, so only the top-left rule decides which triangle owns them.
    w, h = 64, 32
    rng = np.random.default_rng(5)
    corners = {}
    verts, tris = [], []

    def vid(px, py):  # pixel coordinates (y down) -> vertex index
        if (px, py) not in corners:
            corners[(px, py)] = len(verts)
            verts.append([2.0 * px / w - 1.0, 1.0 - 2.0 * py / h, 0.0])
        return corners[(px, py)]

    for a in range(-1, 17):  # cells of 4 x 2 pixels, corners on pixel centres, beyond the image
        for b in range(-1, 17):
            x0, y0 = 4 * a + 0.5, 2 * b + 0.5
            c = vid(x0 + 2.0, y0 + 1.0)  # cell centre: also a pixel centre
            ring = [vid(x0, y0), vid(x0 + 4, y0), vid(x0 + 4, y0 + 2), vid(x0, y0 + 2)]
            for k in range(4):  # fan around the centre vertex, random winding
                t = [c, ring[k], ring[(k + 1) % 4]]
                tris.append(t if rng.random() < 0.5 else t[::-1])
    counts = raster.coverage_count(np.array(verts), np.array(tris), np.eye(4), w, h, exact_edges=exact)
    assert np.all(counts == 1), f"min {counts.min()} max {counts.max()}"


@pytest.mark.parametrize("exact", [False, True])
def test_top_left_rule_on_an_axis_aligned_square(exact):
    # Square with corners exactly on pixel centres (1.5, 1.5) .. (5.5, 5.5) of an 8x8 image (y down):
    # the top and left edges own their centres, the bottom and right edges do not.
    w = h = 8
    px = np.array([[1.5, 1.5], [5.5, 1.5], [5.5, 5.5], [1.5, 5.5]])
    v = np.column_stack([2 * px[:, 0] / w - 1, 1 - 2 * px[:, 1] / h, np.zeros(4)])
    for tris in ([[0, 1, 2], [0, 2, 3]], [[1, 0, 3], [1, 3, 2]]):  # both diagonals, both windings
        counts = raster.coverage_count(v, tris, np.eye(4), w, h, exact_edges=exact)
        expected = np.zeros((h, w), np.int32)
        expected[1:5, 1:5] = 1
        assert np.array_equal(counts, expected)


def test_exact_edges_draw_triangles_below_the_subpixel_grid():
    # exact_edges: centres inside triangles that snap to no area are drawn as the ray through them would hit them
    w = h = 8

    def ndc(px, py):  # pixel coordinates (y down) -> world = NDC (identity matrix)
        return [2.0 * px / w - 1.0, 1.0 - 2.0 * py / h, 0.0]

    e = 1e-4  # a triangle 2e-4 pixel wide around the centre of pixel (3, 2)
    tiny = np.array([ndc(3.5 - e, 2.5 - e), ndc(3.5 + e, 2.5 - e), ndc(3.5, 2.5 + e)])
    assert raster.coverage_count(tiny, [[0, 1, 2]], np.eye(4), w, h).sum() == 0  # fixed point: no area
    counts = raster.coverage_count(tiny, [[0, 1, 2]], np.eye(4), w, h, exact_edges=True)
    assert counts.sum() == 1 and counts[2, 3] == 1
    # a plane cut by a strip 4e-5 pixel wide (two slivers) over the centres of column 3: still covered once, and
    # column 3 by the slivers
    d = 2e-5
    verts = np.array([ndc(x, y) for x in (-0.5, 3.5 - d, 3.5 + d, 8.5) for y in (-0.5, 8.5)])
    tris = [t for k in range(3) for t in ([2 * k, 2 * k + 1, 2 * k + 3], [2 * k, 2 * k + 3, 2 * k + 2])]
    assert np.all(raster.coverage_count(verts, tris, np.eye(4), w, h, exact_edges=True) == 1)
    tri = raster.rasterize(verts, tris, np.eye(4), w, h, exact_edges=True).tri_id[0]
    assert set(tri[:, 3]) <= {2, 3} and set(tri[:, :3].ravel()) <= {0, 1} and set(tri[:, 4:].ravel()) <= {4, 5}


@wp.kernel
def _clip_shared_edge_kernel(
    a: wp.array(dtype=wp.vec4),
    b: wp.array(dtype=wp.vec4),
    c: wp.array(dtype=wp.vec4),
    plane: wp.vec4,
    out1: wp.array(dtype=wp.vec4),
    out2: wp.array(dtype=wp.vec4),
):
    i = wp.tid()
    src = raster.ClipSources()
    p = raster.ClipPolygon()
    p[0] = a[i]
    p[1] = b[i]
    p[2] = c[i]
    q, s, n = raster.clip_polygon_plane(p, src, 3, plane)  # polygon a, b, c: point on a -> b is q[1]
    p[0] = b[i]
    p[1] = a[i]
    r, s2, n2 = raster.clip_polygon_plane(p, src, 3, plane)  # neighbour b, a, c: point on b -> a is r[0]
    out1[i] = q[1]
    out2[i] = r[0]


def test_clipping_of_a_shared_edge_is_bitwise_identical():
    rng = np.random.default_rng(9)
    n = 2000
    a = rng.normal(0, 50, (n, 4)).astype(np.float32)
    b = rng.normal(0, 50, (n, 4)).astype(np.float32)
    plane = np.array([0.0, 0.0, 1.0, 1.0], np.float32)  # near plane z + w >= 0
    a[:, 3] = np.abs(a[:, 3]) + np.abs(a[:, 2]) + 1.0  # a inside, b outside
    b[:, 3] = -np.abs(b[:, 2]) - np.abs(b[:, 3]) - 0.1
    c = a + 1.0  # third vertex inside
    out1, out2 = wp.zeros(n, dtype=wp.vec4), wp.zeros(n, dtype=wp.vec4)
    wp.launch(
        _clip_shared_edge_kernel,
        dim=n,
        inputs=[
            wp.array(a, dtype=wp.vec4),
            wp.array(b, dtype=wp.vec4),
            wp.array(c, dtype=wp.vec4),
            wp.vec4(*plane),
            out1,
            out2,
        ],
    )
    p1, p2 = out1.numpy(), out2.numpy()
    assert np.all(np.abs(p1 @ plane) <= 1e-4 * np.abs(p1).max(axis=1))  # on the plane
    assert np.array_equal(p1.view(np.uint32), p2.view(np.uint32))  # bitwise equal from both sides


@pytest.mark.parametrize("exact", [False, True])
def test_closed_sphere_front_and_back_each_once(exact):
    s = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    v, f = np.asarray(s.vertices), np.asarray(s.faces)
    vp = ortho_view_proj([0.3, 0.2, 5.0], [0, 0, 0], [0, 1, 0], 1.3, 1.3, 1.0, 10.0)
    two = raster.coverage_count(v, f, vp, 64, 64, exact_edges=exact)
    one = raster.coverage_count(v, f, vp, 64, 64, cull_backfaces=True, exact_edges=exact)
    assert set(np.unique(two)) == {0, 2}
    assert set(np.unique(one)) == {0, 1}
    assert np.array_equal(one == 1, two == 2)
    # culling keeps the surfaces facing the viewer (trimesh winds outward, counter-clockwise from outside)
    r = raster.rasterize(v, f, vp, 64, 64, cull_backfaces=True, exact_edges=exact)
    rb = raster.rasterize(v, f, vp, 64, 64, exact_edges=exact)
    assert np.array_equal(r.tri_id, rb.tri_id)


def test_threads_give_identical_keys():
    s = trimesh.creation.icosphere(subdivisions=4, radius=1.0)  # 5120 triangles: split into 2 chunks
    v, f = np.asarray(s.vertices), np.asarray(s.faces)
    cam = Camera([0.3, 0.4, 3.0], [0, 0, 0], [0, 1, 0], 50.0, 64, 48, 0.1, 10.0)
    a = raster.rasterize(v, f, cam.view_projection(), 64, 48, layers=2, threads=1)
    b = raster.rasterize(v, f, cam.view_projection(), 64, 48, layers=2, threads=2)
    assert np.array_equal(a.keys.numpy(), b.keys.numpy())
    ca = raster.coverage_count(v, f, cam.view_projection(), 64, 48, threads=1)
    cb = raster.coverage_count(v, f, cam.view_projection(), 64, 48, threads=2)
    assert np.array_equal(ca, cb)


# ---- clipping and depth clamping ---------------------------------------------------------------------------


def test_near_plane_clipping_keeps_visible_part_with_exact_depth():
    near, far = 2.0, 100.0
    w, h = 64, 48
    cam = Camera([0, 0, 0], [0, 0, -1], [0, 1, 0], 70.0, w, h, near, far)
    vp = cam.view_projection()
    # floor triangle y = -1 reaching behind the camera (z > 0) and far ahead, crossing the near plane;
    # the lowest image rows see the floor at view depth 1.43 .. 2 (nearer than `near`): clipped
    v = np.array([[-6.0, -1.0, 3.0], [6.0, -1.0, 3.0], [0.0, -1.0, -30.0]])
    r = raster.rasterize(v, [[0, 1, 2]], vp, w, h)
    # analytic reference: ray / plane y = -1, inside the triangle, view depth in [near, far]
    d = cam.ray_directions()
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d[..., 1] < 0, -1.0 / d[..., 1], np.inf)
        p = d * t[..., None]
    a, b, c = v[:, [0, 2]]

    def side(p0, p1, q):
        return (p1[0] - p0[0]) * (q[..., 1] - p0[1]) - (p1[1] - p0[1]) * (q[..., 0] - p0[0])

    q = p[..., [0, 2]]
    with np.errstate(invalid="ignore"):
        s1, s2, s3 = side(a, b, q), side(b, c, q), side(c, a, q)
        inside = ((s1 >= 0) & (s2 >= 0) & (s3 >= 0)) | ((s1 <= 0) & (s2 <= 0) & (s3 <= 0))
    depth = -p[..., 2]
    expected = np.isfinite(t) & inside & (depth >= near) & (depth <= far)
    got = r.tri_id[0] == 0
    boundary = silhouette_mask(expected.astype(np.int32))
    assert expected.sum() > 300 and (~expected).sum() > 300
    assert np.array_equal(got[~boundary], expected[~boundary])
    too_near = np.isfinite(t) & inside & (depth < near)
    assert too_near.sum() > 100  # the cut is inside the image ...
    assert not np.any(got & (depth < near * (1 - 1e-4)))  # ... and nothing nearer than `near` is drawn
    ok = got & expected & ~boundary
    with np.errstate(invalid="ignore"):
        c = np.concatenate([p, np.ones((h, w, 1))], -1) @ vp.T
        zref = np.where(expected, c[..., 2] / c[..., 3], np.nan)
    zp = np.pad(zref, 1, mode="edge")
    slope = np.maximum(np.abs(zp[1:-1, 2:] - zref), np.abs(zp[2:, 1:-1] - zref))[ok]  # per pixel
    err = np.abs(r.ndc_depth[0][ok] - zref[ok])
    # the floor's NDC depth changes by up to 0.12 per row near the near plane; snapping to 1/1024 px:
    # measured err <= 5.9e-5 * slope (max absolute error 7.1e-6)
    assert np.all(err <= 2e-3 * slope + 1e-6)


def test_nothing_drawn_from_behind_the_camera():
    cam = Camera([0, 0, 0], [0, 0, -1], [0, 1, 0], 60.0, 32, 32, 0.5, 50.0)
    # entirely behind the camera, laterally wide: a naive w-divide would mirror it into the view
    v = np.array([[-20.0, -20.0, 1.0], [20.0, -20.0, 1.0], [0.0, 20.0, 5.0], [-1, -1, 0.1], [1, -1, 0.1], [0, 1, 0.1]])
    f = np.array([[0, 1, 2], [3, 4, 5]])
    assert raster.coverage_count(v, f, cam.view_projection(), 32, 32).sum() == 0
    r = raster.rasterize(v, f, cam.view_projection(), 32, 32, clamp_depth=True)  # perspective: near clip stays
    assert np.all(r.tri_id == -1) and np.all(np.isinf(r.ndc_depth))


def test_depth_clamping_keeps_orthographic_casters():
    # light looking down -Z from z = 0; view box x, y in [-2, 2], depth in [near, far] = [1, 10]
    vp = ortho_view_proj([0, 0, 0], [0, 0, -1], [0, 1, 0], 2.0, 2.0, 1.0, 10.0)
    quad = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float)

    def at(z, dx):
        return np.column_stack([quad[:, 0] * 0.5 + dx, quad[:, 1], np.full(4, z)])

    v = np.concatenate([at(3.0, -1.0), at(-20.0, 1.0), at(-5.0, 0.0)])  # before near, beyond far, inside
    f = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7], [8, 9, 10], [8, 10, 11]])
    plain = raster.rasterize(v, f, vp, 32, 32)
    clamped = raster.rasterize(v, f, vp, 32, 32, clamp_depth=True)
    ids_c, ids_p = clamped.tri_id[0], plain.tri_id[0]
    assert not np.any(np.isin(ids_p, [0, 1, 2, 3]))  # clipped / discarded without clamping
    front = np.isin(ids_c, [0, 1])
    back = np.isin(ids_c, [2, 3])
    assert front.sum() > 50 and back.sum() > 20
    assert np.all(clamped.ndc_depth[0][front] == -1.0)
    assert np.all(clamped.ndc_depth[0][back] == 1.0)
    mid = np.isin(ids_c, [4, 5])
    assert np.allclose(clamped.ndc_depth[0][mid], (5.0 - 1.0) / 9.0 * 2.0 - 1.0, atol=1e-6)
    assert np.array_equal(mid, np.isin(ids_p, [4, 5]))


# ---- depth peeling -------------------------------------------------------------------------------------------


def test_peeling_stacked_planes_and_coincident_triangles():
    vp = ortho_view_proj([0, 0, 0], [0, 0, -1], [0, 1, 0], 1.0, 1.0, 1.0, 9.0)
    quad = np.array([[-0.8, -0.8], [0.8, -0.8], [0.8, 0.8], [-0.8, 0.8]])
    depths = [4.0, 2.0, 6.0, 4.0]  # the last quad coincides with the first
    v = np.concatenate([np.column_stack([quad, np.full(4, -d)]) for d in depths])
    f = np.concatenate([np.array([[0, 1, 2], [0, 2, 3]]) + 4 * k for k in range(4)])
    r = raster.rasterize(v, f, vp, 24, 24, layers=5)
    covered = r.tri_id[0] >= 0
    assert covered.sum() > 300
    ndc = lambda d: (d - 1.0) / 8.0 * 2.0 - 1.0  # noqa: E731
    expect_quad = [1, 0, 3, 2]  # depth 2, depth 4 (lower ids first), coincident copy, depth 6
    for layer, qd in enumerate(expect_quad):
        assert np.all(r.tri_id[layer][covered] // 2 == qd)
        assert np.allclose(r.ndc_depth[layer][covered], ndc(depths[qd]), atol=1e-6)
    assert np.all(r.tri_id[4] == -1) and np.all(np.isinf(r.ndc_depth[4]))
    assert np.all(r.tri_id[:, ~covered] == -1)


def brute_force_hits(v, f, origins, dirs):
    """All ray/triangle hits (Moeller-Trumbore, float64): t (R, T) with inf for misses, and the smallest
    barycentric coordinate of each hit (how close to an edge it is)."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    e1, e2 = b - a, c - a
    pv = np.cross(dirs[:, None, :], e2[None])
    det = np.einsum("tk,rtk->rt", e1, pv)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = origins[:, None, :] - a[None]
        u = np.einsum("rtk,rtk->rt", s, pv) * inv
        qv = np.cross(s, e1[None])
        vv = np.einsum("rk,rtk->rt", dirs, qv) * inv
        t = np.einsum("tk,rtk->rt", e2, qv) * inv
    ok = (np.abs(det) > 1e-14) & (u >= 0) & (vv >= 0) & (u + vv <= 1) & (t >= 0) & (t <= 1)
    margin = np.minimum(np.minimum(u, vv), 1 - u - vv)
    return np.where(ok, t, np.inf), np.where(ok, margin, np.inf)


def test_peeling_nested_spheres_matches_sorted_ray_hits():
    parts = [trimesh.creation.icosphere(subdivisions=2, radius=r) for r in (0.5, 1.0, 1.5)]
    m = trimesh.util.concatenate(parts)
    v, f = np.asarray(m.vertices), np.asarray(m.faces)
    w = h = 28
    cam = Camera([0.2, 0.3, 4.0], [0, 0, 0], [0, 1, 0], 55.0, w, h, 0.5, 10.0)
    vp = cam.view_projection()
    layers = 4
    r = raster.rasterize(v, f, vp, w, h, layers=layers)
    # reference rays: near-plane point to far-plane point of each pixel centre, as raycast_depth casts them
    inv = np.linalg.inv(vp)
    xs, ys = raster.pixel_center_ndc_grid(w, h)
    X, Y = np.meshgrid(xs, ys)

    def unp(z, dx=0.0, dy=0.0):  # world points of the pixel centres (shifted by dx, dy pixels) at NDC z
        p = np.stack([X + 2.0 * dx / w, Y - 2.0 * dy / h, np.full_like(X, z), np.ones_like(X)], -1).reshape(-1, 4)
        p = p @ inv.T
        return p[:, :3] / p[:, 3:]

    def plane_ndc(o, e, tri):  # NDC depth where the segment o -> e meets the plane of triangle `tri`
        a, b, c = (v[f[tri, k]] for k in range(3))
        n = np.cross(b - a, c - a)
        s = np.einsum("ij,ij->i", n, a - o) / np.einsum("ij,ij->i", n, e - o)
        q = np.column_stack([o + s[:, None] * (e - o), np.ones(len(o))]) @ vp.T
        return q[:, 2] / q[:, 3]

    o, e = unp(-1.0), unp(1.0)
    t, margin = brute_force_hits(v, f, o, e - o)
    order = np.argsort(t, axis=1)[:, :layers]
    ts = np.take_along_axis(t, order, 1)
    margins = np.take_along_axis(margin, order, 1)
    # ambiguous rays pass within a hair of an edge of one of their first hits: skip those texels
    clear = np.all(~np.isfinite(ts) | (margins > 1e-4), axis=1)
    assert clear.mean() > 0.9  # measured 0.9987
    n_checked = 0
    for k in range(layers):
        got_t, got_d = r.tri_id[k].reshape(-1), r.ndc_depth[k].reshape(-1).astype(np.float64)
        hit = np.isfinite(ts[:, k])
        assert np.array_equal(got_t[clear & ~hit], np.full((clear & ~hit).sum(), -1))
        sel = clear & hit
        assert np.array_equal(got_t[sel], order[sel, k])
        tri = order[sel, k]
        z = plane_ndc(o[sel], e[sel], tri)
        slope = np.maximum(
            np.abs(plane_ndc(unp(-1.0, 1.0)[sel], unp(1.0, 1.0)[sel], tri) - z),
            np.abs(plane_ndc(unp(-1.0, 0.0, 1.0)[sel], unp(1.0, 0.0, 1.0)[sel], tri) - z),
        )
        # snapping to 1/1024 px: measured err <= 6.7e-4 * slope per pixel (max absolute error 3.9e-4 on a
        # nearly edge-on facet of an inner sphere)
        assert np.all(np.abs(got_d[sel] - z) <= 2e-3 * slope + 1e-6)
        n_checked += sel.sum()
    assert n_checked > 1000  # rays through the centre see up to 6 surfaces: layers 0..3 all populated


# ---- depth helpers ------------------------------------------------------------------------------------------------


@wp.kernel
def _view_depth_kernel(z: wp.array(dtype=float), p: wp.vec4, out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = raster.ndc_to_view_depth(z[i], p[0], p[1], p[2], p[3])


@pytest.mark.parametrize("kind", ["perspective", "orthographic"])
def test_linearize_depth_round_trip(kind):
    proj = (
        perspective_matrix(50.0, 1.3, 0.2, 40.0)
        if kind == "perspective"
        else orthographic_matrix(-2, 2, -1, 1, 0.2, 40.0)
    )
    d = np.geomspace(0.2, 40.0, 50)
    c = proj @ np.stack([np.zeros_like(d), np.zeros_like(d), -d, np.ones_like(d)])
    z = c[2] / c[3]
    lin = raster.linearize_depth(z, proj)
    assert np.allclose(lin, d, rtol=1e-9)
    assert np.isinf(raster.linearize_depth(np.inf, proj))
    out = wp.zeros(len(d), dtype=float)
    wp.launch(
        _view_depth_kernel,
        dim=len(d),
        inputs=[
            wp.array(z.astype(np.float32), dtype=float),
            wp.vec4(proj[2, 2], proj[2, 3], proj[3, 2], proj[3, 3]),
            out,
        ],
    )
    # float32 kernel path: measured max relative error 6.0e-6 (both projections)
    assert np.allclose(out.numpy(), d, rtol=5e-5)
    with pytest.raises(ValueError, match="projection"):
        raster.linearize_depth(z, np.ones((4, 4)))


# ---- the row-span scan and the parallel splits ------------------------------------------------------------


@wp.kernel
def _scan_rows_kernel(a: wp.array(dtype=wp.vec3d), b: wp.array(dtype=wp.vec3d), c: wp.array(dtype=wp.vec3d),
                      rows: wp.array(dtype=wp.vec2i), p: raster.RasterParams, keys: wp.array3d(dtype=wp.int64),
                      counts: wp.array3d(dtype=wp.int32)):
    k = wp.tid()
    raster.rasterize_screen_triangle_rows(a[k], b[k], c[k], k, p, rows[k][0], rows[k][1], keys[k], keys[k], counts[k])


@wp.kernel
def _every_centre_kernel(a: wp.array(dtype=wp.vec3d), b: wp.array(dtype=wp.vec3d), c: wp.array(dtype=wp.vec3d),
                         rows: wp.array(dtype=wp.vec2i), p: raster.RasterParams, keys: wp.array3d(dtype=wp.int64),
                         counts: wp.array3d(dtype=wp.int32)):
    """Reference: test every pixel centre of the image (the pre-span scan), one thread per (triangle, pixel)."""
    k, j, i = wp.tid()
    if j < rows[k][0] or j > rows[k][1]:
        return
    va = a[k]
    flip = raster.edge_function(wp.int64(va[0]), wp.int64(va[1]), wp.int64(b[k][0]), wp.int64(b[k][1]),
                                wp.int64(c[k][0]), wp.int64(c[k][1])) < wp.int64(0)
    if not flip and p.cull_backfaces != 0:
        return
    vb = wp.where(flip, c[k], b[k])  # orient to positive area
    vc = wp.where(flip, b[k], c[k])
    x0, y0, z0 = wp.int64(va[0]), wp.int64(va[1]), va[2]
    x1, y1, z1 = wp.int64(vb[0]), wp.int64(vb[1]), vb[2]
    x2, y2, z2 = wp.int64(vc[0]), wp.int64(vc[1]), vc[2]
    area = raster.edge_function(x0, y0, x1, y1, x2, y2)
    if area == wp.int64(0):
        return
    b0 = raster.top_left_bias(x1, y1, x2, y2)
    b1 = raster.top_left_bias(x2, y2, x0, y0)
    b2 = raster.top_left_bias(x0, y0, x1, y1)
    px = (wp.int64(i) << wp.int64(10)) + wp.int64(512)
    py = (wp.int64(j) << wp.int64(10)) + wp.int64(512)
    e0 = raster.edge_function(x1, y1, x2, y2, px, py) + b0
    e1 = raster.edge_function(x2, y2, x0, y0, px, py) + b1
    e2 = raster.edge_function(x0, y0, x1, y1, px, py) + b2
    if (e0 | e1 | e2) >= wp.int64(0):
        z = float((wp.float64(e0 - b0) * z0 + wp.float64(e1 - b1) * z1 + wp.float64(e2 - b2) * z2) / wp.float64(area))
        if p.clamp_depth != 0 or z <= 1.0:
            counts[k, j, i] = 1
            keys[k, j, i] = raster.depth_key(wp.clamp(z, -1.0, 1.0), k)


def _bezout(a: int, b: int) -> tuple[int, int]:
    """(x, y) with a x + b y = gcd(a, b) (extended Euclid)."""
    x0, y0, x1, y1 = 1, 0, 0, 1
    while b:
        q = a // b
        a, b, x0, x1, y0, y1 = b, a - q * b, x1, x0 - q * x1, y1, y0 - q * y1
    return (x0, y0) if a > 0 else (-x0, -y0)


@pytest.mark.parametrize("cull", [0, 1])
def test_row_spans_match_testing_every_centre(cull):
    # wide, tiny, sliver and pixel-aligned triangles (both windings), partly outside a 53 x 21 image, random row
    # ranges: the span scan gives the fragments, depths and keys of testing every centre
    rng = np.random.default_rng(5)
    n, w, h = 1200, 53, 21
    scale = rng.choice([2.0, 8.0, 40.0, 120.0], n)[:, None, None]
    pts = rng.uniform([-10, -6], [w + 10, h + 6], (n, 1, 2)) + rng.normal(0, 1, (n, 3, 2)) * scale
    pts[::4, 2] = pts[::4, 0] + 1e-3 * (pts[::4, 1] - pts[::4, 0]) * rng.uniform(-1, 1, (n // 4 + (n % 4 > 0), 1))
    pts[1::5] = np.round(pts[1::5]) + 0.5  # corners on pixel centres: top-left ties
    pts[2::5] = np.round(pts[2::5]) + 0.5
    fixed = np.round(pts * 1024.0)
    fixed[2::5] += rng.integers(-1, 2, fixed[2::5].shape)  # centres nudged by 1/1024: edge functions of +-1 at centres
    for k in range(n - 200, n):  # a centre exactly next to a right edge (edge function 1): the last pixel of a span
        dx, dy = 0, 0
        while np.gcd(dx, dy) != 1:
            dx, dy = int(rng.integers(-40000, 40000)), int(rng.integers(1, 4000))
        x, y = _bezout(dx, dy)  # dx x + dy y = 1
        u, v = (-y, x) if x > 0 else (dx - y, x + dy)  # dx v - dy u = 1, 0 < v <= dy: centre between a and b
        centre = 1024 * rng.integers([0, 0], [w, h]) + 512
        a = centre - [u, v]
        c = centre + max(1, round(30 * 1024 / np.hypot(dx, dy))) * np.array([-dy, dx])
        fixed[k] = [a, a + [dx, dy], c]
    z = rng.uniform(-1.3, 1.3, (n, 3, 1))
    tri = np.concatenate([fixed, z], axis=2)
    r0 = rng.integers(-3, h, n)
    rows = np.stack([r0, r0 + rng.integers(0, h + 3, n)], 1).astype(np.int32)
    args = [wp.array(np.ascontiguousarray(tri[:, v]), dtype=wp.vec3d) for v in range(3)]
    args.append(wp.array(rows, dtype=wp.vec2i))
    for clamp, count_mode in ((0, 0), (1, 0), (0, 1)):
        p = raster.RasterParams()
        p.width, p.height, p.guard_x, p.guard_y = w, h, 1.0, 1.0
        p.clip_near, p.clamp_depth, p.cull_backfaces, p.count_mode, p.peel = 1, clamp, cull, count_mode, 0
        out = []
        for kernel, dim in ((_scan_rows_kernel, n), (_every_centre_kernel, (n, h, w))):
            keys = wp.full((n, h, w), raster.EMPTY_KEY, dtype=wp.int64)
            counts = wp.zeros((n, h, w), dtype=wp.int32)
            wp.launch(kernel, dim=dim, inputs=[*args, p, keys, counts])
            out.append(counts.numpy() if count_mode else keys.numpy())
        assert np.array_equal(out[0], out[1])
        assert (out[0] != (0 if count_mode else raster.EMPTY_KEY)).sum() > 10000


@pytest.mark.parametrize("kind", ["perspective", "orthographic"])
def test_bands_and_triangle_chunks_give_identical_results(kind, monkeypatch):
    v, f = random_scene(3)
    pv, pf = grid_plane(40, 30, 3.0, np.random.default_rng(4))  # 2400 thin triangles crossing many bands
    v, f = np.concatenate([v, pv]), np.concatenate([f, pf + len(v)])
    w, h = 83, 61
    if kind == "perspective":
        cam = Camera([0.4, 2.5, 4.0], [0, 0, 0], [0, 1, 0], 60.0, w, h, 0.5, 9.0)
        proj, view = cam.projection(), cam.view()
    else:
        proj = orthographic_matrix(-3.0, 3.0, -2.4, 2.4, 1.0, 7.0)
        view = view_matrix([0.3, 4.0, 2.0], *look_at_basis([0.3, 4.0, 2.0], [0, 0, 0], [0, 1, 0]))
    vp = proj @ view
    opts = [{"layers": 3}, {"layers": 2, "cull_backfaces": True}, {"clamp_depth": True}]
    ref = [raster.rasterize(v, f, vp, w, h, threads=1, **o) for o in opts]
    ref_counts = raster.coverage_count(v, f, vp, w, h, threads=1)
    lin_ref = raster.linearize_depth(ref[2].ndc_depth[0], proj).astype(np.float32)
    lin_ref[ref[2].tri_id[0] < 0] = np.inf
    monkeypatch.setattr(raster, "MIN_BAND_ROWS", 1)
    monkeypatch.setattr(raster, "MIN_BAND_PIXELS", 1)
    monkeypatch.setattr(raster, "MIN_PIECE_TRIANGLES", 100)
    for per_pixel in (0.0, 1e9):  # chunks of triangles, row bands
        monkeypatch.setattr(raster, "BANDED_TRIANGLES_PER_PIXEL", per_pixel)
        s = raster._Setup(v, f, vp, w, h, False, False, None, 2)
        assert s.banded == (per_pixel > 0) and len(s.band_list) == 16 and len(s.pieces) == (1 if s.banded else 2)
        for threads in (2, 3):
            for o, r in zip(opts, ref, strict=True):
                assert np.array_equal(raster.rasterize(v, f, vp, w, h, threads=threads, **o).keys.numpy(),
                                      r.keys.numpy())
            assert np.array_equal(raster.coverage_count(v, f, vp, w, h, threads=threads), ref_counts)
            seen = np.zeros(h, int)

            def on_rows(keys, r0, r1, seen=seen):  # called once per band, with the band's rows final
                seen[r0:r1] += 1
                assert np.array_equal(keys.numpy()[r0:r1], ref[2].keys.numpy()[0, r0:r1])

            keys = raster.rasterize_keys(v, f, vp, w, h, on_rows=on_rows, clamp_depth=True, threads=threads)
            assert np.array_equal(keys.numpy(), ref[2].keys.numpy()[0]) and (seen == 1).all()
            lin = raster.rasterize_linear_depth(v, f, vp, proj, w, h, clamp_depth=True, threads=threads)
            assert np.array_equal(lin.view(np.uint32), lin_ref.view(np.uint32))


# ---- input validation ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "change, match",
    [
        ({"view_proj": np.full((4, 4), np.nan)}, "view_proj"),
        ({"view_proj": np.eye(3)}, "view_proj"),
        ({"vertices": np.zeros((3, 2))}, "vertices"),
        ({"vertices": np.array([[0, 0, 0], [1, 0, 0], [0, np.inf, 0]])}, "vertices"),
        ({"triangles": [[0, 1, 3]]}, "triangles"),
        ({"triangles": [[0, -1, 2]]}, "triangles"),
        ({"triangles": [[0, 1]]}, "triangles"),
        ({"triangles": [[0.0, 1.0, 2.0]]}, "triangles"),
        ({"width": 0}, "width"),
        ({"height": -3}, "height"),
        ({"width": 2.5}, "width"),
        ({"layers": 0}, "layers"),
    ],
)
def test_bad_input_raises(change, match):
    args = {
        "vertices": np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float),
        "triangles": [[0, 1, 2]],
        "view_proj": np.eye(4),
        "width": 8,
        "height": 8,
        "layers": 1,
    }
    args.update(change)
    with pytest.raises(ValueError, match=match):
        raster.rasterize(**args)
