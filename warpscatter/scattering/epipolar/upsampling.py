"""Interpolation along the epipolar lines and bilateral upsampling to every pixel (Engelhardt & Dachsbacher 2010,
Sec. 4.3 and 5.3), and the degenerate case's grid upsampling.

Per pixel (:func:`upsample_pixel`): the two nearest lines from the border arclength of the ray epipole -> pixel (the
1D border lookup), the pixel's projection onto them, a bilateral filter along each (:func:`line_filter`), then between
the lines by their weight sums; a side without valid taps moves outwards (at most ``outer_lines``). Pixels with no
valid tap are left to the marcher (``unresolved``); pixels whose ray misses a spot light's cone are exactly 0.
:func:`upsample` runs it at every pixel, or on a grid and the pixels its cells cannot interpolate
(:mod:`warpscatter.scattering.sparse_evaluation`, warpscatter's). The work layout (tiles, one record per line, one
vec4 per texel) never changes the arithmetic, so the images do not depend on it.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ...runtime.device import default_device, module_options
from ...runtime.parallel import launch_rows
from ...scene.camera import CameraParams
from ...scene.lights import LightParams
from ..settings import EPIPOLAR_KERNELS, EVALUATE_DEPTH_TOLERANCE, EVALUATE_TOLERANCE, EpipolarSettings
from ..sparse_evaluation import PixelSet, evaluate_sparse, grid_node, set_pixel
from .textures import (
    EpipolarGeometry,
    LineArrays,
    LineRecord,
    border_arclength,
    compact,
    gather_rows,
    screen_point_in_light,
    wrap_line,
)

module_options()

#: ``BilateralFilter.kernel``: the radial basis functions of the filter (Sec. 4.3).
KERNEL_GAUSSIAN = wp.constant(0)
KERNEL_SHEPARD = wp.constant(1)
KERNEL_THRESHOLD = wp.constant(2)

#: Pixels per side of the square tiles the upsampling walks (one thread per band of this many rows).
UPSAMPLE_TILE = wp.constant(16)


#: Distance weights of up to 5 taps, precomputed on the host (index m = tap).
TapWeights = wp.types.vector(length=5, dtype=wp.float32)


@wp.struct
class BilateralFilter:
    """Bilateral upsampling parameters (Engelhardt 2010 Sec. 4.3)."""

    kernel: int  # KERNEL_GAUSSIAN, KERNEL_SHEPARD or KERNEL_THRESHOLD
    taps: int  # taps per line, 3..5
    tap_weights: TapWeights  # distance weight of tap m at offset m - (taps-1)/2 (in units of delta)
    tap_offsets: TapWeights  # offset m - (taps-1)/2 of tap m (in units of delta)
    depth_sigma: float  # relative depth difference mapped to x = 1
    min_weight: float  # depth weight below which a tap is invalid
    depth_cutoff: float  # largest depth x whose weight reaches min_weight (x beyond it: weight 0, no exp)
    outer_lines: int  # outer lines tried per side


# ---- building blocks (public @wp.func API) -------------------------------------------------------


@wp.func
def kernel_weight(kernel: int, x: float) -> float:
    """Radial basis of the bilateral filter (Engelhardt 2010 Sec. 4.3), 1 at x = 0: Gaussian exp(-x^2) (its series
    1 - x^2 + x^4 / 2 below x = 1/16, error < 1e-8, skips the exp on smooth surfaces), Shepard-type 1 / (1 + x^2) or
    threshold [x <= 1]."""
    if kernel == KERNEL_GAUSSIAN:
        if x < 0.0625:
            x2 = x * x
            return 1.0 - x2 + 0.5 * x2 * x2
        return wp.exp(-x * x)
    if kernel == KERNEL_SHEPARD:
        return 1.0 / (1.0 + x * x)
    if x <= 1.0:
        return 1.0
    return 0.0


@wp.func
def depth_scale(flt: BilateralFilter, pixel_depth: float) -> float:
    """1 / (pixel depth_sigma): the factor of :func:`depth_weight_scaled`, computed once per pixel."""
    return 1.0 / wp.max(pixel_depth * flt.depth_sigma, 1.0e-20)


@wp.func
def depth_weight_scaled(flt: BilateralFilter, tap_depth: float, pixel_depth: float, scale: float) -> float:
    """:func:`depth_weight` with the pixel's :func:`depth_scale` precomputed (the per-texel form of the filter)."""
    x = wp.abs(tap_depth - pixel_depth) * scale
    if x > flt.depth_cutoff:
        return 0.0
    wd = kernel_weight(flt.kernel, x)
    if wd < flt.min_weight:
        return 0.0
    return wd


