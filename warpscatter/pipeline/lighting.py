"""The Monte-Carlo lighting pipeline: the ``csm`` and ``raytrace`` methods, direct lighting of a camera view
(Ritschel 2007 Sec. 5).

Stages (names as in the CLI's timing table):

- ``csm`` (method ``csm``): the coherent shadow map of the occluders (meshes not ``receiver_only``), loaded from
  ``render.lighting.csm.file`` (checked against the scene) or built on the fly: lat-long maps for an environment
  light, depth cube maps at the light's samples for an area or linear light (:mod:`warpscatter.csm.occluders`);
  with ``render.lighting.csm.objects: per_mesh`` one lat-long CSM per casting mesh in its object space (Sec. 4.6,
  built once per process per mesh). ``bvh`` (method ``raytrace``): the occluders' ``wp.Mesh`` (the reference).
- ``upload``, ``gbuffer``: the rasterized camera G-buffer, the same for both methods, which so differ only by the
  visibility query.
- ``setup``: :class:`~warpscatter.csm.direct_lighting.DirectLighting` checks the visible pixels' inputs, materials
  and light and puts them on the device once for all passes.
- ``lighting``: ``passes`` progressive passes (Sec. 5.2), each under its own seed, averaged; every ``write_every``
  passes ``on_pass`` gets the current mean.

Outputs: ``surface`` = L_surface exp(-sigma_t s) (the medium only attenuates, ``scattering`` = 0), ``color`` =
surface plus, with ``background``, the environment where no surface is hit (times exp(-sigma_t far)), ``depth``.
Radiance in the light's units; distances, bias and normal offset in scene units.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import warp as wp

from .. import methods
from ..csm.brdf import MaterialTable
from ..csm.direct_lighting import DirectLighting, ProgressiveAccumulator
from ..csm.occluders import prepare_csm, scene_occluders, texel_size
from ..csm.query import csm_device_data
from ..csm.settings import LightingSettings
from ..raster.gbuffer import gbuffer_raster
from ..raster.raycast import cached_bvh
from ..runtime.device import default_device
from ..runtime.stages import StageTimer
from ..scene import DeviceGeometry
from ..scene.lights import EnvironmentLight
from .common import check_finite, compile_kernels


def pass_seed(seed: int, k: int) -> int:
    """Seed of progressive pass ``k``: distinct per pass, so each pass draws new per-pixel patterns."""
    return (int(seed) * 1_000_003 + 7919 * (int(k) + 1)) & 0x7FFFFFFF


@dataclass
class CameraSurface:
    """The visible surface of a camera view as the Monte-Carlo estimators take it (:func:`camera_surface`): the
    G-buffer's arrays (``"distance"``, ``"normal"``, ``"material"``), (H, W) unit ray ``directions``, ``hit`` mask and
    float64 hit ``distance``; (K,) float32 points, normals, directions to the camera and int32 material rows of the
    hit pixels (row-major)."""

    gbuffer: dict
    directions: np.ndarray
    hit: np.ndarray
    distance: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    view_dirs: np.ndarray
    material_index: np.ndarray
    materials: MaterialTable


def camera_surface(scene, stage: StageTimer | None = None, device=None) -> CameraSurface:
    """The stages ``upload`` and ``gbuffer`` of :func:`render_lighting`: the G-buffer and the per-pixel inputs."""
    device = default_device(device)
    timer = stage or StageTimer()
    with timer("upload"):
        geometry = DeviceGeometry(scene, device)
    with timer("gbuffer"):
        gbuf = gbuffer_raster(scene, geometry, device)
    cam = scene.camera
    g = gbuf.numpy()
    dirs = cam.ray_directions()
    hit = g["material"] >= 0
    dist = g["distance"].astype(np.float64)
    points = (np.asarray(cam.position, np.float64) + dirs * dist[..., None])[hit].astype(np.float32)
    return CameraSurface(gbuffer=g, directions=dirs, hit=hit, distance=dist, points=points,
                         normals=g["normal"][hit].astype(np.float32), view_dirs=(-dirs[hit]).astype(np.float32),
                         material_index=g["material"][hit].astype(np.int32),
                         materials=MaterialTable.from_specs(scene.brdf_specs()))


def render_lighting(scene, settings: LightingSettings, stage: StageTimer | None = None,
                    on_pass: Callable[[dict, int, int], None] | None = None, *, device=None,
                    objects: list | None = None) -> tuple[dict, dict]:
    """Monte-Carlo direct lighting of a scene (module docstring), in the lighting methods' call shape: (images,
    stats) as :func:`warpscatter.pipeline.render_images` returns them.

    Args:
        scene: a :class:`~warpscatter.scene.Scene` whose light is an environment, area or linear light.
        settings: ``render.lighting`` (:class:`~warpscatter.csm.settings.LightingSettings`).
        stage, device: the :class:`~..runtime.stages.StageTimer` (created if None) and the Warp device.
        on_pass: ``on_pass(images, passes_done, passes)`` every ``write_every`` passes before the last.
        objects: with ``settings.csm.objects`` ``per_mesh``: the casting meshes, ``(mesh, matrix)`` pairs of
            :func:`warpscatter.scene.object_meshes`.

    Raises:
        CSMFileError: a CSM file that is corrupt or does not match the scene (the message names it).
        NonFiniteImageError: an image with NaN or infinite pixels (a bug).
    """
    device = default_device(device)
    timer = stage or StageTimer()
    method = methods.get("lighting", settings.method)
    light = scene.light
    if light.kind not in method.lights:
        raise ValueError(f"render.lighting.method {settings.method!r} lights {', '.join(method.lights)} lights (the "
                         f"scene's light is {light.kind!r})")
    with timer("compile"):
        compile_kernels(methods.LIGHTING_BASE_MODULES + method.modules, device)
    vertices, triangles = scene_occluders(scene)
    csm = mesh = rigid = None
    per_mesh = method.visibility == methods.VISIBILITY_CSM and settings.csm.objects == "per_mesh"
    if per_mesh:
        if objects is None:
            raise ValueError("render.lighting.csm.objects per_mesh: pass the scene's objects "
                             "(warpscatter.scene.object_meshes)")
        with timer("csm") as s:
            rigid = [(prepare_csm(light, settings.csm, m.vertices, m.triangles, device=device), t)
                     for m, t in objects if len(m.triangles)]
            for c, _ in rigid:
                csm_device_data(c, device)
            s.report(1.0)
    elif method.visibility == methods.VISIBILITY_CSM:
        with timer("csm") as s:
            csm = prepare_csm(light, settings.csm, vertices, triangles, progress=s.report, device=device)
            csm_device_data(csm, device)  # the segment lists on the device, once per render
    else:
        with timer("bvh"):
            mesh = cached_bvh(vertices, triangles, device=device) if len(triangles) else None
    surf = camera_surface(scene, timer, device)
    cam = scene.camera
    h, w = cam.height, cam.width
    g, dirs, hit, dist = surf.gbuffer, surf.directions, surf.hit, surf.distance
    object_bias = None
    if rigid:  # default bias: one texel of each object's CSM; a given one (scene units) is converted per query
        scales = [abs(float(np.linalg.det(np.asarray(t, np.float64)[:3, :3]))) ** (1.0 / 3.0) for _, t in rigid]
        object_bias = [texel_size(c) for c, _ in rigid] if settings.bias is None else None
        bias = min(texel_size(c) * k for (c, _), k in zip(rigid, scales, strict=True)) if settings.bias is None \
            else settings.bias
        offset = 0.25 * min(texel_size(c) * k for (c, _), k in zip(rigid, scales, strict=True)) \
            if settings.normal_offset is None else settings.normal_offset
    elif csm is not None:
        texel = texel_size(csm)
        bias = texel if settings.bias is None else settings.bias
        offset = 0.25 * texel if settings.normal_offset is None else settings.normal_offset
    else:
        lo, hi = scene.bounds()
        bias = 0.0
        offset = 1e-4 * float(np.linalg.norm(hi - lo)) if settings.normal_offset is None else settings.normal_offset
    medium = scene.medium
    if medium.coloured:
        attenuation = medium.transmittance(dist).astype(np.float32)
    else:
        attenuation = np.exp(-medium.extinction * dist)[..., None].astype(np.float32)
    background = np.zeros((h, w, 3), np.float32)
    if settings.background and isinstance(light, EnvironmentLight):
        far = cam.far_distance(dirs)
        background = np.where(hit[..., None], 0.0, light.env.lookup(dirs, device) *
                              medium.transmittance(far)).astype(np.float32)
    scattering = np.zeros((h, w, 3), np.float32)

    def images_of(radiance: np.ndarray) -> dict:
        surface = np.zeros((h, w, 3), np.float32)
        surface[hit] = radiance
        surface *= attenuation
        return {"color": surface + background, "surface": surface, "scattering": scattering,
                "depth": g["distance"].astype(np.float32)}

    with timer("setup"):
        lighting = DirectLighting(surf.points, surf.normals, None, light, samples=settings.samples, csm=csm,
                                  mesh=mesh, view_dirs=surf.view_dirs, materials=surf.materials,
                                  material_index=surf.material_index, filter=settings.filter, bias=float(bias),
                                  ray_eps=float(offset), device=device, objects=rigid, object_bias=object_bias)
    acc = ProgressiveAccumulator()
    pass_seconds = []
    mean = np.zeros((0, 3), np.float32)
    for k in range(settings.passes):
        t0 = time.perf_counter()
        mean = acc.add(lighting.shade(pass_seed(settings.seed, k)))
        wp.synchronize()
        dt = time.perf_counter() - t0
        pass_seconds.append(dt)
        timer.add("lighting", dt)
        if timer.progress:
            timer.progress(f"lighting pass {k + 1}/{settings.passes}", (k + 1) / settings.passes)
        done = k + 1
        if on_pass is not None and settings.write_every and done % settings.write_every == 0 and done < settings.passes:
            on_pass(images_of(mean), done, settings.passes)
    images = images_of(mean)
    check_finite(images)
    stats = {
        "triangles": scene.triangle_count,
        "occluder_triangles": int(len(triangles)),
        "resolution": [w, h],
        "method": settings.method,
        "light": light.kind,
        "samples": settings.samples,
        "passes": settings.passes,
        "directions_per_pixel": light.directions_per_stratum * settings.samples * settings.passes,
        "seconds_per_pass": float(np.median(pass_seconds)),
        "shaded_pixels": int(hit.sum()),
    }
    if rigid:
        stats.update(csm_kind="per_mesh", csm_objects=len(rigid), csm_maps=list(settings.csm.maps),
                     csm_resolution=settings.csm.resolution, csm_segments=sum(c.num_segments for c, _ in rigid),
                     csm_bias=[round(float(b), 6) for b in object_bias] if object_bias else float(bias))
    if csm is not None:
        stats.update(csm_kind=csm.kind, csm_maps=[csm.n1, csm.n2], csm_resolution=csm.resolution,
                     csm_segments=csm.num_segments, csm_file=str(settings.csm.file) if settings.csm.file else None,
                     csm_bias=float(bias))
    if max(medium.sigma_t_rgb) > 0.0:
        stats["medium"] = "attenuation only (L_scat = 0 for the lighting methods)"
    return images, stats


__all__ = ["CameraSurface", "camera_surface", "pass_seed", "render_lighting"]
