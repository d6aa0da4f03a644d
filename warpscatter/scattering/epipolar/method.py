"""The ``epipolar`` render method: epipolar sampling for crepuscular rays (Engelhardt & Dachsbacher 2010).

In-scattered light varies smoothly along epipolar lines (the screen images of planes through the camera and the
light) except at depth discontinuities, so it is ray-marched at sparse samples on them and interpolated elsewhere.
Stages (as in timings): ``lines`` (the lines, clipped, and their textures: :mod:`.lines`, :mod:`.textures`, Sec. 5.1),
``discontinuities`` (each texel's two interpolation sources, Sec. 5.2; texels that are their own source are marched),
``raymarch`` (those samples, with the reference marcher's estimator and ``steps_per_texel``) and ``interpolate``
(along the lines, then per pixel by a bilateral filter between the two nearest lines, Sec. 4.3, 5.3:
:mod:`.upsampling`; pixels without a valid tap are marched). With the epipole at infinity or undefined it falls back
to screen-space subsampling every ``fallback_stride`` pixels. Settings:
:class:`~warpscatter.scattering.settings.EpipolarSettings`.
"""

from __future__ import annotations

import logging

import numpy as np
import warp as wp

from ...runtime.device import default_device, module_options
from ...runtime.parallel import launch_rows
from ...runtime.stages import StageTimer
from ...scene.camera import CameraParams, pixel_ray_direction
from ...scene.lights import LIGHT_SPOT
from ..marching import Marcher, march_ray, march_screen_point, marcher_params, texel_steps, visibility_params
from ..raymarch import march_listed_pixels
from ..settings import EPIPOLAR_LEAST_STEPS
from ..sparse_evaluation import grid_node, grid_size
from .lines import epipolar_lines, light_texture_level
from .textures import (
    EpipolarGeometry,
    classify_samples,
    compact,
    geometry_params,
    line_samples,
    sample_texture_bytes,
    trim_to_cone,
)
from .upsampling import filter_params, grid_upsample_kernel, interpolate_lines_kernel, upsample

module_options()

logger = logging.getLogger("warpscatter")


#: Pixels around a spot light's epipole (its screen position, where in-scattering falls off like the inverse distance)
#: in which every line texel is ray-marched.
LOCAL_DENSE_RADIUS = 24.0
#: Pixels off a spot light's epipole at which the samples nearer to it are marched.
LOCAL_EPIPOLE_OFFSET = wp.constant(0.5)


@wp.kernel
def raymarch_samples_kernel(
    indices: wp.array(dtype=wp.int32),
    geo: EpipolarGeometry,
    coords: wp.array2d(dtype=wp.vec2),
    line_depth: wp.array2d(dtype=wp.float32),
    cam: CameraParams,
    marcher: Marcher,
    steps_per_texel: float,  # EpipolarSettings.steps_per_texel (texel_steps)
    least_steps: int,
    radiance: wp.array2d(dtype=wp.vec3),  # out: radiance texture at the ray-marching samples
    sample_steps: wp.array(dtype=wp.int32),  # out: the steps each sample took
    offset: int,
):
    n = wp.tid() + offset
    flat = indices[n]
    k = flat // geo.samples
    x = flat - k * geo.samples
    p = coords[k, x]
    if marcher.light.kind == LIGHT_SPOT and x + 1 < geo.samples:
        # a spot's epipole is the light itself, where in-scattering diverges: march from LOCAL_EPIPOLE_OFFSET out
        out = p - geo.epipole
        if wp.length(out) < LOCAL_EPIPOLE_OFFSET:
            along = coords[k, x + 1] - p
            if wp.length(along) > 0.0:
                p = geo.epipole + wp.normalize(along) * LOCAL_EPIPOLE_OFFSET
    s = line_depth[k, x]
    m = marcher
    m.steps = texel_steps(marcher, cam.position, pixel_ray_direction(cam, p[0], p[1]), s, steps_per_texel, least_steps)
    sample_steps[n] = m.steps
    radiance[k, x] = march_screen_point(cam, p[0], p[1], s, m)


@wp.kernel
def grid_raymarch_kernel(
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    stride: int,
    marcher: Marcher,
    steps_per_texel: float,
    least_steps: int,
    grid: wp.array2d(dtype=wp.vec3),  # out: L_scat at the grid nodes
    grid_steps: wp.array2d(dtype=wp.int32),  # out: the steps each node took
    offset: int,
):
    gj, gi = wp.tid()
    gj += offset
    i = grid_node(gi, stride, cam.width)
    j = grid_node(gj, stride, cam.height)
    s = distance[j, i]
    m = marcher
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    m.steps = texel_steps(marcher, cam.position, d, s, steps_per_texel, least_steps)
    grid_steps[gj, gi] = m.steps
    grid[gj, gi] = march_ray(cam, i, j, s, m)


