"""Moment soft shadow mapping (Peters et al. 2017, Sec. 4, Appendix D.4) from an integer summed-area table (Sec.
4.2: exact for boxes of <= n_t = max_kernel_px^2 texels), and :func:`pcss_visibility`, a brute-force PCSS
reference. Widths are in texels per map axis; light models and clamps: docs/design/shadows-scene.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from ..runtime.device import default_device, module_options
from ..runtime.parallel import launch_rows
from ..runtime.stages import StageTimer
from . import moments as mm
from . import msm as msmod
from .msm import MomentShadowMap, MomentShadowParams
from .settings import MAX_KERNEL_PX, MIN_KERNEL_PX, REFERENCE_KERNEL_PX
from .shadow_map import ShadowMap

module_options()

#: eps_z0 of Eq. (4).
BLOCKER_EPSILON = wp.constant(1.0e-3)
#: eps_u of Sec. 4.5: umbra when the blocker-search shadow intensity exceeds 1 - eps_u.
UMBRA_EPSILON = wp.constant(0.01)


@wp.struct
class SoftShadowParams:
    """Moment soft shadow (and PCSS) settings as kernels see them."""

    msm: MomentShadowParams
    light_extent: wp.vec2  # orthographic: tan(theta / 2) per map axis; perspective: half light size (scene units)
    max_kernel_px: int  # n_t = max_kernel_px^2
    sat_scale: wp.float64  # (2^32 - 1) / n_t
    moment_bias: float  # alpha_b
    blocker_epsilon: float
    umbra_epsilon: float



@wp.func
def sat_integer(q: float, scale: wp.float64) -> wp.uint32:
    """round(clamp(q, 0, 1) * scale) as uint32 (NaN -> 0); Peters 2017, D.4 ComputeFixedPrecision."""
    qc = q
    if wp.isnan(qc):
        qc = 0.0
    qc = wp.clamp(qc, 0.0, 1.0)
    return wp.uint32(wp.floor(wp.float64(qc) * scale + wp.float64(0.5)))


@wp.func
def sat_texel(texel: wp.vec4, storage: int, scale: wp.float64) -> wp.vec4ui:
    """A texel as the integers the table sums: Theta_4* of its moments, scaled, rounded (Sec. 4.2)."""
    q = mm.quantization_transform4(mm.load_moments4(texel, storage))
    return wp.vec4ui(sat_integer(q[0], scale), sat_integer(q[1], scale), sat_integer(q[2], scale),
                     sat_integer(q[3], scale))


@wp.func
def sat_box_sum(sat: wp.array3d(dtype=wp.vec4ui), c: int, x0: int, y0: int, x1: int, y1: int) -> wp.vec4ui:
    """Modular sum of the texels [x0, x1) x [y0, y1) of channel c; exact for <= n_t texels (Fig. 7a)."""
    return sat[c, y1, x1] - sat[c, y0, x1] - sat[c, y1, x0] + sat[c, y0, x0]


@wp.func
def _to_vec4d(s: wp.vec4ui) -> wp.vec4d:
    return wp.vec4d(wp.float64(s[0]), wp.float64(s[1]), wp.float64(s[2]), wp.float64(s[3]))


@wp.func
def sat_box_average(sat: wp.array3d(dtype=wp.vec4ui), c: int, x0: int, y0: int, x1: int, y1: int,
                    scale: wp.float64) -> wp.vec4:
    """Average Theta_4* moments of the texels [x0, x1) x [y0, y1) (a non-empty box of <= n_t texels)."""
    n = wp.float64((x1 - x0) * (y1 - y0)) * scale
    a = _to_vec4d(sat_box_sum(sat, c, x0, y0, x1, y1)) / n
    return wp.vec4(float(a[0]), float(a[1]), float(a[2]), float(a[3]))


@wp.func
def box_segments(a0: float, a1: float, n: int):
    """Split [a0, a1] (texel units) at the grid into partial, whole, partial texels: (starts, ends, coverage);
    one axis of Fig. 7b's nine sub-rectangles."""
    i0 = wp.clamp(int(wp.floor(a0)), 0, n - 1)
    i1 = wp.clamp(int(wp.floor(a1)), 0, n - 1)
    if i1 <= i0:
        return wp.vec3i(i0, i0, i0), wp.vec3i(i0 + 1, i0, i0), wp.vec3(a1 - a0, 0.0, 0.0)
    return (wp.vec3i(i0, i0 + 1, i1), wp.vec3i(i0 + 1, i1, i1 + 1),
            wp.vec3(float(i0 + 1) - a0, 1.0, a1 - float(i1)))


