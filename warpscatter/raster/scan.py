"""The rasterizer's scan: the fragments of a mesh triangle, after rejection and clipping, into a packed-key z-buffer
or a fragment count. :func:`_row_scan` narrows each row of wide boxes to the exact span of accepted centres
(:func:`edge_span`); it is compiled with and without the exact-edge test.
"""

from __future__ import annotations

import warp as wp

from ..runtime.device import module_options
from .funcs import (
    _EXACT_ALWAYS,
    _EXACT_MARGIN,
    _FIXED_ONLY,
    _SPAN_MIN_PIXELS,
    _SUBPIXEL_BITS,
    _SUBPIXEL_HALF,
    _SUBPIXEL_STEP,
    ClipEdges,
    ClipSources,
    EdgeTolerances,
    ProjectedVertices,
    RasterParams,
    ScreenPolygon,
    clip_triangle,
    clip_triangle_edges,
    depth_key,
    edge_function,
    edge_tolerance,
    exact_edge_inside,
    top_left_bias,
    triangle_crossing,
    triangle_edge_planes,
)

module_options()


@wp.func
def edge_span(e: wp.int64, step: wp.int64, lo: wp.int64, hi: wp.int64) -> tuple[wp.int64, wp.int64]:
    """Narrow [lo, hi] (counted from a row's first centre) to the n with e + n step >= 0, exactly in integers (the
    accepted centres form one interval); empty when lo > hi."""
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
def emit_fragment(
    z: float,
    tri: int,
    j: int,
    i: int,
    p: RasterParams,
    prev_keys: wp.array2d(dtype=wp.int64),
    keys: wp.array2d(dtype=wp.int64),
    counts: wp.array2d(dtype=wp.int32),
):
    """Depth clamp or far-plane discard, then the count (count mode) or the depth test of fragment (i, j) of ``tri``."""
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


