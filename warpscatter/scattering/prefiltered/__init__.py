"""Prefiltered single scattering on a rectified shadow map: the ``fourier`` (Klehm 2014), ``moments4`` and
``moments6`` (Peters 2017 Sec. 5) render methods. They share the rectification, the transmittance-weighted per-row
prefix sums, the per-pixel look-up and the epipole fallback; only the per-texel visibility representation differs:
M Fourier coefficients (Klehm Eq. 8) or 4 / 6 moments of the signed rectified depth with Algorithm 1 and adaptive
overestimation at evaluation (Peters Sec. 5.3-5.4).

:func:`render` runs the paper's steps as passes (stage names as they appear in timings):

1. ``rectify`` (:mod:`.rectify`): the light's view in rectified coordinates, projective (Klehm Sec. 4.2) or
   non-linear (Peters Sec. 5.1.1, App. A), chosen per frame; then ``pixel_coords`` where a step needs every pixel's
   look-up coordinates, and ``caster_culling`` (not in the papers, :mod:`..caster_culling`): every texel whose blocker
   shadows none of the pixels' look-ups is emptied;
2. ``prefilter`` (:mod:`.prefilter`): the Fourier basis or the moments of the rectified depth in per-row prefix sums,
   weighted by the transmittance along each row's reference ray (Klehm Listings 1-3), with row mip levels
   (:mod:`..row_mips`) and per-row depth bounds;
3. ``evaluate`` (:mod:`.evaluate`): per pixel one filtered look-up and one reconstruction (Klehm Listing 4, the
   ``@wp.func`` building blocks in :mod:`.lookups`), on a grid and the pixels it cannot interpolate
   (:mod:`..sparse_evaluation`);
4. ``epipole`` (:mod:`.epipole`): the pixels around the light's epipole, and rays whose whole look-up lies in their
   end surface's own zone, ray-marched with shadow-map visibility (Klehm Sec. 5, Fig. 8).

A spot light (Klehm Sec. 3.2, local lights) takes the same steps on its own map (:mod:`.spot`,
:mod:`..rectify_local`, :mod:`..prefiltered_spot`). Settings:
:class:`~warpscatter.scattering.settings.ScatteringSettings` (``render.scattering.prefiltered``, ``fourier``,
``moments``; keys, defaults and ranges documented there and in the README's config reference).
"""

from .debug import add_debug_images
from .evaluate import (
    EvaluateVariant,
    Evaluation,
    coords_of_every_pixel,
    evaluate_prefiltered_kernel,
    lit_ray_ends,
    lit_ray_ends_kernel,
    pixel_coords,
    pixel_coords_kernel,
    pixel_phase_kernel,
)
from .lookups import (
    left_out_start,
    map_visibility,
    mipped_visibility,
    ray_ends_lit,
    representation_visibility,
    with_left_out_stretch,
)
from .method import render
from .prefilter import Prefiltered, prefilter_map, row_weights, weights_extinction
from .rectify import Rectified, map_depth, rectify_map, resample_filtered
from .spot import evaluate_spot_kernel, render_spot

__all__ = [
    "EvaluateVariant",
    "Evaluation",
    "Prefiltered",
    "Rectified",
    "add_debug_images",
    "coords_of_every_pixel",
    "evaluate_prefiltered_kernel",
    "evaluate_spot_kernel",
    "left_out_start",
    "lit_ray_ends",
    "lit_ray_ends_kernel",
    "map_depth",
    "map_visibility",
    "mipped_visibility",
    "pixel_coords",
    "pixel_coords_kernel",
    "pixel_phase_kernel",
    "prefilter_map",
    "ray_ends_lit",
    "rectify_map",
    "render",
    "render_spot",
    "representation_visibility",
    "resample_filtered",
    "row_weights",
    "weights_extinction",
    "with_left_out_stretch",
]
