"""The classic pipeline: G-buffer, light shadow map, the scattering method, surface shadows and shading.

:func:`render_images` runs a built scene through these stages, with the scattering method of the registry
(:mod:`warpscatter.methods`: what it needs, which Warp modules it launches). Stage names (CLI timing table, ``bench``,
logs): ``compile`` · ``upload`` · ``bvh`` (exact visibility only) · ``gbuffer`` · ``shadow_map`` · the method's own
(``scattering`` for ``raymarch``; ``rectify`` … ``evaluate`` for the prefiltered methods; ``lines`` …
``interpolate`` for ``epipolar``) · surface shadows (``msm_generate`` …) · ``shading`` (surfaces + composition).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .. import methods
from ..raster.gbuffer import gbuffer_raster, gbuffer_raycast
from ..runtime.device import default_device
from ..runtime.stages import StageTimer
from ..scene import DeviceGeometry
from ..shading import ambient_radiance, shade_and_compose
from ..shadows.shadow_map import render_shadow_map
from ..shadows.surface import prepare_shadows
from ..shadows.unseen_planes import without_unseen_planes
from .common import check_finite, compile_kernels
from .frame import Frame

#: Images that add up over a point light's faces (radiance); the others (depth ...) are the first face's.
ADDITIVE_IMAGES = ("color", "scattering", "surface")


#: A render whose light reaches less than this share of what it would unshadowed is dark (:func:`lit_share`).
DARK_SHARE = 0.02
#: The same for a sun below the horizon (``direction`` given toward the sun, not the way the light travels).
DARK_SHARE_SUN_BELOW = 0.25


def lit_share(scene, images: dict, depth: np.ndarray) -> float:
    """How much of the light reaches the image: the larger of the share of surface pixels the light reaches and, for
    a directional light, the image's in-scattering over its unshadowed value (sigma_s f E (1 - exp(-sigma_t s)) /
    sigma_t per pixel, summed over the channels); 1.0 where the medium scatters nothing. A statistic: every 4th pixel
    of every 4th row counts (every pixel of images under 8 pixels high or wide)."""
    cam = scene.camera
    k = 4 if min(cam.width, cam.height) >= 8 else 1
    rows = cols = slice(k // 2, None, k)  # the pixels of cam.ray_directions(k)
    surface, scattering, depth = images["surface"][rows, cols], images["scattering"][rows, cols], depth[rows, cols]
    surface_share = float((surface.max(axis=-1) > 0.0).mean())
    light, medium = scene.light, scene.medium
    if light.kind != "directional":
        return max(surface_share, float(scattering.max() > 0.0))
    sigma_t, sigma_s = np.asarray(medium.sigma_t_rgb), np.asarray(medium.sigma_s_rgb)
    if not sigma_s.any():
        return 1.0
    cos_theta = -(cam.ray_directions(k) @ np.asarray(light.direction, np.float64))
    path = np.where(sigma_t > 0.0, (1.0 - medium.transmittance(depth)) / np.where(sigma_t > 0.0, sigma_t, 1.0),
                    depth[..., None])  # integral of exp(-sigma_t t) dt over [0, s]
    unshadowed = (sigma_s * np.asarray(light.irradiance) * medium.phase_value(cos_theta)[..., None] * path).sum()
    return max(surface_share, float(scattering.sum() / unshadowed) if unshadowed > 0.0 else 1.0)


def dark_image_warnings(scene, images: dict, settings) -> list[str]:
    """Why an image is dark when its light reaches almost none of it (:data:`DARK_SHARE`, :func:`lit_share`): a list
    of one message naming the likely cause, or an empty list. ``images`` are the light's own (before the sky fill)."""
    if not settings.surfaces.enabled and not np.any(scene.medium.sigma_s_rgb):
        return ["the image is black: render.surfaces.enabled is false and the medium scatters nothing (sigma_t or "
                "albedo 0)"]
    light = scene.light
    sun_below = light.kind == "directional" and light.direction[1] > 0.0
    share = lit_share(scene, images, images["depth"])
    if share >= (DARK_SHARE_SUN_BELOW if sun_below else DARK_SHARE):
        return []
    if sun_below:
        why = (f"light.direction {[round(float(c), 3) for c in light.direction]} points up: it is the way the light "
               "travels, so the sun is below the horizon; to give the direction toward the sun, use light.toward_sun "
               "(or light.azimuth_deg and light.elevation_deg)")
    else:
        why = "almost every surface and view ray seen is in shadow" + (
            " or outside the spot's cone" if light.kind == "spot" else "")
    return [f"the light reaches {100.0 * share:.2g} % of what it would unshadowed, so the image is dark: {why}"]


