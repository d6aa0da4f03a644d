"""Surface shading and composition (CONVENTIONS.md).

Lambertian surfaces: L_surface = albedo / pi * E(x) * max(0, dot(n, -omega_l)) * V_shadow(x), V_shadow (RGB) from the
surface shadow method; seen radiance L_surface * exp(-sigma_t s) + L_scat per channel. AOVs (float32, row 0 = top):
``surface``, ``scattering``, ``color`` (their sum), ``depth`` (the G-buffer distance).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .raster.gbuffer import GBufferArrays
from .runtime.device import default_device, module_options
from .runtime.parallel import launch_rows
from .scene.camera import CameraParams, pixel_ray_direction
from .scene.lights import LightParams, light_params, light_sample
from .scene.medium import MediumParams, view_transmittance
from .shadows.surface import SHADOW_MSM, SHADOW_NONE, SurfaceShadows, no_shadows, surface_visibility

module_options()


@wp.func
def pixel_footprint(cam: CameraParams, i: int, j: int, x: wp.vec3, n: wp.vec3):
    """World vectors from x to where the rays of pixels (i + 1, j) and (i, j + 1) meet x's tangent plane: the pixel
    footprint for mip selection (a camera-facing plane where the rays graze)."""
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
def lambert(albedo: wp.vec3, e: wp.vec3, n: wp.vec3, omega_l: wp.vec3) -> wp.vec3:
    """Lambertian reflected radiance albedo/pi * E * max(0, n . -omega_l) (omega_l: travel direction)."""
    c = wp.max(0.0, -wp.dot(n, omega_l))
    return wp.cw_mul(albedo, e) * (c / wp.pi)


@wp.kernel
def shade_kernel(
    cam: CameraParams,
    gbuf: GBufferArrays,
    albedo: wp.array(dtype=wp.vec3),  # per material
    light: LightParams,
    med: MediumParams,
    shadows: SurfaceShadows,
    scattering: wp.array2d(dtype=wp.vec3),
    surface_out: wp.array2d(dtype=wp.vec3),
    color_out: wp.array2d(dtype=wp.vec3),
    offset: int,
):
    j, i = wp.tid()
    j += offset
    surf = wp.vec3(0.0, 0.0, 0.0)
    m = gbuf.material[j, i]
    if m >= 0:
        d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
        s = gbuf.distance[j, i]
        n = gbuf.normal[j, i]
        x = cam.position + d * s
        e, omega, dist = light_sample(light, x)
        v = wp.vec3(1.0, 1.0, 1.0)
        if shadows.mode != SHADOW_NONE and wp.dot(n, omega) < 0.0:
            dx = wp.vec3(0.0)
            dy = wp.vec3(0.0)
            if shadows.mode == SHADOW_MSM and shadows.msm.mip_levels > 0:
                dx, dy = pixel_footprint(cam, i, j, x, n)
            v = surface_visibility(shadows, x, n, dx, dy)
        if med.coloured == 0:
            surf = wp.cw_mul(lambert(albedo[m], e, n, omega), v) * wp.exp(-med.sigma_t * s)
        else:
            surf = wp.cw_mul(wp.cw_mul(lambert(albedo[m], e, n, omega), v), view_transmittance(med, s))
    surface_out[j, i] = surf
    color_out[j, i] = surf + scattering[j, i]


def ambient_radiance(scene, gbuffer, ambient) -> np.ndarray | None:
    """The sky fill of every surface pixel: albedo * L_ambient * exp(-sigma_t s), (H, W, 3) float32, or None when
    ``ambient`` is zero. Unshadowed; the cosine integral of a uniform sky gives albedo * L_ambient."""
    ambient = np.asarray(ambient, dtype=np.float32)
    if not ambient.any():
        return None
    material = gbuffer.material.numpy()
    # per material its albedo * L_ambient, and a last row of zeros for the pixels that hit nothing (material -1)
    fill = np.vstack([np.asarray(scene.albedo, np.float32) * ambient, np.zeros((1, 3), np.float32)])[material]
    sigma_t = np.asarray(scene.medium.sigma_t_rgb, np.float32)
    return fill * np.exp(-sigma_t * gbuffer.distance.numpy()[..., None])


def shade_and_compose(scene, gbuffer, scattering: wp.array, *, shadows: SurfaceShadows | None = None,
                      surfaces: bool = True, device=None) -> dict[str, np.ndarray]:
    """Shade surfaces and add the in-scattered radiance.

    Args:
        scene: the :class:`~warpscatter.scene.Scene`.
        gbuffer: the camera :class:`~.raster.gbuffer.GBuffer`.
        scattering: (H, W) vec3 L_scat.
        shadows: :class:`~warpscatter.shadows.surface.SurfaceShadows` from
            :func:`~warpscatter.shadows.surface.prepare_shadows` (None: no shadows).
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
        albedo = wp.array(scene.albedo, dtype=wp.vec3, device=device)
        launch_rows(shade_kernel, (h, w),
                    [cam.params(), gbuffer.arrays(), albedo, light_params(scene.light, device),
                     scene.medium.params(), shadows if shadows is not None else no_shadows(device), scattering,
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


__all__ = ["ambient_radiance", "lambert", "pixel_footprint", "shade_and_compose", "shade_kernel"]