@wp.func
def depth_weight(flt: BilateralFilter, tap_depth: float, pixel_depth: float) -> float:
    """Depth term of a tap: kernel of |tap - pixel| / (pixel depth_sigma); 0 when below ``min_weight``."""
    return depth_weight_scaled(flt, tap_depth, pixel_depth, depth_scale(flt, pixel_depth))


@wp.func
def record_projection(r: LineRecord, p: wp.vec2) -> float:
    """:func:`~.textures.project_on_line` of p from a line's :data:`~.textures.LineRecord`, operation for operation."""
    if r[4] < 1.0e-12:
        return 0.0
    return wp.dot(p - wp.vec2(r[0], r[1]), wp.vec2(r[2], r[3])) / r[4]


@wp.func
def tap_texels(flt: BilateralFilter, texels: wp.array(dtype=wp.vec4), row: int, n: int, c: float, wdist: float,
               pixel_depth: float, scale: float, acc: wp.vec4, wsum: float):
    """(acc, wsum) plus one tap of :func:`line_taps` at texel position c in [0, n - 1]: its two texels, each weighted
    by its linear weight, ``wdist`` and its depth weight (invalid ones skipped)."""
    t0 = wp.min(int(c), n - 1)  # c >= 0: truncation is the floor
    f = c - float(t0)
    if f < 1.0:
        v0 = texels[row + t0]
        w0 = (1.0 - f) * wdist * depth_weight_scaled(flt, v0[3], pixel_depth, scale)
        if w0 > 0.0:
            acc += v0 * w0
            wsum += w0
    if f > 0.0:
        v1 = texels[row + wp.min(t0 + 1, n - 1)]
        w1 = f * wdist * depth_weight_scaled(flt, v1[3], pixel_depth, scale)
        if w1 > 0.0:
            acc += v1 * w1
            wsum += w1
    return acc, wsum


@wp.func
def line_taps(flt: BilateralFilter, texels: wp.array(dtype=wp.vec4), row: int, n: int, tc: float, step: float,
              pixel_depth: float, scale: float):
    """(sum of w (L, depth), sum of w) of :func:`line_filter`'s taps along the line whose n texels start at flat index
    ``row``, around texel position tc (n - 1), ``step`` texels apart; ``scale`` is :func:`depth_scale`."""
    last = float(n - 1)
    centre = tc * last
    acc = wp.vec4(0.0, 0.0, 0.0, 0.0)
    wsum = float(0.0)
    if flt.taps == 1:
        return tap_texels(flt, texels, row, n, centre, flt.tap_weights[0], pixel_depth, scale, acc, wsum)
    reach = wp.min(centre, last - centre) + 1.0e-4  # taps go in symmetric pairs: a pair reaching past an end is dropped
    for m in range(5):  # unrolled (taps <= 5)
        if m < flt.taps:
            o = flt.tap_offsets[m]
            if not (wp.abs(o) * step > reach and o != 0.0):
                acc, wsum = tap_texels(flt, texels, row, n, wp.clamp(centre + o * step, 0.0, last), flt.tap_weights[m],
                                       pixel_depth, scale, acc, wsum)
    return acc, wsum


