"""The ``raymarch`` render method: reference single scattering by per-pixel ray marching.

Every pixel's ray, from the camera to its G-buffer hit distance, is marched with the estimator of :mod:`.marching`.
With ``visibility: exact`` (and a ray-cast G-buffer) this is the ground truth every fast method is measured against;
``visibility: shadow_map`` is the simple marcher they must beat at equal error. Stage: ``scattering``.
"""

from __future__ import annotations

import warp as wp

from ..runtime.device import default_device, module_options
from ..runtime.parallel import launch_rows
from ..runtime.stages import StageTimer
from ..scene.camera import CameraParams, pixel_ray_direction
from .marching import (
    Marcher,
    march_ray,
    march_transmittance_strata,
    marcher_params,
    pixel_end_normal,
    visibility_params,
)

module_options()


@wp.kernel
def raymarch_kernel(
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    marcher: Marcher,
    x0: int,  # pixel region origin (column, row); the launch covers the region's rows x columns
    y0: int,
    out: wp.array2d(dtype=wp.vec3),
    offset: int,
):
    j, i = wp.tid()
    j += offset + y0
    i += x0
    out[j, i] = march_ray(cam, i, j, distance[j, i], marcher)


@wp.kernel
def raymarch_subset_kernel(
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    marcher: Marcher,
    stride: int,  # every stride-th pixel in x and y, from (first, first)
    first: int,
    out: wp.array2d(dtype=wp.vec3),  # (ceil((H - first) / stride), ceil((W - first) / stride))
    offset: int,
):
    sj, si = wp.tid()
    sj += offset
    i = first + si * stride
    j = first + sj * stride
    out[sj, si] = march_ray(cam, i, j, distance[j, i], marcher)


@wp.kernel
def raymarch_listed_kernel(
    indices: wp.array(dtype=wp.int32),  # flat pixel indices j * width + i
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    marcher: Marcher,
    equal_weight_strata: int,  # 1: strata of equal transmittance weight (march_transmittance_strata), else march_ray
    out: wp.array2d(dtype=wp.vec3),
    offset: int,
):
    n = wp.tid() + offset
    flat = indices[n]
    j = flat // cam.width
    i = flat - j * cam.width
    if equal_weight_strata != 0:
        d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
        out[j, i] = march_transmittance_strata(marcher, cam.position, d, distance[j, i],
                                               pixel_end_normal(marcher, i, j), flat)
    else:
        out[j, i] = march_ray(cam, i, j, distance[j, i], marcher)


def march_listed_pixels(camera, distance: wp.array, marcher: Marcher, indices: wp.array, count: int, out: wp.array, *,
                        equal_weight_strata: bool = False, device=None) -> None:
    """Ray-march the first ``count`` pixels of ``indices`` (flat j * width + i) into ``out``: the same values as
    :func:`march_pixels` there, or with ``equal_weight_strata`` the epipole disc's strata of equal transmittance weight
    (:func:`~.marching.march_transmittance_strata`; directional lights)."""
    if count:
        launch_rows(raymarch_listed_kernel, int(count),
                    [indices, camera.params(), distance, marcher, int(bool(equal_weight_strata)), out],
                    device=default_device(device))


def march_pixel_subset(camera, distance: wp.array, marcher: Marcher, stride: int, first: int = 0, report=None,
                       device=None) -> wp.array:
    """(ceil((H - first) / stride), ceil((W - first) / stride)) L_scat of every ``stride``-th pixel in x and y from
    pixel (first, first): :func:`march_pixels`' values there (same random streams), for references on a subset."""
    device = default_device(device)
    if not (isinstance(stride, int) and stride >= 1 and 0 <= first < stride):
        raise ValueError(f"stride must be an integer >= 1 and first in [0, stride), got {stride}, {first}")
    h = -(-(camera.height - first) // stride)
    w = -(-(camera.width - first) // stride)
    out = wp.zeros((h, w), dtype=wp.vec3, device=device)
    launch_rows(raymarch_subset_kernel, (h, w), [camera.params(), distance, marcher, int(stride), int(first), out],
                device=device, progress=report)
    return out


def march_pixels(camera, distance: wp.array, marcher: Marcher, *, region=None, out: wp.array | None = None,
                 report=None, device=None) -> wp.array:
    """(H, W) vec3 L_scat (linear RGB) of the camera's pixels, ray-marched with ``marcher`` to the G-buffer's
    ``distance``: all of them, or the pixel rectangle ``region`` (x0, y0, width, height) of ``out`` (allocated when
    None); ``report(fraction)`` follows the rows done."""
    device = default_device(device)
    if out is None:
        out = wp.zeros((camera.height, camera.width), dtype=wp.vec3, device=device)
    x0, y0, w, h = region if region is not None else (0, 0, camera.width, camera.height)
    if not (0 <= x0 and 0 <= y0 and w >= 0 and h >= 0 and x0 + w <= camera.width and y0 + h <= camera.height):
        raise ValueError(f"region {region} must lie inside the {camera.width}x{camera.height} image")
    launch_rows(raymarch_kernel, (h, w), [camera.params(), distance, marcher, int(x0), int(y0), out], device=device,
                progress=report)
    return out


def render(frame, settings, stage: StageTimer | None = None) -> tuple[wp.array, dict]:
    """The ``raymarch`` method (the registry's call shape, :mod:`warpscatter.methods`): ((H, W) vec3 L_scat, {}) of a
    :class:`~warpscatter.pipeline.frame.Frame` (its G-buffer, and the BVH or the light's shadow map) with the
    :class:`~warpscatter.scattering.settings.ScatteringSettings` marching keys."""
    stage = stage or StageTimer()
    scene = frame.scene
    vis = visibility_params(scene, settings.visibility, frame.geometry, frame.shadow_map, settings.shadow_map.bias,
                            frame.device)
    marcher = marcher_params(scene, steps=settings.march_steps, visibility=vis, seed=settings.seed,
                             jitter=settings.march_jitter, end_normals=frame.gbuffer.normal, device=frame.device)
    with stage("scattering") as s:
        out = march_pixels(scene.camera, frame.gbuffer.distance, marcher, report=s.report, device=frame.device)
    return out, {}


__all__ = ["march_listed_pixels", "march_pixel_subset", "march_pixels", "raymarch_kernel", "raymarch_listed_kernel",
           "raymarch_subset_kernel", "render"]
