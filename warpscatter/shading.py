"""Surface shading and composition (CONVENTIONS.md).

Surfaces are Lambertian: L_surface = albedo / pi * E(x) * max(0, dot(n, -omega_l)) * V_shadow(x),
with n the camera-facing normal from the G-buffer and V_shadow (RGB, for tinted translucent
occluders) from the selected shadow method:

* ``pcf`` — percentage-closer filtering of the light's shadow map;
* ``msm`` — a filtered 4-moment shadow map with translucent occluders (Peters 2017 Sec. 2-3);
* ``msm_soft`` — moment soft shadows from an integer summed-area table (Peters 2017 Sec. 4);
* ``pcss`` — the brute-force soft-shadow reference (blocker search + PCF) for ``msm_soft``;
* ``none`` — V = 1.

The seen radiance is L_surface * exp(-sigma_t s) + L_scat.

AOVs returned by :func:`shade_and_compose` (all (H, W, 3) float32 linear RGB, row 0 = top):
``surface`` = L_surface * exp(-sigma_t s) (zero where no surface), ``scattering`` = L_scat,
``color`` = their sum.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from .parallel import launch_rows
from .scene.camera import CameraParams, pixel_ray_direction
from .scene.lights import LightParams, light_params, light_sample, light_texture_array
from .shadows import msm, soft
from .shadows.shadow_map import ShadowMapParams, shadow_pcf
from .wpinit import default_device, module_options

module_options()

#: Shadow methods as the shading kernel knows them.
SHADOW_METHODS = {"none": 0, "pcf": 1, "msm": 2, "msm_soft": 3, "pcss": 4}


@dataclass(frozen=True)
class ShadowSettings:
    """Surface-shadow parameters (see the module docstring and ``render.shadows`` in the README).

    Attributes:
        method: ``none`` | ``pcf`` | ``msm`` | ``msm_soft`` | ``pcss``.
        filter_px: PCF box / MSM Gaussian width (texels).
        bias_texels: depth bias in texel sizes.
        storage: MSM bits per texel, 64 or 128 (``msm_soft`` uses 128).
        supersampling: depth samples per texel and axis of the moment map.
        coloured: one moment map per RGB channel (tinted translucency).
        max_translucent_layers: translucent layers peeled into the moment map.
        light_angle_deg: directional lights' angular size (full angle, degrees) for the soft methods.
        light_size: spot lights' size (scene units) for the soft methods.
        max_kernel_px: soft methods' widest region side (texels).
        sampling: MSM look-ups: ``bilinear`` (level 0) or ``mipmap`` (trilinear in a mip chain at the level of each
            pixel's footprint in shadow-map texels; Peters 2017 D.2).
    """

    method: str = "pcf"
    filter_px: int = 3
    bias_texels: float = 1.0
    storage: int = 64
    supersampling: int = 2
    coloured: bool = False
    max_translucent_layers: int = 16
    light_angle_deg: float = 1.0
    light_size: float = 0.5
    max_kernel_px: int = 28
    sampling: str = "bilinear"


#: MSM look-ups of ``render.shadows.sampling``.
SHADOW_SAMPLING = ("bilinear", "mipmap")


@dataclass
class ShadowInputs:
    """Per-frame arrays and parameters of every shadow method (dummies for the ones not selected)."""

    mode: int
    sm: ShadowMapParams
    sm_depth: wp.array
    sm_bias: float
    filter_px: int
    msm: msm.MomentShadowParams
    msm_texels: wp.array
    msm_mips: wp.array  # mip chain of the moment map ((C, 1) placeholder without one)
    soft: soft.SoftShadowParams
    sat: wp.array
    info: dict


def prepare_shadows(scene, shadow_map, settings: ShadowSettings, *, timer=None, device=None) -> ShadowInputs:
    """Build what the selected shadow method reads per pixel (moment maps and tables get their own stages)."""
    device = default_device(device)
    if settings.method not in SHADOW_METHODS:
        raise ValueError(f"shadow method must be one of {', '.join(SHADOW_METHODS)}, got {settings.method!r}")
    if settings.sampling not in SHADOW_SAMPLING:
        raise ValueError(f"shadow sampling must be one of {', '.join(SHADOW_SAMPLING)}, got {settings.sampling!r}")
    mode = SHADOW_METHODS[settings.method] if shadow_map is not None else 0
    if shadow_map is not None:
        sm_params, sm_depth = shadow_map.params(), shadow_map.device_depth(device)
        bias = settings.bias_texels * shadow_map.texel_world
    else:
        sm_params, sm_depth, bias = ShadowMapParams(), wp.zeros((1, 1), dtype=wp.float32, device=device), 0.0
        sm_params.width = sm_params.height = 1
    inputs = ShadowInputs(mode=mode, sm=sm_params, sm_depth=sm_depth, sm_bias=float(bias),
                          filter_px=int(settings.filter_px), msm=msm.MomentShadowParams(),
                          msm_texels=wp.zeros((1, 1, 1), dtype=wp.vec4, device=device),
                          msm_mips=wp.zeros((1, 1), dtype=wp.vec4, device=device),
                          soft=soft.SoftShadowParams(), sat=wp.zeros((1, 1, 1), dtype=wp.vec4ui, device=device),
                          info={"shadows": settings.method if mode else "none"})
    size = {"light_size": settings.light_size} if shadow_map is not None and shadow_map.perspective else {
        "light_angle_deg": settings.light_angle_deg}
    if mode == SHADOW_METHODS["msm"]:
        m = msm.render_moment_shadow_map(scene, shadow_map, supersampling=settings.supersampling,
                                         bits=settings.storage, filter_px=settings.filter_px,
                                         coloured=settings.coloured,
                                         max_translucent_layers=settings.max_translucent_layers,
                                         mipmap=settings.sampling == "mipmap", timer=timer, device=device)
        inputs.msm, inputs.msm_texels, inputs.msm_mips = m.params(depth_bias=bias), m.texels, m.mip_arrays(device)
        inputs.info.update(msm_bits=m.bits, msm_bytes=m.nbytes, translucent_layers=m.translucent_layers,
                           msm_sampling=settings.sampling)
    elif mode == SHADOW_METHODS["msm_soft"]:
        table = soft.render_soft_shadow_map(scene, shadow_map, supersampling=settings.supersampling,
                                            max_kernel_px=settings.max_kernel_px, coloured=settings.coloured,
                                            max_translucent_layers=settings.max_translucent_layers, timer=timer,
                                            device=device)
        inputs.soft, inputs.sat = table.params(depth_bias=bias, **size), table.table
        inputs.info.update(sat_bytes=table.nbytes, translucent_layers=table.msm.translucent_layers)
    elif mode == SHADOW_METHODS["pcss"]:
        inputs.soft = soft.soft_shadow_params(shadow_map, max_kernel_px=settings.max_kernel_px, depth_bias=bias,
                                              **size)
    return inputs


@wp.func
def pixel_footprint(cam: CameraParams, i: int, j: int, x: wp.vec3, n: wp.vec3):
    """World vectors from x to where the rays of pixels (i + 1, j) and (i, j + 1) meet x's tangent plane (normal n):
    the receiver's pixel footprint for mip-level selection. Rays (nearly) parallel to the plane or meeting it
    behind the camera fall back to the footprint of a plane facing the camera at x's distance."""
    o = cam.position
    d0 = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    dist = wp.length(x - o)
    num = wp.dot(x - o, n)
    footprint = wp.vec3(0.0)
    fy = wp.vec3(0.0)
    for k in range(2):
        d = pixel_ray_direction(cam, float(i) + 1.5, float(j) + 0.5)
        if k == 1:
            d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 1.5)
        den = wp.dot(d, n)
        t = float(-1.0)
        if wp.abs(den) > 1.0e-6:
            t = num / den
        e = d * (dist / wp.max(wp.dot(d, d0), 1.0e-6)) - (x - o)  # fallback: camera-facing plane
        if t > 0.0 and t < 1.0e3 * dist:
            e = o + d * t - x
        if k == 0:
            footprint = e
        else:
            fy = e
    return footprint, fy


