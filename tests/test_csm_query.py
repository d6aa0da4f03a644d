"""CSM visibility queries: exact against the uncompressed maps, filters (PCF, roulette), BVH agreement, semi-local
lights and moving / receiver-only objects. Kernels here call the public @wp.funcs of warpscatter.csm.query."""

import numpy as np
import pytest
import trimesh
import warp as wp

from warpscatter.csm import LatLongMapSet, build_csm, csm_objects_visibility_batch, csm_visibility_batch
from warpscatter.csm.depthmaps import latlong_param
from warpscatter.csm.query import (
    CSMData,
    csm_device_data,
    csm_map_visibility,
    csm_nearest_cell,
    csm_project,
    csm_segment_depth,
    csm_texel_visibility,
    csm_visibility,
    csm_visibility_filtered,
    csm_visibility_filtered_uv,
    csm_visibility_pcf,
    csm_visibility_roulette,
    csm_visibility_to_point,
)
from warpscatter.raster.raycast import build_mesh, occluded

KW = {"n1": 16, "n2": 8, "resolution": 32}


def bumpy_mesh_with_moon():
    """A closed bumpy icosphere plus a small box beside it (several surfaces per ray, empty texels)."""
    s = trimesh.creation.icosphere(subdivisions=2)
    v = np.asarray(s.vertices, np.float64)
    v *= (1.0 + 0.3 * np.sin(3.0 * v[:, 0]) * np.sin(2.0 * v[:, 1] + 1.0))[:, None]
    box = trimesh.creation.box(extents=[0.4, 0.4, 0.4])
    bv = np.asarray(box.vertices) + [1.7, 0.2, 0.0]
    return np.vstack([v, bv]).astype(np.float32), np.vstack([s.faces, box.faces + len(v)]).astype(np.int32)


@pytest.fixture(scope="module")
def scene():
    v, t = bumpy_mesh_with_moon()
    csm = build_csm(v, t, maps=(KW["n1"], KW["n2"]), resolution=KW["resolution"], batch=32)
    maps = LatLongMapSet.create(v, t, **KW)
    z_lo, z_hi = maps.render(0, maps.num_maps)
    return v, t, csm, z_lo.reshape(maps.num_maps, -1), z_hi.reshape(maps.num_maps, -1)


@wp.kernel
def _decode_kernel(csm: CSMData, out: wp.array2d(dtype=wp.float32)):
    i, t = wp.tid()
    out[i, t] = csm_segment_depth(csm, t, i)


@wp.kernel
def _project_kernel(csm: CSMData, cells: wp.array(dtype=wp.int32), points: wp.array(dtype=wp.vec3),
                    q: wp.array(dtype=wp.vec3), vis: wp.array(dtype=wp.float32), stored: wp.array(dtype=wp.float32)):
    k = wp.tid()
    q[k] = csm_project(csm, cells[k], points[k])
    vis[k] = csm_map_visibility(csm, cells[k], points[k], 0.0)
    x = int(wp.floor(q[k][0]))
    y = int(wp.floor(q[k][1]))
    stored[k] = wp.nan
    if x >= 0 and y >= 0 and x < csm.resolution and y < csm.resolution:
        stored[k] = csm_segment_depth(csm, y * csm.resolution + x, csm.map_index[cells[k]])


def test_decoded_depths_lie_between_the_layers(scene):
    _, _, csm, z_lo, z_hi = scene
    data = csm_device_data(csm)
    out = wp.empty(z_lo.shape, dtype=wp.float32, device="cpu")
    wp.launch(_decode_kernel, dim=z_lo.shape, inputs=[data, out], device="cpu")
    z = out.numpy()
    assert np.array_equal(z, csm.lists.decode_all())
    assert np.all(z_lo <= z)
    ok_hi = (z < z_hi) | np.isinf(z_hi) | ((z_lo == z_hi) & (z == z_lo))
    assert ok_hi.all()


