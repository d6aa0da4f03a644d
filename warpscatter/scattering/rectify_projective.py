"""Projective rectification of a directional light (Klehm 2014 Sec. 4.2, Eq. 12).

Transitional (issue #51): the code moved to :mod:`warpscatter.scattering.rectify`; this module re-exports the names
its importers use and goes away once they import from the package.
"""

from __future__ import annotations

from .rectify.projective import (
    ProjectiveRectification,
    ProjectiveRectParams,
    RectificationChoice,
    choose_rectification,
    column_lengths,
    cross_ratio_factors,
    epipole_distance,
    logger,
    projection_matrix,
    rasterize_rectified,
    rectified_ray_depth,
    rectified_to_world,
    region_near_far,
    world_to_rectified,
)
from .rectify.reference_rays import (
    ProjectiveReferenceRays,
    reference_rays,
)

__all__ = [
    "ProjectiveRectParams", "ProjectiveRectification", "ProjectiveReferenceRays", "RectificationChoice",
    "choose_rectification", "column_lengths", "cross_ratio_factors", "epipole_distance", "logger",
    "projection_matrix", "rasterize_rectified", "rectified_ray_depth", "rectified_to_world", "reference_rays",
    "region_near_far", "world_to_rectified",
]
