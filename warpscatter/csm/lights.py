"""Monte-Carlo direct lighting from local area and linear lights with coherent-shadow-map visibility
(Ritschel 2007, Sec. 4.2 and 5.1).

Lights (scene units, radiometric quantities in linear RGB):

- Area light: the parallelogram y(s, t) = corner + s u + t v, (s, t) in [0, 1]^2, area A = |u x v|, unit normal
  n_l = (u x v) / A. It emits constant radiance L_e from its front side (the side n_l points to), or from both
  sides when ``two_sided``. A light given by its power P has L_e = P / (pi A) (one-sided) or P / (2 pi A).
- Linear light: the segment y(s) = start + s (end - start), s in [0, 1], of length l, an isotropic line emitter
  of intensity I per unit length (W sr^-1 unit^-1): dE = I cos(theta_x) / d^2 dl. It has no area, so BRDF
  samples never hit it and only light sampling contributes.

Sampling "by radiance" (Sec. 5.1): with constant emission that is uniform in (s, t) (area) or s (linear); the
S = s^2 strata of the per-point jittered pattern stratify (s, t), and S strata stratify s of a linear light.
The area light's solid-angle density of a light sample y seen from x is d^2 / (A |cos theta_l|).

Estimator per stratum for an area light, balance heuristic [VG95] as for environment maps: one light sample,
f L_e V cos / (p_light + p_brdf), and one BRDF sample that contributes f L_e V cos / (p_brdf + p_light) when its
ray hits the parallelogram (on an emitting side). Linear lights: f I V cos(theta_x) / d^2 * l per stratum.

Visibility between x and the light point y of parameters (s, t): the local light's ``"cube"`` CSM
(:func:`~warpscatter.csm.query.csm_local_visibility_filtered`, depth cube maps at the light's sample points,
Sec. 3.3 / 4.2; the CSM must be built on the same parallelogram / segment so that (s, t) index its samples), or
a lat-long CSM of the occluders queried in direction y - x (semi-local lights, Sec. 4.3: valid while the light
stays outside the occluders' convex hull; one CSM serves any such light), or a ``wp.Mesh`` shadow ray from
x + eps n to y (the reference), or none.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from .. import parallel
from ..raycast import occluded
from ..wpinit import default_device, module_options
from .brdf import MaterialData, MaterialTable, material_eval, material_pdf, material_sample
from .compress import KIND_CUBE, KIND_LATLONG, CoherentShadowMap
from .lighting import (
    VIS_CSM,
    VIS_MESH,
    check_strata,
    check_visibility_source,
    dummy_csm,
    stratum_sample,
    surface_inputs,
)
from .query import (
    FILTERS,
    CSMData,
    CubeCSMData,
    csm_device_data,
    csm_local_visibility_filtered,
    csm_visibility_filtered,
)

module_options()

#: Semi-local visibility (Sec. 4.3): a lat-long CSM queried towards the light point.
VIS_SEMI_LOCAL = wp.constant(3)

LIGHT_AREA = wp.constant(0)
LIGHT_LINEAR = wp.constant(1)


@wp.struct
class LocalLightData:
    """An area or linear light as kernels see it (build with :meth:`AreaLight.device_data` /
    :meth:`LinearLight.device_data`)."""

    kind: int  # LIGHT_AREA or LIGHT_LINEAR
    origin: wp.vec3  # area: corner y(0, 0); linear: start
    edge_u: wp.vec3  # area: u; linear: end - start
    edge_v: wp.vec3  # area: v; linear: unused (0)
    normal: wp.vec3  # area: unit n_l = (u x v) / A
    size: float  # area A (area) or length l (linear)
    emission: wp.vec3  # area: radiance L_e; linear: intensity per unit length I
    two_sided: int  # area: 1 emits from both sides


# ---- building blocks (public @wp.func API) ---------------------------------------------------------


@wp.func
def area_light_point(light: LocalLightData, st: wp.vec2) -> wp.vec3:
    """y(s, t) = corner + s u + t v."""
    return light.origin + st[0] * light.edge_u + st[1] * light.edge_v


@wp.func
def area_light_radiance(light: LocalLightData, w: wp.vec3) -> wp.vec3:
    """Radiance L_e leaving the light along the unit direction ``w`` (from the light towards the receiver);
    0 behind a one-sided light."""
    if light.two_sided == 0 and wp.dot(light.normal, w) <= 0.0:
        return wp.vec3(0.0)
    return light.emission


@wp.func
def area_light_pdf(light: LocalLightData, x: wp.vec3, y: wp.vec3) -> float:
    """Solid-angle density (1/sr) of uniform area sampling seen from ``x``: d^2 / (A |cos theta_l|); 0 when
    grazing."""
    w = y - x
    d2 = wp.dot(w, w)
    c = wp.abs(wp.dot(light.normal, w)) / wp.sqrt(d2)
    if not (c > 1.0e-7) or not (light.size > 0.0):
        return 0.0
    return d2 / (light.size * c)


@wp.func
def area_light_intersect(light: LocalLightData, x: wp.vec3, d: wp.vec3) -> tuple[float, wp.vec2]:
    """Ray x + r d (unit d) against the parallelogram: (r, (s, t)) of the hit, r = -1 when missed."""
    denom = wp.dot(light.normal, d)
    if wp.abs(denom) < 1.0e-9:
        return -1.0, wp.vec2(0.0)
    r = wp.dot(light.normal, light.origin - x) / denom
    if not (r > 0.0):
        return -1.0, wp.vec2(0.0)
    q = x + r * d - light.origin
    # solve q = s u + t v in the plane (Gram matrix of u, v)
    uu = wp.dot(light.edge_u, light.edge_u)
    uv = wp.dot(light.edge_u, light.edge_v)
    vv = wp.dot(light.edge_v, light.edge_v)
    qu = wp.dot(q, light.edge_u)
    qv = wp.dot(q, light.edge_v)
    det = uu * vv - uv * uv
    s = (qu * vv - qv * uv) / det
    t = (qv * uu - qu * uv) / det
    if s < 0.0 or s > 1.0 or t < 0.0 or t > 1.0:
        return -1.0, wp.vec2(0.0)
    return r, wp.vec2(s, t)


@wp.func
def local_visibility(mode: int, csm: CubeCSMData, latlong: CSMData, filter_mode: int, bias: float,
                     mesh_id: wp.uint64, eps: float, x: wp.vec3, n: wp.vec3, y: wp.vec3, st: wp.vec2,
                     xi: wp.vec4) -> float:
    """V between surface point ``x`` (normal n) and the light point ``y`` of parameters ``st``: the cube CSM
    query of x + eps n (VIS_CSM), the lat-long CSM towards y (VIS_SEMI_LOCAL), a shadow ray from x + eps n that
    stops just short of y (VIS_MESH), else 1."""
    o = x + eps * n
    if mode == VIS_CSM:
        return csm_local_visibility_filtered(csm, o, st, bias, filter_mode, xi)
    if mode == VIS_SEMI_LOCAL:
        return csm_visibility_filtered(latlong, o, y - o, bias, filter_mode, xi)
    if mode == VIS_MESH:
        w = y - o
        dist = wp.length(w)
        if dist > 0.0 and occluded(mesh_id, o, w / dist, dist * (1.0 - 1.0e-4)):
            return 0.0
    return 1.0


# ---- kernels ---------------------------------------------------------------------------------------


@wp.kernel
def shade_local_light_kernel(
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    view_dirs: wp.array(dtype=wp.vec3),
    material_index: wp.array(dtype=wp.int32),
    mat: MaterialData,
    light: LocalLightData,
    strata: int,
    vis_mode: int,
    csm: CubeCSMData,
    latlong: CSMData,
    filter_mode: int,
    bias: float,
    mesh_id: wp.uint64,
    eps: float,
    seed: int,
    out: wp.array(dtype=wp.vec3),
    offset: int,
):
    """out[k] = one stratified estimate of the radiance reflected at point k from the local light."""
    k = wp.tid() + offset
    rng = wp.rand_init(seed, k)
    x = points[k]
    n = wp.normalize(normals[k])
    wo = wp.normalize(view_dirs[k])
    m = material_index[k]
    total = wp.vec3(0.0)
    count = strata * strata
    for s in range(count):
        j_light = wp.vec2(wp.randf(rng), wp.randf(rng))
        j_brdf = wp.vec2(wp.randf(rng), wp.randf(rng))
        choice = wp.randf(rng)
        xi_light = wp.vec4(wp.randf(rng), wp.randf(rng), wp.randf(rng), wp.randf(rng))
        xi_brdf = wp.vec4(wp.randf(rng), wp.randf(rng), wp.randf(rng), wp.randf(rng))
        if light.kind == LIGHT_LINEAR:
            # ---- linear light: stratified in s, light sampling only (zero area) ----
            sl = (float(s) + j_light[0]) / float(count)
            y = light.origin + sl * light.edge_u
            w = y - x
            d2 = wp.dot(w, w)
            if d2 > 0.0:
                d = w / wp.sqrt(d2)
                c = wp.dot(n, d)
                if c > 0.0:
                    f = material_eval(mat, m, n, wo, d)
                    if wp.length_sq(f) > 0.0:
                        v = local_visibility(vis_mode, csm, latlong, filter_mode, bias, mesh_id, eps, x, n, y,
                                             wp.vec2(sl, 0.5), xi_light)
                        total += wp.cw_mul(f, light.emission) * (v * c * light.size / d2)
        else:
            # ---- area light sample (uniform in (s, t)), balance heuristic ----
            st = stratum_sample(s, strata, j_light)
            y = area_light_point(light, st)
            w = y - x
            d2 = wp.dot(w, w)
            if d2 > 0.0:
                d = w / wp.sqrt(d2)
                c = wp.dot(n, d)
                pl = area_light_pdf(light, x, y)
                le = area_light_radiance(light, -d)
                if c > 0.0 and pl > 0.0 and wp.length_sq(le) > 0.0:
                    f = material_eval(mat, m, n, wo, d)
                    if wp.length_sq(f) > 0.0:
                        v = local_visibility(vis_mode, csm, latlong, filter_mode, bias, mesh_id, eps, x, n, y, st,
                                             xi_light)
                        total += wp.cw_mul(f, le) * (v * c / (pl + material_pdf(mat, m, n, wo, d)))
            # ---- BRDF sample: counts where its ray hits the light ----
            wi = material_sample(mat, m, n, wo, stratum_sample(s, strata, j_brdf), choice)
            c = wp.dot(n, wi)
            if c > 0.0:
                pb = material_pdf(mat, m, n, wo, wi)
                r, sth = area_light_intersect(light, x, wi)
                if pb > 0.0 and r > 0.0:
                    le = area_light_radiance(light, -wi)
                    yh = x + r * wi
                    f = material_eval(mat, m, n, wo, wi)
                    if wp.length_sq(le) > 0.0 and wp.length_sq(f) > 0.0:
                        v = local_visibility(vis_mode, csm, latlong, filter_mode, bias, mesh_id, eps, x, n, yh,
                                             sth, xi_brdf)
                        total += wp.cw_mul(f, le) * (v * c / (pb + area_light_pdf(light, x, yh)))
    out[k] = total / float(count)


# ---- host side -------------------------------------------------------------------------------------


def _vec(a, name: str) -> np.ndarray:
    v = np.asarray(a, np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be 3 finite numbers, got {a!r}")
    return v


@dataclass(frozen=True)
class AreaLight:
    """Parallelogram light corner + s u + t v with constant radiance (see the module docstring).

    Args:
        corner, u, v: the corner y(0, 0) and the two edge vectors (scene units, not parallel).
        radiance: RGB radiance L_e (W m^-2 sr^-1 in scene units).
        two_sided: emit from both sides (else only towards n_l = u x v / |u x v|).
    """

    corner: np.ndarray
    u: np.ndarray
    v: np.ndarray
    radiance: np.ndarray
    two_sided: bool = False

    kind = "area"

    def __post_init__(self):
        for name in ("corner", "u", "v", "radiance"):
            object.__setattr__(self, name, _vec(getattr(self, name), name))
        if np.any(self.radiance < 0.0):
            raise ValueError("radiance must be >= 0")
        if not self.area > 1e-12 * max(np.dot(self.u, self.u), np.dot(self.v, self.v), 1e-30):
            raise ValueError("u and v must span a parallelogram (non-zero and not parallel)")

    @classmethod
    def from_power(cls, corner, u, v, power, two_sided: bool = False) -> AreaLight:
        """The light emitting RGB ``power`` (W): L_e = P / (pi A), or P / (2 pi A) when two-sided."""
        a = float(np.linalg.norm(np.cross(_vec(u, "u"), _vec(v, "v"))))
        if not a > 0.0:
            raise ValueError("u and v must span a parallelogram (non-zero and not parallel)")
        return cls(corner, u, v, _vec(power, "power") / ((2.0 if two_sided else 1.0) * np.pi * a), two_sided)

    @property
    def area(self) -> float:
        """A = |u x v|."""
        return float(np.linalg.norm(np.cross(self.u, self.v)))

    @property
    def normal(self) -> np.ndarray:
        """Unit n_l = (u x v) / A."""
        c = np.cross(self.u, self.v)
        return c / np.linalg.norm(c)

    def sample_points(self, n1: int, n2: int) -> np.ndarray:
        """(n2, n1, 3) cell centres: the sample points of its cube CSM (Sec. 4.2)."""
        from .depthmaps import parallelogram_light_samples

        return parallelogram_light_samples(self.corner, self.u, self.v, n1, n2)

    def device_data(self) -> LocalLightData:
        d = LocalLightData()
        d.kind = 0
        d.origin, d.edge_u, d.edge_v = (wp.vec3(*map(float, a)) for a in (self.corner, self.u, self.v))
        d.normal = wp.vec3(*map(float, self.normal))
        d.size = self.area
        d.emission = wp.vec3(*map(float, self.radiance))
        d.two_sided = int(bool(self.two_sided))
        return d


@dataclass(frozen=True)
class LinearLight:
    """Segment light start -> end, isotropic, RGB ``intensity`` per unit length (W sr^-1 unit^-1)."""

    start: np.ndarray
    end: np.ndarray
    intensity: np.ndarray

    kind = "linear"

    def __post_init__(self):
        for name in ("start", "end", "intensity"):
            object.__setattr__(self, name, _vec(getattr(self, name), name))
        if np.any(self.intensity < 0.0):
            raise ValueError("intensity must be >= 0")
        if not self.length > 0.0:
            raise ValueError("start and end must differ")

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.end - self.start))

    def sample_points(self, n1: int, n2: int = 1) -> np.ndarray:
        """(1, n1, 3) cell centres of the segment: the sample points of its cube CSM (``n2`` is ignored)."""
        from .depthmaps import segment_light_samples

        return segment_light_samples(self.start, self.end, n1)

    def device_data(self) -> LocalLightData:
        d = LocalLightData()
        d.kind = 1
        d.origin = wp.vec3(*map(float, self.start))
        d.edge_u = wp.vec3(*map(float, self.end - self.start))
        d.edge_v = wp.vec3(0.0, 0.0, 0.0)
        d.normal = wp.vec3(0.0, 0.0, 0.0)
        d.size = self.length
        d.emission = wp.vec3(*map(float, self.intensity))
        d.two_sided = 1
        return d


_dummy_cube: dict = {}


def _dummy_cube_csm(device: str) -> CubeCSMData:
    """A one-sample, 1 x 1 cube CSM struct with valid (unused) arrays."""
    if device not in _dummy_cube:
        from .depthmaps import cube_face_frames

        d = CubeCSMData()
        d.resolution, d.n1, d.n2, d.num_samples = 1, 1, 1, 1
        d.faces = wp.array(cube_face_frames().astype(np.float32), dtype=wp.mat33, device=device)
        d.samples = wp.zeros(1, dtype=wp.vec3, device=device)
        d.map_index = wp.zeros(1, dtype=wp.int32, device=device)
        d.seg_start = wp.array(np.array([0, 1], np.int32), dtype=wp.int32, device=device)
        d.seg_depth = wp.array(np.array([np.inf], np.float32), dtype=wp.float32, device=device)
        d.seg_end = wp.array(np.array([5], np.int32), dtype=wp.int32, device=device)
        _dummy_cube[device] = d
    return _dummy_cube[device]


def shade_local_light(
    points,
    normals,
    albedo,
    light: AreaLight | LinearLight,
    *,
    samples: int,
    csm: CoherentShadowMap | None = None,
    mesh: wp.Mesh | None = None,
    seed: int = 0,
    view_dirs=None,
    specular=None,
    exponent=1.0,
    materials: MaterialTable | None = None,
    material_index=None,
    filter: str = "nearest",
    bias: float = 0.0,
    ray_eps: float = 1.0e-4,
    device: str | None = None,
    threads: int | None = None,
) -> np.ndarray:
    """Direct lighting from an area or linear light at surface points (Ritschel 2007 Sec. 4.2, 5), one pass.

    Args:
        points, normals, albedo, view_dirs, specular, exponent, materials, material_index: as for
            :func:`~warpscatter.csm.lighting.shade_environment` (world space).
        light: :class:`AreaLight` or :class:`LinearLight`.
        samples: S = s^2 strata per point (area: one light and one BRDF sample each; linear: one light sample).
        csm: the light's ``"cube"`` CSM (:func:`~warpscatter.csm.compress.build_cube_csm` on
            ``light.sample_points(...)``), or a lat-long CSM of the occluders (semi-local light, Sec. 4.3);
            mesh: a ``wp.Mesh`` for shadow rays (the reference); at most one.
        seed: random seed of this pass.
        filter, bias: CSM filter and depth bias (scene units, >= 0).
        ray_eps: offset of the query point along the normal (scene units, >= 0).
        device, threads: Warp device and CPU worker threads.

    Returns:
        (K, 3) float32 reflected radiance towards ``view_dirs``.

    Raises:
        ValueError: as :func:`~warpscatter.csm.lighting.shade_environment`; a CSM that is not a cube CSM or does
            not hold the light's sample points.
    """
    device = default_device(device)
    if not isinstance(light, (AreaLight, LinearLight)):
        raise ValueError(f"light must be an AreaLight or LinearLight, got {type(light).__name__}")
    strata = check_strata(samples)
    p, n, wo, idx, table = surface_inputs(points, normals, albedo, view_dirs=view_dirs, specular=specular,
                                          exponent=exponent, materials=materials, material_index=material_index)
    check_visibility_source(filter, bias, ray_eps, csm, mesh)
    mode, csm_data, latlong, mesh_id = 0, _dummy_cube_csm(device), dummy_csm(device), wp.uint64(0)
    if isinstance(csm, CoherentShadowMap) and csm.kind == KIND_LATLONG:
        mode, latlong = 3, csm_device_data(csm, device)
    elif csm is not None:
        check_light_csm(csm, light)
        mode, csm_data = 1, csm_device_data(csm, device)
    elif mesh is not None:
        mode, mesh_id = 2, mesh.id
    k = p.shape[0]
    out = wp.zeros(k, dtype=wp.vec3, device=device)
    if k == 0:
        return out.numpy()

    def arr(a):
        return wp.array(a, dtype=wp.vec3, device=device)

    parallel.launch_rows(
        shade_local_light_kernel, k,
        [arr(p), arr(n), arr(wo), wp.array(idx, dtype=wp.int32, device=device), table.device_data(device),
         light.device_data(), strata, mode, csm_data, latlong, FILTERS[filter], float(bias), mesh_id, float(ray_eps),
         int(seed) & 0x7FFFFFFF, out],
        device, threads=threads, min_chunk=256,
    )  # fmt: skip
    return out.numpy()


def check_light_csm(csm, light) -> None:
    """Raises ValueError unless ``csm`` is a cube CSM whose sample points lie on ``light`` as
    ``light.sample_points(n1, n2)`` places them (so light parameters (s, t) select the right samples)."""
    if not isinstance(csm, CoherentShadowMap) or csm.kind != KIND_CUBE:
        raise ValueError("csm must be a cube CoherentShadowMap of the light (build_cube_csm)")
    want = light.sample_points(csm.n1, csm.n2).reshape(-1, 3)
    got = np.asarray(csm.light_samples, np.float64).reshape(-1, 3)
    scale = max(float(np.abs(want).max()), 1.0)
    if got.shape != want.shape or np.abs(got - want).max() > 1e-5 * scale:
        raise ValueError(f"the CSM's {csm.n1} x {csm.n2} light samples do not lie on this light (built for another "
                         f"light or placement)")