def _row_scan(exact: bool):
    """The row scan of a snapped screen triangle, compiled with (``exact``) or without the exact-edge test.

    Visits the bounding box's rows within [row0, row1], narrowed to their exact spans in wide boxes; the fragments are
    those of testing every centre. ``a``, ``b``, ``c`` are (X, Y, z_ndc), X, Y fixed-point (y down). Exact variant:
    centres within ``tols[k]`` of edge k are decided on ``planes[k]`` and the box is widened by ``margin``.
    """

    @wp.func(name="rasterize_screen_triangle_rows_exact" if exact else "rasterize_screen_triangle_rows_fixed")
    def scan(
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
        planes: wp.mat33d,
        tols: EdgeTolerances,
        margin: wp.int64,
    ):
        x0 = wp.int64(a[0])
        y0 = wp.int64(a[1])
        x1 = wp.int64(b[0])
        y1 = wp.int64(b[1])
        x2 = wp.int64(c[0])
        y2 = wp.int64(c[1])
        # ---- pixel centres (i + 0.5, j + 0.5) inside the bounding box, clamped to the image ----
        xmin = wp.min(x0, wp.min(x1, x2)) - margin
        ymin = wp.min(y0, wp.min(y1, y2)) - margin
        i0 = int((xmin - _SUBPIXEL_HALF + _SUBPIXEL_STEP - wp.int64(1)) >> _SUBPIXEL_BITS)
        i1 = int((wp.max(x0, wp.max(x1, x2)) + margin - _SUBPIXEL_HALF) >> _SUBPIXEL_BITS)  # floor (arithmetic shift)
        j0 = int((ymin - _SUBPIXEL_HALF + _SUBPIXEL_STEP - wp.int64(1)) >> _SUBPIXEL_BITS)
        j1 = int((wp.max(y0, wp.max(y1, y2)) + margin - _SUBPIXEL_HALF) >> _SUBPIXEL_BITS)
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
        t0 = _FIXED_ONLY  # fixed-point rule: e_k > -1
        t1 = _FIXED_ONLY
        t2 = _FIXED_ONLY
        if wp.static(exact):
            m0 = wp.vec3d(planes[0, 0], planes[0, 1], planes[0, 2])
            m1 = wp.vec3d(planes[1, 0], planes[1, 1], planes[1, 2])
            m2 = wp.vec3d(planes[2, 0], planes[2, 1], planes[2, 2])
            t0 = tols[0]
            t1 = tols[1]
            t2 = tols[2]
        if area > wp.int64(0):
            if p.cull_backfaces != 0:
                return
        else:
            # orient to positive area (two-sided): swap vertices 1 and 2 (and their opposite edges)
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
            if wp.static(exact):
                tm = m1
                m1 = m2
                m2 = tm
                tt = t1
                t1 = t2
                t2 = tt
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
        one = wp.int64(1)
        for j in range(j0, j1 + 1):
            py = (wp.int64(j) << _SUBPIXEL_BITS) + _SUBPIXEL_HALF
            e0 = edge_function(x1, y1, x2, y2, px0, py) + b0
            e1 = edge_function(x2, y2, x0, y0, px0, py) + b1
            e2 = edge_function(x0, y0, x1, y1, px0, py) + b2
            lo = wp.int64(0)
            hi = last
            if spans:
                # candidates: e_k >= -t_k - 1 (inside the fixed-point edge, or close enough for the exact test)
                lo, hi = edge_span(e0 + t0 + one, step0, lo, hi)
                lo, hi = edge_span(e1 + t1 + one, step1, lo, hi)
                lo, hi = edge_span(e2 + t2 + one, step2, lo, hi)
                e0 += lo * step0
                e1 += lo * step1
                e2 += lo * step2
            for i in range(i0 + int(lo), i0 + int(hi) + 1):
                inside = False
                if e0 > t0 and e1 > t1 and e2 > t2:
                    inside = True
                elif wp.static(exact):
                    if e0 >= -t0 - one and e1 >= -t1 - one and e2 >= -t2 - one:
                        pxf = wp.float64((wp.int64(i) << _SUBPIXEL_BITS) + _SUBPIXEL_HALF)
                        pyf = wp.float64(py)
                        inside = (e0 > t0 or exact_edge_inside(m0, pxf, pyf)) and (e1 > t1 or exact_edge_inside(m1, pxf,
                                                                                                                  pyf))
                        inside = inside and (e2 > t2 or exact_edge_inside(m2, pxf, pyf))
                if inside:
                    # NDC depth is affine in screen space: barycentric interpolation (float64).
                    z = float((wp.float64(e0 - b0) * z0 + wp.float64(e1 - b1) * z1 + wp.float64(e2 - b2) * z2) / farea)
                    emit_fragment(z, tri, j, i, p, prev_keys, keys, counts)
                e0 += step0
                e1 += step1
                e2 += step2

    return scan


#: :func:`_row_scan` with the exact-edge test (``RasterParams.exact_edges``).
rasterize_screen_triangle_rows_exact = _row_scan(exact=True)
_rasterize_screen_triangle_rows_fixed = _row_scan(exact=False)


@wp.func
def rasterize_screen_triangle_rows(a: wp.vec3d, b: wp.vec3d, c: wp.vec3d, tri: int, p: RasterParams, row0: int,
                                   row1: int, prev_keys: wp.array2d(dtype=wp.int64),
                                   keys: wp.array2d(dtype=wp.int64), counts: wp.array2d(dtype=wp.int32)):
    """Scan one snapped screen triangle over image rows [row0, row1] by the fixed-point rule (:func:`_row_scan`)."""
    _rasterize_screen_triangle_rows_fixed(a, b, c, tri, p, row0, row1, prev_keys, keys, counts, wp.mat33d(),
                                          EdgeTolerances(), wp.int64(0))


