"""The per-pixel look-up of a prefiltered map as ``@wp.func`` building blocks (Klehm 2014 Listing 4, Peters 2017
D.5): the visible fraction of a view ray from a Fourier texture or a moment map, its row mip levels, the stretch a
look-up leaves out before a ray's end and the test whether that end is lit. The evaluate passes' kernels
(:mod:`.evaluate`) call them; so may a user's own kernel.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from ...runtime.device import module_options
from ...scene.lights import LightParams, light_sample
from ...shadows import moments as mm
from ..marching import Visibility, point_visibility
from ..settings import END_STRETCH_MIN_WEIGHT
from .filtered_lookups import (
    DepthBounds,
    fourier_visibility,
    mix_row_answers,
    moments_visibility,
    row_bounds,
    rows_undecided,
)
from .ray_weights import RayWeights, inside_map_fraction
from .row_mips import RowMips, level_window
from .textures import FilteredBasisArrays, FilteredMomentArrays

module_options()

#: :data:`~..settings.END_STRETCH_MIN_WEIGHT` for the kernels.
STRETCH_MIN_WEIGHT = wp.constant(END_STRETCH_MIN_WEIGHT)


@wp.func
def representation_visibility(texels: FilteredBasisArrays, weights: RayWeights, u: float, v: float, z_r: float,
                              window: wp.vec3i, beta: wp.vec4, light_direction: wp.vec3,
                              view_direction: wp.vec3) -> float:
    """The look-up's reconstruction from a Fourier texture (Klehm 2014 Listing 4) in the row ``window``; ``beta`` and
    the directions unused."""
    return fourier_visibility(texels, weights, u, v, z_r, window)


@wp.func
def representation_visibility(texels: FilteredMomentArrays, weights: RayWeights, u: float, v: float,  # noqa: F811
                              z_r: float, window: wp.vec3i, beta: wp.vec4, light_direction: wp.vec3,
                              view_direction: wp.vec3) -> float:
    """The look-up's reconstruction from a moment map (Peters 2017 D.5) with the overestimation weight
    ``beta[0] + (beta[1] - beta[0]) clamp((omega_l . omega_p - beta[3]) / (1 - beta[3]), 0, 1)``
    (:meth:`~..settings.MomentsSettings.beta_range`, ``beta[3]``: ``overestimation_rise_cos``);
    ``beta[0]`` < 0: Peters' adaptive weight of the light and view directions (Sec. 5.3.1). Within the epipole
    taper (``beta[2]`` = 1 - cos of its angle, > 0) the weight falls to 0 looking straight into the light:
    times (1 + omega_l . omega_p) / beta[2]."""
    cos_l = wp.dot(light_direction, view_direction)
    b = beta[0]
    if b < 0.0:
        b = mm.adaptive_overestimation_weight(light_direction, view_direction)
    elif beta[1] != beta[0]:
        b += (beta[1] - beta[0]) * wp.clamp((cos_l - beta[3]) / (1.0 - beta[3]), 0.0, 1.0)
    if 1.0 + cos_l < beta[2]:
        b *= (1.0 + cos_l) / beta[2]
    return moments_visibility(texels, weights, u, v, z_r, window, b)


@wp.func
def map_visibility(texels: Any, weights: RayWeights, bounds: DepthBounds, c: wp.vec3, window: wp.vec3i, beta: wp.vec4,
                   light_direction: wp.vec3, view_direction: wp.vec3, ray_end: int) -> float:
    """Visible fraction of the view ray ending at rectified c = (u, v, z_r) from a Fourier texture or a moment map
    (:func:`representation_visibility`) in the row ``window`` (:func:`~.row_mips.level_window`), texels weighted as
    ``weights`` says, those beyond the map lit; rows the ``bounds`` decide skip the reconstruction (``ray_end``:
    what is known of the ray's end, :func:`~.filtered_lookups.row_bounds`)."""
    inside = inside_map_fraction(weights, c[0], c[2])
    u = c[0]
    if inside < 1.0:
        u = 1.0 + weights.end_offset / float(weights.cols)  # the look-up through the whole map
    # a row the bounds decide keeps their exact answer, an undecided one the reconstruction, mixed by row weight
    b = row_bounds(bounds, u - weights.end_offset / float(bounds.bounds.shape[1]), c[1], c[2], window, ray_end)
    r = float(0.0)
    if rows_undecided(b):
        r = representation_visibility(texels, weights, u, c[1], c[2], window, beta, light_direction, view_direction)
    f = mix_row_answers(b, r, b[2])
    if inside < 1.0:
        return inside * f + (1.0 - inside)
    return f


@wp.func(inline=False)  # called once per channel: inlined, NVRTC took a minute
def mipped_visibility(texels: Any, weights: RayWeights, bounds: DepthBounds, mips: RowMips, level: wp.vec2,
                      c: wp.vec3, beta: wp.vec4, light_direction: wp.vec3, view_direction: wp.vec3,
                      ray_end: int) -> float:
    """:func:`map_visibility` at a pixel's mip ``level`` (:func:`~.row_mips.pixel_mip_level`: level, share of the
    next): the two levels' visibilities blended (trilinear filtering, Peters 2017 D.5; :mod:`.row_mips`)."""
    lv = int(level[0])
    f = map_visibility(texels, weights, bounds, c, level_window(mips, lv), beta, light_direction, view_direction,
                       ray_end)
    if level[1] > 0.0:
        f1 = map_visibility(texels, weights, bounds, c, level_window(mips, lv + 1), beta, light_direction,
                            view_direction, ray_end)
        f = f + level[1] * (f1 - f)
    return f


@wp.func
def left_out_start(weights: RayWeights, u: float, s: float) -> float:
    """Distance from the camera at which the look-up of a view ray ending at column coordinate u, distance s, stops:
    ``end_offset`` texels before its end (a non-linear map's columns are equal steps along a ray)."""
    return s * wp.max(1.0 - weights.end_offset / (u * float(weights.cols)), 0.0)


@wp.func
def with_left_out_stretch(f: float, share: float, v_end: float) -> float:
    """Visible fraction of a view ray whose look-up gave f over ``share`` of its own transmittance weight
    (:func:`~.ray_weights.looked_up_share`) and whose left-out end stretch (:func:`left_out_start`) has visibility
    v_end."""
    return f * share + (1.0 - share) * v_end


@wp.func
def ray_ends_lit(x: wp.vec3, n: wp.vec3, faces_away: int, light: LightParams, vis: Visibility) -> int:
    """1 where a view ray ending at x (G-buffer normal n) ends lit: on no surface, or on one facing the light
    (``faces_away`` 0: :func:`~...scene.lights.faces_away_from_light`) whose point, moved one shadow-map texel off it,
    the shadow map sees (hard, with the marcher's bias)."""
    lit = int(0)
    if faces_away == 0:
        _e, omega, dist = light_sample(light, x)
        lit = int(point_visibility(vis, x + n * vis.sm.texel_world, omega, dist) > 0.5)
    return lit


__all__ = [
    "STRETCH_MIN_WEIGHT",
    "left_out_start",
    "map_visibility",
    "mipped_visibility",
    "ray_ends_lit",
    "representation_visibility",
    "with_left_out_stretch",
]
