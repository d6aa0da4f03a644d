"""Caster culling of a rectified shadow map: empty the texels whose blocker shadows no pixel (warpscatter's, not
in the papers).

A pixel's look-up reads rows j0, j1 and the prefix columns up to i1
(:func:`~..prefiltered.filtered_lookups.texel_footprint`); a texel there shadows it only when its blocker depth is
below the pixel's z_r. Emptying (depth 1) a texel no pixel reads with a larger z_r changes no hard-visibility result
but takes its depth out of the filtered representation: typically a ground's own depths just behind the rays ending
on it, where Fourier series ring and moment bounds are loosest (README, *Receivers in the rectified map*).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ...runtime.device import default_device, module_options
from ...runtime.parallel import chunks, launch_rows, run_parallel, thread_count
from ...scene.camera import CameraParams, pixel_ray_direction
from ...scene.lights import LightParams, faces_away_from_light
from ..prefiltered.filtered_lookups import texel_footprint
from ..prefiltered.row_mips import RowMips, level_rows, level_window, pixel_mip_level
from .params import wrap_rows
from .taps import SparseRectifiedDepth

module_options()


#: Depth bins per row of the caster-culling table (pixels are binned by z_r; a texel keeps its blocker when any
#: pixel in its bin or above reads it, so the binning only ever keeps more).
CULL_DEPTH_BINS = 1024


@wp.func
def cull_depth_bin(z: float) -> int:
    """Bin of rectified depth z in the caster-culling table."""
    return wp.clamp(int(wp.floor(z * float(CULL_DEPTH_BINS))), 0, CULL_DEPTH_BINS - 1)


@wp.func
def mark_level_row(table: wp.array2d(dtype=wp.int32), level: int, row: int, b: int, i1: int):
    """Mark the level-0 rows that row ``row`` of mip level ``level`` averages as read through column i1."""
    span = int(1) << level
    for r in range(row * span, row * span + span):
        wp.atomic_max(table, r, b, i1)


@wp.kernel
def end_faces_away_kernel(cam: CameraParams, distance: wp.array2d(dtype=wp.float32),
                          normal: wp.array2d(dtype=wp.vec3), light: LightParams, out: wp.array2d(dtype=wp.int32),
                          offset: int):
    # 1 where pixel (i, j)'s view ray ends on a surface facing away from the light
    j, i = wp.tid()
    j += offset
    x = cam.position + pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5) * distance[j, i]
    out[j, i] = int(faces_away_from_light(light, x, normal[j, i]))


@wp.kernel
def reader_table_kernel(coords: wp.array2d(dtype=wp.vec3), faces_away: wp.array2d(dtype=wp.int32), bias_bins: int,
                        mips: RowMips, cols: int, table: wp.array2d(dtype=wp.int32), offset: int):
    # table[row, bin] = last prefix column a pixel of that depth bin reads in that row (with row mips, in every level-0
    # row its levels average); a pixel ending on a surface facing away from the light counts bias_bins deeper
    j, i = wp.tid()
    j += offset
    c = coords[j, i]
    b = wp.min(cull_depth_bin(c[2]) + bias_bins * faces_away[j, i], CULL_DEPTH_BINS - 1)
    lv = pixel_mip_level(mips, coords, j, i)
    level = int(lv[0])
    top = level
    if lv[1] > 0.0:
        top = level + 1
    for k in range(level, top + 1):
        w = level_window(mips, k)
        j0, j1, ay, i0, i1, ax = texel_footprint(w[1], cols, c[0], c[1], w[2])
        mark_level_row(table, k, j0, b, i1)
        mark_level_row(table, k, j1, b, i1)


@wp.kernel
def reader_suffix_kernel(bands: wp.array3d(dtype=wp.int32), table: wp.array2d(dtype=wp.int32), offset: int):
    # table[row, b] = last column read by any pixel with a depth bin >= b, of any band's table
    j = wp.tid() + offset
    for b in range(CULL_DEPTH_BINS):
        last = bands[0, j, b]
        for band in range(1, bands.shape[0]):
            last = wp.max(last, bands[band, j, b])
        table[j, b] = last
    for k in range(CULL_DEPTH_BINS - 1):
        b = CULL_DEPTH_BINS - 2 - k
        table[j, b] = wp.max(table[j, b], table[j, b + 1])


@wp.func
def unread_blocker(table: wp.array2d(dtype=wp.int32), j: int, i: int, z: float, bias_bins: int) -> bool:
    """True when texel (j, i) holds a blocker (z < 1) that no pixel reads at least ``bias_bins`` bins deeper."""
    return z < 1.0 and table[j, wp.min(cull_depth_bin(z) + bias_bins, CULL_DEPTH_BINS - 1)] < i


@wp.kernel
def cull_casters_kernel(
    table: wp.array2d(dtype=wp.int32),
    depth: wp.array2d(dtype=wp.float32),
    depth2: wp.array2d(dtype=wp.float32),  # the second depth of a SparseRectifiedDepth (two_depths != 0)
    two_depths: int,
    bias_bins: int,
    culled: wp.array(dtype=wp.int32),  # per row: texels emptied (one row per thread: no race)
    offset: int,
):
    j, i = wp.tid()
    j += offset
    if unread_blocker(table, j, i, depth[j, i], bias_bins):
        depth[j, i] = 1.0
        culled[j] = culled[j] + 1
    if two_depths != 0 and unread_blocker(table, j, i, depth2[j, i], bias_bins):
        depth2[j, i] = 1.0


def end_faces_away(camera, gbuffer, light: LightParams, device=None) -> wp.array:
    """(H, W) int32: 1 where the pixel's view ray ends on a surface facing away from the light (by the G-buffer's
    camera-facing normal), which shadows the end of its own ray."""
    device = default_device(device)
    out = wp.empty((camera.height, camera.width), dtype=wp.int32, device=device)
    launch_rows(end_faces_away_kernel, (camera.height, camera.width),
                [camera.params(), gbuffer.distance, gbuffer.normal, light, out], device=device)
    return out


def reader_tables(coords: wp.array, faces_away: wp.array, bias_bins: int, mips: RowMips, rows: int, cols: int,
                  device) -> wp.array:
    """(bands, rows, CULL_DEPTH_BINS) int32 reader tables (:func:`reader_table_kernel`; -1: unread), one per band of
    image rows: on the CPU a band per worker thread, launched concurrently (CPU atomics are exact within a launch
    only); on a GPU one band."""
    height, width = int(coords.shape[0]), int(coords.shape[1])
    parts = chunks(height, thread_count() if wp.get_device(device).is_cpu else 1)
    bands = wp.full((len(parts), rows, CULL_DEPTH_BINS), -1, dtype=wp.int32, device=device)

    def one_band(k: int) -> None:
        start, stop = parts[k]
        wp.launch(reader_table_kernel, dim=(stop - start, width),
                  inputs=[coords, faces_away, bias_bins, mips, cols, bands[k], start], device=device)

    wp.load_module(reader_table_kernel.module, device=device)
    run_parallel(one_band, list(range(len(parts))), len(parts))
    return bands


def cull_unseen_casters(rectified, rect, coords: wp.array, bias: float = 0.0, device=None,
                        mip_levels: int = 1, faces_away: wp.array | None = None) -> float:
    """Empty, in place, every texel of a rectified map whose blocker shadows no pixel's look-up; returns the fraction
    of texels emptied (of the first depth).

    A texel is kept when some pixel's look-up reads it with a z_r of at least its depth + ``bias`` (pixels binned into
    ``CULL_DEPTH_BINS``, rounding towards keeping); with ``bias`` 0 no hard visibility changes. ``bias`` is for a lit
    surface's acne, its own depths a little in front of the rays ending on it; it does not apply to rays ending on a
    surface facing away from the light (``faces_away``, :func:`end_faces_away`), which that surface shadows.

    Args:
        rectified: (rows, cols) float32 rectified depth (1: no blocker), or a
            :class:`~.taps.SparseRectifiedDepth` (both depths are culled).
        rect: its NonlinearRectification or ProjectiveRectification.
        coords: (H, W) vec3 rectified coordinates of the pixels' view-ray ends.
        bias: tolerance in rectified depth (a fraction of the depth range), >= 0.
        mip_levels: the row mip levels the look-ups read (:mod:`..prefiltered.row_mips`).
        faces_away: (H, W) int32 of :func:`end_faces_away`; None: no pixel's surface faces away.
    """
    device = default_device(device)
    if not (np.isfinite(bias) and bias >= 0.0):
        raise ValueError(f"caster culling bias must be finite and >= 0, got {bias}")
    bias_bins = int(np.floor(bias * CULL_DEPTH_BINS))  # floor: a partial bin still counts readers in it
    two = isinstance(rectified, SparseRectifiedDepth)
    depth = rectified.z1 if two else rectified
    rows, cols = int(depth.shape[0]), int(depth.shape[1])
    mips = RowMips()
    mips.rows, mips.levels, mips.wrap = rows, len(level_rows(rows, mip_levels)), int(wrap_rows(rect))
    if faces_away is None:
        faces_away = wp.zeros(coords.shape, dtype=wp.int32, device=device)
    bands = reader_tables(coords, faces_away, bias_bins, mips, rows, cols, device)
    table = wp.empty((rows, CULL_DEPTH_BINS), dtype=wp.int32, device=device)
    launch_rows(reader_suffix_kernel, rows, [bands, table], device=device)
    culled = wp.zeros(rows, dtype=wp.int32, device=device)
    launch_rows(cull_casters_kernel, (rows, cols),
                [table, depth, rectified.z2 if two else depth, int(two), int(bias_bins), culled], device=device)
    return float(culled.numpy().sum()) / float(rows * cols)


__all__ = ["CULL_DEPTH_BINS", "cull_depth_bin", "cull_unseen_casters", "end_faces_away", "unread_blocker"]
