"""Tests of warpscatter.scene.meshes: the TriangleMesh container, file loading through trimesh, transforms, and the
in-process mesh cache."""

import os

import numpy as np
import pytest
import trimesh

from warpscatter.scene.meshes import (
    MeshLoadError,
    TriangleMesh,
    apply_transform,
    concatenate,
    load_mesh,
    transform_matrix,
)


def _sorted_triangles(vertices, triangles) -> np.ndarray:
    """Triangles as sorted tuples of rounded corner coordinates: compares meshes independent of vertex order."""
    corners = np.round(np.asarray(vertices, np.float64)[np.asarray(triangles)], 5)  # (T, 3, 3)
    keys = [tuple(sorted(map(tuple, tri))) for tri in corners]
    return np.array(sorted(keys))


def _apply(m, p):
    return (m @ np.append(p, 1.0))[:3]


# ---- container ---------------------------------------------------------------------------------------------------


def test_mesh_validation_and_dtypes():
    m = TriangleMesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    assert m.vertices.dtype == np.float32 and m.triangles.dtype == np.int32
    assert m.num_triangles == 1 and m.num_vertices == 3
    with pytest.raises(ValueError, match="vertices must be finite"):
        TriangleMesh([[0, 0, 0], [np.nan, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    with pytest.raises(ValueError, match="triangles index vertices"):
        TriangleMesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 3]])
    with pytest.raises(ValueError, match="triangles index vertices"):
        TriangleMesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, -1, 2]])
    with pytest.raises(ValueError, match="at least one triangle"):
        TriangleMesh([[0, 0, 0]], np.zeros((0, 3), int))
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        TriangleMesh([[0, 0], [1, 0], [0, 1]], [[0, 1, 2]])
    with pytest.raises(ValueError, match="integer indices"):
        TriangleMesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 1.5]])


def test_bounds_normals_and_concatenate():
    a = TriangleMesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    b = TriangleMesh([[5, 5, 5], [0, 0, -2], [0, 2, -2], [2, 0, -2]], [[1, 2, 3]])  # vertex 0 unused, clockwise from +Z
    lo, hi = b.bounds()
    np.testing.assert_array_equal(lo, [0, 0, -2])
    np.testing.assert_array_equal(hi, [2, 2, -2])  # the unused vertex (5, 5, 5) does not count
    np.testing.assert_allclose(a.face_normals(), [[0, 0, 1]])
    np.testing.assert_allclose(b.face_normals(), [[0, 0, -1]])
    joined, part = concatenate([a, b, a])
    assert joined.num_triangles == 3 and joined.num_vertices == 10
    np.testing.assert_array_equal(part, [0, 1, 2])
    assert part.dtype == np.int32
    np.testing.assert_array_equal(joined.triangle_vertices()[1], b.triangle_vertices()[0])
    np.testing.assert_array_equal(joined.triangle_vertices()[2], a.triangle_vertices()[0])
    with pytest.raises(ValueError, match="at least one"):
        concatenate([])


# ---- transforms ----------------------------------------------------------------------------------------------------


def test_transform_order_against_hand_computed_points():
    # scale (2, 1, 1), then +90 deg about X, then +90 deg about Y, then translate (10, 0, 0).
    m = transform_matrix(translate=[10, 0, 0], rotate_deg=[90, 90, 0], scale=[2, 1, 1])
    # (1,0,0) -S-> (2,0,0) -Rx-> (2,0,0) -Ry-> (0,0,-2) -T-> (10,0,-2)
    np.testing.assert_allclose(_apply(m, [1, 0, 0]), [10, 0, -2], atol=1e-12)
    # (0,1,0) -S-> (0,1,0) -Rx-> (0,0,1) -Ry-> (1,0,0) -T-> (11,0,0)
    np.testing.assert_allclose(_apply(m, [0, 1, 0]), [11, 0, 0], atol=1e-12)
    # (0,0,1) -Rx-> (0,-1,0) -Ry-> (0,-1,0) -T-> (10,-1,0)
    np.testing.assert_allclose(_apply(m, [0, 0, 1]), [10, -1, 0], atol=1e-12)

    # Z is applied last: +90 about Y then +90 about Z takes (0,0,1) -> (1,0,0) -> (0,1,0);
    # the other order (Z first) would give (1,0,0) -> ... -> (1,0,0) -> (0,0,-1).
    m = transform_matrix(rotate_deg=[0, 90, 90])
    np.testing.assert_allclose(_apply(m, [0, 0, 1]), [0, 1, 0], atol=1e-12)
    # X before Z: +90 about X then +90 about Z takes (0,1,0) -> (0,0,1) -> (0,0,1)
    m = transform_matrix(rotate_deg=[90, 0, 90])
    np.testing.assert_allclose(_apply(m, [0, 1, 0]), [0, 0, 1], atol=1e-12)
    # scale before rotation: non-uniform scale along the mesh's own X, then rotate 90 about Z
    m = transform_matrix(rotate_deg=[0, 0, 90], scale=[3, 1, 1])
    np.testing.assert_allclose(_apply(m, [1, 0, 0]), [0, 3, 0], atol=1e-12)
    np.testing.assert_allclose(_apply(m, [0, 1, 0]), [-1, 0, 0], atol=1e-12)
    # rotation about the mesh origin, translation last
    m = transform_matrix(translate=[1, 2, 3], rotate_deg=[0, 0, 180], scale=2)
    np.testing.assert_allclose(_apply(m, [1, 1, 0]), [-1, 0, 3], atol=1e-12)