def test_queries_equal_the_uncompressed_depth_test(scene, rng):
    _, _, csm, z_lo, z_hi = scene
    k = 20000
    points = (csm.center + rng.uniform(-1.0, 1.0, size=(k, 3)) * csm.radius).astype(np.float32)
    cells = rng.integers(0, csm.num_maps, size=k).astype(np.int32)
    q = wp.empty(k, dtype=wp.vec3, device="cpu")
    vis = wp.empty(k, dtype=wp.float32, device="cpu")
    stored = wp.empty(k, dtype=wp.float32, device="cpu")
    wp.launch(_project_kernel, dim=k,
              inputs=[csm_device_data(csm), wp.array(cells, dtype=wp.int32), wp.array(points, dtype=wp.vec3), q, vis,
                      stored], device="cpu")
    q, vis, stored = q.numpy(), vis.numpy(), stored.numpy()
    x, y = np.floor(q[:, 0]).astype(int), np.floor(q[:, 1]).astype(int)
    m = csm.resolution
    inside = (x >= 0) & (y >= 0) & (x < m) & (y < m)
    assert np.all(vis[~inside] == 1.0)
    seq = csm.map_index.ravel()[cells[inside]]
    texel = y[inside] * m + x[inside]
    lo, hi, depth = z_lo[seq, texel], z_hi[seq, texel], q[inside, 2]
    v = vis[inside]
    # the dual-depth test of the uncompressed maps: lit up to the first surface, shadowed from the upper one on
    lit = depth <= lo
    shadowed = (depth >= hi) & (hi > lo)
    assert np.all(v[lit] == 1.0) and np.all(v[shadowed] == 0.0)
    assert lit.sum() > 5000 and shadowed.sum() > 1000  # measured 11.4k lit, 2.1k shadowed of 20k
    # and exactly the single depth test against the depth the CSM stores for that map and texel
    assert np.array_equal(v == 1.0, depth <= stored[inside])
    # the stored depth itself is the one the decode of map seq gives
    assert np.array_equal(stored[inside], csm.lists.decode_all()[seq, texel])


@wp.kernel
def _filters_kernel(csm: CSMData, points: wp.array(dtype=wp.vec3), dirs: wp.array(dtype=wp.vec3),
                    xi: wp.array(dtype=wp.vec4), out: wp.array2d(dtype=wp.float32), cell: wp.array(dtype=wp.int32)):
    k = wp.tid()
    p = points[k]
    d = dirs[k]
    out[k, 0] = csm_visibility(csm, p, d, 0.0)
    out[k, 1] = csm_visibility_pcf(csm, p, d, 0.0)
    out[k, 2] = csm_visibility_roulette(csm, p, d, 0.0, xi[k])
    out[k, 3] = csm_visibility_to_point(csm, p, p + 5.0 * d, 0.0)
    cell[k] = csm_nearest_cell(csm, d)


@wp.kernel
def _texel_tests_kernel(csm: CSMData, seq: wp.array(dtype=wp.int32), xy: wp.array(dtype=wp.vec2i),
                        depth: wp.array(dtype=wp.float32), out: wp.array(dtype=wp.float32)):
    k = wp.tid()
    out[k] = csm_texel_visibility(csm, seq[k], xy[k][0], xy[k][1], depth[k], 0.0)


def _run_filters(csm, points, dirs, xi):
    k = len(points)
    out = wp.empty((k, 4), dtype=wp.float32, device="cpu")
    cell = wp.empty(k, dtype=wp.int32, device="cpu")
    wp.launch(_filters_kernel, dim=k,
              inputs=[csm_device_data(csm), wp.array(points, dtype=wp.vec3), wp.array(dirs, dtype=wp.vec3),
                      wp.array(xi, dtype=wp.vec4), out, cell], device="cpu")
    return out.numpy(), cell.numpy()


