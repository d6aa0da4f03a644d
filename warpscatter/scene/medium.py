"""Homogeneous participating medium and phase functions (CONVENTIONS.md, Klehm 2014 Sec. 2.1).

``sigma_t`` is extinction (1/scene unit), ``albedo`` the scattering albedo rho (sigma_s = rho sigma_t); both may be
RGB (coloured media; kernels then see ``coloured`` = 1, and the scalar ``sigma_t`` is the channels' mean).
cos_theta = dot(light_direction, -ray_direction), light_direction the direction light TRAVELS; g > 0 scatters forward.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..runtime.device import module_options

module_options()

INV_FOUR_PI = 1.0 / (4.0 * math.pi)

#: Phase-function ids used by kernels.
PHASE_ISOTROPIC = wp.constant(0)
PHASE_HENYEY_GREENSTEIN = wp.constant(1)


def _rgb(v) -> tuple[float, float, float]:
    """A scalar or 3-sequence as an RGB tuple of floats."""
    a = np.broadcast_to(np.asarray(v, np.float64), (3,))
    return (float(a[0]), float(a[1]), float(a[2]))


@dataclass(frozen=True)
class Medium:
    """Homogeneous medium: extinction sigma_t (1/unit), albedo rho (grey or RGB), phase ('isotropic' or
    'henyey_greenstein', g)."""

    sigma_t: float | tuple[float, float, float]
    albedo: float | tuple[float, float, float] = 1.0
    phase: str = "isotropic"
    g: float = 0.0

    @property
    def coloured(self) -> bool:
        """True when sigma_t or albedo differs between the channels."""
        return len(set(self.sigma_t_rgb)) > 1 or len(set(_rgb(self.albedo))) > 1

    @property
    def sigma_t_rgb(self) -> tuple[float, float, float]:
        """Extinction per channel (1/unit)."""
        return _rgb(self.sigma_t)

    @property
    def sigma_s_rgb(self) -> tuple[float, float, float]:
        """Scattering coefficient rho sigma_t per channel (1/unit)."""
        return tuple(a * t for a, t in zip(_rgb(self.albedo), self.sigma_t_rgb, strict=True))

    @property
    def extinction(self) -> float:
        """The scalar extinction (1/unit): sigma_t of a grey medium, the channels' mean of a coloured one."""
        return float(np.mean(self.sigma_t_rgb)) if self.coloured else self.sigma_t_rgb[0]

    @property
    def sigma_s(self):
        """rho sigma_t: a number for a grey medium (as given), an RGB tuple for a coloured one."""
        if np.ndim(self.sigma_t) == 0 and np.ndim(self.albedo) == 0:
            return self.albedo * self.sigma_t
        return self.sigma_s_rgb

    def transmittance(self, distance) -> np.ndarray:
        """exp(-sigma_t s) per channel: shape distance.shape + (3,) (float64)."""
        d = np.asarray(distance, np.float64)[..., None]
        return np.exp(-np.asarray(self.sigma_t_rgb) * d)

    @property
    def phase_id(self) -> int:
        return PHASE_HENYEY_GREENSTEIN if self.phase == "henyey_greenstein" else PHASE_ISOTROPIC

    def phase_value(self, cos_theta):
        """Phase function value (1/sr) on the host (numpy arrays or floats)."""
        if self.phase_id == PHASE_ISOTROPIC:
            return INV_FOUR_PI + 0.0 * cos_theta
        g = self.g
        return (1.0 - g * g) / (4.0 * math.pi * (1.0 + g * g - 2.0 * g * cos_theta) ** 1.5)

    def params(self) -> MediumParams:
        """The medium as kernels see it (:class:`MediumParams`)."""
        p = MediumParams()
        p.coloured = int(self.coloured)
        if self.coloured:
            p.sigma_t = self.extinction
            p.sigma_s = float(np.mean(self.sigma_s_rgb))
        else:
            p.sigma_t = self.sigma_t_rgb[0]
            p.sigma_s = self.sigma_s_rgb[0]
        p.sigma_t_rgb = wp.vec3(*self.sigma_t_rgb)
        p.sigma_s_rgb = wp.vec3(*self.sigma_s_rgb)
        p.phase_id = int(self.phase_id)
        p.g = float(self.g)
        return p


