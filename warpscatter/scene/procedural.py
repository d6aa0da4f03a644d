"""Procedural scenes: deterministic triangle-mesh generators named in configs (``procedural: colonnade``), taking
keyword parameters only and returning a :class:`TriangleMesh` in scene units (about metres), +Y up, on y = 0, centred
on the Y axis; solids face outwards, ``room_window`` inwards. Table and benchmark meshes: docs/design/shadows-scene.md.
"""

from __future__ import annotations

import functools
import inspect
import math
from collections.abc import Callable

import numpy as np

from .meshes import TriangleMesh, concatenate

GENERATORS: dict[str, Callable[..., TriangleMesh]] = {}
_ORIGINALS: dict[str, Callable[..., TriangleMesh]] = {}


def _int(name: str, value, lo: int, hi: int) -> int:
    """An integer in [lo, hi]; integral floats are accepted (YAML ``8.0``), bools are not."""
    ok = isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
    if not ok and isinstance(value, (float, np.floating)) and math.isfinite(value) and float(value).is_integer():
        ok = True
    if not ok:
        raise ValueError(f"parameter {name!r} must be an integer, got {value!r}")
    v = int(value)
    if not lo <= v <= hi:
        raise ValueError(f"parameter {name!r} must be in [{lo}, {hi}], got {v}")
    return v


def _float(name: str, value, lo: float | None = None, hi: float | None = None, open_lo: bool = True) -> float:
    """A finite real number; ``lo`` is exclusive unless ``open_lo`` is False, ``hi`` is inclusive."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"parameter {name!r} must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"parameter {name!r} must be finite, got {v}")
    if lo is not None and (v <= lo if open_lo else v < lo):
        raise ValueError(f"parameter {name!r} must be {'>' if open_lo else '>='} {lo}, got {v}")
    if hi is not None and v > hi:
        raise ValueError(f"parameter {name!r} must be <= {hi}, got {v}")
    return v


def _bool(name: str, value) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"parameter {name!r} must be true or false, got {value!r}")
    return bool(value)


def _floats(name: str, value, n: int, lo: float | None = 0.0) -> tuple[float, ...]:
    """``n`` finite numbers (each > lo when lo is given) from a list or tuple."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != n:
        raise ValueError(f"parameter {name!r} must be a list of {n} numbers, got {value!r}")
    return tuple(_float(f"{name}[{k}]", v, lo) for k, v in enumerate(value))


def _ints(name: str, value, n: int, lo: int, hi: int) -> tuple[int, ...]:
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != n:
        raise ValueError(f"parameter {name!r} must be a list of {n} integers, got {value!r}")
    return tuple(_int(f"{name}[{k}]", v, lo, hi) for k, v in enumerate(value))


def _seed(value) -> int:
    return _int("seed", value, 0, 2**63 - 1)



def quads_to_triangles(quads) -> np.ndarray:
    """Split (Q, 4) quads (a, b, c, d) into (2Q, 3) triangles (a, b, c), (a, c, d), keeping the winding."""
    q = np.asarray(quads, dtype=np.int64).reshape(-1, 4)
    return np.stack([q[:, [0, 1, 2]], q[:, [0, 2, 3]]], axis=1).reshape(-1, 3)


# corner k has bit 0/1/2 selecting hi for x/y/z; faces -X, +X, -Y, +Y, -Z, +Z, counter-clockwise from outside
_BOX_QUADS = np.array(
    [[0, 4, 6, 2], [1, 3, 7, 5], [0, 1, 5, 4], [2, 6, 7, 3], [0, 2, 3, 1], [4, 5, 7, 6]], dtype=np.int64
)