def render_images(scene, settings, *, timer: StageTimer | None = None, device=None,
                  aovs: tuple[str, ...] | list[str] = ()) -> tuple[dict, dict]:
    """Run the classic render stages for a built scene: (images as :func:`warpscatter.shading.shade_and_compose`
    makes them, stats).

    Args:
        scene: a :class:`~warpscatter.scene.Scene` (directional, spot or point light; a point light runs the light
            stages once per cube face and adds the faces' images).
        settings: the validated ``render`` section (:class:`~warpscatter.config.RenderSettings`).
        timer, device: a :class:`~..runtime.stages.StageTimer` (created if None) and the Warp device.
        aovs: the requested outputs (``output.aovs``): the method makes the debug ones among them.

    Raises:
        ValueError: ``render.lighting.method`` is set (see :mod:`.lighting`), or the method lacks the light.
        NonFiniteImageError: an image with NaN or infinite pixels (a bug).
    """
    device = default_device(device)
    timer = timer or StageTimer()
    sc = settings.scattering
    if settings.lighting.method is not None:
        raise ValueError("render.lighting.method is set: Monte-Carlo lighting runs through render() or "
                         "warpscatter.pipeline.lighting.render_lighting, not render_images")
    method = methods.get("scattering", sc.method)
    if scene.light.kind not in method.lights:
        raise ValueError(f"render.scattering.method {sc.method!r} needs a {' or '.join(method.lights)} light "
                         f"(the scene's light is {scene.light.kind!r})")
    marches_exact = method.marches_exact(sc.visibility)
    shadows_on = settings.surfaces.enabled and settings.shadows.method != "none"
    need_shadow_map = shadows_on or not marches_exact

    with timer("compile"):
        compile_kernels(methods.CLASSIC_MODULES + method.modules, device)
    with timer("upload"):
        geometry = DeviceGeometry(scene, device)
    if marches_exact:
        with timer("bvh"):
            _ = geometry.mesh
    with timer("gbuffer"):
        if marches_exact and method.reference_gbuffer:
            gbuf = gbuffer_raycast(scene, geometry, device)
        else:
            gbuf = gbuffer_raster(scene, geometry, device)
    # the light's maps leave out planes that shadow nothing seen (shadows/unseen_planes.py); the BVH above keeps them
    lit_scene, unseen_planes = scene, []
    if need_shadow_map and sc.shadow_map.skip_unseen_planes:
        with timer("shadow_map"):
            lit_scene, unseen_planes = without_unseen_planes(scene, gbuf.distance)
    # a point light: six square spots, one per cube face, images added (Klehm 2014 Sec. 3.2); debug and stats: +X
    faces = ([replace(lit_scene, light=face) for face in scene.light.faces()] if scene.light.kind == "point"
             else [lit_scene])
    images, info, debug_images, shadow_map = {}, {}, {}, None
    for k, lit in enumerate(faces):
        if need_shadow_map:
            with timer("shadow_map"):
                shadow_map = render_shadow_map(lit, sc.shadow_map.resolution, device=device)
        frame = Frame(lit, gbuf, geometry=geometry if marches_exact else None, shadow_map=shadow_map, device=device,
                      aovs=tuple(aovs))
        l_scat, face_info = method.load()(frame, sc, timer)
        face_debug = face_info.pop("debug_images", {})
        shadows = None
        if shadows_on:
            shadows, shadow_info = prepare_shadows(lit, shadow_map, settings.shadows, bias_texels=sc.shadow_map.bias,
                                                   timer=timer, device=device)
            face_info.update(shadow_info)
        with timer("shading"):
            face_images = shade_and_compose(lit, gbuf, l_scat, shadows=shadows, surfaces=settings.surfaces.enabled,
                                            device=device)
        if k == 0:
            images, info, debug_images = face_images, face_info, face_debug
        else:
            for name in ADDITIVE_IMAGES:
                if name in images:
                    images[name] = images[name] + face_images[name]
    if len(faces) > 1:
        info["light_faces"] = len(faces)
    with timer("shading"):
        warnings = dark_image_warnings(scene, images, settings)
        fill = ambient_radiance(scene, gbuf, settings.surfaces.ambient) if settings.surfaces.enabled else None
        if fill is not None:  # the sky fill, once (not per cube face of a point light)
            images["surface"] += fill
            images["color"] += fill
    if warnings:
        info["warnings"] = warnings
    images.update(debug_images)
    stats = {
        "triangles": scene.triangle_count,
        "resolution": [scene.camera.width, scene.camera.height],
        "method": sc.method,
        "visibility": sc.visibility if method.visibility == methods.VISIBILITY_CONFIGURABLE else None,
        "steps": sc.march_steps,
        "jitter": sc.march_jitter,
        **info,
        "shadow_map": list(shadow_map.shape[::-1]) if shadow_map is not None else None,
        "planes_left_out_of_maps": unseen_planes,
    }
    check_finite(images)
    return images, stats


__all__ = ["dark_image_warnings", "render_images"]
