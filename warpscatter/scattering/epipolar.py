"""The ``epipolar`` render method: epipolar sampling for crepuscular rays (Engelhardt & Dachsbacher 2010).

In-scattered light varies smoothly along epipolar lines (the screen images of planes through the camera and
the light) except at depth discontinuities, so it is ray-marched only at a sparse set of samples on those
lines and interpolated elsewhere. Stages (names as they appear in timings):

1. ``lines``           — the epipole and N lines from it to equidistant border points, clipped against the
   viewport and culled when outside (:mod:`.epipolar_lines`, host numpy), clipped against a spot light's cone
   (:func:`trim_to_cone`); then the **coordinate texture** (line x texel -> screen position, Sec. 5.1; row =
   line, column = position along it) and the camera depth (G-buffer distance) at every texel.
2. ``discontinuities`` — every texel searches left and right inside its initial segment for depth
   discontinuities (Sec. 5.2 pseudo-code); the **interpolation texture** stores the two sources found; texels
   that are their own source (initial samples and texels beside a discontinuity) are ray-marching samples,
   compacted into a list (the paper's stencil mask).
3. ``raymarch``        — the ray-marching samples only, with the reference marcher's estimator
   (:func:`march_screen_point` = :func:`~.raymarch.march_ray` at a sub-pixel position; same steps restricted to
   the lit part of the ray, same jitter pattern and visibility: shadow map or exact), into the **radiance
   texture**.
4. ``interpolate``     — linear interpolation along each line between the sources; then per pixel (Sec. 4.3,
   5.3): the two nearest lines from the border arclength of the ray epipole -> pixel (the 1D border lookup,
   analytic because the border points are equidistant), projection onto them, a 3-5 tap bilateral filter
   along each (taps a multiple of the projections' distance apart, in symmetric pairs; distance and depth
   weights, Gaussian, Shepard or threshold), then between the lines by their weight sums; a side without
   valid taps moves to the next outer line (at most ``outer_lines``). Pixels with no valid tap on any tried
   line are ray-marched directly with :func:`~.raymarch.march_ray` (counted in
   ``epipolar_raymarched_fraction``; timed under ``raymarch``), so no pixel is ever left undefined. Pixels
   whose camera ray misses a spot light's cone are exactly 0.

Degenerate case: when the epipole is at infinity (light direction parallel to the image plane) or undefined
(a spot light at the camera), the method falls back to plain screen-space subsampling: a regular grid of
ray-marching samples every ``fallback_stride`` pixels, bilinear interpolation with the same depth weights,
direct ray marching where no grid corner is valid. The reason is logged on the ``warpscatter`` logger.

Spot-light textures modulate the marched samples exactly as in the reference (``light_sample``); with
``prefilter_light_texture`` a box-downsampled (mip-like) copy matched to the angular line spacing is used
instead (Sec. 6: "we have to prefilter the light texture accordingly").

Depth comparisons are relative: two camera depths a, b are discontinuous when |a - b| > threshold min(a, b),
which also raises the absolute threshold for distant parts of the scene as the paper suggests (Sec. 6).
"""

from __future__ import annotations

import logging
from contextlib import nullcontext
from dataclasses import dataclass, replace

import numpy as np
import warp as wp

from ..parallel import launch_rows
from ..scene.camera import CameraParams, pixel_ray_direction
from ..scene.lights import LightParams, SpotLight, light_params, light_texture_array
from ..shadows.shadow_map import ShadowMapParams
from ..wpinit import default_device, module_options
from .epipolar_lines import EpipolarLines, epipolar_lines, light_texture_level
from .raymarch import (
    MediumParams,
    jitter_mode,
    march_along,
    march_ray,
    medium_params,
    visibility_inputs,
)

module_options()

logger = logging.getLogger("warpscatter")

#: Radial basis functions of the bilateral filter (Engelhardt 2010 Sec. 4.3).
KERNELS = ("gaussian", "shepard", "threshold")
KERNEL_GAUSSIAN = wp.constant(0)
KERNEL_SHEPARD = wp.constant(1)
KERNEL_THRESHOLD = wp.constant(2)


