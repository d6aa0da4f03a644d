"""Tests of warpscatter.scene.procedural (the named mesh generators) and of the bundled assets built from them."""

import importlib.util
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from warpscatter.scene import procedural as P
from warpscatter.scene.meshes import TriangleMesh, load_mesh

ROOT = Path(__file__).resolve().parents[1]


def _room_cells(panes):
    pc, pr = panes
    return 2 * pc + 1, 2 * pr + 1, 1  # lattice cells along x, y, z


def _room_triangles(panes):
    nx, ny, nz = _room_cells(panes)
    return 2 * (2 * nx * ny + 2 * ny * nz + 2 * nx * nz - panes[0] * panes[1])


# (generator, params, expected triangle count)
CASES = [
    ("ground_plane", {}, 2),
    ("ground_plane", {"size": 10, "subdivisions": 7}, 2 * 7**2),
    ("colonnade", {}, 2 * 8 * 4 * 16 + 36),
    ("colonnade", {"pillars": 3, "segments": 5, "roof": False}, 2 * 3 * 4 * 5),
    ("fence", {}, 12 * (12 + 11 * 5 + 2)),
    ("fence", {"posts": 3, "slats": 2, "rails": 0}, 12 * (3 + 2 * 2)),
    ("canopy", {}, 4 * 12 + 2 * 4000),
    ("canopy", {"leaves": 37, "trunk_segments": 5, "clusters": 0}, 4 * 5 + 2 * 37),
    ("room_window", {}, _room_triangles((1, 1))),
    ("room_window", {"panes": [3, 2]}, _room_triangles((3, 2))),
    ("terrain", {}, 2 * 128**2),
    ("terrain", {"resolution": 9, "size": 5}, 2 * 9**2),
]


def test_registry_and_descriptions():
    assert P.generator_names() == ["ground_plane", "colonnade", "fence", "canopy", "room_window", "terrain"]
    for name in P.generator_names():
        text = P.describe(name)
        assert text.startswith(f"{name}(") and "): " in text
        assert len(text.split("): ", 1)[1]) > 20  # the first docstring line follows
    assert "pillars: int = 8" in P.describe("colonnade")
    with pytest.raises(ValueError, match="unknown procedural generator 'tower'.*colonnade"):
        P.describe("tower")
    with pytest.raises(ValueError, match="unknown procedural generator"):
        P.generate("tower", {})
    assert P.generate("ground_plane", {"size": 2}).num_triangles == 2


@pytest.mark.parametrize(("name", "params", "triangles"), CASES)
def test_generator_counts_finite_and_deterministic(name, params, triangles):
    mesh = P.GENERATORS[name](**params)
    assert isinstance(mesh, TriangleMesh)
    assert mesh.num_triangles == triangles
    assert np.all(np.isfinite(mesh.vertices))
    assert mesh.triangles.min() >= 0 and mesh.triangles.max() < mesh.num_vertices
    assert np.all(np.linalg.norm(mesh.face_normals(), axis=1) > 0.99)  # no degenerate triangle
    again = P.GENERATORS[name](**params)
    np.testing.assert_array_equal(mesh.vertices, again.vertices)
    np.testing.assert_array_equal(mesh.triangles, again.triangles)


@pytest.mark.parametrize(
    ("name", "params", "named"),
    [
        ("ground_plane", {"sise": 3}, "sise"),
        ("ground_plane", {"size": -1}, "size"),
        ("ground_plane", {"subdivisions": 0}, "subdivisions"),
        ("colonnade", {"pillars": 2.5}, "pillars"),
        ("colonnade", {"roof": "yes"}, "roof"),
        ("colonnade", {"radius": 1.5}, "spacing"),  # pillars would overlap
        ("colonnade", {"segments": 2}, "segments"),
        ("fence", {"gap": 0.5}, "gap"),  # no room for 5 slats in a 1.38 m bay
        ("fence", {"posts": 1}, "posts"),
        ("canopy", {"leaves": -1}, "leaves"),
        ("canopy", {"seed": -3}, "seed"),
        ("canopy", {"leaf_size": float("nan")}, "leaf_size"),
        ("room_window", {"window": [10.0, 1.0]}, "window"),
        ("room_window", {"size": [8.0, 4.0]}, "size"),
        ("room_window", {"panes": [2, 2], "mullion": 1.7}, "mullion"),  # panes 1.6 m high in all
        ("terrain", {"resolution": 0}, "resolution"),
        ("terrain", {"amplitude": True}, "amplitude"),
    ],
)
def test_bad_parameters_are_named(name, params, named):
    with pytest.raises(ValueError, match=f"'{named}'"):
        P.GENERATORS[name](**params)


