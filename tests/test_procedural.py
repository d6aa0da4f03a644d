"""Tests of warpscatter.scene.procedural (the named mesh generators) and of the bundled assets built from them."""

import importlib.util
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from warpscatter.scene import procedural as P
from warpscatter.scene.meshes import TriangleMesh, concatenate, load_mesh

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
    from warpscatter.io.images import read_image

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


# ---- vectorised generators: the same meshes as the part-by-part construction they replaced ------------------------


def _ref_cylinder(radius, y0, y1, s, center_xz, caps=True):
    theta = 2.0 * np.pi * np.arange(s) / s
    ring = np.stack([center_xz[0] + radius * np.cos(theta), np.zeros(s), center_xz[1] + radius * np.sin(theta)], 1)
    k = np.arange(s)
    k1 = (k + 1) % s
    tris = [P.quads_to_triangles(np.stack([k, s + k, s + k1, k1], axis=1))]
    verts = [ring + [0.0, y0, 0.0], ring + [0.0, y1, 0.0]]
    if caps:
        verts.append(np.array([[center_xz[0], y0, center_xz[1]], [center_xz[0], y1, center_xz[1]]]))
        tris.append(np.stack([np.full(s, 2 * s), k, k1], axis=1))
        tris.append(np.stack([np.full(s, 2 * s + 1), s + k1, s + k], axis=1))
    return TriangleMesh(np.concatenate(verts), np.concatenate(tris))


def _ref_colonnade(pillars=8, spacing=2.0, radius=0.3, height=5.0, segments=16, roof=True, row_gap=4.0,
                   roof_thickness=0.4):
    xs = (np.arange(pillars) - 0.5 * (pillars - 1)) * spacing
    parts = [_ref_cylinder(radius, 0.0, height, segments, (x, z)) for z in (-0.5 * row_gap, 0.5 * row_gap) for x in xs]
    if roof:
        t = roof_thickness
        x0, x1 = xs[0] - 0.5 * spacing, xs[-1] + 0.5 * spacing
        for z in (-0.5 * row_gap, 0.5 * row_gap):
            parts.append(P.box([x0, height, z - 1.3 * radius], [x1, height + t, z + 1.3 * radius]))
        zr = 0.5 * row_gap + 1.5 * radius
        parts.append(P.box([x0, height + t, -zr], [x1, height + 2.0 * t, zr]))
    return concatenate(parts)[0]


def _ref_fence(posts=12, slats=5, gap=0.08, height=1.8, post_spacing=1.5, post_width=0.12, slat_thickness=0.03,
               rails=2):
    board = (post_spacing - post_width - (slats + 1) * gap) / slats if slats > 0 else 0.0
    xs = (np.arange(posts) - 0.5 * (posts - 1)) * post_spacing
    hw, thick, rail_h = 0.5 * post_width, slat_thickness, 0.08
    parts = [P.box([x - hw, 0.0, -hw], [x + hw, height, hw]) for x in xs]
    for x in xs[:-1]:
        for k in range(slats):
            bx = x + hw + gap + k * (board + gap)
            parts.append(P.box([bx, 0.06 * height, -0.5 * thick], [bx + board, 0.94 * height, 0.5 * thick]))
    for r in range(rails):
        yc = height * (r + 1) / (rails + 1)
        parts.append(P.box([xs[0] + hw, yc - 0.5 * rail_h, 0.5 * thick],
                           [xs[-1] - hw, yc + 0.5 * rail_h, 0.5 * thick + 0.04]))
    return concatenate(parts)[0]


def _ref_room_quads(nx, ny, pc, pr):
    """The room's wall quads and inward normals, cell by cell."""
    quads, normals = [], []

    def wall(axis, fixed, inward, skip=lambda a, b: False):
        other = [a for a in range(3) if a != axis]
        counts = [nx, ny, 2]
        for a in range(counts[other[0]] - 1):
            for b in range(counts[other[1]] - 1):
                if skip(a, b):
                    continue
                corner = []
                for da, db in ((0, 0), (1, 0), (1, 1), (0, 1)):
                    idx = [0, 0, 0]
                    idx[axis], idx[other[0]], idx[other[1]] = fixed, a + da, b + db
                    corner.append(idx[0] + nx * (idx[1] + ny * idx[2]))
                quads.append(corner)
                n = np.zeros(3)
                n[axis] = inward
                normals.append(n)

    def is_pane(i, j):
        return 1 <= i <= 2 * pc - 1 and i % 2 == 1 and 1 <= j <= 2 * pr - 1 and j % 2 == 1

    for args in ((2, 0, 1.0, is_pane), (2, 1, -1.0), (0, 0, 1.0), (0, nx - 1, -1.0), (1, 0, 1.0), (1, ny - 1, -1.0)):
        wall(*args)
    return np.array(quads, dtype=np.int64), np.array(normals)


