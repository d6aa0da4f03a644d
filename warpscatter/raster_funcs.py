"""Device building blocks of the rasterizer (:mod:`warpscatter.raster`): fixed-point snapping, edge
functions and the fill rule, packed depth keys, homogeneous clipping, and the per-triangle scan.

Fixed point: screen positions are snapped to :data:`SUBPIXEL_BITS` sub-pixel bits, edge functions
are evaluated in int64 and the top-left fill rule decides pixel centres that lie exactly on an edge
or a vertex, as in GPU hardware rasterizers. Every pixel centre covered by a closed tessellated
surface is therefore hit exactly once: no cracks, no double hits.

Depth keys: the z-buffer stores a packed int64 key per texel,

    key = (float32 bits of depth01) << 32 | triangle index,   depth01 = clamp(0.5 z_ndc + 0.5, 0, 1),

resolved with ``wp.atomic_min``: exact and free of races, also on CUDA, and ties between triangles
at equal depth go to the lower triangle index. Depth peeling keeps, per layer, the smallest key
strictly greater than the previous layer's key.

Scan: :func:`rasterize_screen_triangle_rows` walks the rows of a triangle's bounding box (optionally a
band of them) and, in boxes wider than :data:`SPAN_MIN_PIXELS`, narrows each row to the exact span of
centres the three edge functions accept before visiting it (:func:`edge_span`); the fragments are those
of testing every centre of the box.

Clipping: :func:`clip_triangle` (for :func:`rasterize_triangle`) clips in homogeneous clip space against the near plane
(z >= -w) and a guard band on x and y (|x|, |y| <= g w, screen positions within
+-:data:`GUARD_BAND_PIXELS` pixels) with Sutherland-Hodgman; intersection points are always
interpolated from the inside vertex towards the outside vertex, so two triangles sharing an edge
produce bitwise identical clip vertices. The vertex pass (:func:`project_vertex`) computes each mesh
vertex's clip position, outcode and snapped screen position once, in a :class:`ProjectedVertices`.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .wpinit import module_options

module_options()

#: Sub-pixel precision of snapped screen positions (1/1024 pixel).
SUBPIXEL_BITS = 10
#: Screen positions after guard-band clipping stay within +-GUARD_BAND_PIXELS pixels, so snapped
#: coordinates stay within +-2^28 and every int64 edge function within +-2^59 (no overflow).
GUARD_BAND_PIXELS = 2**18
#: Largest accepted image width or height (keeps pixel centres inside the fixed-point range).
MAX_RESOLUTION = 2**16
#: Key of a texel that no fragment reached (the largest int64).
EMPTY_KEY = np.iinfo(np.int64).max

#: Bounding boxes wider than this many pixels are scanned row span by row span (:func:`edge_span`); narrower
#: ones test every centre (cheaper than the span's integer divisions for a few pixels).
SPAN_MIN_PIXELS = 8

_SPAN_MIN_PIXELS = wp.constant(wp.int64(SPAN_MIN_PIXELS))
_SUBPIXEL_SCALE = wp.constant(wp.float64(float(1 << SUBPIXEL_BITS)))
_SUBPIXEL_BITS = wp.constant(wp.int64(SUBPIXEL_BITS))
_SUBPIXEL_STEP = wp.constant(wp.int64(1 << SUBPIXEL_BITS))
_SUBPIXEL_HALF = wp.constant(wp.int64(1 << (SUBPIXEL_BITS - 1)))
_EMPTY_KEY = wp.constant(wp.int64(EMPTY_KEY))

ClipPolygon = wp.types.matrix(shape=(8, 4), dtype=wp.float32)  # clipped polygon: <= 3 + 5 planes vertices
ClipSources = wp.types.vector(length=8, dtype=wp.int32)  # source vertex of each polygon vertex (-1: new)
ScreenPolygon = wp.types.matrix(shape=(8, 3), dtype=wp.float64)  # snapped (X, Y, z_ndc) of polygon vertices

# Outcode bits of a clip-space vertex.
_OUT_NEAR = wp.constant(1)  # z < -w
_OUT_GUARD = wp.constant(2 | 4 | 8 | 16)  # outside the guard band on x or y
_OUT_VIEW = wp.constant(32 | 64 | 128 | 256)  # outside the viewport on x or y
_OUT_FAR = wp.constant(512)  # z > w
_OUT_INVALID = wp.constant(1024)  # non-finite, or w <= 0 inside the guard band (degenerate matrices only)


# ---- building blocks (public @wp.func API) ---------------------------------------------------------


@wp.func
def pixel_center_ndc(i: int, j: int, width: int, height: int) -> wp.vec2:
    """NDC (x, y) of the centre of pixel (i, j), row j counted from the top."""
    x = 2.0 * (float(i) + 0.5) / float(width) - 1.0
    y = 1.0 - 2.0 * (float(j) + 0.5) / float(height)
    return wp.vec2(x, y)


@wp.func
def depth_key(z_ndc: float, tri: int) -> wp.int64:
    """Packed z-buffer key: float32 bits of depth01 = 0.5 z_ndc + 0.5 (in [0, 1]) above the triangle index.

    Bits of non-negative float32 values order like the values, so smaller keys are nearer, and
    equal depths are ordered by triangle index.
    """
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
    """View-space distance along the view axis (positive in front) from NDC depth.

    ``p22, p23, p32, p33`` are the projection matrix entries [2][2], [2][3], [3][2], [3][3]
    (row-major, column vectors): z_ndc = (p22 z + p23) / (p32 z + p33) with view-space z < 0 in
    front, so z = (p23 - p33 z_ndc) / (p32 z_ndc - p22) and the distance is -z. Works for
    perspective and orthographic OpenGL-style matrices. Returns +inf for non-finite input.
    """
    if not wp.isfinite(z_ndc):
        return wp.inf
    return -(p23 - p33 * z_ndc) / (p32 * z_ndc - p22)


@wp.func
def edge_function(ax: wp.int64, ay: wp.int64, bx: wp.int64, by: wp.int64, px: wp.int64, py: wp.int64) -> wp.int64:
    """Fixed-point edge function of the directed edge a -> b at p (y down): > 0 on the interior side.

    Exact in int64 while coordinates stay within +-2^29 (guaranteed by the guard band).
    """
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


@wp.func
def top_left_bias(ax: wp.int64, ay: wp.int64, bx: wp.int64, by: wp.int64) -> wp.int64:
    """0 when edge a -> b owns the pixel centres lying exactly on it (top or left edge), else -1.

    A centre is inside iff edge_function + bias >= 0 for all three edges of a triangle with positive
    signed area. The rule equals a symbolic perturbation of the sample point to the right and
    (infinitesimally less) down, so abutting triangles never both or neither own a shared point.
    """
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
    """Sutherland-Hodgman: keep the part of a convex clip-space polygon where dot(plane, v) >= 0.

    ``src`` holds the mesh vertex index of every polygon vertex (-1 for a vertex made by clipping).
    The intersection on a crossing edge is always interpolated from its inside vertex towards its
    outside vertex, so triangles sharing the edge get bitwise identical points (watertight clipping).
    """
    out = ClipPolygon()
    out_src = ClipSources()
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
            m += 1
        if (da >= 0.0) != (db >= 0.0):
            if da >= 0.0:
                out[m] = a + (b - a) * (da / (da - db))
            else:
                out[m] = b + (a - b) * (db / (db - da))
            out_src[m] = -1
            m += 1
    return out, out_src, m


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
    """Vertex pass for mesh vertex ``i`` at world position ``q``: clip coordinates, outcode, and the snapped
    screen position if the vertex lies inside the guard band (``verts.screen[i]`` stays unset otherwise).
    Triangles read the snapped positions of their mesh vertices from here, so shared vertices are snapped
    once and identically for all of them."""
    v = clip_position(view_proj, q)
    verts.clip[i] = v
    code = clip_outcode(v, guard_x, guard_y)
    if not (wp.isfinite(v[0]) and wp.isfinite(v[1]) and wp.isfinite(v[2]) and wp.isfinite(v[3])):
        code = _OUT_INVALID
    elif (code & _OUT_GUARD) == 0:
        if v[3] > 0.0:
            verts.screen[i] = snap_to_screen(v, width, height)
        else:
            code = code | _OUT_INVALID
    verts.outcode[i] = code


@wp.struct
class RasterParams:
    """Per-pass rasterizer settings as kernels see them."""

    width: int  # image width in pixels
    height: int  # image height in pixels
    guard_x: float  # guard band half-extent in NDC x (|x| <= guard_x w after clipping)
    guard_y: float  # guard band half-extent in NDC y
    clip_near: int  # 1: clip at the near plane (z >= -w)
    clamp_depth: int  # 1: clamp depth to [-1, 1] instead of discarding beyond the far plane
    cull_backfaces: int  # 1: skip triangles clockwise in NDC
    count_mode: int  # 1: count fragments into `counts` instead of the depth test into `keys`
    peel: int  # 1: only keys strictly greater than `prev_keys` (depth peeling)


@wp.func
def edge_span(e: wp.int64, step: wp.int64, lo: wp.int64, hi: wp.int64) -> tuple[wp.int64, wp.int64]:
    """Narrow the pixel range [lo, hi] (counted from a row's first centre) to the n with e + n step >= 0.

    Exact integer version of testing every centre: the edge function is linear along the row, so the
    centres it accepts form one interval. An empty result has lo > hi.
    """
    if step > wp.int64(0):
        if e < wp.int64(0):
            lo = wp.max(lo, (step - e - wp.int64(1)) / step)  # ceil(-e / step), both operands positive
    elif step < wp.int64(0):
        if e < wp.int64(0):
            hi = wp.int64(-1)
        else:
            hi = wp.min(hi, e / (-step))  # floor(e / -step)
    elif e < wp.int64(0):
        hi = wp.int64(-1)
    return lo, hi


@wp.func
def rasterize_screen_triangle_rows(
    a: wp.vec3d,
    b: wp.vec3d,
    c: wp.vec3d,
    tri: int,
    p: RasterParams,
    row0: int,
    row1: int,
    prev_keys: wp.array2d(dtype=wp.int64),
    keys: wp.array2d(dtype=wp.int64),
    counts: wp.array2d(dtype=wp.int32),
):
    """:func:`rasterize_screen_triangle` restricted to image rows [row0, row1] (inclusive).

    In bounding boxes at least :data:`SPAN_MIN_PIXELS` + 1 centres wide each row is first narrowed to the exact
    span of centres the three edge functions accept (:func:`edge_span`, three integer divisions per row) instead
    of testing every centre of the box; the fragments, their depths and keys are those of the full test.
    """
    x0 = wp.int64(a[0])
    y0 = wp.int64(a[1])
    x1 = wp.int64(b[0])
    y1 = wp.int64(b[1])
    x2 = wp.int64(c[0])
    y2 = wp.int64(c[1])
    # ---- pixel centres (i + 0.5, j + 0.5) inside the bounding box, clamped to the image ----
    i0 = int((wp.min(x0, wp.min(x1, x2)) - _SUBPIXEL_HALF + _SUBPIXEL_STEP - wp.int64(1)) >> _SUBPIXEL_BITS)
    i1 = int((wp.max(x0, wp.max(x1, x2)) - _SUBPIXEL_HALF) >> _SUBPIXEL_BITS)  # floor (arithmetic shift)
    j0 = int((wp.min(y0, wp.min(y1, y2)) - _SUBPIXEL_HALF + _SUBPIXEL_STEP - wp.int64(1)) >> _SUBPIXEL_BITS)
    j1 = int((wp.max(y0, wp.max(y1, y2)) - _SUBPIXEL_HALF) >> _SUBPIXEL_BITS)
    i0 = wp.max(i0, 0)
    j0 = wp.max(j0, wp.max(row0, 0))
    i1 = wp.min(i1, p.width - 1)
    j1 = wp.min(j1, wp.min(row1, p.height - 1))
    if i0 > i1 or j0 > j1:
        return
    area = edge_function(x0, y0, x1, y1, x2, y2)  # > 0: clockwise in NDC (back face)
    if area == wp.int64(0):
        return
    z0 = a[2]
    z1 = b[2]
    z2 = c[2]
    if area > wp.int64(0):
        if p.cull_backfaces != 0:
            return
    else:
        # orient to positive area (two-sided): swap vertices 1 and 2
        tx = x1
        ty = y1
        tz = z1
        x1 = x2
        y1 = y2
        z1 = z2
        x2 = tx
        y2 = ty
        z2 = tz
        area = -area
    # ---- edge functions at the first centre, top-left bias folded in ----
    b0 = top_left_bias(x1, y1, x2, y2)  # edge opposite vertex 0
    b1 = top_left_bias(x2, y2, x0, y0)
    b2 = top_left_bias(x0, y0, x1, y1)
    step0 = -(y2 - y1) * _SUBPIXEL_STEP  # change per pixel to the right
    step1 = -(y0 - y2) * _SUBPIXEL_STEP
    step2 = -(y1 - y0) * _SUBPIXEL_STEP
    farea = wp.float64(area)
    px0 = (wp.int64(i0) << _SUBPIXEL_BITS) + _SUBPIXEL_HALF
    last = wp.int64(i1 - i0)
    spans = last >= _SPAN_MIN_PIXELS  # wide boxes: narrow each row to its span first
    for j in range(j0, j1 + 1):
        py = (wp.int64(j) << _SUBPIXEL_BITS) + _SUBPIXEL_HALF
        e0 = edge_function(x1, y1, x2, y2, px0, py) + b0
        e1 = edge_function(x2, y2, x0, y0, px0, py) + b1
        e2 = edge_function(x0, y0, x1, y1, px0, py) + b2
        lo = wp.int64(0)
        hi = last
        if spans:
            lo, hi = edge_span(e0, step0, lo, hi)
            lo, hi = edge_span(e1, step1, lo, hi)
            lo, hi = edge_span(e2, step2, lo, hi)
            e0 += lo * step0
            e1 += lo * step1
            e2 += lo * step2
        for i in range(i0 + int(lo), i0 + int(hi) + 1):
            if (e0 | e1 | e2) >= wp.int64(0):
                # NDC depth is affine in screen space: barycentric interpolation (float64).
                z = float((wp.float64(e0 - b0) * z0 + wp.float64(e1 - b1) * z1 + wp.float64(e2 - b2) * z2) / farea)
                keep = int(1)
                if p.clamp_depth != 0:
                    z = wp.clamp(z, -1.0, 1.0)
                else:
                    if z > 1.0:
                        keep = 0  # beyond the far plane
                    z = wp.max(z, -1.0)
                if keep != 0:
                    if p.count_mode != 0:
                        wp.atomic_add(counts, j, i, 1)
                    else:
                        key = depth_key(z, tri)
                        if p.peel == 0 or key > prev_keys[j, i]:
                            if key < keys[j, i]:
                                wp.atomic_min(keys, j, i, key)
            e0 += step0
            e1 += step1
            e2 += step2


@wp.func
def rasterize_screen_triangle(
    a: wp.vec3d,
    b: wp.vec3d,
    c: wp.vec3d,
    tri: int,
    p: RasterParams,
    prev_keys: wp.array2d(dtype=wp.int64),
    keys: wp.array2d(dtype=wp.int64),
    counts: wp.array2d(dtype=wp.int32),
):
    """Scan one snapped screen triangle into the key (or count) buffer.

    ``a``, ``b``, ``c`` are (X, Y, z_ndc) with X, Y the fixed-point screen position (y down, exact
    integers in float64) from :func:`snap_to_screen`.
    """
    rasterize_screen_triangle_rows(a, b, c, tri, p, 0, p.height - 1, prev_keys, keys, counts)


@wp.func
def triangle_crossing(t: int, verts: ProjectedVertices, triangles: wp.array2d(dtype=wp.int32), p: RasterParams) -> int:
    """Trivial reject of mesh triangle ``t``: -1 when nothing of it can be drawn (an invalid vertex, or all three
    vertices outside one plane), else the clip planes it crosses (0: the unclipped fast path)."""
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
def clip_triangle(
    t: int,
    verts: ProjectedVertices,
    triangles: wp.array2d(dtype=wp.int32),
    p: RasterParams,
    crossing: int,
) -> tuple[ScreenPolygon, int]:
    """Clip mesh triangle ``t`` against the ``crossing`` planes (near, guard band) of :func:`triangle_crossing`:
    the snapped screen polygon and its vertex count (0: nothing left to draw)."""
    sp = ScreenPolygon()
    ia = triangles[t, 0]
    ib = triangles[t, 1]
    ic = triangles[t, 2]
    poly = ClipPolygon()
    src = ClipSources()
    poly[0] = verts.clip[ia]
    poly[1] = verts.clip[ib]
    poly[2] = verts.clip[ic]
    src[0] = ia
    src[1] = ib
    src[2] = ic
    n = int(3)
    if (crossing & 1) != 0:  # near: z + w >= 0
        poly, src, n = clip_polygon_plane(poly, src, n, wp.vec4(0.0, 0.0, 1.0, 1.0))
    if (crossing & 2) != 0:  # guard band: x <= guard_x w
        poly, src, n = clip_polygon_plane(poly, src, n, wp.vec4(-1.0, 0.0, 0.0, p.guard_x))
    if (crossing & 4) != 0:  # -x <= guard_x w
        poly, src, n = clip_polygon_plane(poly, src, n, wp.vec4(1.0, 0.0, 0.0, p.guard_x))
    if (crossing & 8) != 0:  # y <= guard_y w
        poly, src, n = clip_polygon_plane(poly, src, n, wp.vec4(0.0, -1.0, 0.0, p.guard_y))
    if (crossing & 16) != 0:  # -y <= guard_y w
        poly, src, n = clip_polygon_plane(poly, src, n, wp.vec4(0.0, 1.0, 0.0, p.guard_y))
    if n < 3:
        return sp, 0
    # ---- snap: mesh vertices from the vertex pass, new vertices here (one call site each) ----
    for k in range(n):
        v = src[k]
        if v >= 0 and (verts.outcode[v] & _OUT_GUARD) == 0:
            sp[k] = verts.screen[v]
        else:
            if not (poly[k][3] > 0.0):
                return sp, 0  # only reachable for degenerate matrices (vertex at the centre of projection)
            sp[k] = snap_to_screen(poly[k], p.width, p.height)
    return sp, n


@wp.func
def bbox_rows(xmin: wp.int64, xmax: wp.int64, ymin: wp.int64, ymax: wp.int64, p: RasterParams) -> wp.vec2i:
    """Image rows (first, last) with pixel centres in the fixed-point box [xmin, xmax] x [ymin, ymax], clamped to
    the image; (0, -1) when no centre of the image lies in it."""
    i0 = int((xmin - _SUBPIXEL_HALF + _SUBPIXEL_STEP - wp.int64(1)) >> _SUBPIXEL_BITS)
    i1 = int((xmax - _SUBPIXEL_HALF) >> _SUBPIXEL_BITS)
    j0 = wp.max(int((ymin - _SUBPIXEL_HALF + _SUBPIXEL_STEP - wp.int64(1)) >> _SUBPIXEL_BITS), 0)
    j1 = wp.min(int((ymax - _SUBPIXEL_HALF) >> _SUBPIXEL_BITS), p.height - 1)
    if wp.max(i0, 0) > wp.min(i1, p.width - 1) or j0 > j1:
        return wp.vec2i(0, -1)
    return wp.vec2i(j0, j1)


@wp.func
def polygon_rows(sp: ScreenPolygon, n: int, p: RasterParams) -> wp.vec2i:
    """Image rows (first, last) whose centres a screen polygon of :func:`clip_triangle` may cover:
    its bounding box clamped to the image, (0, -1) when empty or outside the image on x."""
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


@wp.func
def rasterize_triangle_rows(
    t: int,
    verts: ProjectedVertices,
    triangles: wp.array2d(dtype=wp.int32),
    p: RasterParams,
    row0: int,
    row1: int,
    prev_keys: wp.array2d(dtype=wp.int64),
    keys: wp.array2d(dtype=wp.int64),
    counts: wp.array2d(dtype=wp.int32),
):
    """Reject, clip where needed, and scan mesh triangle ``t`` (or the fan of its clipped polygon) over
    image rows [row0, row1]."""
    crossing = triangle_crossing(t, verts, triangles, p)
    if crossing == 0:
        # ---- fast path: no clipping, snapped positions from the vertex pass ----
        rasterize_screen_triangle_rows(verts.screen[triangles[t, 0]], verts.screen[triangles[t, 1]],
                                       verts.screen[triangles[t, 2]], t, p, row0, row1, prev_keys, keys, counts)
    elif crossing > 0:
        sp, n = clip_triangle(t, verts, triangles, p, crossing)
        for k in range(1, n - 1):
            rasterize_screen_triangle_rows(sp[0], sp[k], sp[k + 1], t, p, row0, row1, prev_keys, keys, counts)


@wp.func
def rasterize_triangle(
    t: int,
    verts: ProjectedVertices,
    triangles: wp.array2d(dtype=wp.int32),
    p: RasterParams,
    prev_keys: wp.array2d(dtype=wp.int64),
    keys: wp.array2d(dtype=wp.int64),
    counts: wp.array2d(dtype=wp.int32),
):
    """Reject, clip where needed, and scan mesh triangle ``t`` (or the fan of its clipped polygon)."""
    rasterize_triangle_rows(t, verts, triangles, p, 0, p.height - 1, prev_keys, keys, counts)
