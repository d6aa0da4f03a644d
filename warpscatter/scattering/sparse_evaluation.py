"""Evaluating a per-pixel look-up on fewer pixels: a grid, then only the pixels the grid cannot interpolate.

warpscatter's (the papers evaluate every pixel): the look-up runs on a grid of every ``stride``-th pixel in x and y
(the image's last row and column included), and every other pixel takes the bilinear interpolation of its grid
cell's corners when they agree: all four within ``depth_tolerance`` (relative) of the pixel's camera distance, none
left to the marcher (``end_zone``), and their radiance (largest channel) spread by at most ``tolerance`` times the
largest. The rest (silhouettes, edges of shafts and shadows) are evaluated directly, as Engelhardt 2010 places its
epipolar samples. With ``levels`` > 1 the grid itself is filled coarse to fine, each finer grid's new nodes tested in
the coarser grid's cells (:data:`COARSER_TOLERANCE`; the radiance divided by a known per-pixel ``scale``).

Kernels evaluating a :class:`PixelSet` index their pixels with :func:`set_pixel`, launched by :func:`evaluate_sparse`
over (rows, columns), the grid's, or (chunks, pixels per chunk) of a flat list (no thread idles on a short row).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import warp as wp

from ..runtime.device import default_device, module_options
from ..runtime.parallel import launch_rows

module_options()

#: Each coarser level's cells interpolate within this factor of the next finer level's radiance tolerance: a node it
#: fills is a corner of the finer cells, its error carried into theirs (docs/benchmarks.md, "Sparse evaluation").
COARSER_TOLERANCE = 0.5

#: ``PixelSet.mode``: every pixel of the image.
PIXELS_ALL = wp.constant(0)
#: ``PixelSet.mode``: the grid nodes (every ``stride``-th pixel; the last row and column too).
PIXELS_GRID = wp.constant(1)
#: ``PixelSet.mode``: a flat list of pixels (``pixels[:count]``, (row, column) each), launched ``stride`` per row.
PIXELS_LISTED = wp.constant(2)


@wp.struct
class PixelSet:
    """Which pixels a launch evaluates (:func:`set_pixel`)."""

    mode: int
    stride: int  # PIXELS_GRID: pixels between grid nodes; PIXELS_LISTED: listed pixels per launch row
    pixels: wp.array(dtype=wp.vec2i)  # PIXELS_LISTED: the (row, column) of each listed pixel
    count: int  # PIXELS_LISTED: how many


@wp.func
def grid_node(m: int, stride: int, size: int) -> int:
    """Pixel coordinate of grid node m (the last node is clamped to the image's edge)."""
    return wp.min(m * stride, size - 1)


@wp.func
def set_pixel(ps: PixelSet, height: int, width: int, a: int, b: int):
    """(j, i, whether there is one) of launch index (a, b) of a :class:`PixelSet` launch."""
    if ps.mode == PIXELS_GRID:
        return grid_node(a, ps.stride, height), grid_node(b, ps.stride, width), True
    if ps.mode == PIXELS_LISTED:
        k = a * ps.stride + b
        if k >= ps.count:
            return 0, 0, False
        p = ps.pixels[k]
        return p[0], p[1], True
    return a, b, True


@wp.func
def node_span(x: int, stride: int, size: int):
    """(x0, x1, weight f of x1, whether x is a node) of the grid cell around pixel coordinate x; a node keeps the
    cell after it."""
    x0 = (x // stride) * stride
    x1 = wp.min(x0 + stride, size - 1)
    f = float(0.0)
    if x1 > x0:
        f = float(x - x0) / float(x1 - x0)
    return x0, x1, f, x == x0 or x == size - 1


@wp.func
def near(corner_depth: float, depth: float, depth_tolerance: float) -> bool:
    """True if a corner at camera distance ``corner_depth`` lies within ``depth_tolerance`` (relative) of ``depth``."""
    return wp.abs(corner_depth - depth) <= depth_tolerance * depth


@wp.func
def channel_max(v: wp.vec3) -> float:
    """The largest of the three channels."""
    return wp.max(v[0], wp.max(v[1], v[2]))


@wp.struct
class GridPass:
    """One pass of :func:`evaluate_sparse`: which cells it interpolates, how strictly, and what it divides out."""

    stride: int  # pixels between the nodes whose cells are interpolated
    fine: int  # pixels between the pixels filled (1: every pixel; else the nodes of the next finer grid)
    tolerance: float  # largest spread of the corners' radiance, relative to the largest
    depth_tolerance: float  # largest relative camera-distance difference of a corner
    check_end_zone: int  # 1: a cell with a corner in end_zone is not interpolated
    end_zone: wp.array2d(dtype=wp.int32)  # 1 where the look-up left the pixel to the marcher (check_end_zone)
    scaled: int  # 1: the test and the interpolation see the radiance divided by scale
    scale: wp.array2d(dtype=wp.float32)  # a positive per-pixel factor of the radiance, interpolated apart (scaled)


@wp.kernel
def interpolate_grid_kernel(
    grid: GridPass,
    distance: wp.array2d(dtype=wp.float32),  # the G-buffer's camera distance
    out: wp.array2d(dtype=wp.vec3),  # in: the grid nodes' radiance; out: the interpolated pixels'
    columns: wp.array2d(dtype=wp.int32),  # out: per filled row, the pixels to evaluate directly
    counts: wp.array(dtype=wp.int32),  # out: per filled row, how many
    offset: int,
):
    # one thread per filled row (every fine-th, the last included), cell by cell: each filled pixel that is not a node
    # of the stride grid is interpolated or listed
    a = wp.tid() + offset
    stride = grid.stride
    fine = grid.fine
    height = distance.shape[0]
    width = distance.shape[1]
    j = grid_node(a, fine, height)
    y0, y1, fy, node_row = node_span(j, stride, height)
    # the last column is filled although it need not be a multiple of fine
    last_extra = int(0)
    if (width - 1) % fine != 0:
        last_extra = 1
    n = int(0)
    for x0 in range(0, width, stride):
        x1 = wp.min(x0 + stride, width - 1)
        c00 = out[y0, x0]
        c01 = out[y0, x1]
        c10 = out[y1, x0]
        c11 = out[y1, x1]
        if grid.scaled != 0:  # the radiance without its factor: the test and the interpolation see the smooth rest
            c00 = c00 / grid.scale[y0, x0]
            c01 = c01 / grid.scale[y0, x1]
            c10 = c10 / grid.scale[y1, x0]
            c11 = c11 / grid.scale[y1, x1]
        m00 = channel_max(c00)
        m01 = channel_max(c01)
        m10 = channel_max(c10)
        m11 = channel_max(c11)
        hi = wp.max(wp.max(m00, m01), wp.max(m10, m11))
        lo = wp.min(wp.min(m00, m01), wp.min(m10, m11))
        agree = hi - lo <= grid.tolerance * hi
        if grid.check_end_zone != 0:
            if (grid.end_zone[y0, x0] != 0 or grid.end_zone[y0, x1] != 0 or grid.end_zone[y1, x0] != 0
                    or grid.end_zone[y1, x1] != 0):
                agree = False
        d00 = distance[y0, x0]
        d01 = distance[y0, x1]
        d10 = distance[y1, x0]
        d11 = distance[y1, x1]
        end = wp.min(x0 + stride, width)
        filled = (end - x0 + fine - 1) // fine
        if end == width:
            filled += last_extra
        for k in range(filled):
            i = wp.min(x0 + k * fine, width - 1)
            if i == x0 or i == width - 1:
                if node_row:
                    continue  # a node of the stride grid: evaluated (or filled by the coarser grid)
            fx = float(0.0)
            if x1 > x0:
                fx = float(i - x0) / float(x1 - x0)
            if agree:
                depth = distance[j, i]
                if (near(d00, depth, grid.depth_tolerance) and near(d01, depth, grid.depth_tolerance)
                        and near(d10, depth, grid.depth_tolerance) and near(d11, depth, grid.depth_tolerance)):
                    top = c00 * (1.0 - fx) + c01 * fx
                    bottom = c10 * (1.0 - fx) + c11 * fx
                    value = top * (1.0 - fy) + bottom * fy
                    if grid.scaled != 0:
                        value = value * grid.scale[j, i]
                    out[j, i] = value
                    continue
            columns[a, n] = i
            n += 1
    counts[a] = n


def grid_size(size: int, stride: int) -> int:
    """Grid nodes along an image side of ``size`` pixels (every ``stride``-th, the last pixel included)."""
    return -(-(size - 1) // stride) + 1


def pixel_set(mode: int, stride: int = 1, pixels: wp.array | None = None, count: int = 0, device=None) -> PixelSet:
    """A :class:`PixelSet` (a 1-pixel placeholder for the list a mode does not read)."""
    device = default_device(device)
    ps = PixelSet()
    ps.mode = int(mode)
    ps.stride = int(stride)
    ps.pixels = pixels if pixels is not None else wp.zeros(1, dtype=wp.vec2i, device=device)
    ps.count = int(count)
    return ps


@wp.kernel
def gather_listed_kernel(fine: int, height: int, columns: wp.array2d(dtype=wp.int32),
                         counts: wp.array(dtype=wp.int32), starts: wp.array(dtype=wp.int32),
                         pixels: wp.array(dtype=wp.vec2i), offset: int):
    # one thread per filled row (interpolate_grid_kernel's): its listed columns into the flat list, row-major
    a = wp.tid() + offset
    j = grid_node(a, fine, height)
    start = starts[a]
    for n in range(counts[a]):
        pixels[start + n] = wp.vec2i(j, columns[a, n])


#: PIXELS_LISTED launches: listed pixels per launch row (the rows are split across threads).
LISTED_PER_ROW = 256


@dataclass
class ListedPass:
    """The pixels one pass of :func:`evaluate_sparse` listed: ``listed[a]`` in row a of every ``fine``-th row."""

    fine: int
    listed: np.ndarray  # (grid rows,) listed pixels per row
    pixels: wp.array | None  # (listed.sum(),) vec2i (row, column), row-major (read by SparseEvaluation.mask())


@dataclass
class SparseEvaluation:
    """What :func:`evaluate_sparse` did: the pixels it evaluated (the coarsest grid's nodes and the listed ones)."""

    stride: int
    height: int
    width: int
    grid_nodes: int
    levels: int = 1
    passes: list[ListedPass] = field(default_factory=list)  # coarse to fine; empty: stride 1

    @property
    def coarse_stride(self) -> int:
        """Pixels between the nodes of the grid the look-up ran on first."""
        return self.stride * 2 ** (self.levels - 1) if self.stride > 1 else 1

    @property
    def evaluated(self) -> int:
        """Pixels whose look-up ran."""
        return self.grid_nodes + sum(int(ps.listed.sum()) for ps in self.passes)

    @property
    def evaluated_fraction(self) -> float:
        """The evaluated pixels' share of the image."""
        return self.evaluated / float(self.height * self.width)

    def mask(self) -> np.ndarray:
        """(H, W) float32: 1 where the look-up ran, 0 where the pixel was interpolated."""
        m = np.zeros((self.height, self.width), np.float32)
        if not self.passes:
            m[:] = 1.0
            return m
        step = self.coarse_stride
        m[np.ix_(_grid_rows(self.height, step), _grid_rows(self.width, step))] = 1.0
        for ps in self.passes:
            if ps.pixels is not None:
                p = ps.pixels.numpy()  # on a GPU a copy: only when the debug output asks
                m[p[:, 0], p[:, 1]] = 1.0
        return m


def _grid_rows(size: int, stride: int) -> np.ndarray:
    """The pixel coordinates of the grid nodes along a side (numpy's :func:`grid_node`)."""
    return np.minimum(np.arange(grid_size(size, stride)) * stride, size - 1)


def evaluate_sparse(launch: Callable[[PixelSet, tuple[int, int]], None], distance: wp.array, out: wp.array,
                    stride: int, tolerance: float, depth_tolerance: float, end_zone: wp.array | None = None,
                    levels: int = 1, scale: wp.array | None = None, device=None) -> SparseEvaluation:
    """Evaluate a per-pixel look-up on the pixels the image needs (module doc).

    Args:
        launch: ``launch(pixels, dim)`` runs the look-up's kernel on a :class:`PixelSet` over ``dim``, writing ``out``
            (and ``end_zone``) at the pixels it evaluates.
        distance: (H, W) the G-buffer's camera distance.
        out: (H, W) vec3, written at every pixel.
        stride: pixels between the finest grid's nodes; 1 evaluates every pixel.
        tolerance, depth_tolerance: the agreement test's (module doc).
        end_zone: (H, W) int32 the look-up sets to 1 where it leaves a pixel to the marcher, zero elsewhere.
        levels: grids filled coarse to fine, from every ``stride * 2**(levels - 1)``-th pixel (1: one grid).
        scale: (H, W) float32 known positive factor of each pixel's radiance (a directional light's phase function):
            the coarser levels test and interpolate the radiance divided by it (the last level, changing little over
            a ``stride`` cell, as it is).
    """
    device = default_device(device)
    h, w = out.shape
    if levels < 1:
        raise ValueError(f"levels must be at least 1, not {levels}")
    if stride <= 1:
        launch(pixel_set(PIXELS_ALL, device=device), (h, w))
        return SparseEvaluation(1, h, w, h * w)
    strides = [int(stride) * 2 ** k for k in reversed(range(levels))]  # coarse to fine
    gh, gw = grid_size(h, strides[0]), grid_size(w, strides[0])
    launch(pixel_set(PIXELS_GRID, strides[0], device=device), (gh, gw))
    passes = []
    for n, (coarse, fine) in enumerate(zip(strides, [*strides[1:], 1], strict=True)):
        pass_tolerance = float(tolerance) * COARSER_TOLERANCE ** (levels - 1 - n)  # the last pass: tolerance
        rows = grid_size(h, fine)
        columns = wp.empty((rows, w), dtype=wp.int32, device=device)
        counts = wp.empty(rows, dtype=wp.int32, device=device)
        grid = GridPass()
        grid.stride, grid.fine = int(coarse), int(fine)
        grid.tolerance, grid.depth_tolerance = pass_tolerance, float(depth_tolerance)
        if end_zone is not None:
            grid.check_end_zone, grid.end_zone = 1, end_zone
        if scale is not None and fine > 1:  # the last level interpolates the radiance as it is
            grid.scaled, grid.scale = 1, scale
        launch_rows(interpolate_grid_kernel, rows, [grid, distance, out, columns, counts], device=device)
        listed = counts.numpy().copy()
        total = int(listed.sum())
        pixels = None
        if total > 0:
            starts = np.concatenate([[0], np.cumsum(listed)[:-1]]).astype(np.int32)
            pixels = wp.empty(total, dtype=wp.vec2i, device=device)
            launch_rows(gather_listed_kernel, rows, [int(fine), h, columns, counts,
                                                    wp.array(starts, dtype=wp.int32, device=device), pixels],
                        device=device)
            launch(pixel_set(PIXELS_LISTED, LISTED_PER_ROW, pixels, total, device=device),
                   (-(-total // LISTED_PER_ROW), LISTED_PER_ROW))
        passes.append(ListedPass(fine, listed, pixels))
    return SparseEvaluation(int(stride), h, w, gh * gw, int(levels), passes)


__all__ = [
    "COARSER_TOLERANCE",
    "GridPass",
    "PIXELS_ALL",
    "PIXELS_GRID",
    "PIXELS_LISTED",
    "ListedPass",
    "PixelSet",
    "SparseEvaluation",
    "evaluate_sparse",
    "grid_node",
    "grid_size",
    "gather_listed_kernel",
    "interpolate_grid_kernel",
    "pixel_set",
    "set_pixel",
]