@dataclass(frozen=True)
class EpipolarSettings:
    """Parameters of the ``epipolar`` method.

    =========================  ======  ========  ==========================================================
    name                       type    default   meaning
    =========================  ======  ========  ==========================================================
    lines                      int     1024      epipolar lines (equidistant border points), 8..16384
    initial_samples            int     16        initial ray-marching samples per line (Sec. 4.1), 2..1024
    samples_per_line           int     None      texels per line (max samples); None: image diagonal (px)
    depth_threshold            float   0.05      relative camera-depth jump that is a discontinuity
    kernel                     str     gaussian  bilateral weight: gaussian exp(-x^2), shepard 1/(1+x^2),
                                                 threshold (depth only: x <= 1; distance weight 1)
    taps                       int     3         taps per line of the bilateral filter, 3..5
    distance_falloff           float   0.5       a of the distance weight, x^2 = a (offset / delta)^2
    depth_sigma                float   0.1       relative depth difference at which the depth x = 1
    min_weight                 float   0.05      taps whose depth weight is below this are invalid
    outer_lines                int     2         outer lines tried per side when a side has no valid tap
    prefilter_light_texture    bool    False     box-downsample a spot texture to the line spacing
    fallback_stride            int     4         grid spacing (px) of the degenerate-case subsampling
    max_epipole_distance       float   1000      farther epipoles (image diagonals) count as at infinity
    =========================  ======  ========  ==========================================================

    Example::

        settings = EpipolarSettings(lines=512, initial_samples=8, kernel="shepard")
        l_scat, info = render_epipolar(scene, gbuffer, settings=settings, steps=128, visibility="shadow_map",
                                       shadow_map=shadow_map)
    """

    lines: int = 1024
    initial_samples: int = 16
    samples_per_line: int | None = None
    depth_threshold: float = 0.05
    kernel: str = "gaussian"
    taps: int = 3
    distance_falloff: float = 0.5
    depth_sigma: float = 0.1
    min_weight: float = 0.05
    outer_lines: int = 2
    prefilter_light_texture: bool = False
    fallback_stride: int = 4
    max_epipole_distance: float = 1000.0

    def validate(self) -> None:
        """Raise ValueError naming the first out-of-range field."""
        checks = [
            ("lines", 8 <= self.lines <= 16384, "must lie in [8, 16384]"),
            ("initial_samples", 2 <= self.initial_samples <= 1024, "must lie in [2, 1024]"),
            ("samples_per_line", self.samples_per_line is None or self.samples_per_line >= self.initial_samples,
             f"must be None or >= initial_samples ({self.initial_samples})"),
            ("depth_threshold", self.depth_threshold > 0.0, "must be > 0"),
            ("kernel", self.kernel in KERNELS, f"must be one of {', '.join(KERNELS)}"),
            ("taps", 3 <= self.taps <= 5, "must lie in [3, 5]"),
            ("distance_falloff", self.distance_falloff >= 0.0, "must be >= 0"),
            ("depth_sigma", self.depth_sigma > 0.0, "must be > 0"),
            ("min_weight", 0.0 < self.min_weight <= 1.0, "must lie in (0, 1]"),
            ("outer_lines", 0 <= self.outer_lines <= 64, "must lie in [0, 64]"),
            ("fallback_stride", 1 <= self.fallback_stride <= 256, "must lie in [1, 256]"),
            ("max_epipole_distance", self.max_epipole_distance > 0.0, "must be > 0"),
        ]
        for name, ok, why in checks:
            if not ok:
                raise ValueError(f"epipolar {name}: {why}, got {getattr(self, name)!r}")


@wp.struct
class EpipolarGeometry:
    """The line layout as kernels see it (pixels, y down)."""

    epipole: wp.vec2  # screen position of the (anti-)epipole
    border_width: float  # border rectangle [0.5, 0.5 + border_width] x [0.5, 0.5 + border_height], pixels
    border_height: float
    spacing: float  # border arclength between consecutive lines' end points, pixels
    lines: int  # N: rows of the coordinate / interpolation / radiance textures
    samples: int  # texels per line: their columns
    segment: int  # texels per initial segment


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


# ---- helpers ------------------------------------------------------------------------------------------------


@wp.func
def depth_discontinuity(a: float, b: float, threshold: float) -> bool:
    """Engelhardt 2010 Sec. 5.2: a depth discontinuity between camera depths a and b (relative threshold)."""
    return wp.abs(a - b) > threshold * wp.min(a, b)


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
def sample_distance(distance: wp.array2d(dtype=wp.float32), x: float, y: float, threshold: float) -> float:
    """Camera depth at screen point (x, y): bilinear between the 4 nearest pixel centres when they are
    continuous (no pair differs by more than ``threshold`` relative; linear extrapolation outside the outermost
    centres), else the nearest pixel's. Needs an image of at least 2 x 2 pixels."""
    h = distance.shape[0]
    w = distance.shape[1]
    fx = x - 0.5
    fy = y - 0.5
    i0 = wp.clamp(int(wp.floor(fx)), 0, w - 2)
    j0 = wp.clamp(int(wp.floor(fy)), 0, h - 2)
    i1 = i0 + 1
    j1 = j0 + 1
    d00 = distance[j0, i0]
    d10 = distance[j0, i1]
    d01 = distance[j1, i0]
    d11 = distance[j1, i1]
    lo = wp.min(wp.min(d00, d10), wp.min(d01, d11))
    hi = wp.max(wp.max(d00, d10), wp.max(d01, d11))
    if not depth_discontinuity(lo, hi, threshold):
        ax = fx - float(i0)
        ay = fy - float(j0)
        v = (d00 * (1.0 - ax) + d10 * ax) * (1.0 - ay) + (d01 * (1.0 - ax) + d11 * ax) * ay
        return wp.max(v, 0.5 * lo)  # extrapolation never leaves the surface's depth range by more than 2x
    ni = wp.clamp(int(wp.floor(x)), 0, w - 1)
    nj = wp.clamp(int(wp.floor(y)), 0, h - 1)
    return distance[nj, ni]