def test_positional_arguments_rejected():
    with pytest.raises(ValueError, match="keyword parameters only"):
        P.GENERATORS["terrain"](40.0)


def test_closed_parts_are_watertight_and_outward():
    for mesh, parts in ((P.colonnade(), 2 * 8 + 3), (P.fence(posts=4, slats=3), 4 + 3 * 3 + 2)):
        pieces = mesh.to_trimesh().split(only_watertight=False)
        assert len(pieces) == parts
        assert all(p.is_watertight and p.is_winding_consistent and p.volume > 0 for p in pieces)
    cyl = P.cylinder(1.0, 0.0, 2.0, 64)
    # a 64-gon prism: area of the polygon times height, 2 * 32 sin(2 pi / 64) = 3.13655
    assert cyl.to_trimesh().volume == pytest.approx(2.0 * 32 * np.sin(2 * np.pi / 64), rel=1e-6)
    lo, hi = P.colonnade(height=4.0, roof_thickness=0.25).bounds()
    assert hi[1] == pytest.approx(4.5) and lo[1] == 0.0


def test_sheets_face_up():
    for mesh in (P.ground_plane(subdivisions=3), P.terrain(resolution=16, amplitude=0.5)):
        assert np.all(mesh.face_normals()[:, 1] > 0.0)
    lo, hi = P.ground_plane(size=6).bounds()
    np.testing.assert_array_equal(lo, [-3, 0, -3])
    np.testing.assert_array_equal(hi, [3, 0, 3])


def _boundary_loops(mesh: TriangleMesh):
    """Edges used once (boundary) grouped into closed loops; also returns the use count of every undirected edge
    and whether every shared edge is traversed once in each direction (consistent winding)."""
    t = mesh.triangles
    directed = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    undirected = Counter(map(tuple, np.sort(directed, axis=1)))
    consistent = len(set(map(tuple, directed))) == len(directed)
    boundary = [e for e, n in undirected.items() if n == 1]
    adjacency = {}
    for a, b in boundary:
        adjacency.setdefault(a, []).append(b)
        adjacency.setdefault(b, []).append(a)
    loops, seen = [], set()
    for start in adjacency:
        if start in seen:
            continue
        loop, prev, cur = [start], None, start
        seen.add(start)
        while True:
            nxt = [v for v in adjacency[cur] if v != prev]
            if not nxt or nxt[0] == start:
                break
            prev, cur = cur, nxt[0]
            loop.append(cur)
            seen.add(cur)
        loops.append(loop)
    return loops, undirected, consistent, adjacency