@wp.func
def sat_rectangle_average(sat: wp.array3d(dtype=wp.vec4ui), c: int, x0: float, y0: float, x1: float, y1: float,
                          scale: wp.float64) -> wp.vec4:
    """Area-weighted average Theta_4* over [x0, x1] x [y0, y1] (texels, sides <= sqrt(n_t)); Sec. 4.4, Fig. 7b."""
    n_x = sat.shape[2] - 1
    n_y = sat.shape[1] - 1
    xs, xe, xw = box_segments(x0, x1, n_x)
    ys, ye, yw = box_segments(y0, y1, n_y)
    acc = wp.vec4d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    for a in range(3):
        for b in range(3):
            w = xw[a] * yw[b]
            if w > 0.0 and xe[a] > xs[a] and ye[b] > ys[b]:
                acc += wp.float64(w) * _to_vec4d(sat_box_sum(sat, c, xs[a], ys[b], xe[a], ye[b]))
    area = wp.float64((x1 - x0) * (y1 - y0)) * scale
    r = acc / area
    return wp.vec4(float(r[0]), float(r[1]), float(r[2]), float(r[3]))


@wp.func
def sat_biased_moments(p: SoftShadowParams, q: wp.vec4) -> wp.vec4:
    """Table average -> canonical moments biased with alpha_b and b* (D.4)."""
    return mm.bias_moments4(mm.inverse_quantization_transform4(q), p.moment_bias, mm.BIAS_VECTOR4_QUANTIZED)



@wp.func
def average_blocker_depth(b: wp.vec4, z_f: float, eps: float) -> wp.vec2:
    """(average blocker depth, blocker intensity sum_{z_l < z_f} w_l) of Peters 2017 Eq. (4); signed depths."""
    depths, weights = mm.msm4_distribution(b, z_f)
    z0 = depths[0]
    num = eps * z0
    den = eps
    shadow = float(0.0)
    for k in range(1, 3):
        if depths[k] < z0:
            num += weights[k] * depths[k]
            den += weights[k]
            shadow += weights[k]
    return wp.vec2(wp.clamp(num / den, -1.0, z0), wp.clamp(shadow, 0.0, 1.0))


@wp.func
def search_half_width(p: SoftShadowParams, d_r: float) -> wp.vec2:
    """Blocker-search half-width in texels (x, y) at linear depth d_r (Fernando 2005; Peters 2017 Sec. 4.3)."""
    near = p.msm.near
    k = wp.max(d_r - near, 0.0)
    if p.msm.sm.perspective != 0:
        k = k / (wp.max(d_r, near) * near)
    hi = float(p.max_kernel_px) * 0.5 - 1.0
    return wp.vec2(wp.clamp(p.light_extent[0] * k / p.msm.texel_x, 0.5, hi),
                   wp.clamp(p.light_extent[1] * k / p.msm.texel_y, 0.5, hi))


