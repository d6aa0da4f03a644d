"""Lat-long environment maps as light sources: radiance per direction and the importance sampling of Ritschel et
al. 2007 Sec. 5.1. Piecewise constant RGB float32, row 0 = zenith, theta from +Y, phi from +X towards +Z
(assets/README.md); density W H P(texel) in (u, v) = (phi / 2 pi, theta / pi), p_uv / (2 pi^2 sin theta) per solid
angle. The CDFs are searched through guide tables (Chen & Asau 1974), avoiding log2 n mispredicted branches.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..runtime.device import default_device, module_options

module_options()

#: Rec. 709 luminance weights of linear RGB (environment-map and BRDF sampling weights).
LUMA = (0.2126, 0.7152, 0.0722)
#: The largest radiance texel of an environment map or light texture (a config gives at most 1e6 x 1e6: its file's
#: values, warpscatter.schema.MAX_EMISSION, times its scale): larger ones overflow float32 in the renderers' products.
MAX_TEXEL_RADIANCE = 1.0e12


@wp.struct
class EnvData:
    """A lat-long environment map and its sampling tables as kernels see it (build with :class:`EnvironmentMap`)."""

    width: int
    height: int
    pixels: wp.array2d(dtype=wp.vec3)  # (H, W) radiance
    marginal_cdf: wp.array(dtype=wp.float32)  # (H + 1,)
    conditional_cdf: wp.array2d(dtype=wp.float32)  # (H, W + 1)
    texel_pdf: wp.array2d(dtype=wp.float32)  # (H, W) density in (u, v)
    marginal_guide: wp.array(dtype=wp.int32)
    conditional_guide: wp.array2d(dtype=wp.int32)


@wp.func
def latlong_param(d: wp.vec3) -> wp.vec2:
    """Inverse lat-long mapping: direction (any length > 0) -> (u, v) in [0, 1) x [0, 1]."""
    n = wp.length(d)
    y = 1.0
    if n > 0.0:
        y = wp.clamp(d[1] / n, -1.0, 1.0)
    phi = wp.atan2(d[2], d[0])
    if phi < 0.0:
        phi = phi + 2.0 * wp.pi
    u = phi / (2.0 * wp.pi)
    if u >= 1.0:
        u = 0.0
    return wp.vec2(u, wp.acos(y) / wp.pi)



@wp.func
def cdf_search(cdf: wp.array(dtype=wp.float32), n: int, x: float) -> int:
    """Interval k in [0, n) with cdf[k] <= x < cdf[k + 1] of an (n + 1,) CDF, by binary search."""
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
def guided_search(cdf: wp.array(dtype=wp.float32), guide: wp.array(dtype=wp.int32), n: int, x: float) -> int:
    """:func:`cdf_search` (the same interval) by a short scan up from the CDF's guide table (:func:`cdf_guide`)."""
    g = wp.clamp(int(x * float(guide.shape[0])), 0, guide.shape[0] - 1)
    k = guide[g]
    while k + 1 < n and cdf[k + 1] <= x:
        k = k + 1
    return k


@wp.func
def guided_search_row(cdf: wp.array2d(dtype=wp.float32), guide: wp.array2d(dtype=wp.int32), row: int, n: int,
                      x: float) -> int:
    """:func:`guided_search` in row ``row`` of a 2-D table of CDFs and their guide tables."""
    g = wp.clamp(int(x * float(guide.shape[1])), 0, guide.shape[1] - 1)
    k = guide[row, g]
    while k + 1 < n and cdf[row, k + 1] <= x:
        k = k + 1
    return k


@wp.func
def env_direction_sin(u: float, v: float) -> tuple[wp.vec3, float]:
    """:func:`env_direction` of (u, v) and its sin(theta) = sin(pi v) (one sine for both)."""
    phi = 2.0 * wp.pi * u
    theta = wp.pi * v
    st = wp.sin(theta)
    return wp.vec3(st * wp.cos(phi), wp.cos(theta), st * wp.sin(phi)), st


@wp.func
def env_direction(u: float, v: float) -> wp.vec3:
    """Lat-long mapping (u, v) in [0, 1]^2 -> unit direction: phi = 2 pi u, theta = pi v from +Y."""
    d, _st = env_direction_sin(u, v)
    return d


@wp.func
def env_texel_uv(env: EnvData, uv: wp.vec2) -> wp.vec2i:
    """Texel (column i, row j) holding the direction of lat-long parameters ``uv``."""
    i = wp.clamp(int(uv[0] * float(env.width)), 0, env.width - 1)
    j = wp.clamp(int(uv[1] * float(env.height)), 0, env.height - 1)
    return wp.vec2i(i, j)


@wp.func
def env_texel(env: EnvData, d: wp.vec3) -> wp.vec2i:
    """Texel (column i, row j) of the map holding direction ``d`` (any length > 0)."""
    return env_texel_uv(env, latlong_param(d))


@wp.func
def env_lookup_uv(env: EnvData, uv: wp.vec2) -> wp.vec3:
    """:func:`env_lookup` of the direction whose lat-long parameters ``uv`` the caller already has."""
    t = env_texel_uv(env, uv)
    return env.pixels[t[1], t[0]]


@wp.func
def env_lookup(env: EnvData, d: wp.vec3) -> wp.vec3:
    """Radiance L_in arriving from direction ``d`` (nearest texel: the map is piecewise constant)."""
    return env_lookup_uv(env, latlong_param(d))


@wp.func
def env_pdf_uv(env: EnvData, d: wp.vec3, uv: wp.vec2) -> float:
    """:func:`env_pdf` of direction ``d`` whose lat-long parameters ``uv`` the caller already has."""
    n = wp.length(d)
    if not (n > 0.0):
        return 0.0
    s = wp.sqrt(d[0] * d[0] + d[2] * d[2]) / n  # sin theta, accurate near the poles
    if s < 1.0e-7:
        return 0.0
    t = env_texel_uv(env, uv)
    return env.texel_pdf[t[1], t[0]] / (2.0 * wp.pi * wp.pi * s)


