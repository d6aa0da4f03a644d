"""Light sources (CONVENTIONS.md): every light's host class, and the classic lights as kernels see them.

Classic lights (:class:`LightParams`, :func:`light_sample`): directional (``direction`` of travel, RGB
``irradiance``), spot (HALF-angle ``cone_deg``, ``intensity`` in W/sr, optional texture over its projection's square
[-1, 1]^2) and point (six square spots). Monte-Carlo lights (Ritschel et al. 2007 Sec. 4-5): environment maps and
area, linear and volume lights (:class:`LocalLightData`). Each light's config section is in :mod:`.light_configs`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Union

import numpy as np
import warp as wp

from ..runtime.device import default_device, module_options
from .camera import look_at_basis, normalize, perspective_matrix, view_matrix
from .environment_map import MAX_TEXEL_RADIANCE, EnvironmentMap, cdf_search, cdf_search_row

module_options()

LIGHT_DIRECTIONAL = wp.constant(0)
LIGHT_SPOT = wp.constant(1)
LOCAL_LIGHT_AREA = wp.constant(0)
LOCAL_LIGHT_LINEAR = wp.constant(1)
LOCAL_LIGHT_VOLUME = wp.constant(2)


def _light_samples_count(name: str, value, hi: int) -> int:
    """An integer sample count in [1, hi] (ValueError naming ``name`` otherwise)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if not 1 <= int(value) <= hi:
        raise ValueError(f"{name} must lie in [1, {hi}], got {value}")
    return int(value)


def _light_texture(texture) -> np.ndarray:
    """A light texture as (H, W, 3) float32, contiguous; ValueError unless it is an (H, W, >= 3) image of finite
    values in [0, MAX_TEXEL_RADIANCE]."""
    tex = np.asarray(texture, np.float32)
    if tex.ndim != 3 or tex.shape[0] < 1 or tex.shape[1] < 1 or tex.shape[2] < 3:
        raise ValueError(f"texture must be an (H, W, 3) image, got shape {tex.shape}")
    rgb = tex[..., :3]
    if not np.all(np.isfinite(rgb)) or np.any(rgb < 0):
        raise ValueError("texture must be an (H, W, 3) image of finite values >= 0")
    if np.any(rgb > MAX_TEXEL_RADIANCE):
        raise ValueError(f"texture values must be at most {MAX_TEXEL_RADIANCE:g} (largest {float(rgb.max()):g})")
    return np.ascontiguousarray(rgb)


def light_grid_params(n1: int, n2: int) -> np.ndarray:
    """Parameters (s, t) in [0, 1]^2 of the centres of an n1 x n2 light-sample grid, (n2, n1, 2)."""
    s = (np.arange(n1) + 0.5) / n1
    t = (np.arange(n2) + 0.5) / n2
    return np.stack(np.meshgrid(s, t), axis=-1)


def segment_light_samples(p0, p1, n: int) -> np.ndarray:
    """Sample points of a linear light (d = 1): n cell centres of the segment p0 -> p1, shape (1, n, 3)."""
    n = _light_samples_count("n", n, 2**20)
    s = light_grid_params(n, 1)[..., 0:1]
    return np.asarray(p0, np.float64) + s * (np.asarray(p1, np.float64) - np.asarray(p0, np.float64))


def parallelogram_light_samples(corner, edge_s, edge_t, n1: int, n2: int) -> np.ndarray:
    """Sample points of an area light: the n1 x n2 cell centres of corner + s edge_s + t edge_t, (n2, n1, 3)."""
    n1 = _light_samples_count("n1", n1, 2**15)
    n2 = _light_samples_count("n2", n2, 2**15)
    st = light_grid_params(n1, n2)
    c = np.asarray(corner, np.float64)
    return c + st[..., 0:1] * np.asarray(edge_s, np.float64) + st[..., 1:2] * np.asarray(edge_t, np.float64)



@dataclass(frozen=True)
class DirectionalLight:
    """Directional light: unit ``direction`` of travel, RGB ``irradiance``."""

    direction: np.ndarray
    irradiance: np.ndarray = field(default_factory=lambda: np.ones(3))

    def __post_init__(self):
        object.__setattr__(self, "direction", normalize(self.direction))
        object.__setattr__(self, "irradiance", np.asarray(self.irradiance, dtype=np.float64))

    kind = "directional"