@wp.func
def penumbra_half_width(p: SoftShadowParams, d_r: float, d_b: float) -> wp.vec2:
    """Filter half-width in texels (x, y) for linear depths d_r, d_b (Fernando 2005; D.4 EstimatePenumbraSize)."""
    k = wp.max(d_r - d_b, 0.0)
    if p.msm.sm.perspective != 0:
        k = k / (wp.max(d_b, p.msm.near) * wp.max(d_r, p.msm.near))
    hi = float(p.max_kernel_px) * 0.5
    wx = p.light_extent[0] * k / p.msm.texel_x
    wy = p.light_extent[1] * k / p.msm.texel_y
    if not (wp.isfinite(wx) and wp.isfinite(wy)):
        return wp.vec2(hi, hi)
    return wp.vec2(wp.clamp(wx, 0.5, hi), wp.clamp(wy, 0.5, hi))


@wp.func
def search_region(fx: float, fy: float, hs: wp.vec2, w: int, h: int) -> wp.vec4i:
    """Grid-aligned search region (x0, y0, x1, y1), texels [x0, x1) x [y0, y1), clipped to the map (Sec. 4.5)."""
    x0 = wp.clamp(int(wp.floor(fx - hs[0])), 0, w - 1)
    y0 = wp.clamp(int(wp.floor(fy - hs[1])), 0, h - 1)
    x1 = wp.clamp(int(wp.ceil(fx + hs[0])), x0 + 1, w)
    y1 = wp.clamp(int(wp.ceil(fy + hs[1])), y0 + 1, h)
    return wp.vec4i(x0, y0, x1, y1)


@wp.func
def filter_rectangle(fx: float, fy: float, hf: wp.vec2, w: int, h: int) -> wp.vec4:
    """Filter rectangle (x0, y0, x1, y1) in texel units around (fx, fy), clipped to the map (non-empty inside)."""
    x0 = wp.clamp(fx - hf[0], 0.0, float(w))
    y0 = wp.clamp(fy - hf[1], 0.0, float(h))
    x1 = wp.clamp(fx + hf[0], 0.0, float(w))
    y1 = wp.clamp(fy + hf[1], 0.0, float(h))
    return wp.vec4(x0, y0, wp.max(x1, x0 + 1.0e-3), wp.max(y1, y0 + 1.0e-3))


@wp.func
def linear_depth(p: MomentShadowParams, z: float) -> float:
    """Linear light-space depth of signed depth z (inverse of :func:`~warpscatter.shadows.msm.signed_depth`)."""
    return (z - p.depth_offset) / p.depth_scale



@wp.func
def moment_soft_channel_visibility(p: SoftShadowParams, sat: wp.array3d(dtype=wp.vec4ui), c: int, fx: float,
                                   fy: float, d_r: float) -> float:
    """Moment soft shadow visibility of channel c at texel position (fx, fy), linear depth d_r (Sec. 4.3-4.5)."""
    n_x = sat.shape[2] - 1
    n_y = sat.shape[1] - 1
    z_f = msmod.signed_depth(p.msm, d_r)
    r = search_region(fx, fy, search_half_width(p, d_r), n_x, n_y)
    b = sat_biased_moments(p, sat_box_average(sat, c, r[0], r[1], r[2], r[3], p.sat_scale))
    blocker = average_blocker_depth(b, z_f, p.blocker_epsilon)
    if blocker[1] > 1.0 - p.umbra_epsilon:
        return 0.0
    hf = penumbra_half_width(p, d_r, linear_depth(p.msm, blocker[0]))
    rect = filter_rectangle(fx, fy, hf, n_x, n_y)
    q = sat_rectangle_average(sat, c, rect[0], rect[1], rect[2], rect[3], p.sat_scale)
    bias = p.msm.depth_bias * wp.max(1.0, 2.0 * wp.max(hf[0], hf[1]))
    s = mm.msm4_shadow_intensity(sat_biased_moments(p, q), z_f - bias * p.msm.depth_scale)
    return 1.0 - mm.scale_shadow_intensity(s, p.msm.overdarkening)


