"""The resample taps shared by every resampled rectification (Peters 2017 Sec. 5.1.1, 5.2; Klehm 2014 Sec. 3.2).

A rectified texel is a light ray; resampling reads the light's shadow map along it. With ``resample_filter:
supersample`` each texel takes ``samples`` light rays over its column extent, each reading its four nearest
shadow-map texels with bilinear weights (the TAPS), and condenses them to two depths in two passes over the same
taps: the first finds the casters' depth range [lo, hi] and the caster and empty weights (:func:`tap_range`), the
second splits the casters at the middle of that range, each part's weighted mean becoming one depth
(:func:`tap_split`); with empty taps the casters form one depth and the empty taps (depth 1) the other. Opaque maps
keep their taps for the second pass (at most RADIAL_TAPS, at indices fixed when the kernel compiles, so they stay in
registers: :func:`keep_tap`, :func:`kept_taps_parts`). Translucent casters make each tap one part or two
(:func:`tap_part`: the nearest caster with weight 1 - T, the nearest opaque caster with weight T) and the second
pass re-reads them: :func:`split_translucent_taps`, written once for every map kind through the overloaded
``tap_ray`` / ``read_tap`` of its source struct (:mod:`.nonlinear`, :mod:`.local`).

Conventions: maps are (H, W) float32, row 0 = NDC y = +1; a tap's texel may lie off the map (then it is empty).
The result of a supersampled or translucent resampling is a :class:`SparseRectifiedDepth`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from ...runtime.device import module_options
from ...scene.lights import LightParams
from .spherical import NonlinearRectParams

module_options()


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

    @classmethod
    def empty(cls, shape: tuple[int, int], device) -> "SparseRectifiedDepth":
        """Uninitialised maps of ``shape`` (rows, cols) on ``device``, for a kernel to fill."""
        return cls(*(wp.empty(shape, dtype=wp.float32, device=device) for _ in range(3)))

    def texels(self) -> "TwoDepthTexels":
        """The three maps as one kernel argument (:class:`TwoDepthTexels`)."""
        out = TwoDepthTexels()
        out.z1, out.z2, out.w2 = self.z1, self.z2, self.w2
        return out


@wp.struct
class TwoDepthTexels:
    """A :class:`SparseRectifiedDepth` as a kernel writes it: (rows, cols) maps of z1, z2 and the weight w2 of z2."""

    z1: wp.array2d(dtype=wp.float32)  # the nearer rectified depth in [0, 1] (1: no blocker)
    z2: wp.array2d(dtype=wp.float32)  # the farther rectified depth in [0, 1]
    w2: wp.array2d(dtype=wp.float32)  # the weight of z2 in [0, 1]


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


@wp.struct
class TranslucentLayer:
    """A shadow map's translucent layer as the translucent resampling kernels read it."""

    opaque_depth: wp.array2d(dtype=wp.float32)  # (H, W) stored depth of the nearest opaque caster
    transmittance: wp.array2d(dtype=wp.float32)  # (H, W) transmittance of the translucent casters in front of it


@wp.struct
class OrthoShadowMap:
    """A directional light's orthographic shadow map as the resampling kernels read it."""

    depth: wp.array2d(dtype=wp.float32)  # (H, W) stored light-space depth, row 0 = NDC y = +1
    world_to_clip: wp.mat44  # orthographic light world -> clip (w = 1)
    depth_row: wp.vec4  # stored depth of world point p = dot(depth_row, (p, 1))
    depth_per_unit: float  # d(stored depth) / d(distance along the light direction) > 0
    empty_depth: float  # stored values >= this are empty texels (no caster)


#: Most radial sub-samples per rectified texel of the supersampled resampling (``resample_filter: supersample``,
#: :func:`~.nonlinear.resample_shadow_map`).
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
def translucent_tap(layer: TranslucentLayer, x: int, y: int, d: float, depth_per_unit: float, empty_depth: float):
    """The opaque part of tap (x, y) of a map with translucent casters (:func:`tap_caster` gave the nearest caster):
    (the light share T reaching the nearest opaque caster, that caster's distance z_b along the light from the tap's
    light-ray point at stored depth d, 1 if there is one else 0); T = 0 off the map."""
    if x < 0 or y < 0 or x >= layer.transmittance.shape[1] or y >= layer.transmittance.shape[0]:
        return float(0.0), float(0.0), float(0.0)
    stored = layer.opaque_depth[y, x]
    if wp.isfinite(stored) and stored < empty_depth:
        return layer.transmittance[y, x], (stored - d) / depth_per_unit, float(1.0)
    return layer.transmittance[y, x], float(0.0), float(0.0)


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


