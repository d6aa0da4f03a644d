"""Surface shading and composition (CONVENTIONS.md).

Surfaces are Lambertian: L_surface = albedo / pi * E(x) * max(0, dot(n, -omega_l)) * V_shadow(x),
with n the camera-facing normal from the G-buffer and V_shadow a PCF-filtered shadow-map lookup
(or 1 with shadows off). The seen radiance is L_surface * exp(-sigma_t s) + L_scat.

AOVs returned by :func:`shade_and_compose` (all (H, W, 3) float32 linear RGB, row 0 = top):
``surface`` = L_surface * exp(-sigma_t s) (zero where no surface), ``scattering`` = L_scat,
``color`` = their sum.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .parallel import launch_rows
from .scene.camera import CameraParams, pixel_ray_direction
from .scene.lights import LightParams, light_params, light_sample, light_texture_array
from .shadows.shadow_map import ShadowMapParams, shadow_pcf
from .wpinit import default_device, module_options

module_options()


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
    shadows_on: int,
    sm: ShadowMapParams,
    sm_depth: wp.array2d(dtype=wp.float32),
    sm_bias: float,
    filter_px: int,
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
        v = float(1.0)
        if shadows_on != 0 and wp.dot(n, omega) < 0.0:
            # normal offset of one texel keeps lit surfaces out of their own shadow
            v = shadow_pcf(sm, sm_depth, x + n * sm.texel_world, sm_bias, filter_px)
        surf = lambert(albedo[m], e, n, omega) * (v * wp.exp(-sigma_t * s))
    surface_out[j, i] = surf
    color_out[j, i] = surf + scattering[j, i]


def shade_and_compose(scene, gbuffer, scattering: wp.array, *, shadow_map=None, filter_px: int = 3,
                      shadow_bias_texels: float = 1.0, surfaces: bool = True, device=None) -> dict[str, np.ndarray]:
    """Shade surfaces and add the in-scattered radiance.

    Args:
        scene: the :class:`~warpscatter.scene.Scene`.
        gbuffer: the camera :class:`~warpscatter.gbuffer.GBuffer`.
        scattering: (H, W) vec3 L_scat.
        shadow_map: the light's :class:`~warpscatter.shadows.shadow_map.ShadowMap`, or None for no shadows.
        filter_px: PCF kernel width in shadow-map texels (>= 1).
        shadow_bias_texels: depth bias in texel sizes.
        surfaces: False renders surfaces black (only L_scat remains).

    Returns:
        dict with ``color``, ``surface``, ``scattering`` (H, W, 3) float32 and ``depth`` (H, W) float32.
    """
    device = default_device(device)
    cam = scene.camera
    h, w = cam.height, cam.width
    surface = wp.zeros((h, w), dtype=wp.vec3, device=device)
    color = wp.zeros((h, w), dtype=wp.vec3, device=device)
    if surfaces:
        if shadow_map is not None:
            sm_params, sm_depth = shadow_map.params(), shadow_map.device_depth(device)
            bias, on = shadow_bias_texels * shadow_map.texel_world, 1
        else:
            sm_params = ShadowMapParams()
            sm_params.width = sm_params.height = 1
            sm_depth, bias, on = wp.zeros((1, 1), dtype=wp.float32, device=device), 0.0, 0
        albedo = wp.array(scene.albedo, dtype=wp.vec3, device=device)
        launch_rows(shade_kernel, (h, w),
                    [cam.params(), gbuffer.distance, gbuffer.normal, gbuffer.material, albedo,
                     light_params(scene.light), light_texture_array(scene.light, device),
                     float(scene.medium.sigma_t), on, sm_params, sm_depth, float(bias), int(filter_px), scattering,
                     surface, color], device=device)
        color_np = color.numpy()
    else:
        color_np = scattering.numpy()
    return {
        "color": np.ascontiguousarray(color_np, dtype=np.float32),
        "surface": np.ascontiguousarray(surface.numpy(), dtype=np.float32),
        "scattering": np.ascontiguousarray(scattering.numpy(), dtype=np.float32),
        "depth": np.ascontiguousarray(gbuffer.distance.numpy(), dtype=np.float32),
    }
