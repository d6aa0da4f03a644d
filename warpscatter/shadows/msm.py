"""Moment shadow maps for surfaces (Peters et al. 2017, Sec. 2-3, D.1-D.3): filtered hard shadows and translucent
occluders. Signed depth z in [-1, 1]: -1 at the map's near plane, +1 at its far plane and in empty texels; texel
(i, j) has j from the top; look-ups outside the map are lit. Stages and colour rule: docs/design/shadows-scene.md.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import warp as wp

from ..raster.rasterizer import MAX_RESOLUTION, linearize_depth, ndc_to_view_depth, rasterize
from ..runtime.device import default_device, module_options
from ..runtime.parallel import launch_rows
from ..runtime.stages import StageTimer
from . import filterable
from . import moments as mm
from .msm_texels import (  # noqa: F401 (the texel operations are part of this module's API)
    _MIN_ROWS,
    _check_int,
    bilinear_blend,
    bilinear_footprint,
    build_mip_levels,
    fetch_texel,
    gaussian_filter_texels,
    gaussian_weights,
    mip_level_count,
    mip_level_offset,
    round_texel,
    sample_bilinear4,
    sample_mip_bilinear4,
    sample_trilinear4,
)
from .settings import MAX_SUPERSAMPLING
from .shadow_map import ShadowMap, ShadowMapParams, shadow_coords
from .translucency import ALPHA_TEST, OPAQUE_ALPHA, peel_row_bands

module_options()

@wp.struct
class MomentShadowParams:
    """A moment shadow map's geometry and lookup settings as kernels see them."""

    sm: ShadowMapParams
    depth_scale: float  # signed depth z = depth_scale * d + depth_offset, d = linear light-space depth
    depth_offset: float
    near: float  # linear depth of the near plane (z = -1), scene units
    texel_x: float  # world texel size along x (orthographic), or at unit depth (perspective); texel_y likewise
    texel_y: float
    storage: int  # filterable.FORMAT_*
    exponents: wp.vec2  # EVSM (c+, c-)
    depth_bias: float  # scene units
    normal_offset: float  # texels at the receiver's depth
    overdarkening: float  # shadow intensity divisor (Sec. 2.6; <= 0 disables)
    channels: int
    mip_levels: int  # incl. level 0; 0: no chain


@wp.struct
class LightDepthMapping:
    """Rasterized NDC depth of the light view -> signed depth (:func:`signed_depth_from_ndc`)."""

    proj: wp.vec4
    depth_scale: float
    depth_offset: float


@wp.struct
class TranslucentBand:
    """One row band of depth-peeled translucent layers of the supersampled light view (Sec. 3.2, D.3)."""

    trans_ndc: wp.array3d(dtype=wp.float32)  # (k, band sample rows, sW), nearest first
    trans_tri: wp.array3d(dtype=wp.int32)  # same shape, triangle index, -1 empty
    n_layers: int  # k; 0: the arrays are 1x1x1 dummies
    row0: int
    trans_alpha: wp.array2d(dtype=wp.float32)  # (T_t, C) opacity per triangle and channel



@wp.func
def signed_depth(p: MomentShadowParams, d: float) -> float:
    """Signed depth in [-1, 1] of linear light-space depth d (Peters 2017, Sec. 2.3)."""
    z = p.depth_scale * d + p.depth_offset
    if wp.isnan(z):
        return 1.0
    return wp.clamp(z, -1.0, 1.0)


@wp.func
def signed_depth_from_ndc(z_ndc: float, proj: wp.vec4, depth_scale: float, depth_offset: float) -> float:
    """Signed depth of a rasterized NDC depth (``proj`` = P[2,2], P[2,3], P[3,2], P[3,3]); empty (+inf) -> +1
    (Peters 2017, D.1, Sec. 3.2)."""
    if not wp.isfinite(z_ndc):
        return 1.0
    d = ndc_to_view_depth(z_ndc, proj[0], proj[1], proj[2], proj[3])
    z = depth_scale * d + depth_offset
    if wp.isnan(z):
        return 1.0
    return wp.clamp(z, -1.0, 1.0)


