"""What the Monte-Carlo direct-lighting estimators share (Ritschel et al. 2007 Sec. 5): the surface points, the
visibility source, the strata and the progressive average.

The estimators (:mod:`.environment`, :mod:`.local_lights`) shade K surface points with S = s^2 jittered strata
(Sec. 5.1). Visibility modes: ``VIS_CSM`` (a lat-long CSM towards a distant direction, Sec. 4.1, or a local light's
cube CSM, Sec. 4.2), ``VIS_SEMI_LOCAL`` (a lat-long CSM towards a local light's point, Sec. 4.3), ``VIS_OBJECTS``
(rigid objects, each CSM queried with D' = D T^-1, Sec. 4.6), ``VIS_MESH`` (shadow rays, the reference) and
``VIS_NONE``. The per-sample functions are inlined: an out-of-line call copies its struct arguments on the CPU.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..raster.raycast import occluded
from ..runtime import parallel
from ..runtime.device import default_device, module_options
from .batch import object_arrays
from .brdf import MaterialTable
from .compress import KIND_LATLONG, CoherentShadowMap
from .query import FILTERS, CSMData, CubeCSMData, csm_device_data, csm_visibility_filtered

module_options()

VIS_NONE = wp.constant(0)
VIS_CSM = wp.constant(1)
VIS_MESH = wp.constant(2)
VIS_SEMI_LOCAL = wp.constant(3)
VIS_OBJECTS = wp.constant(4)


@wp.struct
class SurfacePoints:
    """The points an estimator shades, as kernels see them (:func:`surface_points`): positions (scene units; with a
    lat-long CSM in its object space), normals and directions to the viewer (any non-zero length), material rows."""

    points: wp.array(dtype=wp.vec3)
    normals: wp.array(dtype=wp.vec3)
    view_dirs: wp.array(dtype=wp.vec3)
    material_index: wp.array(dtype=wp.int32)


@wp.struct
class LightVisibility:
    """The visibility source of an estimator, as kernels see it (:func:`light_visibility`): ``mode`` (a VIS_*
    constant); the lat-long CSM (VIS_CSM of a distant light, VIS_SEMI_LOCAL) or cube CSM (VIS_CSM of a local light),
    1x1 placeholders otherwise; a FILTER_* ``filter_mode``, depth ``bias`` and normal offset ``eps`` (scene units);
    the occluders' BVH ``mesh`` (VIS_MESH); for VIS_OBJECTS each object's lat-long CSM (object space), world ->
    object matrix T^-1 and depth bias (object units), and a ``world_bias`` (scene units) taken to each object's space
    along the query."""

    mode: int
    latlong: CSMData
    cube: CubeCSMData
    filter_mode: int
    bias: float
    mesh: wp.uint64
    eps: float
    objects: wp.array(dtype=CSMData)
    to_object: wp.array(dtype=wp.mat44)
    object_bias: wp.array(dtype=float)
    world_bias: float


@wp.func(inline=True)
def objects_visibility(vis: LightVisibility, o: wp.vec3, d: wp.vec3, xi: wp.vec4) -> float:
    """VIS_OBJECTS: product over the objects of the filtered visibility from ``o`` towards ``d`` (Sec. 4.6)."""
    v = float(1.0)
    for k in range(vis.objects.shape[0]):
        po = wp.transform_point(vis.to_object[k], o)
        do = wp.transform_vector(vis.to_object[k], d)
        # a scene-unit length along d is |T^-1 d| / |d| object units (exact for non-uniform scale too)
        bias = vis.object_bias[k] + vis.world_bias * wp.length(do) / wp.max(wp.length(d), 1.0e-30)
        v = v * csm_visibility_filtered(vis.objects[k], po, do, bias, vis.filter_mode, xi)
    return v


@wp.func(inline=False)
def shadow_ray_blocked(mesh: wp.uint64, origin: wp.vec3, direction: wp.vec3, t_max: float) -> bool:
    """A shadow ray's any-hit query, kept out of line: the BVH traversal is long and its arguments are few."""
    return occluded(mesh, origin, direction, t_max)


