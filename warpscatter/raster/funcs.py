"""Device building blocks of the rasterizer (:mod:`.rasterizer`): fixed-point snapping, edge functions and the fill
rule, packed depth keys, homogeneous clipping and the exact-edge tests.

Screen positions are snapped to :data:`SUBPIXEL_BITS` bits; int64 edge functions with the top-left rule hit every
centre of a closed surface exactly once. The z-buffer key ``(float32 bits of depth01) << 32 | triangle index``,
depth01 = clamp(0.5 z_ndc + 0.5, 0, 1), is resolved with ``wp.atomic_min`` (ties go to the lower index); depth peeling
keeps the smallest key above the previous layer's. Clipping is Sutherland-Hodgman against the near plane and the guard
band, interpolated from the inside vertex so that shared edges clip bitwise identically.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..runtime.device import module_options

module_options()

#: Sub-pixel precision of snapped screen positions (1/1024 pixel).
SUBPIXEL_BITS = 10
#: Guard band in pixels: snapped coordinates stay within +-2^28, int64 edge functions within +-2^59.
GUARD_BAND_PIXELS = 2**18
#: Largest accepted image width or height (keeps pixel centres inside the fixed-point range).
MAX_RESOLUTION = 2**16
#: Key of a texel that no fragment reached (the largest int64).
EMPTY_KEY = np.iinfo(np.int64).max

#: Boxes wider than this (pixels) are scanned span by span (:func:`edge_span`); narrower ones test every centre.
SPAN_MIN_PIXELS = 8

#: Exact-edge mode: bounding boxes widened by this many sub-pixels (1/8 pixel), more than any snapping error.
EXACT_MARGIN_SUBPIXELS = 128

_SPAN_MIN_PIXELS = wp.constant(wp.int64(SPAN_MIN_PIXELS))
_EXACT_MARGIN = wp.constant(wp.int64(EXACT_MARGIN_SUBPIXELS))
_EXACT_ALWAYS = wp.constant(wp.int64(1 << 60))  # edge tolerance: decide every centre on the exact edge
_FIXED_ONLY = wp.constant(wp.int64(-1))  # edge tolerance: the fixed-point test alone (no exact plane)
_SUBPIXEL_SCALE = wp.constant(wp.float64(float(1 << SUBPIXEL_BITS)))
_SUBPIXEL_BITS = wp.constant(wp.int64(SUBPIXEL_BITS))
_SUBPIXEL_STEP = wp.constant(wp.int64(1 << SUBPIXEL_BITS))
_SUBPIXEL_HALF = wp.constant(wp.int64(1 << (SUBPIXEL_BITS - 1)))
_EMPTY_KEY = wp.constant(wp.int64(EMPTY_KEY))

ClipPolygon = wp.types.matrix(shape=(8, 4), dtype=wp.float32)  # clipped polygon: <= 3 + 5 planes vertices
ClipSources = wp.types.vector(length=8, dtype=wp.int32)  # source vertex of each polygon vertex (-1: new)
ScreenPolygon = wp.types.matrix(shape=(8, 3), dtype=wp.float64)  # snapped (X, Y, z_ndc) of polygon vertices
ClipEdges = wp.types.vector(length=8, dtype=wp.int32)  # mesh edge under polygon edge k -> k+1 (see clip_triangle_edges)
EdgeTolerances = wp.types.vector(length=3, dtype=wp.int64)  # per edge of a screen triangle (exact-edge mode)

_OUT_NEAR = wp.constant(1)  # z < -w
_OUT_GUARD = wp.constant(2 | 4 | 8 | 16)  # outside the guard band on x or y
_OUT_VIEW = wp.constant(32 | 64 | 128 | 256)  # outside the viewport on x or y
_OUT_FAR = wp.constant(512)  # z > w
_OUT_INVALID = wp.constant(1024)  # non-finite, or w <= 0 inside the guard band (degenerate matrices only)




@wp.func
def pixel_center_ndc(i: int, j: int, width: int, height: int) -> wp.vec2:
    """NDC (x, y) of the centre of pixel (i, j), row j counted from the top."""
    x = 2.0 * (float(i) + 0.5) / float(width) - 1.0
    y = 1.0 - 2.0 * (float(j) + 0.5) / float(height)
    return wp.vec2(x, y)


@wp.func
def depth_key(z_ndc: float, tri: int) -> wp.int64:
    """Packed z-buffer key: float32 bits of depth01 = 0.5 z_ndc + 0.5 above the triangle index (smaller = nearer)."""
    d = 0.5 * z_ndc + 0.5
    if d <= 0.0:
        d = 0.0  # also turns -0.0 into +0.0, whose bits are the smallest
    d = wp.min(d, 1.0)
    bits = wp.cast(d, wp.uint32)
    return (wp.int64(bits) << wp.int64(32)) | wp.int64(tri)


@wp.func
def key_ndc_depth(key: wp.int64) -> float:
    """NDC depth in [-1, 1] stored in a packed key (+inf for the empty key)."""
    if key == _EMPTY_KEY:
        return wp.inf
    d = wp.cast(wp.uint32(key >> wp.int64(32)), wp.float32)
    return 2.0 * d - 1.0


@wp.func
def key_triangle(key: wp.int64) -> int:
    """Triangle index stored in a packed key (-1 for the empty key)."""
    if key == _EMPTY_KEY:
        return -1
    return int(key & wp.int64(0xFFFFFFFF))


@wp.func
def ndc_to_view_depth(z_ndc: float, p22: float, p23: float, p32: float, p33: float) -> float:
    """View-space distance -z (positive in front) from NDC depth, for OpenGL-style perspective or orthographic
    matrices: z = (p23 - p33 z_ndc) / (p32 z_ndc - p22), ``p22, p23, p32, p33`` the projection's [2][2], [2][3],
    [3][2], [3][3]; +inf for non-finite input."""
    if not wp.isfinite(z_ndc):
        return wp.inf
    return -(p23 - p33 * z_ndc) / (p32 * z_ndc - p22)


@wp.func
def edge_function(ax: wp.int64, ay: wp.int64, bx: wp.int64, by: wp.int64, px: wp.int64, py: wp.int64) -> wp.int64:
    """Fixed-point edge function of edge a -> b at p (y down): > 0 inside; exact in int64 within +-2^29."""
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


@wp.func
def top_left_bias(ax: wp.int64, ay: wp.int64, bx: wp.int64, by: wp.int64) -> wp.int64:
    """0 when edge a -> b owns the pixel centres lying exactly on it (top or left edge), else -1: as if the sample
    moved right and (infinitesimally less) down, so abutting triangles own a shared point once."""
    dx = bx - ax
    dy = by - ay
    if dy < wp.int64(0) or (dy == wp.int64(0) and dx > wp.int64(0)):
        return wp.int64(0)
    return wp.int64(-1)


@wp.func
def clip_outcode(v: wp.vec4, guard_x: float, guard_y: float) -> int:
    """Bit set of the clip planes (near, guard band, viewport, far) that clip-space vertex ``v`` lies outside."""
    x = v[0]
    y = v[1]
    z = v[2]
    w = v[3]
    code = int(0)
    if z < -w:
        code = code | 1
    if x > guard_x * w:
        code = code | 2
    if x < -guard_x * w:
        code = code | 4
    if y > guard_y * w:
        code = code | 8
    if y < -guard_y * w:
        code = code | 16
    if x > w:
        code = code | 32
    if x < -w:
        code = code | 64
    if y > w:
        code = code | 128
    if y < -w:
        code = code | 256
    if z > w:
        code = code | 512
    return code


@wp.func
def clip_polygon_plane(
    poly: ClipPolygon, src: ClipSources, n: int, plane: wp.vec4
) -> tuple[ClipPolygon, ClipSources, int]:
    """Sutherland-Hodgman: keep the part of a convex clip-space polygon where dot(plane, v) >= 0. ``src``: each
    vertex's mesh index (-1: made by clipping). Crossings are interpolated from the inside vertex (watertight)."""
    out, out_src, _edges, m = clip_polygon_plane_edges(poly, src, ClipEdges(), n, plane)
    return out, out_src, m


