"""The ``fourier`` render method: prefiltered single scattering on a rectified shadow map (Klehm 2014).

Stages (names as they appear in timings):

1. ``rectify``   — bounds of the non-linear epipolar rectification for this camera and light
   (Peters 2017 App. A) and resampling of the light's shadow map into it (Peters 2017 Sec. 5.1.1);
2. ``prefilter`` — Fourier basis of the rectified depth fused into per-row prefix sums, plain
   (Klehm Listing 1) or transmittance-weighted with the per-slice reference ray (Listing 2/3);
3. ``evaluate``  — per pixel: the G-buffer hit -> rectified (u, v, z_r) -> bilinear fetch of the
   filtered-basis vector -> dot with a(z_r) + 0.5, clamped -> times sigma_s f E (1 - e^{-sigma_t s}) / sigma_t
   (Klehm Listing 4); the cost per pixel is constant whatever the scene;
4. ``epipole``   — when the light (or its flip) projects into the view, the rectification's slices all
   meet there and precision is low (Klehm 2014 Sec. 5, Fig. 8): a block of pixels around each such
   epipole is ray-marched with shadow-map visibility instead.

Directional lights only (the rectification is built for parallel light rays).
"""

from __future__ import annotations

from contextlib import nullcontext
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..parallel import launch_rows
from ..scene.camera import CameraParams, pixel_ray_direction
from ..scene.lights import DirectionalLight, LightParams, light_params
from ..scene.medium import phase_eval, transmittance_integral
from ..wpinit import default_device, module_options
from .prefilter import prefilter_depth, prefiltered_visibility
from .raymarch import MediumParams, medium_params, raymarch
from .rectify import NonlinearRectification, NonlinearRectParams, reference_ray, resample_shadow_map, world_to_rectified

module_options()


@dataclass(frozen=True)
class FourierSettings:
    """Parameters of the ``fourier`` method.

    Attributes:
        coefficients: M, number of Fourier coefficients (even, 4..128).
        weighting: ``"transmittance"`` (Klehm Sec. 3.2, Listing 2) or ``"average"`` (Listing 1, Eq. 2).
        reference_ray: per-slice reference ray for the weights: ``"optimal"`` (k_ref = sqrt(k_min k_max)
            where defined, else bisectrix), ``"bisectrix"`` or ``"mean"``.
        bits: 0 stores float32 filtered bases; 8 emulates the paper's 8-bit normalised storage (App. A).
        guard_band: relative stretch of the inclination bounds (Peters 2017 uses 0.1).
        epipole_block: side in pixels of the ray-marched block around an epipole in view (0 disables).
        epipole_steps: ray-march steps inside that block.
    """

    coefficients: int = 32
    weighting: str = "transmittance"
    reference_ray: str = "optimal"
    bits: int = 0
    guard_band: float = 0.1
    epipole_block: int = 32
    epipole_steps: int = 64


@wp.kernel
def evaluate_fourier_kernel(
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    rect: NonlinearRectParams,
    filtered_basis: wp.array3d(dtype=wp.float32),
    light: LightParams,
    med: MediumParams,
    out: wp.array2d(dtype=wp.vec3),
    offset: int,
):
    # Klehm 2014 Listing 4: one filtered-basis fetch and one dot product per pixel
    j, i = wp.tid()
    j += offset
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    s = distance[j, i]
    x = cam.position + d * s
    c = world_to_rectified(rect, x)
    f = prefiltered_visibility(filtered_basis, c[0], c[1], c[2], rect.full_circle)
    phase = phase_eval(med.phase_id, med.g, wp.dot(light.direction, -d))
    out[j, i] = light.radiance * (med.sigma_s * phase * f * transmittance_integral(med.sigma_t, 0.0, s))


def epipole_pixels(camera, light_direction) -> list[tuple[float, float, str]]:
    """Image positions (x, y in pixels, y down) of the light's epipole and anti-epipole when they lie in front.

    The epipole is where rays towards the light (direction -L) meet the image; the anti-epipole is the
    vanishing point of the light's travel direction +L (anti-crepuscular rays converge there).
    """
    vp = camera.view_projection()
    out = []
    for sign, name in ((-1.0, "light"), (1.0, "anti-light")):
        c = vp @ np.append(sign * np.asarray(light_direction, float), 0.0)
        if c[3] <= 1e-9:
            continue
        x = (c[0] / c[3] * 0.5 + 0.5) * camera.width
        y = (0.5 - 0.5 * c[1] / c[3]) * camera.height
        out.append((float(x), float(y), name))
    return out