@wp.func
def stratum_sample(k: int, s: int, jitter: wp.vec2) -> wp.vec2:
    """Point of stratum ``k`` of an s x s grid over [0, 1)^2 jittered by ``jitter`` (Sec. 5.1)."""
    a = k % s
    b = k // s
    return wp.vec2((float(a) + jitter[0]) / float(s), (float(b) + jitter[1]) / float(s))


@wp.func
def surface_point(surf: SurfacePoints, k: int):
    """Point k of ``surf``: (position, unit normal, unit direction to the viewer, material index)."""
    return surf.points[k], wp.normalize(surf.normals[k]), wp.normalize(surf.view_dirs[k]), surf.material_index[k]


@wp.func
def stratum_random_numbers(rng: wp.uint32):
    """The uniforms of one stratum, in order: light and BRDF sample jitter, lobe choice, four per sample for the
    roulette filter. Returns them and the advanced state (Warp passes the state by value)."""
    j_light = wp.vec2(wp.randf(rng), wp.randf(rng))
    j_brdf = wp.vec2(wp.randf(rng), wp.randf(rng))
    choice = wp.randf(rng)
    xi_light = wp.vec4(wp.randf(rng), wp.randf(rng), wp.randf(rng), wp.randf(rng))
    xi_brdf = wp.vec4(wp.randf(rng), wp.randf(rng), wp.randf(rng), wp.randf(rng))
    return j_light, j_brdf, choice, xi_light, xi_brdf, rng




class ProgressiveAccumulator:
    """Running mean of Monte-Carlo passes (Ritschel 2007 Sec. 5.2: m frames blended with weight 1 / m)."""

    def __init__(self):
        self._sum: np.ndarray | None = None
        self.passes = 0

    def add(self, frame) -> np.ndarray:
        """Add one pass (any shape, the same for every pass) and return the running mean (float32); ValueError for
        another shape or non-finite values."""
        f = np.asarray(frame, dtype=np.float64)
        if not np.all(np.isfinite(f)):
            raise ValueError("frame contains non-finite values")
        if self._sum is None:
            self._sum = np.zeros_like(f)
        elif f.shape != self._sum.shape:
            raise ValueError(f"frame must have shape {self._sum.shape} like the earlier passes, got {f.shape}")
        self._sum += f
        self.passes += 1
        return self.mean

    @property
    def mean(self) -> np.ndarray:
        """The current mean of all passes (float32); ValueError before the first pass."""
        if self._sum is None:
            raise ValueError("no pass has been added yet")
        return (self._sum / self.passes).astype(np.float32)

    def reset(self) -> None:
        """Forget all passes (call after the scene, camera or lighting changed)."""
        self._sum = None
        self.passes = 0


def _rows3(a, name: str, k: int | None, default=None) -> np.ndarray:
    if a is None:
        return np.ascontiguousarray(np.broadcast_to(np.asarray(default, np.float32), (k, 3)))
    try:
        v = np.asarray(a, dtype=np.float32)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric (K, 3) array") from exc
    if k is not None and v.shape == (3,):
        v = np.broadcast_to(v, (k, 3))
    if v.ndim != 2 or v.shape[1] != 3 or (k is not None and v.shape[0] != k):
        want = "(K, 3)" if k is None else f"({k}, 3) or (3,)"
        raise ValueError(f"{name} must have shape {want}, got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name} contains non-finite values")
    return np.ascontiguousarray(v)


_placeholders: dict = {}