@wp.func
def rasterize_exact_triangle_rows(
    t: int,
    verts: ProjectedVertices,
    triangles: wp.array2d(dtype=wp.int32),
    planes: wp.mat33d,
    p: RasterParams,
    row0: int,
    row1: int,
    prev_keys: wp.array2d(dtype=wp.int64),
    keys: wp.array2d(dtype=wp.int64),
    counts: wp.array2d(dtype=wp.int32),
):
    """Exact-edge mode, a triangle whose snapped screen triangle has no area: every centre of its widened box by the
    three exact edge tests, so the centres it covers are not lost."""
    ia = triangles[t, 0]
    ib = triangles[t, 1]
    ic = triangles[t, 2]
    sa = verts.screen[ia]
    sb = verts.screen[ib]
    sc = verts.screen[ic]
    ha = verts.hom[ia]
    hb = verts.hom[ib]
    hc = verts.hom[ic]
    m0 = wp.vec3d(planes[0, 0], planes[0, 1], planes[0, 2])
    m1 = wp.vec3d(planes[1, 0], planes[1, 1], planes[1, 2])
    m2 = wp.vec3d(planes[2, 0], planes[2, 1], planes[2, 2])
    d0 = wp.dot(m0, ha)  # > 0 for a triangle not seen edge-on
    d1 = wp.dot(m1, hb)
    d2 = wp.dot(m2, hc)
    zero = wp.float64(0.0)
    if not (d0 > zero and d1 > zero and d2 > zero):
        return
    if p.cull_backfaces != 0 and wp.dot(wp.cross(ha, hb), hc) > zero:
        return  # clockwise in NDC (the sign of the fixed-point area)
    xmin = wp.int64(wp.min(sa[0], wp.min(sb[0], sc[0]))) - _EXACT_MARGIN
    xmax = wp.int64(wp.max(sa[0], wp.max(sb[0], sc[0]))) + _EXACT_MARGIN
    ymin = wp.int64(wp.min(sa[1], wp.min(sb[1], sc[1]))) - _EXACT_MARGIN
    ymax = wp.int64(wp.max(sa[1], wp.max(sb[1], sc[1]))) + _EXACT_MARGIN
    i0 = wp.max(int((xmin - _SUBPIXEL_HALF + _SUBPIXEL_STEP - wp.int64(1)) >> _SUBPIXEL_BITS), 0)
    i1 = wp.min(int((xmax - _SUBPIXEL_HALF) >> _SUBPIXEL_BITS), p.width - 1)
    j0 = wp.max(int((ymin - _SUBPIXEL_HALF + _SUBPIXEL_STEP - wp.int64(1)) >> _SUBPIXEL_BITS), wp.max(row0, 0))
    j1 = wp.min(int((ymax - _SUBPIXEL_HALF) >> _SUBPIXEL_BITS), wp.min(row1, p.height - 1))
    for j in range(j0, j1 + 1):
        pyf = wp.float64((wp.int64(j) << _SUBPIXEL_BITS) + _SUBPIXEL_HALF)
        for i in range(i0, i1 + 1):
            pxf = wp.float64((wp.int64(i) << _SUBPIXEL_BITS) + _SUBPIXEL_HALF)
            if exact_edge_inside(m0, pxf, pyf) and exact_edge_inside(m1, pxf, pyf) and exact_edge_inside(m2, pxf, pyf):
                q = wp.vec3d(pxf, pyf, wp.float64(1.0))
                # screen barycentrics: w_k (m_k . q) / (m_k . h_k)
                la = ha[2] * wp.dot(m0, q) / d0
                lb = hb[2] * wp.dot(m1, q) / d1
                lc = hc[2] * wp.dot(m2, q) / d2
                z = float((la * sa[2] + lb * sb[2] + lc * sc[2]) / (la + lb + lc))
                emit_fragment(z, t, j, i, p, prev_keys, keys, counts)


@wp.func
def rasterize_screen_triangle(a: wp.vec3d, b: wp.vec3d, c: wp.vec3d, tri: int, p: RasterParams,
                              prev_keys: wp.array2d(dtype=wp.int64), keys: wp.array2d(dtype=wp.int64),
                              counts: wp.array2d(dtype=wp.int32)):
    """Scan one snapped screen triangle into the key (or count) buffer, all rows (:func:`_row_scan`)."""
    rasterize_screen_triangle_rows(a, b, c, tri, p, 0, p.height - 1, prev_keys, keys, counts)


