"""Either rectification of the light's shadow map as kernels see it, and the per-frame choice between them.

Klehm's projective rectification (Sec. 4.2, :mod:`.projective`) or Peters' non-linear one (Sec. 5.1.1,
:mod:`.spherical`): :func:`build_rectification` picks one per frame (``rectification: auto``: non-linear whenever
look-ups weight each ray by its own transmittance or an epipole is (nearly) in view); :class:`RectificationParams` and
:func:`rectified_coords` give kernels one code path for both.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ...runtime.device import module_options
from ..settings import PrefilteredSettings
from . import projective, spherical
from .bounds import NonlinearRectification, caster_radius
from .projective import ProjectiveRectification, ProjectiveRectParams, choose_rectification
from .spherical import NonlinearRectParams

module_options()

#: ``RectificationParams.kind``.
RECT_NONLINEAR = wp.constant(0)
RECT_PROJECTIVE = wp.constant(1)


@wp.struct
class RectificationParams:
    """Either rectification as kernels see it; ``kind`` selects RECT_NONLINEAR or RECT_PROJECTIVE."""

    kind: int
    nonlinear: NonlinearRectParams
    projective: ProjectiveRectParams


@wp.func
def rectified_coords(rect: RectificationParams, x: wp.vec3) -> wp.vec3:
    """Rectified (u, v, depth) of world point x: u along the view ray from the camera, v = row, depth in [0, 1]
    growing along the light (the convention of both)."""
    if rect.kind == RECT_PROJECTIVE:
        return projective.world_to_rectified(rect.projective, x)
    return spherical.world_to_rectified(rect.nonlinear, x)


def wrap_rows(rect) -> bool:
    """True when the rectified rows wrap around (non-linear rectification over the full azimuth circle)."""
    return isinstance(rect, NonlinearRectification) and bool(rect.full_circle)


def rectification_params(rect) -> RectificationParams:
    """Kernel-side :class:`RectificationParams` of a NonlinearRectification or ProjectiveRectification."""
    p = RectificationParams()
    if isinstance(rect, ProjectiveRectification):
        p.kind = RECT_PROJECTIVE
        p.projective = rect.params()
        p.nonlinear = NonlinearRectParams()
    elif isinstance(rect, NonlinearRectification):
        p.kind = RECT_NONLINEAR
        p.nonlinear = rect.params()
        p.projective = ProjectiveRectParams()
    else:
        raise ValueError(f"rect must be a NonlinearRectification or ProjectiveRectification, got {type(rect).__name__}")
    return p


def build_rectification(scene, settings: PrefilteredSettings, rows: int, cols: int):
    """(rect, :class:`~.projective.RectificationChoice`) for ``scene``'s camera and directional light: a
    :class:`~.bounds.NonlinearRectification` or :class:`~.projective.ProjectiveRectification`."""
    cam, light_dir = scene.camera, scene.light.direction
    choice = choose_rectification(cam, light_dir, settings.rectification, settings.epipole_margin,
                                  weights_per_ray=settings.weights_per_ray)
    if choice.kind == "projective" and settings.rectification == "auto" and scene.medium.coloured:
        choice = projective.RectificationChoice(
            kind="nonlinear", reason="coloured medium: each channel's own ray weights need the non-linear map's "
                                     "uniform columns", epipole_distance=choice.epipole_distance)
    if choice.kind == "projective":
        try:
            rect = ProjectiveRectification.from_camera(cam, light_dir, guard_band=settings.guard_band, rows=rows,
                                                       cols=cols, regions=settings.regions)
            return rect, choice
        except ValueError as exc:  # numerically degenerate, the epipole barely outside the image
            choice = projective.RectificationChoice(
                kind="nonlinear", reason=f"{choice.reason}; projective construction failed ({exc}): non-linear used",
                epipole_distance=choice.epipole_distance)
            projective.logger.warning("fourier rectification: %s", choice.reason)
    radius = None
    if settings.map_radius == "casters":
        casters = scene.casters()
        radius = caster_radius(casters.vertices[np.unique(casters.triangles)] if len(casters.triangles) else [], cam,
                               light_dir)
    rect = NonlinearRectification.from_camera(cam, light_dir, guard_band=settings.guard_band, rows=rows, cols=cols,
                                              radius=radius)
    return rect, choice


__all__ = ["RECT_NONLINEAR", "RECT_PROJECTIVE", "RectificationParams", "build_rectification", "rectification_params",
           "rectified_coords", "wrap_rows"]