@wp.func
def line_filter_at(geo: EpipolarGeometry, flt: BilateralFilter, texels: wp.array(dtype=wp.vec4), k: int,
                   r: LineRecord, tau: float, p: wp.vec2, delta: float, pixel_depth: float, scale: float):
    """:func:`line_filter` with line k's record r, p's projection parameter tau on it and the pixel's
    :func:`depth_scale` given. Returns (sum of w (L, depth), sum of w, distance from p to the line)."""
    tc = wp.clamp(tau, 0.0, 1.0)
    seg_len = r[5]
    dist = wp.length(p - (wp.vec2(r[0], r[1]) + wp.vec2(r[2], r[3]) * tc))
    if r[6] == 0.0 or seg_len < 1.0e-6:
        return wp.vec4(0.0, 0.0, 0.0, 0.0), 0.0, dist
    if wp.abs(tau - tc) * seg_len > wp.max(2.0 * delta, 2.0):
        return wp.vec4(0.0, 0.0, 0.0, 0.0), 0.0, dist
    last = float(geo.samples - 1)
    acc, wsum = line_taps(flt, texels, k * geo.samples, geo.samples, tc, delta / seg_len * last, pixel_depth, scale)
    return acc, wsum, dist


@wp.func
def line_filter(geo: EpipolarGeometry, flt: BilateralFilter, lines: LineArrays, k: int, p: wp.vec2,
                pixel_depth: float, delta: float):
    """1D bilateral filter along epipolar line k for pixel p (Engelhardt 2010 Sec. 4.3): (sum of w L, sum of w,
    distance from p to the line in pixels). Taps at offsets (m - (taps-1)/2) delta from p's projection, in symmetric
    pairs (a pair reaching past an end is dropped, so linear variation is reproduced at the ends), each read linearly
    between two texels with distance and depth weights; one tap is the depth-weighted linear interpolation at the
    projection. The sum of w is 0 for a culled line, one not reaching p (max(2 delta, 2 px)) or no valid tap."""
    r = lines.records[k]
    acc, wsum, dist = line_filter_at(geo, flt, lines.texels, k, r, record_projection(r, p), p, delta, pixel_depth,
                                     depth_scale(flt, pixel_depth))
    return wp.vec3(acc[0], acc[1], acc[2]), wsum, dist


@wp.func
def side_filter(geo: EpipolarGeometry, flt: BilateralFilter, texels: wp.array(dtype=wp.vec4), k: int, r: LineRecord,
                tau: float, p: wp.vec2, m: int, delta: float, pixel_depth: float, scale: float):
    """:func:`line_filter_at` on the m-th line outwards if it has a valid tap within m + 1 line spacings + 1 px of p
    (never a line across the pencil), else zeros."""
    acc, wsum, dist = line_filter_at(geo, flt, texels, k, r, tau, p, delta, pixel_depth, scale)
    if wsum > 0.0 and dist <= (float(m) + 1.0) * geo.spacing + 1.0:
        return acc, wsum, dist
    return wp.vec4(0.0, 0.0, 0.0, 0.0), 0.0, 0.0


@wp.kernel
def tap_weights_kernel(kernel: int, taps: int, distance_scale: float, weights: wp.array(dtype=wp.float32)):
    # distance term of tap m at offset m - (taps-1)/2 delta (Engelhardt 2010 Sec. 4.3); the threshold kernel has none
    m = wp.tid()
    weights[m] = 1.0
    if kernel != KERNEL_THRESHOLD:
        weights[m] = kernel_weight(kernel, distance_scale * wp.abs(float(m) - 0.5 * float(taps - 1)))


@wp.kernel
def interpolate_lines_kernel(
    valid: wp.array(dtype=wp.int32),
    interp: wp.array2d(dtype=wp.vec2i),
    radiance: wp.array2d(dtype=wp.vec3),  # in: ray-marching samples; out: interpolation samples (0 on culled lines)
    offset: int,
):
    # Engelhardt 2010 Sec. 5.3: linear interpolation between the two sources (marched texels)
    k = wp.tid() + offset
    n = radiance.shape[1]
    if valid[k] == 0:
        for x in range(n):
            radiance[k, x] = wp.vec3(0.0, 0.0, 0.0)
        return
    for x in range(n):
        src = interp[k, x]
        left = src[0]
        right = src[1]
        if left != x and right != x:
            t = float(x - left) / float(right - left)
            radiance[k, x] = radiance[k, left] * (1.0 - t) + radiance[k, right] * t


