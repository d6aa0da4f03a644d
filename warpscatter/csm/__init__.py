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
  semi-local lights, moving and receiver-only objects, local lights) and host wrappers for batches.
- :mod:`.brdf`: Lambert, normalized Phong and Lafortune BRDFs with importance sampling and the Russian-roulette
  lobe choice (Sec. 5.1), :class:`MaterialTable`.
- :mod:`.lighting`: importance-sampled lat-long environment maps, the stratified MIS estimator
  :func:`shade_environment` (CSM or wp.Mesh visibility), :class:`ProgressiveAccumulator` (Sec. 5).
- :mod:`.lights`: area (parallelogram) and linear lights sampled by radiance with cube-CSM visibility,
  :func:`shade_local_light` (Sec. 4.2, 5.1).
- :mod:`.render`: the ``csm`` / ``raytrace`` render methods (``render.lighting``): CSM of the scene's occluders,
  G-buffer, progressive passes.

Example::

    from warpscatter.csm import build_csm, csm_visibility_batch
    csm = build_csm(vertices, triangles, n1=64, n2=32, resolution=128)
    vis = csm_visibility_batch(csm, points, directions, filter="pcf")
"""

from .brdf import MAX_LOBES, MaterialData, MaterialTable
from .compress import (
    FORMAT_VERSION,
    CoherentShadowMap,
    CompressionStats,
    CSMFileError,
    SegmentLists,
    StreamingCompressor,
    build_csm,
    build_cube_csm,
    compress_depth_maps,
    geometry_digest,
    load_csm,
    save_csm,
)
from .depthmaps import (
    CubeMapSet,
    LatLongMapSet,
    bounding_sphere,
    cube_face_frames,
    latlong_frames,
    ortho_view_proj,
    parallelogram_light_samples,
    segment_light_samples,
)
from .enumeration import ENUMERATIONS, enumerate_grid, hilbert_order, scanline_order, sequence_index, zigzag_order
from .lighting import EnvData, EnvironmentMap, ProgressiveAccumulator, shade_environment
from .lights import AreaLight, LinearLight, LocalLightData, shade_local_light
from .query import (
    FILTERS,
    CSMData,
    CubeCSMData,
    csm_device_data,
    csm_local_visibility_batch,
    csm_objects_visibility_batch,
    csm_visibility_batch,
)
from .render import EnvironmentLight, LightingSettings, render_lighting

__all__ = [
    "ENUMERATIONS",
    "FILTERS",
    "FORMAT_VERSION",
    "MAX_LOBES",
    "AreaLight",
    "CSMData",
    "CSMFileError",
    "CoherentShadowMap",
    "CompressionStats",
    "CubeCSMData",
    "CubeMapSet",
    "EnvData",
    "EnvironmentLight",
    "EnvironmentMap",
    "LatLongMapSet",
    "LightingSettings",
    "LinearLight",
    "LocalLightData",
    "MaterialData",
    "MaterialTable",
    "ProgressiveAccumulator",
    "SegmentLists",
    "StreamingCompressor",
    "bounding_sphere",
    "build_csm",
    "build_cube_csm",
    "compress_depth_maps",
    "cube_face_frames",
    "csm_device_data",
    "csm_local_visibility_batch",
    "csm_objects_visibility_batch",
    "csm_visibility_batch",
    "enumerate_grid",
    "geometry_digest",
    "hilbert_order",
    "latlong_frames",
    "load_csm",
    "ortho_view_proj",
    "parallelogram_light_samples",
    "render_lighting",
    "save_csm",
    "scanline_order",
    "segment_light_samples",
    "shade_environment",
    "shade_local_light",
    "sequence_index",
    "zigzag_order",
]