#: Taps one supersampled texel of an opaque map keeps for its second pass: four per radial sub-sample.
RADIAL_TAPS = 4 * MAX_RADIAL_SAMPLES
radial_taps = wp.types.vector(length=RADIAL_TAPS, dtype=wp.float32)


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


def map_array(a, name: str, device) -> wp.array:
    """A 2D float32 map as a Warp array on ``device``."""
    if isinstance(a, wp.array):
        arr = a if a.device == wp.get_device(device) else a.to(device)
    else:
        arr = wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=wp.float32, device=device)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 2D array, got {arr.ndim} dimensions")
    return arr


def translucent_layer(opaque_depth, transmittance, shape, device) -> TranslucentLayer:
    """A shadow map's translucent layer (two (H, W) maps, numpy or Warp) as the resampling kernels read it.

    Raises:
        ValueError: when a map is not 2D or its shape differs from the depth map's ``shape``.
    """
    layer = TranslucentLayer()
    layer.opaque_depth = map_array(opaque_depth, "opaque depth", device)
    layer.transmittance = map_array(transmittance, "transmittance", device)
    if layer.opaque_depth.shape != shape or layer.transmittance.shape != shape:
        raise ValueError(f"translucency: the opaque depth and transmittance must have the map's shape {shape}")
    return layer


# ---- tap sources: where split_translucent_taps reads its sub-samples and taps ------------------------------


@wp.struct
class RadialTapSource:
    """A row of a directional map's supersampled texels (:mod:`.nonlinear`): its light-ray points are
    c0 + u ca (clip coordinates) at stored depth d0 + u da, u the column coordinate."""

    rect: NonlinearRectParams
    sm: OrthoShadowMap
    layer: TranslucentLayer
    c0: wp.vec4
    ca: wp.vec4
    d0: float
    da: float


@wp.struct
class SpotTapSource:
    """A row of a spot map's texels (:mod:`.local`): light rays from the spot at angle psi (column) in the
    epipolar plane of azimuth ``phi`` (row)."""

    rect: NonlinearRectParams
    light: LightParams
    depth: wp.array2d(dtype=wp.float32)  # (H, W) the spot map: distance along its axis, +inf empty
    layer: TranslucentLayer
    world_to_clip: wp.mat44  # the spot's perspective world -> clip
    phi: float  # the row's azimuth (radians)
    to_world: wp.mat33  # light view -> world rotation


@wp.func
def spot_tap(rect: NonlinearRectParams, light_pos: wp.vec3, axis: wp.vec3, direction: wp.vec3,
             depth: wp.array2d(dtype=wp.float32), c: wp.vec4, t: int, weight: float):
    """Tap t (0..3) of the bilinear footprint of clip coordinates c (w = 1) in a spot map that stores the casters'
    distance along the spot's ``axis``, for the light ray ``direction`` (unit, world) from ``light_pos``: (the tap
    caster's rectified depth, its bilinear weight times ``weight``, 1 if the texel holds a caster else 0, x, y)."""
    x, y, wx, wy = bilinear_tap(depth, c, t)
    z = float(1.0)
    caster = float(0.0)
    if x >= 0 and y >= 0 and x < depth.shape[1] and y < depth.shape[0]:
        stored = depth[y, x]
        if wp.isfinite(stored):
            s_b = stored / wp.max(wp.dot(direction, axis), 1.0e-6)
            q = rect.to_light * (light_pos + direction * s_b - rect.origin)
            theta = wp.atan2(wp.sqrt(q[0] * q[0] + q[1] * q[1]), q[2])
            z = wp.clamp((rect.theta_hi - theta) / rect.theta_len, 0.0, 1.0)
            caster = 1.0
    return z, weight * wx * wy, caster, x, y


@wp.func
def spot_light_ray(rect: NonlinearRectParams, light: LightParams, world_to_clip: wp.mat44, i: int, k: int,
                   inv: float, phi: float, to_world: wp.mat33):
    """Sub-sample k (of 1 / ``inv``) of texel column i's psi extent on the row at azimuth phi: (its unit light ray
    direction, its point at unit distance in the spot map's clip coordinates, divided by w where w > 0)."""
    psi_k = rect.psi_lo + (float(i) + (float(k) + 0.5) * inv) / float(rect.cols) * rect.r_max
    dk = to_world * wp.vec3(wp.sin(psi_k) * wp.cos(phi), wp.sin(psi_k) * wp.sin(phi), wp.cos(psi_k))
    q = light.position + dk
    c = world_to_clip * wp.vec4(q[0], q[1], q[2], 1.0)
    if c[3] > 0.0:
        c = c / c[3]
    return dk, c