@wp.func
def polygon_edge_exact(
    planes: wp.mat33d, verts: ProjectedVertices, sp: ScreenPolygon, src: ClipSources, edges: ClipEdges, k: int, n: int
) -> tuple[wp.vec3d, wp.int64]:
    """Exact plane and tolerance of edge k -> k + 1 of a clipped polygon (the fixed-point test alone along a clip
    plane)."""
    e = edges[k]
    if e < 0:
        return wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0)), _FIXED_ONLY
    m = wp.vec3d(planes[e, 0], planes[e, 1], planes[e, 2])
    k1 = (k + 1) % n
    u = src[k]
    v = src[k1]
    if u >= 0 and v >= 0:
        return m, edge_tolerance(sp[k], sp[k1], verts.dev[u], verts.dev[v])
    return m, _EXACT_ALWAYS


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
    """Reject, clip where needed, and scan mesh triangle ``t`` (or its clipped polygon's fan) over rows [row0, row1].
    In exact-edge mode centres near a mesh edge are decided on its unrounded projection, as a ray would; clip edges
    and fan diagonals keep the fixed-point rule."""
    crossing = triangle_crossing(t, verts, triangles, p)
    if crossing < 0:
        return
    if p.exact_edges == 0:
        if crossing == 0:
            # ---- fast path: no clipping, snapped positions from the vertex pass ----
            rasterize_screen_triangle_rows(verts.screen[triangles[t, 0]], verts.screen[triangles[t, 1]],
                                           verts.screen[triangles[t, 2]], t, p, row0, row1, prev_keys, keys, counts)
        else:
            sp, n = clip_triangle(t, verts, triangles, p, crossing)
            for k in range(1, n - 1):
                rasterize_screen_triangle_rows(sp[0], sp[k], sp[k + 1], t, p, row0, row1, prev_keys, keys, counts)
        return
    ia = triangles[t, 0]
    ib = triangles[t, 1]
    ic = triangles[t, 2]
    planes = triangle_edge_planes(verts, ia, ib, ic)
    if crossing == 0:
        sa = verts.screen[ia]
        sb = verts.screen[ib]
        sc = verts.screen[ic]
        if edge_function(wp.int64(sa[0]), wp.int64(sa[1]), wp.int64(sb[0]), wp.int64(sb[1]), wp.int64(sc[0]),
                         wp.int64(sc[1])) == wp.int64(0):
            rasterize_exact_triangle_rows(t, verts, triangles, planes, p, row0, row1, prev_keys, keys, counts)
            return
        tols = EdgeTolerances(edge_tolerance(sb, sc, verts.dev[ib], verts.dev[ic]),
                              edge_tolerance(sc, sa, verts.dev[ic], verts.dev[ia]),
                              edge_tolerance(sa, sb, verts.dev[ia], verts.dev[ib]))
        rasterize_screen_triangle_rows_exact(sa, sb, sc, t, p, row0, row1, prev_keys, keys, counts, planes, tols,
                                             _EXACT_MARGIN)
        return
    sp, src, edges, n = clip_triangle_edges(t, verts, triangles, p, crossing)
    zero = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    for k in range(1, n - 1):
        # fan triangle (0, k, k + 1): edge opposite 0 is polygon edge k; the others are polygon edges only at the ends
        m0, t0 = polygon_edge_exact(planes, verts, sp, src, edges, k, n)
        m1 = zero
        t1 = _FIXED_ONLY
        m2 = zero
        t2 = _FIXED_ONLY
        if k + 1 == n - 1:
            m1, t1 = polygon_edge_exact(planes, verts, sp, src, edges, n - 1, n)
        if k == 1:
            m2, t2 = polygon_edge_exact(planes, verts, sp, src, edges, 0, n)
        fan = wp.mat33d(m0[0], m0[1], m0[2], m1[0], m1[1], m1[2], m2[0], m2[1], m2[2])
        rasterize_screen_triangle_rows_exact(sp[0], sp[k], sp[k + 1], t, p, row0, row1, prev_keys, keys, counts, fan,
                                             EdgeTolerances(t0, t1, t2), _EXACT_MARGIN)


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
