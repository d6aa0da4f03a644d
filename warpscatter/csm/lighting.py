"""Monte-Carlo direct lighting from an environment map with coherent-shadow-map visibility (Ritschel 2007, Sec. 5).

Solves the direct lighting equation of Sec. 5,

    L(x, wo) = integral over the sphere of f_r(x, wo, wi) L_in(wi) V(x, wi) max(cos theta_i, 0) dwi,

for surface points (a G-buffer: positions, normals, materials) lit by a distant lat-long environment map:

- Environment maps (:class:`EnvironmentMap`): lat-long RGB float32 images (row 0 = zenith; theta = pi (j + 0.5) / H
  from +Y, phi = 2 pi (i + 0.5) / W, d = (sin t cos p, cos t, sin t sin p), see assets/README.md), piecewise
  constant per texel. Importance sampling by inverse CDFs (Sec. 5.1, P_L^-1): a marginal CDF over rows weighted by
  luminance x sin(theta_j) and one conditional CDF per row. In the (u, v) = (phi / 2 pi, theta / pi) domain the
  density is constant per texel, p_uv = W H P(texel); the solid-angle density is p_uv / (2 pi^2 sin theta).
- BRDFs (Sec. 5.1, P_f^-1), in :mod:`.brdf`: Lambert, normalized Phong and Lafortune lobes, importance sampled
  with the diffuse / lobe choice by Russian roulette (:class:`~warpscatter.csm.brdf.MaterialTable`).
- Estimator: per point S = s^2 strata of a jittered s x s grid (a per-point random pattern, Sec. 5.1 "Random
  Numbers"); each stratum draws one environment sample and one BRDF sample, combined with multiple importance
  sampling (balance heuristic [VG95]): each sample contributes f L V cos / (p_env + p_brdf).
- Visibility: :func:`~warpscatter.csm.query.csm_visibility_filtered` against a lat-long CSM (points in the CSM's
  object space, Sec. 3.3 / 4.1), or a ``wp.Mesh`` shadow ray (the reference), or none.
- Progressive rendering (Sec. 5.2): :class:`ProgressiveAccumulator` averages passes rendered with different seeds.

Radiance units follow the environment map (its texels are radiance L_in).
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from .. import parallel
from ..raycast import occluded
from ..wpinit import default_device, module_options
from .brdf import LUMA, MaterialData, MaterialTable, material_eval, material_pdf, material_sample
from .brdf import brdf_eval as brdf_eval  # the Lambert / Phong building blocks, re-exported from here
from .brdf import brdf_pdf as brdf_pdf
from .brdf import brdf_sample as brdf_sample
from .brdf import luminance as luminance
from .brdf import phong_lobe as phong_lobe
from .brdf import phong_pdf as phong_pdf
from .brdf import phong_sample as phong_sample
from .compress import KIND_LATLONG, CoherentShadowMap
from .depthmaps import latlong_param
from .query import FILTERS, CSMData, csm_device_data, csm_visibility_filtered

module_options()

VIS_NONE = wp.constant(0)
VIS_CSM = wp.constant(1)
VIS_MESH = wp.constant(2)

@wp.struct
class EnvData:
    """A lat-long environment map and its sampling tables as kernels see it (build with :class:`EnvironmentMap`)."""

    width: int  # W, columns (azimuth)
    height: int  # H, rows (polar angle, row 0 = zenith)
    pixels: wp.array2d(dtype=wp.vec3)  # (H, W) radiance
    marginal_cdf: wp.array(dtype=wp.float32)  # (H + 1,) CDF over rows, 0 ... 1
    conditional_cdf: wp.array2d(dtype=wp.float32)  # (H, W + 1) CDF over the columns of each row
    texel_pdf: wp.array2d(dtype=wp.float32)  # (H, W) density in (u, v) = W H P(texel)


# ---- building blocks (public @wp.func API) ---------------------------------------------------------


@wp.func
def cdf_search(cdf: wp.array(dtype=wp.float32), n: int, x: float) -> int:
    """Interval k in [0, n) with cdf[k] <= x < cdf[k + 1] of an (n + 1,) CDF (empty intervals are never chosen
    for x in [0, 1)); binary search, O(log n)."""
    lo = int(0)
    hi = n - 1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if cdf[mid] <= x:
            lo = mid
        else:
            hi = mid - 1
    return lo


@wp.func
def cdf_search_row(cdf: wp.array2d(dtype=wp.float32), row: int, n: int, x: float) -> int:
    """:func:`cdf_search` in row ``row`` of a 2-D table of CDFs (n + 1 entries per row)."""
    lo = int(0)
    hi = n - 1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if cdf[row, mid] <= x:
            lo = mid
        else:
            hi = mid - 1
    return lo


@wp.func
def env_direction(u: float, v: float) -> wp.vec3:
    """Lat-long mapping (u, v) in [0, 1]^2 -> unit direction: phi = 2 pi u, theta = pi v from +Y."""
    phi = 2.0 * wp.pi * u
    theta = wp.pi * v
    st = wp.sin(theta)
    return wp.vec3(st * wp.cos(phi), wp.cos(theta), st * wp.sin(phi))


@wp.func
def env_texel(env: EnvData, d: wp.vec3) -> wp.vec2i:
    """Texel (column i, row j) of the map holding direction ``d`` (any length > 0)."""
    uv = latlong_param(d)
    i = wp.clamp(int(uv[0] * float(env.width)), 0, env.width - 1)
    j = wp.clamp(int(uv[1] * float(env.height)), 0, env.height - 1)
    return wp.vec2i(i, j)


@wp.func
def env_lookup(env: EnvData, d: wp.vec3) -> wp.vec3:
    """Radiance L_in arriving from direction ``d`` (nearest texel: the map is piecewise constant)."""
    t = env_texel(env, d)
    return env.pixels[t[1], t[0]]


@wp.func
def env_pdf(env: EnvData, d: wp.vec3) -> float:
    """Solid-angle density (1/sr) with which :func:`env_sample` draws direction ``d``:
    p = p_uv / (2 pi^2 sin theta); 0 at the poles (sin theta = 0, probability zero)."""
    n = wp.length(d)
    if not (n > 0.0):
        return 0.0
    s = wp.sqrt(d[0] * d[0] + d[2] * d[2]) / n  # sin theta, accurate near the poles (unlike sqrt(1 - y^2))
    if s < 1.0e-7:
        return 0.0
    t = env_texel(env, d)
    return env.texel_pdf[t[1], t[0]] / (2.0 * wp.pi * wp.pi * s)


@wp.func
def env_sample(env: EnvData, xi: wp.vec2) -> tuple[wp.vec3, wp.vec3, float]:
    """Importance-sample the map (Ritschel 2007 Sec. 5.1, inverse CDFs P_L^-1) with uniform ``xi`` in [0, 1)^2.

    Returns:
        (direction (unit), radiance L_in of its texel, solid-angle pdf in 1/sr; pdf 0 marks an unusable sample
        at a pole).
    """
    x0 = wp.clamp(xi[0], 0.0, 0.99999994)
    x1 = wp.clamp(xi[1], 0.0, 0.99999994)
    j = cdf_search(env.marginal_cdf, env.height, x0)
    c0 = env.marginal_cdf[j]
    c1 = env.marginal_cdf[j + 1]
    dv = wp.clamp((x0 - c0) / wp.max(c1 - c0, 1.0e-30), 0.0, 1.0)
    i = cdf_search_row(env.conditional_cdf, j, env.width, x1)
    r0 = env.conditional_cdf[j, i]
    r1 = env.conditional_cdf[j, i + 1]
    du = wp.clamp((x1 - r0) / wp.max(r1 - r0, 1.0e-30), 0.0, 1.0)
    u = (float(i) + du) / float(env.width)
    v = (float(j) + dv) / float(env.height)
    d = env_direction(u, v)
    s = wp.sin(wp.pi * v)
    pdf = float(0.0)
    if s >= 1.0e-7:
        pdf = env.texel_pdf[j, i] / (2.0 * wp.pi * wp.pi * s)
    return d, env.pixels[j, i], pdf


@wp.func
def stratum_sample(k: int, s: int, jitter: wp.vec2) -> wp.vec2:
    """Point of stratum ``k`` of an s x s grid over [0, 1)^2 jittered by ``jitter`` in [0, 1)^2 (stratified
    pattern, Sec. 5.1)."""
    a = k % s
    b = k // s
    return wp.vec2((float(a) + jitter[0]) / float(s), (float(b) + jitter[1]) / float(s))


@wp.func
def shadow_visibility(mode: int, csm: CSMData, filter_mode: int, bias: float, mesh_id: wp.uint64, eps: float,
                      p: wp.vec3, n: wp.vec3, d: wp.vec3, xi: wp.vec4) -> float:
    """V(p, d) in [0, 1] towards a distant direction ``d``: 1 for VIS_NONE, the CSM query of p + eps n (Sec. 3.3;
    ``p`` in the CSM's object space; ``xi`` uniform in [0, 1)^4 for the roulette filter) for VIS_CSM, a shadow
    ray from p + eps n for VIS_MESH (``eps``: normal offset in scene units)."""
    if mode == VIS_CSM:
        return csm_visibility_filtered(csm, p + eps * n, d, bias, filter_mode, xi)
    if mode == VIS_MESH:
        if occluded(mesh_id, p + eps * n, d, 1.0e30):
            return 0.0
    return 1.0


# ---- kernels ---------------------------------------------------------------------------------------


@wp.kernel
def shade_environment_kernel(
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    view_dirs: wp.array(dtype=wp.vec3),
    material_index: wp.array(dtype=wp.int32),
    mat: MaterialData,
    env: EnvData,
    strata: int,
    vis_mode: int,
    csm: CSMData,
    filter_mode: int,
    bias: float,
    mesh_id: wp.uint64,
    eps: float,
    seed: int,
    out: wp.array(dtype=wp.vec3),
    offset: int,
):
    """out[k] = one stratified MIS estimate (s^2 strata) of the reflected radiance of point k towards view_dirs[k]."""
    k = wp.tid() + offset
    rng = wp.rand_init(seed, k)  # a different pattern per point and per pass (seed)
    p = points[k]
    n = wp.normalize(normals[k])
    wo = wp.normalize(view_dirs[k])
    m = material_index[k]
    total = wp.vec3(0.0)
    count = strata * strata
    for s in range(count):
        # random numbers are drawn here: wp.randf advances a state that @wp.funcs would only copy
        j_env = wp.vec2(wp.randf(rng), wp.randf(rng))
        j_brdf = wp.vec2(wp.randf(rng), wp.randf(rng))
        choice = wp.randf(rng)
        xi_env = wp.vec4(wp.randf(rng), wp.randf(rng), wp.randf(rng), wp.randf(rng))
        xi_brdf = wp.vec4(wp.randf(rng), wp.randf(rng), wp.randf(rng), wp.randf(rng))
        # ---- environment sample (P_L^-1), balance heuristic: f L V cos / (p_env + p_brdf) ----
        d, radiance, pe = env_sample(env, stratum_sample(s, strata, j_env))
        c = wp.dot(n, d)
        if pe > 0.0 and c > 0.0:
            f = material_eval(mat, m, n, wo, d)
            if wp.length_sq(f) > 0.0 and wp.length_sq(radiance) > 0.0:
                v = shadow_visibility(vis_mode, csm, filter_mode, bias, mesh_id, eps, p, n, d, xi_env)
                total += wp.cw_mul(f, radiance) * (v * c / (pe + material_pdf(mat, m, n, wo, d)))
        # ---- BRDF sample (P_f^-1 with the diffuse / lobe roulette) ----
        wi = material_sample(mat, m, n, wo, stratum_sample(s, strata, j_brdf), choice)
        c = wp.dot(n, wi)
        if c > 0.0:
            pb = material_pdf(mat, m, n, wo, wi)
            if pb > 0.0:
                f = material_eval(mat, m, n, wo, wi)
                radiance = env_lookup(env, wi)
                if wp.length_sq(f) > 0.0 and wp.length_sq(radiance) > 0.0:
                    v = shadow_visibility(vis_mode, csm, filter_mode, bias, mesh_id, eps, p, n, wi, xi_brdf)
                    total += wp.cw_mul(f, radiance) * (v * c / (pb + env_pdf(env, wi)))
    out[k] = total / float(count)


@wp.kernel
def env_lookup_kernel(env: EnvData, directions: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    """out[k] = radiance of the map along directions[k] (:func:`env_lookup`)."""
    k = wp.tid()
    out[k] = env_lookup(env, directions[k])


# ---- host side -------------------------------------------------------------------------------------


class EnvironmentMap:
    """A lat-long environment map with the inverse-CDF tables of its importance sampling.

    Args:
        image: (H, W, 3) or (H, W, 4) linear RGB(A) radiance (alpha ignored), row 0 = zenith; H >= 1, W >= 1,
            finite and >= 0.

    Attributes:
        image: (H, W, 3) float32 radiance.
        marginal_cdf: (H + 1,) float32 CDF over rows (weights: sum over the row of luminance x sin theta_j).
        conditional_cdf: (H, W + 1) float32 CDFs over the columns of each row (weights: luminance).
        texel_pdf: (H, W) float32 density in (u, v) of each texel, W H P(texel), P from the stored float32 CDFs.

    A map whose sampling weight is zero everywhere (black) is sampled by sin theta alone (uniform on the sphere).

    Raises:
        ValueError: wrong shape, empty, non-finite or negative texels.
    """

    def __init__(self, image):
        try:
            img = np.asarray(image, dtype=np.float32)
        except (TypeError, ValueError) as exc:
            raise ValueError("image must be a numeric (H, W, 3) array") from exc
        if img.ndim != 3 or img.shape[2] not in (3, 4) or img.shape[0] < 1 or img.shape[1] < 1:
            raise ValueError(f"image must have shape (H, W, 3) or (H, W, 4), got {img.shape}")
        img = np.ascontiguousarray(img[:, :, :3])
        if not np.all(np.isfinite(img)):
            raise ValueError("image contains non-finite texels")
        if np.any(img < 0.0):
            raise ValueError("image contains negative radiance")
        h, w = img.shape[:2]
        self.image = img
        sin_t = np.sin(np.pi * (np.arange(h) + 0.5) / h)
        lum = img.astype(np.float64) @ np.asarray(LUMA)
        weight = lum * sin_t[:, None]
        if not weight.sum() > 0.0:
            lum = np.ones((h, w))
            weight = lum * sin_t[:, None]
        row = weight.sum(axis=1)
        marginal = np.concatenate([[0.0], np.cumsum(row)]) / row.sum()
        marginal[-1] = 1.0
        cond = np.zeros((h, w + 1))
        for j in range(h):
            s = lum[j].sum()
            cond[j, 1:] = np.cumsum(lum[j]) / s if s > 0.0 else (np.arange(1, w + 1) / w)
            cond[j, -1] = 1.0
        self.marginal_cdf = marginal.astype(np.float32)
        self.conditional_cdf = cond.astype(np.float32)
        m = self.marginal_cdf.astype(np.float64)
        c = self.conditional_cdf.astype(np.float64)
        prob = np.diff(m)[:, None] * np.diff(c, axis=1)
        self.texel_pdf = (prob * (w * h)).astype(np.float32)
        self._device_cache: dict = {}

    @property
    def width(self) -> int:
        """Map width W (azimuth texels)."""
        return int(self.image.shape[1])

    @property
    def height(self) -> int:
        """Map height H (polar texels)."""
        return int(self.image.shape[0])

    def texel_solid_angles(self) -> np.ndarray:
        """(H, W) solid angle (sr) of each texel: (2 pi / W) (cos theta_j - cos theta_{j+1})."""
        edges = np.cos(np.pi * np.arange(self.height + 1) / self.height)
        return np.repeat(((edges[:-1] - edges[1:]) * 2.0 * np.pi / self.width)[:, None], self.width, axis=1)

    def lookup(self, directions, device: str | None = None) -> np.ndarray:
        """(..., 3) float32 radiance along (..., 3) directions (any non-zero length), as :func:`env_lookup`."""
        device = default_device(device)
        d = np.asarray(directions, np.float32)
        flat = np.ascontiguousarray(d.reshape(-1, 3))
        out = wp.empty(len(flat), dtype=wp.vec3, device=device)
        if len(flat):
            wp.launch(env_lookup_kernel, dim=len(flat), inputs=[self.device_data(device),
                                                                 wp.array(flat, dtype=wp.vec3, device=device), out],
                      device=device)  # fmt: skip
        return out.numpy().reshape(d.shape)

    def device_data(self, device: str | None = None) -> EnvData:
        """The :class:`EnvData` struct on ``device`` (cached per device)."""
        device = default_device(device)
        if device not in self._device_cache:
            d = EnvData()
            d.width, d.height = self.width, self.height
            d.pixels = wp.array(self.image, dtype=wp.vec3, device=device)
            d.marginal_cdf = wp.array(self.marginal_cdf, dtype=wp.float32, device=device)
            d.conditional_cdf = wp.array(self.conditional_cdf, dtype=wp.float32, device=device)
            d.texel_pdf = wp.array(self.texel_pdf, dtype=wp.float32, device=device)
            self._device_cache[device] = d
        return self._device_cache[device]


class ProgressiveAccumulator:
    """Running mean of Monte-Carlo passes (Ritschel 2007 Sec. 5.2: m frames blended with weight 1 / m).

    Example::

        acc = ProgressiveAccumulator()
        for k in range(passes):
            image = acc.add(shade_environment(..., seed=k))   # write ``image`` as it converges
    """

    def __init__(self):
        self._sum: np.ndarray | None = None
        self.passes = 0

    def add(self, frame) -> np.ndarray:
        """Add one pass (any array shape, the same for every pass) and return the running mean (float32).

        Raises:
            ValueError: a shape differing from the earlier passes, or non-finite values.
        """
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
        """The current mean of all passes (float32).

        Raises:
            ValueError: no pass added yet.
        """
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


_dummy_cache: dict = {}


def dummy_csm(device: str) -> CSMData:
    """A 1 x 1 CSM struct with valid (unused) arrays, for launches that do not query a CSM."""
    if device not in _dummy_cache:
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
        _dummy_cache[device] = d
    return _dummy_cache[device]


def surface_inputs(points, normals, albedo, *, view_dirs=None, specular=None, exponent=1.0, materials=None,
                   material_index=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, MaterialTable]:
    """Check and normalise the per-point inputs shared by the Monte-Carlo shading functions.

    Either Lambert + Phong per point (``albedo``, ``specular``, ``exponent``) or a :class:`MaterialTable` with
    a per-point ``material_index`` (then albedo / specular / exponent must be None / defaults).

    Returns:
        (points, normals, view_dirs, material_index (K,) int32, materials).

    Raises:
        ValueError: malformed arrays, zero normals or view directions, negative exponents, indices out of range.
    """
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
    """s for ``samples`` = s^2 >= 1 strata (a jittered s x s grid).

    Raises:
        ValueError: not a positive integer or not a perfect square.
    """
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 1:
        raise ValueError(f"samples must be a positive integer, got {samples!r}")
    strata = math.isqrt(int(samples))
    if strata * strata != samples:
        raise ValueError(f"samples must be a perfect square (jittered s x s grid), got {samples}")
    return strata


def check_offsets(bias, ray_eps) -> None:
    """Raises ValueError unless the depth bias and the normal offset are finite and >= 0."""
    if not np.isfinite(bias) or bias < 0.0:
        raise ValueError(f"bias must be a finite number >= 0, got {bias!r}")
    if not np.isfinite(ray_eps) or ray_eps < 0.0:
        raise ValueError(f"ray_eps must be a finite number >= 0, got {ray_eps!r}")


def check_visibility_source(filter: str, bias, ray_eps, csm, mesh) -> None:
    """The checks every shading host function makes of its visibility inputs.

    Raises:
        ValueError: an unknown CSM filter, a negative or non-finite bias / ray_eps, both ``csm`` and ``mesh``, or
            a ``mesh`` that is not a ``wp.Mesh``.
    """
    if filter not in FILTERS:
        raise ValueError(f"filter must be one of {tuple(FILTERS)}, got {filter!r}")
    check_offsets(bias, ray_eps)
    if csm is not None and mesh is not None:
        raise ValueError("give at most one of csm and mesh as the visibility source")
    if mesh is not None and not isinstance(mesh, wp.Mesh):
        raise ValueError(f"mesh must be a wp.Mesh, got {type(mesh).__name__}")


def shade_environment(
    points,
    normals,
    albedo,
    env: EnvironmentMap,
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
    """Direct lighting from an environment map at surface points (Ritschel 2007 Sec. 5), one Monte-Carlo pass.

    Args:
        points: (K, 3) surface positions (scene units); with ``csm`` they must be in the CSM's object space.
        normals: (K, 3) surface normals (any non-zero length).
        albedo: (K, 3) or (3,) diffuse reflectance k_d (Lambert f = k_d / pi); None with ``materials``.
        env: the environment map (distant light; L_in from its texels).
        samples: S strata per point, a perfect square s^2 >= 1; each stratum gives one environment and one BRDF
            sample (2 S directions, combined by the balance heuristic).
        csm: lat-long coherent shadow map of the occluders (visibility by ``csm_visibility_filtered``).
        mesh: ``wp.Mesh`` of the occluders for exact shadow rays (the reference). At most one of csm / mesh;
            neither: no occlusion.
        seed: random seed of this pass (use a different one per progressive pass: it changes every pattern).
        view_dirs: (K, 3) or (3,) unit-ish directions from the point towards the viewer (default: the normal).
        specular: (K, 3) or (3,) Phong reflectance k_s (default 0).
        exponent: (K,) or scalar Phong exponent n >= 0.
        materials: a :class:`~warpscatter.csm.brdf.MaterialTable` (Lambert / Phong / Lafortune) instead of
            albedo / specular / exponent, with ``material_index`` (K,) rows into it (default 0).
        filter: CSM filter ``"nearest"``, ``"pcf"`` or ``"roulette"`` (Sec. 4.5).
        bias: CSM depth bias (object-space units, >= 0).
        ray_eps: offset of the query point along the normal (scene units, >= 0): the shadow-ray origin for
            ``mesh``, the CSM query point for ``csm``.
        device: Warp device.
        threads: CPU worker threads.

    Returns:
        (K, 3) float32 outgoing radiance towards ``view_dirs``.

    Raises:
        ValueError: malformed arrays, zero normals or view directions, a non-square or non-positive ``samples``,
            both ``csm`` and ``mesh``, a non-lat-long CSM, an unknown filter, negative bias / ray_eps / exponent.
    """
    device = default_device(device)
    if not isinstance(env, EnvironmentMap):
        raise ValueError(f"env must be an EnvironmentMap, got {type(env).__name__}")
    strata = check_strata(samples)
    p, n, wo, idx, table = surface_inputs(points, normals, albedo, view_dirs=view_dirs, specular=specular,
                                          exponent=exponent, materials=materials, material_index=material_index)
    check_visibility_source(filter, bias, ray_eps, csm, mesh)
    mode, csm_data, mesh_id = 0, dummy_csm(device), wp.uint64(0)
    if csm is not None:
        if not isinstance(csm, CoherentShadowMap) or csm.kind != KIND_LATLONG:
            raise ValueError("csm must be a lat-long CoherentShadowMap (build_csm)")
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
        shade_environment_kernel, k,
        [arr(p), arr(n), arr(wo), wp.array(idx, dtype=wp.int32, device=device), table.device_data(device),
         env.device_data(device), strata, mode, csm_data, FILTERS[filter], float(bias), mesh_id, float(ray_eps),
         int(seed) & 0x7FFFFFFF, out],
        device, threads=threads, min_chunk=256,
    )  # fmt: skip
    return out.numpy()
