"""Non-linear rectification of a spot light's shadow map (Klehm 2014 Sec. 3.2, local lights).

Transitional (issue #51): the code moved to :mod:`warpscatter.scattering.rectify`; this module re-exports the names
its importers use and goes away once they import from the package.
"""

from __future__ import annotations

from .rectify.local import (
    FAR_PLANE_SAMPLES,
    REFERENCE_ROW_REACH,
    SPOT_FILTER_SAMPLES,
    coloured_emission,
    emission_peaks,
    resample_spot_kernel,
    resample_spot_shadow_map,
    resample_spot_translucent_kernel,
    spot_rectification,
    spot_texel_weights,
)

__all__ = [
    "FAR_PLANE_SAMPLES", "REFERENCE_ROW_REACH", "SPOT_FILTER_SAMPLES", "coloured_emission", "emission_peaks",
    "resample_spot_kernel", "resample_spot_shadow_map", "resample_spot_translucent_kernel", "spot_rectification",
    "spot_texel_weights",
]
