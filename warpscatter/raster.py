"""Triangle rasterization into depth maps for any 4x4 world -> clip matrix, with depth peeling.

The rasterizer is exact in the sense of GPU hardware rasterizers: screen positions are snapped to
fixed point (:data:`SUBPIXEL_BITS` sub-pixel bits), edge functions are evaluated in int64 and the
top-left fill rule decides pixel centres that lie exactly on an edge or a vertex. Every pixel
centre covered by a closed tessellated surface is therefore hit exactly once: no cracks, no double
hits. The z-buffer stores a packed int64 key per texel,

    key = (float32 bits of depth01) << 32 | triangle index,   depth01 = clamp(0.5 z_ndc + 0.5, 0, 1),

resolved with ``wp.atomic_min``: exact and free of races, also on CUDA, and ties between triangles
at equal depth go to the lower triangle index. Depth peeling keeps, per layer, the smallest key
strictly greater than the previous layer's key.

Conventions (OpenGL-style, as in :mod:`warpscatter.scene.camera`): clip space -> NDC in [-1, 1]^3,
z_ndc = -1 at the near plane. Pixel (i, j), j counted from the TOP row, has its centre at
x_ndc = 2 (i + 0.5) / width - 1, y_ndc = 1 - 2 (j + 0.5) / height, which is exactly the centre of
the ray :meth:`Camera.ray_directions` gives for that pixel.

Clipping: triangles are clipped in homogeneous clip space against the near plane (z >= -w) and a
guard band on x and y (|x|, |y| <= g w, screen positions within +-2^18 pixels) with
Sutherland-Hodgman; intersection points are always interpolated from the inside vertex towards the
outside vertex, so two triangles sharing an edge produce bitwise identical clip vertices. Fragments
beyond the far plane (z_ndc > 1) are discarded. With ``clamp_depth=True`` (shadow maps) fragments
beyond the far plane are kept at depth +1 and, for affine (orthographic) matrices whose w is a
positive constant, nothing is clipped at the near plane: geometry in front of it is kept at depth
-1. A perspective matrix keeps its near clipping even with ``clamp_depth`` (points behind the centre
of projection have no meaningful projection) unless the caller passes ``clip_near=False``: then only
the guard band clips, and since |x| <= g w and |y| <= g w imply w >= 0 (w = 0 only at the centre of
projection itself, where the triangle is dropped), everything behind the centre of projection is
still cut away while geometry in front of the near plane is kept (at depth -1 with ``clamp_depth``).
Klehm 2014's projective rectification (Sec. 4.2, projecting along x with the camera as centre of
projection) needs exactly this: casters between the light and the camera frustum stay in the map.

Parallelism: one CPU launch runs on one core, so the triangles are split into contiguous chunks,
one per thread, each rasterizing into a private key buffer; the buffers are merged with a minimum
over the packed keys, which is exact. On CUDA one launch with real atomics does the work.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from . import parallel
from .wpinit import default_device, module_options

module_options()

#: Sub-pixel precision of snapped screen positions (1/1024 pixel).
SUBPIXEL_BITS = 10
#: Screen positions after guard-band clipping stay within +-GUARD_BAND_PIXELS pixels, so snapped
#: coordinates stay within +-2^28 and every int64 edge function within +-2^59 (no overflow).
GUARD_BAND_PIXELS = 2**18
#: Largest accepted image width or height (keeps pixel centres inside the fixed-point range).
MAX_RESOLUTION = 2**16
#: Triangles (or vertices) per Warp thread on the CPU (amortises the per-thread cost of a CPU launch).
TRIANGLES_PER_CPU_THREAD = 64
#: Key of a texel that no fragment reached (the largest int64).
EMPTY_KEY = np.iinfo(np.int64).max

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
    j0 = wp.max(j0, 0)
    i1 = wp.min(i1, p.width - 1)
    j1 = wp.min(j1, p.height - 1)
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
    for j in range(j0, j1 + 1):
        py = (wp.int64(j) << _SUBPIXEL_BITS) + _SUBPIXEL_HALF
        e0 = edge_function(x1, y1, x2, y2, px0, py) + b0
        e1 = edge_function(x2, y2, x0, y0, px0, py) + b1
        e2 = edge_function(x0, y0, x1, y1, px0, py) + b2
        for i in range(i0, i1 + 1):
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
def rasterize_triangle(
    t: int,
    clip: wp.array(dtype=wp.vec4),
    screen: wp.array(dtype=wp.vec3d),
    outcode: wp.array(dtype=wp.int32),
    triangles: wp.array2d(dtype=wp.int32),
    p: RasterParams,
    prev_keys: wp.array2d(dtype=wp.int64),
    keys: wp.array2d(dtype=wp.int64),
    counts: wp.array2d(dtype=wp.int32),
):
    """Reject, clip where needed, and scan mesh triangle ``t`` (or the fan of its clipped polygon)."""
    ia = triangles[t, 0]
    ib = triangles[t, 1]
    ic = triangles[t, 2]
    oa = outcode[ia]
    ob = outcode[ib]
    oc = outcode[ic]
    # ---- trivial reject: an invalid vertex, or all three vertices outside one plane ----
    if ((oa | ob | oc) & _OUT_INVALID) != 0:
        return
    reject = _OUT_VIEW
    if p.clip_near != 0:
        reject = reject | _OUT_NEAR
    if p.clamp_depth == 0:
        reject = reject | _OUT_FAR
    if (oa & ob & oc & reject) != 0:
        return
    crossing = (oa | ob | oc) & (_OUT_GUARD | (_OUT_NEAR * p.clip_near))
    if crossing == 0:
        # ---- fast path: no clipping, snapped positions from the vertex pass ----
        rasterize_screen_triangle(screen[ia], screen[ib], screen[ic], t, p, prev_keys, keys, counts)
        return
    # ---- clip against the near plane and the guard band ----
    poly = ClipPolygon()
    src = ClipSources()
    poly[0] = clip[ia]
    poly[1] = clip[ib]
    poly[2] = clip[ic]
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
        return
    # ---- snap: mesh vertices from the vertex pass, new vertices here (one call site each) ----
    sp = ScreenPolygon()
    for k in range(n):
        v = src[k]
        if v >= 0 and (outcode[v] & _OUT_GUARD) == 0:
            sp[k] = screen[v]
        else:
            if not (poly[k][3] > 0.0):
                return  # only reachable for degenerate matrices (vertex at the centre of projection)
            sp[k] = snap_to_screen(poly[k], p.width, p.height)
    # ---- scan the triangle fan of the convex polygon ----
    for k in range(1, n - 1):
        rasterize_screen_triangle(sp[0], sp[k], sp[k + 1], t, p, prev_keys, keys, counts)


# ---- kernels ---------------------------------------------------------------------------------------


@wp.kernel
def project_vertices_kernel(
    points: wp.array(dtype=wp.vec3),
    view_proj: wp.mat44d,
    width: int,
    height: int,
    guard_x: float,
    guard_y: float,
    batch: int,
    clip: wp.array(dtype=wp.vec4),
    screen: wp.array(dtype=wp.vec3d),
    outcode: wp.array(dtype=wp.int32),
    offset: int,
):
    """Per vertex: clip coordinates (float64 product, stored float32), outcode, and the snapped screen
    position of vertices inside the guard band. Triangles read the snapped positions of their mesh
    vertices from here, so shared vertices are snapped once and identically for all of them.
    Thread ``tid + offset`` handles vertices [batch (tid + offset), batch (tid + offset + 1))."""
    first = (wp.tid() + offset) * batch
    for i in range(first, wp.min(first + batch, points.shape[0])):
        q = points[i]
        c = view_proj * wp.vec4d(wp.float64(q[0]), wp.float64(q[1]), wp.float64(q[2]), wp.float64(1.0))
        v = wp.vec4(float(c[0]), float(c[1]), float(c[2]), float(c[3]))
        clip[i] = v
        code = clip_outcode(v, guard_x, guard_y)
        if not (wp.isfinite(v[0]) and wp.isfinite(v[1]) and wp.isfinite(v[2]) and wp.isfinite(v[3])):
            code = _OUT_INVALID
        elif (code & _OUT_GUARD) == 0:
            if v[3] > 0.0:
                screen[i] = snap_to_screen(v, width, height)
            else:
                code = code | _OUT_INVALID
        outcode[i] = code


@wp.kernel
def rasterize_kernel(
    clip: wp.array(dtype=wp.vec4),
    screen: wp.array(dtype=wp.vec3d),
    outcode: wp.array(dtype=wp.int32),
    triangles: wp.array2d(dtype=wp.int32),
    params: RasterParams,
    prev_keys: wp.array2d(dtype=wp.int64),
    keys: wp.array2d(dtype=wp.int64),
    counts: wp.array2d(dtype=wp.int32),
    stop: int,
    batch: int,
    offset: int,
):
    """Triangles [offset + tid * batch, offset + (tid + 1) * batch) clipped to ``stop``, one thread each
    batch (batches amortise the per-thread cost of CPU launches; use batch 1 on CUDA)."""
    start = offset + wp.tid() * batch
    for t in range(start, wp.min(start + batch, stop)):
        rasterize_triangle(t, clip, screen, outcode, triangles, params, prev_keys, keys, counts)


@wp.kernel
def resolve_keys_kernel(
    keys: wp.array2d(dtype=wp.int64),
    layer: int,
    ndc_depth: wp.array3d(dtype=wp.float32),
    tri_id: wp.array3d(dtype=wp.int32),
    offset: int,
):
    """Packed keys -> NDC depth (+inf when empty) and triangle index (-1 when empty); one row per thread."""
    j = wp.tid() + offset
    for i in range(keys.shape[1]):
        key = keys[j, i]
        ndc_depth[layer, j, i] = key_ndc_depth(key)
        tri_id[layer, j, i] = key_triangle(key)


# ---- host side -------------------------------------------------------------------------------------


@dataclass
class RasterResult:
    """Depth layers of a rasterization (or of :func:`warpscatter.raycast.raycast_depth`).

    Attributes:
        ndc_depth: (layers, height, width) float32 NDC depth in [-1, 1]; +inf where no surface.
        tri_id: (layers, height, width) int32 triangle index; -1 where no surface.
        keys: (layers, height, width) int64 packed keys (see :func:`depth_key`) on the device; None for
            ray-cast results.
        device_ndc_depth: ``ndc_depth`` as a ``wp.array`` on the device (shares memory on the CPU).
        device_tri_id: ``tri_id`` as a ``wp.array`` on the device (shares memory on the CPU).
        view_proj: the float64 4x4 world -> clip matrix used.
    """

    ndc_depth: np.ndarray
    tri_id: np.ndarray
    keys: wp.array | None
    device_ndc_depth: wp.array
    device_tri_id: wp.array
    view_proj: np.ndarray

    @property
    def layers(self) -> int:
        return int(self.ndc_depth.shape[0])

    @property
    def height(self) -> int:
        return int(self.ndc_depth.shape[1])

    @property
    def width(self) -> int:
        return int(self.ndc_depth.shape[2])


def check_matrix(m, name: str = "view_proj") -> np.ndarray:
    """Return ``m`` as a float64 (4, 4) array; ValueError naming ``name`` when malformed or non-finite."""
    try:
        a = np.asarray(m, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a 4x4 numeric matrix") from exc
    if a.shape != (4, 4):
        raise ValueError(f"{name} must have shape (4, 4), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains non-finite entries")
    return a


def check_size(width, height) -> tuple[int, int]:
    """Validate an image size in pixels (1 .. MAX_RESOLUTION); ValueError naming the argument."""
    out = []
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise ValueError(f"{name} must be an integer, got {v!r}")
        if not 1 <= int(v) <= MAX_RESOLUTION:
            raise ValueError(f"{name} must lie in [1, {MAX_RESOLUTION}], got {v}")
        out.append(int(v))
    return out[0], out[1]


def as_points(vertices, device: str) -> wp.array:
    """(N, 3) numpy vertices or a ``wp.array(dtype=wp.vec3)`` -> contiguous vec3 array on ``device``.

    Numpy input must be finite (ValueError otherwise); a ``wp.array`` is taken as is (the rasterizer
    skips triangles with non-finite clip coordinates).
    """
    if isinstance(vertices, wp.array):
        if vertices.dtype != wp.vec3 or vertices.ndim != 1:
            raise ValueError("vertices as a wp.array must be 1-D with dtype wp.vec3")
        if str(vertices.device) != str(wp.get_device(device)) or not vertices.is_contiguous:
            vertices = wp.clone(vertices, device=device)
        return vertices
    try:
        v = np.asarray(vertices, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError("vertices must be a numeric (N, 3) array") from exc
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must have shape (N, 3), got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError("vertices contain non-finite coordinates")
    return wp.array(np.ascontiguousarray(v, dtype=np.float32), dtype=wp.vec3, device=device)


def as_triangles(triangles, num_points: int, device: str) -> wp.array:
    """(T, 3) integer indices (numpy or wp.array) -> int32 ``wp.array2d`` on ``device``, range-checked."""
    if isinstance(triangles, wp.array):
        t = triangles.numpy()
    else:
        t = np.asarray(triangles)
    if t.size == 0:
        t = t.reshape(0, 3)
    if t.ndim == 1 and t.size % 3 == 0:
        t = t.reshape(-1, 3)
    if t.ndim != 2 or t.shape[1] != 3:
        raise ValueError(f"triangles must have shape (T, 3), got {t.shape}")
    if not np.issubdtype(t.dtype, np.integer):
        raise ValueError(f"triangles must hold integer vertex indices, got dtype {t.dtype}")
    if t.size and (t.min() < 0 or t.max() >= num_points):
        raise ValueError(f"triangles index vertices out of range [0, {num_points}) (min {t.min()}, max {t.max()})")
    if t.shape[0] >= 2**31:
        raise ValueError("triangles: at most 2^31 - 1 triangles are supported")
    return wp.array(np.ascontiguousarray(t, dtype=np.int32), dtype=wp.int32, device=device)


def is_affine(view_proj: np.ndarray) -> bool:
    """True when clip w is a positive constant (orthographic-style matrix: last row (0, 0, 0, c > 0))."""
    m = np.asarray(view_proj, dtype=np.float64)
    return bool(np.all(m[3, :3] == 0.0) and m[3, 3] > 0.0)


def project_vertices(
    points: wp.array,
    view_proj: np.ndarray,
    width: int,
    height: int,
    guard_x: float,
    guard_y: float,
    device: str,
    threads: int | None = None,
) -> tuple[wp.array, wp.array, wp.array]:
    """Vertex pass: (clip vec4, snapped screen vec3d, outcode int32) arrays for ``points``."""
    n = points.shape[0]
    clip = wp.empty(n, dtype=wp.vec4, device=device)
    screen = wp.empty(n, dtype=wp.vec3d, device=device)  # entries of vertices outside the guard band stay unset
    outcode = wp.empty(n, dtype=wp.int32, device=device)
    batch = TRIANGLES_PER_CPU_THREAD if wp.get_device(device).is_cpu else 1
    parallel.launch_rows(
        project_vertices_kernel, (n + batch - 1) // batch,
        [points, wp.mat44d(*view_proj.ravel()), width, height, guard_x, guard_y, batch, clip, screen, outcode],
        device, threads=threads, min_chunk=1024,
    )  # fmt: skip
    return clip, screen, outcode


class _Setup:
    """Everything a rasterization pass needs, prepared once per call."""

    def __init__(self, vertices, triangles, view_proj, width, height, clamp_depth, cull_backfaces, device, threads,
                 clip_near=None):
        self.device = default_device(device)
        self.view_proj = check_matrix(view_proj, "view_proj")
        self.width, self.height = check_size(width, height)
        points = as_points(vertices, self.device)
        self.tris = as_triangles(triangles, points.shape[0], self.device)
        self.clamp_depth = int(bool(clamp_depth))
        self.cull_backfaces = int(bool(cull_backfaces))
        if clip_near is None:
            self.clip_near = 0 if (clamp_depth and is_affine(self.view_proj)) else 1
        else:
            self.clip_near = int(bool(clip_near))
        # Guard band in NDC: |x_ndc| <= gx keeps screen x within +-GUARD_BAND_PIXELS.
        self.guard_x = float(2.0 * GUARD_BAND_PIXELS / self.width - 1.0)
        self.guard_y = float(2.0 * GUARD_BAND_PIXELS / self.height - 1.0)
        self.threads = threads or parallel.thread_count()
        self.clip, self.screen, self.outcode = project_vertices(
            points, self.view_proj, self.width, self.height, self.guard_x, self.guard_y, self.device, self.threads
        )
        self.dummy_keys = wp.zeros((1, 1), dtype=wp.int64, device=self.device)
        self.dummy_counts = wp.zeros((1, 1), dtype=wp.int32, device=self.device)
        self.is_cpu = wp.get_device(self.device).is_cpu

    def pieces(self) -> list[tuple[int, int]]:
        n = self.tris.shape[0]
        if not self.is_cpu or self.threads <= 1:
            return [(0, n)] if n else []
        return parallel.chunks(n, self.threads, min_chunk=2048) if n else []

    def launch(self, piece, prev_keys, keys, counts, count_mode: int, peel: int) -> None:
        """Rasterize triangles [start, stop) of ``piece`` into ``keys`` (or ``counts``)."""
        start, stop = piece
        params = RasterParams()
        params.width, params.height = self.width, self.height
        params.guard_x, params.guard_y = self.guard_x, self.guard_y
        params.clip_near, params.clamp_depth = self.clip_near, self.clamp_depth
        params.cull_backfaces = self.cull_backfaces
        params.count_mode, params.peel = count_mode, peel
        batch = TRIANGLES_PER_CPU_THREAD if self.is_cpu else 1
        wp.launch(
            rasterize_kernel,
            dim=(stop - start + batch - 1) // batch,
            inputs=[self.clip, self.screen, self.outcode, self.tris, params, prev_keys, keys, counts, stop, batch,
                    start],
            device=self.device,
        )  # fmt: skip

    def key_pass(self, prev_keys, keys, private: list) -> None:
        """Rasterize all triangles into ``keys`` (pre-filled with EMPTY_KEY); ``private``: spare buffers."""
        pieces = self.pieces()
        peel = 0 if prev_keys is None else 1
        prev = self.dummy_keys if prev_keys is None else prev_keys
        if len(pieces) <= 1:
            for piece in pieces:
                self.launch(piece, prev, keys, self.dummy_counts, 0, peel)
            return
        wp.load_module(rasterize_kernel.module, device=self.device)
        while len(private) < len(pieces) - 1:
            private.append(wp.empty((self.height, self.width), dtype=wp.int64, device=self.device))
        buffers = [keys, *private[: len(pieces) - 1]]
        for buf in buffers[1:]:
            buf.fill_(EMPTY_KEY)
        parallel.run_parallel(
            lambda k: self.launch(pieces[k], prev, buffers[k], self.dummy_counts, 0, peel),
            list(range(len(pieces))), self.threads,
        )  # fmt: skip
        out = keys.numpy()
        for buf in buffers[1:]:
            np.minimum(out, buf.numpy(), out=out)  # exact: packed keys


def rasterize(
    vertices,
    triangles,
    view_proj,
    width: int,
    height: int,
    *,
    layers: int = 1,
    clamp_depth: bool = False,
    cull_backfaces: bool = False,
    clip_near: bool | None = None,
    device: str | None = None,
    threads: int | None = None,
) -> RasterResult:
    """Rasterize a triangle mesh into ``layers`` depth layers seen through ``view_proj``.

    Args:
        vertices: (N, 3) world-space positions (numpy float32/float64, or ``wp.array(dtype=wp.vec3)``).
        triangles: (T, 3) vertex indices (integer numpy array or int32 ``wp.array``).
        view_proj: 4x4 world -> clip matrix (OpenGL-style, column vectors; perspective or orthographic).
        width: image width in pixels (1 .. MAX_RESOLUTION).
        height: image height in pixels; row 0 is the top of the image (NDC y = +1).
        layers: number of depth-peeled layers (>= 1): layer n holds the nearest surface strictly behind
            layer n-1 in (depth, triangle index) order, so coincident triangles land in separate layers.
        clamp_depth: keep fragments beyond the far plane at depth +1 instead of discarding them and,
            for affine (orthographic) matrices, keep geometry in front of the near plane at depth -1
            instead of clipping it (shadow maps). Perspective matrices keep near clipping.
        cull_backfaces: skip triangles whose projection is clockwise in NDC (front = counter-clockwise,
            the OpenGL default). Off by default: both sides are drawn.
        clip_near: None (default) clips at the near plane z >= -w unless ``clamp_depth`` is set and the
            matrix is affine; False never clips there (only the guard band, which keeps w > 0, so a
            perspective matrix still drops everything behind its centre of projection); True always clips.
        device: Warp device (default :func:`warpscatter.wpinit.default_device`).
        threads: CPU worker threads (default :func:`warpscatter.parallel.thread_count`).

    Returns:
        :class:`RasterResult` with (layers, height, width) ``ndc_depth`` (float32, +inf where empty)
        and ``tri_id`` (int32, -1 where empty).

    Raises:
        ValueError: malformed or non-finite ``view_proj``/``vertices``, ``triangles`` of wrong shape or
            with out-of-range indices, ``width``/``height`` outside [1, MAX_RESOLUTION], ``layers`` < 1.
    """
    if isinstance(layers, bool) or not isinstance(layers, (int, np.integer)) or layers < 1:
        raise ValueError(f"layers must be an integer >= 1, got {layers!r}")
    s = _Setup(vertices, triangles, view_proj, width, height, clamp_depth, cull_backfaces, device, threads, clip_near)
    h, w = s.height, s.width
    keys = wp.full((int(layers), h, w), EMPTY_KEY, dtype=wp.int64, device=s.device)
    ndc_depth = wp.empty((int(layers), h, w), dtype=wp.float32, device=s.device)
    tri_id = wp.empty((int(layers), h, w), dtype=wp.int32, device=s.device)
    private: list = []
    for layer in range(int(layers)):
        s.key_pass(keys[layer - 1] if layer > 0 else None, keys[layer], private)
        parallel.launch_rows(
            resolve_keys_kernel, h, [keys[layer], layer, ndc_depth, tri_id], s.device, threads=s.threads, min_chunk=64
        )
    return RasterResult(
        ndc_depth=ndc_depth.numpy(), tri_id=tri_id.numpy(), keys=keys, device_ndc_depth=ndc_depth,
        device_tri_id=tri_id, view_proj=s.view_proj,
    )  # fmt: skip


def coverage_count(
    vertices,
    triangles,
    view_proj,
    width: int,
    height: int,
    *,
    clamp_depth: bool = False,
    cull_backfaces: bool = False,
    clip_near: bool | None = None,
    device: str | None = None,
    threads: int | None = None,
) -> np.ndarray:
    """Number of fragments each pixel centre receives (same rules as :func:`rasterize`, no depth test).

    A closed tessellated surface seen through the image gives exactly 1 per covered pixel: the
    watertightness check of the fill rule. Arguments as in :func:`rasterize`.

    Returns:
        (height, width) int32 fragment counts, row 0 at the top.
    """
    s = _Setup(vertices, triangles, view_proj, width, height, clamp_depth, cull_backfaces, device, threads, clip_near)
    pieces = s.pieces()
    buffers = [wp.zeros((s.height, s.width), dtype=wp.int32, device=s.device) for _ in range(max(1, len(pieces)))]
    wp.load_module(rasterize_kernel.module, device=s.device)
    parallel.run_parallel(
        lambda k: s.launch(pieces[k], s.dummy_keys, s.dummy_keys, buffers[k], 1, 0), list(range(len(pieces))),
        s.threads,
    )  # fmt: skip
    total = buffers[0].numpy().copy()
    for buf in buffers[1:]:
        total += buf.numpy()
    return total


def pixel_center_ndc_grid(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """NDC x (width,) and y (height,) of pixel centres, row 0 at the top (float64, host mirror of
    :func:`pixel_center_ndc`)."""
    x = 2.0 * (np.arange(width) + 0.5) / width - 1.0
    y = 1.0 - 2.0 * (np.arange(height) + 0.5) / height
    return x, y


def unproject(ndc_depth, view_proj) -> np.ndarray:
    """World positions of pixel centres at the given NDC depths.

    Args:
        ndc_depth: (..., H, W) NDC depths (e.g. ``RasterResult.ndc_depth``); non-finite = no surface.
        view_proj: the 4x4 world -> clip matrix the depths were rendered with.

    Returns:
        (..., H, W, 3) float64 world positions; +inf where the depth is not finite.
    """
    m = check_matrix(view_proj, "view_proj")
    z = np.asarray(ndc_depth, dtype=np.float64)
    if z.ndim < 2:
        raise ValueError(f"ndc_depth must have at least 2 dimensions (H, W), got shape {z.shape}")
    h, w = z.shape[-2:]
    xs, ys = pixel_center_ndc_grid(w, h)
    finite = np.isfinite(z)
    zz = np.where(finite, z, 0.0)
    ndc = np.stack(np.broadcast_arrays(xs[None, :], ys[:, None], zz, np.ones_like(zz)), axis=-1)
    p = ndc @ np.linalg.inv(m).T
    with np.errstate(divide="ignore", invalid="ignore"):
        world = p[..., :3] / p[..., 3:4]
    world[~finite | ~np.all(np.isfinite(world), axis=-1)] = np.inf
    return world


def linearize_depth(ndc_depth, projection) -> np.ndarray:
    """View-space distance along the view axis (positive in front of the camera) from NDC depth.

    Host mirror of :func:`ndc_to_view_depth`; handles perspective and orthographic OpenGL-style
    projections (the matrix without the view part, or any matrix whose rows 2 and 3 depend only on
    view-space z).

    Args:
        ndc_depth: NDC depths, any shape; non-finite entries (empty texels) map to +inf.
        projection: 4x4 projection matrix.

    Returns:
        float64 array of the same shape, scene units.

    Raises:
        ValueError: malformed projection, or rows 2/3 of it depending on view-space x or y.
    """
    p = check_matrix(projection, "projection")
    if np.any(p[2:, :2] != 0.0):
        raise ValueError("projection: rows 2 and 3 must not depend on view-space x or y")
    z = np.asarray(ndc_depth, dtype=np.float64)
    finite = np.isfinite(z)
    zz = np.where(finite, z, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = -(p[2, 3] - p[3, 3] * zz) / (p[3, 2] * zz - p[2, 2])
    return np.where(finite & np.isfinite(d), d, np.inf)
