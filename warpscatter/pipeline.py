"""Config → scene → raster → technique stages → composition → files, with per-stage timings.

:func:`render` is what ``warpscatter render`` runs. Each stage is a library function taking arrays
and parameters (never the config); this module is the only place that reads the config and hands
each stage what it needs. Stage names appear in the CLI's timing table, in ``bench`` and in logs:

``scene`` (load/generate meshes) · ``compile`` (Warp kernel modules; apart from the work itself) ·
``upload`` (device arrays) · ``bvh`` (``wp.Mesh``, exact visibility only) · ``gbuffer`` (camera) ·
``shadow_map`` (light) · ``scattering`` (the selected method) · ``shading`` (surfaces + composition) ·
``write`` (EXR/PNG files). With ``render.lighting.method`` set (``csm`` / ``raytrace``, Monte-Carlo direct
lighting, :mod:`warpscatter.csm.render`): ``csm`` or ``bvh`` (occluder visibility) · ``gbuffer`` · ``lighting``
(progressive passes, the outputs rewritten every ``write_every`` passes) · ``write``.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import warp as wp

from .config import SCATTERING_METHODS as METHODS  # the methods the pipeline runs (render.scattering.method)
from .wpinit import default_device, init

ProgressFn = Callable[[str, float], None]


@dataclass
class RenderResult:
    """What a render produced: images (name → float32 array), written files, stage timings (s), stats."""

    images: dict[str, np.ndarray]
    files: list[Path] = field(default_factory=list)
    timings: "OrderedDict[str, float]" = field(default_factory=OrderedDict)
    stats: dict = field(default_factory=dict)


class StageTimer:
    """Times named stages in order and reports progress to an optional callback."""

    def __init__(self, progress: ProgressFn | None = None):
        self.timings: OrderedDict[str, float] = OrderedDict()
        self.progress = progress

    def __call__(self, name: str):
        timer = self

        class _Scope:
            def __enter__(self):
                if timer.progress:
                    timer.progress(name, 0.0)
                self.t0 = time.perf_counter()
                return self

            def report(self, fraction: float) -> None:
                """Progress inside the stage (0..1)."""
                if timer.progress:
                    timer.progress(name, fraction)

            def __exit__(self, *exc):
                wp.synchronize()
                timer.timings[name] = timer.timings.get(name, 0.0) + time.perf_counter() - self.t0
                if timer.progress and exc[0] is None:
                    timer.progress(name, 1.0)
                return False

        return _Scope()


def kernel_modules() -> list:
    """The warpscatter modules holding kernels a render launches (compiled in the ``compile`` stage)."""
    from . import gbuffer, raster, shading
    from .scattering import epipolar, prefilter, prefiltered, raymarch, rectify
    from .shadows import msm, soft

    return [raster, gbuffer, raymarch, rectify, prefilter, prefiltered, epipolar, msm, soft, shading]


def compile_kernels(device=None) -> None:
    """Compile (or load from Warp's cache) every kernel module a render uses."""
    device = default_device(device)
    for m in kernel_modules():
        wp.load_module(m, device=device)


def render_images(scene, render_cfg, *, timer: StageTimer | None = None, device=None) -> tuple[dict, dict]:
    """Run the render stages for a built scene.

    Args:
        scene: a :class:`~warpscatter.scene.Scene`.
        render_cfg: the validated ``render`` section (method, visibility, steps, shadow map, shadows, surfaces).
        timer: a :class:`StageTimer` (created if None).
        device: Warp device.

    Returns:
        (images, stats): images as in :func:`warpscatter.shading.shade_and_compose`; stats with sizes.
    """
    from .gbuffer import gbuffer_raster, gbuffer_raycast
    from .scattering.epipolar import EpipolarSettings, render_epipolar
    from .scattering.prefiltered import PrefilteredSettings, render_prefiltered
    from .scattering.raymarch import raymarch
    from .scene import DeviceGeometry
    from .shading import ShadowSettings, prepare_shadows, shade_and_compose
    from .shadows.shadow_map import render_shadow_map

    device = default_device(device)
    timer = timer or StageTimer()
    sc = render_cfg.scattering
    if render_cfg.lighting.method is not None:
        raise ValueError("render.lighting.method is set: Monte-Carlo lighting runs through render() or "
                         "warpscatter.csm.render.render_lighting, not render_images")
    if sc.method not in METHODS:
        raise ValueError(f"render.scattering.method: unknown method {sc.method!r} (choose from {', '.join(METHODS)})")
    exact = sc.method == "raymarch" and sc.visibility == "exact"  # the reference: ray-cast everything
    marches_exact = sc.method in ("raymarch", "epipolar") and sc.visibility == "exact"
    shadows_on = render_cfg.surfaces.enabled and render_cfg.shadows.method != "none"
    need_shadow_map = shadows_on or not marches_exact

    with timer("compile"):
        compile_kernels(device)
    with timer("upload"):
        geometry = DeviceGeometry(scene, device)
    if marches_exact:
        with timer("bvh"):
            _ = geometry.mesh
    with timer("gbuffer"):
        gbuf = gbuffer_raycast(scene, geometry, device) if exact else gbuffer_raster(scene, geometry, device)
    shadow_map = None
    if need_shadow_map:
        with timer("shadow_map"):
            shadow_map = render_shadow_map(scene, sc.shadow_map.resolution, device=device)
    info = {}
    if sc.method == "raymarch":
        with timer("scattering") as stage:
            l_scat = raymarch(scene, gbuf, steps=sc.steps, visibility=sc.visibility, geometry=geometry,
                              shadow_map=shadow_map, seed=sc.seed, jitter=sc.jitter,
                              shadow_bias_texels=sc.shadow_map.bias,
                              progress=stage.report, device=device)
    elif sc.method == "epipolar":
        l_scat, info = render_epipolar(scene, gbuf, settings=EpipolarSettings(**sc.epipolar.model_dump()),
                                       steps=sc.steps, visibility=sc.visibility, geometry=geometry,
                                       shadow_map=shadow_map, seed=sc.seed, jitter=sc.jitter,
                                       shadow_bias_texels=sc.shadow_map.bias,
                                       timer=timer, device=device)
    else:
        p, f, mo = sc.prefiltered, sc.fourier, sc.moments
        settings = PrefilteredSettings(basis=sc.method, coefficients=f.coefficients, bits=f.storage_bits,
                                       moment_storage_bits=mo.storage_bits, overestimation=mo.overestimation,
                                       weighting=p.weighting, reference_ray=p.reference_ray,
                                       guard_band=p.guard_band, epipole_block=p.epipole_block,
                                       epipole_angle_deg=p.epipole_angle_deg, epipole_steps=sc.steps,
                                       rectification=p.rectification, epipole_margin=p.epipole_margin,
                                       regions=p.regions, projective_weights=p.projective_weights, splits=p.splits,
                                       resample_filter=p.resample_filter, resample_filter_px=p.resample_filter_px,
                                       caster_culling=p.caster_culling, caster_culling_bias=p.caster_culling_bias)
        l_scat, info = render_prefiltered(scene, gbuf, shadow_map, map_size=sc.shadow_map.size, settings=settings,
                                          seed=sc.seed, shadow_bias_texels=sc.shadow_map.bias, timer=timer,
                                          device=device)
    shadows = None
    if shadows_on:
        sh = render_cfg.shadows
        settings = ShadowSettings(method=sh.method, filter_px=sh.filter_px, bias_texels=sc.shadow_map.bias,
                                  storage=sh.storage, supersampling=sh.supersampling, coloured=sh.coloured,
                                  max_translucent_layers=sh.max_translucent_layers,
                                  light_angle_deg=sh.light_angle_deg, light_size=sh.light_size,
                                  max_kernel_px=sh.max_kernel_px, sampling=sh.sampling)
        shadows = prepare_shadows(scene, shadow_map, settings, timer=timer, device=device)
        info.update(shadows.info)
    with timer("shading"):
        images = shade_and_compose(scene, gbuf, l_scat, shadows=shadows, surfaces=render_cfg.surfaces.enabled,
                                   device=device)
    stats = {
        "triangles": scene.triangle_count,
        "resolution": [scene.camera.width, scene.camera.height],
        "method": sc.method,
        "visibility": sc.visibility if sc.method in ("raymarch", "epipolar") else None,
        "steps": sc.steps,
        **info,
        "shadow_map": list(shadow_map.shape[::-1]) if shadow_map is not None else None,
    }
    for name, img in images.items():
        if not np.all(np.isfinite(img)):
            raise FloatingPointError(f"{name} image has non-finite pixels (a bug: please report it)")
    return images, stats


def render(config, out_dir: Path | None = None, progress: ProgressFn | None = None, device=None,
           write: bool = True) -> RenderResult:
    """Render a validated :class:`~warpscatter.config.Config` and write its images.

    Args:
        config: the validated config.
        out_dir: output folder (default ``config.output.dir``).
        progress: optional ``progress(stage, fraction)`` callback.
        device: Warp device (default: ``WARPSCATTER_DEVICE`` or cpu).
        write: False skips the ``write`` stage (images are still returned).

    Returns:
        :class:`RenderResult` with images, written files, per-stage timings and stats.
    """
    from .imageio import write_outputs
    from .scene import build_scene

    init()
    timer = StageTimer(progress)
    with timer("scene"):
        scene = build_scene(config)
    out = Path(out_dir) if out_dir is not None else Path(config.output.dir)
    if config.render.lighting.method is not None:  # Monte-Carlo direct lighting (csm / raytrace), progressive
        from .csm.render import render_lighting

        def on_pass(images, done, total):  # rewrite the outputs as the image converges
            if write:
                with timer("write"):
                    write_outputs(out, config.output.name, images, config.output.aovs, config.output.exposure)

        images, stats = render_lighting(config, scene, timer=timer, on_pass=on_pass, device=device)
    else:
        images, stats = render_images(scene, config.render, timer=timer, device=device)
    files: list[Path] = []
    if write:
        with timer("write"):
            files = write_outputs(out, config.output.name, images, config.output.aovs, config.output.exposure)
    return RenderResult(images=images, files=files, timings=timer.timings, stats=stats)