def _host_pcf(csm, points, dirs):
    """Generalised PCF by hand: bilinear maps x bilinear texels, 16 texel tests through the public func."""
    d = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    u = (np.arctan2(d[:, 2], d[:, 0]) % (2 * np.pi)) / (2 * np.pi)
    v = np.arccos(np.clip(d[:, 1], -1, 1)) / np.pi
    s, t = u * csm.n1 - 0.5, v * csm.n2 - 0.5
    a0, b0 = np.floor(s).astype(int), np.floor(t).astype(int)
    fa, fb = s - a0, t - b0
    frames = csm.frames
    seqs, xys, depths, weights = [], [], [], []
    for da, wa in ((0, 1 - fa), (1, fa)):
        for db, wb in ((0, 1 - fb), (1, fb)):
            a = (a0 + da) % csm.n1
            b = np.clip(b0 + db, 0, csm.n2 - 1)
            cell = b * csm.n1 + a
            f = frames[cell]
            r = points - csm.center
            px = (np.einsum("kj,kj->k", r, f[:, 0]) / csm.radius + 1) * 0.5 * csm.resolution - 0.5
            py = (1 - np.einsum("kj,kj->k", r, f[:, 1]) / csm.radius) * 0.5 * csm.resolution - 0.5
            qz = csm.radius - np.einsum("kj,kj->k", r, f[:, 2])
            x0, y0 = np.floor(px).astype(int), np.floor(py).astype(int)
            fx, fy = px - x0, py - y0
            for dx, wx in ((0, 1 - fx), (1, fx)):
                for dy, wy in ((0, 1 - fy), (1, fy)):
                    seqs.append(csm.map_index.ravel()[cell])
                    xys.append(np.stack([x0 + dx, y0 + dy], axis=1))
                    depths.append(qz)
                    weights.append(wa * wb * wx * wy)
    seq = np.concatenate(seqs).astype(np.int32)
    xy = np.concatenate(xys).astype(np.int32)
    out = wp.empty(seq.size, dtype=wp.float32, device="cpu")
    wp.launch(_texel_tests_kernel, dim=seq.size,
              inputs=[csm_device_data(csm), wp.array(seq, dtype=wp.int32), wp.array(xy, dtype=wp.vec2i),
                      wp.array(np.concatenate(depths).astype(np.float32), dtype=wp.float32), out], device="cpu")
    tests = out.numpy().reshape(16, -1)
    return np.sum(np.stack(weights) * tests, axis=0), np.stack([a0 % csm.n1, np.clip(b0, 0, csm.n2 - 1)])


def test_filters(scene, rng):
    _, _, csm, _, _ = scene
    k = 3000
    points = (csm.center + rng.uniform(-0.8, 0.8, size=(k, 3)) * csm.radius).astype(np.float32)
    dirs = rng.normal(size=(k, 3)).astype(np.float32)
    xi = rng.random((k, 4)).astype(np.float32)
    out, cell = _run_filters(csm, points, dirs, xi)
    nearest, pcf, roulette, to_point = out.T
    # nearest-map selection: the lat-long cell containing the direction
    d = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    u = (np.arctan2(d[:, 2], d[:, 0]) % (2 * np.pi)) / (2 * np.pi)
    v = np.arccos(np.clip(d[:, 1], -1, 1)) / np.pi
    host_cell = np.minimum((v * csm.n2).astype(int), csm.n2 - 1) * csm.n1 + np.minimum((u * csm.n1).astype(int),
                                                                                          csm.n1 - 1)
    assert np.mean(host_cell == cell) > 0.999  # measured 1.0 (float32 vs float64 at cell borders)
    assert np.array_equal(to_point, nearest)  # semi-local: d = l - p
    assert set(np.unique(nearest)) <= {0.0, 1.0} and set(np.unique(roulette)) <= {0.0, 1.0}
    ref, _ = _host_pcf(csm, points.astype(np.float64), dirs.astype(np.float64))
    assert np.mean(np.abs(ref - pcf) < 1e-4) > 0.995  # measured 0.999 (float32 vs float64 texel borders)
    assert 0.05 < np.mean((pcf > 0) & (pcf < 1))  # partial shadow occurs (measured 0.19)
    # Russian roulette picks one of the 16 comparisons with the PCF weight: unbiased
    p1 = np.repeat(points[:40], 2000, axis=0)
    d1 = np.repeat(dirs[:40], 2000, axis=0)
    out1, _ = _run_filters(csm, p1, d1, rng.random((p1.shape[0], 4)).astype(np.float32))
    mean = out1[:, 2].reshape(40, 2000).mean(axis=1)
    target = pcf[:40]
    sigma = np.sqrt(np.maximum(target * (1 - target), 1e-6) / 2000)
    assert np.all(np.abs(mean - target) < 5 * sigma + 1e-6)


def surface_samples(v, t, k, rng):
    tri = v[t].astype(np.float64)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    idx = rng.choice(len(t), size=k, p=area / area.sum())
    a, b = rng.random((2, k))
    s = np.sqrt(a)
    w = np.stack([1 - s, s * (1 - b), s * b], 1)
    p = np.einsum("kj,kjc->kc", w, tri[idx])
    n = np.cross(tri[idx, 1] - tri[idx, 0], tri[idx, 2] - tri[idx, 0])
    return p, n / np.linalg.norm(n, axis=1, keepdims=True)


@wp.kernel
def _bvh_kernel(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), dirs: wp.array(dtype=wp.vec3),
                out: wp.array(dtype=wp.float32)):
    k = wp.tid()
    d = wp.normalize(dirs[k])
    out[k] = wp.where(occluded(mesh, points[k] + 1.0e-4 * d, d, 1.0e6), 0.0, 1.0)