@wp.func
def clip_polygon_plane_edges(
    poly: ClipPolygon, src: ClipSources, edges: ClipEdges, n: int, plane: wp.vec4
) -> tuple[ClipPolygon, ClipSources, ClipEdges, int]:
    """:func:`clip_polygon_plane` that also carries ``edges``, the mesh edge (0..2, -1: clip plane) under each edge."""
    out = ClipPolygon()
    out_src = ClipSources()
    out_edges = ClipEdges()
    m = int(0)
    for k in range(n):
        k1 = (k + 1) % n
        a = poly[k]
        b = poly[k1]
        da = wp.dot(plane, a)
        db = wp.dot(plane, b)
        if da >= 0.0:
            out[m] = a
            out_src[m] = src[k]
            out_edges[m] = edges[k]  # a -> b, or a -> the crossing point, both on edge k
            m += 1
        if (da >= 0.0) != (db >= 0.0):
            if da >= 0.0:
                out[m] = a + (b - a) * (da / (da - db))
                out_edges[m] = -1  # leaving: the next polygon edge runs along the clip plane
            else:
                out[m] = b + (a - b) * (db / (db - da))
                out_edges[m] = edges[k]  # entering: the crossing point -> b lies on edge k
            out_src[m] = -1
            m += 1
    return out, out_src, out_edges, m


