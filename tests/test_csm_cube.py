"""Depth-cube-map CSMs of fixed local lights (Ritschel 2007 Sec. 3.3, 4.2): face-major concatenation, lossless
decode, shadows of a sphere, filters, files."""

import numpy as np
import pytest
import trimesh
import warp as wp

from warpscatter.csm import (
    CSMFileError,
    CubeMapSet,
    build_csm,
    build_cube_csm,
    compress_depth_maps,
    csm_device_data,
    csm_local_visibility_batch,
    cube_face_frames,
    load_csm,
    parallelogram_light_samples,
    save_csm,
    segment_light_samples,
)
from warpscatter.csm.query import CubeCSMData, csm_cube_project, cube_face, segment_lookup


def unit_sphere(subdivisions=3):
    s = trimesh.creation.icosphere(subdivisions=subdivisions)
    return np.asarray(s.vertices, np.float32), np.asarray(s.faces, np.int32)


def ground_grid():
    g = np.linspace(-3.0, 3.0, 41)
    gx, gz = np.meshgrid(g, g)
    return np.stack([gx.ravel(), np.full(gx.size, -2.0), gz.ravel()], axis=1)


def segment_distance_to_origin(a, b):
    """Distance from the origin to the segments a[k] -> b."""
    d = b - a
    t = np.clip(np.einsum("kj,kj->k", -a, d) / np.einsum("kj,kj->k", d, d), 0.0, 1.0)
    return np.linalg.norm(a + t[:, None] * d, axis=1)


def test_cube_faces_and_face_selection():
    f = cube_face_frames()
    np.testing.assert_allclose(np.cross(f[:, 0], f[:, 1]), -f[:, 2], atol=1e-12)  # right x up = -forward
    np.testing.assert_allclose(f[:, 2], np.repeat(np.eye(3), 2, axis=0) * np.tile([[1], [-1]], (3, 1)))

    @wp.kernel
    def faces_kernel(w: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.int32)):
        i = wp.tid()
        out[i] = cube_face(w[i])

    w = np.random.default_rng(3).normal(size=(500, 3)).astype(np.float32)
    out = wp.empty(500, dtype=wp.int32, device="cpu")
    wp.launch(faces_kernel, dim=500, inputs=[wp.array(w, dtype=wp.vec3), out], device="cpu")
    assert np.array_equal(out.numpy(), np.argmax(w @ f[:, 2].T, axis=1))  # the face whose forward is nearest


def test_linear_depth_of_a_face():
    v, t = unit_sphere(4)
    maps = CubeMapSet.create(v, t, segment_light_samples([0, 3, 0], [0, 3, 0], 1), resolution=33)
    z_lo, z_hi = maps.render(3, 4)  # face 3 (-Y) of the only sample looks down at the sphere
    c = 16  # centre texel: the ray along -Y meets the sphere at y = +1 and leaves it at y = -1
    assert abs(z_lo[0, c, c] - 2.0) < 0.01 and abs(z_hi[0, c, c] - 4.0) < 0.01  # icosphere faceting ~4e-3
    assert np.isinf(z_lo[0, 0, 0]) and np.isinf(z_hi[0, 0, 0])  # the corner ray misses the sphere


def test_cube_csm_is_lossless_face_major_and_round_trips(tmp_path):
    s = trimesh.creation.icosphere(subdivisions=2)
    v = (np.asarray(s.vertices) * (1 + 0.3 * np.sin(3 * s.vertices[:, :1]))).astype(np.float32)
    t = np.asarray(s.faces, np.int32)
    samples = parallelogram_light_samples([-0.5, 2.5, -0.5], [1, 0, 0], [0, 0, 1], 3, 2)
    csm = build_cube_csm(v, t, samples, resolution=12, layers="z1z2", batch=5)
    maps = CubeMapSet.create(v, t, samples, resolution=12)
    z_lo, z_hi = maps.render(0, maps.num_maps)
    assert csm.num_maps == 36 and maps.face_matrices(7)[2].tolist() == samples.reshape(-1, 3)[
        maps.order[1][1] * 3 + maps.order[1][0]].tolist()  # map 7 = face 1 of sample 1
    one_shot = compress_depth_maps(z_lo, z_hi, batch_maps=36)
    assert np.array_equal(one_shot.seg_depth, csm.lists.seg_depth)
    assert np.array_equal(one_shot.seg_end, csm.lists.seg_end)
    z = csm.lists.decode_all().reshape(z_lo.shape)
    assert np.all(z_lo <= z) and np.all((z < z_hi) | np.isinf(z_hi) | ((z_lo == z_hi) & (z == z_lo)))
    path = tmp_path / "cube.npz"
    save_csm(csm, path)
    back = load_csm(path)
    assert back.kind == "cube" and back.params() == csm.params()
    assert np.array_equal(back.light_samples, csm.light_samples)
    assert np.array_equal(back.lists.seg_depth, csm.lists.seg_depth)
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files if k != "light_samples"}
    np.savez(tmp_path / "no_samples.npz", **arrays)
    with pytest.raises(CSMFileError, match="light_samples"):
        load_csm(tmp_path / "no_samples.npz")
    arrays["light_samples"] = np.zeros((5, 3))
    np.savez(tmp_path / "short_samples.npz", **arrays)
    with pytest.raises(CSMFileError, match="light_samples has shape"):
        load_csm(tmp_path / "short_samples.npz")


