"""The epipole fallback of the prefiltered methods: ray-march the pixels around an epipole in view (Klehm et al.
2014 Sec. 5, Fig. 8).

Where the light (or its flip) projects into the view the non-linear rectification's slices all meet, precision is low
and light bleeds into a ring. The pixels whose view ray lies within an angle of the light direction (or its flip), at
least Klehm's block of ``epipole_block`` pixels, are ray-marched with shadow-map visibility and blended linearly in
the angle with the prefiltered result over a band of ``EPIPOLE_BLEND`` times that radius (an angle keeps the region
the same at every resolution). The march (:func:`~warpscatter.scattering.marching.march_transmittance_strata`) puts
its strata at equal shares of the transmittance weight and reads the map with 2 x 2 PCF; the directional look-up
skips the pixels inside the inner cones (:func:`wholly_marched`). Why: docs/benchmarks.md, "The epipole fallback".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from ...runtime.device import module_options
from ...runtime.parallel import launch_rows
from ...scene.camera import CameraParams, pixel_ray_direction
from ...scene.lights import LIGHT_SPOT
from ..epipolar.textures import compact
from ..marching import (
    Marcher,
    march_to_surface,
    march_transmittance_strata,
    marcher_params,
    pixel_end_normal,
    visibility_params,
)
from ..raymarch import march_listed_pixels
from ..settings import EVALUATE_DEPTH_TOLERANCE
from ..sparse_evaluation import PixelSet, evaluate_sparse, set_pixel

module_options()

#: Width of the blend band beyond the ray-marched disc, relative to its radius.
EPIPOLE_BLEND = 0.25


@wp.kernel
def epipole_march_kernel(
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    axis: wp.vec3,  # unit direction of the epipole from the camera (-L for the light, +L for its flip)
    cos_outer: float,  # cos of the outer radius of the blend band
    marcher: Marcher,  # shadow-map visibility, ``steps`` strata, ``jitter``
    x0: int,  # pixel rectangle origin (column, row): pixel (j, i) of ``marched`` is image pixel (y0 + j, x0 + i)
    y0: int,
    marched: wp.array2d(dtype=wp.vec3),  # out: the region's marched radiance (0 beyond the blend band)
    pixels: PixelSet,  # the region's pixels to march (sparse_evaluation)
    offset: int,
):
    # Klehm 2014 Sec. 5, Fig. 8: ray-march where the epipolar slices converge
    a, b = wp.tid()
    lj, li, listed = set_pixel(pixels, marched.shape[0], marched.shape[1], a + offset, b)
    if not listed:
        return
    j = lj + y0
    i = li + x0
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    v = wp.vec3(0.0, 0.0, 0.0)
    if wp.dot(d, axis) > cos_outer:
        if marcher.light.kind == LIGHT_SPOT:  # a spot: the general marcher (the strata need parallel light rays)
            v = march_to_surface(marcher, cam.position, d, distance[j, i], pixel_end_normal(marcher, i, j),
                                 j * cam.width + i)
        else:
            v = march_transmittance_strata(marcher, cam.position, d, distance[j, i], pixel_end_normal(marcher, i, j),
                                           j * cam.width + i)
    marched[lj, li] = v


@wp.kernel
def epipole_blend_kernel(
    cam: CameraParams,
    axis: wp.vec3,
    cos_inner: float,  # cos of the fully ray-marched angular radius
    cos_outer: float,  # cos of the outer radius of the blend band (<= cos_inner)
    x0: int,
    y0: int,
    marched: wp.array2d(dtype=wp.vec3),  # the region's marched radiance (epipole_march_kernel)
    out: wp.array2d(dtype=wp.vec3),  # in: the prefiltered image; out: blended with the march in the region
    offset: int,
):
    # a linear blend in the angle between the inner and outer radius hides the seam (Klehm 2014 Sec. 5)
    lj, li = wp.tid()
    lj += offset
    j = lj + y0
    i = li + x0
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    c = wp.dot(d, axis)
    if c > cos_outer:
        w = float(1.0)
        if c < cos_inner:
            psi = wp.acos(wp.clamp(c, -1.0, 1.0))
            psi_in = wp.acos(cos_inner)
            psi_out = wp.acos(cos_outer)
            w = (psi_out - psi) / wp.max(psi_out - psi_in, 1.0e-12)
        out[j, i] = marched[lj, li] * w + out[j, i] * (1.0 - w)


@wp.struct
class MarchedCones:
    """The inner cones of up to two :class:`EpipoleRegion` as kernels see them (:func:`marched_cones`): a pixel whose
    view ray lies in one takes the ray-marched result alone (:func:`wholly_marched`)."""

    count: int  # regions (0-2)
    axis0: wp.vec3
    cos0: float  # cos of the region's inner radius (epipole_blend_kernel's cos_inner)
    rect0: wp.vec4i  # the region's launch rectangle: x0, y0, x1, y1 (exclusive)
    axis1: wp.vec3
    cos1: float
    rect1: wp.vec4i


@wp.func
def in_marched_cone(axis: wp.vec3, cos_inner: float, rect: wp.vec4i, d: wp.vec3, i: int, j: int) -> bool:
    """Whether epipole_blend_kernel gives pixel (i, j) with view direction d the weight 1 (the same test)."""
    return i >= rect[0] and j >= rect[1] and i < rect[2] and j < rect[3] and wp.dot(d, axis) >= cos_inner


@wp.func
def wholly_marched(cones: MarchedCones, d: wp.vec3, i: int, j: int) -> bool:
    """Whether :func:`march_epipole_regions` will replace pixel (i, j)'s value (view direction d, as
    :func:`~warpscatter.scene.camera.pixel_ray_direction` gives it) by its ray-marched one, whatever it was."""
    if cones.count > 0 and in_marched_cone(cones.axis0, cones.cos0, cones.rect0, d, i, j):
        return True
    return cones.count > 1 and in_marched_cone(cones.axis1, cones.cos1, cones.rect1, d, i, j)


@dataclass(frozen=True)
class EpipoleRegion:
    """A ray-marched region around an epipole in view (Klehm 2014 Sec. 5, Fig. 8): view rays within ``inner_deg`` of
    ``axis`` are marched, blended up to ``outer_deg``; ``rect`` (x0, y0, w, h) bounds those pixels."""

    name: str  # "light" (axis -L) or "anti-light" (axis +L)
    axis: tuple[float, float, float]  # unit direction of the epipole from the camera (world)
    inner_deg: float
    outer_deg: float
    rect: tuple[int, int, int, int]


def _pixel_angle_deg(camera, block: int) -> float:
    """Angle (degrees) subtended by ``block / 2`` pixels at the image centre (a pixel size -> angle conversion)."""
    t = np.tan(np.radians(camera.fov_y) / 2.0)
    return float(np.degrees(np.arctan(t * block / camera.height)))


def _cone_rect(camera, axis: np.ndarray, angle_deg: float, stride: int = 4) -> tuple[int, int, int, int] | None:
    """Pixel rectangle (x0, y0, w, h) bounding the view rays within ``angle_deg`` of ``axis``, or None: found on every
    ``stride``-th pixel with angle and rectangle widened by ``stride`` (conservative for cones over a few pixels)."""
    d = camera.ray_directions(stride)
    margin = _pixel_angle_deg(camera, 2 * stride)
    rows, cols = np.nonzero(d @ axis > np.cos(np.radians(min(angle_deg + margin, 180.0))))
    if len(rows) == 0:
        return None
    x0 = max(int(cols.min()) * stride - stride, 0)
    y0 = max(int(rows.min()) * stride - stride, 0)
    x1 = min(int(cols.max()) * stride + 2 * stride, camera.width)
    y1 = min(int(rows.max()) * stride + 2 * stride, camera.height)
    return (x0, y0, x1 - x0, y1 - y0)


def epipole_regions(camera, light_direction, angle_deg: float, block: int = 0,
                    blend: float = EPIPOLE_BLEND) -> list[EpipoleRegion]:
    """One :class:`EpipoleRegion` per epipole ("light", "anti-light": its flip) whose cone meets the image (none when
    both radii are 0): ``angle_deg`` the marched disc's angular radius (degrees), at least ``block / 2`` pixels at the
    image centre (Klehm's block side; 0: none); outer radius inner * (1 + ``blend``). ``light_direction``: unit, the
    way the light travels."""
    inner = max(float(angle_deg), _pixel_angle_deg(camera, block) if block > 0 else 0.0)
    if inner <= 0.0:
        return []
    outer = min(inner * (1.0 + blend), 89.0)
    inner = min(inner, outer)
    regions = []
    for sign, name in ((-1.0, "light"), (1.0, "anti-light")):
        axis = sign * np.asarray(light_direction, float)
        axis = axis / np.linalg.norm(axis)
        rect = _cone_rect(camera, axis, outer)
        if rect is not None:
            regions.append(EpipoleRegion(name, tuple(float(a) for a in axis), inner, outer, rect))
    return regions


def epipole_pixel_fraction(camera, regions: list[EpipoleRegion], stride: int = 4) -> float:
    """Fraction of the image's pixels inside the regions' outer cones (ray-marched), estimated on every
    ``stride``-th pixel."""
    if not regions:
        return 0.0
    d = camera.ray_directions(stride)
    inside = np.zeros(d.shape[:2], bool)
    for r in regions:
        inside |= d @ np.asarray(r.axis) > np.cos(np.radians(r.outer_deg))
    return float(inside.mean())


def _cos_inner(region: EpipoleRegion) -> float:
    """The cosine epipole_region_kernel compares with (as the kernel receives it: float32)."""
    return float(np.float32(np.cos(np.radians(region.inner_deg))))


def marched_cones(regions: list[EpipoleRegion]) -> MarchedCones:
    """:class:`MarchedCones` of at most two regions (:func:`epipole_regions` gives one per epipole)."""
    if len(regions) > 2:
        raise ValueError(f"at most two epipole regions (one per epipole), got {len(regions)}")
    cones = MarchedCones()
    cones.count = len(regions)
    cones.axis0 = cones.axis1 = wp.vec3(0.0, 0.0, 0.0)
    cones.cos0 = cones.cos1 = 2.0
    cones.rect0 = cones.rect1 = wp.vec4i(0, 0, 0, 0)
    for k, r in enumerate(regions):
        x0, y0, w, h = r.rect
        setattr(cones, f"axis{k}", wp.vec3(*r.axis))
        setattr(cones, f"cos{k}", _cos_inner(r))
        setattr(cones, f"rect{k}", wp.vec4i(int(x0), int(y0), int(x0 + w), int(y0 + h)))
    return cones


def march_epipole_regions(scene, gbuffer, shadow_map, regions: list[EpipoleRegion], out: wp.array, *, steps: int,
                          seed: int, shadow_bias_texels: float, jitter: str = "per_pixel", stride: int = 1,
                          tolerance: float = 0.0, device=None) -> float:
    """Ray-march the pixels of ``regions`` into ``out`` (``steps`` equal-weight strata), blended with the prefiltered
    values there over each blend band; ``stride`` > 1 marches a grid and the pixels it cannot interpolate
    (:func:`~warpscatter.scattering.sparse_evaluation.evaluate_sparse`, radiance ``tolerance``). Returns the share of
    the regions' pixels marched (1.0 with stride 1 or no region)."""
    cam = scene.camera
    vis = visibility_params(scene, "shadow_map", None, shadow_map, shadow_bias_texels, device)
    marcher = marcher_params(scene, steps=steps, visibility=vis, seed=seed, jitter=jitter, end_normals=gbuffer.normal,
                             device=device)
    marched_pixels = total = 0
    for r in regions:
        x0, y0, w, h = r.rect
        axis, cos_outer = wp.vec3(*r.axis), float(np.cos(np.radians(r.outer_deg)))
        marched = wp.empty((h, w), dtype=wp.vec3, device=device)
        distance = gbuffer.distance[y0:y0 + h, x0:x0 + w]  # a view: the region's camera distances for the grid's tests

        def march(pixels, dim, x0=x0, y0=y0, axis=axis, cos_outer=cos_outer, marched=marched):
            launch_rows(epipole_march_kernel, dim, [cam.params(), gbuffer.distance, axis, cos_outer, marcher, int(x0),
                                                     int(y0), marched, pixels], device=device)

        sparse = evaluate_sparse(march, distance, marched, stride, tolerance, EVALUATE_DEPTH_TOLERANCE, device=device)
        launch_rows(epipole_blend_kernel, (h, w), [cam.params(), axis, _cos_inner(r), cos_outer, int(x0), int(y0),
                                                   marched, out], device=device)
        marched_pixels += sparse.evaluated
        total += h * w
    return marched_pixels / total if total else 1.0


def march_flagged_pixels(scene, gbuffer, shadow_map, flags: wp.array, out: wp.array, *, steps: int, seed: int,
                         shadow_bias_texels: float, jitter: str, device=None) -> int:
    """Ray-march the pixels of non-zero ``flags`` (H, W int32) into ``out`` as the disc does; returns how many."""
    cam = scene.camera
    indices, count = compact(flags.reshape((cam.height * cam.width,)), device)
    if count:
        vis = visibility_params(scene, "shadow_map", None, shadow_map, shadow_bias_texels, device)
        marcher = marcher_params(scene, steps=steps, visibility=vis, seed=seed, jitter=jitter,
                                 end_normals=gbuffer.normal, device=device)
        march_listed_pixels(cam, gbuffer.distance, marcher, indices, count, out, equal_weight_strata=True,
                            device=device)
    return count


def epipole_weights(camera, regions: list[EpipoleRegion]) -> np.ndarray:
    """(H, W) float32 weight of the ray-marched result per pixel, as :func:`epipole_blend_kernel` blends (the
    ``epipole_mask`` debug output)."""
    d = camera.ray_directions(1)
    w = np.zeros(d.shape[:2], np.float32)
    for r in regions:
        psi = np.degrees(np.arccos(np.clip(d @ np.asarray(r.axis), -1.0, 1.0)))
        band = max(r.outer_deg - r.inner_deg, 1e-12)
        w = np.maximum(w, np.clip((r.outer_deg - psi) / band, 0.0, 1.0).astype(np.float32))
    return w


__all__ = ["EPIPOLE_BLEND", "EpipoleRegion", "epipole_blend_kernel", "epipole_march_kernel", "epipole_pixel_fraction",
           "epipole_regions",
           "epipole_weights", "march_epipole_regions", "march_flagged_pixels"]