@wp.func
def moment_soft_visibility_rgb(p: SoftShadowParams, sat: wp.array3d(dtype=wp.vec4ui), x: wp.vec3,
                               n: wp.vec3) -> wp.vec3:
    """Moment soft shadow visibility (R, G, B) in [0, 1] of x with normal n; ``sat``: :attr:`SummedAreaTable.table`."""
    cc = msmod.receiver_coords(p.msm, x, n)
    if not msmod.inside_map(cc):
        return wp.vec3(1.0, 1.0, 1.0)
    fx = cc[0] * float(sat.shape[2] - 1)
    fy = cc[1] * float(sat.shape[1] - 1)
    v0 = moment_soft_channel_visibility(p, sat, 0, fx, fy, cc[2])
    if p.msm.channels < 3:
        return wp.vec3(v0, v0, v0)
    return wp.vec3(v0, moment_soft_channel_visibility(p, sat, 1, fx, fy, cc[2]),
                   moment_soft_channel_visibility(p, sat, 2, fx, fy, cc[2]))


@wp.func
def moment_soft_visibility(p: SoftShadowParams, sat: wp.array3d(dtype=wp.vec4ui), x: wp.vec3, n: wp.vec3) -> float:
    """Scalar moment soft shadow visibility in [0, 1] (mean over channels of :func:`moment_soft_visibility_rgb`)."""
    v = moment_soft_visibility_rgb(p, sat, x, n)
    return (v[0] + v[1] + v[2]) / 3.0


@wp.func
def pcss_visibility(p: SoftShadowParams, depth_map: wp.array2d(dtype=wp.float32), x: wp.vec3, n: wp.vec3) -> float:
    """Brute-force PCSS (Fernando 2005) on the linear depth map with the moment version's regions; 1 = lit."""
    cc = msmod.receiver_coords(p.msm, x, n)
    if not msmod.inside_map(cc):
        return 1.0
    n_x = depth_map.shape[1]
    n_y = depth_map.shape[0]
    fx = cc[0] * float(n_x)
    fy = cc[1] * float(n_y)
    d_r = cc[2]
    r = search_region(fx, fy, search_half_width(p, d_r), n_x, n_y)
    total = float(0.0)
    count = int(0)
    for j in range(r[1], r[3]):
        for i in range(r[0], r[2]):
            d = depth_map[j, i]
            if d < d_r - p.msm.depth_bias:
                total += d
                count += 1
    if count == 0:
        return 1.0
    hf = penumbra_half_width(p, d_r, total / float(count))
    rect = filter_rectangle(fx, fy, hf, n_x, n_y)
    bias = p.msm.depth_bias * wp.max(1.0, 2.0 * wp.max(hf[0], hf[1]))
    lit = float(0.0)
    i0 = int(wp.floor(rect[0]))
    i1 = wp.min(int(wp.ceil(rect[2])), n_x)
    j0 = int(wp.floor(rect[1]))
    j1 = wp.min(int(wp.ceil(rect[3])), n_y)
    for j in range(j0, j1):
        wy = wp.min(rect[3], float(j + 1)) - wp.max(rect[1], float(j))
        for i in range(i0, i1):
            if d_r - bias <= depth_map[j, i]:
                lit += wy * (wp.min(rect[2], float(i + 1)) - wp.max(rect[0], float(i)))
    return wp.clamp(lit / ((rect[2] - rect[0]) * (rect[3] - rect[1])), 0.0, 1.0)



@wp.kernel
def _sat_rows_kernel(texels: wp.array3d(dtype=wp.vec4), storage: int, scale: wp.float64,
                     sat: wp.array3d(dtype=wp.vec4ui), offset: int):
    j = wp.tid() + offset  # D.4 ApplyPrefixSumHorizontal
    for c in range(texels.shape[0]):
        run = wp.vec4ui(wp.uint32(0), wp.uint32(0), wp.uint32(0), wp.uint32(0))
        for i in range(texels.shape[2]):
            run = run + sat_texel(texels[c, j, i], storage, scale)
            sat[c, j + 1, i + 1] = run


