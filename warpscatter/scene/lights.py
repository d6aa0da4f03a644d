"""Light sources (CONVENTIONS.md): directional and spot lights, host-side and as kernels see them.

* Directional: ``direction`` is the unit direction light TRAVELS; ``irradiance`` RGB on a plane
  perpendicular to it. The light is at infinity: every point of the medium receives the same E.
* Spot: ``position``, unit axis ``direction``, ``cone_deg`` the HALF-angle of the cone (degrees),
  ``intensity`` RGB (W/sr). Irradiance at x is intensity / d^2 times the light texture, if any, for
  points inside the cone and 0 outside. The texture spans the square [-1,1]^2 of the spot's
  perspective projection (field of view 2 * cone_deg, its +v axis along the light's up), so a
  spot shadow map and its texture share texel coordinates.

``LightParams`` is a single struct for both types so kernels need one code path;
:func:`light_sample` returns, for a world point, the incident irradiance, the unit direction the
light travels at that point and the distance to the light (inf for directional lights).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import warp as wp

from ..wpinit import module_options
from .camera import look_at_basis, normalize, perspective_matrix, view_matrix

module_options()

LIGHT_DIRECTIONAL = 0
LIGHT_SPOT = 1


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
    """Spot light at ``position`` with unit axis ``direction``, half-angle ``cone_deg``, RGB ``intensity`` (W/sr).

    ``texture`` is an optional linear RGB float32 image (H, W, 3), row 0 = top (+v of the light).
    """

    position: np.ndarray
    direction: np.ndarray
    cone_deg: float
    intensity: np.ndarray
    texture: np.ndarray | None = None

    kind = "spot"

    def __post_init__(self):
        object.__setattr__(self, "position", np.asarray(self.position, dtype=np.float64))
        object.__setattr__(self, "direction", normalize(self.direction))
        object.__setattr__(self, "intensity", np.asarray(self.intensity, dtype=np.float64))
        if not 0.0 < self.cone_deg < 90.0:
            raise ValueError("spot cone_deg (half-angle) must lie in (0, 90) degrees")

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up, forward) of the spot's frame; up is the projection of world +Y (or +Z if parallel)."""
        up = np.array([0.0, 1.0, 0.0])
        if abs(np.dot(up, self.direction)) > 0.99:
            up = np.array([0.0, 0.0, 1.0])
        return look_at_basis(self.position, self.position + self.direction, up)

    def view_projection(self, near: float, far: float) -> np.ndarray:
        """World -> clip matrix of the spot's square frustum (fov = 2 * cone_deg)."""
        return perspective_matrix(2.0 * self.cone_deg, 1.0, near, far) @ view_matrix(self.position, *self.basis())


@wp.struct
class LightParams:
    """A light as kernels see it (one struct for every light type)."""

    kind: int  # LIGHT_DIRECTIONAL or LIGHT_SPOT
    direction: wp.vec3  # unit: travel direction (directional) or cone axis (spot)
    position: wp.vec3  # spot position (unused for directional)
    radiance: wp.vec3  # irradiance E (directional) or intensity I in W/sr (spot)
    right: wp.vec3  # spot frame, for the texture lookup
    up: wp.vec3
    tan_cone: float  # tan(cone half-angle)
    cos_cone: float  # cos(cone half-angle)
    has_texture: int


def light_params(light) -> LightParams:
    """Build :class:`LightParams` from a :class:`DirectionalLight` or :class:`SpotLight`."""
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
        p.has_texture = 0
    else:
        right, up, _ = light.basis()
        p.kind = LIGHT_SPOT
        p.radiance = wp.vec3(*light.intensity)
        p.position = wp.vec3(*light.position)
        p.right = wp.vec3(*right)
        p.up = wp.vec3(*up)
        p.tan_cone = float(np.tan(np.radians(light.cone_deg)))
        p.cos_cone = float(np.cos(np.radians(light.cone_deg)))
        p.has_texture = int(light.texture is not None)
    return p


def light_texture_array(light, device=None) -> wp.array:
    """The light texture as a wp.array2d(vec3) (a 1x1 white texel when the light has none)."""
    tex = getattr(light, "texture", None)
    if tex is None:
        tex = np.ones((1, 1, 3), dtype=np.float32)
    return wp.array(np.ascontiguousarray(tex[..., :3], dtype=np.float32), dtype=wp.vec3, device=device)


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
def light_sample(light: LightParams, tex: wp.array2d(dtype=wp.vec3), x: wp.vec3):
    """Incident light at world point ``x``.

    Returns:
        (E, omega_l, dist): irradiance RGB at x on a plane facing the light (0 outside a spot's cone),
        the unit direction light travels at x, and the distance from x to the light (1e30 when directional).
    """
    if light.kind == 0:
        return light.radiance, light.direction, 1.0e30
    to_x = x - light.position
    d2 = wp.max(wp.dot(to_x, to_x), 1.0e-20)
    d = wp.sqrt(d2)
    omega = to_x / d
    c = wp.dot(omega, light.direction)
    e = wp.vec3(0.0, 0.0, 0.0)
    if c > light.cos_cone and c > 0.0:
        e = light.radiance / d2
        if light.has_texture != 0:
            # project onto the spot's image plane at unit distance: [-1,1]^2 spans the cone's square
            su = wp.dot(omega, light.right) / (c * light.tan_cone)
            sv = wp.dot(omega, light.up) / (c * light.tan_cone)
            t = sample_bilinear_rgb(tex, 0.5 * su + 0.5, 0.5 - 0.5 * sv)
            e = wp.cw_mul(e, t)
    return e, omega, d
