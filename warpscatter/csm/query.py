"""Visibility queries against coherent shadow maps (Ritschel 2007, Sec. 3.2, 4.1, 4.3, 4.5, 4.6).

A query for point p and direction d (towards the light) selects the map whose lat-long cell holds d, projects
q = D_i p (texel x, y and linear depth q_z), binary-searches the texel's segment j with i_end(j - 1) < i <= i_end(j)
and returns shadowed iff q_z - bias > z_avg(j); points outside the map are lit. ``bias`` is in object-space units.

Filters (Sec. 4.5), visibility in [0, 1]: nearest (one map, one texel); generalised PCF (the 4 nearest maps,
azimuth wrapped and polar clamped, times the 4 nearest texels, bilinear weights [RSC87]); Russian roulette (one of
those 16 comparisons picked with its PCF weight, so its expectation is the PCF value).

Semi-local lights (Sec. 4.3) use d = l - p; rigid objects (Sec. 4.6) are queried with D' = D T^-1
(:func:`csm_object_space`), their visibilities multiplied. Fixed local lights (Sec. 3.3, 4.2) use ``"cube"`` CSMs:
the nearest light sample o, the cube face of p - o, map k N + i. Both kinds share the filters (generic over the CSM
struct, with per-kind overloads of ``_texel_test`` and ``_map_footprint``), inlined because an out-of-line call
copies the struct's arrays on the CPU. Batches: :mod:`warpscatter.csm.batch`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from ..runtime.device import default_device, module_options
from . import settings
from .compress import KIND_CUBE, CoherentShadowMap
from .depthmaps import cube_face_frames, latlong_param

module_options()

FILTER_NEAREST = wp.constant(0)
FILTER_PCF = wp.constant(1)
FILTER_ROULETTE = wp.constant(2)
#: Filter names accepted by the host wrappers (:data:`~warpscatter.csm.settings.FILTERS`) -> FILTER_* code.
FILTERS = {name: code for code, name in enumerate(settings.FILTERS)}


@wp.struct
class CSMData:
    """A lat-long coherent shadow map as kernels see it (build with :func:`csm_device_data`): the bounding sphere
    (``center`` in object space, ``radius`` R: maps span [-R, R]^2, depth 0 at the map plane), map size
    ``resolution`` M, ``n1`` azimuth x ``n2`` polar cells (``num_maps`` N), per cell b n1 + a the ``frames`` rows
    (right, up, dir) and sequence index i (``map_index``), and the segment lists (``seg_start``: M^2 + 1 lookup
    texture; ``seg_depth``: z_avg; ``seg_end``: i_end, inclusive)."""

    center: wp.vec3
    radius: float
    resolution: int
    n1: int
    n2: int
    num_maps: int
    frames: wp.array(dtype=wp.mat33)
    map_index: wp.array(dtype=wp.int32)
    seg_start: wp.array(dtype=wp.int32)
    seg_depth: wp.array(dtype=wp.float32)
    seg_end: wp.array(dtype=wp.int32)


@wp.struct
class CubeCSMData:
    """A depth-cube-map CSM of a fixed local light as kernels see it (build with :func:`csm_device_data`): face size
    ``resolution`` M, light-sample grid ``n1`` x ``n2`` (n2 = 1 for linear lights) of ``num_samples`` N (6N maps,
    map k N + i = face k of sample i), the 6 ``faces`` rows (right, up, forward), per cell b n1 + a the sample
    position and sequence index i, and the segment lists as in :class:`CSMData`."""

    resolution: int
    n1: int
    n2: int
    num_samples: int
    faces: wp.array(dtype=wp.mat33)
    samples: wp.array(dtype=wp.vec3)
    map_index: wp.array(dtype=wp.int32)
    seg_start: wp.array(dtype=wp.int32)
    seg_depth: wp.array(dtype=wp.float32)
    seg_end: wp.array(dtype=wp.int32)




@wp.func
def segment_lookup(
    seg_start: wp.array(dtype=wp.int32),
    seg_depth: wp.array(dtype=wp.float32),
    seg_end: wp.array(dtype=wp.int32),
    texel: int,
    sequence: int,
) -> float:
    """Stored depth of ``texel`` in map ``sequence``: binary search for the segment j with
    i_end(j - 1) < i <= i_end(j) (Ritschel 2007 Sec. 3.2), O(log n) reads."""
    lo = seg_start[texel]
    hi = seg_start[texel + 1] - 1
    while lo < hi:
        mid = (lo + hi) // 2
        if seg_end[mid] < sequence:
            lo = mid + 1
        else:
            hi = mid
    return seg_depth[lo]


@wp.func
def grid_bilinear(u: float, v: float, n1: int, n2: int, wrap_u: int) -> tuple[wp.vec4i, wp.vec2]:
    """The 2^2 cells of an n1 x n2 grid around (u, v) in [0, 1]^2 and bilinear weights over cell centres: cells
    (c00, c10, c01, c11) as b n1 + a and (fa, fb). ``wrap_u`` != 0 wraps the first axis; the second is clamped."""
    s = u * float(n1) - 0.5
    t = v * float(n2) - 0.5
    fs = wp.floor(s)
    ft = wp.floor(t)
    fa = s - fs
    fb = t - ft
    a0 = int(fs)
    b0 = int(ft)
    a1 = a0 + 1
    if wrap_u != 0:
        if a0 < 0:
            a0 = a0 + n1
        if a1 >= n1:
            a1 = a1 - n1
    else:
        a0 = wp.clamp(a0, 0, n1 - 1)
        a1 = wp.clamp(a1, 0, n1 - 1)
    b1 = wp.clamp(b0 + 1, 0, n2 - 1)
    b0 = wp.clamp(b0, 0, n2 - 1)
    return wp.vec4i(b0 * n1 + a0, b0 * n1 + a1, b1 * n1 + a0, b1 * n1 + a1), wp.vec2(fa, fb)


@wp.func
def bilinear_blend(v00: float, v10: float, v01: float, v11: float, fx: float, fy: float) -> float:
    """Bilinear interpolation of the corner values v00, v10, v01, v11 with fractions (fx, fy) in [0, 1]^2."""
    return (1.0 - fy) * ((1.0 - fx) * v00 + fx * v10) + fy * ((1.0 - fx) * v01 + fx * v11)


@wp.func
def bilinear_pick(xi: wp.vec2, w: wp.vec2) -> wp.vec2i:
    """Corner (dx, dy) of a bilinear stencil with fractions ``w``, chosen by ``xi`` in [0, 1)^2 with its weight."""
    dx = int(0)
    dy = int(0)
    if xi[0] < w[0]:
        dx = 1
    if xi[1] < w[1]:
        dy = 1
    return wp.vec2i(dx, dy)


@wp.func
def randf4(state: wp.uint32) -> tuple[wp.vec4, wp.uint32]:
    """Four uniform numbers in [0, 1) drawn in order from the random ``state``, and the advanced state."""
    xi = wp.vec4(wp.randf(state), wp.randf(state), wp.randf(state), wp.randf(state))
    return xi, state


@wp.func
def roulette_numbers(filter_mode: int, seed: int, query: int) -> wp.vec4:
    """The uniforms ``xi`` of query ``query`` (stream (seed, query)) under FILTER_ROULETTE; zero otherwise."""
    if filter_mode == FILTER_ROULETTE:
        xi, _state = randf4(wp.rand_init(seed, query))
        return xi
    return wp.vec4(0.0)


@wp.func
def _texel_stencil(sx: float, sy: float) -> tuple[wp.vec2i, wp.vec2]:
    """Lower-corner texel (x0, y0) of the 2x2 stencil at filter coordinates (sx, sy) and the fractions past it."""
    fx0 = wp.floor(sx)
    fy0 = wp.floor(sy)
    return wp.vec2i(int(fx0), int(fy0)), wp.vec2(sx - fx0, sy - fy0)


@wp.func
def _map_pcf(csm: Any, cell: int, p: wp.vec3, bias: float) -> float:
    sequence, s = _map_footprint(csm, cell, p)
    if sequence < 0:
        return 1.0
    c, f = _texel_stencil(s[0], s[1])
    v00 = _texel_test(csm, sequence, c[0], c[1], s[2], bias)
    v10 = _texel_test(csm, sequence, c[0] + 1, c[1], s[2], bias)
    v01 = _texel_test(csm, sequence, c[0], c[1] + 1, s[2], bias)
    v11 = _texel_test(csm, sequence, c[0] + 1, c[1] + 1, s[2], bias)
    return bilinear_blend(v00, v10, v01, v11, f[0], f[1])


@wp.func
def _map_roulette(csm: Any, cell: int, p: wp.vec3, bias: float, xi: wp.vec2) -> float:
    """One of the 4 texel tests of :func:`_map_pcf`, picked with its weight by ``xi`` (texel x, texel y)."""
    sequence, s = _map_footprint(csm, cell, p)
    if sequence < 0:
        return 1.0
    c, f = _texel_stencil(s[0], s[1])
    d = bilinear_pick(xi, f)
    return _texel_test(csm, sequence, c[0] + d[0], c[1] + d[1], s[2], bias)


@wp.func
def _cells_pcf(csm: Any, cells: wp.vec4i, w: wp.vec2, p: wp.vec3, bias: float) -> float:
    """Generalised PCF: the 4-texel PCF of ``p`` in the maps of the 2^2 ``cells``, blended with weights ``w``."""
    v00 = _map_pcf(csm, cells[0], p, bias)
    v10 = _map_pcf(csm, cells[1], p, bias)
    v01 = _map_pcf(csm, cells[2], p, bias)
    v11 = _map_pcf(csm, cells[3], p, bias)
    return bilinear_blend(v00, v10, v01, v11, w[0], w[1])


@wp.func
def _cells_roulette(csm: Any, cells: wp.vec4i, w: wp.vec2, p: wp.vec3, bias: float, xi: wp.vec4) -> float:
    """One of the 16 comparisons of :func:`_cells_pcf`, picked with its weight by ``xi``."""
    d = bilinear_pick(wp.vec2(xi[0], xi[1]), w)
    return _map_roulette(csm, cells[d[0] + 2 * d[1]], p, bias, wp.vec2(xi[2], xi[3]))




@wp.func
def csm_segment_depth(csm: CSMData, texel: int, sequence: int) -> float:
    """Stored depth of ``texel`` in map ``sequence`` of a lat-long CSM (:func:`segment_lookup`)."""
    return segment_lookup(csm.seg_start, csm.seg_depth, csm.seg_end, texel, sequence)


@wp.func
def csm_nearest_cell_uv(csm: CSMData, uv: wp.vec2) -> int:
    """Grid cell b n1 + a of the map selected for lat-long parameters ``uv`` (nearest cell centre)."""
    a = wp.min(int(uv[0] * float(csm.n1)), csm.n1 - 1)
    b = wp.min(int(uv[1] * float(csm.n2)), csm.n2 - 1)
    return b * csm.n1 + a


@wp.func
def csm_nearest_cell(csm: CSMData, d: wp.vec3) -> int:
    """Grid cell b n1 + a of the map selected for direction ``d`` (nearest cell centre in (u, v))."""
    return csm_nearest_cell_uv(csm, latlong_param(d))


@wp.func
def csm_bilinear_cells_uv(csm: CSMData, uv: wp.vec2) -> tuple[wp.vec4i, wp.vec2]:
    """:func:`csm_bilinear_cells` of the direction of lat-long parameters ``uv``."""
    return grid_bilinear(uv[0], uv[1], csm.n1, csm.n2, 1)


@wp.func
def csm_bilinear_cells(csm: CSMData, d: wp.vec3) -> tuple[wp.vec4i, wp.vec2]:
    """The 2^2 cells around direction ``d`` and their bilinear weights (fa, fb), as :func:`grid_bilinear`."""
    return csm_bilinear_cells_uv(csm, latlong_param(d))


@wp.func
def csm_project(csm: CSMData, cell: int, p: wp.vec3) -> wp.vec3:
    """q = D_i p for the map of ``cell``: continuous texel (x, y) (row y from the top) and linear depth q_z."""
    f = csm.frames[cell]
    r = p - csm.center
    half = 0.5 * float(csm.resolution)
    x = (wp.dot(r, f[0]) / csm.radius + 1.0) * half
    y = (1.0 - wp.dot(r, f[1]) / csm.radius) * half
    return wp.vec3(x, y, csm.radius - wp.dot(r, f[2]))


@wp.func
def csm_texel_visibility(csm: CSMData, sequence: int, x: int, y: int, depth: float, bias: float) -> float:
    """Depth test of one texel of map ``sequence``: 0 when depth - bias > z stored, else 1 (1 outside the map)."""
    m = csm.resolution
    if x < 0 or y < 0 or x >= m or y >= m:
        return 1.0
    if depth - bias > csm_segment_depth(csm, y * m + x, sequence):
        return 0.0
    return 1.0


@wp.func
def _texel_test(csm: CSMData, sequence: int, x: int, y: int, depth: float, bias: float) -> float:
    return csm_texel_visibility(csm, sequence, x, y, depth, bias)


@wp.func
def _map_footprint(csm: CSMData, cell: int, p: wp.vec3) -> tuple[int, wp.vec3]:
    """Lat-long footprint: none (-1) when the 2x2 texels around q = D_i p all lie outside the map (or NaN)."""
    q = csm_project(csm, cell, p)
    m = float(csm.resolution)
    sx = q[0] - 0.5
    sy = q[1] - 0.5
    if not (sx > -1.0 and sx < m and sy > -1.0 and sy < m):
        return -1, wp.vec3(0.0)
    return csm.map_index[cell], wp.vec3(sx, sy, q[2])


@wp.func
def csm_map_visibility(csm: CSMData, cell: int, p: wp.vec3, bias: float) -> float:
    """Nearest-texel visibility of ``p`` in the map of ``cell``."""
    q = csm_project(csm, cell, p)
    m = float(csm.resolution)
    if not (q[0] >= 0.0 and q[0] < m and q[1] >= 0.0 and q[1] < m):
        return 1.0  # also catches NaN
    return csm_texel_visibility(csm, csm.map_index[cell], int(q[0]), int(q[1]), q[2], bias)


@wp.func
def csm_map_pcf(csm: CSMData, cell: int, p: wp.vec3, bias: float) -> float:
    """Bilinear percentage-closer filter over the 4 texels around ``p`` in the map of ``cell``."""
    return _map_pcf(csm, cell, p, bias)


@wp.func
def csm_visibility(csm: CSMData, p: wp.vec3, d: wp.vec3, bias: float) -> float:
    """Binary visibility of the ray from ``p`` towards ``d`` (any length > 0): nearest map, nearest texel."""
    return csm_map_visibility(csm, csm_nearest_cell(csm, d), p, bias)


@wp.func
def csm_visibility_pcf(csm: CSMData, p: wp.vec3, d: wp.vec3, bias: float) -> float:
    """Generalised PCF (Ritschel 2007 Sec. 4.5): 4 nearest maps x 4 texels, bilinear weights, in [0, 1]."""
    cells, w = csm_bilinear_cells(csm, d)
    return _cells_pcf(csm, cells, w, p, bias)


@wp.func
def csm_visibility_roulette(csm: CSMData, p: wp.vec3, d: wp.vec3, bias: float, xi: wp.vec4) -> float:
    """Russian-roulette filter (Sec. 4.5): one of the 16 PCF comparisons, picked with its PCF weight by ``xi`` in
    [0, 1)^4. E[result] = :func:`csm_visibility_pcf`."""
    cells, w = csm_bilinear_cells(csm, d)
    return _cells_roulette(csm, cells, w, p, bias, xi)


@wp.func(inline=True)
def csm_visibility_filtered_uv(csm: CSMData, p: wp.vec3, uv: wp.vec2, bias: float, filter_mode: int,
                               xi: wp.vec4) -> float:
    """:func:`csm_visibility_filtered` for a direction whose lat-long parameters ``uv`` the caller already has."""
    if filter_mode == FILTER_PCF:
        cells, w = csm_bilinear_cells_uv(csm, uv)
        return _cells_pcf(csm, cells, w, p, bias)
    if filter_mode == FILTER_ROULETTE:
        cells, w = csm_bilinear_cells_uv(csm, uv)
        return _cells_roulette(csm, cells, w, p, bias, xi)
    return csm_map_visibility(csm, csm_nearest_cell_uv(csm, uv), p, bias)


@wp.func(inline=True)
def csm_visibility_filtered(csm: CSMData, p: wp.vec3, d: wp.vec3, bias: float, filter_mode: int, xi: wp.vec4) -> float:
    """Visibility with the filter ``filter_mode`` (``xi`` used by the roulette only)."""
    return csm_visibility_filtered_uv(csm, p, latlong_param(d), bias, filter_mode, xi)


@wp.func
def csm_visibility_to_point(csm: CSMData, p: wp.vec3, light_point: wp.vec3, bias: float) -> float:
    """Semi-local lights (Sec. 4.3): visibility between ``p`` and a light point, the distant query with d = l - p."""
    return csm_visibility(csm, p, light_point - p, bias)


@wp.func
def csm_object_space(inv_transform: wp.mat44, p: wp.vec3, d: wp.vec3) -> tuple[wp.vec3, wp.vec3]:
    """World point and direction -> object space of an object placed by T (Sec. 4.6: D' = D T^-1, T^-1 affine)."""
    return wp.transform_point(inv_transform, p), wp.transform_vector(inv_transform, d)




@wp.func
def cube_face(w: wp.vec3) -> int:
    """Cube face k = 0..5 (+X, -X, +Y, -Y, +Z, -Z) that direction ``w`` falls on (its major axis)."""
    ax = wp.abs(w[0])
    ay = wp.abs(w[1])
    az = wp.abs(w[2])
    if ax >= ay and ax >= az:
        if w[0] >= 0.0:
            return 0
        return 1
    if ay >= az:
        if w[1] >= 0.0:
            return 2
        return 3
    if w[2] >= 0.0:
        return 4
    return 5


@wp.func
def csm_cube_project(csm: CubeCSMData, cell: int, p: wp.vec3) -> tuple[int, wp.vec3]:
    """Face k and q = (x, y, depth) of ``p`` in the cube map of light sample ``cell`` (linear depth along the
    face axis); a point at the sample itself gets x = -1 (lit)."""
    w = p - csm.samples[cell]
    k = cube_face(w)
    f = csm.faces[k]
    z = wp.dot(w, f[2])
    if not (z > 0.0):
        return k, wp.vec3(-1.0, -1.0, 0.0)
    half = 0.5 * float(csm.resolution)
    x = (wp.dot(w, f[0]) / z + 1.0) * half
    y = (1.0 - wp.dot(w, f[1]) / z) * half
    return k, wp.vec3(x, y, z)


@wp.func
def csm_cube_texel_visibility(csm: CubeCSMData, sequence: int, x: int, y: int, depth: float, bias: float) -> float:
    """Depth test of one texel of cube-face map ``sequence`` (= k N + i); texels are clamped to the face."""
    m = csm.resolution
    xc = wp.clamp(x, 0, m - 1)
    yc = wp.clamp(y, 0, m - 1)
    if depth - bias > segment_lookup(csm.seg_start, csm.seg_depth, csm.seg_end, yc * m + xc, sequence):
        return 0.0
    return 1.0


@wp.func
def _texel_test(csm: CubeCSMData, sequence: int, x: int, y: int, depth: float, bias: float) -> float:  # noqa: F811
    return csm_cube_texel_visibility(csm, sequence, x, y, depth, bias)


@wp.func
def _map_footprint(csm: CubeCSMData, cell: int, p: wp.vec3) -> tuple[int, wp.vec3]:  # noqa: F811
    """Cube footprint: in face k of sample ``cell``; none (-1) for a point at the sample itself."""
    k, q = csm_cube_project(csm, cell, p)
    if q[0] < 0.0:
        return -1, wp.vec3(0.0)
    return k * csm.num_samples + csm.map_index[cell], wp.vec3(q[0] - 0.5, q[1] - 0.5, q[2])


@wp.func
def csm_cube_sample_visibility(csm: CubeCSMData, cell: int, p: wp.vec3, bias: float) -> float:
    """Nearest-texel visibility between light sample ``cell`` and ``p`` (Ritschel 2007 Fig. 7 left)."""
    k, q = csm_cube_project(csm, cell, p)
    if q[0] < 0.0:
        return 1.0
    seq = k * csm.num_samples + csm.map_index[cell]
    return csm_cube_texel_visibility(csm, seq, int(q[0]), int(q[1]), q[2], bias)


@wp.func
def csm_cube_sample_pcf(csm: CubeCSMData, cell: int, p: wp.vec3, bias: float) -> float:
    """Bilinear PCF over the 4 texels around ``p`` in the selected face of sample ``cell``."""
    return _map_pcf(csm, cell, p, bias)


@wp.func
def csm_local_cell(csm: CubeCSMData, x: wp.vec2) -> int:
    """Light sample b n1 + a nearest to light parameters ``x`` in [0, 1]^2 (D(x) discretised, Sec. 4.2)."""
    a = wp.clamp(int(x[0] * float(csm.n1)), 0, csm.n1 - 1)
    b = wp.clamp(int(x[1] * float(csm.n2)), 0, csm.n2 - 1)
    return b * csm.n1 + a


@wp.func
def csm_local_visibility(csm: CubeCSMData, p: wp.vec3, x: wp.vec2, bias: float) -> float:
    """Visibility between ``p`` and the light point of parameters ``x`` (nearest sample, nearest texel)."""
    return csm_cube_sample_visibility(csm, csm_local_cell(csm, x), p, bias)


@wp.func
def csm_local_visibility_pcf(csm: CubeCSMData, p: wp.vec3, x: wp.vec2, bias: float) -> float:
    """Generalised PCF for local lights (Sec. 4.5): the 2^d nearest light samples times 4 texels."""
    cells, w = grid_bilinear(x[0], x[1], csm.n1, csm.n2, 0)
    return _cells_pcf(csm, cells, w, p, bias)


@wp.func
def csm_local_visibility_roulette(csm: CubeCSMData, p: wp.vec3, x: wp.vec2, bias: float, xi: wp.vec4) -> float:
    """Russian-roulette filter for local lights: one of the PCF comparisons, picked with its weight."""
    cells, w = grid_bilinear(x[0], x[1], csm.n1, csm.n2, 0)
    return _cells_roulette(csm, cells, w, p, bias, xi)


@wp.func(inline=True)
def csm_local_visibility_filtered(
    csm: CubeCSMData, p: wp.vec3, x: wp.vec2, bias: float, filter_mode: int, xi: wp.vec4
) -> float:
    """Local-light visibility with the filter ``filter_mode`` (FILTER_NEAREST, FILTER_PCF, FILTER_ROULETTE)."""
    if filter_mode == FILTER_PCF:
        return csm_local_visibility_pcf(csm, p, x, bias)
    if filter_mode == FILTER_ROULETTE:
        return csm_local_visibility_roulette(csm, p, x, bias, xi)
    return csm_local_visibility(csm, p, x, bias)




@wp.struct
class CSMObjects:
    """Rigid objects (Sec. 4.6) as :func:`visibility_kernel` sees them (:func:`object_arrays`)."""

    csms: wp.array(dtype=CSMData)  # each object's lat-long CSM (object space)
    inv_transforms: wp.array(dtype=wp.mat44)  # each object's world -> object matrix T^-1


@wp.func
def batch_visibility(csm: CSMData, p: wp.vec3, d: wp.vec3, bias: float, filter_mode: int, seed: int,
                     query: int) -> float:
    """Query ``query`` of a batch against one lat-long CSM: (point, direction towards the light)."""
    xi = roulette_numbers(filter_mode, seed, query)
    return csm_visibility_filtered(csm, p, d, bias, filter_mode, xi)


@wp.func
def batch_visibility(csm: CubeCSMData, p: wp.vec3, x: wp.vec2, bias: float, filter_mode: int,  # noqa: F811
                     seed: int, query: int) -> float:
    """Query ``query`` of a batch against a local light's cube CSM: (point, light parameters x in [0, 1]^2)."""
    xi = roulette_numbers(filter_mode, seed, query)
    return csm_local_visibility_filtered(csm, p, x, bias, filter_mode, xi)


@wp.func
def batch_visibility(objects: CSMObjects, p: wp.vec3, d: wp.vec3, bias: float, filter_mode: int,  # noqa: F811
                     seed: int, query: int) -> float:
    """Query against rigid objects: the product of each object's filtered visibility (D' = D T^-1)."""
    state = wp.rand_init(seed, query)
    v = float(1.0)
    for k in range(objects.csms.shape[0]):
        po, do = csm_object_space(objects.inv_transforms[k], p, d)
        xi, state = randf4(state)
        v = v * csm_visibility_filtered(objects.csms[k], po, do, bias, filter_mode, xi)
        if v == 0.0:
            break
    return v


@wp.kernel
def visibility_kernel(
    csm: Any,
    points: wp.array(dtype=wp.vec3),
    queries: wp.array(dtype=Any),
    bias: float,
    filter_mode: int,
    seed: int,
    out: wp.array(dtype=wp.float32),
    offset: int,
):
    """out[i] = filtered visibility of points[i] and queries[i] (a direction or light parameters) against ``csm``."""
    i = wp.tid() + offset
    out[i] = batch_visibility(csm, points[i], queries[i], bias, filter_mode, seed, i)


#: The query type of each CSM struct; one compiled overload of :func:`visibility_kernel` each.
QUERY_TYPES = {CSMData: wp.vec3, CubeCSMData: wp.vec2, CSMObjects: wp.vec3}
for _struct, _query in QUERY_TYPES.items():
    wp.overload(visibility_kernel, {"csm": _struct, "queries": wp.array(dtype=_query)})




def csm_device_data(csm: CoherentShadowMap, device: str | None = None) -> CSMData | CubeCSMData:
    """The :class:`CSMData` or :class:`CubeCSMData` of a CSM on ``device`` (uploaded once, cached on the CSM)."""
    device = default_device(device)
    key = str(device)
    if key not in csm._device_cache:
        if csm.kind == KIND_CUBE:
            d = CubeCSMData()
            d.num_samples = int(csm.num_cells)
            d.faces = wp.array(cube_face_frames().astype(np.float32), dtype=wp.mat33, device=device)
            d.samples = wp.array(np.asarray(csm.light_samples, np.float32), dtype=wp.vec3, device=device)
        else:
            d = CSMData()
            d.center = wp.vec3(*(float(x) for x in csm.center))
            d.radius = float(csm.radius)
            d.num_maps = int(csm.num_maps)
            d.frames = wp.array(csm.frames.astype(np.float32), dtype=wp.mat33, device=device)
        d.resolution = int(csm.resolution)
        d.n1, d.n2 = int(csm.n1), int(csm.n2)
        d.map_index = wp.array(csm.map_index.ravel().astype(np.int32), dtype=wp.int32, device=device)
        d.seg_start = wp.array(csm.lists.seg_start, dtype=wp.int32, device=device)
        d.seg_depth = wp.array(csm.lists.seg_depth, dtype=wp.float32, device=device)
        d.seg_end = wp.array(csm.lists.seg_end, dtype=wp.int32, device=device)
        csm._device_cache[key] = d
    return csm._device_cache[key]