def test_transform_defaults_and_errors():
    np.testing.assert_array_equal(transform_matrix(), np.eye(4))
    with pytest.raises(ValueError, match="scale must be > 0"):
        transform_matrix(scale=0)
    with pytest.raises(ValueError, match="scale must be > 0"):
        transform_matrix(scale=[1, -1, 1])
    with pytest.raises(ValueError, match="translate"):
        transform_matrix(translate=[1, 2])
    with pytest.raises(ValueError, match="rotate_deg must be finite"):
        transform_matrix(rotate_deg=[0, np.inf, 0])


def test_apply_transform_moves_vertices_and_keeps_normals_outward():
    box = trimesh.creation.box(extents=[1, 2, 3])
    mesh = TriangleMesh(box.vertices, box.faces)
    m = transform_matrix([1, -2, 0.5], [30, -45, 60], [2, 0.5, 1.5])
    moved = apply_transform(mesh, m)
    expect = box.vertices @ m[:3, :3].T + m[:3, 3]
    np.testing.assert_allclose(moved.vertices, expect, atol=1e-5)
    tm = moved.to_trimesh()
    assert tm.volume == pytest.approx(6.0 * 1.5, rel=1e-5)  # det = 2 * 0.5 * 1.5, positive volume: outward
    mirrored = apply_transform(mesh, np.diag([-1.0, 1.0, 1.0, 1.0]))
    assert mirrored.to_trimesh().volume == pytest.approx(6.0, rel=1e-6)  # winding flipped with the mirror
    with pytest.raises(ValueError, match="affine"):
        apply_transform(mesh, np.ones((4, 4)))


# ---- loading -------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def reference_mesh():
    """A small closed mesh with distinct triangles (an icosphere stretched and shifted)."""
    s = trimesh.creation.icosphere(subdivisions=1)
    s.apply_scale([1.0, 2.0, 0.5])
    s.apply_translation([0.25, 1.0, -3.0])
    return s


@pytest.mark.parametrize("ext", ["obj", "ply", "stl", "glb", "off"])
def test_each_format_loads_the_same_triangles(tmp_path, reference_mesh, ext):
    path = tmp_path / f"mesh.{ext}"
    reference_mesh.export(path)
    mesh = load_mesh(path)
    assert mesh.num_triangles == len(reference_mesh.faces)
    np.testing.assert_allclose(
        _sorted_triangles(mesh.vertices, mesh.triangles),
        _sorted_triangles(reference_mesh.vertices, reference_mesh.faces),
        atol=2e-5,  # float32 storage (STL/GLB/PLY) and 8-digit OBJ text
    )
    # winding kept: the loaded closed mesh has the same positive volume
    assert mesh.to_trimesh().volume == pytest.approx(reference_mesh.volume, rel=1e-5)


def test_scene_flattened_with_node_transforms(tmp_path):
    scene = trimesh.Scene()
    box = trimesh.creation.box(extents=[1, 1, 1])
    m1 = transform_matrix([5, 0, 0], [0, 90, 0], 1)
    m2 = transform_matrix([0, 3, 0], [0, 0, 0], 2)
    scene.add_geometry(box, node_name="a", geom_name="box", transform=m1)
    scene.add_geometry(box, node_name="b", geom_name="box2", transform=m2)
    path = tmp_path / "scene.glb"
    scene.export(path)
    mesh = load_mesh(path)
    assert mesh.num_triangles == 24
    lo, hi = mesh.bounds()
    np.testing.assert_allclose(lo, [-1, -0.5, -1], atol=1e-6)  # x, z from the scaled box, y from the shifted one
    np.testing.assert_allclose(hi, [5.5, 4, 1], atol=1e-6)  # x from the shifted box at x = 5, y, z from the scaled one


