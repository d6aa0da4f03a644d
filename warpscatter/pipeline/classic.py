"""The classic pipeline: G-buffer, light shadow map, the scattering method, surface shadows and shading.

:func:`render_images` runs a built scene through the stages below; the scattering method is looked up in the
registry (:mod:`warpscatter.methods`), which also says what it needs (a BVH for exact visibility, the shadow map,
a ray-cast G-buffer) and which Warp modules it launches. Stage names appear in the CLI's timing table, in
``bench`` and in logs:

``compile`` (Warp kernel modules; apart from the work itself) · ``upload`` (device arrays) · ``bvh``
(``wp.Mesh``, exact visibility only) · ``gbuffer`` (camera) · ``shadow_map`` (light) · the method's own stages
(``scattering`` for ``raymarch``; ``rectify`` … ``evaluate`` for the prefiltered methods; ``lines`` …
``interpolate`` for ``epipolar``) · surface-shadow stages (``msm_generate`` …) · ``shading`` (surfaces +
composition).
"""

from __future__ import annotations

from dataclasses import replace

from .. import methods
from ..gbuffer import gbuffer_raster, gbuffer_raycast
from ..scene import DeviceGeometry
from ..shading import shade_and_compose
from ..shadows.shadow_map import render_shadow_map
from ..shadows.surface import prepare_shadows
from ..shadows.unseen_planes import without_unseen_planes
from ..stages import StageTimer
from ..wpinit import default_device
from .common import check_finite, compile_kernels
from .frame import Frame

#: The images that add up over a point light's faces (radiance, linear in the light); the rest (depth ...) are the
#: first face's, the same for all.
ADDITIVE_IMAGES = ("color", "scattering", "surface")


def render_images(scene, settings, *, timer: StageTimer | None = None, device=None,
                  aovs: tuple[str, ...] | list[str] = ()) -> tuple[dict, dict]:
    """Run the classic render stages for a built scene.

    Args:
        scene: a :class:`~warpscatter.scene.Scene` (directional, spot or point light; a point light runs the light
            stages once per cube face and adds the faces' images).
        settings: the validated ``render`` section (:class:`~warpscatter.config.RenderSettings`: scattering,
            surfaces, shadows).
        timer: a :class:`~warpscatter.stages.StageTimer` (created if None).
        device: Warp device.
        aovs: the requested outputs (``output.aovs``); the method's debug outputs among them are made and returned
            with the images.

    Returns:
        (images, stats): images as in :func:`warpscatter.shading.shade_and_compose`; stats with sizes and the
        method's own statistics.

    Raises:
        ValueError: ``render.lighting.method`` is set (the Monte-Carlo path is :mod:`.lighting`), or the method
            does not render the scene's light.
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
    # a point light is six square spots, one per cube face, whose images add up (Klehm 2014 Sec. 3.2); the debug
    # outputs and the method's stats are the first face's (+X)
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


__all__ = ["render_images"]