@wp.func
def border_arclength(e: wp.vec2, d: wp.vec2, width: float, height: float) -> float:
    """Border arclength (clockwise from the top-left corner, pixels) where the ray e + t d, t > 0, leaves the
    rectangle [0, width] x [0, height] (the ray must cross it; e may lie outside). Engelhardt 2010 Fig. 8.

    Callers pass positions relative to the border rectangle's corner (0.5, 0.5).
    """
    tx = float(1.0e30)
    ty = float(1.0e30)
    if d[0] > 0.0:
        tx = (width - e[0]) / d[0]
    elif d[0] < 0.0:
        tx = -e[0] / d[0]
    if d[1] > 0.0:
        ty = (height - e[1]) / d[1]
    elif d[1] < 0.0:
        ty = -e[1] / d[1]
    if tx < ty:
        y = wp.clamp(e[1] + tx * d[1], 0.0, height)
        if d[0] > 0.0:
            return width + y  # right edge, downwards
        return 2.0 * width + 2.0 * height - y  # left edge, upwards
    x = wp.clamp(e[0] + ty * d[0], 0.0, width)
    if d[1] > 0.0:
        return 2.0 * width + height - x  # bottom edge, leftwards
    return x  # top edge, rightwards


@wp.func
def ray_enters_cone(origin: wp.vec3, d: wp.vec3, apex: wp.vec3, axis: wp.vec3, cos_cone: float) -> bool:
    """True if the ray origin + t d (unit d, t >= 0, unbounded) enters the cone of unit ``axis`` at ``apex``:
    {x: angle(x - apex, axis) <= acos(cos_cone)}, cos_cone > 0 (the forward nappe only).

    Seen from the apex, the ray's points sweep the great-circle arc from normalize(origin - apex) to d; the ray
    enters the cone iff the arc comes within the cone's half-angle of the axis (closest point of the great
    circle if it lies on the arc, else the nearer end).
    """
    w = origin - apex
    lw = wp.length(w)
    if lw < 1.0e-12:
        return True
    u0 = w / lw
    best = wp.max(wp.dot(u0, axis), wp.dot(d, axis))
    m = wp.cross(u0, d)
    lm = wp.length(m)
    if lm > 1.0e-9:
        m = m / lm
        am = wp.dot(axis, m)
        q = axis - m * am
        lq = wp.length(q)
        if lq > 1.0e-9:
            q = q / lq
            if wp.dot(wp.cross(u0, q), m) >= 0.0 and wp.dot(wp.cross(q, d), m) >= 0.0:
                best = wp.max(best, wp.sqrt(wp.max(1.0 - am * am, 0.0)))
    return best >= cos_cone


@wp.func
def screen_point_in_light(cam: CameraParams, light: LightParams, p: wp.vec2) -> bool:
    """True if the camera ray through screen point p (pixels) enters the light's frustum (always for directional
    lights; for spot lights the cone of :func:`~warpscatter.scene.lights.light_sample`)."""
    if light.kind == 0:
        return True
    d = pixel_ray_direction(cam, p[0], p[1])
    return ray_enters_cone(cam.position, d, light.position, light.direction, light.cos_cone)


@wp.func
def march_screen_point(cam: CameraParams, x: float, y: float, s: float, light: LightParams,
                       light_tex: wp.array2d(dtype=wp.vec3), med: MediumParams, steps: int, seed: int, jitter: int,
                       vis_mode: int, mesh: wp.uint64, eps: float, sm: ShadowMapParams,
                       sm_depth: wp.array2d(dtype=wp.float32), sm_bias: float) -> wp.vec3:
    """L_scat along the camera ray through screen point (x, y) (pixels) ending at distance s.

    The reference marcher's estimator (:func:`~warpscatter.scattering.raymarch.march_along`: strata over the
    lit part of the ray, exact transmittance per stratum, ``jitter`` pattern) at a sub-pixel position; the random
    stream is that of the pixel containing (x, y), so a sample at a pixel centre reproduces the reference value
    bit for bit.
    """
    d = pixel_ray_direction(cam, x, y)
    pi = wp.clamp(int(wp.floor(x)), 0, cam.width - 1)
    pj = wp.clamp(int(wp.floor(y)), 0, cam.height - 1)
    return march_along(cam.position, d, s, pj * cam.width + pi, light, light_tex, med, steps, seed, jitter, vis_mode,
                       mesh, eps, sm, sm_depth, sm_bias)


@wp.func
def project_on_line(a: wp.vec2, b: wp.vec2, p: wp.vec2) -> float:
    """Parameter tau of the orthogonal projection of p onto the line a + tau (b - a) (0 for a zero-length line)."""
    ab = b - a
    l2 = wp.dot(ab, ab)
    if l2 < 1.0e-12:
        return 0.0
    return wp.dot(p - a, ab) / l2