@wp.func
def surface_visibility(mode: int, x: wp.vec3, n: wp.vec3, sm: ShadowMapParams,
                       sm_depth: wp.array2d(dtype=wp.float32), sm_bias: float, filter_px: int,
                       mp: msm.MomentShadowParams, msm_texels: wp.array3d(dtype=wp.vec4),
                       msm_mips: wp.array2d(dtype=wp.vec4), dx: wp.vec3, dy: wp.vec3, sp: soft.SoftShadowParams,
                       sat: wp.array3d(dtype=wp.vec4ui)) -> wp.vec3:
    """RGB light visibility of surface point x (camera-facing normal n, pixel footprint dx, dy) for shadow method
    ``mode``."""
    if mode == 1:
        # normal offset of one texel keeps lit surfaces out of their own shadow
        return wp.vec3(shadow_pcf(sm, sm_depth, x + n * sm.texel_world, sm_bias, filter_px))
    if mode == 2:
        return msm.msm_visibility_rgb_footprint(mp, msm_texels, msm_mips, x, n, dx, dy)
    if mode == 3:
        return soft.moment_soft_visibility_rgb(sp, sat, x, n)
    if mode == 4:
        return wp.vec3(soft.pcss_visibility(sp, sm_depth, x, n))
    return wp.vec3(1.0, 1.0, 1.0)


