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

Example::

    from warpscatter.csm import build_csm, csm_visibility_batch
    csm = build_csm(vertices, triangles, n1=64, n2=32, resolution=128)
    vis = csm_visibility_batch(csm, points, directions, filter="pcf")
"""

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
from .query import (
    FILTERS,
    CSMData,
    CubeCSMData,
    csm_device_data,
    csm_local_visibility_batch,
    csm_objects_visibility_batch,
    csm_visibility_batch,
)

__all__ = [
    "ENUMERATIONS",
    "FILTERS",
    "FORMAT_VERSION",
    "CSMData",
    "CSMFileError",
    "CoherentShadowMap",
    "CompressionStats",
    "CubeCSMData",
    "CubeMapSet",
    "LatLongMapSet",
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
    "hilbert_order",
    "latlong_frames",
    "load_csm",
    "ortho_view_proj",
    "parallelogram_light_samples",
    "save_csm",
    "scanline_order",
    "segment_light_samples",
    "sequence_index",
    "zigzag_order",
]