@wp.func
def blend_over(dst: wp.vec4, src: wp.vec4, alpha: float) -> wp.vec4:
    """Over operator alpha src + (1 - alpha) dst (Peters 2017, Sec. 3.2 / D.3)."""
    return alpha * src + (1.0 - alpha) * dst


@wp.func
def footprint_lod(p: MomentShadowParams, x: wp.vec3, dx: wp.vec3, dy: wp.vec3) -> float:
    """Level of detail of the footprint dx, dy at x: log2 of its longer side in texels; -1 if non-finite."""
    c = shadow_coords(p.sm, x)
    cx = shadow_coords(p.sm, x + dx)
    cy = shadow_coords(p.sm, x + dy)
    size = wp.vec2(float(p.sm.width), float(p.sm.height))
    ex = wp.cw_mul(wp.vec2(cx[0] - c[0], cx[1] - c[1]), size)
    ey = wp.cw_mul(wp.vec2(cy[0] - c[0], cy[1] - c[1]), size)
    rho = wp.max(wp.length(ex), wp.length(ey))
    if not (wp.isfinite(rho) and rho > 0.0):
        return -1.0
    return wp.log2(rho)


@wp.func
def texel_size_at(p: MomentShadowParams, d: float) -> wp.vec2:
    """World size (x, y) of one texel at linear light-space depth d."""
    if p.sm.perspective != 0:
        return wp.vec2(p.texel_x * d, p.texel_y * d)
    return wp.vec2(p.texel_x, p.texel_y)


@wp.func
def receiver_coords(p: MomentShadowParams, x: wp.vec3, n: wp.vec3) -> wp.vec3:
    """(u, v, d) of x moved ``normal_offset`` texels along n (v down, d linear depth); (-1, -1, 0) if non-finite."""
    c0 = shadow_coords(p.sm, x)
    t = texel_size_at(p, wp.max(c0[2], 0.0))
    c = shadow_coords(p.sm, x + n * (p.normal_offset * wp.max(t[0], t[1])))
    if not (wp.isfinite(c[0]) and wp.isfinite(c[1]) and wp.isfinite(c[2])):
        return wp.vec3(-1.0, -1.0, 0.0)
    return c


@wp.func
def inside_map(c: wp.vec3) -> bool:
    """True when texture coordinates (u, v) lie in [0, 1)^2."""
    return c[0] >= 0.0 and c[0] < 1.0 and c[1] >= 0.0 and c[1] < 1.0


@wp.func
def moment_shadow_intensity(p: MomentShadowParams, texel: wp.vec4, z_f: float) -> float:
    """Over-darkened shadow intensity of a filtered texel at biased depth z_f (Peters 2017 D.2, Algorithm 1)."""
    return filterable.shadow_intensity(texel, z_f, p.storage, p.exponents, p.overdarkening)


@wp.func
def msm_visibility_rgb(p: MomentShadowParams, texels: wp.array3d(dtype=wp.vec4), x: wp.vec3, n: wp.vec3) -> wp.vec3:
    """Filtered hard-shadow visibility (R, G, B) in [0, 1] of point x with normal n (Peters 2017, D.2); ``texels``:
    :attr:`MomentShadowMap.texels`."""
    c = receiver_coords(p, x, n)
    if not inside_map(c):
        return wp.vec3(1.0, 1.0, 1.0)
    z_f = signed_depth(p, c[2]) - p.depth_bias * p.depth_scale
    v0 = 1.0 - moment_shadow_intensity(p, sample_bilinear4(texels, 0, c[0], c[1]), z_f)
    if p.channels < 3:
        return wp.vec3(v0, v0, v0)
    v1 = 1.0 - moment_shadow_intensity(p, sample_bilinear4(texels, 1, c[0], c[1]), z_f)
    v2 = 1.0 - moment_shadow_intensity(p, sample_bilinear4(texels, 2, c[0], c[1]), z_f)
    return wp.vec3(v0, v1, v2)