@wp.kernel
def _sat_columns_kernel(sat: wp.array3d(dtype=wp.vec4ui), offset: int):
    i = wp.tid() + offset  # D.4 ApplyPrefixSumVertical
    for c in range(sat.shape[0]):
        run = wp.vec4ui(wp.uint32(0), wp.uint32(0), wp.uint32(0), wp.uint32(0))
        for j in range(1, sat.shape[1]):
            run = run + sat[c, j, i]
            sat[c, j, i] = run


@wp.kernel
def _sat_texels_kernel(texels: wp.array3d(dtype=wp.vec4), storage: int, scale: wp.float64,
                       out: wp.array3d(dtype=wp.vec4ui), offset: int):
    j, i = wp.tid()
    j += offset
    for c in range(texels.shape[0]):
        out[c, j, i] = sat_texel(texels[c, j, i], storage, scale)


@wp.kernel
def _soft_points_kernel(p: SoftShadowParams, sat: wp.array3d(dtype=wp.vec4ui), points: wp.array(dtype=wp.vec3),
                        normals: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3), offset: int):
    k = wp.tid() + offset
    out[k] = moment_soft_visibility_rgb(p, sat, points[k], normals[k])


@wp.kernel
def _pcss_points_kernel(p: SoftShadowParams, depth_map: wp.array2d(dtype=wp.float32),
                        points: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
                        out: wp.array(dtype=wp.float32), offset: int):
    k = wp.tid() + offset
    out[k] = pcss_visibility(p, depth_map, points[k], normals[k])



def _kernel_px(max_kernel_px) -> int:
    if isinstance(max_kernel_px, bool) or not isinstance(max_kernel_px, (int, np.integer)) or not (
        MIN_KERNEL_PX <= max_kernel_px <= MAX_KERNEL_PX
    ):
        raise ValueError(f"max_kernel_px: expected an integer in [{MIN_KERNEL_PX}, {MAX_KERNEL_PX}], got "
                         f"{max_kernel_px!r}")
    return int(max_kernel_px)


def sat_scale(max_kernel_px: int) -> float:
    """(2^32 - 1) / n_t with n_t = max_kernel_px^2 (Sec. 4.2)."""
    return 4294967295.0 / float(_kernel_px(max_kernel_px) ** 2)


def sat_moment_bias(max_kernel_px: int) -> float:
    """alpha_b: 6e-7 up to n_t = 784 (Sec. 4.2), then in proportion to n_t, as the rounding error grows."""
    n_t = _kernel_px(max_kernel_px) ** 2
    return float(mm.MOMENT_BIAS4_SAT_UINT32) * max(1.0, n_t / float(REFERENCE_KERNEL_PX**2))


@dataclass
class SummedAreaTable:
    """Integer summed-area table (C, H + 1, W + 1) ``wp.vec4ui`` of ``msm`` (Sec. 4.2): S[c, j, i] = modular sum
    of the texels x < i, y < j."""

    table: wp.array
    max_kernel_px: int
    msm: MomentShadowMap

    @property
    def n_t(self) -> int:
        return self.max_kernel_px**2

    @property
    def scale(self) -> float:
        return sat_scale(self.max_kernel_px)

    @property
    def nbytes(self) -> int:
        return int(np.prod(self.table.shape)) * 16

    def params(self, *, light_size=None, light_angle_deg=None, depth_bias: float = 0.0,
               normal_offset_texels: float = 1.0,
               overdarkening: float = float(mm.OVERDARKENING_DIVISOR)) -> SoftShadowParams:
        """Kernel parameters for :func:`moment_soft_visibility_rgb` (see :func:`soft_shadow_params`)."""
        return soft_shadow_params(self.msm.shadow_map, light_size=light_size, light_angle_deg=light_angle_deg,
                                  max_kernel_px=self.max_kernel_px, storage=self.msm.storage,
                                  channels=self.msm.channels, depth_bias=depth_bias,
                                  normal_offset_texels=normal_offset_texels, overdarkening=overdarkening)