@wp.func
def env_pdf(env: EnvData, d: wp.vec3) -> float:
    """Solid-angle density (1/sr) of :func:`env_sample` drawing ``d``: p_uv / (2 pi^2 sin theta); 0 at the poles."""
    return env_pdf_uv(env, d, latlong_param(d))


@wp.func
def env_sample_uv(env: EnvData, xi: wp.vec2) -> tuple[wp.vec3, wp.vec3, float, wp.vec2]:
    """:func:`env_sample`, also returning the sample's lat-long parameters (u, v)."""
    x0 = wp.clamp(xi[0], 0.0, 0.99999994)
    x1 = wp.clamp(xi[1], 0.0, 0.99999994)
    j = guided_search(env.marginal_cdf, env.marginal_guide, env.height, x0)
    c0 = env.marginal_cdf[j]
    c1 = env.marginal_cdf[j + 1]
    dv = wp.clamp((x0 - c0) / wp.max(c1 - c0, 1.0e-30), 0.0, 1.0)
    i = guided_search_row(env.conditional_cdf, env.conditional_guide, j, env.width, x1)
    r0 = env.conditional_cdf[j, i]
    r1 = env.conditional_cdf[j, i + 1]
    du = wp.clamp((x1 - r0) / wp.max(r1 - r0, 1.0e-30), 0.0, 1.0)
    u = (float(i) + du) / float(env.width)
    v = (float(j) + dv) / float(env.height)
    d, s = env_direction_sin(u, v)
    pdf = float(0.0)
    if s >= 1.0e-7:
        pdf = env.texel_pdf[j, i] / (2.0 * wp.pi * wp.pi * s)
    return d, env.pixels[j, i], pdf, wp.vec2(u, v)


@wp.func
def env_sample(env: EnvData, xi: wp.vec2) -> tuple[wp.vec3, wp.vec3, float]:
    """Importance-sample the map (Ritschel 2007 Sec. 5.1, inverse CDFs P_L^-1) with uniform ``xi`` in [0, 1)^2.

    Returns:
        (unit direction, radiance L_in, solid-angle pdf in 1/sr; 0 marks an unusable sample at a pole).
    """
    d, radiance, pdf, _uv = env_sample_uv(env, xi)
    return d, radiance, pdf


@wp.kernel
def env_lookup_kernel(env: EnvData, directions: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    """out[k] = radiance of the map along directions[k] (:func:`env_lookup`)."""
    k = wp.tid()
    out[k] = env_lookup(env, directions[k])


#: Guide-table buckets per CDF interval (:func:`cdf_guide`).
GUIDE = 2


def cdf_guide(cdf, buckets: int) -> np.ndarray:
    """(buckets,) int32 guide table of an (n + 1,) float32 CDF (Chen & Asau 1974): entry g is the last interval
    with cdf[k] <= the smallest float32 x the kernel puts in bucket g."""
    c = np.asarray(cdf, np.float32)
    n = c.shape[0] - 1
    g = np.arange(buckets)
    scale = np.float32(buckets)
    x = (g / buckets).astype(np.float32)
    for _ in range(8):
        below = (x * scale).astype(np.float32) < g
        if not below.any():
            break
        x = np.where(below, np.nextafter(x, np.float32(2.0)), x)
    for _ in range(8):
        lower = np.nextafter(x, np.float32(-1.0))
        inside = (x > 0.0) & ((lower * scale).astype(np.float32) >= g)
        if not inside.any():
            break
        x = np.where(inside, lower, x)
    k = np.searchsorted(c[:n], x, side="right") - 1
    return np.clip(k, 0, n - 1).astype(np.int32)



class EnvironmentMap:
    """A lat-long environment map with the inverse-CDF tables of its importance sampling: rows weighted by luminance
    x sin theta_j, columns by luminance (a black map is sampled uniformly).

    Args:
        image: (H, W, 3) or (H, W, 4) linear RGB(A) radiance (alpha ignored), row 0 = zenith; ValueError for a wrong
            shape, an empty image, non-finite or negative texels, or texels above :data:`MAX_TEXEL_RADIANCE`.
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
        if np.any(img > MAX_TEXEL_RADIANCE):
            raise ValueError(f"image contains radiance above {MAX_TEXEL_RADIANCE:g} (largest {float(img.max()):g})")
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
        self.marginal_guide = cdf_guide(self.marginal_cdf, GUIDE * h)
        self.conditional_guide = np.stack([cdf_guide(row, GUIDE * w) for row in self.conditional_cdf])
        self._device_cache: dict = {}

    @property
    def width(self) -> int:
        return int(self.image.shape[1])

    @property
    def height(self) -> int:
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
                      device=device)
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
            d.marginal_guide = wp.array(self.marginal_guide, dtype=wp.int32, device=device)
            d.conditional_guide = wp.array(self.conditional_guide, dtype=wp.int32, device=device)
            self._device_cache[device] = d
        return self._device_cache[device]


__all__ = [
    "GUIDE",
    "LUMA",
    "MAX_TEXEL_RADIANCE",
    "EnvData",
    "EnvironmentMap",
    "cdf_guide",
    "cdf_search",
    "cdf_search_row",
    "env_direction",
    "env_direction_sin",
    "env_lookup",
    "env_lookup_uv",
    "env_pdf",
    "env_pdf_uv",
    "env_sample",
    "env_sample_uv",
    "env_texel",
    "env_texel_uv",
    "guided_search",
    "guided_search_row",
]