@wp.func
def msm_visibility_rgb_footprint(p: MomentShadowParams, texels: wp.array3d(dtype=wp.vec4),
                                 mips: wp.array2d(dtype=wp.vec4), x: wp.vec3, n: wp.vec3, dx: wp.vec3,
                                 dy: wp.vec3) -> wp.vec3:
    """:func:`msm_visibility_rgb` with a trilinear look-up in ``mips`` at the level of the pixel footprint dx, dy
    (world vectors on the tangent plane); ``p.mip_levels`` = 0: bilinear. Peters 2017, D.2 (mipmapping)."""
    if p.mip_levels <= 0:
        return msm_visibility_rgb(p, texels, x, n)
    c = receiver_coords(p, x, n)
    if not inside_map(c):
        return wp.vec3(1.0, 1.0, 1.0)
    lod = footprint_lod(p, x, dx, dy)
    z_f = signed_depth(p, c[2]) - p.depth_bias * p.depth_scale
    w = p.sm.width
    h = p.sm.height
    v0 = 1.0 - moment_shadow_intensity(p, sample_trilinear4(mips, 0, w, h, p.mip_levels, c[0], c[1], lod), z_f)
    if p.channels < 3:
        return wp.vec3(v0, v0, v0)
    v1 = 1.0 - moment_shadow_intensity(p, sample_trilinear4(mips, 1, w, h, p.mip_levels, c[0], c[1], lod), z_f)
    v2 = 1.0 - moment_shadow_intensity(p, sample_trilinear4(mips, 2, w, h, p.mip_levels, c[0], c[1], lod), z_f)
    return wp.vec3(v0, v1, v2)


@wp.func
def msm_visibility(p: MomentShadowParams, texels: wp.array3d(dtype=wp.vec4), x: wp.vec3, n: wp.vec3) -> float:
    """Scalar filtered hard-shadow visibility in [0, 1] (the mean over channels of :func:`msm_visibility_rgb`)."""
    v = msm_visibility_rgb(p, texels, x, n)
    return (v[0] + v[1] + v[2]) / 3.0



@wp.kernel
def _generate_kernel(
    opaque_ndc: wp.array3d(dtype=wp.float32),  # (1, sH, sW), +inf where empty
    band: TranslucentBand,
    s: int,
    depth: LightDepthMapping,
    storage: int,
    exponents: wp.vec2,
    texels: wp.array3d(dtype=wp.vec4),  # out: (C, H, W)
    offset: int,
):
    j, i = wp.tid()
    j += offset + band.row0
    y0 = band.row0 * s
    for c in range(texels.shape[0]):
        acc = wp.vec4(0.0, 0.0, 0.0, 0.0)
        for sj in range(s):
            y = j * s + sj
            for si in range(s):
                xs = i * s + si
                z_o = signed_depth_from_ndc(opaque_ndc[0, y, xs], depth.proj, depth.depth_scale, depth.depth_offset)
                b = filterable.texel_from_depth(z_o, storage, exponents)
                # translucent layers back to front (Sec. 3.2); q: the render target's stored value
                blended = bool(False)
                q = wp.vec4(0.0, 0.0, 0.0, 0.0)
                for k in range(band.n_layers):
                    layer = band.n_layers - 1 - k
                    t = band.trans_tri[layer, y - y0, xs]
                    if t >= 0:
                        z_t = signed_depth_from_ndc(band.trans_ndc[layer, y - y0, xs], depth.proj, depth.depth_scale,
                                                    depth.depth_offset)
                        alpha = band.trans_alpha[t, c]
                        if z_t < z_o and alpha >= ALPHA_TEST:
                            if not blended:
                                q = filterable.store_texel(b, storage)
                                blended = True
                            src = filterable.encode_texel(filterable.texel_from_depth(z_t, storage, exponents), storage)
                            q = round_texel(blend_over(q, src, alpha), storage)
                if blended:
                    b = filterable.load_texel(q, storage)
                acc += b
        # one quantization after the average suffices: the transforms are affine
        texels[c, j, i] = filterable.store_texel(acc / float(s * s), storage)


@wp.kernel
def _visibility_footprint_kernel(p: MomentShadowParams, texels: wp.array3d(dtype=wp.vec4),
                                 mips: wp.array2d(dtype=wp.vec4), points: wp.array(dtype=wp.vec3),
                                 normals: wp.array(dtype=wp.vec3), dx: wp.array(dtype=wp.vec3),
                                 dy: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3), offset: int):
    k = wp.tid() + offset
    out[k] = msm_visibility_rgb_footprint(p, texels, mips, points[k], normals[k], dx[k], dy[k])