def test_csm_agrees_with_ray_casting_on_surface_points(rng):
    # A closed bumpy sphere, 64 x 32 maps of 64^2: CSM visibility is a discretisation of the exact visibility
    # (directions snap to map centres, points to texels), so most, not all, answers agree.
    s = trimesh.creation.icosphere(subdivisions=4)
    sv = np.asarray(s.vertices)
    v = sv * (1.0 + 0.35 * np.sin(5 * sv[:, 0]) * np.sin(5 * sv[:, 1] + 1) * np.sin(5 * sv[:, 2]))[:, None]
    v, t = v.astype(np.float32), np.asarray(s.faces, np.int32)
    csm = build_csm(v, t, maps=(64, 32), resolution=64, layers="z1z2", batch=256)
    k = 20000
    p, n = surface_samples(v.astype(np.float64), t, k, rng)
    d = rng.normal(size=(k, 3))
    d *= np.sign(np.sum(d * n, axis=1))[:, None]  # upper hemisphere
    exact = wp.empty(k, dtype=wp.float32, device="cpu")
    mesh = build_mesh(v, t)  # keep a reference: the BVH must outlive the launch
    wp.launch(_bvh_kernel, dim=k, inputs=[mesh.id, wp.array(p, dtype=wp.vec3),
                                          wp.array(d, dtype=wp.vec3), exact], device="cpu")
    exact = exact.numpy()
    near = csm_visibility_batch(csm, p, d, bias=0.01)
    pcf = csm_visibility_batch(csm, p, d, filter="pcf", bias=0.01)
    assert 0.1 < 1.0 - exact.mean() < 0.5  # the test has shadows: measured 0.18 shadowed
    assert np.mean(near == exact) > 0.95  # measured 0.968
    assert np.mean(np.abs(pcf - exact)) < 0.06  # measured 0.039 (PCF adds self-shadowing on slopes)
    assert csm.stats.ratio > 5  # measured 10.1


def test_semi_local_light_and_receiver_plane():
    # A sphere of radius 1 at the origin; a point light at (0, 4, 0) (outside the hull) and a receiver plane y = -2.
    s = trimesh.creation.icosphere(subdivisions=4)
    v, t = np.asarray(s.vertices, np.float32), np.asarray(s.faces, np.int32)
    csm = build_csm(v, t, maps=(64, 32), resolution=64)
    g = np.linspace(-3.0, 3.0, 61)
    gx, gz = np.meshgrid(g, g)
    ground = np.stack([gx.ravel(), np.full(gx.size, -2.0), gz.ravel()], axis=1)
    light = np.array([0.0, 4.0, 0.0])
    vis = csm_visibility_batch(csm, ground, light - ground)
    # exact: the segment ground -> light misses the unit ball (icosphere inscribed radius ~0.996)
    dvec = light - ground
    tc = np.clip(np.einsum("kj,kj->k", -ground, dvec) / np.einsum("kj,kj->k", dvec, dvec), 0, 1)
    dist = np.linalg.norm(ground + tc[:, None] * dvec, axis=1)
    clear = dist > 1.02
    blocked = dist < 0.97
    assert blocked.sum() > 50 and clear.sum() > 1000
    assert np.all(vis[blocked] == 0.0) and np.all(vis[clear] == 1.0)


def test_moving_objects_use_the_inverse_transform(scene, rng):
    v, t, csm, _, _ = scene
    angle = 0.7
    rot = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    tf = np.eye(4)
    tf[:3, :3] = 1.5 * rot
    tf[:3, 3] = [2.0, -1.0, 0.5]
    k = 20000
    p_obj = csm.center + rng.uniform(-1, 1, size=(k, 3)) * csm.radius
    d_obj = rng.normal(size=(k, 3))
    p_world = p_obj @ tf[:3, :3].T + tf[:3, 3]
    d_world = d_obj @ tf[:3, :3].T
    moved = csm_objects_visibility_batch([(csm, tf)], p_world, d_world)
    direct = csm_visibility_batch(csm, p_obj, d_obj)
    assert np.mean(moved == direct) > 0.998  # measured 0.9998: float32 round trip at texel / depth borders
    assert 0.1 < direct.mean() < 0.95
    # Two objects (identity placements here): visibilities multiply exactly.
    v2, t2 = v + np.float32([0.0, 3.0, 0.0]), t
    other = build_csm(v2, t2, maps=(8, 4), resolution=16)
    both = csm_objects_visibility_batch([(csm, None), (other, None)], p_obj, d_obj)
    assert np.array_equal(both, direct * csm_visibility_batch(other, p_obj, d_obj))