def placeholder_csms(device: str) -> tuple[CSMData, CubeCSMData]:
    """A 1 x 1 lat-long and a one-sample cube CSM struct, for launches that query neither."""
    if device not in _placeholders:
        from .depthmaps import cube_face_frames

        d = CSMData()
        d.center = wp.vec3(0.0, 0.0, 0.0)
        d.radius = 1.0
        d.resolution = 1
        d.n1, d.n2, d.num_maps = 1, 1, 1
        d.frames = wp.array(np.eye(3, dtype=np.float32)[None], dtype=wp.mat33, device=device)
        d.map_index = wp.zeros(1, dtype=wp.int32, device=device)
        d.seg_start = wp.array(np.array([0, 1], np.int32), dtype=wp.int32, device=device)
        d.seg_depth = wp.array(np.array([np.inf], np.float32), dtype=wp.float32, device=device)
        d.seg_end = wp.zeros(1, dtype=wp.int32, device=device)
        c = CubeCSMData()
        c.resolution, c.n1, c.n2, c.num_samples = 1, 1, 1, 1
        c.faces = wp.array(cube_face_frames().astype(np.float32), dtype=wp.mat33, device=device)
        c.samples = wp.zeros(1, dtype=wp.vec3, device=device)
        c.map_index = wp.zeros(1, dtype=wp.int32, device=device)
        c.seg_start = wp.array(np.array([0, 1], np.int32), dtype=wp.int32, device=device)
        c.seg_depth = wp.array(np.array([np.inf], np.float32), dtype=wp.float32, device=device)
        c.seg_end = wp.array(np.array([5], np.int32), dtype=wp.int32, device=device)
        _placeholders[device] = (d, c)
    return _placeholders[device]


def surface_inputs(points, normals, albedo, *, view_dirs=None, specular=None, exponent=1.0, materials=None,
                   material_index=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, MaterialTable]:
    """Checked per-point inputs (points, normals, view_dirs, material_index (K,) int32, materials) of Lambert + Phong
    per point, or of a :class:`MaterialTable` with ``material_index``; ValueError for malformed ones."""
    p = _rows3(points, "points", None)
    k = p.shape[0]
    n = _rows3(normals, "normals", k)
    if np.any(np.all(n == 0.0, axis=1)):
        raise ValueError("normals must be non-zero")
    wo = n if view_dirs is None else _rows3(view_dirs, "view_dirs", k)
    if np.any(np.all(wo == 0.0, axis=1)):
        raise ValueError("view_dirs must be non-zero")
    if materials is not None:
        if not isinstance(materials, MaterialTable):
            raise ValueError(f"materials must be a MaterialTable, got {type(materials).__name__}")
        if albedo is not None or specular is not None:
            raise ValueError("give either materials (with material_index) or albedo / specular, not both")
        idx = np.zeros(k, np.int32) if material_index is None else np.asarray(material_index)
        if idx.shape != (k,) or not np.issubdtype(idx.dtype, np.integer):
            raise ValueError(f"material_index must be ({k},) integers")
        if k and (idx.min() < 0 or idx.max() >= len(materials)):
            raise ValueError(f"material_index must lie in [0, {len(materials)})")
        return p, n, wo, np.ascontiguousarray(idx, np.int32), materials
    kd = _rows3(albedo, "albedo", k)
    ks = _rows3(specular, "specular", k, default=0.0)
    e = np.asarray(exponent, dtype=np.float32)
    if e.ndim == 0:
        e = np.full(k, float(e), np.float32)
    if e.shape != (k,) or not np.all(np.isfinite(e)) or np.any(e < 0.0):
        raise ValueError(f"exponent must be a finite scalar or ({k},) array >= 0")
    if k == 0:
        return p, n, wo, np.zeros(0, np.int32), MaterialTable(np.zeros((1, 3), np.float32))
    return p, n, wo, np.arange(k, dtype=np.int32), MaterialTable.phong(kd, ks, e)


def check_strata(samples) -> int:
    """s for ``samples`` = s^2 >= 1 strata; ValueError if not a positive perfect square."""
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 1:
        raise ValueError(f"samples must be a positive integer, got {samples!r}")
    strata = math.isqrt(int(samples))
    if strata * strata != samples:
        raise ValueError(f"samples must be a perfect square (jittered s x s grid), got {samples}")
    return strata