@wp.kernel
def _visibility_points_kernel(p: MomentShadowParams, texels: wp.array3d(dtype=wp.vec4),
                              points: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
                              out: wp.array(dtype=wp.vec3), offset: int):
    k = wp.tid() + offset
    out[k] = msm_visibility_rgb(p, texels, points[k], normals[k])


@dataclass
class MapGeometry:
    """Depth range (linear depths of signed depth -1 and +1, scene units) and texel size of a light view."""

    near: float
    far: float
    texel_x: float
    texel_y: float

    @property
    def depth_scale(self) -> float:
        return 2.0 / (self.far - self.near)

    @property
    def depth_offset(self) -> float:
        return -(self.far + self.near) / (self.far - self.near)


def map_geometry(shadow_map: ShadowMap) -> MapGeometry:
    """Near/far depths and texel sizes of ``shadow_map``'s light view."""
    p = np.asarray(shadow_map.projection, np.float64)
    near, far = (float(x) for x in linearize_depth(np.array([-1.0, 1.0]), p))
    if not (np.isfinite(near) and np.isfinite(far) and far > near):
        raise ValueError(f"shadow_map: its projection gives no valid depth range (near {near}, far {far})")
    h, w = shadow_map.shape
    return MapGeometry(near=near, far=far, texel_x=2.0 / (p[0, 0] * w), texel_y=2.0 / (p[1, 1] * h))


def moment_params(shadow_map: ShadowMap, *, storage: int = int(mm.STORAGE4_FLOAT32), channels: int = 1,
                  depth_bias: float = 0.0, normal_offset_texels: float = 1.0,
                  overdarkening: float = float(mm.OVERDARKENING_DIVISOR),
                  exponents: tuple[float, float] = (0.0, 0.0)) -> MomentShadowParams:
    """Kernel parameters for lookups in a map with ``shadow_map``'s geometry.

    Args:
        shadow_map: the light's :class:`ShadowMap` (transforms and resolution).
        storage: one of :data:`.filterable.FORMATS`.
        exponents: EVSM (c+, c-) (:func:`.filterable.evsm_exponents`).
        channels: 1 or 3.
        depth_bias: scene units (>= 0) subtracted from the receiver's light-space depth.
        normal_offset_texels: receivers move this many texels (at their depth) along their normal (>= 0).
        overdarkening: shadow intensity divisor in (0, 1] (Sec. 2.6); 0 disables over-darkening.

    Raises:
        ValueError: negative or non-finite bias/offset, overdarkening outside [0, 1], unknown storage or channels.
    """
    _check_nonneg(depth_bias, "depth_bias")
    _check_nonneg(normal_offset_texels, "normal_offset_texels")
    if not (np.isfinite(overdarkening) and 0.0 <= overdarkening <= 1.0):
        raise ValueError(f"overdarkening: must lie in [0, 1] (0 disables it), got {overdarkening!r}")
    if int(storage) not in filterable.FORMATS.values():
        raise ValueError(f"storage: expected a format of filterable.FORMATS, got {storage!r}")
    if channels not in (1, 3):
        raise ValueError(f"channels: expected 1 or 3, got {channels!r}")
    g = map_geometry(shadow_map)
    p = MomentShadowParams()
    p.sm = shadow_map.params()
    p.depth_scale = float(g.depth_scale)
    p.depth_offset = float(g.depth_offset)
    p.near = float(g.near)
    p.texel_x = float(g.texel_x)
    p.texel_y = float(g.texel_y)
    p.storage = int(storage)
    p.exponents = wp.vec2(float(exponents[0]), float(exponents[1]))
    p.depth_bias = float(depth_bias)
    p.normal_offset = float(normal_offset_texels)
    p.overdarkening = float(overdarkening)
    p.channels = int(channels)
    p.mip_levels = 0
    return p


