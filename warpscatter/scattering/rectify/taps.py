"""The resample taps shared by every resampled rectification (Peters 2017 Sec. 5.1.1, 5.2; Klehm 2014 Sec. 3.2).

With ``resample_filter: supersample`` a rectified texel (a light ray) takes ``samples`` light rays over its column
extent, each reading its four nearest shadow-map texels with bilinear weights (the TAPS), and condenses them to two
depths in two passes: the first finds the casters' depth range and the caster and empty weights (:func:`tap_range`),
the second splits the casters at the middle of that range, each part's weighted mean one depth (:func:`tap_split`);
with empty taps the casters form one depth and the empty taps (1) the other. Opaque maps keep their taps in registers
for the second pass (:func:`keep_tap`); translucent casters make a tap two parts (:func:`tap_part`) and the second
pass re-reads them (:func:`split_translucent_taps`, generic over the source structs' ``tap_ray`` / ``read_tap``).
Maps are (H, W) float32, row 0 = NDC y = +1; a tap off the map is empty.
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
    """A rectified map with up to two blocker depths per texel, Z = (1 - w_2) delta_{z_1} + w_2 delta_{z_2} (Peters
    2017 Sec. 5.2, D.5's "sparse rectified representation"; the prefilter stores (1 - w_2) B(z_1) + w_2 B(z_2)):
    (rows, cols) float32 Warp arrays z1, z2 (rectified depth, 1: no blocker) and w2."""

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
    """A :class:`SparseRectifiedDepth` as kernels write it: the nearer depth z1, the farther z2, the weight w2 of z2."""

    z1: wp.array2d(dtype=wp.float32)
    z2: wp.array2d(dtype=wp.float32)
    w2: wp.array2d(dtype=wp.float32)


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
    """The 2 x 2 footprint of clip coordinates c: its first texel (x, y), maybe off the map, and the bilinear weights
    (ax, ay) of the next column and row, linear over the whole texel (docs/design/shadows-scene.md,
    ``PCF_RAMP_TEXELS``)."""
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
    """Texel (x, y), maybe off the map, and bilinear weights (wx, wy) of tap t (0..3) of clip coordinates c."""
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
    """(T, z_b, 1 if a caster else 0) of the nearest opaque caster of tap (x, y) with translucent casters: the light
    share reaching it and its distance along the light from the light-ray point at stored depth d; T = 0 off the map."""
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
    """(depth, weight, caster flag) of part 0 (the nearest caster, weight w_tap (1 - T)) or 1 (the nearest opaque
    caster, w_tap T) of a tap, T = ``passed``."""
    if part == 1:
        return z_o, w_tap * passed, caster_o
    return z_n, w_tap * (1.0 - passed), caster_n


@wp.func
def empty_tap_range():
    """The first pass's start, before any tap: (lo, hi, w_caster, w_empty) of :func:`tap_range`."""
    return float(1.0e30), float(-1.0e30), float(0.0), float(0.0)


@wp.func
def tap_range(lo: float, hi: float, w_caster: float, w_empty: float, z_b: float, w: float, caster: float):
    """First pass: a caster part (z_b, w) extends the casters' range [lo, hi] (if w > 0) and weight w_caster, an empty
    one w_empty."""
    if caster > 0.0:
        if w > 0.0:
            return wp.min(lo, z_b), wp.max(hi, z_b), w_caster + w, w_empty
        return lo, hi, w_caster + w, w_empty
    return lo, hi, w_caster, w_empty + w


@wp.func
def tap_split(s1: float, w1: float, s2: float, w2: float, two: bool, mid: float, z_b: float, w: float,
              caster: float):
    """Second pass: a caster part (z_b, w) adds to the farther part's sums (s2, w2) when the casters split (``two``)
    and it lies beyond ``mid``, else to the nearer part's (s1, w1)."""
    if caster > 0.0:
        if two and z_b > mid:
            return s1, w1, s2 + w * z_b, w2 + w
        return s1 + w * z_b, w1 + w, s2, w2
    return s1, w1, s2, w2


@wp.func
def split_point(lo: float, hi: float, w_empty: float):
    """(whether the casters split in two: no empty tap and a range wider than a point, the middle of their range)."""
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
    """:func:`tap_range` plus the casters' weighted depth sum s_caster, and the weight to keep (-1: empty tap)."""
    lo, hi, w_caster, w_empty = tap_range(lo, hi, w_caster, w_empty, z_b, w, caster)
    if caster > 0.0:
        return lo, hi, w_caster, w_empty, s_caster + w * z_b, w
    return lo, hi, w_caster, w_empty, s_caster, float(-1.0)


@wp.func
def kept_taps_parts(z: radial_taps, w: radial_taps, count: int, lo: float, hi: float, w_caster: float,
                    w_empty: float, s_caster: float):
    """(s1, w1, s2, w2) of :func:`tap_split` over the first ``count`` kept taps (weight < 0: empty), given the first
    pass's results (:func:`keep_tap`)."""
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
    """A shadow map's translucent layer (two (H, W) maps, numpy or Warp, of the depth map's ``shape``) for kernels."""
    layer = TranslucentLayer()
    layer.opaque_depth = map_array(opaque_depth, "opaque depth", device)
    layer.transmittance = map_array(transmittance, "transmittance", device)
    if layer.opaque_depth.shape != shape or layer.transmittance.shape != shape:
        raise ValueError(f"translucency: the opaque depth and transmittance must have the map's shape {shape}")
    return layer


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
    """(rectified depth, bilinear weight times ``weight``, caster flag, x, y) of tap t of clip coordinates c (w = 1) in
    a spot map storing distance along ``axis``, for the unit light ray ``direction`` from ``light_pos``."""
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
    """(unit light-ray direction, its point at unit distance in clip coordinates, divided by w > 0) of sub-sample k
    (of 1 / ``inv``) of texel column i's psi extent on the row at azimuth phi."""
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
    """(z_n, w_tap, caster_n, z_o, caster_o, T) of tap t of the sub-sample at clip coordinates c, stored depth d."""
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


@wp.func
def split_translucent_taps(src: Any, samples: int, i: int):
    """(w_caster, w_empty, s1, w1, s2, w2): the two passes over texel column i's taps (module doc). ``src`` is a tap
    source struct with overloads ``tap_ray`` (sub-sample k) and ``read_tap`` (its tap t); unlit sub-samples: empty."""
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
