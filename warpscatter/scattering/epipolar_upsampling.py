"""Interpolation along the epipolar lines and bilateral upsampling to every pixel (Engelhardt & Dachsbacher 2010,
Sec. 4.3 and 5.3), and the degenerate case's grid upsampling.

Per pixel: the two nearest lines from the border arclength of the ray epipole -> pixel (the 1D border lookup,
analytic because the border points are equidistant), projection onto them, a 3-5 tap bilateral filter along each
(taps a multiple of the projections' distance apart, in symmetric pairs; distance and depth weights, Gaussian,
Shepard or threshold), then between the lines by their weight sums; a side without valid taps moves to the next
outer line (at most ``outer_lines``). Pixels with no valid tap on any tried line are flagged ``unresolved`` (the
method ray-marches them). Pixels whose camera ray misses a spot light's cone are exactly 0.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..scene.camera import CameraParams
from ..scene.lights import LightParams
from ..wpinit import default_device, module_options
from .epipolar_textures import (
    EpipolarGeometry,
    LineArrays,
    border_arclength,
    project_on_line,
    screen_point_in_light,
    wrap_line,
)
from .settings import EPIPOLAR_KERNELS, EpipolarSettings

module_options()

#: ``BilateralFilter.kernel``: the radial basis functions of the filter (Sec. 4.3).
KERNEL_GAUSSIAN = wp.constant(0)
KERNEL_SHEPARD = wp.constant(1)
KERNEL_THRESHOLD = wp.constant(2)


#: Distance weights of up to 5 taps, precomputed on the host (index m = tap).
TapWeights = wp.types.vector(length=5, dtype=wp.float32)


@wp.struct
class BilateralFilter:
    """Bilateral upsampling parameters (Engelhardt 2010 Sec. 4.3)."""

    kernel: int  # KERNEL_GAUSSIAN, KERNEL_SHEPARD or KERNEL_THRESHOLD
    taps: int  # taps per line, 3..5
    tap_weights: TapWeights  # distance weight of tap m at offset m - (taps-1)/2 (in units of delta)
    depth_sigma: float  # relative depth difference mapped to x = 1
    min_weight: float  # depth weight below which a tap is invalid
    depth_cutoff: float  # largest depth x whose weight reaches min_weight (x beyond it: weight 0, no exp)
    outer_lines: int  # outer lines tried per side


# ---- building blocks (public @wp.func API) -------------------------------------------------------


@wp.func
def kernel_weight(kernel: int, x: float) -> float:
    """Radial basis of the bilateral filter (Engelhardt 2010 Sec. 4.3), 1 at x = 0.

    Gaussian exp(-x^2), Shepard-type 1 / (1 + x^2) (the inverse square regularised at 0), threshold [x <= 1].
    The Gaussian uses its series 1 - x^2 + x^4 / 2 below x = 1/16 (error < x^6 / 6 = 1e-8, under float32
    resolution at 1): taps on one smooth surface, the common case of the upsampling, skip the exp.
    """
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
def line_filter(geo: EpipolarGeometry, flt: BilateralFilter, lines: LineArrays, k: int, p: wp.vec2,
                pixel_depth: float, delta: float):
    """1D bilateral filter along epipolar line k for pixel p (Engelhardt 2010 Sec. 4.3).

    Taps at offsets (m - (taps-1)/2) delta from p's projection on the line, in symmetric pairs (a pair with a
    tap beyond an end of the segment is dropped, so a linear variation along the line is reproduced at the
    ends too); each tap reads the radiance texture linearly between its two texels, each texel weighted by its
    linear weight, the distance weight and its depth weight (texels with an invalid depth weight are skipped).

    Returns:
        (sum of w L, sum of w, distance from p to the line in pixels); the sum of w is 0 when the line is
        culled, does not reach p (the projection lies more than max(2 delta, 2 px) beyond the segment) or has
        no valid tap.
    """
    acc = wp.vec3(0.0, 0.0, 0.0)
    wsum = float(0.0)
    a = lines.entry[k]
    b = lines.exit_[k]
    tau = project_on_line(a, b, p)
    tc = wp.clamp(tau, 0.0, 1.0)
    seg_len = wp.length(b - a)
    dist = wp.length(p - (a + (b - a) * tc))
    if lines.valid[k] == 0 or seg_len < 1.0e-6:
        return acc, wsum, dist
    if wp.abs(tau - tc) * seg_len > wp.max(2.0 * delta, 2.0):
        return acc, wsum, dist
    last = float(geo.samples - 1)
    centre = tc * last
    step = delta / seg_len * last
    reach = wp.min(centre, last - centre)  # taps go in symmetric pairs: a pair reaching past an end is dropped
    scale = depth_scale(flt, pixel_depth)
    for m in range(flt.taps):
        o = float(m) - 0.5 * float(flt.taps - 1)
        if wp.abs(o) * step > reach + 1.0e-4 and o != 0.0:
            continue
        c = wp.clamp(centre + o * step, 0.0, last)
        wdist = flt.tap_weights[m]
        t0 = wp.min(int(wp.floor(c)), geo.samples - 1)
        t1 = wp.min(t0 + 1, geo.samples - 1)
        f = c - float(t0)
        if f < 1.0:
            w0 = (1.0 - f) * wdist * depth_weight_scaled(flt, lines.depth[k, t0], pixel_depth, scale)
            if w0 > 0.0:
                acc += lines.radiance[k, t0] * w0
                wsum += w0
        if f > 0.0:
            w1 = f * wdist * depth_weight_scaled(flt, lines.depth[k, t1], pixel_depth, scale)
            if w1 > 0.0:
                acc += lines.radiance[k, t1] * w1
                wsum += w1
    return acc, wsum, dist


@wp.func
def grid_node(m: int, stride: int, size: int) -> int:
    """Pixel coordinate of grid node m of the degenerate-case subsampling (the last node is clamped to the edge)."""
    return wp.min(m * stride, size - 1)


# ---- kernels -------------------------------------------------------------------------------------


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
    radiance: wp.array2d(dtype=wp.vec3),  # in: ray-marching samples; out: interpolation samples
    offset: int,
):
    # Engelhardt 2010 Sec. 5.3: linear interpolation between the two sources (reads marched texels only)
    k, x = wp.tid()
    k += offset
    if valid[k] == 0:
        return
    src = interp[k, x]
    left = src[0]
    right = src[1]
    if left == x or right == x:
        return
    t = float(x - left) / float(right - left)
    radiance[k, x] = radiance[k, left] * (1.0 - t) + radiance[k, right] * t


@wp.kernel
def upsample_kernel(
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    light: LightParams,
    geo: EpipolarGeometry,
    flt: BilateralFilter,
    lines: LineArrays,
    out: wp.array2d(dtype=wp.vec3),  # out: L_scat per pixel
    unresolved: wp.array(dtype=wp.int32),  # out: 1 where no valid tap was found (ray-marched afterwards)
    offset: int,
):
    # Engelhardt 2010 Sec. 4.3 / 5.3 and Fig. 5, 8
    j, i = wp.tid()
    j += offset
    unresolved[j * cam.width + i] = 0
    p = wp.vec2(float(i) + 0.5, float(j) + 0.5)
    if not screen_point_in_light(cam, light, p):
        out[j, i] = wp.vec3(0.0, 0.0, 0.0)  # the ray never enters the light frustum: exactly 0
        return
    pixel_depth = distance[j, i]
    # ---- 1D border lookup: the two lines whose border points enclose the ray's exit point ----
    dv = p - geo.epipole
    if wp.length(dv) < 1.0e-6:
        dv = wp.vec2(1.0, 0.0)
    u = border_arclength(geo.epipole - wp.vec2(0.5, 0.5), dv, geo.border_width, geo.border_height) / geo.spacing - 0.5
    k0 = wrap_line(int(wp.floor(u)), geo.lines)
    k1 = wrap_line(k0 + 1, geo.lines)
    # ---- tap spacing: distance between p's projections on the two nearest lines ----
    q0 = lines.entry[k0] + (lines.exit_[k0] - lines.entry[k0]) * project_on_line(lines.entry[k0], lines.exit_[k0], p)
    q1 = lines.entry[k1] + (lines.exit_[k1] - lines.entry[k1]) * project_on_line(lines.entry[k1], lines.exit_[k1], p)
    delta = wp.length(q0 - q1)
    # ---- bilateral filter along each side's nearest valid line, moving outwards ----
    acc_l = wp.vec3(0.0, 0.0, 0.0)
    w_l = float(0.0)
    d_l = float(0.0)
    for m in range(flt.outer_lines + 1):
        a, wsum, dist = line_filter(geo, flt, lines,
                                    wrap_line(k0 - m, geo.lines), p, pixel_depth, delta)
        if wsum > 0.0 and dist <= (float(m) + 1.0) * geo.spacing + 1.0:  # never a line across the pencil
            acc_l = a
            w_l = wsum
            d_l = dist
            break
    acc_r = wp.vec3(0.0, 0.0, 0.0)
    w_r = float(0.0)
    d_r = float(0.0)
    for m in range(flt.outer_lines + 1):
        a, wsum, dist = line_filter(geo, flt, lines,
                                    wrap_line(k1 + m, geo.lines), p, pixel_depth, delta)
        if wsum > 0.0 and dist <= (float(m) + 1.0) * geo.spacing + 1.0:
            acc_r = a
            w_r = wsum
            d_r = dist
            break
    if w_l <= 0.0 and w_r <= 0.0:
        out[j, i] = wp.vec3(0.0, 0.0, 0.0)
        unresolved[j * cam.width + i] = 1
        return
    # ---- between the lines: linear position between them times their weight sums ----
    frac = float(0.5)
    if d_l + d_r > 0.0:
        frac = d_l / (d_l + d_r)
    wl = (1.0 - frac) * w_l
    wr = frac * w_r
    if wl + wr > 1.0e-30:
        out[j, i] = (acc_l * (1.0 - frac) + acc_r * frac) / (wl + wr)
    else:
        out[j, i] = (acc_l + acc_r) / (w_l + w_r)


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


# ---- host ----------------------------------------------------------------------------------------


def filter_params(settings: EpipolarSettings, device=None) -> BilateralFilter:
    """:class:`BilateralFilter` from :class:`EpipolarSettings` (the tap distance weights come from a tiny kernel)."""
    device = default_device(device)
    f = BilateralFilter()
    f.kernel = EPIPOLAR_KERNELS.index(settings.kernel)
    f.taps = int(settings.taps)
    weights = wp.zeros(5, dtype=wp.float32, device=device)
    wp.launch(tap_weights_kernel, settings.taps, [f.kernel, f.taps, float(np.sqrt(settings.distance_falloff)),
                                                  weights], device=device)
    f.tap_weights = TapWeights(*weights.numpy())
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
    "BilateralFilter",
    "depth_scale",
    "depth_weight",
    "depth_weight_scaled",
    "filter_params",
    "kernel_weight",
    "line_filter",
]