@dataclass
class MomentShadowMap:
    """A filterable shadow map on a device: 4-moment (Peters 2017) or another :mod:`.filterable` ``method``.

    Attributes:
        texels: (C, H, W) ``wp.vec4`` stored texel values; C = 1, or 3 for coloured translucency.
        bits: bits per texel and channel (:data:`.filterable.BITS_OF_METHOD`).
        shadow_map: the plain :class:`ShadowMap` whose transforms this map shares.
        mips: None, or the (C, N) mip chain of :func:`build_mip_chain`, levels packed (:func:`mip_level_offset`).
    """

    texels: wp.array
    bits: int
    shadow_map: ShadowMap
    geometry: MapGeometry
    supersampling: int
    translucent_layers: int = 0
    filter_px: int = 1
    mips: wp.array | None = None
    mip_levels: int = 0
    method: str = "msm"
    exponents: tuple[float, float] = (0.0, 0.0)

    @property
    def storage(self) -> int:
        """The format (:data:`.filterable.FORMATS`)."""
        return filterable.format_of(self.method, self.bits)

    @property
    def channels(self) -> int:
        return int(self.texels.shape[0])

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.texels.shape[1]), int(self.texels.shape[2])

    @property
    def nbytes(self) -> int:
        """Bytes of the texels and mip chain in the emulated format."""
        n = self.shape[0] * self.shape[1] + (int(self.mips.shape[1]) if self.mips is not None else 0)
        return self.channels * n * self.bits // 8

    def numpy(self) -> np.ndarray:
        """Texel values as a (C, H, W, 4) float32 array."""
        return self.texels.numpy().reshape(self.channels, *self.shape, 4)

    def params(self, *, depth_bias: float = 0.0, normal_offset_texels: float = 1.0,
               overdarkening: float = float(mm.OVERDARKENING_DIVISOR)) -> MomentShadowParams:
        """Kernel parameters for the look-ups (arguments as in :func:`moment_params`)."""
        p = moment_params(self.shadow_map, storage=self.storage, channels=self.channels, depth_bias=depth_bias,
                          normal_offset_texels=normal_offset_texels, overdarkening=overdarkening,
                          exponents=self.exponents)
        p.mip_levels = int(self.mip_levels)
        return p

    def mip_arrays(self, device=None) -> wp.array:
        """The mip chain, or a (C, 1) placeholder."""
        if self.mips is not None:
            return self.mips
        return wp.zeros((self.channels, 1), dtype=wp.vec4, device=default_device(device))


def _check_nonneg(x, name: str) -> None:
    if not (np.isscalar(x) and np.isfinite(x) and x >= 0.0):
        raise ValueError(f"{name}: must be a finite number >= 0, got {x!r}")


def channel_opacities(opacity, albedo, coloured: bool = False) -> np.ndarray:
    """Per-material, per-channel opacities alpha_c for the over operator (Peters 2017, Sec. 3.3); ValueError for bad
    shapes or values.

    Args:
        opacity: (K,) material opacities in [0, 1].
        albedo: (K, 3) material albedos in [0, 1] (used when ``coloured``).
        coloured: False: one channel, alpha_c = alpha. True: R, G, B with T_c = (1 - alpha) ** s_c,
            s_c = (1 - a_c) / (1 - mean(a)) (1 for grey albedos), alpha_c = 1 - T_c.

    Returns:
        (K, C) float32, C = 1 or 3; opaque materials (alpha = 1) give 1 in every channel.
    """
    a = np.asarray(opacity, np.float64).reshape(-1)
    if not np.all(np.isfinite(a)) or np.any(a < 0.0) or np.any(a > 1.0):
        raise ValueError(f"opacity: material opacities must lie in [0, 1], got {a.tolist()}")
    if not coloured:
        return a[:, None].astype(np.float32)
    rgb = np.asarray(albedo, np.float64)
    if rgb.shape != (a.size, 3) or not np.all(np.isfinite(rgb)) or np.any(rgb < 0.0) or np.any(rgb > 1.0):
        raise ValueError(f"albedo: expected ({a.size}, 3) values in [0, 1] for coloured translucency, got {rgb!r}")
    absorbed = 1.0 - rgb
    mean = absorbed.mean(axis=1, keepdims=True)
    grey = np.ptp(rgb, axis=1, keepdims=True) < 1e-6
    share = np.where(grey | (mean < 1e-6), 1.0, absorbed / np.maximum(mean, 1e-6))
    with np.errstate(divide="ignore"):
        transmittance = np.where(a[:, None] >= 1.0, 0.0, (1.0 - a[:, None]) ** share)
    return (1.0 - transmittance).astype(np.float32)


