"""Homogeneous participating medium and phase functions (CONVENTIONS.md, Klehm 2014 Sec. 2.1).

``sigma_t`` is extinction (1/scene unit), ``albedo`` the scattering albedo rho, so sigma_s = rho sigma_t.
cos_theta = dot(light_direction, -ray_direction) where light_direction is the direction light TRAVELS;
g > 0 scatters forward (looking into the light is brightest).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import warp as wp

from ..wpinit import module_options

module_options()

INV_FOUR_PI = 1.0 / (4.0 * math.pi)

#: Phase-function ids used by kernels.
PHASE_ISOTROPIC = wp.constant(0)
PHASE_HENYEY_GREENSTEIN = wp.constant(1)


@dataclass(frozen=True)
class Medium:
    """Homogeneous medium: extinction sigma_t (1/unit), albedo rho, phase ('isotropic' or 'henyey_greenstein', g)."""

    sigma_t: float
    albedo: float = 1.0
    phase: str = "isotropic"
    g: float = 0.0

    @property
    def sigma_s(self) -> float:
        return self.albedo * self.sigma_t

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
        p.sigma_t = float(self.sigma_t)
        p.sigma_s = float(self.sigma_s)
        p.phase_id = int(self.phase_id)
        p.g = float(self.g)
        return p


@wp.struct
class MediumParams:
    """Homogeneous medium as kernels see it."""

    sigma_t: float  # extinction, 1/unit
    sigma_s: float  # scattering, 1/unit
    phase_id: int  # PHASE_ISOTROPIC or PHASE_HENYEY_GREENSTEIN
    g: float  # HG asymmetry


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