@wp.func
def line_filter(geo: EpipolarGeometry, flt: BilateralFilter, entry: wp.array(dtype=wp.vec2),
                exit_: wp.array(dtype=wp.vec2), valid: wp.array(dtype=wp.int32),
                line_depth: wp.array2d(dtype=wp.float32), radiance: wp.array2d(dtype=wp.vec3), k: int, p: wp.vec2,
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
    a = entry[k]
    b = exit_[k]
    tau = project_on_line(a, b, p)
    tc = wp.clamp(tau, 0.0, 1.0)
    seg_len = wp.length(b - a)
    dist = wp.length(p - (a + (b - a) * tc))
    if valid[k] == 0 or seg_len < 1.0e-6:
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
            w0 = (1.0 - f) * wdist * depth_weight_scaled(flt, line_depth[k, t0], pixel_depth, scale)
            if w0 > 0.0:
                acc += radiance[k, t0] * w0
                wsum += w0
        if f > 0.0:
            w1 = f * wdist * depth_weight_scaled(flt, line_depth[k, t1], pixel_depth, scale)
            if w1 > 0.0:
                acc += radiance[k, t1] * w1
                wsum += w1
    return acc, wsum, dist


@wp.func
def wrap_line(k: int, n: int) -> int:
    """Line index k modulo n (non-negative)."""
    r = k % n
    if r < 0:
        r += n
    return r


# ---- kernels -------------------------------------------------------------------------------------------------


@wp.kernel
def tap_weights_kernel(kernel: int, taps: int, distance_scale: float, weights: wp.array(dtype=wp.float32)):
    # distance term of tap m at offset m - (taps-1)/2 delta (Engelhardt 2010 Sec. 4.3); the threshold kernel has none
    m = wp.tid()
    weights[m] = 1.0
    if kernel != KERNEL_THRESHOLD:
        weights[m] = kernel_weight(kernel, distance_scale * wp.abs(float(m) - 0.5 * float(taps - 1)))


@wp.kernel
def trim_to_cone_kernel(
    cam: CameraParams,
    light: LightParams,
    points: int,
    entry: wp.array(dtype=wp.vec2),  # in/out: segment start
    exit_: wp.array(dtype=wp.vec2),  # in/out: segment end
    valid: wp.array(dtype=wp.int32),  # in/out: 0 when no camera ray of the segment enters the cone
    offset: int,
):
    # Engelhardt 2010 Sec. 5.1: clip the lines against the light frustum. The camera rays of one epipolar line
    # that enter the cone form one interval along it: find it on ``points`` equidistant points, refine both ends
    # by bisection, keep one pixel of margin.
    k = wp.tid() + offset
    if valid[k] == 0:
        return
    a = entry[k]
    ab = exit_[k] - a
    first = int(-1)
    last = int(-1)
    for n in range(points):
        if screen_point_in_light(cam, light, a + ab * (float(n) / float(points - 1))):
            if first < 0:
                first = n
            last = n
    if first < 0:
        valid[k] = 0
        return
    dt = 1.0 / float(points - 1)
    t_lo = float(first) * dt
    if first > 0:
        lo = t_lo - dt  # outside
        hi = t_lo  # inside
        for _it in range(24):
            mid = 0.5 * (lo + hi)
            if screen_point_in_light(cam, light, a + ab * mid):
                hi = mid
            else:
                lo = mid
        t_lo = lo
    t_hi = float(last) * dt
    if last < points - 1:
        lo = t_hi  # inside
        hi = t_hi + dt  # outside
        for _it in range(24):
            mid = 0.5 * (lo + hi)
            if screen_point_in_light(cam, light, a + ab * mid):
                lo = mid
            else:
                hi = mid
        t_hi = hi
    pad = 1.0 / wp.max(wp.length(ab), 1.0e-6)
    t_lo = wp.max(t_lo - pad, 0.0)
    t_hi = wp.min(t_hi + pad, 1.0)
    entry[k] = a + ab * t_lo
    exit_[k] = a + ab * t_hi


@wp.kernel
def line_samples_kernel(
    geo: EpipolarGeometry,
    entry: wp.array(dtype=wp.vec2),
    exit_: wp.array(dtype=wp.vec2),
    valid: wp.array(dtype=wp.int32),
    distance: wp.array2d(dtype=wp.float32),
    threshold: float,
    coords: wp.array2d(dtype=wp.vec2),  # out: coordinate texture (line, texel) -> screen position
    line_depth: wp.array2d(dtype=wp.float32),  # out: camera depth at each texel
    offset: int,
):
    # Engelhardt 2010 Sec. 5.1: texel positions by interpolation between the clipped segment's end points
    k, x = wp.tid()
    k += offset
    if valid[k] == 0:
        coords[k, x] = wp.vec2(-1.0, -1.0)
        line_depth[k, x] = 0.0
        return
    t = float(x) / float(geo.samples - 1)
    p = entry[k] + (exit_[k] - entry[k]) * t
    coords[k, x] = p
    line_depth[k, x] = sample_distance(distance, p[0], p[1], threshold)


@wp.kernel
def segment_discontinuity_kernel(
    geo: EpipolarGeometry,
    valid: wp.array(dtype=wp.int32),
    line_depth: wp.array2d(dtype=wp.float32),
    threshold: float,
    segment_has_edge: wp.array2d(dtype=wp.int32),  # out: 1 if initial segment m of line k holds a discontinuity
    offset: int,
):
    # one pass per initial segment, so that texels of discontinuity-free segments (most of them) need no search
    k, m = wp.tid()
    k += offset
    found = int(0)
    if valid[k] != 0:
        x0 = m * geo.segment
        for x in range(x0, x0 + geo.segment):
            if depth_discontinuity(line_depth[k, x], line_depth[k, x + 1], threshold):
                found = 1
                break
    segment_has_edge[k, m] = found


@wp.kernel
def discontinuity_kernel(
    geo: EpipolarGeometry,
    valid: wp.array(dtype=wp.int32),
    line_depth: wp.array2d(dtype=wp.float32),
    threshold: float,
    segment_has_edge: wp.array2d(dtype=wp.int32),
    interp: wp.array2d(dtype=wp.vec2i),  # out: interpolation texture (left, right source texels)
    march: wp.array(dtype=wp.int32),  # out: 1 for ray-marching samples, flat index line * samples + texel
    offset: int,
):
    # Engelhardt 2010 Sec. 5.2 pseudo-code: search the texel's initial segment left and right for discontinuities
    k, x = wp.tid()
    k += offset
    flat = k * geo.samples + x
    if valid[k] == 0:
        interp[k, x] = wp.vec2i(x, x)
        march[flat] = 0
        return
    m = x // geo.segment
    seg_start = m * geo.segment
    seg_end = wp.min(seg_start + geo.segment, geo.samples - 1)
    if m < segment_has_edge.shape[1]:
        if segment_has_edge[k, m] == 0:  # the search would run to both ends of the segment
            interp[k, x] = wp.vec2i(seg_start, seg_end)
            if x == seg_start:
                march[flat] = 1
            else:
                march[flat] = 0
            return
    left = int(x)
    while left > seg_start:
        if depth_discontinuity(line_depth[k, left - 1], line_depth[k, left], threshold):
            break
        left -= 1
    right = int(x)
    while right < seg_end:
        if depth_discontinuity(line_depth[k, right], line_depth[k, right + 1], threshold):
            break
        right += 1
    interp[k, x] = wp.vec2i(left, right)
    if left == x or right == x:  # interpolates from itself: a ray-marching sample
        march[flat] = 1
    else:
        march[flat] = 0


@wp.kernel
def compact_kernel(flags: wp.array(dtype=wp.int32), scan: wp.array(dtype=wp.int32),
                   indices: wp.array(dtype=wp.int32), offset: int):
    # scatter the flagged flat indices to their exclusive-scan slots (the paper's stencil mask as a list)
    n = wp.tid() + offset
    if flags[n] != 0:
        indices[scan[n]] = n


@wp.kernel
def raymarch_samples_kernel(
    indices: wp.array(dtype=wp.int32),
    geo: EpipolarGeometry,
    coords: wp.array2d(dtype=wp.vec2),
    line_depth: wp.array2d(dtype=wp.float32),
    cam: CameraParams,
    light: LightParams,
    light_tex: wp.array2d(dtype=wp.vec3),
    med: MediumParams,
    steps: int,
    seed: int,
    jitter: int,
    vis_mode: int,
    mesh: wp.uint64,
    eps: float,
    sm: ShadowMapParams,
    sm_depth: wp.array2d(dtype=wp.float32),
    sm_bias: float,
    radiance: wp.array2d(dtype=wp.vec3),  # out: radiance texture at the ray-marching samples
    offset: int,
):
    n = wp.tid() + offset
    flat = indices[n]
    k = flat // geo.samples
    x = flat - k * geo.samples
    p = coords[k, x]
    radiance[k, x] = march_screen_point(cam, p[0], p[1], line_depth[k, x], light, light_tex, med, steps, seed,
                                        jitter, vis_mode, mesh, eps, sm, sm_depth, sm_bias)


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
    entry: wp.array(dtype=wp.vec2),
    exit_: wp.array(dtype=wp.vec2),
    valid: wp.array(dtype=wp.int32),
    line_depth: wp.array2d(dtype=wp.float32),
    radiance: wp.array2d(dtype=wp.vec3),
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
    q0 = entry[k0] + (exit_[k0] - entry[k0]) * project_on_line(entry[k0], exit_[k0], p)
    q1 = entry[k1] + (exit_[k1] - entry[k1]) * project_on_line(entry[k1], exit_[k1], p)
    delta = wp.length(q0 - q1)
    # ---- bilateral filter along each side's nearest valid line, moving outwards ----
    acc_l = wp.vec3(0.0, 0.0, 0.0)
    w_l = float(0.0)
    d_l = float(0.0)
    for m in range(flt.outer_lines + 1):
        a, wsum, dist = line_filter(geo, flt, entry, exit_, valid, line_depth, radiance,
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
        a, wsum, dist = line_filter(geo, flt, entry, exit_, valid, line_depth, radiance,
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
def raymarch_pixels_kernel(
    indices: wp.array(dtype=wp.int32),
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    light: LightParams,
    light_tex: wp.array2d(dtype=wp.vec3),
    med: MediumParams,
    steps: int,
    seed: int,
    jitter: int,
    vis_mode: int,
    mesh: wp.uint64,
    eps: float,
    sm: ShadowMapParams,
    sm_depth: wp.array2d(dtype=wp.float32),
    sm_bias: float,
    out: wp.array2d(dtype=wp.vec3),
    offset: int,
):
    # pixels without any valid source: the reference marcher at the pixel centre
    n = wp.tid() + offset
    flat = indices[n]
    j = flat // cam.width
    i = flat - j * cam.width
    out[j, i] = march_ray(cam, i, j, distance[j, i], light, light_tex, med, steps, seed, jitter, vis_mode, mesh, eps,
                          sm, sm_depth, sm_bias)


@wp.func
def grid_node(m: int, stride: int, size: int) -> int:
    """Pixel coordinate of grid node m of the degenerate-case subsampling (the last node is clamped to the edge)."""
    return wp.min(m * stride, size - 1)


@wp.kernel
def grid_raymarch_kernel(
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    stride: int,
    light: LightParams,
    light_tex: wp.array2d(dtype=wp.vec3),
    med: MediumParams,
    steps: int,
    seed: int,
    jitter: int,
    vis_mode: int,
    mesh: wp.uint64,
    eps: float,
    sm: ShadowMapParams,
    sm_depth: wp.array2d(dtype=wp.float32),
    sm_bias: float,
    grid: wp.array2d(dtype=wp.vec3),  # out: L_scat at the grid nodes
    offset: int,
):
    gj, gi = wp.tid()
    gj += offset
    i = grid_node(gi, stride, cam.width)
    j = grid_node(gj, stride, cam.height)
    grid[gj, gi] = march_ray(cam, i, j, distance[j, i], light, light_tex, med, steps, seed, jitter, vis_mode, mesh,
                             eps, sm, sm_depth, sm_bias)


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


@wp.kernel
def box_downsample_kernel(src: wp.array2d(dtype=wp.vec3), factor: int, out: wp.array2d(dtype=wp.vec3), offset: int):
    # light-texture prefiltering: mean of each factor x factor block (partial blocks at the far edges)
    j, i = wp.tid()
    j += offset
    acc = wp.vec3(0.0, 0.0, 0.0)
    n = float(0.0)
    for dj in range(factor):
        y = j * factor + dj
        if y < src.shape[0]:
            for di in range(factor):
                x = i * factor + di
                if x < src.shape[1]:
                    acc += src[y, x]
                    n += 1.0
    out[j, i] = acc / wp.max(n, 1.0)


# ---- host ----------------------------------------------------------------------------------------------------


def _stage(timer, name):
    return timer(name) if timer is not None else nullcontext()


def compact(flags: wp.array, device=None) -> tuple[wp.array, int]:
    """Indices of the non-zero entries of a 1-D int32 flag array (exclusive scan + scatter).

    Returns:
        (indices, count): int32 array of length max(count, 1) (the first ``count`` entries are valid) and count.
    """
    device = default_device(device)
    n = flags.shape[0]
    scan = wp.empty(n, dtype=wp.int32, device=device)
    wp.utils.array_scan(flags, scan, inclusive=False)
    count = int(scan[n - 1:].numpy()[0] + flags[n - 1:].numpy()[0]) if n else 0
    indices = wp.empty(max(count, 1), dtype=wp.int32, device=device)
    if count:
        launch_rows(compact_kernel, n, [flags, scan, indices], device=device)
    return indices, count


def prefilter_light_texture(texture: np.ndarray, level: int, device=None) -> wp.array:
    """Box-downsample an (H, W, 3) light texture by 2^level (one mip level; level 0 returns it unchanged).

    Args:
        texture: linear RGB float32, row 0 = top.
        level: mip level >= 0.
        device: Warp device.

    Returns:
        wp.array2d(vec3) of shape (ceil(H / 2^level), ceil(W / 2^level)).
    """
    if level < 0:
        raise ValueError(f"level must be >= 0, got {level}")
    device = default_device(device)
    src = wp.array(np.ascontiguousarray(texture[..., :3], dtype=np.float32), dtype=wp.vec3, device=device)
    if level == 0:
        return src
    f = 2 ** level
    h, w = -(-texture.shape[0] // f), -(-texture.shape[1] // f)
    out = wp.empty((h, w), dtype=wp.vec3, device=device)
    launch_rows(box_downsample_kernel, (h, w), [src, f, out], device=device)
    return out


def geometry_params(lines: EpipolarLines) -> EpipolarGeometry:
    """:class:`EpipolarGeometry` of a set of lines."""
    g = EpipolarGeometry()
    g.epipole = wp.vec2(float(lines.epipole[0]), float(lines.epipole[1]))
    g.border_width, g.border_height = float(lines.width - 1), float(lines.height - 1)
    g.spacing = float(lines.spacing)
    g.lines, g.samples, g.segment = int(lines.count), int(lines.samples), int(lines.segment)
    return g


def filter_params(settings: EpipolarSettings, device=None) -> BilateralFilter:
    """:class:`BilateralFilter` from :class:`EpipolarSettings` (the tap distance weights come from a tiny kernel)."""
    device = default_device(device)
    f = BilateralFilter()
    f.kernel = KERNELS.index(settings.kernel)
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


@dataclass
class LineTextures:
    """Device textures of the epipolar lines, all (lines, samples) in the paper's layout (Fig. 6)."""

    entry: wp.array  # (N,) vec2
    exit: wp.array  # (N,) vec2
    valid: wp.array  # (N,) int32
    coords: wp.array  # coordinate texture: vec2 screen position
    depth: wp.array  # camera depth (G-buffer distance) at each texel
    interp: wp.array | None = None  # interpolation texture: vec2i (left, right) sources
    march: wp.array | None = None  # (N * samples,) int32: 1 for ray-marching samples
    radiance: wp.array | None = None  # radiance texture: vec3 L_scat


#: Points per line at which the light frustum is tested before the bisection of :func:`trim_to_cone`.
CONE_TRIM_POINTS = 128


def trim_to_cone(lines: EpipolarLines, camera, light, device=None) -> EpipolarLines:
    """Clip the lines against a spot light's cone (Engelhardt 2010 Sec. 5.1); lines missing it are culled.

    Directional lights return ``lines`` unchanged. The segment ends keep one pixel of margin beyond the interval
    of camera rays that enter the cone (an interval narrower than 1 / CONE_TRIM_POINTS of a line may be missed:
    its pixels find no valid line and are ray-marched directly).
    """
    if not isinstance(light, SpotLight):
        return lines
    device = default_device(device)
    entry = wp.array(lines.entry, dtype=wp.vec2, device=device)
    exit_ = wp.array(lines.exit, dtype=wp.vec2, device=device)
    valid = wp.array(lines.valid.astype(np.int32), dtype=wp.int32, device=device)
    launch_rows(trim_to_cone_kernel, lines.count,
                [camera.params(), light_params(light), CONE_TRIM_POINTS, entry, exit_, valid], device=device)
    return replace(lines, entry=entry.numpy(), exit=exit_.numpy(), valid=valid.numpy().astype(bool))


def line_samples(lines: EpipolarLines, distance: wp.array, depth_threshold: float, device=None) -> LineTextures:
    """Coordinate texture and per-texel camera depth (Engelhardt 2010 Sec. 5.1).

    Args:
        lines: the frame's :class:`EpipolarLines`.
        distance: (H, W) G-buffer distance (camera depth along each pixel ray).
        depth_threshold: relative threshold deciding where the depth is sampled bilinearly (continuous).
        device: Warp device.
    """
    device = default_device(device)
    n, s = lines.count, lines.samples
    tex = LineTextures(entry=wp.array(lines.entry, dtype=wp.vec2, device=device),
                       exit=wp.array(lines.exit, dtype=wp.vec2, device=device),
                       valid=wp.array(lines.valid.astype(np.int32), dtype=wp.int32, device=device),
                       coords=wp.empty((n, s), dtype=wp.vec2, device=device),
                       depth=wp.empty((n, s), dtype=wp.float32, device=device))
    launch_rows(line_samples_kernel, (n, s),
                [geometry_params(lines), tex.entry, tex.exit, tex.valid, distance, float(depth_threshold), tex.coords,
                 tex.depth], device=device)
    return tex


def classify_samples(lines: EpipolarLines, tex: LineTextures, depth_threshold: float, device=None) -> LineTextures:
    """Discontinuity search and classification into ray-marching / interpolation samples (Sec. 5.2).

    Fills ``tex.interp`` (left, right sources per texel) and ``tex.march`` (flat ray-marching flags).
    """
    device = default_device(device)
    n, s = lines.count, lines.samples
    tex.interp = wp.empty((n, s), dtype=wp.vec2i, device=device)
    tex.march = wp.empty(n * s, dtype=wp.int32, device=device)
    geo = geometry_params(lines)
    segments = (s - 1) // lines.segment
    has_edge = wp.empty((n, segments), dtype=wp.int32, device=device)
    launch_rows(segment_discontinuity_kernel, (n, segments),
                [geo, tex.valid, tex.depth, float(depth_threshold), has_edge], device=device)
    launch_rows(discontinuity_kernel, (n, s),
                [geo, tex.valid, tex.depth, float(depth_threshold), has_edge, tex.interp, tex.march], device=device)
    return tex


def sample_texture_bytes(lines: EpipolarLines) -> int:
    """Bytes of the per-line textures (coordinate 8, depth 4, interpolation 8, flags 4, radiance 12 per texel)."""
    return int(lines.count * lines.samples * (8 + 4 + 8 + 4 + 12))


def render_epipolar(scene, gbuffer, *, settings: EpipolarSettings | None = None, steps: int = 128,
                    visibility: str = "shadow_map", geometry=None, shadow_map=None, seed: int = 0,
                    jitter: str = "per_pixel", shadow_bias_texels: float = 1.0, timer=None,
                    device=None) -> tuple[wp.array, dict]:
    """Single scattering by epipolar sampling (the ``epipolar`` method; see the module doc).

    Args:
        scene: the :class:`~warpscatter.scene.Scene` (directional or spot light, textured or not).
        gbuffer: the camera :class:`~warpscatter.gbuffer.GBuffer` (its ``distance`` is the camera depth).
        settings: :class:`EpipolarSettings` (defaults when None).
        steps: ray-marching steps per sample, as the reference marcher (>= 1).
        visibility: ``"shadow_map"`` (needs ``shadow_map``) or ``"exact"`` (needs ``geometry``).
        geometry: :class:`~warpscatter.scene.DeviceGeometry` for exact visibility.
        shadow_map: the light's :class:`~warpscatter.shadows.shadow_map.ShadowMap` for shadow-map visibility.
        seed: jitter seed (the reference marcher's: a sample at a pixel centre reproduces its value).
        jitter: the reference marcher's step pattern, ``"per_pixel"`` or ``"fixed"``
            (:mod:`~warpscatter.scattering.raymarch`).
        shadow_bias_texels: shadow-map depth bias in texel sizes.
        timer: optional callable ``timer(stage_name)`` returning a context manager (e.g. a pipeline StageTimer);
            stages ``lines``, ``discontinuities``, ``raymarch``, ``interpolate``.
        device: Warp device.

    Returns:
        (L_scat, info): (H, W) vec3 wp.array of in-scattered radiance (linear RGB) and a dict with
        ``epipolar_raymarched_fraction`` (ray marches / pixels), sample and pixel counts, the epipole, the valid
        line count, the light-texture level and ``epipolar_fallback`` (None or the degenerate-case reason).

    Raises:
        ValueError: bad settings, steps, visibility mode or missing visibility input.
    """
    device = default_device(device)
    settings = settings or EpipolarSettings()
    settings.validate()
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    vis_mode, mesh_id, eps, sm_params, sm_depth, bias = visibility_inputs(scene, visibility, geometry, shadow_map,
                                                                           shadow_bias_texels, device)
    cam, light = scene.camera, scene.light
    if cam.width < 2 or cam.height < 2:
        raise ValueError(f"scene.camera: epipolar sampling needs an image of at least 2x2 pixels, got "
                         f"{cam.width}x{cam.height}")
    cam_p, light_p, med_p = cam.params(), light_params(light), medium_params(scene.medium)
    flt = filter_params(settings, device)
    h, w = cam.height, cam.width
    march_args = [int(steps), int(seed), jitter_mode(jitter), vis_mode, mesh_id, eps, sm_params, sm_depth, bias]
    out = wp.empty((h, w), dtype=wp.vec3, device=device)
    unresolved = wp.empty(h * w, dtype=wp.int32, device=device)
    info = {"epipolar_lines": settings.lines, "epipolar_initial_samples": settings.initial_samples}

    with _stage(timer, "lines"):
        lines, reason = epipolar_lines(cam, light, settings.lines, settings.initial_samples,
                                       settings.samples_per_line, settings.max_epipole_distance)
        if lines is not None:
            lines = trim_to_cone(lines, cam, light, device)
        level, footprint = (0, 0.0)
        texture = getattr(light, "texture", None)
        if lines is not None and settings.prefilter_light_texture and texture is not None:
            level, footprint = light_texture_level(lines, cam, light, texture.shape)
        light_tex = (prefilter_light_texture(texture, level, device) if level > 0
                     else light_texture_array(light, device))
        if lines is not None:
            tex = line_samples(lines, gbuffer.distance, settings.depth_threshold, device)
    info["epipolar_light_texture_level"] = level
    info["epipolar_light_texture_footprint"] = footprint

    if lines is None:
        # ---- degenerate case: plain screen-space subsampling ----
        logger.warning("epipolar sampling falls back to screen-space subsampling every %d px: %s",
                       settings.fallback_stride, reason)
        stride = settings.fallback_stride
        gw, gh = -(-(w - 1) // stride) + 1, -(-(h - 1) // stride) + 1
        grid = wp.empty((gh, gw), dtype=wp.vec3, device=device)
        with _stage(timer, "raymarch"):
            launch_rows(grid_raymarch_kernel, (gh, gw),
                        [cam_p, gbuffer.distance, int(stride), light_p, light_tex, med_p, *march_args, grid],
                        device=device)
        with _stage(timer, "interpolate"):
            launch_rows(grid_upsample_kernel, (h, w),
                        [cam_p, gbuffer.distance, int(stride), grid, flt, out, unresolved], device=device)
        marched_samples = gw * gh
        info.update({"epipolar_fallback": reason, "epipolar_epipole": None, "epipolar_lines_valid": 0,
                     "epipolar_grid": [gw, gh]})
    else:
        geo = geometry_params(lines)
        with _stage(timer, "discontinuities"):
            classify_samples(lines, tex, settings.depth_threshold, device)
            sample_idx, marched_samples = compact(tex.march, device)
        with _stage(timer, "raymarch"):
            tex.radiance = wp.zeros((lines.count, lines.samples), dtype=wp.vec3, device=device)
            if marched_samples:
                launch_rows(raymarch_samples_kernel, marched_samples,
                            [sample_idx, geo, tex.coords, tex.depth, cam_p, light_p, light_tex, med_p, *march_args,
                             tex.radiance], device=device)
        with _stage(timer, "interpolate"):
            launch_rows(interpolate_lines_kernel, (lines.count, lines.samples), [tex.valid, tex.interp, tex.radiance],
                        device=device)
            launch_rows(upsample_kernel, (h, w),
                        [cam_p, gbuffer.distance, light_p, geo, flt, tex.entry, tex.exit, tex.valid, tex.depth,
                         tex.radiance, out, unresolved], device=device)
        info.update({"epipolar_fallback": None, "epipolar_epipole": [float(v) for v in lines.epipole],
                     "epipolar_light_behind": lines.light_behind, "epipolar_lines_valid": int(lines.valid.sum()),
                     "epipolar_samples_per_line": lines.samples,
                     "epipolar_texture_bytes": sample_texture_bytes(lines)})

    with _stage(timer, "raymarch"):
        pixel_idx, marched_pixels = compact(unresolved, device)
        if marched_pixels:
            launch_rows(raymarch_pixels_kernel, marched_pixels,
                        [pixel_idx, cam_p, gbuffer.distance, light_p, light_tex, med_p, *march_args, out],
                        device=device)
    info.update({
        "epipolar_raymarched_samples": int(marched_samples),
        "epipolar_raymarched_pixels": int(marched_pixels),
        "epipolar_raymarched_fraction": float((marched_samples + marched_pixels) / (w * h)),
    })
    return out, info


__all__ = [
    "KERNELS",
    "BilateralFilter",
    "border_arclength",
    "classify_samples",
    "compact",
    "depth_discontinuity",
    "depth_scale",
    "depth_weight",
    "depth_weight_scaled",
    "EpipolarGeometry",
    "EpipolarSettings",
    "kernel_weight",
    "line_filter",
    "line_samples",
    "LineTextures",
    "march_screen_point",
    "prefilter_light_texture",
    "ray_enters_cone",
    "render_epipolar",
    "sample_distance",
    "sample_texture_bytes",
    "screen_point_in_light",
    "trim_to_cone",
]