@wp.func
def snap_to_screen(v: wp.vec4, width: int, height: int) -> wp.vec3d:
    """Clip-space vertex (w > 0) -> (X, Y, z_ndc): X, Y screen position (y down) in fixed point,
    exact integers held in float64, rounded to 1 / 2^SUBPIXEL_BITS pixel."""
    w = wp.float64(v[3])
    inv_w = wp.float64(1.0) / w
    half = wp.float64(0.5)
    x = wp.round((wp.float64(v[0]) * inv_w * half + half) * wp.float64(width) * _SUBPIXEL_SCALE)
    y = wp.round((half - wp.float64(v[1]) * inv_w * half) * wp.float64(height) * _SUBPIXEL_SCALE)
    return wp.vec3d(x, y, wp.float64(v[2]) * inv_w)


@wp.func
def homogeneous_screen(c: wp.vec4d, width: int, height: int) -> wp.vec3d:
    """Homogeneous screen position (X W, Y W, W) of float64 clip coordinates, unrounded; the sign of
    ``dot(cross(h_u, h_v), (X_p, Y_p, 1))`` gives the side of edge u v a ray through p passes."""
    half = wp.float64(0.5)
    return wp.vec3d((half * c[0] + half * c[3]) * wp.float64(width) * _SUBPIXEL_SCALE,
                    (half * c[3] - half * c[1]) * wp.float64(height) * _SUBPIXEL_SCALE, c[3])


@wp.func
def clip_position(view_proj: wp.mat44d, q: wp.vec3) -> wp.vec4:
    """Clip coordinates of world point ``q``: the float64 product ``view_proj (q, 1)``, stored as float32."""
    c = view_proj * wp.vec4d(wp.float64(q[0]), wp.float64(q[1]), wp.float64(q[2]), wp.float64(1.0))
    return wp.vec4(float(c[0]), float(c[1]), float(c[2]), float(c[3]))


@wp.struct
class ProjectedVertices:
    """Vertex pass output, one entry per mesh vertex (see :func:`project_vertex`)."""

    clip: wp.array(dtype=wp.vec4)  # clip coordinates (float64 product, stored float32)
    screen: wp.array(dtype=wp.vec3d)  # snapped (X, Y, z_ndc); set only for vertices inside the guard band
    outcode: wp.array(dtype=wp.int32)  # clip planes the vertex lies outside (see clip_outcode)
    hom: wp.array(dtype=wp.vec3d)  # unrounded homogeneous screen position (see homogeneous_screen), float64
    dev: wp.array(dtype=wp.float64)  # bound on |snapped - unrounded| screen position (sub-pixels); inf: not snapped


