"""Coherent shadow maps (Ritschel, Grosch, Kautz, Müller 2007): precomputed visibility of rigid objects.

N1 x N2 orthographic depth maps around an object are put in a coherent order (:mod:`.enumeration`), rendered
(:mod:`.depthmaps`), compressed losslessly into per-texel segment lists (:mod:`.compress`; CSM files are read by
:mod:`.files`) and queried by binary search (:mod:`.query`, batches in :mod:`.batch`). :mod:`.brdf`,
:mod:`.direct_lighting`, :mod:`.environment` and :mod:`.local_lights` are the Monte-Carlo estimators (Sec. 5);
:mod:`.occluders` the CSM of a scene; :mod:`.settings` ``render.lighting``. The ``csm`` / ``raytrace`` render
methods are :mod:`warpscatter.pipeline.lighting`.

Example::

    from warpscatter.csm import build_csm, csm_visibility_batch
    csm = build_csm(vertices, triangles, maps=(64, 32), resolution=128)
    vis = csm_visibility_batch(csm, points, directions, filter="pcf")
"""


from __future__ import annotations

import importlib

#: Public name -> the module holding it. Loaded on first access, so importing this package (or its
#: Warp-free :mod:`.settings`) does not import Warp.
_EXPORTS = {
    "MAX_LOBES": "warpscatter.csm.brdf",
    "MaterialData": "warpscatter.csm.brdf",
    "MaterialTable": "warpscatter.csm.brdf",
    "CoherentShadowMap": "warpscatter.csm.compress",
    "CompressionStats": "warpscatter.csm.compress",
    "FORMAT_VERSION": "warpscatter.csm.compress",
    "SegmentLists": "warpscatter.csm.compress",
    "StreamingCompressor": "warpscatter.csm.compress",
    "build_csm": "warpscatter.csm.compress",
    "build_cube_csm": "warpscatter.csm.compress",
    "compress_depth_maps": "warpscatter.csm.compress",
    "geometry_digest": "warpscatter.csm.compress",
    "save_csm": "warpscatter.csm.compress",
    "CubeMapSet": "warpscatter.csm.depthmaps",
    "LatLongMapSet": "warpscatter.csm.depthmaps",
    "bounding_sphere": "warpscatter.csm.depthmaps",
    "cube_face_frames": "warpscatter.csm.depthmaps",
    "latlong_frames": "warpscatter.csm.depthmaps",
    "ortho_view_proj": "warpscatter.csm.depthmaps",
    "parallelogram_light_samples": "warpscatter.csm.depthmaps",
    "segment_light_samples": "warpscatter.csm.depthmaps",
    "ProgressiveAccumulator": "warpscatter.csm.direct_lighting",
    "ENUMERATIONS": "warpscatter.csm.enumeration",
    "enumerate_grid": "warpscatter.csm.enumeration",
    "hilbert_order": "warpscatter.csm.enumeration",
    "scanline_order": "warpscatter.csm.enumeration",
    "sequence_index": "warpscatter.csm.enumeration",
    "zigzag_order": "warpscatter.csm.enumeration",
    "CSMFileError": "warpscatter.csm.files",
    "load_csm": "warpscatter.csm.files",
    "shade_direct": "warpscatter.csm.direct_lighting",
    "shade_environment": "warpscatter.csm.environment",
    "shade_local_light": "warpscatter.csm.local_lights",
    "check_csm_for_scene": "warpscatter.csm.occluders",
    "csm_kind_for": "warpscatter.csm.occluders",
    "prepare_csm": "warpscatter.csm.occluders",
    "scene_occluders": "warpscatter.csm.occluders",
    "CSMData": "warpscatter.csm.query",
    "CubeCSMData": "warpscatter.csm.query",
    "FILTERS": "warpscatter.csm.query",
    "csm_device_data": "warpscatter.csm.query",
    "csm_local_visibility_batch": "warpscatter.csm.batch",
    "csm_objects_visibility_batch": "warpscatter.csm.batch",
    "csm_visibility_batch": "warpscatter.csm.batch",
    "CSMBuildSettings": "warpscatter.csm.settings",
    "LightingSettings": "warpscatter.csm.settings",
    "EnvData": "warpscatter.scene.environment_map",
    "EnvironmentMap": "warpscatter.scene.environment_map",
    "AreaLight": "warpscatter.scene.lights",
    "EnvironmentLight": "warpscatter.scene.lights",
    "LinearLight": "warpscatter.scene.lights",
    "LocalLightData": "warpscatter.scene.lights",
}


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])


__all__ = sorted(_EXPORTS)