@wp.func(inline=True)
def upsample_pixel(cam: CameraParams, light: LightParams, geo: EpipolarGeometry, flt: BilateralFilter,
                   lines: LineArrays, e_rel: wp.vec2, i: int, j: int, pixel_depth: float):
    """(L_scat, resolved) of pixel (i, j) at camera distance ``pixel_depth`` from the line textures (Engelhardt 2010
    Sec. 4.3, 5.3; module doc), ``e_rel`` = epipole - (0.5, 0.5); 0 when unresolved (no valid tap)."""
    p = wp.vec2(float(i) + 0.5, float(j) + 0.5)
    if not screen_point_in_light(cam, light, p):
        return wp.vec3(0.0, 0.0, 0.0), True  # the ray never enters the light frustum: exactly 0
    # ---- 1D border lookup: the two lines whose border points enclose the ray's exit point ----
    dv = p - geo.epipole
    if wp.length(dv) < 1.0e-6:
        dv = wp.vec2(1.0, 0.0)
    u = border_arclength(e_rel, dv, geo.border_width, geo.border_height) / geo.spacing - 0.5
    k0 = wrap_line(int(wp.floor(u)), geo.lines)
    k1 = k0 + 1
    if k1 == geo.lines:
        k1 = 0
    # ---- tap spacing: distance between p's projections on the two nearest lines ----
    r0 = lines.records[k0]
    r1 = lines.records[k1]
    tau0 = record_projection(r0, p)
    tau1 = record_projection(r1, p)
    delta = wp.length((wp.vec2(r0[0], r0[1]) + wp.vec2(r0[2], r0[3]) * tau0)
                      - (wp.vec2(r1[0], r1[1]) + wp.vec2(r1[2], r1[3]) * tau1))
    scale = depth_scale(flt, pixel_depth)
    # ---- bilateral filter along each side's nearest valid line, moving outwards only without a valid tap ----
    a_l, w_l, d_l = side_filter(geo, flt, lines.texels, k0, r0, tau0, p, 0, delta, pixel_depth, scale)
    a_r, w_r, d_r = side_filter(geo, flt, lines.texels, k1, r1, tau1, p, 0, delta, pixel_depth, scale)
    m = int(1)
    while w_l <= 0.0 and m <= flt.outer_lines:
        k = wrap_line(k0 - m, geo.lines)
        r = lines.records[k]
        a_l, w_l, d_l = side_filter(geo, flt, lines.texels, k, r, record_projection(r, p), p, m, delta,
                                    pixel_depth, scale)
        m += 1
    m = int(1)
    while w_r <= 0.0 and m <= flt.outer_lines:
        k = wrap_line(k1 + m, geo.lines)
        r = lines.records[k]
        a_r, w_r, d_r = side_filter(geo, flt, lines.texels, k, r, record_projection(r, p), p, m, delta,
                                    pixel_depth, scale)
        m += 1
    acc_l = wp.vec3(a_l[0], a_l[1], a_l[2])
    acc_r = wp.vec3(a_r[0], a_r[1], a_r[2])
    if w_l <= 0.0 and w_r <= 0.0:
        return wp.vec3(0.0, 0.0, 0.0), False
    # ---- between the lines: linear position between them times their weight sums ----
    frac = float(0.5)
    if d_l + d_r > 0.0:
        frac = d_l / (d_l + d_r)
    wl = (1.0 - frac) * w_l
    wr = frac * w_r
    if wl + wr > 1.0e-30:
        return (acc_l * (1.0 - frac) + acc_r * frac) / (wl + wr), True
    return (acc_l + acc_r) / (w_l + w_r), True