@wp.func
def project_vertex(
    verts: ProjectedVertices,
    i: int,
    q: wp.vec3,
    view_proj: wp.mat44d,
    width: int,
    height: int,
    guard_x: float,
    guard_y: float,
):
    """Vertex pass for mesh vertex ``i``: clip coordinates, outcode, unrounded homogeneous position, and (inside the
    guard band) the snapped position with a bound on its error, so shared vertices are snapped once."""
    v = clip_position(view_proj, q)
    verts.clip[i] = v
    h = homogeneous_screen(view_proj * wp.vec4d(wp.float64(q[0]), wp.float64(q[1]), wp.float64(q[2]), wp.float64(1.0)),
                           width, height)
    verts.hom[i] = h
    dev = wp.float64(wp.inf)
    code = clip_outcode(v, guard_x, guard_y)
    if not (wp.isfinite(v[0]) and wp.isfinite(v[1]) and wp.isfinite(v[2]) and wp.isfinite(v[3])):
        code = _OUT_INVALID
    elif (code & _OUT_GUARD) == 0:
        if v[3] > 0.0:
            s = snap_to_screen(v, width, height)
            verts.screen[i] = s
            if h[2] > wp.float64(0.0):
                x = h[0] / h[2]
                y = h[1] / h[2]
                # the snapping error (1/1024-pixel rounding, float32 clip coordinates), plus float64 rounding
                dev = wp.max(wp.abs(s[0] - x), wp.abs(s[1] - y))
                dev += (wp.abs(x) + wp.abs(y)) * wp.float64(1.0e-12) + wp.float64(1.0e-3)
        else:
            code = code | _OUT_INVALID
    if not (dev < wp.float64(1.0e15)):
        dev = wp.float64(wp.inf)
    verts.dev[i] = dev
    verts.outcode[i] = code


@wp.struct
class RasterParams:
    """Per-pass rasterizer settings as kernels see them."""

    width: int
    height: int
    guard_x: float  # guard band half-extent in NDC x (|x| <= guard_x w after clipping)
    guard_y: float  # guard band half-extent in NDC y
    clip_near: int  # 1: clip at the near plane (z >= -w)
    clamp_depth: int  # 1: clamp depth to [-1, 1] instead of discarding beyond the far plane
    cull_backfaces: int  # 1: skip triangles clockwise in NDC
    count_mode: int  # 1: count fragments into `counts` instead of the depth test into `keys`
    peel: int  # 1: only keys strictly greater than `prev_keys` (depth peeling)
    exact_edges: int  # 1: centres near a mesh edge are decided on the unrounded positions (see rasterize_triangle_rows)


@wp.func
def exact_edge_plane(hu: wp.vec3d, hv: wp.vec3d, u: int, v: int, hw: wp.vec3d) -> wp.vec3d:
    """Exact-edge test of mesh edge (u, v) opposite w: the plane through the eye and the edge, oriented so that
    m . (X, Y, 1) > 0 on w's side; 0 for a triangle seen edge-on. Lower vertex index first, so the two triangles of
    the edge get the same plane up to sign (watertight)."""
    n = wp.cross(hu, hv)
    if v < u:
        n = wp.cross(hv, hu)
    side = wp.dot(n, hw)
    if side > wp.float64(0.0):
        return n
    if side < wp.float64(0.0):
        return -n
    return wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))


@wp.func
def triangle_edge_planes(verts: ProjectedVertices, ia: int, ib: int, ic: int) -> wp.mat33d:
    """Rows: the :func:`exact_edge_plane` of the edges opposite mesh vertices ``ia``, ``ib``, ``ic`` of a triangle."""
    ha = verts.hom[ia]
    hb = verts.hom[ib]
    hc = verts.hom[ic]
    m0 = exact_edge_plane(hb, hc, ib, ic, ha)
    m1 = exact_edge_plane(hc, ha, ic, ia, hb)
    m2 = exact_edge_plane(ha, hb, ia, ib, hc)
    return wp.mat33d(m0[0], m0[1], m0[2], m1[0], m1[1], m1[2], m2[0], m2[1], m2[2])


@wp.func
def exact_edge_inside(m: wp.vec3d, px: wp.float64, py: wp.float64) -> bool:
    """Whether screen point (px, py) lies on the inner side of plane ``m``; ties follow the top-left rule."""
    zero = wp.float64(0.0)
    o = m[0] * px + m[1] * py + m[2]
    if o != zero:
        return o > zero
    return m[0] > zero or (m[0] == zero and m[1] > zero)