@pytest.mark.parametrize("panes", [(1, 1), (2, 3)])
def test_room_window_closed_except_the_openings(panes):
    size, window, centre, mullion = (6.0, 3.0, 5.0), (2.0, 1.2), (0.5, 1.6), 0.1
    mesh = P.room_window(size=size, window=window, window_center=centre, panes=panes, mullion=mullion)
    loops, undirected, consistent, adjacency = _boundary_loops(mesh)
    assert consistent
    assert set(undirected.values()) == {1, 2}  # no edge shared by 3+ triangles, no T-junction edge
    assert all(len(n) == 2 for n in adjacency.values())  # boundary vertices have exactly 2 boundary edges
    assert len(loops) == panes[0] * panes[1]  # one loop around each pane opening
    for loop in loops:
        p = mesh.vertices[loop].astype(np.float64)
        assert len(loop) == 4  # a rectangle with no extra vertices on its sides
        np.testing.assert_allclose(p[:, 2], -0.5 * size[2])  # in the window wall
        assert (
            p[:, 0].min() >= centre[0] - 0.5 * window[0] - 1e-6 and p[:, 0].max() <= centre[0] + 0.5 * window[0] + 1e-6
        )
        assert (
            p[:, 1].min() >= centre[1] - 0.5 * window[1] - 1e-6 and p[:, 1].max() <= centre[1] + 0.5 * window[1] + 1e-6
        )
    # the openings cover the window minus the mullions
    pane_w = (window[0] - (panes[0] - 1) * mullion) / panes[0]
    pane_h = (window[1] - (panes[1] - 1) * mullion) / panes[1]
    box_area = 2 * (size[0] * size[1] + size[1] * size[2] + size[0] * size[2])
    assert mesh.to_trimesh().area == pytest.approx(box_area - panes[0] * panes[1] * pane_w * pane_h, rel=1e-6)
    # normals face the inside: a point a little along the normal from each face centre is inside the room
    centre_pts = mesh.triangle_vertices().mean(axis=1) + 0.01 * mesh.face_normals()
    half = np.array([0.5 * size[0], size[1], 0.5 * size[2]])
    assert np.all(np.abs(centre_pts[:, [0, 2]]) < half[[0, 2]]) and np.all(
        (centre_pts[:, 1] > 0) & (centre_pts[:, 1] < size[1])
    )


def test_canopy_leaves():
    leaves, ts, size = 500, 8, 0.3
    mesh = P.canopy(leaves=leaves, trunk_segments=ts, leaf_size=size, seed=4)
    assert (mesh.num_triangles - 4 * ts) // 2 == leaves
    leaf_tris = mesh.triangle_vertices()[4 * ts :].reshape(leaves, 2, 3, 3).astype(np.float64)
    # each leaf: two right triangles sharing the diagonal, edges of length leaf_size, together a square
    edges = np.linalg.norm(leaf_tris[:, 0, 1] - leaf_tris[:, 0, 0], axis=1)
    np.testing.assert_allclose(edges, size, rtol=1e-5)
    area = 0.5 * np.linalg.norm(
        np.cross(leaf_tris[:, :, 1] - leaf_tris[:, :, 0], leaf_tris[:, :, 2] - leaf_tris[:, :, 0]), axis=2
    )
    np.testing.assert_allclose(area.sum(axis=1), size**2, rtol=1e-5)
    # leaf centres lie in the crown ellipsoid grown by one cluster radius (+ half a leaf diagonal)
    c = 0.5 * (leaf_tris[:, 0, 0] + leaf_tris[:, 0, 2])  # midpoint of the diagonal
    semi = np.array([3.0, 2.1, 3.0]) + 0.8 + size
    inside = (((c - [0.0, 3.0 + 2.1, 0.0]) / semi) ** 2).sum(axis=1)
    assert inside.max() <= 1.0  # measured 0.46
    assert c[:, 1].min() > 3.0 - 0.8 - size  # above the trunk height minus a clump radius
    # orientations are spread over the sphere: mean |n . axis| is 1/2 for uniform directions (measured 0.495-0.508)
    n = P.canopy(leaves=4000).face_normals()[48::2]
    assert np.all(np.abs(np.abs(n).mean(axis=0) - 0.5) < 0.03)
    other = P.canopy(leaves=leaves, trunk_segments=ts, leaf_size=size, seed=5)
    assert not np.allclose(other.vertices, mesh.vertices)


def _side(u: np.ndarray, v: np.ndarray, p: np.ndarray) -> np.ndarray:
    """2-D cross product (v - u) x (p - u): its sign tells on which side of the edge u -> v the points lie."""
    return (v[:, 0] - u[:, 0]) * (p[..., 1] - u[:, 1]) - (v[:, 1] - u[:, 1]) * (p[..., 0] - u[:, 0])