@dataclass(frozen=True)
class SpotLight:
    """Spot light at ``position``, axis ``direction``, half-angle ``cone_deg``, RGB ``intensity`` (W/sr) and an
    optional linear RGB ``texture`` (H, W, 3) of finite values in [0, MAX_TEXEL_RADIANCE], row 0 = top (+v)."""

    position: np.ndarray
    direction: np.ndarray
    cone_deg: float
    intensity: np.ndarray
    texture: np.ndarray | None = None
    square: bool = False  # the cone is its shadow map's square pyramid (a point light's cube face)

    kind = "spot"

    def __post_init__(self):
        object.__setattr__(self, "position", np.asarray(self.position, dtype=np.float64))
        object.__setattr__(self, "direction", normalize(self.direction))
        object.__setattr__(self, "intensity", np.asarray(self.intensity, dtype=np.float64))
        if not 0.0 < self.cone_deg < 90.0:
            raise ValueError("spot cone_deg (half-angle) must lie in (0, 90) degrees")
        if self.texture is not None:
            object.__setattr__(self, "texture", _light_texture(self.texture))

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up, forward) of the spot's frame; up is the projection of world +Y (or +Z if parallel)."""
        up = np.array([0.0, 1.0, 0.0])
        if abs(np.dot(up, self.direction)) > 0.99:
            up = np.array([0.0, 0.0, 1.0])
        return look_at_basis(self.position, self.position + self.direction, up)

    def view_projection(self, near: float, far: float) -> np.ndarray:
        """World -> clip matrix of the spot's square frustum (fov = 2 * cone_deg)."""
        return perspective_matrix(2.0 * self.cone_deg, 1.0, near, far) @ view_matrix(self.position, *self.basis())

    @property
    def outer_cone_deg(self) -> float:
        """Half-angle of the smallest circular cone holding every lit direction (a square spot's corner)."""
        if not self.square:
            return float(self.cone_deg)
        return math.degrees(math.atan(math.sqrt(2.0) * math.tan(math.radians(self.cone_deg))))


#: A point light's six cube faces: the axes its square spots look along.
CUBE_FACES = ((1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0), (0.0, 0.0, -1.0))


@dataclass(frozen=True)
class PointLight:
    """Omnidirectional light at ``position``, RGB ``intensity`` (W/sr); rendered as six square spots with their own
    shadow maps (:meth:`faces`; Klehm 2014 Sec. 3.2)."""

    position: np.ndarray
    intensity: np.ndarray

    kind = "point"

    def __post_init__(self):
        object.__setattr__(self, "position", _vec(self.position, "position"))
        object.__setattr__(self, "intensity", _vec(self.intensity, "intensity"))
        if np.any(self.intensity < 0.0):
            raise ValueError("intensity must be >= 0")

    def faces(self) -> tuple[SpotLight, ...]:
        """The six square 90-degree spots (cone_deg 45, axis-aligned frusta) that tile every direction."""
        return tuple(SpotLight(self.position, np.array(axis), 45.0, self.intensity, square=True)
                     for axis in CUBE_FACES)


@dataclass(frozen=True)
class EnvironmentLight:
    """A distant lat-long environment map (radiance texels, already multiplied by the config's ``scale``)."""

    env: EnvironmentMap

    kind = "environment"
    directions_per_stratum = 2  # a light sample and a BRDF sample