def _light_depth_mapping(shadow_map: ShadowMap, geom: MapGeometry) -> LightDepthMapping:
    p = np.asarray(shadow_map.projection, np.float64)
    d = LightDepthMapping()
    d.proj = wp.vec4(float(p[2, 2]), float(p[2, 3]), float(p[3, 2]), float(p[3, 3]))
    d.depth_scale = float(geom.depth_scale)
    d.depth_offset = float(geom.depth_offset)
    return d


def _translucent_band(trans_ndc: wp.array, trans_tri: wp.array, n_layers: int, row0: int,
                      trans_alpha: wp.array) -> TranslucentBand:
    band = TranslucentBand()
    band.trans_ndc = trans_ndc
    band.trans_tri = trans_tri
    band.n_layers = int(n_layers)
    band.row0 = int(row0)
    band.trans_alpha = trans_alpha
    return band


def generate_moment_shadow_map(scene, shadow_map: ShadowMap, *, supersampling: int = 2, bits: int = 64,
                               coloured: bool = False, max_translucent_layers: int = 16, method: str = "msm",
                               evsm_exponents=None, device=None) -> MomentShadowMap:
    """Moment shadow map of ``scene``'s casters in ``shadow_map``'s light view (D.1, D.3), unfiltered.

    Args:
        scene: the :class:`~warpscatter.scene.Scene` (``opacity``/``albedo`` per material, ``tri_material``).
        shadow_map: the plain map from :func:`~warpscatter.shadows.shadow_map.render_shadow_map`; its view,
            projection and resolution define the moment map.
        supersampling: s >= 1 samples per texel per axis, their moments averaged.
        bits: 64 (Theta_4*, 16-bit unorm, Sec. 2.4) or 128 (float32, Sec. 2.3); :data:`.filterable.BITS_OF_METHOD`.
        coloured: one map per colour channel (Sec. 3.3); otherwise monochrome.
        max_translucent_layers: most translucent fragments blended per sample; beyond, the farthest are dropped.
        method: ``msm`` (Peters 2017), or the baselines ``msm2015``, ``vsm``, ``evsm`` (:mod:`.filterable`).
        evsm_exponents: EVSM (c+, c-); None: Peters 2017 Fig. 4's for the storage.
        device: Warp device.

    Raises:
        ValueError: unknown ``bits``, bad supersampling or layer count, opacities outside [0, 1].
    """
    device = default_device(device)
    storage = filterable.format_of(method, bits)
    exponents = filterable.evsm_exponents(bits, evsm_exponents) if method == "evsm" else (0.0, 0.0)
    s = _check_int(supersampling, "supersampling", 1, MAX_SUPERSAMPLING)
    max_layers = _check_int(max_translucent_layers, "max_translucent_layers", 1)
    h, w = shadow_map.shape
    if s * max(h, w) > MAX_RESOLUTION:
        raise ValueError(f"supersampling: {s} x {max(h, w)} texels exceeds the rasterizer's {MAX_RESOLUTION}")
    scene = scene.casters()
    geom = map_geometry(shadow_map)
    alpha = channel_opacities(scene.opacity, scene.albedo, coloured)
    channels = alpha.shape[1]
    tri_mat = np.asarray(scene.tri_material, np.int64)
    if tri_mat.shape != (scene.triangle_count,) or (tri_mat.size and (tri_mat.min() < 0 or
                                                                       tri_mat.max() >= alpha.shape[0])):
        raise ValueError("scene.tri_material: expected one valid material index per triangle")
    tri_alpha = alpha[tri_mat]
    opaque = np.asarray(scene.opacity, np.float64)[tri_mat] >= OPAQUE_ALPHA
    translucent = ~opaque & (tri_alpha.max(axis=1, initial=0.0) >= float(ALPHA_TEST))
    view_proj = shadow_map.view_projection
    sw, sh = s * w, s * h
    clamp = not shadow_map.perspective
    if np.any(opaque):
        opaque_ndc = rasterize(scene.vertices, scene.triangles[opaque], view_proj, sw, sh, clamp_depth=clamp,
                               device=device).device_ndc_depth
    else:
        opaque_ndc = wp.full((1, sh, sw), np.inf, dtype=wp.float32, device=device)
    texels = wp.empty((channels, h, w), dtype=wp.vec4, device=device)
    dummy_ndc = wp.full((1, 1, 1), np.inf, dtype=wp.float32, device=device)
    dummy_tri = wp.full((1, 1, 1), -1, dtype=wp.int32, device=device)
    depth = _light_depth_mapping(shadow_map, geom)
    if not np.any(translucent):
        band = _translucent_band(dummy_ndc, dummy_tri, 0, 0, wp.zeros((1, channels), dtype=wp.float32, device=device))
        launch_rows(_generate_kernel, (h, w), [opaque_ndc, band, s, depth, int(storage), wp.vec2(*exponents), texels],
                    device=device, min_chunk=_MIN_ROWS)
        return MomentShadowMap(texels=texels, bits=bits, shadow_map=shadow_map, geometry=geom, supersampling=s,
                               method=method, exponents=exponents)
    tris = scene.triangles[translucent]
    trans_alpha = wp.array(np.ascontiguousarray(tri_alpha[translucent]), dtype=wp.float32, device=device)
    layers = 0
    for y0, y1, k, r in peel_row_bands(scene.vertices, tris, view_proj, sw, sh, max_layers=max_layers, row_multiple=s,
                                       clamp_depth=clamp, device=device):
        layers = max(layers, k)
        trans_ndc, trans_tri = (dummy_ndc, dummy_tri) if r is None else (r.device_ndc_depth, r.device_tri_id)
        band = _translucent_band(trans_ndc, trans_tri, k, y0 // s, trans_alpha)
        launch_rows(_generate_kernel, ((y1 - y0) // s, w),
                    [opaque_ndc, band, s, depth, int(storage), wp.vec2(*exponents), texels], device=device,
                    min_chunk=_MIN_ROWS)
    return MomentShadowMap(texels=texels, bits=bits, shadow_map=shadow_map, geometry=geom, supersampling=s,
                           translucent_layers=layers, method=method, exponents=exponents)


def filter_moment_shadow_map(msm: MomentShadowMap, filter_px: int, device=None) -> MomentShadowMap:
    """A new :class:`MomentShadowMap`: ``msm``'s texels blurred by a two-pass separable Gaussian (D.2)
    ``filter_px`` texels wide (:func:`gaussian_weights`; 1 returns ``msm`` itself)."""
    device = default_device(device)
    weights = gaussian_weights(filter_px)
    if len(weights) // 2 == 0:
        return msm
    return replace(msm, texels=gaussian_filter_texels(msm.texels, weights, msm.storage, device),
                   filter_px=int(filter_px))


def build_mip_chain(msm: MomentShadowMap, device=None) -> MomentShadowMap:
    """Full mip chain of the texels by 2x2 box averages (D.2; :func:`build_mip_levels`); returns a new map."""
    mips, levels = build_mip_levels(msm.texels, msm.storage, device)
    return replace(msm, mips=mips, mip_levels=levels)


def render_moment_shadow_map(scene, shadow_map: ShadowMap, *, supersampling: int = 2, bits: int = 64,
                             filter_px: int = 5, coloured: bool = False, max_translucent_layers: int = 16,
                             mipmap: bool = False, method: str = "msm", evsm_exponents=None,
                             timer: StageTimer | None = None, device=None) -> MomentShadowMap:
    """Generate, filter and optionally mip a moment shadow map (stages ``msm_generate``, ``msm_filter``,
    ``msm_mipmap``); arguments as in :func:`generate_moment_shadow_map` and :func:`filter_moment_shadow_map`."""
    stage = timer or StageTimer()
    with stage("msm_generate"):
        msm = generate_moment_shadow_map(scene, shadow_map, supersampling=supersampling, bits=bits,
                                         coloured=coloured, max_translucent_layers=max_translucent_layers,
                                         method=method, evsm_exponents=evsm_exponents, device=device)
    with stage("msm_filter"):
        msm = filter_moment_shadow_map(msm, filter_px, device=device)
    if not mipmap:
        return msm
    with stage("msm_mipmap"):
        return build_mip_chain(msm, device=device)


def point_arrays(points, normals, device):
    """(shape, points, normals) as flat ``wp.vec3`` arrays; normals default to zero, broadcast to points."""
    p = np.asarray(points, np.float32)
    if p.ndim < 1 or p.shape[-1] != 3:
        raise ValueError(f"points: expected an array of shape (..., 3), got {p.shape}")
    shape = p.shape[:-1]
    n = np.zeros_like(p) if normals is None else np.asarray(normals, np.float32)
    try:
        n = np.broadcast_to(n, p.shape)
    except ValueError:
        raise ValueError(f"normals: shape {np.shape(normals)} does not broadcast to points {p.shape}") from None
    return (shape, wp.array(np.ascontiguousarray(p.reshape(-1, 3)), dtype=wp.vec3, device=device),
            wp.array(np.ascontiguousarray(n.reshape(-1, 3)), dtype=wp.vec3, device=device))


def msm_visibility_at(msm: MomentShadowMap, points, normals=None, *, depth_bias: float = 0.0,
                      normal_offset_texels: float = 0.0, overdarkening: float = float(mm.OVERDARKENING_DIVISOR),
                      device=None) -> np.ndarray:
    """Host wrapper of :func:`msm_visibility_rgb` at world points (tests, bench): (..., C) float32 visibilities in
    [0, 1] (C = msm.channels).

    Args:
        msm: the (filtered) map.
        points: (..., 3) world positions.
        normals: (..., 3) receiver normals for the normal offset (default: none).
        depth_bias, normal_offset_texels, overdarkening: see :func:`moment_params`.
        device: Warp device.
    """
    device = default_device(device)
    shape, pts, nrm = point_arrays(points, normals, device)
    params = msm.params(depth_bias=depth_bias, normal_offset_texels=normal_offset_texels,
                        overdarkening=overdarkening)
    out = wp.zeros(pts.shape[0], dtype=wp.vec3, device=device)
    launch_rows(_visibility_points_kernel, pts.shape[0], [params, msm.texels, pts, nrm, out], device=device,
                min_chunk=1024)
    return out.numpy()[:, : msm.channels].reshape(*shape, msm.channels)


def msm_visibility_footprint_at(msm: MomentShadowMap, points, dx, dy, normals=None, *, depth_bias: float = 0.0,
                                normal_offset_texels: float = 0.0,
                                overdarkening: float = float(mm.OVERDARKENING_DIVISOR), device=None) -> np.ndarray:
    """Host wrapper of :func:`msm_visibility_rgb_footprint` (trilinear look-ups when ``msm`` has a mip chain).

    Args:
        msm: the (filtered) map, with a mip chain from :func:`build_mip_chain` (without one: bilinear).
        points: (..., 3) world positions.
        dx, dy: (..., 3) world vectors spanning each receiver's footprint (broadcast to points).
        normals, depth_bias, normal_offset_texels, overdarkening, device: as in :func:`msm_visibility_at`.
    """
    device = default_device(device)
    shape, pts, nrm = point_arrays(points, normals, device)
    dxa = point_arrays(points, dx, device)[2]
    dya = point_arrays(points, dy, device)[2]
    params = msm.params(depth_bias=depth_bias, normal_offset_texels=normal_offset_texels,
                        overdarkening=overdarkening)
    out = wp.zeros(pts.shape[0], dtype=wp.vec3, device=device)
    launch_rows(_visibility_footprint_kernel, pts.shape[0],
                [params, msm.texels, msm.mip_arrays(device), pts, nrm, dxa, dya, out], device=device, min_chunk=1024)
    return out.numpy()[:, : msm.channels].reshape(*shape, msm.channels)