@wp.func
def edge_tolerance(sa: wp.vec3d, sb: wp.vec3d, da: wp.float64, db: wp.float64) -> wp.int64:
    """Exact-edge mode: bound on |fixed-point - exact edge function| (|delta E| <= 2 d |p - sa|_1 + d |sb - sa|_1 +
    4 d^2) of edge ``sa``-``sb`` whose ends moved by at most ``da``, ``db``; beyond it the fixed-point sign is exact.
    Symmetric, so both triangles agree."""
    d = wp.max(da, db)
    l1 = wp.abs(sb[0] - sa[0]) + wp.abs(sb[1] - sa[1])
    t = wp.float64(4.0) * d * (l1 + wp.float64(8.0) * d + wp.float64(8.0)) + wp.float64(8.0)
    if not (t < wp.float64(1.0e18)):
        return _EXACT_ALWAYS
    return wp.int64(t) + wp.int64(1)


@wp.func
def triangle_crossing(t: int, verts: ProjectedVertices, triangles: wp.array2d(dtype=wp.int32), p: RasterParams) -> int:
    """Trivial reject of triangle ``t``: -1 when nothing can be drawn, else the clip planes it crosses (0: none)."""
    oa = verts.outcode[triangles[t, 0]]
    ob = verts.outcode[triangles[t, 1]]
    oc = verts.outcode[triangles[t, 2]]
    if ((oa | ob | oc) & _OUT_INVALID) != 0:
        return -1
    reject = _OUT_VIEW
    if p.clip_near != 0:
        reject = reject | _OUT_NEAR
    if p.clamp_depth == 0:
        reject = reject | _OUT_FAR
    if (oa & ob & oc & reject) != 0:
        return -1
    return (oa | ob | oc) & (_OUT_GUARD | (_OUT_NEAR * p.clip_near))


@wp.func
def clip_triangle_edges(
    t: int,
    verts: ProjectedVertices,
    triangles: wp.array2d(dtype=wp.int32),
    p: RasterParams,
    crossing: int,
) -> tuple[ScreenPolygon, ClipSources, ClipEdges, int]:
    """:func:`clip_triangle` with each polygon vertex's mesh vertex and the triangle edge under each polygon edge."""
    sp = ScreenPolygon()
    ia = triangles[t, 0]
    ib = triangles[t, 1]
    ic = triangles[t, 2]
    poly = ClipPolygon()
    src = ClipSources()
    edges = ClipEdges()
    poly[0] = verts.clip[ia]
    poly[1] = verts.clip[ib]
    poly[2] = verts.clip[ic]
    src[0] = ia
    src[1] = ib
    src[2] = ic
    edges[0] = 2  # a -> b: opposite c
    edges[1] = 0
    edges[2] = 1
    n = int(3)
    if (crossing & 1) != 0:  # near: z + w >= 0
        poly, src, edges, n = clip_polygon_plane_edges(poly, src, edges, n, wp.vec4(0.0, 0.0, 1.0, 1.0))
    if (crossing & 2) != 0:  # guard band: x <= guard_x w
        poly, src, edges, n = clip_polygon_plane_edges(poly, src, edges, n, wp.vec4(-1.0, 0.0, 0.0, p.guard_x))
    if (crossing & 4) != 0:  # -x <= guard_x w
        poly, src, edges, n = clip_polygon_plane_edges(poly, src, edges, n, wp.vec4(1.0, 0.0, 0.0, p.guard_x))
    if (crossing & 8) != 0:  # y <= guard_y w
        poly, src, edges, n = clip_polygon_plane_edges(poly, src, edges, n, wp.vec4(0.0, -1.0, 0.0, p.guard_y))
    if (crossing & 16) != 0:  # -y <= guard_y w
        poly, src, edges, n = clip_polygon_plane_edges(poly, src, edges, n, wp.vec4(0.0, 1.0, 0.0, p.guard_y))
    if n < 3:
        return sp, src, edges, 0
    # ---- snap: mesh vertices from the vertex pass, new vertices here (one call site each) ----
    for k in range(n):
        v = src[k]
        if v >= 0 and (verts.outcode[v] & _OUT_GUARD) == 0:
            sp[k] = verts.screen[v]
        else:
            if not (poly[k][3] > 0.0):
                return sp, src, edges, 0  # only reachable for degenerate matrices (vertex at the centre of projection)
            sp[k] = snap_to_screen(poly[k], p.width, p.height)
    return sp, src, edges, n