def test_obj_quads_polygons_and_objects(tmp_path):
    path = tmp_path / "poly.obj"
    path.write_text(
        "o quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n"
        "o pentagon\nv 2 0 0\nv 3 0 0\nv 3 1 0\nv 2.5 1.5 0\nv 2 1 0\nf 5 6 7 8 9\n"
    )
    mesh = load_mesh(path)
    assert mesh.num_triangles == 2 + 3
    area = (
        0.5
        * np.linalg.norm(
            np.cross(*(mesh.triangle_vertices()[:, 1:] - mesh.triangle_vertices()[:, :1]).transpose(1, 0, 2)), axis=1
        ).sum()
    )
    assert area == pytest.approx(1.0 + 1.25, rel=1e-6)
    assert np.all(mesh.face_normals()[:, 2] > 0.99)  # counter-clockwise in the file: +Z normals kept


def test_ply_quads_triangulated(tmp_path):
    path = tmp_path / "quad.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n"
    )
    mesh = load_mesh(path)
    assert mesh.num_triangles == 2
    assert np.all(mesh.face_normals()[:, 2] > 0.99)


@pytest.mark.parametrize(
    ("name", "content", "reason"),
    [
        ("missing.obj", None, "no such file"),
        ("empty.obj", "", "the file is empty"),
        ("garbage.ply", "this is not a ply file\n", "cannot be parsed"),
        ("garbage.stl", b"\x00\x01garbage" * 7, "contains no triangles"),
        ("points.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\n", "contains no triangles"),
        ("lines.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nl 1 2 3\n", "contains no triangles"),
        ("mesh.xyz", "0 0 0\n", "unsupported extension"),
    ],
)
def test_load_errors_name_file_and_reason(tmp_path, name, content, reason):
    path = tmp_path / name
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        path.write_text(content)
    with pytest.raises(MeshLoadError, match=reason) as info:
        load_mesh(path)
    assert name in str(info.value)
    assert isinstance(info.value, ValueError)


# ---- the in-process mesh cache ---------------------------------------------------------------------------------------


@pytest.fixture
def empty_cache():
    from warpscatter.scene import meshes

    meshes.clear_mesh_cache()
    yield meshes
    meshes.clear_mesh_cache()


def _bits(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a).view(np.uint8).tobytes()


def test_apply_transform_identity_is_exactly_the_general_path():
    v = np.array([[-0.0, -0.0, -0.0], [1e-45, -3.25, 7.0], [2.0, -0.0, 0.0], [-0.0, 1.0, -2.0]], np.float32)
    mesh = TriangleMesh(v, [[0, 1, 2], [1, 2, 3]])

    def general(m):  # the float64 product every other matrix takes
        return (v.astype(np.float64) @ m[:3, :3].T + m[:3, 3]).astype(np.float32)

    fast = apply_transform(mesh, transform_matrix())
    assert _bits(fast.vertices) == _bits(general(np.eye(4))) and not np.signbit(fast.vertices[0]).any()
    assert fast.vertices is not mesh.vertices and fast.triangles is not mesh.triangles
    for m in (transform_matrix(translate=[-0.0, 0.0, -0.0]), transform_matrix(rotate_deg=[0, 360, 0]),
              transform_matrix(scale=2.0)):  # not the identity (or not exactly): the general path
        assert _bits(apply_transform(mesh, m).vertices) == _bits(general(m))