@wp.kernel
def _project_kernel(csm: CubeCSMData, cells: wp.array(dtype=wp.int32), points: wp.array(dtype=wp.vec3),
                    q: wp.array(dtype=wp.vec4), stored: wp.array(dtype=wp.float32)):
    k = wp.tid()
    face, p = csm_cube_project(csm, cells[k], points[k])
    q[k] = wp.vec4(p[0], p[1], p[2], float(face))
    x = wp.clamp(int(p[0]), 0, csm.resolution - 1)
    y = wp.clamp(int(p[1]), 0, csm.resolution - 1)
    seq = face * csm.num_samples + csm.map_index[cells[k]]
    stored[k] = segment_lookup(csm.seg_start, csm.seg_depth, csm.seg_end, y * csm.resolution + x, seq)


def test_cube_queries_equal_the_uncompressed_depth_test(rng):
    v, t = unit_sphere(2)
    samples = segment_light_samples([-1.0, 2.5, 0.0], [1.0, 2.5, 0.3], 5)
    csm = build_cube_csm(v, t, samples, resolution=16, batch=7)
    maps = CubeMapSet.create(v, t, samples, resolution=16)
    z_lo, z_hi = maps.render(0, maps.num_maps)
    k = 4000
    pts = rng.uniform(-1.5, 1.5, size=(k, 3)).astype(np.float32)
    cells = rng.integers(0, 5, size=k).astype(np.int32)
    q = wp.empty(k, dtype=wp.vec4, device="cpu")
    stored = wp.empty(k, dtype=wp.float32, device="cpu")
    wp.launch(_project_kernel, dim=k, inputs=[csm_device_data(csm), wp.array(cells, dtype=wp.int32),
                                              wp.array(pts, dtype=wp.vec3), q, stored], device="cpu")
    q, stored = q.numpy(), stored.numpy()
    face = q[:, 3].astype(int)
    seq = face * 5 + csm.map_index.ravel()[cells]
    x, y = np.clip(q[:, 0].astype(int), 0, 15), np.clip(q[:, 1].astype(int), 0, 15)
    lo, hi, depth = z_lo[seq, y, x], z_hi[seq, y, x], q[:, 2]
    params = np.stack([(cells + 0.5) / 5, np.full(k, 0.5)], axis=1)
    vis = csm_local_visibility_batch(csm, pts, params)
    lit, shadowed = depth <= lo, (depth >= hi) & (hi > lo)
    assert np.all(vis[lit] == 1.0) and np.all(vis[shadowed] == 0.0)
    assert lit.sum() > 1000 and shadowed.sum() > 300  # measured 2.6k lit, 0.9k shadowed of 4k
    assert np.array_equal(vis == 1.0, depth <= stored)


def test_area_light_shadows_of_a_sphere_on_the_ground():
    v, t = unit_sphere(4)
    samples = parallelogram_light_samples([-0.5, 3.0, -0.5], [1, 0, 0], [0, 0, 1], 2, 2)
    csm = build_cube_csm(v, t, samples, resolution=64)
    ground = ground_grid()
    for x in ((0.3, 0.3), (0.9, 0.1)):
        params = np.tile(np.array([x]), (len(ground), 1))
        vis = csm_local_visibility_batch(csm, ground, params)
        o = samples[int(x[1] * 2), int(x[0] * 2)]
        dist = segment_distance_to_origin(ground, o)
        # 64^2 face texels seen from ~3 units are ~0.1 wide at the sphere: errors measured in [0.964, 1.042]
        assert np.all(vis[dist < 0.93] == 0.0) and np.all(vis[dist > 1.07] == 1.0)
        assert (dist < 0.93).sum() > 20
        pcf = csm_local_visibility_batch(csm, ground, params, filter="pcf")
        roulette = np.mean([csm_local_visibility_batch(csm, ground, params, filter="roulette", seed=s)
                            for s in range(200)], axis=0)
        # PCF blends the 2^2 nearest samples bilinearly: away from every sample's shadow edge it equals the
        # weighted exact visibilities
        sx, sy = x[0] * 2 - 0.5, x[1] * 2 - 0.5
        a0, b0 = int(np.floor(sx)), int(np.floor(sy))
        fa, fb = sx - a0, sy - b0
        expected = np.zeros(len(ground))
        clear_of_edges = np.ones(len(ground), bool)
        for da, wa in ((0, 1 - fa), (1, fa)):
            for db, wb in ((0, 1 - fb), (1, fb)):
                dj = segment_distance_to_origin(ground, samples[np.clip(b0 + db, 0, 1), np.clip(a0 + da, 0, 1)])
                expected += wa * wb * (dj > 1.0)
                clear_of_edges &= (dj < 0.9) | (dj > 1.2)
        assert clear_of_edges.sum() > 1000
        np.testing.assert_allclose(pcf[clear_of_edges], expected[clear_of_edges], atol=1e-6)
        assert np.max(np.abs(roulette - pcf)) < 0.15  # 200 samples: 5 sigma of a Bernoulli mean ~ 0.18
        assert abs(np.mean(roulette - pcf)) < 0.01


def test_local_queries_reject_bad_input():
    v, t = unit_sphere(1)
    cube = build_cube_csm(v, t, segment_light_samples([0, 3, 0], [1, 3, 0], 2), resolution=4)
    latlong = build_csm(v, t, maps=(2, 2), resolution=4)
    p = np.zeros((2, 3))
    with pytest.raises(ValueError, match="'cube' CSM"):
        csm_local_visibility_batch(latlong, p, np.zeros((2, 2)))
    with pytest.raises(ValueError, match="light_params must lie"):
        csm_local_visibility_batch(cube, p, np.full((2, 2), 1.5))
    with pytest.raises(ValueError, match="light_params must have shape"):
        csm_local_visibility_batch(cube, p, np.zeros((3, 2)))
    with pytest.raises(ValueError, match="samples"):
        build_cube_csm(v, t, np.zeros((2, 2)), resolution=4)
    with pytest.raises(ValueError, match="near"):
        build_cube_csm(v, t, np.zeros((1, 3)) + 3, resolution=4, near=-1.0)