def epipole_regions(camera, light_direction, block: int) -> list[tuple[int, int, int, int, str]]:
    """Pixel rectangles (x0, y0, w, h, name) of side ``block`` centred on each epipole that touches the image."""
    regions = []
    if block <= 0:
        return regions
    for x, y, name in epipole_pixels(camera, light_direction):
        x0 = int(np.floor(x - block / 2))
        y0 = int(np.floor(y - block / 2))
        x1, y1 = x0 + block, y0 + block
        x0, y0 = max(x0, 0), max(y0, 0)
        x1, y1 = min(x1, camera.width), min(y1, camera.height)
        if x1 > x0 and y1 > y0:
            regions.append((x0, y0, x1 - x0, y1 - y0, name))
    return regions


def render_fourier(scene, gbuffer, shadow_map, *, map_size: tuple[int, int], settings: FourierSettings = None,
                   seed: int = 0, shadow_bias_texels: float = 1.0, timer=None, device=None):
    """Prefiltered single scattering with a Fourier basis (the ``fourier`` method; see the module doc).

    Args:
        scene: the :class:`~warpscatter.scene.Scene` (directional light).
        gbuffer: the camera :class:`~warpscatter.gbuffer.GBuffer` (rasterized).
        shadow_map: the light's :class:`~warpscatter.shadows.shadow_map.ShadowMap` (orthographic).
        map_size: (cols, rows) of the rectified map: texels along each view ray x epipolar slices.
        settings: :class:`FourierSettings`.
        seed: jitter seed of the epipole block's ray marching.
        shadow_bias_texels: shadow-map bias of the epipole block's ray marching.
        timer: optional callable ``timer(stage_name)`` returning a context manager (e.g. a pipeline StageTimer).
        device: Warp device.

    Returns:
        (L_scat, info): (H, W) vec3 wp.array and a dict describing the rectification and epipole blocks.
    """
    device = default_device(device)
    settings = settings or FourierSettings()
    if not isinstance(scene.light, DirectionalLight):
        raise ValueError("the fourier method needs a directional light (render.scattering.method)")
    if settings.weighting not in ("transmittance", "average"):
        raise ValueError(f"weighting must be 'transmittance' or 'average', got {settings.weighting!r}")
    stage = timer or (lambda name: nullcontext())
    cam = scene.camera
    cols, rows = map_size
    with stage("rectify"):
        rect = NonlinearRectification.from_camera(cam, scene.light.direction, guard_band=settings.guard_band,
                                                  rows=rows, cols=cols)
        rectified = resample_shadow_map(rect, shadow_map.depth, shadow_map.view_projection, depth="linear",
                                        world_to_view=shadow_map.view, device=device)
    with stage("prefilter"):
        tau = None
        if settings.weighting == "transmittance":
            tau = reference_ray(rect, settings.reference_ray).optical_steps(scene.medium.sigma_t)
        fb = prefilter_depth(rectified, settings.coefficients, tau, bits=settings.bits, device=device)
    with stage("evaluate"):
        out = wp.empty((cam.height, cam.width), dtype=wp.vec3, device=device)
        launch_rows(evaluate_fourier_kernel, (cam.height, cam.width),
                    [cam.params(), gbuffer.distance, rect.params(), fb, light_params(scene.light),
                     medium_params(scene.medium), out], device=device)
    regions = epipole_regions(cam, scene.light.direction, settings.epipole_block)
    if regions:
        with stage("epipole"):
            for x0, y0, w, h, _ in regions:
                raymarch(scene, gbuffer, steps=settings.epipole_steps, visibility="shadow_map", shadow_map=shadow_map,
                         seed=seed, shadow_bias_texels=shadow_bias_texels, region=(x0, y0, w, h), out=out,
                         device=device)
    info = {
        "rectification": "nonlinear",
        "rectified_map": [cols, rows],
        "full_circle": rect.full_circle,
        "coefficients": settings.coefficients,
        "filtered_basis_bytes": int(rows * cols * settings.coefficients * (1 if settings.bits == 8 else 4)),
        "epipole_blocks": [list(r[:4]) + [r[4]] for r in regions],
    }
    return out, info
