"""BRDFs and their importance sampling for Monte-Carlo direct lighting (Ritschel 2007, Sec. 5.1).

Directions are unit vectors pointing AWAY from the surface: ``wo`` towards the viewer, ``wi`` towards the light, ``n``
the camera-facing normal. f_r is in 1/sr, 0 below the surface.

- Lambert: f = k_d / pi, sampled cosine-weighted.
- Normalized Phong (Lafortune and Willems 1994): f = k_d / pi + k_s (e + 2) / (2 pi) cos^e(alpha), alpha from the
  mirror direction; sampled with p = (e + 1) / (2 pi) cos^e(alpha), diffuse or specular by Russian roulette.
- Lafortune et al. 1997, generalized cosine lobes in the frame (t, b, n) of :func:`orthonormal_basis`:

      f = k_d / pi + sum_i rho_i [C_x,i u_x v_x + C_y,i u_y v_y + C_z,i u_z v_z]^(e_i)     (0 where [..] <= 0)

  Each lobe is sampled as a Phong lobe about its axis w_i = (C_x u_x, C_y u_y, C_z u_z), picked by roulette with its
  preintegrated albedo lum(rho_i) |w_i|^e_i 2 pi / (e_i + 2) (Sec. 5.1). Phong is the lobe C = (-1, -1, 1),
  rho = k_s (e + 2) / (2 pi), so both agree exactly.

``material_*`` are the one-direction form of ``shading_*`` (:class:`ShadingPoint`: what a point's samples share).
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ..runtime.device import default_device, module_options

module_options()

#: Most lobes a material may have (beside the diffuse term).
MAX_LOBES = 4


@wp.struct
class MaterialData:
    """A table of M materials as kernels see it (build with :class:`MaterialTable`): (M,) diffuse reflectance ``kd``
    and ``lobe_count`` (0 .. MAX_LOBES), (M, MAX_LOBES) ``lobes`` (C_x, C_y, C_z, exponent e) and their RGB scale
    ``lobe_rho`` (1/sr)."""

    kd: wp.array(dtype=wp.vec3)
    lobe_count: wp.array(dtype=wp.int32)
    lobes: wp.array2d(dtype=wp.vec4)
    lobe_rho: wp.array2d(dtype=wp.vec3)




@wp.func
def luminance(c: wp.vec3) -> float:
    """Rec. 709 luminance of a linear RGB value."""
    return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]


@wp.func
def orthonormal_basis(n: wp.vec3) -> tuple[wp.vec3, wp.vec3]:
    """Two unit tangents (t, b) with (t, b, n) right-handed orthonormal (Duff et al. 2017, branchless)."""
    sign = 1.0
    if n[2] < 0.0:
        sign = -1.0
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    t = wp.vec3(1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0])
    bb = wp.vec3(b, sign + n[1] * n[1] * a, -n[1])
    return t, bb


@wp.func
def lobe_direction(axis: wp.vec3, cos_t: float, phi: float) -> wp.vec3:
    """Unit direction at polar angle acos(cos_t) and azimuth ``phi`` about the unit ``axis``."""
    t, b = orthonormal_basis(axis)
    sin_t = wp.sqrt(wp.max(1.0 - cos_t * cos_t, 0.0))
    return wp.normalize(sin_t * wp.cos(phi) * t + sin_t * wp.sin(phi) * b + cos_t * axis)


@wp.func
def cos_power_sample(axis: wp.vec3, exponent: float, xi: wp.vec2) -> wp.vec3:
    """Direction about the unit ``axis`` with density (e + 1) / (2 pi) cos^e(alpha), e >= 0 (Sec. 5.1)."""
    cos_a = wp.pow(1.0 - xi[0], 1.0 / (exponent + 1.0))
    return lobe_direction(axis, cos_a, 2.0 * wp.pi * xi[1])


@wp.func
def cos_power_pdf(axis: wp.vec3, wi: wp.vec3, exponent: float) -> float:
    """Density (1/sr) of :func:`cos_power_sample`: (e + 1) / (2 pi) cos^e(alpha) for cos(alpha) > 0, else 0."""
    c = wp.dot(axis, wi)
    if c <= 0.0:
        return 0.0
    return (exponent + 1.0) / (2.0 * wp.pi) * wp.pow(c, exponent)


@wp.func
def lambert_sample(n: wp.vec3, xi: wp.vec2) -> wp.vec3:
    """Cosine-weighted direction about the unit normal ``n`` (pdf :func:`lambert_pdf`)."""
    return lobe_direction(n, wp.sqrt(1.0 - xi[0]), 2.0 * wp.pi * xi[1])


@wp.func
def lambert_pdf(n: wp.vec3, wi: wp.vec3) -> float:
    """Density (1/sr) of :func:`lambert_sample`: max(cos theta_i, 0) / pi."""
    return wp.max(wp.dot(n, wi), 0.0) / wp.pi


@wp.func
def phong_reflect(n: wp.vec3, wo: wp.vec3) -> wp.vec3:
    """Mirror direction of the unit outgoing direction ``wo`` about the unit normal ``n``."""
    return 2.0 * wp.dot(n, wo) * n - wo


@wp.func
def phong_lobe(n: wp.vec3, wo: wp.vec3, wi: wp.vec3, exponent: float) -> float:
    """Normalized Phong lobe (n + 2) / (2 pi) cos^n(alpha), alpha from the mirror of ``wo`` (Lafortune 1994)."""
    c = wp.dot(phong_reflect(n, wo), wi)
    if c <= 0.0:
        return 0.0
    return (exponent + 2.0) / (2.0 * wp.pi) * wp.pow(c, exponent)


@wp.func
def phong_sample(n: wp.vec3, wo: wp.vec3, exponent: float, xi: wp.vec2) -> wp.vec3:
    """Direction about the mirror of ``wo`` with density :func:`phong_pdf` (may lie below the surface)."""
    return cos_power_sample(phong_reflect(n, wo), exponent, xi)


@wp.func
def phong_pdf(n: wp.vec3, wo: wp.vec3, wi: wp.vec3, exponent: float) -> float:
    """Density (1/sr) of :func:`phong_sample`: (n + 1) / (2 pi) cos^n(alpha) for cos(alpha) > 0."""
    return cos_power_pdf(phong_reflect(n, wo), wi, exponent)


@wp.func
def specular_probability(kd: wp.vec3, ks: wp.vec3) -> float:
    """Roulette probability of a specular sample (Sec. 5.1): lum(k_s) / (lum(k_d) + lum(k_s)); 0 if both vanish."""
    a = wp.max(luminance(kd), 0.0)
    b = wp.max(luminance(ks), 0.0)
    if a + b <= 0.0:
        return 0.0
    return b / (a + b)


@wp.func
def brdf_eval(n: wp.vec3, wo: wp.vec3, wi: wp.vec3, kd: wp.vec3, ks: wp.vec3, exponent: float) -> wp.vec3:
    """Lambert + normalized Phong BRDF f_r (1/sr) for unit n, wo, wi; 0 below the surface."""
    if wp.dot(n, wi) <= 0.0:
        return wp.vec3(0.0)
    return kd / wp.pi + ks * phong_lobe(n, wo, wi, exponent)


@wp.func
def brdf_sample(n: wp.vec3, wo: wp.vec3, kd: wp.vec3, ks: wp.vec3, exponent: float, xi: wp.vec2,
                choice: float) -> wp.vec3:
    """Sample the BRDF (Sec. 5.1): ``choice`` picks the Phong lobe with :func:`specular_probability`, else Lambert."""
    if choice < specular_probability(kd, ks):
        return phong_sample(n, wo, exponent, xi)
    return lambert_sample(n, xi)


@wp.func
def brdf_pdf(n: wp.vec3, wo: wp.vec3, wi: wp.vec3, kd: wp.vec3, ks: wp.vec3, exponent: float) -> float:
    """Density (1/sr) of :func:`brdf_sample`: the roulette mixture of the Lambert and Phong densities."""
    ps = specular_probability(kd, ks)
    return (1.0 - ps) * lambert_pdf(n, wi) + ps * phong_pdf(n, wo, wi, exponent)


@wp.func
def lafortune_axis(n: wp.vec3, t: wp.vec3, b: wp.vec3, wo: wp.vec3, c: wp.vec4) -> wp.vec3:
    """Unnormalised world-space axis w = (C_x u_x, C_y u_y, C_z u_z) of lobe ``c`` for ``wo``: lobe = (w . wi)^e."""
    return (c[0] * wp.dot(wo, t)) * t + (c[1] * wp.dot(wo, b)) * b + (c[2] * wp.dot(wo, n)) * n


@wp.func
def lafortune_lobe(axis: wp.vec3, wi: wp.vec3, exponent: float) -> float:
    """Value of one generalized cosine lobe, max(axis . wi, 0)^e (Lafortune et al. 1997, Eq. 4)."""
    c = wp.dot(axis, wi)
    if c <= 0.0:
        return 0.0
    return wp.pow(c, exponent)


@wp.func
def lafortune_lobe_weight(axis: wp.vec3, rho: wp.vec3, exponent: float) -> float:
    """Preintegrated roulette weight of a lobe (Sec. 5.1): lum(rho) |w|^e 2 pi / (e + 2); 0 for a null axis."""
    a = wp.length(axis)
    if not (a > 0.0):
        return 0.0
    return wp.max(luminance(rho), 0.0) * wp.pow(a, exponent) * 2.0 * wp.pi / (exponent + 2.0)


LobeRows = wp.types.matrix(shape=(MAX_LOBES, 3), dtype=wp.float32)


@wp.struct
class ShadingPoint:
    """Material ``m`` at one surface point seen from ``wo`` (:func:`shading_point`), shared by the point's samples:
    unit normal ``n`` and (``t``, ``b``) = orthonormal_basis(n), ``diffuse`` = k_d / pi, diffuse roulette weight
    ``wd`` = max(lum(k_d), 0); per lobe (rows of MAX_LOBES x 3 matrices) the :func:`lafortune_axis` (world space, not
    normalised), ``unit_axis`` with its basis (``axis_t``, ``axis_b``), ``rho`` (1/sr), ``exponent`` and the
    :func:`lafortune_lobe_weight`; normalisers ``total_pdf`` = wd + the weights > 0 and ``total_sample`` = wd + all."""

    n: wp.vec3
    t: wp.vec3
    b: wp.vec3
    diffuse: wp.vec3
    wd: float
    lobe_count: int
    axis: LobeRows
    unit_axis: LobeRows
    axis_t: LobeRows
    axis_b: LobeRows
    rho: LobeRows
    exponent: wp.vec4
    weight: wp.vec4
    total_pdf: float
    total_sample: float


@wp.func
def frame_direction(t: wp.vec3, b: wp.vec3, axis: wp.vec3, cos_t: float, phi: float) -> wp.vec3:
    """:func:`lobe_direction` with the frame (t, b) = orthonormal_basis(axis) given."""
    sin_t = wp.sqrt(wp.max(1.0 - cos_t * cos_t, 0.0))
    return wp.normalize(sin_t * wp.cos(phi) * t + sin_t * wp.sin(phi) * b + cos_t * axis)


@wp.func
def shading_point(mat: MaterialData, m: int, n: wp.vec3, wo: wp.vec3) -> ShadingPoint:
    """The per-point part of material ``m`` (unit normal ``n``, unit ``wo``), computed once per surface point."""
    sp = ShadingPoint()
    t, b = orthonormal_basis(n)
    sp.n = n
    sp.t = t
    sp.b = b
    kd = mat.kd[m]
    sp.diffuse = kd / wp.pi
    wd = wp.max(luminance(kd), 0.0)
    sp.wd = wd
    count = mat.lobe_count[m]
    sp.lobe_count = count
    total_pdf = wd
    total_sample = wd
    for i in range(count):
        c = mat.lobes[m, i]
        axis = lafortune_axis(n, t, b, wo, c)
        w = lafortune_lobe_weight(axis, mat.lobe_rho[m, i], c[3])
        unit = wp.normalize(axis)
        at, ab = orthonormal_basis(unit)
        sp.axis[i] = axis
        sp.unit_axis[i] = unit
        sp.axis_t[i] = at
        sp.axis_b[i] = ab
        sp.rho[i] = mat.lobe_rho[m, i]
        sp.exponent[i] = c[3]
        sp.weight[i] = w
        total_sample += w
        if w > 0.0:
            total_pdf += w
    sp.total_pdf = total_pdf
    sp.total_sample = total_sample
    return sp


@wp.func(inline=True)
def shading_eval(sp: ShadingPoint, wi: wp.vec3) -> wp.vec3:
    """f_r (1/sr) towards unit ``wi`` of the point's material, n and wo (:func:`material_eval`)."""
    if wp.dot(sp.n, wi) <= 0.0:
        return wp.vec3(0.0)
    f = sp.diffuse
    for i in range(sp.lobe_count):
        f += sp.rho[i] * lafortune_lobe(sp.axis[i], wi, sp.exponent[i])
    return f