@wp.kernel
def upsample_kernel(
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    light: LightParams,
    geo: EpipolarGeometry,
    flt: BilateralFilter,
    lines: LineArrays,
    out: wp.array2d(dtype=wp.vec3),  # out: L_scat per pixel
    unresolved: wp.array2d(dtype=wp.int32),  # out: per row, the columns of the pixels without a valid tap
    unresolved_count: wp.array(dtype=wp.int32),  # out: per row, how many
    offset: int,
):
    # every pixel: one thread per band of UPSAMPLE_TILE rows, in square tiles (the few lines crossing one stay cached)
    j0 = (wp.tid() + offset) * UPSAMPLE_TILE
    j1 = wp.min(j0 + UPSAMPLE_TILE, cam.height)
    for j in range(j0, j1):
        unresolved_count[j] = 0
    e_rel = geo.epipole - wp.vec2(0.5, 0.5)
    for x0 in range(0, cam.width, UPSAMPLE_TILE):
        for j in range(j0, j1):
            for i in range(x0, wp.min(x0 + UPSAMPLE_TILE, cam.width)):
                value, resolved = upsample_pixel(cam, light, geo, flt, lines, e_rel, i, j, distance[j, i])
                out[j, i] = value
                if not resolved:
                    c = unresolved_count[j]
                    unresolved[j, c] = i
                    unresolved_count[j] = c + 1


@wp.kernel
def upsample_set_kernel(
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    light: LightParams,
    geo: EpipolarGeometry,
    flt: BilateralFilter,
    lines: LineArrays,
    out: wp.array2d(dtype=wp.vec3),  # out: L_scat at the set's pixels
    unresolved: wp.array2d(dtype=wp.int32),  # out: 1 at the set's pixels without a valid tap, else 0
    pixels: PixelSet,
    offset: int,
):
    # the pixels of a PixelSet (upsample_stride > 1: sparse_evaluation drives the launches)
    a, b = wp.tid()
    j, i, listed = set_pixel(pixels, cam.height, cam.width, a + offset, b)
    if not listed:
        return
    value, resolved = upsample_pixel(cam, light, geo, flt, lines, geo.epipole - wp.vec2(0.5, 0.5), i, j,
                                     distance[j, i])
    out[j, i] = value
    unresolved[j, i] = int(not resolved)


@wp.kernel
def grid_upsample_kernel(
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    stride: int,
    grid: wp.array2d(dtype=wp.vec3),
    flt: BilateralFilter,
    out: wp.array2d(dtype=wp.vec3),
    unresolved: wp.array(dtype=wp.int32),
    offset: int,
):
    # degenerate case: bilinear interpolation of the grid, corners weighted by depth (invalid corners dropped)
    j, i = wp.tid()
    j += offset
    gw = grid.shape[1]
    gh = grid.shape[0]
    gi0 = i // stride
    gj0 = j // stride
    gi1 = wp.min(gi0 + 1, gw - 1)
    gj1 = wp.min(gj0 + 1, gh - 1)
    x0 = grid_node(gi0, stride, cam.width)
    x1 = grid_node(gi1, stride, cam.width)
    y0 = grid_node(gj0, stride, cam.height)
    y1 = grid_node(gj1, stride, cam.height)
    fx = float(0.0)
    fy = float(0.0)
    if x1 > x0:
        fx = float(i - x0) / float(x1 - x0)
    if y1 > y0:
        fy = float(j - y0) / float(y1 - y0)
    pd = distance[j, i]
    w00 = (1.0 - fx) * (1.0 - fy) * depth_weight(flt, distance[y0, x0], pd)
    w10 = fx * (1.0 - fy) * depth_weight(flt, distance[y0, x1], pd)
    w01 = (1.0 - fx) * fy * depth_weight(flt, distance[y1, x0], pd)
    w11 = fx * fy * depth_weight(flt, distance[y1, x1], pd)
    wsum = w00 + w10 + w01 + w11
    unresolved[j * cam.width + i] = 0
    if wsum <= 0.0:
        out[j, i] = wp.vec3(0.0, 0.0, 0.0)
        unresolved[j * cam.width + i] = 1
        return
    out[j, i] = (grid[gj0, gi0] * w00 + grid[gj0, gi1] * w10 + grid[gj1, gi0] * w01 + grid[gj1, gi1] * w11) / wsum