@wp.func
def tap_ray(src: RadialTapSource, i: int, k: int, inv: float):
    """Sub-sample k (of 1 / ``inv``) of texel column i: (clip coordinates, stored depth, unused direction, lit)."""
    u = (float(i) + (float(k) + 0.5) * inv) / float(src.rect.cols)
    return src.c0 + src.ca * u, src.d0 + src.da * u, wp.vec3(0.0, 0.0, 0.0), True


@wp.func
def tap_ray(src: SpotTapSource, i: int, k: int, inv: float):  # noqa: F811 (a Warp overload)
    """Sub-sample k (of 1 / ``inv``) of texel column i: (clip coordinates divided by w, unused depth, the unit light
    ray direction, lit: in front of the spot)."""
    dk, c = spot_light_ray(src.rect, src.light, src.world_to_clip, i, k, inv, src.phi, src.to_world)
    return c, float(0.0), dk, c[3] > 0.0


@wp.func
def read_tap(src: RadialTapSource, c: wp.vec4, d: float, direction: wp.vec3, t: int, inv: float):
    """Tap t (0..3) of the sub-sample at clip coordinates c, stored depth d: (nearest caster's z_b, bilinear weight
    times ``inv``, 1 if a caster, nearest opaque caster's z_b, 1 if one, the light share T reaching it)."""
    x, y, wx, wy = bilinear_tap(src.sm.depth, c, t)
    z_n, caster_n = tap_caster(src.sm.depth, x, y, d, src.sm.depth_per_unit, src.sm.empty_depth)
    passed, z_o, caster_o = translucent_tap(src.layer, x, y, d, src.sm.depth_per_unit, src.sm.empty_depth)
    return z_n, inv * wx * wy, caster_n, z_o, caster_o, passed


@wp.func
def read_tap(src: SpotTapSource, c: wp.vec4, d: float, direction: wp.vec3, t: int, inv: float):  # noqa: F811
    """Tap t (0..3) of the light ray ``direction`` at clip coordinates c: as the directional overload, with
    rectified depths instead of z_b (:func:`spot_tap`)."""
    z_n, w_tap, caster_n, x, y = spot_tap(src.rect, src.light.position, src.light.direction, direction, src.depth, c,
                                          t, inv)
    z_o, w_o, caster_o, xo, yo = spot_tap(src.rect, src.light.position, src.light.direction, direction,
                                          src.layer.opaque_depth, c, t, inv)
    passed = float(0.0)
    if x >= 0 and y >= 0 and x < src.layer.transmittance.shape[1] and y < src.layer.transmittance.shape[0]:
        passed = src.layer.transmittance[y, x]
    return z_n, w_tap, caster_n, z_o, caster_o, passed


# ---- the tap split, once for every source -------------------------------------------------------------------


@wp.func
def split_translucent_taps(src: Any, samples: int, i: int):
    """The two passes over the taps of texel column i of a map that may hold translucent casters (module doc):
    (caster weight, empty weight, s1, w1, s2, w2) as :func:`tap_split`. ``src`` is a tap source struct with
    overloads ``tap_ray(src, i, k, inv)`` -> (clip coordinates, stored depth, unit direction, lit) of sub-sample k
    and ``read_tap(src, c, d, direction, t, inv)`` -> (z_n, w_tap, caster_n, z_o, caster_o, T) of its tap t; an
    unlit sub-sample (behind a spot) is empty."""
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
            c, d, direction, lit = tap_ray(src, i, k, inv)
            if not lit:  # behind the spot: no light there anyway (its filter is 0)
                if p == 0:
                    w_empty += inv
            for t in range(4 * int(lit)):
                z_n, w_tap, caster_n, z_o, caster_o, passed = read_tap(src, c, d, direction, t, inv)
                for part in range(tap_parts(passed)):
                    z_b, w, caster = tap_part(z_n, caster_n, z_o, caster_o, w_tap, passed, part)
                    if p == 0:
                        lo, hi, w_caster, w_empty = tap_range(lo, hi, w_caster, w_empty, z_b, w, caster)
                    else:
                        s1, w1, s2, w2 = tap_split(s1, w1, s2, w2, two, mid, z_b, w, caster)
    return w_caster, w_empty, s1, w1, s2, w2
