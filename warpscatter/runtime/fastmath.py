"""Fast approximations of transcendental functions for per-pixel and per-texel kernels.

:func:`fast_atan2`: the octant reduction of atan2 to atan(a), a = min(|x|, |y|) / max(|x|, |y|) in [0, 1], and a
degree-11 odd minimax polynomial for atan on [0, 1], where an angle becomes a texture coordinate (the non-linear
rectification's azimuth and inclination). Error and speed: docs/design/csm-core.md.
"""

from __future__ import annotations

import warp as wp

from .device import module_options

module_options()

HALF_PI = wp.constant(1.5707963267948966)
PI = wp.constant(3.141592653589793)


@wp.func
def fast_atan2(y: float, x: float) -> float:
    """atan2(y, x) in (-pi, pi] to 1.9e-6 rad; 0 for x = y = 0."""
    ax = wp.abs(x)
    ay = wp.abs(y)
    a = wp.min(ax, ay) / wp.max(wp.max(ax, ay), 1.0e-30)
    s = a * a
    r = (((((-0.0117212 * s + 0.05265332) * s - 0.11643287) * s + 0.19354346) * s - 0.33262347) * s
         + 0.99997726) * a
    if ay > ax:
        r = HALF_PI - r
    if x < 0.0:
        r = PI - r
    if y < 0.0:
        r = -r
    return r


__all__ = ["fast_atan2"]
