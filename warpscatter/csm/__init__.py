"""Coherent shadow maps (Ritschel, Grosch, Kautz, Müller 2007): precomputed visibility of rigid objects.

Many orthographic depth maps around an object (N1 x N2 lat-long directions, M x M texels each) are put in a
coherent order, compressed losslessly into per-texel segment lists and queried with a binary search:

- :mod:`.depthmaps`: the depth-map sets (:class:`LatLongMapSet` for distant / semi-local lights,
  :class:`CubeMapSet` for fixed local lights), depth peeling for z1 / z2 (or z3), the spherical far plane.
- :mod:`.enumeration`: scan-line, zig-zag and Hilbert orders of the map grid.
- :mod:`.compress`: Eq. 1 segment compression, streaming in batches (:class:`StreamingCompressor`,
  :func:`build_csm`, :func:`build_cube_csm`), :class:`CoherentShadowMap`, ``.npz`` files (:func:`save_csm`,
  :func:`load_csm`, :class:`CSMFileError`).
- :mod:`.query`: public ``@wp.func`` visibility queries (nearest, generalised PCF, Russian roulette,
  semi-local lights, moving and receiver-only objects, local lights) and the batch kernel; :mod:`.batch`: the
  host functions that run batches of them.
- :mod:`.brdf`: Lambert, normalized Phong and Lafortune BRDFs with importance sampling and the Russian-roulette
  lobe choice (Sec. 5.1), :class:`MaterialTable`.
- :mod:`.direct_lighting`: what the Monte-Carlo estimators share: surface points, the visibility source (CSM,
  shadow rays or none), strata, :class:`ProgressiveAccumulator` (Sec. 5, 5.2).
- :mod:`.environment`: the stratified MIS estimator :func:`shade_environment` of lat-long environment maps
  (:class:`~warpscatter.scene.environment_map.EnvironmentMap`, importance-sampled, Sec. 5.1).
- :mod:`.local_lights`: area (parallelogram) and linear lights (:mod:`warpscatter.scene.lights`) sampled by
  radiance with cube-CSM visibility, :func:`shade_local_light` (Sec. 4.2, 5.1).
- :mod:`.occluders`: the CSM of a scene's occluders: built, or loaded and checked against the scene.
- :mod:`.settings`: the Warp-free settings of ``render.lighting`` (:class:`LightingSettings`).

The ``csm`` / ``raytrace`` render methods (``render.lighting``: CSM of the scene's occluders, G-buffer,
progressive passes) are :mod:`warpscatter.pipeline.lighting`.

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
    "CSMFileError": "warpscatter.csm.compress",
    "CoherentShadowMap": "warpscatter.csm.compress",
    "CompressionStats": "warpscatter.csm.compress",
    "FORMAT_VERSION": "warpscatter.csm.compress",
    "SegmentLists": "warpscatter.csm.compress",
    "StreamingCompressor": "warpscatter.csm.compress",
    "build_csm": "warpscatter.csm.compress",
    "build_cube_csm": "warpscatter.csm.compress",
    "compress_depth_maps": "warpscatter.csm.compress",
    "geometry_digest": "warpscatter.csm.compress",
    "load_csm": "warpscatter.csm.compress",
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