def test_cached_mesh_builds_once_and_hands_out_read_only_arrays(empty_cache):
    built = []

    def build():
        built.append(1)
        return TriangleMesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])

    a = empty_cache.cached_mesh(("k", 1), build)
    b = empty_cache.cached_mesh(("k", 1), build)
    assert len(built) == 1 and a is not b
    assert _bits(a.vertices) == _bits(b.vertices) and _bits(a.triangles) == _bits(b.triangles)
    with pytest.raises(ValueError, match="read-only"):
        a.vertices[0, 0] = 5.0
    with pytest.raises(ValueError, match="read-only"):
        b.triangles += 1
    a.vertices = np.zeros((3, 3), np.float32)  # rebinding a returned mesh's attribute does not reach the cache
    c = empty_cache.cached_mesh(("k", 1), build)
    np.testing.assert_array_equal(c.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    info = empty_cache.mesh_cache_info()
    assert (info["entries"], info["hits"], info["misses"], len(built)) == (1, 2, 1, 1)
    assert info["bytes"] == 3 * 3 * 4 + 3 * 4
    empty_cache.cached_mesh(None, build)  # no key: built every time, not stored
    empty_cache.cached_mesh(None, build)
    assert len(built) == 3 and empty_cache.mesh_cache_info()["entries"] == 1


def test_cached_mesh_does_not_keep_failures_and_evicts_least_recent(empty_cache, monkeypatch):
    def fail():
        raise MeshLoadError("broken")

    with pytest.raises(MeshLoadError):
        empty_cache.cached_mesh("bad", fail)
    assert empty_cache.mesh_cache_info()["entries"] == 0

    def tri(x):
        return lambda: TriangleMesh([[x, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])

    monkeypatch.setattr(empty_cache, "MESH_CACHE_BYTES", 2 * 48)  # room for two 48-byte meshes
    empty_cache.cached_mesh("a", tri(1))
    empty_cache.cached_mesh("b", tri(2))
    empty_cache.cached_mesh("a", tri(99))  # a hit: "a" becomes the most recent
    empty_cache.cached_mesh("c", tri(3))  # evicts "b"
    assert empty_cache.cached_mesh("a", tri(99)).vertices[0, 0] == 1
    assert empty_cache.cached_mesh("b", tri(4)).vertices[0, 0] == 4  # rebuilt
    assert empty_cache.mesh_cache_info()["entries"] == 2 and empty_cache.mesh_cache_info()["bytes"] == 96
    monkeypatch.setattr(empty_cache, "MESH_CACHE_BYTES", 0)  # off: nothing new is stored
    empty_cache.clear_mesh_cache()
    empty_cache.cached_mesh("d", tri(5))
    assert empty_cache.mesh_cache_info()["entries"] == 0


def test_file_key_follows_the_file(tmp_path):
    from warpscatter.scene.meshes import file_key

    path = tmp_path / "m.obj"
    assert file_key(path) is None
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    key = file_key(path)
    assert key == file_key(str(path)) and key[1] == str(path)
    path.write_text("v 0 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\n")  # same size, new content: times change
    os.utime(path, ns=(1, 1))  # even with an old modification time the change time differs
    assert file_key(path) != key


def _scene_config(tmp_path, meshes):
    from warpscatter.config import Config

    return Config.from_dict({"scene": {"meshes": meshes}, "camera": {"position": [0, 1, 5], "look_at": [0, 1, 0]},
                             "light": {"type": "directional", "direction": [0, -1, 0]}}, config_dir=tmp_path)


def test_build_scene_caches_meshes_and_returns_fresh_arrays(tmp_path, empty_cache):
    from warpscatter.scene import build_scene, load_entry_mesh
    from warpscatter.scene.procedural import canopy

    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    entries = [
        {"procedural": "canopy", "params": {"leaves": 50, "seed": 3}, "transform": {"rotate_deg": [0, 30, 0]}},
        {"procedural": "canopy", "params": {"leaves": 50, "seed": 3}},  # same generator, other transform
        {"path": "tri.obj", "transform": {"translate": [1, 2, 3]}},
    ]
    cfg = _scene_config(tmp_path, entries)
    first = build_scene(cfg)
    assert empty_cache.mesh_cache_info()["misses"] == 3
    turned = apply_transform(canopy(leaves=50, seed=3), transform_matrix(rotate_deg=[0, 30, 0]))
    expect = np.concatenate([turned.vertices, canopy(leaves=50, seed=3).vertices,
                             np.float32([[1, 2, 3], [2, 2, 3], [1, 3, 3]])])
    assert _bits(first.vertices) == _bits(expect)
    first.vertices[:] = 7.0  # the scene's arrays are its own ...
    first.triangles[:] = 0
    again = build_scene(cfg)
    assert empty_cache.mesh_cache_info()["hits"] == 3
    assert _bits(again.vertices) == _bits(expect)  # ... the cache is untouched
    assert again.vertices.flags.writeable and again.triangles.flags.writeable
    assert not load_entry_mesh(cfg.scene.meshes[0]).vertices.flags.writeable
    # a changed file is loaded again
    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nf 1 2 4\n")
    changed = build_scene(cfg)
    np.testing.assert_array_equal(changed.vertices[-1], [6, 7, 8])
    # other parameters are other meshes
    misses = empty_cache.mesh_cache_info()["misses"]
    for params in ({"leaves": 51, "seed": 3}, {"leaves": 50, "seed": 4}):
        build_scene(_scene_config(tmp_path, [{"procedural": "canopy", "params": params}]))
    assert empty_cache.mesh_cache_info()["misses"] == misses + 2