@wp.func
def lambert(albedo: wp.vec3, e: wp.vec3, n: wp.vec3, omega_l: wp.vec3) -> wp.vec3:
    """Lambertian reflected radiance albedo/pi * E * max(0, n . -omega_l) (omega_l: travel direction)."""
    c = wp.max(0.0, -wp.dot(n, omega_l))
    return wp.cw_mul(albedo, e) * (c / wp.pi)


@wp.kernel
def shade_kernel(
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    normal: wp.array2d(dtype=wp.vec3),
    material: wp.array2d(dtype=wp.int32),
    albedo: wp.array(dtype=wp.vec3),
    light: LightParams,
    light_tex: wp.array2d(dtype=wp.vec3),
    sigma_t: float,
    shadow_mode: int,
    sm: ShadowMapParams,
    sm_depth: wp.array2d(dtype=wp.float32),
    sm_bias: float,
    filter_px: int,
    mp: msm.MomentShadowParams,
    msm_texels: wp.array3d(dtype=wp.vec4),
    msm_mips: wp.array2d(dtype=wp.vec4),
    sp: soft.SoftShadowParams,
    sat: wp.array3d(dtype=wp.vec4ui),
    scattering: wp.array2d(dtype=wp.vec3),
    surface_out: wp.array2d(dtype=wp.vec3),
    color_out: wp.array2d(dtype=wp.vec3),
    offset: int,
):
    j, i = wp.tid()
    j += offset
    surf = wp.vec3(0.0, 0.0, 0.0)
    m = material[j, i]
    if m >= 0:
        d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
        s = distance[j, i]
        n = normal[j, i]
        x = cam.position + d * s
        e, omega, dist = light_sample(light, light_tex, x)
        v = wp.vec3(1.0, 1.0, 1.0)
        if shadow_mode != 0 and wp.dot(n, omega) < 0.0:
            dx = wp.vec3(0.0)
            dy = wp.vec3(0.0)
            if shadow_mode == 2 and mp.mip_levels > 0:
                dx, dy = pixel_footprint(cam, i, j, x, n)
            v = surface_visibility(shadow_mode, x, n, sm, sm_depth, sm_bias, filter_px, mp, msm_texels, msm_mips, dx,
                                   dy, sp, sat)
        surf = wp.cw_mul(lambert(albedo[m], e, n, omega), v) * wp.exp(-sigma_t * s)
    surface_out[j, i] = surf
    color_out[j, i] = surf + scattering[j, i]


def shade_and_compose(scene, gbuffer, scattering: wp.array, *, shadows: ShadowInputs | None = None,
                      surfaces: bool = True, device=None) -> dict[str, np.ndarray]:
    """Shade surfaces and add the in-scattered radiance.

    Args:
        scene: the :class:`~warpscatter.scene.Scene`.
        gbuffer: the camera :class:`~warpscatter.gbuffer.GBuffer`.
        scattering: (H, W) vec3 L_scat.
        shadows: :class:`ShadowInputs` from :func:`prepare_shadows` (None: no shadows).
        surfaces: False renders surfaces black (only L_scat remains).
        device: Warp device.

    Returns:
        dict with ``color``, ``surface``, ``scattering`` (H, W, 3) float32 and ``depth`` (H, W) float32.
    """
    device = default_device(device)
    cam = scene.camera
    h, w = cam.height, cam.width
    surface = wp.zeros((h, w), dtype=wp.vec3, device=device)
    color = wp.zeros((h, w), dtype=wp.vec3, device=device)
    if surfaces:
        sh = shadows or prepare_shadows(scene, None, ShadowSettings(method="none"), device=device)
        albedo = wp.array(scene.albedo, dtype=wp.vec3, device=device)
        launch_rows(shade_kernel, (h, w),
                    [cam.params(), gbuffer.distance, gbuffer.normal, gbuffer.material, albedo,
                     light_params(scene.light), light_texture_array(scene.light, device),
                     float(scene.medium.sigma_t), sh.mode, sh.sm, sh.sm_depth, sh.sm_bias, sh.filter_px, sh.msm,
                     sh.msm_texels, sh.msm_mips, sh.soft, sh.sat, scattering, surface, color], device=device)
        color_np = color.numpy()
    else:
        color_np = scattering.numpy()
    return {
        "color": np.ascontiguousarray(color_np, dtype=np.float32),
        "surface": np.ascontiguousarray(surface.numpy(), dtype=np.float32),
        "scattering": np.ascontiguousarray(scattering.numpy(), dtype=np.float32),
        "depth": np.ascontiguousarray(gbuffer.distance.numpy(), dtype=np.float32),
    }