def _pair(x, name: str) -> np.ndarray:
    a = np.asarray(x, np.float64).reshape(-1)
    if a.size == 1:
        a = np.repeat(a, 2)
    if a.size != 2 or not np.all(np.isfinite(a)) or np.any(a < 0.0):
        raise ValueError(f"{name}: expected a number >= 0 or a pair (x, y) of them, got {x!r}")
    return a


def soft_shadow_params(shadow_map: ShadowMap, *, light_size=None, light_angle_deg=None,
                       max_kernel_px: int = REFERENCE_KERNEL_PX, storage: int = int(mm.STORAGE4_FLOAT32),
                       channels: int = 1, depth_bias: float = 0.0, normal_offset_texels: float = 1.0,
                       overdarkening: float = float(mm.OVERDARKENING_DIVISOR)) -> SoftShadowParams:
    """Kernel parameters for moment soft shadows and the PCSS reference in ``shadow_map``'s light view.

    Args:
        shadow_map: the light's plain :class:`ShadowMap` (transforms, resolution).
        light_size: spot (perspective) maps: the light's size in scene units, scalar or (x, y).
        light_angle_deg: directional (orthographic) maps: full angular size in degrees (< 180), scalar or (x, y).
        max_kernel_px: widest region side in texels (28 in the paper).
        storage, channels, depth_bias, normal_offset_texels, overdarkening: as in
            :func:`~warpscatter.shadows.msm.moment_params`.

    Raises:
        ValueError: a light size not matching the projection, negative sizes, bad kernel size.
    """
    kpx = _kernel_px(max_kernel_px)
    if shadow_map.perspective:
        if light_size is None or light_angle_deg is not None:
            raise ValueError("light_size: a perspective (spot light) map needs light_size in scene units "
                             "(and no light_angle_deg)")
        extent = 0.5 * _pair(light_size, "light_size")
    else:
        if light_angle_deg is None or light_size is not None:
            raise ValueError("light_angle_deg: an orthographic (directional light) map needs light_angle_deg "
                             "(and no light_size)")
        angle = _pair(light_angle_deg, "light_angle_deg")
        if np.any(angle >= 180.0):
            raise ValueError(f"light_angle_deg: must be below 180 degrees, got {light_angle_deg!r}")
        extent = np.tan(np.radians(angle) / 2.0)
    p = SoftShadowParams()
    p.msm = msmod.moment_params(shadow_map, storage=storage, channels=channels, depth_bias=depth_bias,
                                normal_offset_texels=normal_offset_texels, overdarkening=overdarkening)
    p.light_extent = wp.vec2(float(extent[0]), float(extent[1]))
    p.max_kernel_px = kpx
    p.sat_scale = wp.float64(sat_scale(kpx))
    p.moment_bias = sat_moment_bias(kpx)
    p.blocker_epsilon = float(BLOCKER_EPSILON)
    p.umbra_epsilon = float(UMBRA_EPSILON)
    return p


def build_summed_area_table(msm: MomentShadowMap, max_kernel_px: int = REFERENCE_KERNEL_PX,
                            device=None) -> SummedAreaTable:
    """Integer summed-area table of ``msm`` (Sec. 4.2, D.4), meant for 128-bit maps.

    Args:
        msm: an unfiltered moment shadow map (:func:`~warpscatter.shadows.msm.generate_moment_shadow_map`).
        max_kernel_px: largest query side in texels (n_t = max_kernel_px^2, at most MAX_KERNEL_PX).
        device: Warp device.
    """
    device = default_device(device)
    kpx = _kernel_px(max_kernel_px)
    c, h, w = msm.channels, *msm.shape
    table = wp.zeros((c, h + 1, w + 1), dtype=wp.vec4ui, device=device)
    scale = wp.float64(sat_scale(kpx))
    launch_rows(_sat_rows_kernel, h, [msm.texels, int(msm.storage), scale, table], device=device, min_chunk=16)
    launch_rows(_sat_columns_kernel, w + 1, [table], device=device, min_chunk=16)
    return SummedAreaTable(table=table, max_kernel_px=kpx, msm=msm)