@wp.struct
class MediumParams:
    """Homogeneous medium as kernels see it."""

    sigma_t: float  # 1/unit, channels' mean
    sigma_s: float
    coloured: int  # 1: use sigma_t_rgb / sigma_s_rgb
    sigma_t_rgb: wp.vec3
    sigma_s_rgb: wp.vec3
    phase_id: int
    g: float


@wp.func
def phase_hg(cos_theta: float, g: float) -> float:
    """Henyey-Greenstein phase function (1/sr); g = 0 gives the isotropic 1/(4 pi)."""
    d = 1.0 + g * g - 2.0 * g * cos_theta
    return (1.0 - g * g) / (4.0 * wp.pi * d * wp.sqrt(d))


@wp.func
def phase_eval(phase_id: int, g: float, cos_theta: float) -> float:
    """Phase function by id (PHASE_ISOTROPIC or PHASE_HENYEY_GREENSTEIN)."""
    if phase_id == PHASE_ISOTROPIC:
        return 1.0 / (4.0 * wp.pi)
    return phase_hg(cos_theta, g)


@wp.func
def transmittance_integral(sigma_t: float, t0: float, t1: float) -> float:
    """Integral of exp(-sigma_t t) dt over [t0, t1] (Klehm 2014 Eq. 3); exact limit t1 - t0 when sigma_t -> 0."""
    if sigma_t * (t1 - t0) < 1.0e-4:
        # series keeps relative precision for thin media
        x = sigma_t * (t1 - t0)
        return wp.exp(-sigma_t * t0) * (t1 - t0) * (1.0 - 0.5 * x + x * x / 6.0)
    return (wp.exp(-sigma_t * t0) - wp.exp(-sigma_t * t1)) / sigma_t


@wp.func
def transmittance_integral_rgb(med: MediumParams, t0: float, t1: float) -> wp.vec3:
    """:func:`transmittance_integral` per channel of a coloured medium (all three equal for a grey one)."""
    if med.coloured == 0:
        v = transmittance_integral(med.sigma_t, t0, t1)
        return wp.vec3(v, v, v)
    return wp.vec3(transmittance_integral(med.sigma_t_rgb[0], t0, t1),
                   transmittance_integral(med.sigma_t_rgb[1], t0, t1),
                   transmittance_integral(med.sigma_t_rgb[2], t0, t1))


@wp.func
def coloured_scattering(med: MediumParams, radiance: wp.vec3, t0: float, t1: float) -> wp.vec3:
    """radiance * sigma_s * integral_t0^t1 exp(-sigma_t t) dt per channel: single scattering before phase and
    visibility."""
    return wp.cw_mul(wp.cw_mul(radiance, med.sigma_s_rgb), transmittance_integral_rgb(med, t0, t1))


@wp.func
def channel_decay(med: MediumParams, t: float, sigma_ref: float) -> wp.vec3:
    """exp(-(sigma_c - sigma_ref) t) per channel c of the medium's extinction."""
    k = med.sigma_t_rgb - wp.vec3(sigma_ref, sigma_ref, sigma_ref)
    return wp.vec3(wp.exp(-k[0] * t), wp.exp(-k[1] * t), wp.exp(-k[2] * t))


@wp.func
def view_transmittance(med: MediumParams, s: float) -> wp.vec3:
    """exp(-sigma_t s) per channel: what reaches the camera of radiance leaving a surface at distance s."""
    if med.coloured == 0:
        v = wp.exp(-med.sigma_t * s)
        return wp.vec3(v, v, v)
    return channel_decay(med, s, 0.0)