def check_visibility_source(filter: str, bias, ray_eps, csm, mesh, objects=None) -> None:
    """ValueError for an unknown filter, a bad bias / ray_eps, several sources or a ``mesh`` not a ``wp.Mesh``."""
    if sum(x is not None for x in (csm, mesh, objects)) > 1:
        raise ValueError("give at most one of csm, mesh and objects as the visibility source")
    if objects is not None and not list(objects):
        raise ValueError("objects must hold at least one (csm, transform) pair")
    if filter not in FILTERS:
        raise ValueError(f"filter must be one of {tuple(FILTERS)}, got {filter!r}")
    if not np.isfinite(bias) or bias < 0.0:
        raise ValueError(f"bias must be a finite number >= 0, got {bias!r}")
    if not np.isfinite(ray_eps) or ray_eps < 0.0:
        raise ValueError(f"ray_eps must be a finite number >= 0, got {ray_eps!r}")
    if mesh is not None and not isinstance(mesh, wp.Mesh):
        raise ValueError(f"mesh must be a wp.Mesh, got {type(mesh).__name__}")


def light_visibility(csm: CoherentShadowMap | None, mesh: wp.Mesh | None, *, filter: str, bias: float,
                     ray_eps: float, device: str, objects=None, object_bias=None) -> LightVisibility:
    """:class:`LightVisibility` of a CSM, a ``wp.Mesh``, rigid ``objects`` (``(csm, transform)`` pairs; without
    ``object_bias`` the scene-unit ``bias`` is taken into each object's space) or none. The caller switches a
    lat-long CSM of a local light to ``VIS_SEMI_LOCAL``."""
    v = LightVisibility()
    v.latlong, v.cube = placeholder_csms(device)
    v.mode, v.mesh = VIS_NONE, wp.uint64(0)
    if objects is None:  # 1-element placeholders (kernels need arrays either way)
        v.objects = wp.array([v.latlong], dtype=CSMData, device=device)
        v.to_object = wp.array(np.eye(4, dtype=np.float32)[None], dtype=wp.mat44, device=device)
    else:
        v.objects, v.to_object = object_arrays(objects, device)
    per_object = object_bias is not None
    biases = list(object_bias) if per_object else [0.0] * (len(objects) if objects is not None else 1)
    v.object_bias = wp.array(np.asarray(biases, np.float32), dtype=float, device=device)
    v.world_bias = 0.0 if per_object else float(bias)
    if objects is not None:
        v.mode = VIS_OBJECTS
    elif csm is not None:
        v.mode = VIS_CSM
        if csm.kind == KIND_LATLONG:
            v.latlong = csm_device_data(csm, device)
        else:
            v.cube = csm_device_data(csm, device)
    elif mesh is not None:
        v.mode, v.mesh = VIS_MESH, mesh.id
    v.filter_mode, v.bias, v.eps = FILTERS[filter], float(bias), float(ray_eps)
    return v


def surface_points(p: np.ndarray, n: np.ndarray, wo: np.ndarray, idx: np.ndarray, device: str) -> SurfacePoints:
    """:class:`SurfacePoints` of checked (:func:`surface_inputs`) host arrays."""
    s = SurfacePoints()
    s.points, s.normals, s.view_dirs = (wp.array(a, dtype=wp.vec3, device=device) for a in (p, n, wo))
    s.material_index = wp.array(idx, dtype=wp.int32, device=device)
    return s


#: Chunks per worker thread of a CPU pass: points differ in cost, so a few more chunks than threads balance the load.
CHUNKS_PER_THREAD = 8


def launch_points(kernel, count: int, inputs: list, device: str, threads: int | None = None) -> None:
    """Launch ``kernel(*inputs, offset)`` over ``count`` points: CPU chunks per thread, one launch on CUDA."""
    if count == 0:
        return
    n = threads or parallel.thread_count()
    if not wp.get_device(device).is_cpu or n <= 1:
        wp.launch(kernel, dim=count, inputs=[*inputs, 0], device=device)
        return
    wp.load_module(kernel.module, device=device)

    def _one(piece):
        start, stop = piece
        wp.launch(kernel, dim=stop - start, inputs=[*inputs, start], device=device)

    parallel.run_parallel(_one, parallel.chunks(count, CHUNKS_PER_THREAD * n, min_chunk=256), n)