@pytest.mark.parametrize(
    "params",
    [{}, {"pillars": 3, "segments": 5, "roof": False}, {"pillars": 1}, {"pillars": 12, "segments": 24, "row_gap": 5.0},
     {"pillars": 7, "segments": 3, "spacing": 1.1, "radius": 0.5, "height": 2.3, "row_gap": 1.01,
      "roof_thickness": 0.07}, {"pillars": 40, "segments": 31, "spacing": 0.9, "radius": 0.333}],
)
def test_colonnade_is_the_part_by_part_mesh(params):
    mesh, ref = P.colonnade(**params), _ref_colonnade(**params)
    assert mesh.vertices.tobytes() == ref.vertices.tobytes()  # bit for bit
    assert mesh.triangles.tobytes() == ref.triangles.tobytes()


@pytest.mark.parametrize(
    "params",
    [{}, {"posts": 3, "slats": 2, "rails": 0}, {"posts": 2, "slats": 0, "rails": 1},
     {"posts": 5, "slats": 1, "gap": 0.3},
     {"posts": 57, "slats": 13, "gap": 0.011, "height": 2.7, "post_spacing": 1.33, "post_width": 0.17,
      "slat_thickness": 0.021, "rails": 5}],
)
def test_fence_is_the_part_by_part_mesh(params):
    mesh, ref = P.fence(**params), _ref_fence(**params)
    assert mesh.vertices.tobytes() == ref.vertices.tobytes()
    assert mesh.triangles.tobytes() == ref.triangles.tobytes()


def test_cylinder_is_the_direct_construction():
    for args in ((0.7, -1.0, 2.5, 13, (0.3, -0.2)), (1.0, 0.0, 2.0, 64, (0.0, 0.0)), (0.25, 1.0, 1.5, 3, (-0.0, 4.0))):
        for caps in (True, False):
            mesh, ref = P.cylinder(*args, caps=caps), _ref_cylinder(*args, caps=caps)
            assert mesh.vertices.tobytes() == ref.vertices.tobytes()
            assert mesh.triangles.tobytes() == ref.triangles.tobytes()


def _ref_room_window(size=(8.0, 4.0, 8.0), window=(2.0, 1.6), window_center=(0.0, 2.2), panes=(1, 1), mullion=0.08):
    (W, H, D), (ww, wh), (cx, cy), (pc, pr) = size, window, window_center, panes
    pane_w, pane_h = (ww - (pc - 1) * mullion) / pc, (wh - (pr - 1) * mullion) / pr

    def lines(lo_edge, hi_edge, start, pane, count):
        inner = []
        for k in range(count):
            a = start + k * (pane + mullion)
            inner += [a, a + pane]
        return np.array([lo_edge, *inner, hi_edge])

    xl, yl = lines(-0.5 * W, 0.5 * W, cx - 0.5 * ww, pane_w, pc), lines(0.0, H, cy - 0.5 * wh, pane_h, pr)
    zl = np.array([-0.5 * D, 0.5 * D])
    nx, ny = len(xl), len(yl)
    quads, normals = _ref_room_quads(nx, ny, pc, pr)
    gx, gy, gz = np.meshgrid(xl, yl, zl, indexing="ij")
    lattice = np.zeros((nx * ny * 2, 3))
    ii, jj, kk = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(2), indexing="ij")
    lattice[(ii + nx * (jj + ny * kk)).ravel()] = np.stack([gx, gy, gz], axis=-1).reshape(-1, 3)
    p = lattice[quads]
    facing = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), normals)
    quads[facing < 0] = quads[facing < 0][:, ::-1]
    used, remap = np.unique(quads, return_inverse=True)
    return TriangleMesh(lattice[used], P.quads_to_triangles(remap.reshape(-1, 4)))