def _vec(a, name: str) -> np.ndarray:
    v = np.asarray(a, np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be 3 finite numbers, got {a!r}")
    return v


@dataclass(frozen=True)
class AreaLight:
    """Parallelogram light corner + s u + t v (scene units), RGB radiance L_e (W m^-2 sr^-1), emitting towards
    n_l = u x v / |u x v| or ``two_sided``; an optional ``texture`` over (s, t) has row 0 at the edge t = 1."""

    corner: np.ndarray
    u: np.ndarray
    v: np.ndarray
    radiance: np.ndarray
    two_sided: bool = False
    texture: np.ndarray | None = None

    kind = "area"
    directions_per_stratum = 2

    def __post_init__(self):
        for name in ("corner", "u", "v", "radiance"):
            object.__setattr__(self, name, _vec(getattr(self, name), name))
        if np.any(self.radiance < 0.0):
            raise ValueError("radiance must be >= 0")
        if not self.area > 1e-12 * max(np.dot(self.u, self.u), np.dot(self.v, self.v), 1e-30):
            raise ValueError("u and v must span a parallelogram (non-zero and not parallel)")
        if np.any(self.radiance > MAX_TEXEL_RADIANCE):
            raise ValueError(f"radiance must be at most {MAX_TEXEL_RADIANCE:g}, got {self.radiance.tolist()}")
        if self.texture is not None:
            tex = _light_texture(self.texture)
            if not tex.max() > 0.0:
                raise ValueError("texture is black: the light would emit nothing")
            object.__setattr__(self, "texture", tex)

    @classmethod
    def from_power(cls, corner, u, v, power, two_sided: bool = False, texture=None) -> AreaLight:
        """The light emitting RGB ``power`` (W): L_e = P / (pi A), two-sided P / (2 pi A), over the texture's mean."""
        a = float(np.linalg.norm(np.cross(_vec(u, "u"), _vec(v, "v"))))
        if not a > 0.0:
            raise ValueError("u and v must span a parallelogram (non-zero and not parallel)")
        radiance = _vec(power, "power") / ((2.0 if two_sided else 1.0) * np.pi * a)
        if texture is not None:
            mean = np.asarray(texture, np.float64)[..., :3].reshape(-1, 3).mean(axis=0)
            if np.any((mean <= 0.0) & (radiance > 0.0)):
                raise ValueError("texture: a channel with power is black all over")
            radiance = np.where(mean > 0.0, radiance / np.maximum(mean, 1e-300), 0.0)
            if np.any(radiance > MAX_TEXEL_RADIANCE):
                raise ValueError(f"texture: its mean {mean.tolist()} is so dark that the radiance giving the power, "
                                 f"{radiance.tolist()}, exceeds {MAX_TEXEL_RADIANCE:g} (brighten the texture)")
        return cls(corner, u, v, radiance, two_sided, texture)

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

        return parallelogram_light_samples(self.corner, self.u, self.v, n1, n2)

    def device_data(self, device=None) -> LocalLightData:
        """The light as kernels see it (:class:`LocalLightData`)."""
        d = LocalLightData()
        d.kind = LOCAL_LIGHT_AREA
        d.origin, d.edge_u, d.edge_v = (wp.vec3(*map(float, a)) for a in (self.corner, self.u, self.v))
        d.normal = wp.vec3(*map(float, self.normal))
        d.size = self.area
        d.emission = wp.vec3(*map(float, self.radiance))
        d.two_sided = int(bool(self.two_sided))
        d.has_texture = int(self.texture is not None)
        d.texture = light_texture_array(self, device)
        marginal, conditional, texel_pdf = self.sampling_tables()
        d.marginal_cdf = wp.array(marginal, dtype=wp.float32, device=default_device(device))
        d.conditional_cdf = wp.array(conditional, dtype=wp.float32, device=default_device(device))
        d.texel_pdf = wp.array(texel_pdf, dtype=wp.float32, device=default_device(device))
        return d

    def sampling_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Tables for sampling by radiance (Ritschel 2007 Sec. 5.1): rows' CDF (H + 1,), per-row CDFs (H, W + 1),
        texel density relative to uniform (H, W). A texel weighs its 3 x 3 maximum, as bilinear look-ups spread it."""
        if self.texture is None:
            return np.array([0.0, 1.0], np.float32), np.array([[0.0, 1.0]], np.float32), np.ones((1, 1), np.float32)
        emit = (np.asarray(self.texture, np.float64) * self.radiance).sum(axis=-1)
        padded = np.pad(emit, 1, mode="edge")
        h, w = emit.shape
        weight = np.max([padded[a:a + h, b:b + w] for a in range(3) for b in range(3)], axis=0)
        if not weight.sum() > 0.0:  # emits nothing (a black radiance): sample the texels uniformly
            weight = np.ones((h, w))
        rows = weight.sum(axis=1)
        marginal = np.concatenate([[0.0], np.cumsum(rows)]) / rows.sum()
        conditional = np.concatenate([np.zeros((h, 1)), np.cumsum(weight, axis=1)], axis=1)
        conditional /= np.maximum(conditional[:, -1:], 1e-300)
        texel_pdf = weight / weight.mean()
        return marginal.astype(np.float32), conditional.astype(np.float32), texel_pdf.astype(np.float32)


@dataclass(frozen=True)
class LinearLight:
    """Segment light start -> end, isotropic, RGB ``intensity`` per unit length (W sr^-1 unit^-1)."""

    start: np.ndarray
    end: np.ndarray
    intensity: np.ndarray

    kind = "linear"
    directions_per_stratum = 1  # no surface for a BRDF sample to hit

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

        return segment_light_samples(self.start, self.end, n1)

    def device_data(self, device=None) -> LocalLightData:
        """The light as kernels see it (:class:`LocalLightData`)."""
        d = LocalLightData()
        d.has_texture = 0
        d.texture = light_texture_array(self, device)
        d.marginal_cdf = wp.array([0.0, 1.0], dtype=wp.float32, device=default_device(device))
        d.conditional_cdf = wp.array([[0.0, 1.0]], dtype=wp.float32, device=default_device(device))
        d.texel_pdf = wp.ones((1, 1), dtype=wp.float32, device=default_device(device))
        d.kind = LOCAL_LIGHT_LINEAR
        d.origin = wp.vec3(*map(float, self.start))
        d.edge_u = wp.vec3(*map(float, self.end - self.start))
        d.edge_v = wp.vec3(0.0, 0.0, 0.0)
        d.normal = wp.vec3(0.0, 0.0, 0.0)
        d.size = self.length
        d.emission = wp.vec3(*map(float, self.intensity))
        d.two_sided = 1
        return d


@dataclass(frozen=True)
class VolumeLight:
    """Parallelepiped light corner + s u + t v + r w, isotropic, RGB ``intensity`` per unit volume (W sr^-1 unit^-3)."""

    corner: np.ndarray
    u: np.ndarray
    v: np.ndarray
    w: np.ndarray
    intensity: np.ndarray

    kind = "volume"
    directions_per_stratum = 1

    def __post_init__(self):
        for name in ("corner", "u", "v", "w", "intensity"):
            object.__setattr__(self, name, _vec(getattr(self, name), name))
        if np.any(self.intensity < 0.0):
            raise ValueError("intensity must be >= 0")
        scale = float(np.linalg.norm(self.u) * np.linalg.norm(self.v) * np.linalg.norm(self.w))
        if not self.volume > 1e-9 * scale:
            raise ValueError("u, v and w must span a volume (non-zero and not coplanar)")

    @classmethod
    def from_power(cls, corner, u, v, w, power) -> VolumeLight:
        """The light emitting RGB ``power`` (W): I = P / (4 pi V)."""
        vol = abs(float(np.dot(_vec(u, "u"), np.cross(_vec(v, "v"), _vec(w, "w")))))
        if not vol > 0.0:
            raise ValueError("u, v and w must span a volume (non-zero and not coplanar)")
        return cls(corner, u, v, w, _vec(power, "power") / (4.0 * np.pi * vol))

    @property
    def volume(self) -> float:
        """V = |u . (v x w)|."""
        return abs(float(np.dot(self.u, np.cross(self.v, self.w))))

    def device_data(self, device=None) -> LocalLightData:
        """The light as kernels see it (:class:`LocalLightData`; ``normal`` holds the third edge w)."""
        d = LinearLight.device_data(LinearLight(self.corner, self.corner + self.u, self.intensity), device)
        d.kind = LOCAL_LIGHT_VOLUME
        d.edge_v = wp.vec3(*map(float, self.v))
        d.normal = wp.vec3(*map(float, self.w))
        d.size = self.volume
        return d


#: Any light of a :class:`~warpscatter.scene.Scene`.
Light = Union[DirectionalLight, SpotLight, PointLight, EnvironmentLight, AreaLight, LinearLight, VolumeLight]


@wp.struct
class LocalLightData:
    """An area, linear or volume light as kernels see it (build with the lights' ``device_data``)."""

    kind: int  # LOCAL_LIGHT_*
    origin: wp.vec3  # corner; linear: start
    edge_u: wp.vec3  # linear: end - start
    edge_v: wp.vec3
    normal: wp.vec3  # area: unit n_l; volume: the third edge w
    size: float  # area, length or volume
    emission: wp.vec3  # area: radiance L_e; linear, volume: intensity I
    two_sided: int
    has_texture: int
    texture: wp.array2d(dtype=wp.vec3)  # area: row 0 = the edge t = 1; 1x1 white without one
    marginal_cdf: wp.array(dtype=wp.float32)
    conditional_cdf: wp.array2d(dtype=wp.float32)
    texel_pdf: wp.array2d(dtype=wp.float32)


@wp.func
def area_light_point(light: LocalLightData, st: wp.vec2) -> wp.vec3:
    """y(s, t) = corner + s u + t v."""
    return light.origin + st[0] * light.edge_u + st[1] * light.edge_v


@wp.func
def area_light_radiance(light: LocalLightData, w: wp.vec3, st: wp.vec2) -> wp.vec3:
    """Radiance leaving point (s, t) along unit ``w`` (towards the receiver); 0 behind a one-sided light."""
    if light.two_sided == 0 and wp.dot(light.normal, w) <= 0.0:
        return wp.vec3(0.0)
    if light.has_texture != 0:
        return wp.cw_mul(light.emission, sample_bilinear_rgb(light.texture, st[0], 1.0 - st[1]))
    return light.emission


@wp.func
def area_light_texel(light: LocalLightData, st: wp.vec2) -> wp.vec2i:
    """(row, column) of the texture texel holding the light's point (s, t) (row 0 = the edge t = 1)."""
    h = light.texel_pdf.shape[0]
    w = light.texel_pdf.shape[1]
    return wp.vec2i(wp.clamp(int((1.0 - st[1]) * float(h)), 0, h - 1), wp.clamp(int(st[0] * float(w)), 0, w - 1))


@wp.func
def area_light_sample_st(light: LocalLightData, xi: wp.vec2) -> wp.vec2:
    """(s, t) for uniform ``xi`` in [0, 1)^2: ``xi``, or sampled by radiance through a texture's CDFs."""
    if light.has_texture == 0:
        return xi
    h = light.texel_pdf.shape[0]
    w = light.texel_pdf.shape[1]
    x0 = wp.clamp(xi[0], 0.0, 0.99999994)
    x1 = wp.clamp(xi[1], 0.0, 0.99999994)
    j = cdf_search(light.marginal_cdf, h, x1)
    dv = wp.clamp((x1 - light.marginal_cdf[j]) / wp.max(light.marginal_cdf[j + 1] - light.marginal_cdf[j], 1.0e-30),
                  0.0, 1.0)
    i = cdf_search_row(light.conditional_cdf, j, w, x0)
    r0 = light.conditional_cdf[j, i]
    du = wp.clamp((x0 - r0) / wp.max(light.conditional_cdf[j, i + 1] - r0, 1.0e-30), 0.0, 1.0)
    return wp.vec2((float(i) + du) / float(w), 1.0 - (float(j) + dv) / float(h))


@wp.func
def area_light_pdf(light: LocalLightData, x: wp.vec3, y: wp.vec3, st: wp.vec2) -> float:
    """Solid-angle density (1/sr) from ``x`` of sampling y(s, t): p(s, t) d^2 / (A |cos theta_l|); 0 when grazing."""
    w = y - x
    d2 = wp.dot(w, w)
    c = wp.abs(wp.dot(light.normal, w)) / wp.sqrt(d2)
    if not (c > 1.0e-7) or not (light.size > 0.0):
        return 0.0
    p = float(1.0)
    if light.has_texture != 0:
        k = area_light_texel(light, st)
        p = light.texel_pdf[k[0], k[1]]
    return p * d2 / (light.size * c)


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


@wp.struct
class LightParams:
    """A light as kernels see it (one struct for every light type)."""

    kind: int
    direction: wp.vec3  # travel direction or cone axis
    position: wp.vec3
    radiance: wp.vec3  # irradiance E (directional) or intensity I in W/sr (spot)
    right: wp.vec3
    up: wp.vec3
    tan_cone: float
    cos_cone: float  # of the outer cone (SpotLight.outer_cone_deg)
    square: int
    has_texture: int
    texture: wp.array2d(dtype=wp.vec3)  # row 0 = top (+v); 1x1 white without one


def light_params(light, device=None, texture: wp.array | None = None) -> LightParams:
    """:class:`LightParams` of a :class:`DirectionalLight` or :class:`SpotLight`, its texture array on ``device``;
    ``texture``: an (H, W) vec3 array replacing ``light.texture`` (a prefiltered copy, say)."""
    p = LightParams()
    p.direction = wp.vec3(*light.direction)
    if isinstance(light, DirectionalLight):
        p.kind = LIGHT_DIRECTIONAL
        p.radiance = wp.vec3(*light.irradiance)
        p.position = wp.vec3(0.0, 0.0, 0.0)
        p.right = wp.vec3(1.0, 0.0, 0.0)
        p.up = wp.vec3(0.0, 1.0, 0.0)
        p.tan_cone = 0.0
        p.cos_cone = -1.0
        p.square = 0
        p.has_texture = 0
    else:
        right, up, _ = light.basis()
        p.kind = LIGHT_SPOT
        p.radiance = wp.vec3(*light.intensity)
        p.position = wp.vec3(*light.position)
        p.right = wp.vec3(*right)
        p.up = wp.vec3(*up)
        p.tan_cone = float(np.tan(np.radians(light.cone_deg)))
        p.cos_cone = float(np.cos(np.radians(light.outer_cone_deg)))
        p.square = int(bool(light.square))
        p.has_texture = int(light.texture is not None)
    p.texture = texture if texture is not None else light_texture_array(light, device)
    return p


def light_texture_array(light, device=None) -> wp.array:
    """The light texture as a wp.array2d(vec3) (a 1x1 white texel when the light has none)."""
    tex = getattr(light, "texture", None)
    if tex is None:
        tex = np.ones((1, 1, 3), dtype=np.float32)
    return wp.array(np.ascontiguousarray(tex[..., :3], dtype=np.float32), dtype=wp.vec3,
                    device=default_device(device))


@wp.func
def sample_bilinear_rgb(tex: wp.array2d(dtype=wp.vec3), u: float, v: float) -> wp.vec3:
    """Bilinear lookup of an RGB texture at (u, v) in [0,1]^2, u to the right, v DOWN (row 0 = v 0), clamped."""
    h = tex.shape[0]
    w = tex.shape[1]
    x = wp.clamp(u * float(w) - 0.5, 0.0, float(w - 1))
    y = wp.clamp(v * float(h) - 0.5, 0.0, float(h - 1))
    x0 = int(wp.floor(x))
    y0 = int(wp.floor(y))
    x1 = wp.min(x0 + 1, w - 1)
    y1 = wp.min(y0 + 1, h - 1)
    fx = x - float(x0)
    fy = y - float(y0)
    top = tex[y0, x0] * (1.0 - fx) + tex[y0, x1] * fx
    bottom = tex[y1, x0] * (1.0 - fx) + tex[y1, x1] * fx
    return top * (1.0 - fy) + bottom * fy


@wp.func
def light_sample(light: LightParams, x: wp.vec3):
    """Incident light at world point ``x``.

    Returns:
        (E, omega_l, dist): irradiance RGB at x on a plane facing the light (0 outside a spot's cone),
        the unit direction light travels at x, and the distance from x to the light (1e30 when directional).
    """
    if light.kind == LIGHT_DIRECTIONAL:
        return light.radiance, light.direction, 1.0e30
    to_x = x - light.position
    d2 = wp.max(wp.dot(to_x, to_x), 1.0e-20)
    d = wp.sqrt(d2)
    omega = to_x / d
    c = wp.dot(omega, light.direction)
    e = wp.vec3(0.0, 0.0, 0.0)
    inside = c > light.cos_cone and c > 0.0
    if light.square != 0:
        reach = c * light.tan_cone
        inside = c > 0.0 and wp.abs(wp.dot(omega, light.right)) <= reach and wp.abs(wp.dot(omega, light.up)) <= reach
    if inside:
        e = light.radiance / d2
        if light.has_texture != 0:
            su = wp.dot(omega, light.right) / (c * light.tan_cone)
            sv = wp.dot(omega, light.up) / (c * light.tan_cone)
            t = sample_bilinear_rgb(light.texture, 0.5 * su + 0.5, 0.5 - 0.5 * sv)
            e = wp.cw_mul(e, t)
    return e, omega, d


@wp.func
def faces_away_from_light(light: LightParams, x: wp.vec3, n: wp.vec3) -> bool:
    """Whether a surface at ``x`` with viewer-facing unit normal ``n`` faces away from the light (False for n = 0)."""
    if wp.dot(n, n) < 0.25:
        return False
    _e, omega, _d = light_sample(light, x)
    return wp.dot(n, omega) > 0.0