@wp.kernel
def box_downsample_kernel(src: wp.array2d(dtype=wp.vec3), factor: int, out: wp.array2d(dtype=wp.vec3), offset: int):
    # light-texture prefiltering: mean of each factor x factor block (partial blocks at the far edges)
    j, i = wp.tid()
    j += offset
    acc = wp.vec3(0.0, 0.0, 0.0)
    n = float(0.0)
    for dj in range(factor):
        y = j * factor + dj
        if y < src.shape[0]:
            for di in range(factor):
                x = i * factor + di
                if x < src.shape[1]:
                    acc += src[y, x]
                    n += 1.0
    out[j, i] = acc / wp.max(n, 1.0)


def prefilter_light_texture(texture: np.ndarray, level: int, device=None) -> wp.array:
    """Box-downsample an (H, W, 3) linear RGB light texture (row 0 = top) by 2^level >= 1 to a
    (ceil(H / 2^level), ceil(W / 2^level)) vec3 array, the line spacing's mip level (Sec. 6)."""
    if level < 0:
        raise ValueError(f"level must be >= 0, got {level}")
    device = default_device(device)
    src = wp.array(np.ascontiguousarray(texture[..., :3], dtype=np.float32), dtype=wp.vec3, device=device)
    if level == 0:
        return src
    f = 2 ** level
    h, w = -(-texture.shape[0] // f), -(-texture.shape[1] // f)
    out = wp.empty((h, w), dtype=wp.vec3, device=device)
    launch_rows(box_downsample_kernel, (h, w), [src, f, out], device=device)
    return out


def marched_steps_image(width: int, height: int, samples: np.ndarray, sample_steps: np.ndarray, pixels: np.ndarray,
                        pixel_steps: int) -> np.ndarray:
    """The ``epipolar_samples`` debug output: (height, width) float32 ray-march steps per pixel (0: interpolated), from
    the marched ``samples`` (N, 2) screen positions and their ``sample_steps``, and the directly marched ``pixels``
    (flat indices), ``pixel_steps`` each; samples sharing a pixel add up."""
    img = np.zeros((height, width), np.float32)
    if len(samples):
        i = np.clip(np.floor(samples[:, 0]).astype(np.int64), 0, width - 1)
        j = np.clip(np.floor(samples[:, 1]).astype(np.int64), 0, height - 1)
        np.add.at(img, (j, i), np.asarray(sample_steps, np.float32))
    np.add.at(img.reshape(-1), np.asarray(pixels, np.int64), np.float32(pixel_steps))
    return img


def render(frame, settings, stage: StageTimer | None = None) -> tuple[wp.array, dict]:
    """Single scattering by epipolar sampling: the ``epipolar`` method (see the module doc; the registry's call
    shape, :mod:`warpscatter.methods`).

    Args:
        frame: :class:`~warpscatter.pipeline.frame.Frame` (directional or spot light): the G-buffer, and the BVH
            (``visibility: exact``) or the light's shadow map (``visibility: shadow_map``).
        settings: :class:`~warpscatter.scattering.settings.ScatteringSettings`; the marching keys as the reference
            marcher's (with the same steps a sample at a pixel centre reproduces its value), and ``epipolar``.
        stage: the :class:`~warpscatter.runtime.stages.StageTimer`.

    Returns:
        (L_scat, info): (H, W) vec3 linear RGB, and a dict of the ``epipolar_*`` counts and fractions, the epipole,
        ``epipolar_fallback`` (None or the reason) and, when asked, ``debug_images`` (:func:`marched_steps_image`).
    """
    stage = stage or StageTimer()
    device = default_device(frame.device)
    scene, gbuffer, ep = frame.scene, frame.gbuffer, settings.epipolar
    cam, light = scene.camera, scene.light
    if cam.width < 2 or cam.height < 2:
        raise ValueError(f"scene.camera: epipolar sampling needs an image of at least 2x2 pixels, got "
                         f"{cam.width}x{cam.height}")
    vis = visibility_params(scene, settings.visibility, frame.geometry, frame.shadow_map, settings.shadow_map.bias,
                            device)
    cam_p = cam.params()
    flt = filter_params(ep, device)
    h, w = cam.height, cam.width
    out = wp.empty((h, w), dtype=wp.vec3, device=device)
    line_count = ep.lines_for(w, h)
    info = {"epipolar_lines": line_count, "epipolar_initial_samples": ep.initial_samples}

    with stage("lines"):
        if ep.sampling == "screen":  # the naive baseline asked for (Engelhardt 2010 Fig. 9)
            lines, reason = None, "screen-space sampling asked (epipolar.sampling: screen)"
        else:
            lines, reason = epipolar_lines(cam, light, line_count, ep.initial_samples, ep.samples_per_line,
                                           ep.max_epipole_distance)
        if lines is not None:
            lines = trim_to_cone(lines, cam, light, device)
        level, footprint = (0, 0.0)
        texture = getattr(light, "texture", None)
        if lines is not None and ep.prefilter_light_texture and texture is not None:
            level, footprint = light_texture_level(lines, cam, light, texture.shape)
        marcher = marcher_params(scene, steps=settings.march_steps, visibility=vis, seed=settings.seed,
                                 jitter=settings.march_jitter, end_normals=gbuffer.normal, device=device,
                                 light_texture=prefilter_light_texture(texture, level, device) if level > 0 else None)
        if lines is not None:
            tex = line_samples(lines, gbuffer.distance, ep.depth_threshold, device)
    adaptive_steps = [float(ep.steps_per_texel), EPIPOLAR_LEAST_STEPS]  # texel_steps' per_texel and least
    info["epipolar_light_texture_level"] = level
    info["epipolar_light_texture_footprint"] = footprint

    if lines is None:
        # ---- degenerate case: plain screen-space subsampling ----
        if ep.sampling != "screen":
            logger.warning("epipolar sampling falls back to screen-space subsampling every %d px: %s",
                           ep.fallback_stride, reason)
        stride = ep.fallback_stride
        gw, gh = grid_size(w, stride), grid_size(h, stride)
        grid = wp.empty((gh, gw), dtype=wp.vec3, device=device)
        steps_taken = wp.empty((gh, gw), dtype=wp.int32, device=device)
        with stage("raymarch"):
            launch_rows(grid_raymarch_kernel, (gh, gw),
                        [cam_p, gbuffer.distance, int(stride), marcher, *adaptive_steps, grid, steps_taken],
                        device=device)
        with stage("interpolate"):
            unresolved = wp.empty(h * w, dtype=wp.int32, device=device)
            launch_rows(grid_upsample_kernel, (h, w),
                        [cam_p, gbuffer.distance, int(stride), grid, flt, out, unresolved], device=device)
        marched_samples = gw * gh
        info.update({"epipolar_fallback": reason, "epipolar_epipole": None, "epipolar_lines_valid": 0,
                     "epipolar_grid": [gw, gh]})
    else:
        geo = geometry_params(lines)
        upsample_stride = ep.upsample_stride_for(scene.light.kind == "spot")
        with stage("discontinuities"):
            dense = LOCAL_DENSE_RADIUS if scene.light.kind == "spot" and not lines.light_behind else 0.0
            classify_samples(lines, tex, ep.depth_threshold, device, dense_radius=dense)
            sample_idx, marched_samples = tex.samples, tex.sample_count
        steps_taken = wp.zeros(max(int(marched_samples), 1), dtype=wp.int32, device=device)
        with stage("raymarch"):
            if marched_samples:
                launch_rows(raymarch_samples_kernel, marched_samples,
                            [sample_idx, geo, tex.coords, tex.depth, cam_p, marcher, *adaptive_steps, tex.radiance,
                             steps_taken], device=device)
        with stage("interpolate"):
            launch_rows(interpolate_lines_kernel, lines.count, [tex.valid, tex.interp, tex.radiance], device=device)
            pixel_idx, marched_pixels, upsampled = upsample(cam, gbuffer.distance, marcher.light, geo, flt,
                                                            tex.arrays(), out, upsample_stride, device)
        info.update({"epipolar_fallback": None, "epipolar_epipole": [float(v) for v in lines.epipole],
                     "epipolar_light_behind": lines.light_behind, "epipolar_lines_valid": int(lines.valid.sum()),
                     "epipolar_samples_per_line": lines.samples,
                     "epipolar_upsample_stride": upsample_stride,
                     "epipolar_upsampled_fraction": round(upsampled, 4),
                     "epipolar_texture_bytes": sample_texture_bytes(lines)})

    with stage("raymarch"):
        if lines is None:
            pixel_idx, marched_pixels = compact(unresolved, device)
        march_listed_pixels(scene.camera, gbuffer.distance, marcher, pixel_idx, marched_pixels, out, device=device)
    if "epipolar_samples" in frame.aovs:
        if lines is None:
            gy, gx = np.mgrid[0:gh, 0:gw]
            xy = np.stack([np.minimum(gx * stride, w - 1), np.minimum(gy * stride, h - 1)], -1).reshape(-1, 2) + 0.5
        else:
            xy = tex.coords.numpy().reshape(-1, 2)[sample_idx.numpy()[:marched_samples]]
        info["debug_images"] = {"epipolar_samples": marched_steps_image(
            w, h, xy, steps_taken.numpy().reshape(-1)[:len(xy)], pixel_idx.numpy()[:marched_pixels], marcher.steps)}
    info.update({
        "epipolar_raymarched_samples": int(marched_samples),
        "epipolar_mean_sample_steps": float(steps_taken.numpy().mean()) if marched_samples else 0.0,
        "epipolar_raymarched_pixels": int(marched_pixels),
        "epipolar_raymarched_fraction": float((marched_samples + marched_pixels) / (w * h)),
    })
    return out, info


__all__ = [
    "grid_raymarch_kernel",
    "marched_steps_image",
    "prefilter_light_texture",
    "raymarch_samples_kernel",
    "render",
]
