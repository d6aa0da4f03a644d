"""The coherent shadow map of a scene's occluders (Ritschel et al. 2007): which triangles occlude (meshes not
``receiver_only``), which CSM kind a light needs, building or loading it and checking that it fits the scene.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import replace

import numpy as np

from ..runtime.stages import ReportFn
from .compress import (
    KIND_CUBE,
    KIND_LATLONG,
    CoherentShadowMap,
    build_csm,
    build_cube_csm,
    geometry_digest,
)
from .files import CSMFileError, load_csm
from .local_lights import check_light_csm
from .settings import CSMBuildSettings


def scene_occluders(scene, receiver_only=None) -> tuple[np.ndarray, np.ndarray]:
    """The occluder mesh: triangles of the meshes not ``receiver_only`` (default: the scene's flags), compacted
    (float32 world positions, int32 indices; empty when nothing casts)."""
    from ..scene import compact_mesh

    if receiver_only is not None:
        scene = replace(scene, receiver_only=np.asarray(receiver_only, bool))
    return compact_mesh(scene.vertices, scene.triangles[scene.caster_mask()])


def csm_kind_for(light, local_lights: str = "cube") -> str:
    """The CSM kind a light needs: cube for area or linear lights with ``local_lights: cube`` (Sec. 4.2), else
    lat-long (environment, semi-local and volume lights, or none, Sec. 4.3)."""
    if getattr(light, "kind", None) in ("area", "linear") and local_lights == "cube":
        return KIND_CUBE
    return KIND_LATLONG


def check_csm_for_scene(csm: CoherentShadowMap, light, vertices, triangles, where: str = "csm",
                        local_lights: str = "cube") -> None:
    """Raise :class:`CSMFileError` (naming ``where`` and the mismatch) for a CSM whose kind, geometry (digest, else
    bounding sphere) or cube light samples do not fit."""
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
        v = np.asarray(vertices, np.float64)
        far = float(np.sqrt(np.max(np.sum((v - csm.center) ** 2, axis=1)))) if len(v) else 0.0
        if not far <= csm.radius * (1.0 + 1e-9):  # a build's sphere encloses its mesh: the file was altered
            raise CSMFileError(f"{where}: its bounding sphere (centre {np.round(csm.center, 4).tolist()}, radius "
                               f"{csm.radius:.4g}) does not enclose this scene's occluders (farthest vertex at "
                               f"{far:.4g})")
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


def prepare_csm(light, settings: CSMBuildSettings, vertices, triangles, *, progress: ReportFn | None = None,
                device=None) -> CoherentShadowMap:
    """Load (and check) ``settings.file`` or build the CSM of the occluders for ``light``; built CSMs are kept for
    later renders (:data:`BUILT_CACHE_BYTES`).

    Args:
        light: the scene's environment, area or linear light.
        settings: :class:`~warpscatter.csm.settings.CSMBuildSettings` (``render.lighting.csm``).
        vertices, triangles: the occluders (:func:`scene_occluders`).
        progress, device: ``progress(fraction)`` of the build and the Warp device.

    Raises:
        CSMFileError: an unreadable, corrupt or mismatched file (the message names it).
    """
    if settings.file is not None:
        csm = load_csm(settings.file)
        check_csm_for_scene(csm, light, vertices, triangles, where=str(settings.file),
                            local_lights=settings.local_lights)
        return csm
    latlong = csm_kind_for(light, settings.local_lights) == KIND_LATLONG
    points = None if latlong else np.asarray(light.sample_points(*settings.light_samples), np.float64)
    key = (geometry_digest(vertices, triangles), settings.model_dump_json(exclude={"file"}), str(device),
           None if points is None else points.tobytes())
    with _BUILT_LOCK:  # one build per key, also when several threads render the same scene
        csm = _BUILT.pop(key, None)
        if csm is None:
            csm = (build_csm(vertices, triangles, settings, progress=progress, device=device) if latlong else
                   build_cube_csm(vertices, triangles, points, settings, progress=progress, device=device))
        elif progress is not None:
            progress(1.0)
        _BUILT[key] = csm  # most recently used last
        while len(_BUILT) > 1 and sum(_held_bytes(c) for c in _BUILT.values()) > BUILT_CACHE_BYTES:
            _BUILT.popitem(last=False)
    return csm


def _held_bytes(csm: CoherentShadowMap) -> int:
    """Bytes of a cached CSM's segment lists, on the host and once per device it was put on."""
    return csm.stats.compressed_bytes * (1 + len(getattr(csm, "_device_cache", {}) or {}))


def clear_csm_cache() -> None:
    """Drop the CSMs this process built and kept (:func:`prepare_csm`)."""
    with _BUILT_LOCK:
        _BUILT.clear()


#: CSMs this process built, by (occluder geometry, settings, device, light samples): reused by later renders.
_BUILT: OrderedDict = OrderedDict()
#: Bytes of built CSMs kept, host and device copies (least recently used leave first; the last one stays).
BUILT_CACHE_BYTES = 512 * 2**20
_BUILT_LOCK = threading.RLock()


def texel_size(csm: CoherentShadowMap) -> float:
    """2R / M: one lat-long texel of the occluders' bounding sphere. The default depth bias is one texel and the
    normal offset a quarter (larger offsets leak light; docs/benchmarks.md, "CSM offsets")."""
    return 2.0 * float(csm.radius) / float(csm.resolution)


__all__ = ["check_csm_for_scene", "csm_kind_for", "prepare_csm", "scene_occluders", "texel_size"]