def sat_texel_integers(msm: MomentShadowMap, max_kernel_px: int = REFERENCE_KERNEL_PX, device=None) -> np.ndarray:
    """The uint32 integers a table sums, per texel: (C, H, W, 4) (tests and diagnostics)."""
    device = default_device(device)
    kpx = _kernel_px(max_kernel_px)
    c, h, w = msm.channels, *msm.shape
    out = wp.zeros((c, h, w), dtype=wp.vec4ui, device=device)
    launch_rows(_sat_texels_kernel, (h, w), [msm.texels, int(msm.storage), wp.float64(sat_scale(kpx)), out],
                device=device, min_chunk=16)
    return out.numpy().reshape(c, h, w, 4)


def render_soft_shadow_map(scene, shadow_map: ShadowMap, *, supersampling: int = 2,
                           max_kernel_px: int = REFERENCE_KERNEL_PX, coloured: bool = False,
                           max_translucent_layers: int = 16, timer: StageTimer | None = None,
                           device=None) -> SummedAreaTable:
    """128-bit moment shadow map (stage ``msm_generate``) and its summed-area table (stage ``msm_sat``); arguments
    as in :func:`~warpscatter.shadows.msm.generate_moment_shadow_map` and :func:`build_summed_area_table`."""
    stage = timer or StageTimer()
    with stage("msm_generate"):
        m = msmod.generate_moment_shadow_map(scene, shadow_map, supersampling=supersampling, bits=128,
                                             coloured=coloured, max_translucent_layers=max_translucent_layers,
                                             device=device)
    with stage("msm_sat"):
        return build_summed_area_table(m, max_kernel_px, device=device)


def moment_soft_visibility_at(sat: SummedAreaTable, points, normals=None, *, light_size=None,
                              light_angle_deg=None, depth_bias: float = 0.0, normal_offset_texels: float = 0.0,
                              overdarkening: float = float(mm.OVERDARKENING_DIVISOR), device=None) -> np.ndarray:
    """Host wrapper of :func:`moment_soft_visibility_rgb` at world points: (..., C) float32 in [0, 1]."""
    device = default_device(device)
    shape, pts, nrm = msmod.point_arrays(points, normals, device)
    p = sat.params(light_size=light_size, light_angle_deg=light_angle_deg, depth_bias=depth_bias,
                   normal_offset_texels=normal_offset_texels, overdarkening=overdarkening)
    out = wp.zeros(pts.shape[0], dtype=wp.vec3, device=device)
    launch_rows(_soft_points_kernel, pts.shape[0], [p, sat.table, pts, nrm, out], device=device, min_chunk=256)
    c = sat.msm.channels
    return out.numpy()[:, :c].reshape(*shape, c)


def pcss_visibility_at(shadow_map: ShadowMap, points, normals=None, *, light_size=None, light_angle_deg=None,
                       max_kernel_px: int = REFERENCE_KERNEL_PX, depth_bias: float = 0.0,
                       normal_offset_texels: float = 0.0, device=None) -> np.ndarray:
    """Host wrapper of :func:`pcss_visibility` (brute force on ``shadow_map.depth``): (...) float32 in [0, 1]."""
    device = default_device(device)
    shape, pts, nrm = msmod.point_arrays(points, normals, device)
    p = soft_shadow_params(shadow_map, light_size=light_size, light_angle_deg=light_angle_deg,
                           max_kernel_px=max_kernel_px, depth_bias=depth_bias,
                           normal_offset_texels=normal_offset_texels)
    out = wp.zeros(pts.shape[0], dtype=wp.float32, device=device)
    launch_rows(_pcss_points_kernel, pts.shape[0], [p, shadow_map.device_depth(device), pts, nrm, out],
                device=device, min_chunk=64)
    return out.numpy().reshape(shape)