@wp.func
def clip_triangle(
    t: int,
    verts: ProjectedVertices,
    triangles: wp.array2d(dtype=wp.int32),
    p: RasterParams,
    crossing: int,
) -> tuple[ScreenPolygon, int]:
    """Clip mesh triangle ``t`` against the ``crossing`` planes (near, guard band) of :func:`triangle_crossing`:
    the snapped screen polygon and its vertex count (0: nothing left to draw)."""
    sp, src, edges, n = clip_triangle_edges(t, verts, triangles, p, crossing)
    return sp, n


@wp.func
def bbox_rows(xmin: wp.int64, xmax: wp.int64, ymin: wp.int64, ymax: wp.int64, p: RasterParams) -> wp.vec2i:
    """Image rows (first, last) with centres in the fixed-point box, clamped to the image; (0, -1) for none.
    Widened by :data:`EXACT_MARGIN_SUBPIXELS` in exact-edge mode."""
    if p.exact_edges != 0:
        xmin = xmin - _EXACT_MARGIN
        xmax = xmax + _EXACT_MARGIN
        ymin = ymin - _EXACT_MARGIN
        ymax = ymax + _EXACT_MARGIN
    i0 = int((xmin - _SUBPIXEL_HALF + _SUBPIXEL_STEP - wp.int64(1)) >> _SUBPIXEL_BITS)
    i1 = int((xmax - _SUBPIXEL_HALF) >> _SUBPIXEL_BITS)
    j0 = wp.max(int((ymin - _SUBPIXEL_HALF + _SUBPIXEL_STEP - wp.int64(1)) >> _SUBPIXEL_BITS), 0)
    j1 = wp.min(int((ymax - _SUBPIXEL_HALF) >> _SUBPIXEL_BITS), p.height - 1)
    if wp.max(i0, 0) > wp.min(i1, p.width - 1) or j0 > j1:
        return wp.vec2i(0, -1)
    return wp.vec2i(j0, j1)


@wp.func
def polygon_rows(sp: ScreenPolygon, n: int, p: RasterParams) -> wp.vec2i:
    """Image rows (first, last) a clipped screen polygon may cover, (0, -1) when empty."""
    if n < 3:
        return wp.vec2i(0, -1)
    xmin = wp.int64(sp[0][0])
    xmax = xmin
    ymin = wp.int64(sp[0][1])
    ymax = ymin
    for k in range(1, n):
        x = wp.int64(sp[k][0])
        y = wp.int64(sp[k][1])
        xmin = wp.min(xmin, x)
        xmax = wp.max(xmax, x)
        ymin = wp.min(ymin, y)
        ymax = wp.max(ymax, y)
    return bbox_rows(xmin, xmax, ymin, ymax, p)


@wp.func
def triangle_rows(t: int, verts: ProjectedVertices, triangles: wp.array2d(dtype=wp.int32), p: RasterParams) -> wp.vec2i:
    """Image rows (first, last) mesh triangle ``t`` may cover after rejection and clipping, (0, -1) for none."""
    crossing = triangle_crossing(t, verts, triangles, p)
    if crossing < 0:
        return wp.vec2i(0, -1)
    if crossing > 0:
        sp, n = clip_triangle(t, verts, triangles, p, crossing)
        return polygon_rows(sp, n, p)
    a = verts.screen[triangles[t, 0]]
    b = verts.screen[triangles[t, 1]]
    c = verts.screen[triangles[t, 2]]
    return bbox_rows(wp.int64(wp.min(a[0], wp.min(b[0], c[0]))), wp.int64(wp.max(a[0], wp.max(b[0], c[0]))),
                     wp.int64(wp.min(a[1], wp.min(b[1], c[1]))), wp.int64(wp.max(a[1], wp.max(b[1], c[1]))), p)
