"""Non-linear rectification of a directional light (Peters 2017 Sec. 5.1.1, 5.2, App. A).

Transitional (issue #51): the code moved to :mod:`warpscatter.scattering.rectify`; this module re-exports the names
its importers use and goes away once they import from the package.
"""

from __future__ import annotations

from .rectify.bounds import (
    TWO_PI,
    NonlinearRectification,
    caster_radius,
    direction_in_frustum,
)
from .rectify.nonlinear import (
    EMPTY_DEPTH_TOLERANCE,
    radial_samples_for,
    radial_span,
    resample_footprint_texels,
    resample_kernel,
    resample_moment_shadow_map,
    resample_moments_kernel,
    resample_radial_kernel,
    resample_shadow_map,
    resample_translucent_kernel,
    sentinel_gap_depth,
)
from .rectify.reference_rays import (
    PIXEL_MEDIAN_SHARE,
    REFERENCE_METHODS,
    ReferenceRays,
    check_reference_method,
    median_per_row,
    reference_ray,
)
from .rectify.spherical import (
    NonlinearRectParams,
    light_ray_point,
    rectified_blocker_depth,
    rectified_ray_depth,
    rectified_to_world,
    texel_light_ray,
    world_to_rectified,
)
from .rectify.taps import (
    MAX_RADIAL_SAMPLES,
    RADIAL_TAPS,
    SparseRectifiedDepth,
    TranslucentLayer,
    bilinear_footprint,
    bilinear_tap,
    empty_tap_range,
    footprint_tap,
    keep_tap,
    kept_taps_parts,
    part_mean,
    radial_taps,
    split_point,
    tap_caster,
    tap_part,
    tap_parts,
    tap_range,
    tap_split,
)

__all__ = [
    "EMPTY_DEPTH_TOLERANCE", "MAX_RADIAL_SAMPLES", "NonlinearRectParams", "NonlinearRectification",
    "PIXEL_MEDIAN_SHARE", "RADIAL_TAPS", "REFERENCE_METHODS", "ReferenceRays", "SparseRectifiedDepth", "TWO_PI",
    "TranslucentLayer", "bilinear_footprint", "bilinear_tap", "caster_radius", "check_reference_method",
    "direction_in_frustum", "empty_tap_range", "footprint_tap", "keep_tap", "kept_taps_parts", "light_ray_point",
    "median_per_row", "part_mean", "radial_samples_for", "radial_span", "radial_taps", "rectified_blocker_depth",
    "rectified_ray_depth", "rectified_to_world", "reference_ray", "resample_footprint_texels", "resample_kernel",
    "resample_moment_shadow_map", "resample_moments_kernel", "resample_radial_kernel", "resample_shadow_map",
    "resample_translucent_kernel", "sentinel_gap_depth", "split_point", "tap_caster", "tap_part", "tap_parts",
    "tap_range", "tap_split", "texel_light_ray", "world_to_rectified",
]
