"""Non-linear epipolar rectification of a directional light's shadow map (Peters 2017 Sec. 5.1.1, App. A).

Prefiltered single scattering (Klehm 2014) needs a shadow map in which every camera view ray lies in
ONE row, runs along the columns from the camera outward, and has ONE constant depth. Peters 2017
builds it from spherical coordinates in light view space:

* light view space: origin at the camera position, z axis = the direction the light TRAVELS
  (CONVENTIONS.md), x/y any orthonormal completion (``to_light`` holds the three axes as rows);
* r = sqrt(x^2 + y^2), the distance of the light ray from the camera  -> COLUMN, u = r / r_max;
* phi = atan2(y, x), the azimuth, i.e. the epipolar slice              -> ROW, v in [0, 1];
* theta = atan2(r, z), the inclination of the direction from the camera; the stored DEPTH is the
  flipped inclination pi - theta, normalised over the guard-banded theta bounds:
  depth = (theta_hi - theta) / (theta_hi - theta_lo) in [0, 1], growing with shadow-map depth.

A view ray x_t = position + t d keeps phi and theta (hence row and depth) and has r = t sin(theta):
it runs along its row from u = 0 outward with a constant world step per column,
Delta = (r_max / cols) / sin(theta) (Klehm 2014 Sec. 3.2 with k(omega) = sin(theta)).

Bounds (Peters 2017 App. A) come from the four far-plane corners q_j in light view space (the near
plane is ignored, r_min = 0): r_max = max_j |q_j,xy|; phi from the pair of corners enclosing the
largest angle, or the full circle when the light direction or its flip lies inside the view
frustum; theta from the corners, the critical points on the far-plane edges and 0 / pi when the
light / flipped light direction lies inside the frustum. The theta interval is stretched by the
guard band (10 % of its length, half on each side) to avoid light leaking.

Texture conventions: texel (row j, column i) has its centre at (u, v) = ((i + 0.5) / cols,
(j + 0.5) / rows). A map is a float32 array of shape (rows, cols).

Filtering during resampling (Peters 2017 Sec. 5.2, Fig. 17): instead of one nearest depth per light ray,
:func:`resample_moment_shadow_map` takes a FILTERED (bilinear) sample of a Gaussian-filtered 4-moment
shadow map (:mod:`warpscatter.shadows.msm`), turns its first three moments into two depths with
Algorithm 2 (non-positive variance: the single depth b_1), converts both to rectified depth with
clamping and returns the sparse representation (z_1, z_2, w_2) per texel (:class:`SparseRectifiedDepth`,
D.5's "sparse rectified representation"); the prefilter stores w_1 B(z_1) + w_2 B(z_2) for any basis B.

Translucent casters (a :class:`~warpscatter.shadows.shadow_map.ShadowMap` with ``transmittance``): every shadow-map
texel is itself the two-depth distribution (1 - T) delta(nearest caster) + T delta(nearest opaque caster)
(:mod:`warpscatter.shadows.translucency`), so the resampling returns a :class:`SparseRectifiedDepth` with both depths
(nearest look-up), or with the texel's taps split into those two parts (``supersample``); the moment map of
``moments`` filtering blends them in itself (Peters 2017 Sec. 3.2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..fastmath import fast_atan2
from ..parallel import launch_rows
from ..scene.camera import normalize
from ..shadows import moments as mm
from ..shadows.msm import MomentShadowMap, MomentShadowParams, sample_bilinear4
from ..shadows.shadow_map import shadow_coords
from ..wpinit import default_device, module_options

module_options()

TWO_PI = 2.0 * math.pi
_INSIDE_TOL = 1e-9  # relative tolerance of the inclusive "direction inside the frustum" test


@wp.struct
class NonlinearRectParams:
    """A non-linear rectification as kernels see it (see :class:`NonlinearRectification`)."""

    origin: wp.vec3  # camera position (world), origin of light view space
    to_light: wp.mat33  # world -> light view rotation; rows = light-view x, y, z (z = light travel dir)
    r_max: float  # distance from the light axis through the camera covered by u = 1 (world units)
    phi_mid: float  # azimuth of v = 0.5 (radians)
    phi_span: float  # azimuth range covered by v in [0, 1] (radians; 2 pi for the full circle)
    theta_hi: float  # guarded upper inclination bound = rectified depth 0 (radians)
    theta_len: float  # guarded inclination range = rectified depth 1 - depth 0 (radians)
    rows: int  # epipolar slices
    cols: int  # texels along a view ray
    full_circle: int  # 1 when phi covers the full circle (rows wrap around)
    light_distance: float  # local light: camera-light distance D (world units); 0 for a directional light
    psi_lo: float  # local light: the angle at the light of u = 0 (radians); r_max is then the angle span of u in [0, 1]


# ---- kernel-side coordinate transforms ------------------------------------------------------------


@wp.func
def world_to_rectified(rect: NonlinearRectParams, x: wp.vec3) -> wp.vec3:
    """Rectified (u, v, depth) of world point x (Peters 2017 Sec. 5.1.1): u = r / r_max (column),
    v = normalised azimuth (row), depth = normalised flipped inclination (pi - theta)."""
    q = rect.to_light * (x - rect.origin)
    r = wp.sqrt(q[0] * q[0] + q[1] * q[1])
    d = fast_atan2(q[1], q[0]) - rect.phi_mid
    d = d - 2.0 * wp.pi * wp.floor((d + wp.pi) / (2.0 * wp.pi))  # wrap into [-pi, pi)
    theta = fast_atan2(r, q[2])
    u = r / rect.r_max
    if rect.light_distance > 0.0:  # local light: the angle at the light from the baseline (rectify_local)
        u = (fast_atan2(r, q[2] + rect.light_distance) - rect.psi_lo) / rect.r_max
    return wp.vec3(u, 0.5 + d / rect.phi_span, (rect.theta_hi - theta) / rect.theta_len)


@wp.func
def rectified_to_world(rect: NonlinearRectParams, c: wp.vec3) -> wp.vec3:
    """World point of rectified (u, v, depth); defined for inclinations strictly inside (0, pi)."""
    r = c[0] * rect.r_max
    phi = rect.phi_mid + (c[1] - 0.5) * rect.phi_span
    theta = rect.theta_hi - c[2] * rect.theta_len
    q = wp.vec3(r * wp.cos(phi), r * wp.sin(phi), r * wp.cos(theta) / wp.max(wp.sin(theta), 1.0e-12))
    return rect.origin + wp.transpose(rect.to_light) * q


@wp.func
def rectified_ray_depth(rect: NonlinearRectParams, direction: wp.vec3) -> float:
    """Constant rectified depth of the camera view ray with (unit or not) world direction ``direction``."""
    q = rect.to_light * direction
    theta = fast_atan2(wp.sqrt(q[0] * q[0] + q[1] * q[1]), q[2])
    return (rect.theta_hi - theta) / rect.theta_len


@wp.func
def light_ray_point(rect: NonlinearRectParams, u: float, v: float) -> wp.vec3:
    """World point of the light ray through rectified (u, v) closest to the camera (light-view z = 0)."""
    r = u * rect.r_max
    phi = rect.phi_mid + (v - 0.5) * rect.phi_span
    return rect.origin + wp.transpose(rect.to_light) * wp.vec3(r * wp.cos(phi), r * wp.sin(phi), 0.0)


@wp.func
def texel_light_ray(rect: NonlinearRectParams, i: int, j: int):
    """Column coordinate u of texel (column i, row j)'s centre and the point of its light ray closest to the camera
    (:func:`light_ray_point`)."""
    u = (float(i) + 0.5) / float(rect.cols)
    v = (float(j) + 0.5) / float(rect.rows)
    return u, light_ray_point(rect, u, v)


# ---- resampling kernel ----------------------------------------------------------------------------------


#: Signed moment-map depths at or above 1 - EMPTY_DEPTH_TOLERANCE are the cleared far plane (no caster, Sec. 3.2).
EMPTY_DEPTH_TOLERANCE = wp.constant(1.0e-3)


@wp.func
def sentinel_gap_depth(z: float, d: float, caster_limit: float, d_limit: float) -> float:
    """Light-space depth of an Algorithm-2 depth z (linear depth d) that may lie in the gap between the farthest caster
    (signed ``caster_limit``, linear ``d_limit``) and the cleared far plane: below the limit d itself; in the gap the
    distance beyond the limit is stretched by 1 / (1 - s), s = the position in the gap, so that the depth goes to
    infinity (no blocker in the frustum) as z reaches the empty threshold 1 - EMPTY_DEPTH_TOLERANCE.

    No caster lies in the gap: a depth there is the empty texels' +1 pulled down by a mixture of more than two depths
    (Algorithm 2 fits two). Read as a blocker at the map's far plane, it shadowed everything behind that plane along
    the light (with a map fitted to the casters, the camera's side of the medium), and the hard threshold switched a
    whole texel from shadowed to lit between neighbouring epipolar slices: a seam along one epipolar line.
    """
    z_empty = 1.0 - EMPTY_DEPTH_TOLERANCE
    if z <= caster_limit:
        return d
    keep = wp.max((z_empty - z) / wp.max(z_empty - caster_limit, 1.0e-30), 1.0e-30)  # 1 - s
    return d_limit + (d - d_limit) / keep


@wp.func
def rectified_blocker_depth(rect: NonlinearRectParams, u: float, z_b: float) -> float:
    """Rectified depth of a blocker at light-view distance z_b (along the light, from the light ray's point
    closest to the camera) on the light ray of column coordinate u, clamped to [0, 1] (Klehm 2014 Sec. 4.1:
    blockers in front of the frustum -> 0, behind it -> 1; both cast the same shadows into the frustum)."""
    theta_b = fast_atan2(u * rect.r_max, z_b)
    return wp.clamp((rect.theta_hi - theta_b) / rect.theta_len, 0.0, 1.0)


@wp.func
def nearest_map_texel(texels: wp.array2d(dtype=wp.float32), c: wp.vec4):
    """(inside the map, column, row) of the shadow-map texel nearest to clip coordinates c (row 0 = NDC y = +1)."""
    sx = (0.5 * c[0] + 0.5) * float(texels.shape[1])
    sy = (0.5 - 0.5 * c[1]) * float(texels.shape[0])
    inside = sx >= 0.0 and sy >= 0.0 and sx < float(texels.shape[1]) and sy < float(texels.shape[0])
    x = int(0)
    y = int(0)
    if inside:
        x = int(sx)
        y = int(sy)
    return inside, x, y


@wp.func
def stored_blocker_depth(
    rect: NonlinearRectParams,
    shadow_depth: wp.array2d(dtype=wp.float32),
    c: wp.vec4,  # clip coordinates of the light ray's point p0 (orthographic: w = 1)
    p0_depth: float,  # stored depth of p0
    depth_per_unit: float,
    empty_depth: float,
    u: float,  # column coordinate of the light ray
) -> float:
    """Rectified blocker depth of the light ray of column coordinate u through the point p0 at clip coordinates c:
    the nearest shadow-map texel's caster placed on the same light ray (1: no caster, or off the map)."""
    inside, x, y = nearest_map_texel(shadow_depth, c)
    result = float(1.0)  # no caster: the blocker lies at the far end
    if inside:
        stored = shadow_depth[y, x]
        if wp.isfinite(stored) and stored < empty_depth:
            # blocker on this light ray: light-view z (distance along the light from p0)
            z_b = (stored - p0_depth) / depth_per_unit
            result = rectified_blocker_depth(rect, u, z_b)
    return result


@wp.func
def stored_transmittance(transmittance: wp.array2d(dtype=wp.float32), c: wp.vec4) -> float:
    """Transmittance of the translucent casters in the nearest shadow-map texel of clip coordinates c (the texel of
    :func:`stored_blocker_depth`; 1 off the map)."""
    inside, x, y = nearest_map_texel(transmittance, c)
    if inside:
        return transmittance[y, x]
    return 1.0


@wp.kernel
def resample_kernel(
    rect: NonlinearRectParams,
    shadow_depth: wp.array2d(dtype=wp.float32),  # (H, W) stored light-space depth, row 0 = NDC y = +1
    world_to_clip: wp.mat44,  # orthographic light world -> clip (w = 1)
    depth_row: wp.vec4,  # stored depth of world point p = dot(depth_row, (p, 1))
    depth_per_unit: float,  # d(stored depth) / d(distance along the light direction) > 0
    empty_depth: float,  # stored values >= this are empty texels (no caster)
    out: wp.array2d(dtype=wp.float32),  # (rows, cols) rectified blocker depth in [0, 1]
    offset: int,
):
    j, i = wp.tid()
    j += offset
    # the texel is a light ray; its point closest to the camera finds the shadow-map texel
    u, p0 = texel_light_ray(rect, i, j)
    p0h = wp.vec4(p0[0], p0[1], p0[2], 1.0)
    out[j, i] = stored_blocker_depth(rect, shadow_depth, world_to_clip * p0h, wp.dot(depth_row, p0h), depth_per_unit,
                                     empty_depth, u)


@wp.struct
class TranslucentLayer:
    """A shadow map's translucent layer as the resampling kernels read it (``translucent`` 0: 1x1 placeholders)."""

    translucent: int
    opaque_depth: wp.array2d(dtype=wp.float32)  # (H, W) stored depth of the nearest opaque caster
    transmittance: wp.array2d(dtype=wp.float32)  # (H, W) transmittance of the translucent casters in front of it


@wp.kernel
def resample_translucent_kernel(
    rect: NonlinearRectParams,
    shadow_depth: wp.array2d(dtype=wp.float32),  # as resample_kernel: the nearest caster of any kind
    layer: TranslucentLayer,
    world_to_clip: wp.mat44,
    depth_row: wp.vec4,
    depth_per_unit: float,
    empty_depth: float,
    out_z1: wp.array2d(dtype=wp.float32),  # (rows, cols) the nearest caster's rectified depth
    out_z2: wp.array2d(dtype=wp.float32),  # (rows, cols) the nearest opaque caster's
    out_w2: wp.array2d(dtype=wp.float32),  # (rows, cols) the light passing the translucent casters in front of it
    offset: int,
):
    # resample_kernel's nearest look-up of both depths of the texel's two-depth distribution (module doc)
    j, i = wp.tid()
    j += offset
    u, p0 = texel_light_ray(rect, i, j)
    p0h = wp.vec4(p0[0], p0[1], p0[2], 1.0)
    c = world_to_clip * p0h
    d0 = wp.dot(depth_row, p0h)
    out_z1[j, i] = stored_blocker_depth(rect, shadow_depth, c, d0, depth_per_unit, empty_depth, u)
    out_z2[j, i] = stored_blocker_depth(rect, layer.opaque_depth, c, d0, depth_per_unit, empty_depth, u)
    out_w2[j, i] = stored_transmittance(layer.transmittance, c)


#: Most radial sub-samples per rectified texel of the supersampled resampling (``resample_filter: supersample``,
#: :func:`resample_shadow_map`).
MAX_RADIAL_SAMPLES = 4


@wp.func
def bilinear_footprint(texels: wp.array2d(dtype=wp.float32), c: wp.vec4):
    """The 2 x 2 footprint of clip coordinates c in a map (row 0 = NDC y = +1): its first texel (x, y), which may
    lie off the map, and the bilinear weights (ax, ay) of the next column and row: c's fractional offsets from that
    texel's centre. (Weights ramping over half a texel narrowed a grey fringe beside a low sun while the map was
    fitted to the whole ground; with :mod:`~warpscatter.shadows.unseen_planes` the finer map removes it, and its
    radial streaks want the whole texel's blur: :data:`~warpscatter.shadows.shadow_map.PCF_RAMP_TEXELS`.)"""
    fx = (0.5 * c[0] + 0.5) * float(texels.shape[1]) - 0.5
    fy = (0.5 - 0.5 * c[1]) * float(texels.shape[0]) - 0.5
    x = int(wp.floor(fx))
    y = int(wp.floor(fy))
    return x, y, fx - float(x), fy - float(y)


@wp.func
def footprint_tap(x: int, y: int, ax: float, ay: float, t: int):
    """Texel and bilinear weights (wx, wy) of tap t (0..3, x fastest) of the footprint at texel (x, y) with
    offsets (ax, ay) (:func:`bilinear_footprint`)."""
    wx = ax
    wy = ay
    if t % 2 == 0:
        wx = 1.0 - ax
    else:
        x += 1
    if t < 2:
        wy = 1.0 - ay
    else:
        y += 1
    return x, y, wx, wy


@wp.func
def bilinear_tap(texels: wp.array2d(dtype=wp.float32), c: wp.vec4, t: int):
    """Texel (x, y) and bilinear weights (wx, wy) of tap t (0..3) of the footprint of clip coordinates c in a map
    (row 0 = NDC y = +1); the texel may lie off the map."""
    x, y, ax, ay = bilinear_footprint(texels, c)
    return footprint_tap(x, y, ax, ay, t)


@wp.func
def tap_caster(shadow_depth: wp.array2d(dtype=wp.float32), x: int, y: int, d: float, depth_per_unit: float,
               empty_depth: float):
    """The caster of shadow-map texel (x, y) seen from a light-ray point at stored depth d: (its distance z_b along
    the light from that point, 1 if the texel holds a caster else 0); (0, 0) for empty texels and off the map."""
    if x >= 0 and y >= 0 and x < shadow_depth.shape[1] and y < shadow_depth.shape[0]:
        stored = shadow_depth[y, x]
        if wp.isfinite(stored) and stored < empty_depth:
            return (stored - d) / depth_per_unit, float(1.0)
    return float(0.0), float(0.0)


@wp.func
def radial_tap(shadow_depth: wp.array2d(dtype=wp.float32), c0: wp.vec4, ca: wp.vec4, d0: float, da: float,
               depth_per_unit: float, empty_depth: float, u: float, t: int, weight: float):
    """Tap t (0..3) of the bilinear footprint at column coordinate u of :func:`resample_radial_kernel`'s light rays:
    (its caster's distance z_b along the light from the ray's point, its bilinear weight times ``weight``, 1 if the
    texel holds a caster else 0, the texel's column and row)."""
    x, y, wx, wy = bilinear_tap(shadow_depth, c0 + ca * u, t)
    z_b, caster = tap_caster(shadow_depth, x, y, d0 + da * u, depth_per_unit, empty_depth)
    return z_b, weight * wx * wy, caster, x, y


@wp.func
def translucent_tap(layer: TranslucentLayer, x: int, y: int, d: float, depth_per_unit: float, empty_depth: float):
    """The opaque part of tap (x, y) of a map with translucent casters (:func:`radial_tap` gave the nearest caster):
    (the light share T reaching the nearest opaque caster, that caster's distance z_b along the light from the tap's
    light-ray point at stored depth d, 1 if there is one else 0); T = 0 without translucency or off the map."""
    if layer.translucent == 0 or x < 0 or y < 0 or x >= layer.transmittance.shape[1] or \
            y >= layer.transmittance.shape[0]:
        return float(0.0), float(0.0), float(0.0)
    stored = layer.opaque_depth[y, x]
    if wp.isfinite(stored) and stored < empty_depth:
        return layer.transmittance[y, x], (stored - d) / depth_per_unit, float(1.0)
    return layer.transmittance[y, x], float(0.0), float(0.0)


# A supersampled texel condenses its taps to two depths in two passes over the same taps: the first finds the casters'
# depth range [lo, hi] and the caster and empty weights (:func:`tap_range`), the second splits the casters at the middle
# of that range, each part's weighted mean becoming one depth (:func:`tap_split`). Opaque maps keep their taps for the
# second pass (at most RADIAL_TAPS, at indices fixed when the kernel compiles, so they stay in registers;
# :func:`keep_tap`, :func:`kept_taps_parts`) and skip it where there are empty taps or the range is a point (the casters
# are then one part, the first pass's caster sum): about 1.8x faster on two threads at 1024^2 than re-reading the taps,
# bit-identical (:func:`radial_opaque_texel`; resample_radial_kernel picks it per map). On the CPU a thread takes a
# whole row (radial_span): a row's light-ray setup (one sin/cos, two matrix products) done once instead of per texel
# halved the opaque maps' time again (1024^2, two cores, 46 -> 23 ms), bit-identical. With translucent casters a tap is
# one part or two (:func:`tap_part`) and the second pass recomputes them (keeping up to 32 parts at run-time indices was
# a third slower).


@wp.func
def tap_parts(passed: float) -> int:
    """Parts of a tap: its nearest caster, and where translucent casters pass light (T = ``passed`` > 0) its nearest
    opaque caster too."""
    return 1 + int(passed > 0.0)


@wp.func
def tap_part(z_n: float, caster_n: float, z_o: float, caster_o: float, w_tap: float, passed: float, part: int):
    """Part ``part`` of a tap of weight ``w_tap``: 0 its nearest caster (depth z_n, 1 in caster_n if there is one)
    with weight w_tap (1 - T), 1 its nearest opaque caster (z_o, caster_o) with weight w_tap T (T = ``passed``).
    Returns (depth, weight, 1 if a caster else 0)."""
    if part == 1:
        return z_o, w_tap * passed, caster_o
    return z_n, w_tap * (1.0 - passed), caster_n


@wp.func
def empty_tap_range():
    """The first pass's start, before any tap: (lo, hi, w_caster, w_empty) of :func:`tap_range`."""
    return float(1.0e30), float(-1.0e30), float(0.0), float(0.0)


@wp.func
def tap_range(lo: float, hi: float, w_caster: float, w_empty: float, z_b: float, w: float, caster: float):
    """First pass: a tap part (depth z_b, weight w) extends the casters' depth range [lo, hi] (parts of weight 0
    excepted) and their weight w_caster, or adds to the empty weight w_empty. Returns (lo, hi, w_caster, w_empty)."""
    if caster > 0.0:
        if w > 0.0:
            return wp.min(lo, z_b), wp.max(hi, z_b), w_caster + w, w_empty
        return lo, hi, w_caster + w, w_empty
    return lo, hi, w_caster, w_empty + w


@wp.func
def tap_split(s1: float, w1: float, s2: float, w2: float, two: bool, mid: float, z_b: float, w: float,
              caster: float):
    """Second pass: a caster tap part (depth z_b, weight w) adds to the farther part's weighted sums (s2, w2) when
    the casters split in two (``two``) and it lies beyond ``mid``, else to the nearer part's (s1, w1); an empty part
    adds nothing. Returns (s1, w1, s2, w2)."""
    if caster > 0.0:
        if two and z_b > mid:
            return s1, w1, s2 + w * z_b, w2 + w
        return s1 + w * z_b, w1 + w, s2, w2
    return s1, w1, s2, w2


@wp.func
def split_point(lo: float, hi: float, w_empty: float):
    """Where the second pass splits a texel's casters: (whether they split in two, the middle of their range). They
    split when no tap is empty and the range is not a point; with empty taps the casters form one depth and the empty
    taps the other."""
    return w_empty <= 0.0 and hi > lo, 0.5 * (lo + hi)


@wp.func
def part_mean(s: float, w: float) -> float:
    """The weighted mean depth of a part (0 when it has no weight)."""
    if w > 0.0:
        return s / w
    return 0.0


@wp.func
def radial_texel_depths(rect: NonlinearRectParams, i: int, w_caster: float, w_empty: float, s1: float, w1: float,
                        s2: float, w2: float):
    """A supersampled texel of column i from its two parts' sums (s1, w1), (s2, w2) (:func:`tap_split`) and its
    caster and empty weights: (the nearer rectified depth z1, the farther z2, the weight of z2), each part's mean
    z_b placed at the texel's centre column. One caster part and empty taps give the casters' depth and the empty
    far end (1) with the empty weight; no caster gives (1, 1, 0)."""
    u_mid = (float(i) + 0.5) / float(rect.cols)
    z1 = float(1.0)
    z2 = float(1.0)
    share = float(0.0)
    if w_caster > 0.0:
        if w1 > 0.0:
            z1 = rectified_blocker_depth(rect, u_mid, part_mean(s1, w1))
        if w2 > 0.0:  # two caster depths
            z2 = rectified_blocker_depth(rect, u_mid, part_mean(s2, w2))
            share = w2 / (w1 + w2)
        else:  # the casters' depth, and the empty taps at depth 1
            share = w_empty / (w_caster + w_empty)
            if share <= 0.0:
                z2 = z1
    return z1, z2, share


#: Taps one supersampled texel of an opaque map keeps for its second pass: four per radial sub-sample.
RADIAL_TAPS = 4 * MAX_RADIAL_SAMPLES
radial_taps = wp.types.vector(length=RADIAL_TAPS, dtype=wp.float32)


@wp.func
def radial_row(rect: NonlinearRectParams, world_to_clip: wp.mat44, depth_row: wp.vec4, j: int):
    """Row j's light-ray points p(u) = origin + u a in a directional map (clip coordinates c0 + u ca, stored depth
    d0 + u da): (c0, ca, d0, da); the point is affine in u, so one sin/cos per row."""
    v = (float(j) + 0.5) / float(rect.rows)
    a = light_ray_point(rect, 1.0, v) - rect.origin
    o = wp.vec4(rect.origin[0], rect.origin[1], rect.origin[2], 1.0)
    av = wp.vec4(a[0], a[1], a[2], 0.0)
    return world_to_clip * o, world_to_clip * av, wp.dot(depth_row, o), wp.dot(depth_row, av)


@wp.func
def keep_tap(lo: float, hi: float, w_caster: float, w_empty: float, s_caster: float, z_b: float, w: float,
             caster: float):
    """First pass over a tap (depth z_b, weight w, 1 in ``caster`` if it holds one) of an opaque map whose taps
    are kept: :func:`tap_range`, and the casters' weighted depth sum. Returns (lo, hi, w_caster, w_empty, s_caster,
    the weight to keep: w, or -1 for an empty tap)."""
    lo, hi, w_caster, w_empty = tap_range(lo, hi, w_caster, w_empty, z_b, w, caster)
    if caster > 0.0:
        return lo, hi, w_caster, w_empty, s_caster + w * z_b, w
    return lo, hi, w_caster, w_empty, s_caster, float(-1.0)


@wp.func
def kept_taps_parts(z: radial_taps, w: radial_taps, count: int, lo: float, hi: float, w_caster: float,
                    w_empty: float, s_caster: float):
    """The two parts (s1, w1, s2, w2) of :func:`tap_split` from the first ``count`` kept taps (depth in ``z``,
    weight in ``w``, < 0: empty) and the first pass's range, weights and caster sum (:func:`keep_tap`): the
    casters split at the middle of their range when :func:`split_point` says so, else they are one part."""
    two, mid = split_point(lo, hi, w_empty)
    if w_caster <= 0.0 or not two:
        return s_caster, w_caster, float(0.0), float(0.0)
    s1 = float(0.0)
    w1 = float(0.0)
    s2 = float(0.0)
    w2 = float(0.0)
    for n in range(wp.static(RADIAL_TAPS)):
        if n < count:
            if w[n] >= 0.0:
                s1, w1, s2, w2 = tap_split(s1, w1, s2, w2, True, mid, z[n], w[n], 1.0)
    return s1, w1, s2, w2


@wp.func
def radial_opaque_texel(rect: NonlinearRectParams, shadow_depth: wp.array2d(dtype=wp.float32), c0: wp.vec4,
                        ca: wp.vec4, d0: float, da: float, depth_per_unit: float, empty_depth: float, samples: int,
                        i: int):
    """Texel of column i of a row (its light-ray points from :func:`radial_row`) of an opaque map: the
    supersampled two-depth mix (z1, z2, share) of :func:`radial_texel_depths`. One pass reads the taps, keeps them
    (static indices: registers) and sums the casters; the split pass runs over the kept taps."""
    inv = 1.0 / float(samples)
    lo, hi, w_caster, w_empty = empty_tap_range()
    s_caster = float(0.0)
    z_kept = radial_taps()
    w_kept = radial_taps()
    for k in range(wp.static(MAX_RADIAL_SAMPLES)):
        if k < samples:
            u = (float(i) + (float(k) + 0.5) * inv) / float(rect.cols)
            x, y, ax, ay = bilinear_footprint(shadow_depth, c0 + ca * u)
            d = d0 + da * u
            for t in range(4):
                xt, yt, wx, wy = footprint_tap(x, y, ax, ay, wp.static(t))
                z_b, caster = tap_caster(shadow_depth, xt, yt, d, depth_per_unit, empty_depth)
                lo, hi, w_caster, w_empty, s_caster, kept = keep_tap(lo, hi, w_caster, w_empty, s_caster, z_b,
                                                                     inv * wx * wy, caster)
                z_kept[wp.static(4 * k + t)] = z_b
                w_kept[wp.static(4 * k + t)] = kept
    s1, w1, s2, w2 = kept_taps_parts(z_kept, w_kept, 4 * samples, lo, hi, w_caster, w_empty, s_caster)
    return radial_texel_depths(rect, i, w_caster, w_empty, s1, w1, s2, w2)


@wp.func
def radial_translucent_texel(rect: NonlinearRectParams, shadow_depth: wp.array2d(dtype=wp.float32),
                             layer: TranslucentLayer, c0: wp.vec4, ca: wp.vec4, d0: float, da: float,
                             depth_per_unit: float, empty_depth: float, samples: int, i: int):
    """Texel of column i of a row (its light-ray points from :func:`radial_row`) of a map that may hold translucent
    casters: the supersampled two-depth mix (z1, z2, share) of :func:`radial_texel_depths`, in two passes over the
    taps (:func:`tap_range`, :func:`tap_split`); each tap is one part or two (:func:`tap_part`)."""
    inv = 1.0 / float(samples)
    lo, hi, w_caster, w_empty = empty_tap_range()
    s1 = float(0.0)
    w1 = float(0.0)
    s2 = float(0.0)
    w2 = float(0.0)
    two = bool(False)
    mid = float(0.0)
    for p in range(2):
        if p == 1:
            if w_caster <= 0.0:
                break
            two, mid = split_point(lo, hi, w_empty)
        for k in range(samples):
            u = (float(i) + (float(k) + 0.5) * inv) / float(rect.cols)
            for t in range(4):
                z_n, w_tap, caster_n, x, y = radial_tap(shadow_depth, c0, ca, d0, da, depth_per_unit, empty_depth,
                                                        u, t, inv)
                passed, z_o, caster_o = translucent_tap(layer, x, y, d0 + da * u, depth_per_unit, empty_depth)
                for part in range(tap_parts(passed)):
                    z_b, w, caster = tap_part(z_n, caster_n, z_o, caster_o, w_tap, passed, part)
                    if p == 0:
                        lo, hi, w_caster, w_empty = tap_range(lo, hi, w_caster, w_empty, z_b, w, caster)
                    else:
                        s1, w1, s2, w2 = tap_split(s1, w1, s2, w2, two, mid, z_b, w, caster)
    return radial_texel_depths(rect, i, w_caster, w_empty, s1, w1, s2, w2)


@wp.kernel
def resample_radial_kernel(
    rect: NonlinearRectParams,
    shadow_depth: wp.array2d(dtype=wp.float32),  # as resample_kernel
    layer: TranslucentLayer,
    world_to_clip: wp.mat44,
    depth_row: wp.vec4,
    depth_per_unit: float,
    empty_depth: float,
    samples: int,  # sub-samples along the texel's column extent, 1..MAX_RADIAL_SAMPLES
    span: int,  # texels of a row per thread (radial_span): launch dim (rows, ceil(cols / span))
    out_z1: wp.array2d(dtype=wp.float32),  # (rows, cols) the nearer depth of the texel's two-depth mix
    out_z2: wp.array2d(dtype=wp.float32),  # (rows, cols) the farther depth
    out_w2: wp.array2d(dtype=wp.float32),  # (rows, cols) the weight of z2
    offset: int,
):
    # ``samples`` points at equal steps over the texel's radial extent [i, i + 1) / cols, each reading its four
    # nearest shadow-map texels with bilinear weights (bilinear_footprint). Each tap's
    # caster lies at z_b along the light from the sample's light-ray point (the rectified depth grows with z_b). The
    # caster taps split in two at the middle of their z_b range, each part's weighted mean z_b becoming one rectified
    # depth at the texel's centre column; with empty taps (no caster: depth 1) the casters form one depth and the
    # empty taps the other. The light-ray point is affine in u (p0 = origin + u a), so are its map coordinates and
    # depth: a thread takes ``span`` texels of a row and sets them up once (one sin/cos, two matrix products), then at
    # most two atan2 per texel. With translucent casters a tap is two parts, its nearest caster with weight (1 - T)
    # and its nearest opaque caster (or the empty far end) with weight T.
    j, g = wp.tid()
    j += offset
    c0, ca, d0, da = radial_row(rect, world_to_clip, depth_row, j)
    for i in range(g * span, wp.min(g * span + span, rect.cols)):
        z1 = float(0.0)
        z2 = float(0.0)
        share = float(0.0)
        if layer.translucent == 0:  # an opaque map keeps its taps for the split pass (bit-identical, faster)
            z1, z2, share = radial_opaque_texel(rect, shadow_depth, c0, ca, d0, da, depth_per_unit, empty_depth,
                                                samples, i)
        else:
            z1, z2, share = radial_translucent_texel(rect, shadow_depth, layer, c0, ca, d0, da, depth_per_unit,
                                                     empty_depth, samples, i)
        out_z1[j, i] = z1
        out_z2[j, i] = z2
        out_w2[j, i] = share


@wp.kernel
def resample_moments_kernel(
    rect: NonlinearRectParams,
    mp: MomentShadowParams,  # geometry of the filtered moment map (the light's shadow-map view)
    texels: wp.array3d(dtype=wp.vec4),  # (C, H, W) filtered stored moments; channel 0 is used
    out_z1: wp.array2d(dtype=wp.float32),  # (rows, cols) rectified depth of the first depth in [0, 1]
    out_z2: wp.array2d(dtype=wp.float32),  # (rows, cols) rectified depth of the second depth in [0, 1]
    out_w2: wp.array2d(dtype=wp.float32),  # (rows, cols) weight w_2 of the second depth in [0, 1]
    caster_limit: float,  # signed depth of the farthest caster (<= 1 - EMPTY_DEPTH_TOLERANCE), sentinel_gap_depth
    offset: int,
):
    # Peters 2017 Sec. 5.2 / D.5: filtered moment sample -> Algorithm 2 -> two rectified depths
    j, i = wp.tid()
    j += offset
    u, p0 = texel_light_ray(rect, i, j)
    c = shadow_coords(mp.sm, p0)  # (u_s, v_s, linear light depth of p0)
    z1 = float(1.0)  # no caster: the blocker lies at the far end
    z2 = float(1.0)
    w2 = float(0.0)
    if c[0] >= 0.0 and c[1] >= 0.0 and c[0] < 1.0 and c[1] < 1.0:
        b = mm.load_moments4(sample_bilinear4(texels, 0, c[0], c[1]), mp.storage)
        depths, weights = mm.two_depth_distribution(wp.vec3(b[0], b[1], b[2]))
        w2 = weights[1]
        for k in range(2):
            r = float(1.0)
            z = depths[k]
            if z < 1.0 - EMPTY_DEPTH_TOLERANCE:
                d = (z - mp.depth_offset) / mp.depth_scale  # linear light-space depth of the blocker
                d = sentinel_gap_depth(z, d, caster_limit, (caster_limit - mp.depth_offset) / mp.depth_scale)
                r = rectified_blocker_depth(rect, u, d - c[2])
            if k == 0:
                z1 = r
            else:
                z2 = r
    out_z1[j, i] = z1
    out_z2[j, i] = z2
    out_w2[j, i] = w2


# ---- host side: bounds ----------------------------------------------------------------------------------


def _light_basis(light_direction) -> np.ndarray:
    """Rotation whose rows are light-view x, y, z; z = the light travel direction (right-handed)."""
    try:
        ez = normalize(light_direction)
    except ValueError as exc:
        raise ValueError(f"light_direction must be a finite non-zero 3-vector: {exc}") from None
    helper = np.eye(3)[int(np.argmin(np.abs(ez)))]
    ex = helper - helper.dot(ez) * ez
    ex /= np.linalg.norm(ex)
    ey = np.cross(ez, ex)
    return np.stack([ex, ey, ez])


def direction_in_frustum(camera, direction) -> bool:
    """True when the (infinite) view frustum of ``camera`` contains the ray from its position along ``direction``."""
    right, up, fwd = camera.basis
    d = np.asarray(direction, float)
    cz = d @ fwd
    if cz <= 0.0:
        return False
    t = math.tan(math.radians(camera.fov_y) / 2.0)
    tol = 1.0 + _INSIDE_TOL
    return abs(d @ right) <= cz * t * camera.aspect * tol and abs(d @ up) <= cz * t * tol


def _inclination(q: np.ndarray) -> np.ndarray:
    """theta = arccos(z / |q|) of light-view points, computed as atan2(r, z)."""
    return np.arctan2(np.hypot(q[..., 0], q[..., 1]), q[..., 2])


def _edge_critical_inclinations(quad: np.ndarray) -> list[float]:
    """Inclinations at the critical points on the far-plane edges (Peters 2017 App. A)."""
    out = []
    for a in range(4):
        qj, qk = quad[a], quad[(a + 1) % 4]
        b = qk - qj
        den = b[2] * qj.dot(b) - qj[2] * b.dot(b)
        if abs(den) <= 1e-300:
            continue
        t = (qj[2] * qj.dot(b) - b[2] * qj.dot(qj)) / den
        if 0.0 <= t <= 1.0:
            out.append(float(_inclination(qj + t * b)))
    return out


def _azimuth_bounds(xy: np.ndarray) -> tuple[float, float]:
    """(phi_min in [0, 2 pi), span) of the cone spanned by 2D vectors xy: the pair enclosing the largest angle."""
    best, pair = -1.0, (0, 1)
    for a in range(len(xy)):
        for b in range(a + 1, len(xy)):
            cross = xy[a, 0] * xy[b, 1] - xy[a, 1] * xy[b, 0]
            ang = math.atan2(abs(cross), float(xy[a] @ xy[b]))
            if ang > best:
                best, pair = ang, (a, b)
    a, b = pair
    if xy[a, 0] * xy[b, 1] - xy[a, 1] * xy[b, 0] < 0.0:
        a, b = b, a  # counter-clockwise from a to b
    return math.atan2(xy[a, 1], xy[a, 0]) % TWO_PI, best


@dataclass(frozen=True)
class NonlinearRectification:
    """Non-linear rectification of a directional light for one camera (Peters 2017 Sec. 5.1.1, App. A).

    Attributes:
        position: camera position (world), the origin of light view space.
        to_light: (3, 3) world -> light-view rotation, rows = x, y, z axes; z = light travel direction.
        far_corners: (4, 3) far-plane corners in light view space, in cyclic order.
        r_max: largest distance of the frustum from the light axis through the camera (world units).
        phi_min, phi_span: azimuth range [phi_min, phi_min + phi_span] mapped to v in [0, 1] (radians).
        full_circle: True when phi covers the full circle (light or flipped light direction inside the view).
        light_in_view / flipped_light_in_view: the light direction / its flip lies inside the view frustum.
        theta_min, theta_max: tight inclination bounds of the frustum (radians).
        guard_band: relative stretch of the theta interval (0.1 = 10 %, half on each side).
        rows, cols: resolution of the rectified map (epipolar slices x texels along a view ray).
        view_radius: r_max of the view frustum alone (before a ``radius`` cap).
    """

    position: np.ndarray
    to_light: np.ndarray
    far_corners: np.ndarray
    r_max: float
    phi_min: float
    phi_span: float
    full_circle: bool
    light_in_view: bool
    flipped_light_in_view: bool
    theta_min: float
    theta_max: float
    guard_band: float
    rows: int
    cols: int
    view_radius: float = 0.0
    light_distance: float = 0.0
    psi_lo: float = 0.0

    @property
    def local(self) -> bool:
        """True for a local (spot) light's rectification (:mod:`.rectify_local`): columns are angles at the light."""
        return self.light_distance > 0.0

    @property
    def column_scale(self) -> float:
        """View radius / r_max: how many times finer the columns are than those of a map reaching the view's far
        corners (1 unless ``radius`` capped it)."""
        return self.view_radius / self.r_max if self.view_radius > 0.0 else 1.0

    @classmethod
    def from_camera(cls, camera, light_direction, guard_band: float = 0.1, rows: int = 1024,
                    cols: int = 1024, radius: float | None = None) -> "NonlinearRectification":
        """Tight bounds of the rectified coordinates for ``camera`` and a directional light (Peters 2017 App. A).

        Args:
            camera: a :class:`~warpscatter.scene.camera.Camera`.
            light_direction: direction the light travels (any length > 0).
            guard_band: relative stretch of the theta interval (Peters 2017 uses 0.1), >= 0.
            rows: epipolar slices of the rectified map (>= 2).
            cols: texels along each view ray (>= 2).
            radius: caps r_max (world units, > 0): the map then covers light rays up to this distance from the
                camera's light axis only, and the look-ups count a view ray's texels beyond it as lit
                (:func:`caster_radius`: where the last caster is).

        Raises:
            ValueError: on a zero/non-finite light direction, a negative guard band or a map below 2x2.
        """
        if not (np.isfinite(guard_band) and guard_band >= 0.0):
            raise ValueError(f"guard_band must be finite and >= 0, got {guard_band}")
        for name, val in (("rows", rows), ("cols", cols)):
            if int(val) != val or val < 2:
                raise ValueError(f"{name} must be an integer >= 2, got {val}")
        to_light = _light_basis(light_direction)
        ez = to_light[2]
        position = np.asarray(camera.position, float)
        far = camera.frustum_corners()[4:][[0, 1, 3, 2]]  # cyclic order around the far plane
        quad = (far - position) @ to_light.T

        # ---- r: distance to the light axis through the camera (r_min = 0, near plane ignored) ----
        r_max = float(np.max(np.hypot(quad[:, 0], quad[:, 1])))
        r_max = max(r_max, 1e-12 * float(np.max(np.linalg.norm(quad, axis=1))))
        view_radius = r_max
        if radius is not None:
            if not (np.isfinite(radius) and radius > 0.0):
                raise ValueError(f"radius must be finite and > 0, got {radius}")
            r_max = min(r_max, float(radius))

        # ---- phi: full circle when the (flipped) light direction lies inside the frustum ----
        light_in = direction_in_frustum(camera, ez)
        flipped_in = direction_in_frustum(camera, -ez)
        if light_in or flipped_in:
            phi_min, phi_span = 0.0, TWO_PI
        else:
            phi_min, phi_span = _azimuth_bounds(quad[:, :2])
            phi_span = max(phi_span, 1e-9)

        # ---- theta: corners, edge critical points, and the interior when the axis is inside ----
        thetas = list(_inclination(quad)) + _edge_critical_inclinations(quad)
        if light_in:
            thetas.append(0.0)
        if flipped_in:
            thetas.append(math.pi)
        return cls(position=position, to_light=to_light, far_corners=quad, r_max=r_max, phi_min=float(phi_min),
                   phi_span=float(phi_span), full_circle=bool(light_in or flipped_in), light_in_view=bool(light_in),
                   flipped_light_in_view=bool(flipped_in), theta_min=float(min(thetas)),
                   theta_max=float(max(thetas)), guard_band=float(guard_band), rows=int(rows), cols=int(cols),
                   view_radius=float(view_radius))

    # ---- derived bounds ------------------------------------------------------------------------------
    @property
    def light_direction(self) -> np.ndarray:
        """Unit direction the light travels (light-view z axis)."""
        return self.to_light[2]

    @property
    def phi_mid(self) -> float:
        return self.phi_min + 0.5 * self.phi_span

    @property
    def theta_lo(self) -> float:
        """Guarded lower inclination bound (rectified depth 1)."""
        return self.theta_min - 0.5 * self.guard_band * (self.theta_max - self.theta_min)

    @property
    def theta_hi(self) -> float:
        """Guarded upper inclination bound (rectified depth 0)."""
        return self.theta_max + 0.5 * self.guard_band * (self.theta_max - self.theta_min)

    @property
    def theta_len(self) -> float:
        return max(self.theta_hi - self.theta_lo, 1e-9)

    @property
    def delta_perp(self) -> float:
        """World width of one column for a ray perpendicular to the light (Klehm 2014 Delta-perp)."""
        return self.r_max / self.cols

    def params(self) -> NonlinearRectParams:
        """Kernel-side parameters (:class:`NonlinearRectParams`)."""
        p = NonlinearRectParams()
        p.origin = wp.vec3(*self.position)
        p.to_light = wp.mat33(*self.to_light.ravel())
        p.r_max = float(self.r_max)
        p.phi_mid = float(self.phi_mid)
        p.phi_span = float(self.phi_span)
        p.theta_hi = float(self.theta_hi)
        p.theta_len = float(self.theta_len)
        p.rows = int(self.rows)
        p.cols = int(self.cols)
        p.full_circle = 1 if self.full_circle else 0
        p.light_distance = float(self.light_distance)
        p.psi_lo = float(self.psi_lo)
        return p

    # ---- host coordinate transforms (float64) --------------------------------------------------------
    def world_to_rectified(self, points) -> np.ndarray:
        """Rectified (u, v, depth) of world points, shape (..., 3) -> (..., 3) float64 (see the module doc)."""
        p = np.asarray(points, dtype=np.float64)
        if p.shape[-1] != 3:
            raise ValueError(f"points must have shape (..., 3), got {p.shape}")
        q = (p - self.position) @ self.to_light.T
        d = np.mod(np.arctan2(q[..., 1], q[..., 0]) - self.phi_mid + math.pi, TWO_PI) - math.pi
        u = np.hypot(q[..., 0], q[..., 1]) / self.r_max
        if self.local:
            u = (np.arctan2(np.hypot(q[..., 0], q[..., 1]), q[..., 2] + self.light_distance) - self.psi_lo) / self.r_max
        depth = (self.theta_hi - _inclination(q)) / self.theta_len
        return np.stack([u, 0.5 + d / self.phi_span, depth], axis=-1)

    def rectified_to_world(self, coords) -> np.ndarray:
        """World points of rectified (u, v, depth), shape (..., 3); inclinations must lie inside (0, pi)."""
        c = np.asarray(coords, dtype=np.float64)
        if c.shape[-1] != 3:
            raise ValueError(f"coords must have shape (..., 3), got {c.shape}")
        phi = self.phi_mid + (c[..., 1] - 0.5) * self.phi_span
        theta = self.theta_hi - c[..., 2] * self.theta_len
        if self.local:  # the view ray theta meets the light ray psi at t = D sin(psi) / sin(theta - psi)
            psi = self.psi_lo + c[..., 0] * self.r_max
            t = self.light_distance * np.sin(psi) / np.maximum(np.sin(theta - psi), 1e-300)
            r = t * np.sin(theta)
        else:
            r = c[..., 0] * self.r_max
        z = r * np.cos(theta) / np.maximum(np.sin(theta), 1e-300)
        q = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
        return self.position + q @ self.to_light

    def row_azimuths(self) -> np.ndarray:
        """Azimuth phi (radians) of every row centre, shape (rows,)."""
        return self.phi_mid + ((np.arange(self.rows) + 0.5) / self.rows - 0.5) * self.phi_span

    def slice_inclination_range(self, phi) -> tuple[np.ndarray, np.ndarray]:
        """Inclination interval [theta_lo, theta_hi] of the frustum's view rays inside the epipolar slice(s) phi.

        The slice half-plane meets the frustum in a 2D cone whose boundary rays cross the far-plane
        edges, or run along the light axis (theta = 0 / pi) when the (flipped) light lies inside the view.
        Slices that miss the frustum (only possible outside [phi_min, phi_min + phi_span]) get the global
        tight bounds.

        Args:
            phi: azimuths (radians), any shape.

        Returns:
            (theta_lo, theta_hi) arrays of phi's shape (radians, unguarded).
        """
        phi = np.asarray(phi, dtype=np.float64)
        e = np.stack([np.cos(phi), np.sin(phi)], axis=-1)
        lo = np.full(phi.shape, np.inf)
        hi = np.full(phi.shape, -np.inf)
        for a in range(4):
            qa, qb = self.far_corners[a], self.far_corners[(a + 1) % 4]
            da = qa[0] * e[..., 1] - qa[1] * e[..., 0]  # cross(qa_xy, e)
            dd = (qb[0] - qa[0]) * e[..., 1] - (qb[1] - qa[1]) * e[..., 0]
            with np.errstate(divide="ignore", invalid="ignore"):
                s = np.where(np.abs(dd) > 1e-300, -da / dd, np.nan)
            ok = (s >= -1e-9) & (s <= 1.0 + 1e-9)
            s = np.clip(np.nan_to_num(s), 0.0, 1.0)
            pts = qa + s[..., None] * (qb - qa)
            ok &= (pts[..., 0] * e[..., 0] + pts[..., 1] * e[..., 1]) >= 0.0  # same half-plane, not opposite
            th = _inclination(pts)
            lo = np.where(ok, np.minimum(lo, th), lo)
            hi = np.where(ok, np.maximum(hi, th), hi)
        if self.light_in_view:
            lo = np.zeros_like(lo)
        if self.flipped_light_in_view:
            hi = np.full_like(hi, math.pi)
        empty = ~(lo <= hi)
        lo = np.where(empty, self.theta_min, lo)
        hi = np.where(empty, self.theta_max, hi)
        return lo, hi


# ---- host side: reference rays (Klehm 2014 Sec. 3.2) ---------------------------------------------------


@dataclass(frozen=True)
class ReferenceRays:
    """Per-row reference view rays and their world step per rectified texel (Klehm 2014 Sec. 3.2).

    Attributes:
        phi: (rows,) azimuth of each row centre (radians).
        theta_lo, theta_hi: (rows,) inclination range of the frustum's rays in the slice (radians).
        theta_ref: (rows,) inclination of the reference ray (radians).
        k_ref: (rows,) k(omega_ref) = cos of its angle to the light-perpendicular = sin(theta_ref).
        delta_ref: (rows,) world distance per column along the reference ray, delta_perp / k_ref.
        direction: (rows, 3) unit world direction of the reference ray.
        optimal: (rows,) bool, True where k_ref = sqrt(k_min k_max) was used (else the bisectrix).
    """

    phi: np.ndarray
    theta_lo: np.ndarray
    theta_hi: np.ndarray
    theta_ref: np.ndarray
    k_ref: np.ndarray
    delta_ref: np.ndarray
    direction: np.ndarray
    optimal: np.ndarray

    def optical_steps(self, sigma_t: float) -> np.ndarray:
        """Per-row optical thickness of one texel along the reference ray, sigma_t * delta_ref (float32)."""
        if not (np.isfinite(sigma_t) and sigma_t >= 0.0):
            raise ValueError(f"sigma_t must be finite and >= 0, got {sigma_t}")
        return (sigma_t * self.delta_ref).astype(np.float32)


def caster_radius(vertices, camera, light_direction, margin: float = 0.02) -> float | None:
    """Largest distance of a caster vertex from the light axis through the camera, widened by ``margin`` (relative):
    no light ray farther out is blocked, so a rectified map need not reach beyond it (``map_radius: casters``).
    None without vertices. World units."""
    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    if len(v) == 0:
        return None
    axis = np.asarray(light_direction, np.float64)
    axis = axis / np.linalg.norm(axis)
    p = v - np.asarray(camera.position, np.float64)
    r = np.sqrt(np.maximum(np.einsum("ij,ij->i", p, p) - (p @ axis) ** 2, 0.0))
    return float(r.max() * (1.0 + margin)) if r.max() > 0 else None


def reference_ray(rect: NonlinearRectification, method: str = "optimal", camera=None,
                  pixel_stride: int = 4) -> ReferenceRays:
    """Reference ray per epipolar slice and its world step per rectified texel (Klehm 2014 Sec. 3.2).

    In a slice, a view ray with inclination theta crosses one column over Delta = Delta_perp / k,
    k = sin(theta) (its cosine to the light-perpendicular omega_l-perp). omega_min is the ray of the
    slice closest to omega_l-perp (largest k), omega_max the one farthest from it (smallest k).

    Args:
        rect: the rectification.
        method: ``"optimal"`` — k_ref = sqrt(k(omega_min) k(omega_max)), which minimises the worst
            ratio of Delta errors, where defined (omega_max is not the light axis); the bisectrix of
            omega_min and omega_max otherwise. ``"bisectrix"`` — the bisectrix everywhere (Klehm's
            default). ``"mean"`` — the arithmetic mean of the global theta bounds (Peters 2017 Sec. 5.1.1).
            ``"pixels"`` — the median k of the camera's pixel rays that fall in the slice (every
            ``pixel_stride``-th pixel), the bisectrix in slices no pixel ray reaches, then a running median over
            :data:`PIXEL_MEDIAN_SHARE` of the rows (9 of 1024). Klehm's reference
            minimises the worst Delta error over all rays of the slice, including the few that run
            almost along the light (k -> 0) when the epipole is in view; weighting by the rays actually
            rendered gives lower image error there (warpscatter's choice, measured in ``bench prefiltered``).
            ``"least"`` — omega_min itself, the slice's least optical step: every view ray of the slice decays at
            least as fast, which the per-ray segment weights need (:mod:`.ray_weights`).
        camera: the :class:`~warpscatter.scene.camera.Camera`, required by ``"pixels"``.
        pixel_stride: pixel subsampling of ``"pixels"`` (>= 1).

    Returns:
        :class:`ReferenceRays` with (rows,) arrays.

    Raises:
        ValueError: on an unknown method.
    """
    check_reference_method(method, camera, "reference_ray")
    phi = rect.row_azimuths()
    lo, hi = rect.slice_inclination_range(phi)
    half_pi = 0.5 * math.pi
    theta_kmax = np.clip(half_pi, lo, hi)  # omega_min: closest to the light-perpendicular
    theta_kmin = np.where(np.abs(lo - half_pi) >= np.abs(hi - half_pi), lo, hi)  # omega_max: farthest
    k_big, k_small = np.sin(theta_kmax), np.sin(theta_kmin)
    bisectrix = 0.5 * (theta_kmax + theta_kmin)
    if method == "mean":
        theta_ref = np.full(phi.shape, 0.5 * (rect.theta_min + rect.theta_max))
        optimal = np.zeros(phi.shape, bool)
    elif method == "bisectrix":
        theta_ref = bisectrix
        optimal = np.zeros(phi.shape, bool)
    elif method == "pixels":
        theta_ref = _pixel_median_inclination(rect, camera, pixel_stride, default=bisectrix)
        optimal = np.zeros(phi.shape, bool)
    elif method == "least":
        theta_ref = theta_kmax
        optimal = np.zeros(phi.shape, bool)
    else:
        optimal = k_small > 1e-12  # undefined iff omega_max is the light axis (k = 0)
        k_opt = np.sqrt(np.clip(k_big * k_small, 0.0, 1.0))
        # the ray with sin(theta) = k_opt between omega_min and omega_max
        theta_opt = np.where(theta_kmin <= half_pi, np.arcsin(k_opt), math.pi - np.arcsin(k_opt))
        theta_ref = np.where(optimal, theta_opt, bisectrix)
    k_ref = np.maximum(np.sin(theta_ref), 1e-6)
    st, ct = np.sin(theta_ref), np.cos(theta_ref)
    local = np.stack([st * np.cos(phi), st * np.sin(phi), ct], axis=-1)
    return ReferenceRays(phi=phi, theta_lo=lo, theta_hi=hi, theta_ref=theta_ref, k_ref=k_ref,
                         delta_ref=rect.delta_perp / k_ref, direction=local @ rect.to_light, optimal=optimal)


REFERENCE_METHODS = ("optimal", "bisectrix", "mean", "pixels", "least")


def check_reference_method(method: str, camera, caller: str) -> None:
    """Raise ValueError for an unknown reference-ray method, or ``"pixels"`` without a camera."""
    if method not in REFERENCE_METHODS:
        raise ValueError(f"method must be one of {', '.join(map(repr, REFERENCE_METHODS))}, got {method!r}")
    if method == "pixels" and camera is None:
        raise ValueError(f"{caller}(method='pixels') needs the camera")


def median_per_row(row: np.ndarray, key: np.ndarray, value: np.ndarray, rows: int, default: np.ndarray) -> np.ndarray:
    """Per row r in [0, rows), ``value`` of the sample with the median ``key`` among those with row == r
    (``default[r]`` where a row has none). Used by the pixel-weighted reference rays of both rectifications."""
    order = np.lexsort((key, row))  # by row, then by key
    row_sorted = row[order]
    start = np.searchsorted(row_sorted, np.arange(rows), side="left")
    stop = np.searchsorted(row_sorted, np.arange(rows), side="right")
    has = stop > start
    mid = order[(start + stop - 1) // 2]
    return np.where(has, value[np.where(has, mid, 0)], default)


#: Share of the rows in the running median over the per-row pixel-median reference rays (``reference_ray:
#: pixels``): 9 of 1024 rows. Measured on colonnade_fourier with one segment per ray at 640x360 (1024 rows): the
#: largest jump of a row's reference inclination from its neighbours' 31 deg without (a horizontal line left of the
#: sun), 5.8 deg over 5 rows, 2.2 deg over 9, 1.7 over 15; rel. L1 (colonnade / canopy / window) 8.05 / 2.23 / 32.8 %
#: -> 7.98 / 2.22 / 32.7 % over 9 rows.
PIXEL_MEDIAN_SHARE = 9.0 / 1024.0


def _pixel_median_inclination(rect: NonlinearRectification, camera, stride: int, default: np.ndarray) -> np.ndarray:
    """Per row, the inclination of the median-k pixel ray of ``camera`` in that slice (``default`` where none)."""
    if int(stride) != stride or stride < 1:
        raise ValueError(f"pixel_stride must be an integer >= 1, got {stride}")
    d = camera.ray_directions(stride).reshape(-1, 3)
    q = d @ rect.to_light.T
    theta = _inclination(q)
    v = (np.mod(np.arctan2(q[:, 1], q[:, 0]) - rect.phi_mid + math.pi, TWO_PI) - math.pi) / rect.phi_span + 0.5
    row = np.clip((v * rect.rows).astype(np.int64), 0, rect.rows - 1)
    theta_ref = median_per_row(row, np.sin(theta), theta, rect.rows, default)
    # a running median over neighbouring rows: near the epipole a slice holds a few sampled pixels (or none: the
    # default), and one odd reference ray among its neighbours gives the row its own weights, a line in the image
    # (colonnade_fourier with one segment per ray: a horizontal line left of the sun, -60 % on 3 pixel rows at
    # 640x360)
    half = int(round(0.5 * (PIXEL_MEDIAN_SHARE * rect.rows - 1.0)))
    if half < 1:
        return theta_ref
    padded = np.pad(theta_ref, half, mode="wrap" if rect.full_circle else "edge")
    window = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)
    return np.median(window, axis=1)


# ---- host side: resampling ------------------------------------------------------------------------------


def radial_span(cols: int, device) -> int:
    """Texels of a rectified row one thread of the supersampled resampling takes: the whole row on the CPU (a
    thread per row sets the row's light-ray points up once: half the time of a thread per texel at 1024^2), one on
    CUDA (a thread per texel: a GPU needs the threads more than the saved setup). Any span gives the same texels."""
    return max(1, int(cols)) if wp.get_device(device).is_cpu else 1


def resample_shadow_map(rect: NonlinearRectification, shadow_depth, world_to_clip, *, depth: str = "ndc",
                        world_to_view=None, radial_samples: int = 0, translucency=None, device=None):
    """Resample an orthographic light shadow map into the rectified blocker-depth map (Peters 2017 Sec. 5.1.1).

    Each rectified texel (row j, column i) is a light ray; its point closest to the camera is projected
    into the shadow map (nearest texel), the stored caster is placed on the same light ray and its
    inclination converted to the rectified depth. Casters in front of the frustum clamp to 0, behind it
    to 1 (Klehm 2014 Sec. 4.1); empty texels and light rays outside the shadow map give 1 (no blocker).

    Args:
        rect: the rectification (its rows x cols is the output size).
        shadow_depth: (H, W) float32 numpy or Warp array of light-space depth, row 0 = NDC y = +1.
        world_to_clip: (4, 4) OpenGL-style orthographic world -> clip matrix of the shadow map
            (``projection @ view``), NDC z in [-1, 1], depth growing along the light direction.
        depth: what the texels store: ``"ndc"`` NDC z in [-1, 1] (>= 1 empty), ``"window"`` (NDC z + 1) / 2
            in [0, 1] (>= 1 empty), or ``"linear"`` the distance along the light from the light view's
            origin, -z of ``world_to_view`` (:class:`~warpscatter.shadows.shadow_map.ShadowMap`'s
            convention). Non-finite values (e.g. +inf) are empty in all three.
        world_to_view: (4, 4) light view matrix, required for ``depth="linear"``.
        radial_samples: 0: one nearest depth at each texel's centre. 1 to :data:`MAX_RADIAL_SAMPLES`: that many
            points spread evenly over the texel's radial (column) extent, each reading its four nearest shadow-map
            texels with bilinear weights (:func:`bilinear_footprint`), condensed to two
            depths (:class:`SparseRectifiedDepth`, see :func:`resample_radial_kernel`). One nearest depth per texel
            aliases: the casters' texel staircases (seen from the camera, shadow-map texels are wedges from the light's
            epipole) and, where a rectified texel is wider than a shadow-map texel (:func:`resample_footprint_texels`),
            casters' edges skipped at random along each row show as radial streaks in the look-ups.
        translucency: None, or the shadow map's translucent layer (opaque depth, transmittance): two (H, W) arrays
            (numpy or Warp), the depth in the same kind as ``shadow_depth`` (module doc).
        device: Warp device.

    Returns:
        (rows, cols) float32 Warp array of rectified blocker depth in [0, 1]; with ``radial_samples`` > 0 or
        ``translucency`` a :class:`SparseRectifiedDepth`.

    Raises:
        ValueError: on a matrix that is not an orthographic projection along the light direction, a bad
            ``depth`` kind or a shadow map that is not 2D.
    """
    device = default_device(device)
    m = np.asarray(world_to_clip, dtype=np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise ValueError(f"world_to_clip must be a finite 4x4 matrix, got shape {m.shape}")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise ValueError("world_to_clip must be orthographic (last row 0 0 0 1) for a directional light")
    light = rect.light_direction
    xy_drift = np.abs(m[:2, :3] @ light) / np.maximum(np.linalg.norm(m[:2, :3], axis=1), 1e-300)
    if np.any(xy_drift > 1e-5):
        raise ValueError("world_to_clip must project along the light direction (light rays map to one texel)")
    if depth == "ndc":
        row, empty = m[2], 1.0
    elif depth == "window":
        row, empty = 0.5 * m[2] + np.array([0.0, 0.0, 0.0, 0.5]), 1.0
    elif depth == "linear":
        if world_to_view is None:
            raise ValueError("world_to_view is required for depth='linear'")
        v = np.asarray(world_to_view, dtype=np.float64)
        if v.shape != (4, 4):
            raise ValueError(f"world_to_view must be a 4x4 matrix, got shape {v.shape}")
        row, empty = -v[2], np.inf
    else:
        raise ValueError(f"depth must be 'ndc', 'window' or 'linear', got {depth!r}")
    if int(radial_samples) != radial_samples or not 0 <= radial_samples <= MAX_RADIAL_SAMPLES:
        raise ValueError(f"radial_samples must be an integer in 0..{MAX_RADIAL_SAMPLES}, got {radial_samples}")
    per_unit = float(row[:3] @ light)
    if not per_unit > 0.0:
        raise ValueError("shadow-map depth must grow along the light direction (check world_to_clip / world_to_view)")
    sm = _map_array(shadow_depth, "shadow_depth", device)
    layer = TranslucentLayer()
    layer.translucent = int(translucency is not None)
    if translucency is None:
        layer.opaque_depth = layer.transmittance = wp.ones((1, 1), dtype=wp.float32, device=device)
    else:
        opaque_depth, transmittance = translucency
        layer.opaque_depth = _map_array(opaque_depth, "opaque depth", device)
        layer.transmittance = _map_array(transmittance, "transmittance", device)
        if layer.opaque_depth.shape != sm.shape or layer.transmittance.shape != sm.shape:
            raise ValueError(f"translucency: the opaque depth and transmittance must have the map's shape {sm.shape}")
    head = [rect.params(), sm]
    tail = [wp.mat44(*m.astype(np.float32).ravel()), wp.vec4(*row.astype(np.float32)), per_unit, float(empty)]
    shape = (rect.rows, rect.cols)
    if radial_samples > 0 or translucency is not None:
        z1, z2, w2 = (wp.empty(shape, dtype=wp.float32, device=device) for _ in range(3))
        span = radial_span(rect.cols, device)
        dim = (rect.rows, (rect.cols + span - 1) // span)
        if radial_samples > 0:
            launch_rows(resample_radial_kernel, dim, [*head, layer, *tail, int(radial_samples), span, z1, z2, w2],
                        device=device)
        else:
            launch_rows(resample_translucent_kernel, shape, [*head, layer, *tail, z1, z2, w2], device=device)
        return SparseRectifiedDepth(z1=z1, z2=z2, w2=w2)
    out = wp.empty(shape, dtype=wp.float32, device=device)
    launch_rows(resample_kernel, shape, [*head, *tail, out], device=device)
    return out


def _map_array(a, name: str, device) -> wp.array:
    """A 2D float32 map as a Warp array on ``device``."""
    if isinstance(a, wp.array):
        arr = a if a.device == wp.get_device(device) else a.to(device)
    else:
        arr = wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=wp.float32, device=device)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 2D array, got {arr.ndim} dimensions")
    return arr


# ---- host side: resampling with filtering (Peters 2017 Sec. 5.2) -------------------------------------------


@dataclass
class SparseRectifiedDepth:
    """A rectified map with up to two blocker depths per texel: Z = (1 - w_2) delta_{z_1} + w_2 delta_{z_2}.

    The output of filtering during resampling (Peters 2017 Sec. 5.2, D.5 "sparse rectified representation"); the
    prefilter stores the weighted combination (1 - w_2) B(z_1) + w_2 B(z_2) of any basis B. A plain rectified
    depth map is the case w_2 = 0.

    Attributes:
        z1, z2: (rows, cols) float32 Warp arrays of rectified depth in [0, 1] (1: no blocker).
        w2: (rows, cols) float32 Warp array, weight of z2 in [0, 1].
    """

    z1: wp.array
    z2: wp.array
    w2: wp.array

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.z1.shape[0]), int(self.z1.shape[1])

    def numpy(self) -> np.ndarray:
        """(rows, cols, 3) float32 array of (z1, z2, w2)."""
        return np.stack([self.z1.numpy(), self.z2.numpy(), self.w2.numpy()], axis=-1)


def resample_footprint_texels(rect: NonlinearRectification, texel_world: float) -> float:
    """Radial width of a rectified texel's footprint in the light plane, in shadow-map texels: Delta_r / texel.

    A rectified texel at column coordinate u covers Delta_r = r_max / cols radially (the same for every texel) and
    u r_max phi_span / rows along the azimuth (0 at the camera's light ray, largest at u = 1). The isotropic
    Gaussian of filtering during resampling (``resample_filter_px``) defaults to the finer, radial side, so that it
    does not blur what the rectified map resolves along its rows. (Measured in ``bench moments``-like runs: the
    wider, area-matched width sqrt(Delta_r x azimuthal width at u = 1/2) raised the error against the exact
    marcher on the colonnade from 0.151 to 0.164; the radial width left it at 0.154.)

    Args:
        rect: the rectification.
        texel_world: world size of one shadow-map texel (:attr:`~warpscatter.shadows.shadow_map.ShadowMap.texel_world`).
    """
    if not (np.isfinite(texel_world) and texel_world > 0.0):
        raise ValueError(f"texel_world must be finite and > 0, got {texel_world}")
    return float(rect.r_max / rect.cols / texel_world)


def radial_samples_for(rect: NonlinearRectification, texel_world: float) -> int:
    """Radial sub-samples of ``resample_filter: supersample`` (:func:`resample_shadow_map`): one per shadow-map texel
    a rectified texel spans radially (:func:`resample_footprint_texels`, rounded up), 1 to
    :data:`MAX_RADIAL_SAMPLES`."""
    return int(np.clip(math.ceil(resample_footprint_texels(rect, texel_world) - 1e-6), 1, MAX_RADIAL_SAMPLES))


def resample_moment_shadow_map(rect: NonlinearRectification, msm: MomentShadowMap, farthest_caster: float | None = None,
                               device=None) -> SparseRectifiedDepth:
    """Filtering during resampling (Peters 2017 Sec. 5.2, Algorithm 2, D.5): rectify a filtered moment shadow map.

    Each rectified texel is a light ray; its point closest to the camera is projected into ``msm`` (the light's
    orthographic view) and a BILINEAR sample of the (Gaussian-filtered) stored moments is taken. Its first three
    canonical moments give w_1 delta_{z_1} + w_2 delta_{z_2} by Algorithm 2 (non-positive variance: delta_{b_1}).
    Both signed depths go back to light-space distances on the light ray and to rectified depth, clamped to
    [0, 1] like :func:`resample_shadow_map`; depths of the cleared far plane (z >= 1 - EMPTY_DEPTH_TOLERANCE) and
    light rays outside the map are "no blocker" (1).

    Args:
        rect: the rectification (its rows x cols is the output size).
        msm: a :class:`~warpscatter.shadows.msm.MomentShadowMap` of an ORTHOGRAPHIC light view along the
            rectification's light direction (channel 0 is used), filtered as wanted.
        farthest_caster: linear light-space depth of the farthest caster in the map (e.g. the largest finite depth
            of the plain shadow map), or None (unknown: the far plane). Algorithm-2 depths between it and the
            cleared far plane are no casters but the empty +1 pulled down by mixtures of three or more depths; they
            are moved continuously to infinity (:func:`sentinel_gap_depth`) instead of becoming blockers at the far
            plane.
        device: Warp device.

    Returns:
        :class:`SparseRectifiedDepth` of shape (rows, cols).

    Raises:
        ValueError: for a perspective map or one whose view does not look along the light direction.
    """
    device = default_device(device)
    sm = msm.shadow_map
    if sm.perspective:
        raise ValueError("msm: filtering during resampling needs an orthographic (directional-light) moment map")
    forward = -np.asarray(sm.view, np.float64)[2, :3]
    if np.linalg.norm(np.cross(forward / np.linalg.norm(forward), rect.light_direction)) > 1e-5:
        raise ValueError("msm: its light view must look along the rectification's light direction")
    params = msm.params(normal_offset_texels=0.0)
    texels = msm.texels if msm.texels.device == wp.get_device(device) else msm.texels.to(device)
    shape = (rect.rows, rect.cols)
    z1, z2, w2 = (wp.empty(shape, dtype=wp.float32, device=device) for _ in range(3))
    z_empty = 1.0 - float(EMPTY_DEPTH_TOLERANCE)
    limit = z_empty
    if farthest_caster is not None and np.isfinite(farthest_caster):
        g = msm.geometry
        limit = float(np.clip(g.depth_scale * float(farthest_caster) + g.depth_offset, -1.0, z_empty))
    launch_rows(resample_moments_kernel, shape, [rect.params(), params, texels, z1, z2, w2, limit], device=device)
    return SparseRectifiedDepth(z1=z1, z2=z2, w2=w2)