def upsample(cam, distance: wp.array, light: LightParams, geo: EpipolarGeometry, flt: BilateralFilter,
             lines: LineArrays, out: wp.array, stride: int = 1, device=None) -> tuple[wp.array, int, float]:
    """Bilateral upsampling of the line textures to every pixel of ``out``: (indices, count, upsampled fraction), the
    flat indices ``j * width + i`` of the pixels without a valid tap (``out`` 0 there; the caller marches them) and the
    share of pixels the filter ran at.

    ``stride`` 1: every pixel (the paper's). ``stride`` > 1 (warpscatter's): a grid and the pixels whose cell does not
    agree (:func:`~warpscatter.scattering.sparse_evaluation.evaluate_sparse`, the prefiltered rule and tolerances); a
    corner without a valid tap refuses its cell, so every marched pixel is one the filter found no tap for, and a
    feature narrower than a cell between agreeing corners (a thin shaft) is interpolated over.
    """
    device = default_device(device)
    h, w = cam.height, cam.width
    cam_p = cam.params()
    if stride <= 1:
        rows = wp.empty((h, w), dtype=wp.int32, device=device)
        row_count = wp.empty(h, dtype=wp.int32, device=device)
        launch_rows(upsample_kernel, -(-h // UPSAMPLE_TILE), [cam_p, distance, light, geo, flt, lines, out, rows,
                                                              row_count], device=device)
        return (*gather_rows(rows, row_count, device), 1.0)
    unresolved = wp.zeros((h, w), dtype=wp.int32, device=device)

    def look_up(pixels: PixelSet, dim: tuple[int, int]) -> None:
        launch_rows(upsample_set_kernel, dim, [cam_p, distance, light, geo, flt, lines, out, unresolved, pixels],
                    device=device)

    sparse = evaluate_sparse(look_up, distance, out, stride, EVALUATE_TOLERANCE, EVALUATE_DEPTH_TOLERANCE,
                             end_zone=unresolved, device=device)
    return (*compact(unresolved.flatten(), device), sparse.evaluated_fraction)


def filter_params(settings: EpipolarSettings, device=None) -> BilateralFilter:
    """:class:`BilateralFilter` from :class:`EpipolarSettings`."""
    device = default_device(device)
    f = BilateralFilter()
    f.kernel = EPIPOLAR_KERNELS.index(settings.kernel)
    f.taps = int(settings.taps)
    weights = wp.zeros(5, dtype=wp.float32, device=device)
    wp.launch(tap_weights_kernel, settings.taps, [f.kernel, f.taps, float(np.sqrt(settings.distance_falloff)),
                                                  weights], device=device)
    f.tap_weights = TapWeights(*weights.numpy())
    f.tap_offsets = TapWeights(*[m - 0.5 * (f.taps - 1) for m in range(5)])
    f.depth_sigma = float(settings.depth_sigma)
    f.min_weight = float(settings.min_weight)
    # kernel_weight(x) >= min_weight  <=>  x <= depth_cutoff
    f.depth_cutoff = float({"gaussian": np.sqrt(-np.log(settings.min_weight)),
                            "shepard": np.sqrt(1.0 / settings.min_weight - 1.0),
                            "threshold": 1.0}[settings.kernel])
    f.outer_lines = int(settings.outer_lines)
    return f


__all__ = [
    "KERNEL_GAUSSIAN",
    "KERNEL_SHEPARD",
    "KERNEL_THRESHOLD",
    "UPSAMPLE_TILE",
    "BilateralFilter",
    "depth_scale",
    "depth_weight",
    "depth_weight_scaled",
    "filter_params",
    "kernel_weight",
    "line_filter",
    "line_filter_at",
    "line_taps",
    "record_projection",
    "side_filter",
    "tap_texels",
    "upsample",
    "upsample_pixel",
]