@wp.func(inline=True)
def shading_pdf(sp: ShadingPoint, wi: wp.vec3) -> float:
    """Density (1/sr) of :func:`shading_sample` at unit ``wi``: sum over components of P(component) x its density."""
    p = sp.wd * lambert_pdf(sp.n, wi)
    for i in range(sp.lobe_count):
        w = sp.weight[i]
        if w > 0.0:
            p += w * cos_power_pdf(sp.unit_axis[i], wi, sp.exponent[i])
    if not (sp.total_pdf > 0.0):
        return 0.0
    return p / sp.total_pdf


@wp.func(inline=True)
def shading_sample(sp: ShadingPoint, xi: wp.vec2, choice: float) -> wp.vec3:
    """Sample the point's material with ``xi`` in [0, 1)^2 and roulette ``choice`` (:func:`material_sample`)."""
    if not (sp.total_sample > 0.0):
        return sp.n
    x = choice * sp.total_sample
    if x < sp.wd:
        return frame_direction(sp.t, sp.b, sp.n, wp.sqrt(1.0 - xi[0]), 2.0 * wp.pi * xi[1])
    acc = sp.wd
    chosen = int(-1)
    last = int(-1)
    for i in range(sp.lobe_count):
        w = sp.weight[i]
        if w > 0.0:
            last = i
            acc += w
            if chosen < 0 and x < acc:
                chosen = i
    if chosen < 0:
        chosen = last  # x rounded onto the total
    if chosen < 0:
        return frame_direction(sp.t, sp.b, sp.n, wp.sqrt(1.0 - xi[0]), 2.0 * wp.pi * xi[1])
    cos_a = wp.pow(1.0 - xi[0], 1.0 / (sp.exponent[chosen] + 1.0))
    return frame_direction(sp.axis_t[chosen], sp.axis_b[chosen], sp.unit_axis[chosen], cos_a, 2.0 * wp.pi * xi[1])