@pytest.mark.parametrize(
    "params",
    [{}, {"panes": (3, 2)}, {"panes": (16, 12), "mullion": 0.02},
     {"size": (6.0, 3.0, 5.0), "window": (2.0, 1.2), "window_center": (0.5, 1.6), "panes": (2, 3), "mullion": 0.1}],
)
def test_room_window_is_the_cell_by_cell_mesh(params):
    mesh, ref = P.room_window(**params), _ref_room_window(**params)
    assert mesh.vertices.tobytes() == ref.vertices.tobytes()
    assert mesh.triangles.tobytes() == ref.triangles.tobytes()


def _ref_canopy(leaves=4000, radius=3.0, trunk_height=3.0, seed=0, leaf_size=0.25, crown_ratio=0.7, clusters=40,
                cluster_radius=0.8, trunk_radius=0.2, trunk_segments=12):
    rng = np.random.default_rng(seed)
    semi = np.array([radius, crown_ratio * radius, radius])
    centre = np.array([0.0, trunk_height + semi[1], 0.0])
    trunk = _ref_cylinder(trunk_radius, 0.0, centre[1], trunk_segments, (0.0, 0.0))

    def in_ball(count):
        d = rng.normal(size=(count, 3))
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        return d * rng.random((count, 1)) ** (1.0 / 3.0)

    if clusters == 0:
        pos = centre + in_ball(leaves) * semi
    else:
        centres = centre + in_ball(clusters) * np.maximum(semi - cluster_radius, 0.25 * semi)
        pos = centres[rng.integers(0, clusters, size=leaves)] + in_ball(leaves) * cluster_radius
    normal = rng.normal(size=(leaves, 3))
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    helper = np.where(np.abs(normal[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u0 = np.cross(normal, helper)
    u0 /= np.linalg.norm(u0, axis=1, keepdims=True)
    v0 = np.cross(normal, u0)
    phi = rng.random((leaves, 1)) * 2.0 * np.pi
    u = np.cos(phi) * u0 + np.sin(phi) * v0
    v = np.cross(normal, u)
    h = 0.5 * leaf_size
    corners = np.stack([pos - h * u - h * v, pos + h * u - h * v, pos + h * u + h * v, pos - h * u + h * v], axis=1)
    leaf_mesh = TriangleMesh(corners.reshape(-1, 3), P.quads_to_triangles(np.arange(4 * leaves).reshape(leaves, 4)))
    return concatenate([trunk, leaf_mesh])[0]


@pytest.mark.parametrize(
    "params",
    [{}, {"leaves": 37, "trunk_segments": 5, "clusters": 0}, {"leaves": 1, "seed": 9},
     {"leaves": 3000, "clusters": 7, "cluster_radius": 0.3, "radius": 2.0, "crown_ratio": 1.3, "trunk_radius": 0.1,
      "trunk_height": 1.5, "seed": 77}],
)
def test_canopy_is_the_concatenated_mesh(params):
    mesh, ref = P.canopy(**params), _ref_canopy(**params)
    assert mesh.vertices.tobytes() == ref.vertices.tobytes()
    assert mesh.triangles.tobytes() == ref.triangles.tobytes()


# ---- cache keys ------------------------------------------------------------------------------------------------------


def test_generator_key_is_exact():
    key = P.generator_key("canopy", {"leaves": 10, "seed": 2})
    assert key == P.generator_key("canopy", {"seed": 2, "leaves": 10})  # parameter order does not matter
    assert hash(key) == hash(P.generator_key("canopy", {"seed": 2, "leaves": 10}))
    assert P.generator_key("canopy", None) == P.generator_key("canopy", {})
    different = [
        P.generator_key("canopy", {"leaves": 10.0, "seed": 2}),  # 10.0 == 10 in Python, but another value here
        P.generator_key("canopy", {"leaves": 11, "seed": 2}),
        P.generator_key("terrain", {"leaves": 10, "seed": 2}),
    ]
    assert all(k is not None and k != key for k in different)
    assert P.generator_key("colonnade", {"roof": True}) != P.generator_key("colonnade", {"roof": 1})
    assert P.generator_key("room_window", {"window_center": [0.0, 2.0]}) != P.generator_key(
        "room_window", {"window_center": [-0.0, 2.0]})
    assert P.generator_key("room_window", {"panes": [2, 3]}) == P.generator_key("room_window", {"panes": [2, 3]})
    assert P.generator_key("tower", {}) is None  # unknown generator
    assert P.generator_key("canopy", {"leaves": object()}) is None  # not keyable: not cached