def box_quads(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (8, 3) float64, outward quads (6, 4) int64) of the box ``lo`` < ``hi`` (scene units); ValueError
    for an empty box."""
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    if lo.shape != (3,) or hi.shape != (3,) or not np.all(hi > lo):
        raise ValueError(f"box needs lo < hi componentwise, got lo={lo.tolist()} hi={hi.tolist()}")
    bits = (np.arange(8)[:, None] >> np.arange(3)[None, :]) & 1
    return np.where(bits == 1, hi, lo), _BOX_QUADS.copy()


def box(lo, hi) -> TriangleMesh:
    """Closed axis-aligned box from ``lo`` to ``hi`` (scene units): 8 vertices, 12 outward triangles."""
    v, q = box_quads(lo, hi)
    return TriangleMesh(v, quads_to_triangles(q))


def _boxes(lo: np.ndarray, hi: np.ndarray) -> TriangleMesh:
    """B boxes (corners (B, 3)) at once, the same mesh as concatenating :func:`box` of each."""
    bad = np.flatnonzero(~np.all(hi > lo, axis=1))
    if len(bad):
        box_quads(lo[bad[0]], hi[bad[0]])  # raises box()'s error
    bits = (np.arange(8)[:, None] >> np.arange(3)[None, :]) & 1
    vertices = np.where(bits[None] == 1, hi[:, None, :], lo[:, None, :])
    triangles = quads_to_triangles(_BOX_QUADS)[None] + 8 * np.arange(len(lo))[:, None, None]
    return TriangleMesh(vertices.reshape(-1, 3), triangles.reshape(-1, 3))


def _cylinders(radius: float, y0: float, y1: float, s: int, cx: np.ndarray, cz: np.ndarray,
               caps: bool = True) -> TriangleMesh:
    """P cylinders with axes at (cx[p], cz[p]) at once, the same mesh as concatenating :func:`cylinder` of each."""
    theta = 2.0 * np.pi * np.arange(s) / s
    ring = np.zeros((len(cx), s, 3))
    ring[:, :, 0] = cx[:, None] + radius * np.cos(theta)
    ring[:, :, 2] = cz[:, None] + radius * np.sin(theta)
    per = 2 * s + 2 if caps else 2 * s  # bottom ring, top ring, cap centres
    verts = np.empty((len(cx), per, 3))
    verts[:, :s] = ring + [0.0, y0, 0.0]
    verts[:, s : 2 * s] = ring + [0.0, y1, 0.0]
    k = np.arange(s)
    k1 = (k + 1) % s
    quads = np.stack([k, s + k, s + k1, k1], axis=1)
    tris = [quads_to_triangles(quads)]
    if caps:
        verts[:, 2 * s] = np.stack([cx, np.full(len(cx), y0), cz], axis=1)
        verts[:, 2 * s + 1] = np.stack([cx, np.full(len(cx), y1), cz], axis=1)
        cb, ct = 2 * s, 2 * s + 1
        tris.append(np.stack([np.full(s, cb), k, k1], axis=1))
        tris.append(np.stack([np.full(s, ct), s + k1, s + k], axis=1))
    triangles = np.concatenate(tris)[None] + per * np.arange(len(cx))[:, None, None]
    return TriangleMesh(verts.reshape(-1, 3), triangles.reshape(-1, 3))


def cylinder(radius: float, y0: float, y1: float, segments: int, center_xz=(0.0, 0.0), caps: bool = True):
    """Vertical cylinder (axis parallel to +Y, at ``center_xz`` = (x, z)) from height ``y0`` to ``y1`` (> y0): a prism
    with ``segments`` (>= 3) sides whose vertices lie on the ring of ``radius`` (scene units); ``caps`` closes the ends
    with triangle fans around a centre vertex."""
    if not (radius > 0.0 and y1 > y0 and segments >= 3):
        raise ValueError(f"cylinder needs radius > 0, y1 > y0, segments >= 3; got {radius}, {y0}, {y1}, {segments}")
    cx, cz = np.array([center_xz[0]], np.float64), np.array([center_xz[1]], np.float64)
    return _cylinders(radius, y0, y1, int(segments), cx, cz, caps)


def _height_grid(size: float, n: int, heights: np.ndarray | None = None) -> TriangleMesh:
    """(n+1)^2 vertex grid over [-size/2, size/2]^2 in x-z facing +Y; vertex (i, j) at heights[j, i] (or 0)."""
    c = np.linspace(-0.5 * size, 0.5 * size, n + 1)
    x, z = np.meshgrid(c, c, indexing="xy")
    y = np.zeros_like(x) if heights is None else heights
    verts = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="xy")
    a = (j * (n + 1) + i).ravel()
    quads = np.stack([a, a + n + 1, a + n + 2, a + 1], axis=1)
    return TriangleMesh(verts, quads_to_triangles(quads))



def _generator(fn: Callable[..., TriangleMesh]) -> Callable[..., TriangleMesh]:
    """Register ``fn`` in GENERATORS behind a wrapper that rejects positional and unknown parameters."""
    names = list(inspect.signature(fn).parameters)

    @functools.wraps(fn)
    def wrapper(*args, **params) -> TriangleMesh:
        if args:
            raise ValueError(f"{fn.__name__} takes keyword parameters only, got {len(args)} positional")
        unknown = sorted(set(params) - set(names))
        if unknown:
            raise ValueError(f"{fn.__name__}: unknown parameter {unknown[0]!r} (parameters: {', '.join(names)})")
        return fn(**params)

    GENERATORS[fn.__name__] = wrapper
    _ORIGINALS[fn.__name__] = fn
    return wrapper


def generator_names() -> list[str]:
    """Names of all registered generators, in registration order."""
    return list(GENERATORS)


def _lookup(name: str) -> Callable[..., TriangleMesh]:
    if name not in GENERATORS:
        raise ValueError(f"unknown procedural generator {name!r} (available: {', '.join(GENERATORS)})")
    return _ORIGINALS[name]


def describe(name: str) -> str:
    """One-line description ``name(param: type = default, ...): first docstring line`` of a generator."""
    fn = _lookup(name)
    parts = []
    for p in inspect.signature(fn).parameters.values():
        ann = p.annotation if isinstance(p.annotation, str) else getattr(p.annotation, "__name__", str(p.annotation))
        parts.append(f"{p.name}: {ann} = {p.default!r}")
    doc = (inspect.getdoc(fn) or "").strip().splitlines()
    return f"{name}({', '.join(parts)}): {doc[0] if doc else ''}"


def _canonical(value):
    """Hashable stand-in for a parameter value, equal only for the same type and repr (1, 1.0, True differ)."""
    if isinstance(value, dict):
        return ("dict", tuple(sorted((str(k), _canonical(v)) for k, v in value.items())))
    if isinstance(value, (list, tuple)):
        return (type(value).__name__, tuple(_canonical(v) for v in value))
    if value is None or isinstance(value, (bool, int, float, str, np.bool_, np.integer, np.floating)):
        return (type(value).__name__, repr(value))
    raise TypeError(f"no cache key for a {type(value).__name__}")


def generator_key(name: str, params: dict | None = None) -> tuple | None:
    """Cache key of ``GENERATORS[name](**params)``; None (not cached) for an unknown name or uncacheable values."""
    fn = GENERATORS.get(name)
    if fn is None:
        return None
    try:
        return ("procedural", name, fn, _canonical(dict(params or {})))
    except TypeError:
        return None


def generate(name: str, params: dict | None = None) -> TriangleMesh:
    """Build the mesh of generator ``name`` with keyword ``params``; ValueError names a bad generator or parameter."""
    _lookup(name)
    params = {} if params is None else params
    if not isinstance(params, dict):
        raise ValueError(f"params of {name!r} must be a mapping, got {type(params).__name__}")
    return GENERATORS[name](**params)



@_generator
def ground_plane(*, size: float = 40.0, subdivisions: int = 1) -> TriangleMesh:
    """Square ground in the plane y = 0, centred at the origin, facing +Y.

    Args:
        size: edge length in scene units (> 0).
        subdivisions: cells per edge (1..4096); 2 * subdivisions^2 triangles.
    """
    size = _float("size", size, 0.0)
    n = _int("subdivisions", subdivisions, 1, 4096)
    return _height_grid(size, n)


@_generator
def colonnade(
    *,
    pillars: int = 8,
    spacing: float = 2.0,
    radius: float = 0.3,
    height: float = 5.0,
    segments: int = 16,
    roof: bool = True,
    row_gap: float = 4.0,
    roof_thickness: float = 0.4,
) -> TriangleMesh:
    """Two rows of cylindrical pillars along X under an architrave and a slab roof (crepuscular-rays scene).

    Args:
        pillars: pillars per row (1..10000).
        spacing: axis-to-axis distance along X (> 2 radius), scene units.
        radius: pillar radius (> 0).
        height: pillar height (> 0).
        segments: sides per pillar (3..1024).
        roof: add the architraves and the roof slab (36 triangles).
        row_gap: distance between the two rows' axes (> 2 radius).
        roof_thickness: thickness of architrave and slab (> 0).
    """
    n = _int("pillars", pillars, 1, 10000)
    radius = _float("radius", radius, 0.0)
    spacing = _float("spacing", spacing, 2.0 * radius)
    height = _float("height", height, 0.0)
    s = _int("segments", segments, 3, 1024)
    roof = _bool("roof", roof)
    row_gap = _float("row_gap", row_gap, 2.0 * radius)
    t = _float("roof_thickness", roof_thickness, 0.0)

    xs = (np.arange(n) - 0.5 * (n - 1)) * spacing
    rows = np.array([-0.5 * row_gap, 0.5 * row_gap])
    pillars = _cylinders(radius, 0.0, height, s, np.tile(xs, 2), np.repeat(rows, n))
    if not roof:
        return pillars
    x0, x1 = xs[0] - 0.5 * spacing, xs[-1] + 0.5 * spacing
    parts = [pillars]
    for z in (-0.5 * row_gap, 0.5 * row_gap):
        parts.append(box([x0, height, z - 1.3 * radius], [x1, height + t, z + 1.3 * radius]))
    zr = 0.5 * row_gap + 1.5 * radius
    parts.append(box([x0, height + t, -zr], [x1, height + 2.0 * t, zr]))
    return concatenate(parts)[0]


@_generator
def fence(
    *,
    posts: int = 12,
    slats: int = 5,
    gap: float = 0.08,
    height: float = 1.8,
    post_spacing: float = 1.5,
    post_width: float = 0.12,
    slat_thickness: float = 0.03,
    rails: int = 2,
) -> TriangleMesh:
    """Slatted fence along X in the plane z = 0: square posts, vertical slats separated by gaps, and rails.

    Args:
        posts: number of posts (2..10000).
        slats: boards per bay (0..1000).
        gap: clear width between boards (> 0), scene units; the board width follows from the bay width.
        height: post height (> 0).
        post_spacing: post axis distance (> post_width).
        post_width: square post cross-section (> 0).
        slat_thickness: board thickness along Z (> 0).
        rails: horizontal rails (0..100), 0.08 high and 0.04 deep, evenly spread over the height.
    """
    n = _int("posts", posts, 2, 10000)
    m = _int("slats", slats, 0, 1000)
    gap = _float("gap", gap, 0.0)
    height = _float("height", height, 0.0)
    post_width = _float("post_width", post_width, 0.0)
    post_spacing = _float("post_spacing", post_spacing, post_width)
    thick = _float("slat_thickness", slat_thickness, 0.0)
    rails = _int("rails", rails, 0, 100)

    clear = post_spacing - post_width
    board = (clear - (m + 1) * gap) / m if m > 0 else 0.0
    if m > 0 and board <= 0.0:
        raise ValueError(
            f"parameter 'gap' = {gap} leaves no room for {m} slats in a bay {clear:.4g} wide "
            f"(need gap < {clear / (m + 1):.4g})"
        )
    rail_h = 0.08
    if rails > 0 and height / (rails + 1) <= rail_h:
        raise ValueError(f"parameter 'rails' = {rails} does not fit in height {height}")
    xs = (np.arange(n) - 0.5 * (n - 1)) * post_spacing
    hw = 0.5 * post_width

    def corners(x, y, z) -> np.ndarray:
        x, y, z = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64), np.asarray(z, np.float64))
        return np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)

    lo = [corners(xs - hw, 0.0, -hw)]
    hi = [corners(xs + hw, height, hw)]
    if m > 0:
        bx = (xs[:-1, None] + hw + gap + np.arange(m)[None, :] * (board + gap)).ravel()
        lo.append(corners(bx, 0.06 * height, -0.5 * thick))
        hi.append(corners(bx + board, 0.94 * height, 0.5 * thick))
    if rails > 0:
        yc = height * (np.arange(rails) + 1) / (rails + 1)
        lo.append(corners(xs[0] + hw, yc - 0.5 * rail_h, 0.5 * thick))
        hi.append(corners(xs[-1] - hw, yc + 0.5 * rail_h, 0.5 * thick + 0.04))
    return _boxes(np.concatenate(lo), np.concatenate(hi))


@_generator
def canopy(
    *,
    leaves: int = 4000,
    radius: float = 3.0,
    trunk_height: float = 3.0,
    seed: int = 0,
    leaf_size: float = 0.25,
    crown_ratio: float = 0.7,
    clusters: int = 40,
    cluster_radius: float = 0.8,
    trunk_radius: float = 0.2,
    trunk_segments: int = 12,
) -> TriangleMesh:
    """A tree: trunk cylinder plus many small randomly oriented square leaf cards clumped in a crown ellipsoid.

    Args:
        leaves: number of leaf cards (0..10,000,000).
        radius: horizontal crown semi-axis (> 0), scene units.
        trunk_height: height of the crown bottom (> 0).
        seed: random seed (>= 0); equal seeds give equal meshes.
        leaf_size: leaf edge length (> 0).
        crown_ratio: vertical / horizontal crown semi-axis (> 0).
        clusters: number of leaf clumps (0..100000).
        cluster_radius: clump radius (> 0).
        trunk_radius: trunk radius (> 0).
        trunk_segments: trunk sides (3..1024).

    Returns:
        The trunk's 4 * trunk_segments triangles, then two per leaf.
    """
    nl = _int("leaves", leaves, 0, 10_000_000)
    radius = _float("radius", radius, 0.0)
    trunk_height = _float("trunk_height", trunk_height, 0.0)
    rng = np.random.default_rng(_seed(seed))
    leaf_size = _float("leaf_size", leaf_size, 0.0)
    crown_ratio = _float("crown_ratio", crown_ratio, 0.0)
    nc = _int("clusters", clusters, 0, 100_000)
    cluster_radius = _float("cluster_radius", cluster_radius, 0.0)
    trunk_radius = _float("trunk_radius", trunk_radius, 0.0)
    ts = _int("trunk_segments", trunk_segments, 3, 1024)

    semi = np.array([radius, crown_ratio * radius, radius])
    centre = np.array([0.0, trunk_height + semi[1], 0.0])
    trunk = cylinder(trunk_radius, 0.0, centre[1], ts)
    if nl == 0:
        return trunk

    def in_ball(count: int) -> np.ndarray:
        d = rng.normal(size=(count, 3))
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        return d * rng.random((count, 1)) ** (1.0 / 3.0)

    if nc == 0:
        pos = centre + in_ball(nl) * semi
    else:
        shrunk = np.maximum(semi - cluster_radius, 0.25 * semi)
        centres = centre + in_ball(nc) * shrunk
        pos = centres[rng.integers(0, nc, size=nl)] + in_ball(nl) * cluster_radius
    normal = rng.normal(size=(nl, 3))
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    helper = np.where(np.abs(normal[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u0 = np.cross(normal, helper)
    u0 /= np.linalg.norm(u0, axis=1, keepdims=True)
    v0 = np.cross(normal, u0)
    phi = rng.random((nl, 1)) * 2.0 * np.pi
    u = np.cos(phi) * u0 + np.sin(phi) * v0
    v = np.cross(normal, u)
    h = 0.5 * leaf_size
    hu, hv = h * u, h * v
    nt = trunk.num_vertices
    vertices = np.empty((nt + 4 * nl, 3), dtype=np.float32)
    vertices[:nt] = trunk.vertices
    corners = vertices[nt:].reshape(nl, 4, 3)
    corners[:, 0] = pos - hu - hv
    corners[:, 1] = pos + hu - hv
    corners[:, 2] = pos + hu + hv
    corners[:, 3] = pos - hu + hv
    leaf_triangles = quads_to_triangles(np.arange(nt, nt + 4 * nl).reshape(nl, 4))
    return TriangleMesh(vertices, np.concatenate([trunk.triangles, leaf_triangles]))


@_generator
def room_window(
    *,
    size: tuple = (8.0, 4.0, 8.0),
    window: tuple = (2.0, 1.6),
    window_center: tuple = (0.0, 2.2),
    panes: tuple = (1, 1),
    mullion: float = 0.08,
) -> TriangleMesh:
    """Closed box room, faces pointing inwards, with a rectangular window opening in its -Z wall.

    The walls share one lattice of grid lines, so the mesh has no cracks or T-junctions.

    Args:
        size: (W, H, D) room extent, each > 0, scene units.
        window: (width, height) of the opening, each > 0, strictly inside the wall.
        window_center: (x, y) of the opening's centre on the -Z wall.
        panes: (columns, rows) of panes (1..64 each).
        mullion: width of the strips between panes (> 0; unused with one pane).
    """
    W, H, D = _floats("size", size, 3)
    ww, wh = _floats("window", window, 2)
    cx, cy = _floats("window_center", window_center, 2, lo=None)
    pc, pr = _ints("panes", panes, 2, 1, 64)
    mul = _float("mullion", mullion, 0.0)
    if not (abs(cx) + 0.5 * ww < 0.5 * W and cy - 0.5 * wh > 0.0 and cy + 0.5 * wh < H):
        raise ValueError(
            f"parameter 'window' {ww} x {wh} centred at window_center ({cx}, {cy}) must lie strictly inside the "
            f"-Z wall x in ({-0.5 * W}, {0.5 * W}), y in (0, {H})"
        )
    pane_w = (ww - (pc - 1) * mul) / pc
    pane_h = (wh - (pr - 1) * mul) / pr
    if pane_w <= 0.0 or pane_h <= 0.0:
        raise ValueError(f"parameter 'mullion' = {mul} leaves no opening for {pc} x {pr} panes in the window")

    def lines(lo_edge: float, hi_edge: float, start: float, pane: float, count: int) -> np.ndarray:
        inner = []
        for k in range(count):
            a = start + k * (pane + mul)
            inner += [a, a + pane]
        return np.array([lo_edge, *inner, hi_edge])

    xl = lines(-0.5 * W, 0.5 * W, cx - 0.5 * ww, pane_w, pc)
    yl = lines(0.0, H, cy - 0.5 * wh, pane_h, pr)
    zl = np.array([-0.5 * D, 0.5 * D])
    nx, ny = len(xl), len(yl)

    def vid(i, j, k):
        return i + nx * (j + ny * k)

    quads, normals = [], []

    def wall(axis: int, fixed: int, inward: float, skip=None):
        """Quads of the wall at lattice index ``fixed`` along ``axis``, cells where ``skip(a, b)`` left out."""
        other = [a for a in range(3) if a != axis]
        counts = [nx, ny, 2]
        a, b = np.meshgrid(np.arange(counts[other[0]] - 1), np.arange(counts[other[1]] - 1), indexing="ij")
        a, b = a.ravel(), b.ravel()
        if skip is not None:
            keep = ~skip(a, b)
            a, b = a[keep], b[keep]
        corner = []
        for da, db in ((0, 0), (1, 0), (1, 1), (0, 1)):
            idx = [0, 0, 0]
            idx[axis], idx[other[0]], idx[other[1]] = fixed, a + da, b + db
            corner.append(vid(*idx))
        quads.append(np.stack(corner, axis=1))
        n = np.zeros((len(a), 3))
        n[:, axis] = inward
        normals.append(n)

    def is_pane(i, j):
        return (1 <= i) & (i <= 2 * pc - 1) & (i % 2 == 1) & (1 <= j) & (j <= 2 * pr - 1) & (j % 2 == 1)

    wall(2, 0, +1.0, skip=is_pane)  # the window wall
    wall(2, 1, -1.0)
    wall(0, 0, +1.0)
    wall(0, nx - 1, -1.0)
    wall(1, 0, +1.0)
    wall(1, ny - 1, -1.0)

    gx, gy, gz = np.meshgrid(xl, yl, zl, indexing="ij")
    lattice = np.zeros((nx * ny * 2, 3))
    ii, jj, kk = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(2), indexing="ij")
    lattice[vid(ii, jj, kk).ravel()] = np.stack([gx, gy, gz], axis=-1).reshape(-1, 3)
    quads = np.concatenate(quads).astype(np.int64)
    # orient each quad's (b - a) x (c - a) along its inward normal
    p = lattice[quads]
    facing = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), np.concatenate(normals))
    quads[facing < 0] = quads[facing < 0][:, ::-1]
    used, remap = np.unique(quads, return_inverse=True)
    return TriangleMesh(lattice[used], quads_to_triangles(remap.reshape(-1, 4)))


@_generator
def terrain(*, size: float = 40.0, resolution: int = 128, amplitude: float = 2.0, seed: int = 0) -> TriangleMesh:
    """Rolling height-field terrain: a square grid displaced by a sum of random sinusoids (smooth noise).

    8 waves of random direction and phase, wavelengths ``size`` / 0.8 to ``size`` / 12, amplitude in proportion.

    Args:
        size: edge length (> 0), scene units.
        resolution: cells per edge (1..4096); 2 * resolution^2 triangles (710 gives 1,008,200).
        amplitude: largest |height| (>= 0).
        seed: random seed (>= 0).
    """
    size = _float("size", size, 0.0)
    n = _int("resolution", resolution, 1, 4096)
    amplitude = _float("amplitude", amplitude, 0.0, open_lo=False)
    rng = np.random.default_rng(_seed(seed))
    waves = 8
    wavelength = size / np.geomspace(0.8, 12.0, waves)
    angle = rng.random(waves) * 2.0 * np.pi
    phase = rng.random(waves) * 2.0 * np.pi
    weight = wavelength / wavelength[0] * (0.6 + 0.8 * rng.random(waves))
    c = np.linspace(-0.5 * size, 0.5 * size, n + 1)
    h = np.zeros((n + 1, n + 1))  # [z, x]
    for k in range(waves):
        kx, kz = 2.0 * np.pi * np.cos(angle[k]) / wavelength[k], 2.0 * np.pi * np.sin(angle[k]) / wavelength[k]
        # sin(kx x + kz z + p) split into outer products
        h += weight[k] * (
            np.outer(np.cos(kz * c + phase[k]), np.sin(kx * c)) + np.outer(np.sin(kz * c + phase[k]), np.cos(kx * c))
        )
    peak = np.abs(h).max()
    h = h * (amplitude / peak) if peak > 0.0 else h
    return _height_grid(size, n, h)
