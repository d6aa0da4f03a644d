"""Triangle rasterization into depth maps for any 4x4 world -> clip matrix, with depth peeling, exact as GPU
rasterizers are (fixed-point positions, top-left rule, packed-key z-buffer: :mod:`.funcs`). Entry points:
:func:`rasterize`, :func:`rasterize_keys` (with a per-band callback for fused passes), :func:`rasterize_linear_depth`
(shadow maps), :func:`coverage_count`; input checks and numpy depth utilities are re-exported from :mod:`.inputs` and
:mod:`.depth`.

Conventions (OpenGL-style): NDC in [-1, 1]^3, z_ndc = -1 at the near plane; pixel (i, j), j from the TOP row, has its
centre at x_ndc = 2 (i + 0.5) / width - 1, y_ndc = 1 - 2 (j + 0.5) / height, the centre of the camera's ray.

``exact_edges``: centres within the snapping error (~1/1024 pixel) of an edge are decided on the unrounded float64
plane through the eye and the edge, as a ray would, still watertight. Clipping is homogeneous, against the near plane
and a guard band (+-2^18 pixels); ``clip_near=False`` keeps only the guard band (which still cuts everything behind a
perspective centre), as Klehm 2014's projective rectification needs (Sec. 4.2).

Parallelism: CPU atomics are not atomic across concurrent launches, so each launch owns the keys it writes. Sparse
scenes are cut into row bands (triangles binned to the bands they overlap); dense ones into chunks of triangles with
private key buffers merged by a minimum. Both give bitwise the result of a single scan.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..runtime import parallel
from ..runtime.device import default_device, module_options
from .depth import RasterResult, linearize_depth, pixel_center_ndc_grid, unproject
from .funcs import (
    EMPTY_KEY,
    EXACT_MARGIN_SUBPIXELS,
    GUARD_BAND_PIXELS,
    MAX_RESOLUTION,
    SUBPIXEL_BITS,
    ClipEdges,
    ClipPolygon,
    ClipSources,
    EdgeTolerances,
    ProjectedVertices,
    RasterParams,
    ScreenPolygon,
    bbox_rows,
    clip_outcode,
    clip_polygon_plane,
    clip_polygon_plane_edges,
    clip_position,
    clip_triangle,
    clip_triangle_edges,
    depth_key,
    edge_function,
    edge_tolerance,
    exact_edge_inside,
    exact_edge_plane,
    homogeneous_screen,
    key_ndc_depth,
    key_triangle,
    ndc_to_view_depth,
    pixel_center_ndc,
    polygon_rows,
    project_vertex,
    snap_to_screen,
    top_left_bias,
    triangle_crossing,
    triangle_edge_planes,
    triangle_rows,
)
from .inputs import as_points, as_triangles, check_matrix, check_size, is_affine
from .scan import (
    edge_span,
    emit_fragment,
    polygon_edge_exact,
    rasterize_exact_triangle_rows,
    rasterize_screen_triangle,
    rasterize_screen_triangle_rows,
    rasterize_screen_triangle_rows_exact,
    rasterize_triangle,
    rasterize_triangle_rows,
)

module_options()

_EMPTY_KEY = wp.constant(wp.int64(EMPTY_KEY))

#: Triangles (or vertices) per Warp thread on the CPU (amortises the per-thread cost of a CPU launch).
TRIANGLES_PER_CPU_THREAD = 64
#: Row bands per CPU thread (more bands than threads even out unequal band costs).
BANDS_PER_THREAD = 8
#: Fewest image rows in a band.
MIN_BAND_ROWS = 16
#: Fewest triangles in a chunk scanned into its own key buffer (when not banded).
MIN_PIECE_TRIANGLES = 2048
#: Fewest pixels in a band (each band costs a few launches: small images get few bands).
MIN_BAND_PIXELS = 32768
#: Up to this many triangles per pixel, CPU threads split the image into row bands (else chunks of triangles):
#: banding shares out large triangles and needs no merge.
BANDED_TRIANGLES_PER_PIXEL = 0.125




@wp.kernel
def project_vertices_kernel(
    points: wp.array(dtype=wp.vec3),
    view_proj: wp.mat44d,
    width: int,
    height: int,
    guard_x: float,
    guard_y: float,
    batch: int,
    verts: ProjectedVertices,
    offset: int,
):
    """Vertex pass (:func:`project_vertex`): thread ``tid + offset`` handles vertices
    [batch (tid + offset), batch (tid + offset + 1))."""
    first = (wp.tid() + offset) * batch
    for i in range(first, wp.min(first + batch, points.shape[0])):
        project_vertex(verts, i, points[i], view_proj, width, height, guard_x, guard_y)


@wp.kernel
def rasterize_kernel(
    verts: ProjectedVertices,
    triangles: wp.array2d(dtype=wp.int32),
    params: RasterParams,
    prev_keys: wp.array2d(dtype=wp.int64),
    keys: wp.array2d(dtype=wp.int64),
    counts: wp.array2d(dtype=wp.int32),
    stop: int,
    batch: int,
    offset: int,
):
    """Triangles [offset + tid * batch, offset + (tid + 1) * batch) clipped to ``stop``, a batch per thread."""
    start = offset + wp.tid() * batch
    for t in range(start, wp.min(start + batch, stop)):
        rasterize_triangle(t, verts, triangles, params, prev_keys, keys, counts)


@wp.struct
class TriangleBins:
    """Triangles binned to horizontal bands of image rows (see :func:`triangle_rows_kernel`)."""

    rows: wp.array(dtype=wp.vec2i)  # per triangle: image rows (first, last) it may cover, (0, -1) for none
    band_of_row: wp.array(dtype=wp.int32)  # band index of each image row
    start: wp.array(dtype=wp.int32)  # bands + 1 offsets: band b holds tris[start[b]:start[b + 1]]
    tris: wp.array(dtype=wp.int32)  # triangle indices, band by band, ascending within a band


@wp.kernel
def triangle_rows_kernel(
    verts: ProjectedVertices,
    triangles: wp.array2d(dtype=wp.int32),
    params: RasterParams,
    bins: TriangleBins,
    counts: wp.array2d(dtype=wp.int32),
    batch: int,
    chunk: int,
    offset: int,
):
    """Triangle pass: ``bins.rows[t]`` = rows (first, last) triangle ``t`` may cover, and ``counts[chunk, b]`` +=
    the triangles overlapping band b. Concurrent launches take distinct ``chunk`` rows."""
    first = (wp.tid() + offset) * batch
    for t in range(first, wp.min(first + batch, triangles.shape[0])):
        r = triangle_rows(t, verts, triangles, params)
        bins.rows[t] = r
        if r[0] <= r[1]:
            for b in range(bins.band_of_row[r[0]], bins.band_of_row[r[1]] + 1):
                counts[chunk, b] += 1


@wp.kernel
def bin_triangles_kernel(bins: TriangleBins, cursor: wp.array2d(dtype=wp.int32), batch: int, chunk: int, offset: int):
    """Write each triangle to the bins of the bands it overlaps, at ``cursor[chunk, b]`` (exclusive prefix sums of
    the counts, so chunks fill disjoint slots in ascending order)."""
    first = (wp.tid() + offset) * batch
    for t in range(first, wp.min(first + batch, bins.rows.shape[0])):
        r = bins.rows[t]
        if r[0] <= r[1]:
            for b in range(bins.band_of_row[r[0]], bins.band_of_row[r[1]] + 1):
                k = cursor[chunk, b]
                bins.tris[k] = t
                cursor[chunk, b] = k + 1


@wp.kernel
def rasterize_band_kernel(
    verts: ProjectedVertices,
    triangles: wp.array2d(dtype=wp.int32),
    params: RasterParams,
    bins: TriangleBins,
    band: wp.vec3i,
    prev_keys: wp.array2d(dtype=wp.int64),
    keys: wp.array2d(dtype=wp.int64),
    counts: wp.array2d(dtype=wp.int32),
    batch: int,
):
    """The triangles of bin ``band[2]``, scanned over rows [band[0], band[1]] only, ``batch`` per thread."""
    first = bins.start[band[2]] + wp.tid() * batch
    for k in range(first, wp.min(first + batch, bins.start[band[2] + 1])):
        t = bins.tris[k]
        r = bins.rows[t]
        rasterize_triangle_rows(t, verts, triangles, params, wp.max(r[0], band[0]), wp.min(r[1], band[1]), prev_keys,
                                keys, counts)


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


@wp.kernel
def linear_depth_kernel(
    keys: wp.array2d(dtype=wp.int64),
    p22: wp.float64,
    p23: wp.float64,
    p32: wp.float64,
    p33: wp.float64,
    depth: wp.array2d(dtype=wp.float32),
    offset: int,
):
    """Packed keys -> float32 view-space distance (+inf where empty), a row per thread (as :func:`linearize_depth`)."""
    j = wp.tid() + offset
    for i in range(keys.shape[1]):
        key = keys[j, i]
        out = wp.inf
        if key != _EMPTY_KEY:
            z = wp.float64(key_ndc_depth(key))
            d = -(p23 - p33 * z) / (p32 * z - p22)
            if wp.isfinite(d):
                out = wp.float32(d)
        depth[j, i] = out




#: numpy layout (scalar type, trailing shape) of the Warp dtypes :func:`empty_array` backs with numpy memory
_NUMPY_LAYOUT = {wp.int64: (np.int64, ()), wp.int32: (np.int32, ()), wp.float32: (np.float32, ()),
                 wp.vec3: (np.float32, (3,)), wp.vec4: (np.float32, (4,))}


def empty_array(shape, dtype, device: str, fill=None) -> wp.array:
    """``wp.empty`` (or ``wp.full``) that on the CPU takes its memory from numpy, which asks for transparent huge
    pages: far fewer page faults on fresh image-sized buffers (docs/benchmarks.md, "Raster buffers from numpy").
    """
    layout = _NUMPY_LAYOUT.get(dtype)
    if layout is None or not wp.get_device(device).is_cpu:
        return wp.empty(shape, dtype=dtype, device=device) if fill is None else wp.full(shape, fill, dtype=dtype,
                                                                                        device=device)
    shape = (shape,) if isinstance(shape, int) else tuple(shape)
    a = np.empty(shape + layout[1], layout[0]) if fill is None else np.full(shape + layout[1], fill, layout[0])
    return wp.array(a, dtype=dtype, device=device, copy=False)


def project_vertices(
    points: wp.array,
    view_proj: np.ndarray,
    width: int,
    height: int,
    guard_x: float,
    guard_y: float,
    device: str,
    threads: int | None = None,
) -> ProjectedVertices:
    """Vertex pass: clip coordinates, snapped and unrounded screen positions and outcodes of ``points``."""
    n = points.shape[0]
    verts = ProjectedVertices()
    verts.clip = wp.empty(n, dtype=wp.vec4, device=device)
    verts.screen = wp.empty(n, dtype=wp.vec3d, device=device)  # entries of vertices outside the guard band stay unset
    verts.outcode = wp.empty(n, dtype=wp.int32, device=device)
    verts.hom = wp.empty(n, dtype=wp.vec3d, device=device)
    verts.dev = wp.empty(n, dtype=wp.float64, device=device)
    batch = TRIANGLES_PER_CPU_THREAD if wp.get_device(device).is_cpu else 1
    parallel.launch_rows(
        project_vertices_kernel, (n + batch - 1) // batch,
        [points, wp.mat44d(*view_proj.ravel()), width, height, guard_x, guard_y, batch, verts],
        device, threads=threads, min_chunk=128,
    )
    return verts


class _Setup:
    """Everything a rasterization pass needs, prepared once per call: checked inputs, the vertex pass, and the split
    across CPU threads: row bands (:attr:`banded`) or chunks of triangles (:attr:`pieces`)."""

    def __init__(self, vertices, triangles, view_proj, width, height, clamp_depth, cull_backfaces, device, threads,
                 clip_near=None, exact_edges=False):
        self.device = default_device(device)
        self.exact_edges = int(bool(exact_edges))
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
        self.is_cpu = wp.get_device(self.device).is_cpu
        self.batch = TRIANGLES_PER_CPU_THREAD if self.is_cpu else 1
        self.verts = project_vertices(
            points, self.view_proj, self.width, self.height, self.guard_x, self.guard_y, self.device, self.threads
        )
        self.dummy_keys = wp.zeros((1, 1), dtype=wp.int64, device=self.device)
        self.dummy_counts = wp.zeros((1, 1), dtype=wp.int32, device=self.device)
        self.dummy_ints = wp.zeros(1, dtype=wp.int32, device=self.device)
        n = self.tris.shape[0]
        multi = self.is_cpu and self.threads > 1
        #: row bands [start, stop): the CPU tasks of the scan (banded) or of the merge and resolve (else)
        self.band_list = [(0, self.height)]
        if multi:
            parts = min(BANDS_PER_THREAD * self.threads, self.height // MIN_BAND_ROWS,
                        self.width * self.height // MIN_BAND_PIXELS)
            self.band_list = parallel.chunks(self.height, max(1, parts))
        self.banded = len(self.band_list) > 1 and n <= BANDED_TRIANGLES_PER_PIXEL * self.width * self.height
        #: triangle ranges [start, stop) scanned into separate key buffers (not banded)
        self.pieces = [(0, n)]
        if self.banded:
            self._bin()
        elif multi:
            self.pieces = parallel.chunks(n, self.threads, min_chunk=MIN_PIECE_TRIANGLES) or [(0, 0)]
        wp.load_module(rasterize_kernel.module, device=self.device)

    def _bin(self) -> None:
        """Triangle pass and binning of the triangles to the bands, both in chunks across threads."""
        n = self.tris.shape[0]
        bands = len(self.band_list)
        bins = self.bins = TriangleBins()
        bins.rows = wp.empty(n, dtype=wp.vec2i, device=self.device)
        sizes = [stop - start for start, stop in self.band_list]
        bins.band_of_row = wp.array(np.repeat(np.arange(bands, dtype=np.int32), sizes), device=self.device)
        bins.start = bins.tris = self.dummy_ints
        nbatch = (n + self.batch - 1) // self.batch
        pieces = parallel.chunks(nbatch, self.threads * 4, min_chunk=16)
        counts = wp.zeros((max(1, len(pieces)), bands), dtype=wp.int32, device=self.device)
        params = self.params(0, 0)

        def count(c):
            start, stop = pieces[c]
            wp.launch(triangle_rows_kernel, dim=stop - start,
                      inputs=[self.verts, self.tris, params, bins, counts, self.batch, c, start], device=self.device)

        parallel.run_parallel(count, list(range(len(pieces))), self.threads)
        per_chunk = counts.numpy()
        start = np.concatenate([[0], np.cumsum(per_chunk.sum(axis=0))]).astype(np.int32)
        bins.start = wp.array(start, dtype=wp.int32, device=self.device)
        bins.tris = wp.empty(max(1, int(start[-1])), dtype=wp.int32, device=self.device)
        cursor = wp.array((start[:-1] + np.cumsum(per_chunk, axis=0) - per_chunk).astype(np.int32), dtype=wp.int32,
                          device=self.device)

        def scatter(c):
            begin, stop = pieces[c]
            wp.launch(bin_triangles_kernel, dim=stop - begin, inputs=[bins, cursor, self.batch, c, begin],
                      device=self.device)

        parallel.run_parallel(scatter, list(range(len(pieces))), self.threads)

    def params(self, count_mode: int, peel: int) -> RasterParams:
        p = RasterParams()
        p.width, p.height = self.width, self.height
        p.guard_x, p.guard_y = self.guard_x, self.guard_y
        p.clip_near, p.clamp_depth = self.clip_near, self.clamp_depth
        p.cull_backfaces = self.cull_backfaces
        p.count_mode, p.peel = count_mode, peel
        p.exact_edges = self.exact_edges
        return p

    def scan_band(self, band: int, params, prev_keys, keys, counts) -> None:
        """Rasterize the triangles of band number ``band`` of :attr:`band_list` into its rows (banded)."""
        start, stop = self.band_list[band]
        n = int(self.bins.tris.shape[0])
        batch = n if self.is_cpu else 1  # one CPU thread per band: no per-thread cost
        wp.launch(
            rasterize_band_kernel, dim=(n + batch - 1) // batch,
            inputs=[self.verts, self.tris, params, self.bins, wp.vec3i(start, stop - 1, band), prev_keys, keys, counts,
                    batch],
            device=self.device,
        )

    def scan_piece(self, piece: int, params, prev_keys, keys, counts) -> None:
        """Rasterize the triangles of :attr:`pieces` number ``piece`` into the whole image (not banded)."""
        start, stop = self.pieces[piece]
        if stop > start:
            wp.launch(
                rasterize_kernel, dim=(stop - start + self.batch - 1) // self.batch,
                inputs=[self.verts, self.tris, params, prev_keys, keys, counts, stop, self.batch, start],
                device=self.device,
            )

    def render_keys(self, keys, on_rows=None) -> None:
        """Rasterize all layers of ``keys`` (layers, H, W); ``on_rows(layer, start, stop)`` runs (in a worker
        thread) once those rows are final."""
        layers = keys.shape[0]
        first = self.params(0, 0)
        peel = self.params(0, 1)
        bands = list(range(len(self.band_list)))
        if self.banded:

            def band_task(band):
                r0, r1 = self.band_list[band]
                for layer in range(layers):
                    keys[layer][r0:r1].fill_(EMPTY_KEY)
                    if layer == 0:
                        self.scan_band(band, first, self.dummy_keys, keys[0], self.dummy_counts)
                    else:
                        self.scan_band(band, peel, keys[layer - 1], keys[layer], self.dummy_counts)
                    if on_rows is not None:
                        on_rows(layer, r0, r1)

            parallel.run_parallel(band_task, bands, self.threads)
            return
        private = [empty_array((self.height, self.width), wp.int64, self.device) for _ in self.pieces[1:]]
        for layer in range(layers):
            self._render_layer(keys, layer, first if layer == 0 else peel, private, on_rows)

    def _render_layer(self, keys, layer: int, params, private: list, on_rows) -> None:
        """One layer, not banded: the pieces in parallel, then per band the merge and ``on_rows``."""
        buffers = [keys[layer], *private]
        prev = self.dummy_keys if layer == 0 else keys[layer - 1]

        def piece_task(k):
            buffers[k].fill_(EMPTY_KEY)
            self.scan_piece(k, params, prev, buffers[k], self.dummy_counts)

        def merge_task(band):
            r0, r1 = self.band_list[band]
            if private:
                out = keys[layer].numpy()[r0:r1]
                for buf in private:
                    np.minimum(out, buf.numpy()[r0:r1], out=out)  # exact: packed keys
            if on_rows is not None:
                on_rows(layer, r0, r1)

        parallel.run_parallel(piece_task, list(range(len(self.pieces))), self.threads)
        if private or on_rows is not None:
            parallel.run_parallel(merge_task, list(range(len(self.band_list))), self.threads)

    def render_counts(self) -> np.ndarray:
        """(H, W) int32 fragment counts (count mode, no depth test)."""
        params = self.params(1, 0)
        if self.banded:
            counts = empty_array((self.height, self.width), wp.int32, self.device, fill=0)
            parallel.run_parallel(lambda band: self.scan_band(band, params, self.dummy_keys, self.dummy_keys, counts),
                                  list(range(len(self.band_list))), self.threads)
            return counts.numpy().copy()
        buffers = [empty_array((self.height, self.width), wp.int32, self.device, fill=0) for _ in self.pieces]
        parallel.run_parallel(lambda k: self.scan_piece(k, params, self.dummy_keys, self.dummy_keys, buffers[k]),
                              list(range(len(self.pieces))), self.threads)
        total = buffers[0].numpy().copy()
        for buf in buffers[1:]:
            total += buf.numpy()
        return total


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
    exact_edges: bool = False,
    device: str | None = None,
    threads: int | None = None,
) -> RasterResult:
    """Rasterize a triangle mesh into ``layers`` depth layers seen through ``view_proj``.

    Args:
        vertices: (N, 3) world-space positions (numpy or ``wp.array(dtype=wp.vec3)``).
        triangles: (T, 3) vertex indices (integer numpy or int32 ``wp.array``).
        view_proj: 4x4 world -> clip matrix (OpenGL-style, column vectors).
        width: image width in pixels (1 .. MAX_RESOLUTION).
        height: image height in pixels; row 0 is the top (NDC y = +1).
        layers: depth-peeled layers (>= 1): layer n is the nearest surface strictly behind layer n-1 in
            (depth, triangle index) order.
        clamp_depth: keep fragments beyond the far plane at +1 and, for affine matrices, those before the near
            plane at -1 (shadow maps).
        cull_backfaces: skip triangles clockwise in NDC (front = counter-clockwise).
        clip_near: None clips at z >= -w unless ``clamp_depth`` with an affine matrix; False never (guard band only).
        exact_edges: decide centres near an edge on its unrounded projection, matching :func:`.raycast.raycast_depth`.
        device: Warp device (default :func:`..runtime.device.default_device`).
        threads: CPU worker threads (default :func:`..runtime.parallel.thread_count`).

    Returns:
        :class:`RasterResult` with (layers, height, width) ``ndc_depth`` (float32, +inf where empty)
        and ``tri_id`` (int32, -1 where empty).

    Raises:
        ValueError: malformed or non-finite inputs, out-of-range indices, sizes outside [1, MAX_RESOLUTION], layers < 1.
    """
    if isinstance(layers, bool) or not isinstance(layers, (int, np.integer)) or layers < 1:
        raise ValueError(f"layers must be an integer >= 1, got {layers!r}")
    s = _Setup(vertices, triangles, view_proj, width, height, clamp_depth, cull_backfaces, device, threads, clip_near,
               exact_edges)
    h, w = s.height, s.width
    keys = empty_array((int(layers), h, w), wp.int64, s.device)
    ndc_depth = empty_array((int(layers), h, w), wp.float32, s.device)
    tri_id = empty_array((int(layers), h, w), wp.int32, s.device)

    def resolve(layer, r0, r1):
        wp.launch(resolve_keys_kernel, dim=r1 - r0, inputs=[keys[layer], layer, ndc_depth, tri_id, r0], device=s.device)

    s.render_keys(keys, resolve)
    return RasterResult.from_device(ndc_depth, tri_id, keys, s.view_proj)


def rasterize_keys(
    vertices,
    triangles,
    view_proj,
    width: int,
    height: int,
    *,
    on_rows=None,
    clamp_depth: bool = False,
    cull_backfaces: bool = False,
    clip_near: bool | None = None,
    exact_edges: bool = False,
    device: str | None = None,
    threads: int | None = None,
) -> wp.array:
    """One depth layer as (height, width) int64 packed keys on the device (EMPTY_KEY where empty), for passes fused
    with the scan: ``on_rows(keys, start, stop)`` runs, from the worker thread that rasterized them, once those rows
    are final. Other arguments as in :func:`rasterize`."""
    s = _Setup(vertices, triangles, view_proj, width, height, clamp_depth, cull_backfaces, device, threads, clip_near,
               exact_edges)
    keys = empty_array((1, s.height, s.width), wp.int64, s.device)
    s.render_keys(keys, None if on_rows is None else (lambda layer, r0, r1: on_rows(keys[0], r0, r1)))
    return keys[0]


def rasterize_linear_depth(
    vertices,
    triangles,
    view_proj,
    projection,
    width: int,
    height: int,
    *,
    clamp_depth: bool = False,
    device: str | None = None,
    threads: int | None = None,
) -> np.ndarray:
    """Nearest view-space distance per texel, float32 (+inf where empty), resolved band by band with the scan;
    bitwise ``linearize_depth(rasterize(...).ndc_depth[0], projection)``. ``projection``: the 4x4 projection part of
    ``view_proj``; other arguments as in :func:`rasterize`."""
    p = check_matrix(projection, "projection")
    if np.any(p[2:, :2] != 0.0):
        raise ValueError("projection: rows 2 and 3 must not depend on view-space x or y")
    coeffs = [wp.float64(float(p[2, 2])), wp.float64(float(p[2, 3])), wp.float64(float(p[3, 2])),
              wp.float64(float(p[3, 3]))]
    w, h = check_size(width, height)
    depth = empty_array((h, w), wp.float32, default_device(device))

    def resolve(keys, r0, r1):
        wp.launch(linear_depth_kernel, dim=r1 - r0, inputs=[keys, *coeffs, depth, r0], device=depth.device)

    rasterize_keys(vertices, triangles, view_proj, w, h, on_rows=resolve, clamp_depth=clamp_depth, device=device,
                   threads=threads)
    return depth.numpy()


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
    exact_edges: bool = False,
    device: str | None = None,
    threads: int | None = None,
) -> np.ndarray:
    """(height, width) int32 count of the fragments each pixel centre receives (no depth test), row 0 at the top:
    exactly 1 per covered pixel of a closed surface."""
    s = _Setup(vertices, triangles, view_proj, width, height, clamp_depth, cull_backfaces, device, threads, clip_near,
               exact_edges)
    return s.render_counts()


__all__ = [
    "BANDED_TRIANGLES_PER_PIXEL",
    "BANDS_PER_THREAD",
    "EMPTY_KEY",
    "EXACT_MARGIN_SUBPIXELS",
    "GUARD_BAND_PIXELS",
    "MAX_RESOLUTION",
    "MIN_BAND_PIXELS",
    "MIN_BAND_ROWS",
    "MIN_PIECE_TRIANGLES",
    "SUBPIXEL_BITS",
    "TRIANGLES_PER_CPU_THREAD",
    "ClipEdges",
    "ClipPolygon",
    "ClipSources",
    "EdgeTolerances",
    "ProjectedVertices",
    "RasterParams",
    "RasterResult",
    "ScreenPolygon",
    "TriangleBins",
    "as_points",
    "as_triangles",
    "bbox_rows",
    "bin_triangles_kernel",
    "check_matrix",
    "check_size",
    "clip_outcode",
    "clip_polygon_plane",
    "clip_polygon_plane_edges",
    "clip_position",
    "clip_triangle",
    "clip_triangle_edges",
    "coverage_count",
    "depth_key",
    "edge_function",
    "edge_span",
    "edge_tolerance",
    "emit_fragment",
    "empty_array",
    "exact_edge_inside",
    "exact_edge_plane",
    "homogeneous_screen",
    "is_affine",
    "key_ndc_depth",
    "key_triangle",
    "linear_depth_kernel",
    "linearize_depth",
    "ndc_to_view_depth",
    "pixel_center_ndc",
    "pixel_center_ndc_grid",
    "polygon_edge_exact",
    "polygon_rows",
    "project_vertex",
    "project_vertices",
    "project_vertices_kernel",
    "rasterize",
    "rasterize_band_kernel",
    "rasterize_exact_triangle_rows",
    "rasterize_kernel",
    "rasterize_keys",
    "rasterize_linear_depth",
    "rasterize_screen_triangle",
    "rasterize_screen_triangle_rows",
    "rasterize_screen_triangle_rows_exact",
    "rasterize_triangle",
    "rasterize_triangle_rows",
    "resolve_keys_kernel",
    "snap_to_screen",
    "top_left_bias",
    "triangle_crossing",
    "triangle_edge_planes",
    "triangle_rows",
    "triangle_rows_kernel",
    "unproject",
]
