"""Triangle rasterization into depth maps for any 4x4 world -> clip matrix, with depth peeling.

The rasterizer is exact in the sense of GPU hardware rasterizers: fixed-point screen positions,
int64 edge functions and the top-left fill rule hit every pixel centre covered by a closed
tessellated surface exactly once, and the z-buffer resolves packed (depth, triangle index) int64
keys with ``wp.atomic_min`` (see :mod:`warpscatter.raster_funcs` for these device building blocks).
This module holds the kernels and the host entry points :func:`rasterize` and
:func:`coverage_count`; input checks live in :mod:`warpscatter.raster_inputs` and the numpy depth
utilities (:func:`unproject`, :func:`linearize_depth`, :func:`pixel_center_ndc_grid`) in
:mod:`warpscatter.raster_depth`. The names of those modules are re-exported here.

Conventions (OpenGL-style, as in :mod:`warpscatter.scene.camera`): clip space -> NDC in [-1, 1]^3,
z_ndc = -1 at the near plane. Pixel (i, j), j counted from the TOP row, has its centre at
x_ndc = 2 (i + 0.5) / width - 1, y_ndc = 1 - 2 (j + 0.5) / height, which is exactly the centre of
the ray :meth:`Camera.ray_directions` gives for that pixel.

Clipping: triangles are clipped in homogeneous clip space against the near plane (z >= -w) and a
guard band on x and y (|x|, |y| <= g w, screen positions within +-2^18 pixels), watertight along
shared edges. Fragments beyond the far plane (z_ndc > 1) are discarded. With ``clamp_depth=True``
(shadow maps) fragments beyond the far plane are kept at depth +1 and, for affine (orthographic)
matrices whose w is a positive constant, nothing is clipped at the near plane: geometry in front of
it is kept at depth -1. A perspective matrix keeps its near clipping even with ``clamp_depth``
(points behind the centre of projection have no meaningful projection) unless the caller passes
``clip_near=False``: then only the guard band clips, and since |x| <= g w and |y| <= g w imply
w >= 0 (w = 0 only at the centre of projection itself, where the triangle is dropped), everything
behind the centre of projection is still cut away while geometry in front of the near plane is kept
(at depth -1 with ``clamp_depth``). Klehm 2014's projective rectification (Sec. 4.2, projecting
along x with the camera as centre of projection) needs exactly this: casters between the light and
the camera frustum stay in the map.

Parallelism: one CPU launch runs on one core, so the triangles are split into contiguous chunks,
one per thread, each rasterizing into a private key buffer; the buffers are merged with a minimum
over the packed keys, which is exact. On CUDA one launch with real atomics does the work.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from . import parallel
from .raster_depth import linearize_depth, pixel_center_ndc_grid, unproject
from .raster_funcs import (
    EMPTY_KEY,
    GUARD_BAND_PIXELS,
    MAX_RESOLUTION,
    SUBPIXEL_BITS,
    ClipPolygon,
    ClipSources,
    ProjectedVertices,
    RasterParams,
    ScreenPolygon,
    clip_outcode,
    clip_polygon_plane,
    clip_position,
    depth_key,
    edge_function,
    key_ndc_depth,
    key_triangle,
    ndc_to_view_depth,
    pixel_center_ndc,
    project_vertex,
    rasterize_screen_triangle,
    rasterize_triangle,
    snap_to_screen,
    top_left_bias,
)
from .raster_inputs import as_points, as_triangles, check_matrix, check_size, is_affine
from .wpinit import default_device, module_options

module_options()

#: Triangles (or vertices) per Warp thread on the CPU (amortises the per-thread cost of a CPU launch).
TRIANGLES_PER_CPU_THREAD = 64


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
    """Triangles [offset + tid * batch, offset + (tid + 1) * batch) clipped to ``stop``, one thread each
    batch (batches amortise the per-thread cost of CPU launches; use batch 1 on CUDA)."""
    start = offset + wp.tid() * batch
    for t in range(start, wp.min(start + batch, stop)):
        rasterize_triangle(t, verts, triangles, params, prev_keys, keys, counts)


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

    @classmethod
    def from_device(cls, ndc_depth: wp.array, tri_id: wp.array, keys: wp.array | None, view_proj) -> RasterResult:
        """Result holding the device arrays ``ndc_depth`` and ``tri_id`` and their host copies."""
        return cls(
            ndc_depth=ndc_depth.numpy(), tri_id=tri_id.numpy(), keys=keys, device_ndc_depth=ndc_depth,
            device_tri_id=tri_id, view_proj=view_proj,
        )


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
    """Vertex pass: clip coordinates, snapped screen positions and outcodes of ``points``."""
    n = points.shape[0]
    verts = ProjectedVertices()
    verts.clip = wp.empty(n, dtype=wp.vec4, device=device)
    verts.screen = wp.empty(n, dtype=wp.vec3d, device=device)  # entries of vertices outside the guard band stay unset
    verts.outcode = wp.empty(n, dtype=wp.int32, device=device)
    batch = TRIANGLES_PER_CPU_THREAD if wp.get_device(device).is_cpu else 1
    parallel.launch_rows(
        project_vertices_kernel, (n + batch - 1) // batch,
        [points, wp.mat44d(*view_proj.ravel()), width, height, guard_x, guard_y, batch, verts],
        device, threads=threads, min_chunk=1024,
    )
    return verts


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
        self.verts = project_vertices(
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
            inputs=[self.verts, self.tris, params, prev_keys, keys, counts, stop, batch, start],
            device=self.device,
        )

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
        )
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
    return RasterResult.from_device(ndc_depth, tri_id, keys, s.view_proj)


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
    )
    total = buffers[0].numpy().copy()
    for buf in buffers[1:]:
        total += buf.numpy()
    return total


__all__ = [
    "EMPTY_KEY",
    "GUARD_BAND_PIXELS",
    "MAX_RESOLUTION",
    "SUBPIXEL_BITS",
    "TRIANGLES_PER_CPU_THREAD",
    "ClipPolygon",
    "ClipSources",
    "ProjectedVertices",
    "RasterParams",
    "RasterResult",
    "ScreenPolygon",
    "as_points",
    "as_triangles",
    "check_matrix",
    "check_size",
    "clip_outcode",
    "clip_polygon_plane",
    "clip_position",
    "coverage_count",
    "depth_key",
    "edge_function",
    "is_affine",
    "key_ndc_depth",
    "key_triangle",
    "linearize_depth",
    "ndc_to_view_depth",
    "pixel_center_ndc",
    "pixel_center_ndc_grid",
    "project_vertex",
    "project_vertices",
    "project_vertices_kernel",
    "rasterize",
    "rasterize_kernel",
    "rasterize_screen_triangle",
    "rasterize_triangle",
    "resolve_keys_kernel",
    "snap_to_screen",
    "top_left_bias",
    "unproject",
]
