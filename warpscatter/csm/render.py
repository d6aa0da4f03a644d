"""The ``csm`` and ``raytrace`` render methods: Monte-Carlo direct lighting of a camera view (Ritschel 2007 Sec. 5).

Stages (names as in the CLI's timing table):

- ``csm`` (method ``csm``): the coherent shadow map of the scene's occluders (every mesh not marked
  ``receiver_only``, in world space), loaded from ``render.lighting.csm.file`` (checked against the scene:
  kind, occluder geometry, light samples) or built on the fly with the streaming builder: lat-long maps for an
  environment light, depth cube maps at the light's sample points for an area or linear light.
  ``bvh`` (method ``raytrace``): the ``wp.Mesh`` of the same occluders, for exact shadow rays (the reference).
- ``gbuffer``: the rasterized camera G-buffer (:func:`warpscatter.gbuffer.gbuffer_raster`), the same for both
  methods so that they differ only by the visibility query.
- ``lighting``: ``passes`` progressive passes (Sec. 5.2). Each pass shades every visible pixel with S = s^2
  strata (:func:`~warpscatter.csm.lighting.shade_environment` or :func:`~warpscatter.csm.lights.shade_local_light`)
  under its own seed, so every pass draws new stratified patterns; :class:`ProgressiveAccumulator` averages them.
  Every ``write_every`` passes the current mean is handed to ``on_pass`` (the pipeline writes the outputs then).

Outputs (as the other methods): ``surface`` = L_surface exp(-sigma_t s) (the medium only attenuates: single
scattering of environment / area / linear lights is not modelled, so ``scattering`` = 0), ``color`` = surface
plus, with ``background``, the environment seen where no surface is hit (times exp(-sigma_t far)), ``depth``.

Units: radiance as the light's (environment texels, area radiance, linear intensity per length); distances, bias
and normal offset in scene units.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import warp as wp

from ..wpinit import default_device
from .brdf import MaterialTable
from .compress import (
    KIND_CUBE,
    KIND_LATLONG,
    CoherentShadowMap,
    CSMFileError,
    build_csm,
    build_cube_csm,
    geometry_digest,
    load_csm,
)
from .lighting import EnvironmentMap, ProgressiveAccumulator, shade_environment
from .lights import AreaLight, LinearLight, check_light_csm, shade_local_light

#: The lighting methods (``render.lighting.method``).
METHODS = ("csm", "raytrace")


@dataclass(frozen=True)
class EnvironmentLight:
    """A distant lat-long environment map (radiance texels, already multiplied by the config's ``scale``)."""

    env: EnvironmentMap

    kind = "environment"


@dataclass(frozen=True)
class LightingSettings:
    """Parameters of the lighting methods (``render.lighting`` in the README).

    Attributes:
        method: ``csm`` (coherent-shadow-map visibility) or ``raytrace`` (wp.Mesh shadow rays, the reference).
        samples: strata per pixel and pass, a perfect square (each: one light and one BRDF sample).
        passes: progressive passes; pass k uses seed (seed, k).
        seed: base random seed.
        filter: CSM filter ``nearest`` | ``pcf`` | ``roulette`` (Sec. 4.5).
        bias: CSM depth bias in scene units (None: one texel, :func:`texel_size`).
        normal_offset: query-point offset along the normal in scene units (None: a quarter texel for ``csm``,
            1e-4 x the scene's bounding-box diagonal for ``raytrace``).
        write_every: hand the image to ``on_pass`` every this many passes (0: only the final image).
        background: show the environment map where no surface is hit.
        csm_file: a CSM from ``warpscatter precompute`` (None: build it).
        maps, light_samples, resolution, enumeration, layers, far, batch: how to build it (see
            :func:`~warpscatter.csm.compress.build_csm` / :func:`~warpscatter.csm.compress.build_cube_csm`).
        local_lights: area / linear lights: ``cube`` (depth cube maps at the light's samples, Sec. 4.2) or
            ``semi_local`` (the lat-long CSM queried towards each light point, Sec. 4.3).
    """

    method: str = "csm"
    samples: int = 16
    passes: int = 8
    seed: int = 0
    filter: str = "roulette"
    bias: float | None = None
    normal_offset: float | None = None
    write_every: int = 1
    background: bool = True
    csm_file: Path | None = None
    maps: tuple[int, int] = (64, 32)
    light_samples: tuple[int, int] = (8, 8)
    resolution: int = 128
    enumeration: str = "hilbert"
    layers: str = "z1z2"
    far: str = "sphere"
    batch: int = 64
    local_lights: str = "cube"

    @classmethod
    def from_config(cls, lighting) -> LightingSettings:
        """From the validated ``render.lighting`` section."""
        c = lighting.csm
        return cls(method=lighting.method, samples=lighting.samples, passes=lighting.passes, seed=lighting.seed,
                   filter=lighting.filter, bias=lighting.bias, normal_offset=lighting.normal_offset,
                   write_every=lighting.write_every, background=lighting.background, csm_file=c.file,
                   maps=tuple(c.maps), light_samples=tuple(c.light_samples), resolution=c.resolution,
                   enumeration=c.enumeration, layers=c.layers, far=c.far, batch=c.batch,
                   local_lights=c.local_lights)  # fmt: skip


def light_from_config(c):
    """The host light of an ``environment``, ``area`` or ``linear`` light config.

    Raises:
        ConfigError: the environment map cannot be read or is not a valid lat-long radiance map.
    """
    from ..config import ConfigError
    from ..imageio import read_image

    if c.type == "environment":
        try:
            image = read_image(c.map)
        except OSError as exc:
            raise ConfigError(f"light.map: {exc}") from None
        if image.ndim == 3 and image.shape[2] == 1:
            image = np.repeat(image, 3, axis=2)
        try:
            return EnvironmentLight(EnvironmentMap(np.asarray(image)[..., :3] * np.float32(c.scale)))
        except ValueError as exc:
            raise ConfigError(f"light.map: {c.map}: {exc}") from None
    if c.type == "area":
        if c.power is not None:
            return AreaLight.from_power(c.position, c.u, c.v, c.power, c.two_sided)
        return AreaLight(c.position, c.u, c.v, c.radiance if c.radiance is not None else (1.0, 1.0, 1.0),
                         c.two_sided)
    if c.type == "linear":
        return LinearLight(c.start, c.end, c.intensity)
    raise ValueError(f"light.type {c.type!r} is not a Monte-Carlo light")


def scene_occluders(scene, receiver_only=None) -> tuple[np.ndarray, np.ndarray]:
    """The occluder mesh of a scene: the triangles of every material (= mesh entry) k with ``receiver_only[k]``
    false (default: the scene's own flags, :meth:`~warpscatter.scene.Scene.caster_mask`), compacted to the vertices
    they use (float32 world positions, int32 indices; both empty when nothing casts)."""
    from ..scene import compact_mesh

    if receiver_only is not None:
        scene = replace(scene, receiver_only=np.asarray(receiver_only, bool))
    return compact_mesh(scene.vertices, scene.triangles[scene.caster_mask()])


def csm_kind_for(light, local_lights: str = "cube") -> str:
    """The CSM kind a light needs: lat-long for environment maps and semi-local lights, else cube."""
    if isinstance(light, EnvironmentLight) or local_lights == "semi_local":
        return KIND_LATLONG
    return KIND_CUBE


def check_csm_for_scene(csm: CoherentShadowMap, light, vertices, triangles, where: str = "csm",
                        local_lights: str = "cube") -> None:
    """Refuse a CSM that does not belong to these occluders and this light.

    Checks: the kind (:func:`csm_kind_for`: lat-long for environment and semi-local lights, else cube), the geometry
    (:func:`~warpscatter.csm.compress.geometry_digest`, or the bounding sphere for files without a digest) and,
    for cube CSMs, that the light samples lie on the light.

    Raises:
        CSMFileError: naming ``where`` and the mismatch.
    """
    from .depthmaps import bounding_sphere

    want = csm_kind_for(light, local_lights)
    if csm.kind != want:
        hint = "; build it from this config: warpscatter precompute CONFIG" if want == KIND_CUBE else ""
        if want == KIND_CUBE and csm.kind == KIND_LATLONG:
            hint += ", or set render.lighting.csm.local_lights: semi_local to query it towards the light points"
        raise CSMFileError(f"{where}: a {csm.kind!r} CSM cannot light the {light.kind} light (it needs a {want!r} "
                           f"CSM{hint})")
    if csm.geometry is not None:
        if csm.geometry != geometry_digest(vertices, triangles):
            raise CSMFileError(f"{where}: built for other occluders (the geometry digest differs from this scene's "
                               f"{len(triangles)} occluder triangles: another mesh, transform or receiver_only set)")
    else:
        center, radius = bounding_sphere(np.asarray(vertices, np.float64))
        if abs(radius - csm.radius) > 1e-4 * radius or np.linalg.norm(center - csm.center) > 1e-4 * radius:
            raise CSMFileError(f"{where}: its bounding sphere (centre {np.round(csm.center, 4).tolist()}, radius "
                               f"{csm.radius:.4g}) is not that of this scene's occluders (centre "
                               f"{np.round(center, 4).tolist()}, radius {radius:.4g})")
    if want == KIND_CUBE:
        try:
            check_light_csm(csm, light)
        except ValueError as exc:
            raise CSMFileError(f"{where}: {exc}") from None


def prepare_csm(scene, light, settings: LightingSettings, vertices, triangles, *,
                progress: Callable[[float], None] | None = None, device=None) -> CoherentShadowMap:
    """Load (and check) ``settings.csm_file`` or build the CSM of the occluders for ``light``.

    Raises:
        CSMFileError: an unreadable, corrupt or mismatched file (the message names it).
    """
    if settings.csm_file is not None:
        csm = load_csm(settings.csm_file)
        check_csm_for_scene(csm, light, vertices, triangles, where=str(settings.csm_file),
                            local_lights=settings.local_lights)
        return csm

    def report(done, total):
        if progress is not None:
            progress(done / total)

    common = {"resolution": settings.resolution, "enumeration": settings.enumeration, "depth_layers": settings.layers,
                  "far": settings.far, "batch_maps": settings.batch, "progress": report, "device": device}  # fmt: skip
    if csm_kind_for(light, settings.local_lights) == KIND_LATLONG:
        return build_csm(vertices, triangles, n1=settings.maps[0], n2=settings.maps[1], **common)
    samples = light.sample_points(*settings.light_samples)
    return build_cube_csm(vertices, triangles, samples, **common)


def pass_seed(seed: int, k: int) -> int:
    """Seed of progressive pass ``k``: distinct per pass, so each pass draws new per-pixel patterns."""
    return (int(seed) * 1_000_003 + 7919 * (int(k) + 1)) & 0x7FFFFFFF


def texel_size(csm: CoherentShadowMap) -> float:
    """2R / M: the world size of one lat-long texel of the occluders' bounding sphere (R) at map size M. The
    default depth bias of the lighting methods is one such texel and the normal offset a quarter of it (measured
    on configs/csm_gate.yaml against raytrace: rel. L1 1.04 % for the sky, 0.96 % for an area light's cube maps;
    larger normal offsets leak light into contact shadows)."""
    return 2.0 * float(csm.radius) / float(csm.resolution)


def render_lighting(config, scene, *, timer, on_pass: Callable[[dict, int, int], None] | None = None,
                    device=None) -> tuple[dict, dict]:
    """Render a config whose ``render.lighting.method`` is set (see the module docstring).

    Args:
        config: the validated :class:`~warpscatter.config.Config`.
        scene: its built :class:`~warpscatter.scene.Scene` (``scene.light`` an environment, area or linear light).
        timer: the pipeline's :class:`~warpscatter.pipeline.StageTimer`.
        on_pass: ``on_pass(images, passes_done, passes)`` every ``write_every`` passes before the last.
        device: Warp device.

    Returns:
        (images, stats) as :func:`warpscatter.pipeline.render_images`.

    Raises:
        ConfigError: a CSM file that is corrupt or does not match the scene (``render.lighting.csm.file: ...``).
    """
    from .. import gbuffer as gbuffer_module
    from .. import raster
    from ..config import ConfigError
    from ..gbuffer import gbuffer_raster
    from ..raycast import build_mesh
    from ..scene import DeviceGeometry
    from . import brdf, compress, depthmaps, lighting, lights, query

    device = default_device(device)
    settings = LightingSettings.from_config(config.render.lighting)
    light = scene.light
    receiver_only = [m.receiver_only for m in config.scene.meshes]
    with timer("compile"):
        for m in (raster, gbuffer_module, brdf, compress, depthmaps, query, lighting, lights):
            wp.load_module(m, device=device)
    vertices, triangles = scene_occluders(scene, receiver_only)
    csm = mesh = None
    if settings.method == "csm":
        with timer("csm") as stage:
            try:
                csm = prepare_csm(scene, light, settings, vertices, triangles, progress=stage.report, device=device)
            except CSMFileError as exc:
                raise ConfigError(f"render.lighting.csm.file: {exc}") from None
    else:
        with timer("bvh"):
            mesh = build_mesh(vertices, triangles, device=device) if len(triangles) else None
    with timer("upload"):
        geometry = DeviceGeometry(scene, device)
    with timer("gbuffer"):
        gbuf = gbuffer_raster(scene, geometry, device)
    cam = scene.camera
    h, w = cam.height, cam.width
    g = gbuf.numpy()
    dirs = cam.ray_directions()
    hit = g["material"] >= 0
    dist = g["distance"].astype(np.float64)
    points = (np.asarray(cam.position, np.float64) + dirs * dist[..., None])[hit].astype(np.float32)
    normals = g["normal"][hit].astype(np.float32)
    view = (-dirs[hit]).astype(np.float32)
    mat_index = g["material"][hit].astype(np.int32)
    table = MaterialTable.from_specs([m.material.brdf_spec() for m in config.scene.meshes])
    if csm is not None:
        texel = texel_size(csm)
        bias = texel if settings.bias is None else settings.bias
        offset = 0.25 * texel if settings.normal_offset is None else settings.normal_offset
    else:
        lo, hi = scene.bounds()
        bias = 0.0
        offset = 1e-4 * float(np.linalg.norm(hi - lo)) if settings.normal_offset is None else settings.normal_offset
    sigma_t = float(scene.medium.sigma_t)
    attenuation = np.exp(-sigma_t * dist)[..., None].astype(np.float32)
    background = np.zeros((h, w, 3), np.float32)
    if settings.background and isinstance(light, EnvironmentLight):
        far = cam.far_distance(dirs)
        background = np.where(hit[..., None], 0.0, light.env.lookup(dirs, device) *
                              np.exp(-sigma_t * far)[..., None]).astype(np.float32)  # fmt: skip
    scattering = np.zeros((h, w, 3), np.float32)

    def images_of(radiance: np.ndarray) -> dict:
        surface = np.zeros((h, w, 3), np.float32)
        surface[hit] = radiance
        surface *= attenuation
        return {"color": surface + background, "surface": surface, "scattering": scattering,
                "depth": g["distance"].astype(np.float32)}

    kw = {"samples": settings.samples, "view_dirs": view, "materials": table, "material_index": mat_index,
              "filter": settings.filter, "bias": float(bias), "ray_eps": float(offset), "device": device}  # fmt: skip
    if csm is not None:
        kw["csm"] = csm
    elif mesh is not None:
        kw["mesh"] = mesh
    acc = ProgressiveAccumulator()
    pass_seconds = []
    mean = np.zeros((0, 3), np.float32)
    for k in range(settings.passes):
        t0 = time.perf_counter()
        if isinstance(light, EnvironmentLight):
            frame = shade_environment(points, normals, None, light.env, seed=pass_seed(settings.seed, k), **kw)
        else:
            frame = shade_local_light(points, normals, None, light, seed=pass_seed(settings.seed, k), **kw)
        mean = acc.add(frame)
        wp.synchronize()
        dt = time.perf_counter() - t0
        pass_seconds.append(dt)
        timer.timings["lighting"] = timer.timings.get("lighting", 0.0) + dt
        if timer.progress:
            timer.progress(f"lighting pass {k + 1}/{settings.passes}", (k + 1) / settings.passes)
        done = k + 1
        if on_pass is not None and settings.write_every and done % settings.write_every == 0 and done < settings.passes:
            on_pass(images_of(mean), done, settings.passes)
    images = images_of(mean)
    for name, img in images.items():
        if not np.all(np.isfinite(img)):
            raise FloatingPointError(f"{name} image has non-finite pixels (a bug: please report it)")
    stats = {
        "triangles": scene.triangle_count,
        "occluder_triangles": int(len(triangles)),
        "resolution": [w, h],
        "method": settings.method,
        "light": light.kind,
        "samples": settings.samples,
        "passes": settings.passes,
        "directions_per_pixel": 2 * settings.samples * settings.passes if light.kind != "linear"
        else settings.samples * settings.passes,
        "seconds_per_pass": float(np.median(pass_seconds)),
        "shaded_pixels": int(hit.sum()),
    }
    if csm is not None:
        stats.update(csm_kind=csm.kind, csm_maps=[csm.n1, csm.n2], csm_resolution=csm.resolution,
                     csm_segments=csm.num_segments, csm_file=str(settings.csm_file) if settings.csm_file else None,
                     csm_bias=float(bias))
    if sigma_t > 0.0:
        stats["medium"] = "attenuation only (L_scat = 0 for the lighting methods)"
    return images, stats


__all__ = [
    "METHODS",
    "EnvironmentLight",
    "LightingSettings",
    "check_csm_for_scene",
    "csm_kind_for",
    "light_from_config",
    "pass_seed",
    "prepare_csm",
    "render_lighting",
    "scene_occluders",
    "texel_size",
]