def test_bad_query_arguments_raise(scene):
    _, _, csm, _, _ = scene
    p = np.zeros((3, 3))
    with pytest.raises(ValueError, match="filter"):
        csm_visibility_batch(csm, p, p + 1, filter="box")
    with pytest.raises(ValueError, match="non-zero"):
        csm_visibility_batch(csm, p, p)
    with pytest.raises(ValueError, match="directions must have 3 rows"):
        csm_visibility_batch(csm, p, np.ones((2, 3)))
    with pytest.raises(ValueError, match="bias"):
        csm_visibility_batch(csm, p, p + 1, bias=-1.0)
    with pytest.raises(ValueError, match="points"):
        csm_visibility_batch(csm, np.full((3, 3), np.nan), p + 1)
    with pytest.raises(ValueError, match="singular"):
        csm_objects_visibility_batch([(csm, np.zeros((4, 4)) + np.diag([0, 0, 0, 1.0]))], p, p + 1)
    with pytest.raises(ValueError, match="at least one"):
        csm_objects_visibility_batch([], p, p + 1)
    with pytest.raises(ValueError, match="nearly so"):  # flattened along one axis: its float32 inverse loses the shape
        csm_objects_visibility_batch([(csm, np.diag([1.0, 1.0, 1e-7, 1.0]))], p, p + 1)


def test_a_uniformly_tiny_object_is_queried_like_its_unscaled_self(scene):
    # a uniform scale of any size inverts exactly (the singularity test is relative, not on the determinant): the
    # object scaled by 1e-6 with the points scaled alike sees what the unscaled object sees
    _, _, csm, _, _ = scene
    rng = np.random.default_rng(3)
    points = csm.center + csm.radius * rng.uniform(-1.0, 1.0, (2000, 3))
    dirs = rng.normal(size=(2000, 3))
    s = 1.0e-6
    unscaled = csm_objects_visibility_batch([(csm, np.eye(4))], points, dirs)
    tiny = csm_objects_visibility_batch([(csm, np.diag([s, s, s, 1.0]))], points * s, dirs)
    assert 0.0 < unscaled.mean() < 1.0
    assert np.mean(unscaled == tiny) > 0.995  # measured 1.0 (float32 rounding of p * 1e-6 * 1e6 may move a texel)


@wp.kernel
def _uv_filters_kernel(csm: CSMData, points: wp.array(dtype=wp.vec3), dirs: wp.array(dtype=wp.vec3),
                       xi: wp.array(dtype=wp.vec4), out: wp.array2d(dtype=wp.float32)):
    k = wp.tid()
    p = points[k]
    d = dirs[k]
    uv = latlong_param(d)
    for f in range(3):
        out[k, f] = csm_visibility_filtered(csm, p, d, 0.01, f, xi[k])
        out[k, 3 + f] = csm_visibility_filtered_uv(csm, p, uv, 0.01, f, xi[k])
    out[k, 6] = csm_visibility(csm, p, d, 0.01)
    out[k, 7] = csm_visibility_pcf(csm, p, d, 0.01)
    out[k, 8] = csm_visibility_roulette(csm, p, d, 0.01, xi[k])


def test_queries_of_known_lat_long_parameters_equal_the_direction_queries(scene, rng):
    """csm_visibility_filtered_uv with uv = latlong_param(d) (what the environment estimator passes for a BRDF
    sample, sharing the parameters with its map look-up) is csm_visibility_filtered(d) bit for bit, for every
    filter, and csm_visibility_filtered is the nearest / PCF / roulette query it names."""
    _, _, csm, _, _ = scene
    k = 20_000
    points = rng.uniform(-1.6, 1.6, (k, 3)).astype(np.float32)
    dirs = rng.normal(size=(k, 3)).astype(np.float32)
    xi = rng.random((k, 4)).astype(np.float32)
    out = wp.zeros((k, 9), dtype=wp.float32)
    wp.launch(_uv_filters_kernel, dim=k, inputs=[csm_device_data(csm), wp.array(points, dtype=wp.vec3),
                                                 wp.array(dirs, dtype=wp.vec3), wp.array(xi, dtype=wp.vec4), out],
              device="cpu")
    o = out.numpy()
    assert np.array_equal(o[:, :3], o[:, 3:6]) and np.array_equal(o[:, :3], o[:, 6:9])
    assert 0.05 < (o[:, 0] == 0.0).mean() < 0.95  # both lit and shadowed queries