def shade_points(kernel, surface: tuple, light_data, strata: int, vis: LightVisibility, table: MaterialTable,
                 seed: int, device: str, threads: int | None) -> np.ndarray:
    """Launch an estimator over the points of ``surface``; (K, 3) float32 radiance."""
    p, n, wo, idx = surface
    k = p.shape[0]
    out = wp.zeros(k, dtype=wp.vec3, device=device)
    launch_points(kernel, k, [surface_points(p, n, wo, idx, device), table.device_data(device), light_data, strata,
                              vis, int(seed) & 0x7FFFFFFF, out], device, threads)
    return out.numpy()


@dataclass(frozen=True)
class ShadingOptions:
    """The keyword arguments of :class:`DirectLighting` and :func:`shade_direct` (except ``seed``).

    Attributes:
        samples: S strata per point, s^2 >= 1 (one light and one BRDF sample each, balance heuristic).
        csm: a lat-long CSM (distant or semi-local lights, Sec. 4.3) or the local light's cube CSM (Sec. 4.2).
        mesh: ``wp.Mesh`` of the occluders for exact shadow rays (the reference).
        objects: rigid objects (Sec. 4.6): ``(csm, transform)`` pairs, object -> world 4x4. At most one of
            csm / mesh / objects; none: no occlusion.
        object_bias: one depth bias per object (object-space units); default: ``bias`` taken into each object.
        view_dirs, specular, exponent: (K, 3) or (3,) directions to the viewer (default: the normal), Phong k_s
            (default 0), (K,) or scalar Phong exponent n >= 0; or ``materials`` (a
            :class:`~warpscatter.csm.brdf.MaterialTable`) and their (K,) ``material_index`` (default 0).
        filter: CSM filter ``"nearest"``, ``"pcf"`` or ``"roulette"`` (Sec. 4.5).
        bias, ray_eps: CSM depth bias and offset of the query point along the normal (scene units, >= 0).
    """

    samples: int
    csm: CoherentShadowMap | None = None
    mesh: wp.Mesh | None = None
    objects: object = None
    object_bias: object = None
    view_dirs: object = None
    specular: object = None
    exponent: object = 1.0
    materials: MaterialTable | None = None
    material_index: object = None
    filter: str = "nearest"
    bias: float = 0.0
    ray_eps: float = 1.0e-4
    device: str | None = None
    threads: int | None = None


def shading_options(options: ShadingOptions | None, keywords: dict) -> ShadingOptions:
    """``options`` with ``keywords`` (fields of :class:`ShadingOptions`) replaced, or the options of ``keywords``."""
    return ShadingOptions(**keywords) if options is None else dataclasses.replace(options, **keywords)