def _blocked_along_z(mesh: TriangleMesh, points: np.ndarray) -> np.ndarray:
    """Whether a ray parallel to Z through each (x, y) point hits a triangle (2-D point-in-triangle test on the
    triangles' x-y projections, brute force)."""
    tri = mesh.triangle_vertices()[:, :, :2].astype(np.float64)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    blocked = np.zeros(len(points), bool)
    for k in range(0, len(points), 256):
        p = points[k : k + 256, None, :]

        s0, s1, s2 = _side(a, b, p), _side(b, c, p), _side(c, a, p)
        inside = ((s0 >= 0) & (s1 >= 0) & (s2 >= 0)) | ((s0 <= 0) & (s1 <= 0) & (s2 <= 0))
        blocked[k : k + 256] = inside.any(axis=1)
    return blocked


def test_canopy_crown_has_gaps():
    # Rays along Z through the inner 90% of the crown silhouette: the clumps leave gaps for shafts.
    # Measured pass fraction: 0.215 with the default 40 clusters, 0.000 with clusters=0 (uniform leaves).
    rng = np.random.default_rng(1)
    u = rng.random((3000, 2)) * 2 - 1
    u = u[(u**2).sum(axis=1) < 0.81]
    points = np.stack([3.0 * u[:, 0], 5.1 + 2.1 * u[:, 1]], axis=1)
    clumped = 1.0 - _blocked_along_z(P.canopy(clusters=40), points).mean()
    uniform = 1.0 - _blocked_along_z(P.canopy(clusters=0), points).mean()
    assert 0.1 < clumped < 0.35
    assert uniform < 0.02


def test_terrain_heights_and_benchmark_size():
    mesh = P.terrain(size=20.0, resolution=64, amplitude=1.5, seed=2)
    y = mesh.vertices[:, 1]
    assert np.abs(y).max() == pytest.approx(1.5, rel=1e-6)
    assert y.std() > 0.2 * 1.5  # not flat (measured std 0.48)
    grid = y.reshape(65, 65)
    # smooth: neighbouring heights (0.31 apart) differ by a small fraction of the 3.0 range (measured max 0.26)
    assert np.abs(np.diff(grid, axis=0)).max() < 0.35 and np.abs(np.diff(grid, axis=1)).max() < 0.35
    assert not np.allclose(P.terrain(resolution=16, seed=3).vertices, P.terrain(resolution=16, seed=4).vertices)
    assert np.all(P.terrain(resolution=8, amplitude=0.0).vertices[:, 1] == 0.0)
    big = P.terrain(resolution=710)
    assert big.num_triangles == 1_008_200 >= 1_000_000


# ---- bundled assets ------------------------------------------------------------------------------------------------


def test_bundled_gate_obj():
    mesh = load_mesh(ROOT / "assets" / "gate.obj")
    assert mesh.num_triangles == 324
    pieces = mesh.to_trimesh().split(only_watertight=False)
    assert len(pieces) == 27
    assert all(p.is_watertight and p.volume > 0 for p in pieces)
    lo, hi = mesh.bounds()
    np.testing.assert_allclose(lo, [-2.6, 0.0, -0.5], atol=1e-6)
    np.testing.assert_allclose(hi, [2.6, 5.65, 0.5], atol=1e-6)


def test_make_assets_reproduces_the_bundled_files(tmp_path):
    from warpscatter.imageio import read_image

    spec = importlib.util.spec_from_file_location("make_assets", ROOT / "assets" / "make_assets.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.main(["--out", str(tmp_path)]) == 0
    assert (tmp_path / "gate.obj").read_text() == (ROOT / "assets" / "gate.obj").read_text()
    for name, shape in (("light_cookie.png", (256, 256, 3)), ("sky_small.exr", (32, 64, 3))):
        fresh, bundled = read_image(tmp_path / name), read_image(ROOT / "assets" / name)
        assert bundled.shape == shape
        np.testing.assert_array_equal(fresh, bundled)
    total = sum((ROOT / "assets" / n).stat().st_size for n in ("gate.obj", "light_cookie.png", "sky_small.exr"))
    assert total < 300 * 1024  # measured 63 KiB