@wp.func
def material_eval(mat: MaterialData, m: int, n: wp.vec3, wo: wp.vec3, wi: wp.vec3) -> wp.vec3:
    """f_r (1/sr) of material ``m`` towards unit ``wi``: k_d / pi plus its Lafortune lobes; 0 below the surface."""
    return shading_eval(shading_point(mat, m, n, wo), wi)


@wp.func
def material_pdf(mat: MaterialData, m: int, n: wp.vec3, wo: wp.vec3, wi: wp.vec3) -> float:
    """Density (1/sr) of :func:`material_sample`: sum over components of P(component) x its density."""
    return shading_pdf(shading_point(mat, m, n, wo), wi)


@wp.func
def material_sample(mat: MaterialData, m: int, n: wp.vec3, wo: wp.vec3, xi: wp.vec2, choice: float) -> wp.vec3:
    """Sample material ``m`` (Sec. 5.1): roulette ``choice`` picks diffuse or a lobe by preintegrated weight, then
    ``xi`` draws wi; a black material returns the normal with density 0."""
    return shading_sample(shading_point(mat, m, n, wo), xi, choice)




class MaterialTable:
    """Materials for the Monte-Carlo kernels: diffuse k_d plus up to :data:`MAX_LOBES` Lafortune lobes each.

    Args:
        kd: (M, 3) diffuse reflectance (>= 0).
        lobes: (M, L, 4) per lobe (C_x, C_y, C_z, exponent e >= 0), L <= MAX_LOBES (may be None: no lobes).
        lobe_rho: (M, L, 3) per lobe RGB scale rho (>= 0).
        lobe_count: (M,) lobes in use per material (default: L for every material).

    Raises:
        ValueError: wrong shapes, non-finite or negative values, too many lobes.
    """

    def __init__(self, kd, lobes=None, lobe_rho=None, lobe_count=None):
        kd = np.asarray(kd, np.float32)
        if kd.ndim != 2 or kd.shape[1] != 3 or kd.shape[0] < 1:
            raise ValueError(f"kd must have shape (M, 3), got {kd.shape}")
        m = kd.shape[0]
        if lobes is None:
            lobes = np.zeros((m, 0, 4), np.float32)
            lobe_rho = np.zeros((m, 0, 3), np.float32)
        lobes = np.asarray(lobes, np.float32)
        lobe_rho = np.asarray(lobe_rho, np.float32)
        if lobes.ndim != 3 or lobes.shape[0] != m or lobes.shape[2] != 4 or lobes.shape[1] > MAX_LOBES:
            raise ValueError(f"lobes must have shape ({m}, L <= {MAX_LOBES}, 4), got {lobes.shape}")
        if lobe_rho.shape != lobes.shape[:2] + (3,):
            raise ValueError(f"lobe_rho must have shape {lobes.shape[:2] + (3,)}, got {lobe_rho.shape}")
        count = np.full(m, lobes.shape[1], np.int32) if lobe_count is None else np.asarray(lobe_count, np.int32)
        if count.shape != (m,) or np.any(count < 0) or np.any(count > lobes.shape[1]):
            raise ValueError(f"lobe_count must be ({m},) integers in [0, {lobes.shape[1]}]")
        for name, a in (("kd", kd), ("lobes", lobes), ("lobe_rho", lobe_rho)):
            if not np.all(np.isfinite(a)):
                raise ValueError(f"{name} contains non-finite values")
        if np.any(kd < 0.0) or np.any(lobe_rho < 0.0):
            raise ValueError("kd and lobe_rho must be >= 0")
        if np.any(lobes[..., 3] < 0.0):
            raise ValueError("lobe exponents must be >= 0")
        full = np.zeros((m, MAX_LOBES, 4), np.float32)
        full_rho = np.zeros((m, MAX_LOBES, 3), np.float32)
        full[:, : lobes.shape[1]] = lobes
        full_rho[:, : lobes.shape[1]] = lobe_rho
        self.kd, self.lobes, self.lobe_rho, self.lobe_count = kd, full, full_rho, count
        self._device_cache: dict = {}

    def __len__(self) -> int:
        return int(self.kd.shape[0])

    @classmethod
    def phong(cls, kd, ks, exponent) -> MaterialTable:
        """Lambert + normalized Phong materials: (M, 3) k_d, (M, 3) k_s, (M,) exponents e >= 0; each Phong lobe
        becomes the Lafortune lobe C = (-1, -1, 1), rho = k_s (e + 2) / (2 pi)."""
        kd = np.asarray(kd, np.float32)
        ks = np.asarray(ks, np.float32)
        e = np.broadcast_to(np.asarray(exponent, np.float32), (kd.shape[0],))
        if ks.shape != kd.shape:
            raise ValueError(f"ks must have shape {kd.shape} like kd, got {ks.shape}")
        lobes = np.zeros((kd.shape[0], 1, 4), np.float32)
        lobes[:, 0] = np.stack([-np.ones_like(e), -np.ones_like(e), np.ones_like(e), e], axis=1)
        rho = (ks * ((e + 2.0) / (2.0 * math.pi))[:, None])[:, None, :]
        return cls(kd, lobes, rho, (np.any(ks > 0.0, axis=1)).astype(np.int32))

    @classmethod
    def from_specs(cls, specs) -> MaterialTable:
        """Materials from plain specs: ``{"albedo": rgb}`` plus optionally ``{"phong": {...}}`` or
        ``{"lafortune": [...]}`` (as :mod:`warpscatter.config` validates)."""
        specs = list(specs)
        m = len(specs)
        kd = np.zeros((m, 3), np.float32)
        lobes = np.zeros((m, MAX_LOBES, 4), np.float32)
        rho = np.zeros((m, MAX_LOBES, 3), np.float32)
        count = np.zeros(m, np.int32)
        for k, s in enumerate(specs):
            kd[k] = s["albedo"]
            if s.get("phong") is not None:
                p = s["phong"]
                one = cls.phong(kd[k:k + 1], np.asarray(p["specular"], np.float32)[None], p["exponent"])
                lobes[k, :1], rho[k, :1], count[k] = one.lobes[0, :1], one.lobe_rho[0, :1], one.lobe_count[0]
            for i, lobe in enumerate(s.get("lafortune") or []):
                if i >= MAX_LOBES:
                    raise ValueError(f"material {k}: at most {MAX_LOBES} lobes")
                lobes[k, i] = [*lobe["coefficients"], lobe["exponent"]]
                rho[k, i] = lobe.get("color", (1.0, 1.0, 1.0))
                count[k] = i + 1
        return cls(kd, lobes, rho, count)

    def device_data(self, device: str | None = None) -> MaterialData:
        """The :class:`MaterialData` struct on ``device`` (cached per device)."""
        device = default_device(device)
        if device not in self._device_cache:
            d = MaterialData()
            d.kd = wp.array(self.kd, dtype=wp.vec3, device=device)
            d.lobe_count = wp.array(self.lobe_count, dtype=wp.int32, device=device)
            d.lobes = wp.array(self.lobes, dtype=wp.vec4, device=device)
            d.lobe_rho = wp.array(self.lobe_rho, dtype=wp.vec3, device=device)
            self._device_cache[device] = d
        return self._device_cache[device]