class DirectLighting:
    """Monte-Carlo direct lighting of fixed surface points under one light, set up once for any number of passes
    (Ritschel 2007 Sec. 5.2; average them with :class:`ProgressiveAccumulator`); :meth:`shade` launches one pass per
    seed. Arguments and errors as :func:`shade_direct`."""

    def __init__(self, points, normals, albedo, light, options: ShadingOptions | None = None, **keywords):
        from ..scene.environment_map import EnvironmentMap
        from ..scene.lights import AreaLight, EnvironmentLight, LinearLight, VolumeLight

        o = shading_options(options, keywords)
        csm = o.csm
        device = default_device(o.device)
        strata = check_strata(o.samples)
        p, n, wo, idx, table = surface_inputs(points, normals, albedo, view_dirs=o.view_dirs, specular=o.specular,
                                              exponent=o.exponent, materials=o.materials,
                                              material_index=o.material_index)
        check_visibility_source(o.filter, o.bias, o.ray_eps, csm, o.mesh, o.objects)
        latlong = isinstance(csm, CoherentShadowMap) and csm.kind == KIND_LATLONG
        if isinstance(light, EnvironmentLight):
            light = light.env
        if isinstance(light, EnvironmentMap):
            from .environment import shade_environment_kernel as kernel

            if csm is not None and not latlong:
                raise ValueError("csm must be a lat-long CoherentShadowMap (build_csm)")
            light_data = light.device_data(device)
        elif isinstance(light, (AreaLight, LinearLight, VolumeLight)):
            from .local_lights import check_light_csm
            from .local_lights import shade_local_light_kernel as kernel

            if csm is not None and not latlong:
                if isinstance(light, VolumeLight):
                    raise ValueError("a volume light's visibility is semi-local: csm must be a lat-long "
                                     "CoherentShadowMap of the occluders (build_csm), not a cube CSM")
                check_light_csm(csm, light)
            light_data = light.device_data(device)
        else:
            raise ValueError(f"light must be an EnvironmentMap, AreaLight, LinearLight or VolumeLight, got "
                             f"{type(light).__name__}")
        vis = light_visibility(csm, o.mesh, filter=o.filter, bias=o.bias, ray_eps=o.ray_eps, device=device,
                               objects=o.objects, object_bias=o.object_bias)
        if latlong and not isinstance(light, EnvironmentMap):
            vis.mode = VIS_SEMI_LOCAL  # a lat-long CSM queried towards the local light's points
        self.count = int(p.shape[0])
        self.samples = int(o.samples)
        self.device = device
        self.threads = o.threads
        self._kernel = kernel
        self._inputs = [surface_points(p, n, wo, idx, device), table.device_data(device), light_data, strata, vis]
        self._out = wp.zeros(self.count, dtype=wp.vec3, device=device)

    def shade(self, seed: int = 0) -> np.ndarray:
        """One pass: (K, 3) float32 outgoing radiance, drawn with ``seed`` (a new seed per pass)."""
        launch_points(self._kernel, self.count, [*self._inputs, int(seed) & 0x7FFFFFFF, self._out], self.device,
                      self.threads)
        return self._out.numpy().copy()


def shade_direct(points, normals, albedo, light, options: ShadingOptions | None = None, *, seed: int = 0,
                 **keywords) -> np.ndarray:
    """Direct lighting at surface points from any Monte-Carlo light (Ritschel 2007 Sec. 4.2, 5), one pass: (K, 3)
    float32 outgoing radiance towards ``view_dirs``.

    Args:
        points, normals: (K, 3) positions (scene units; in a lat-long ``csm``'s object space) and normals (non-zero).
        albedo: (K, 3) or (3,) diffuse reflectance k_d (Lambert f = k_d / pi); None with ``materials``.
        light: an environment map or :class:`~warpscatter.scene.lights.EnvironmentLight`, an
            :class:`~warpscatter.scene.lights.AreaLight` or a :class:`~warpscatter.scene.lights.LinearLight`.
        options: :class:`ShadingOptions`, or its fields as keyword arguments.
        seed: random seed of this pass (one per progressive pass).

    Raises:
        ValueError: malformed inputs, a bad ``samples``, several visibility sources, a CSM that does not fit the
            light, an unknown filter or light, negative bias / ray_eps / exponent.
    """
    return DirectLighting(points, normals, albedo, light, options, **keywords).shade(seed)


__all__ = [
    "CHUNKS_PER_THREAD",
    "VIS_CSM",
    "VIS_MESH",
    "VIS_NONE",
    "VIS_OBJECTS",
    "VIS_SEMI_LOCAL",
    "objects_visibility",
    "DirectLighting",
    "LightVisibility",
    "ProgressiveAccumulator",
    "ShadingOptions",
    "SurfacePoints",
    "check_strata",
    "check_visibility_source",
    "launch_points",
    "light_visibility",
    "placeholder_csms",
    "shadow_ray_blocked",
    "shade_direct",
    "shade_points",
    "shading_options",
    "stratum_random_numbers",
    "stratum_sample",
    "surface_point",
    "surface_inputs",
    "surface_points",
]
