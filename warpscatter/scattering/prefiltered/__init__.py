"""Prefiltered single scattering on a rectified shadow map: the ``fourier`` (Klehm 2014), ``moments4`` and
``moments6`` (Peters 2017 Sec. 5) render methods. They share the rectification, the transmittance-weighted per-row
prefix sums, the per-pixel look-up and the epipole fallback; only the per-texel visibility representation differs:
M Fourier coefficients (Klehm Eq. 8) or 4 / 6 moments of the signed rectified depth with Algorithm 1 and adaptive
overestimation at evaluation (Peters Sec. 5.3-5.4).

:func:`render` runs the paper's steps as passes (stage names as they appear in timings):

1. ``rectify`` (:mod:`.rectify`): the light's view in rectified coordinates, projective (Klehm Sec. 4.2) or
   non-linear (Peters Sec. 5.1.1, App. A), chosen per frame; then ``pixel_coords`` where a step needs every pixel's
   look-up coordinates, and ``caster_culling`` (not in the papers, :mod:`..rectify.caster_culling`): every texel whose
   blocker shadows none of the pixels' look-ups is emptied;
2. ``prefilter`` (:mod:`.prefilter`): the Fourier basis or the moments of the rectified depth in per-row prefix sums,
   weighted by the transmittance along each row's reference ray (Klehm Listings 1-3), with row mip levels
   (:mod:`.row_mips`) and per-row depth bounds;
3. ``evaluate`` (:mod:`.evaluate`): per pixel one filtered look-up and one reconstruction (Klehm Listing 4, the
   ``@wp.func`` building blocks in :mod:`.lookups`), on a grid and the pixels it cannot interpolate
   (:mod:`..sparse_evaluation`);
4. ``epipole`` (:mod:`.epipole`): the pixels around the light's epipole, and rays whose whole look-up lies in their
   end surface's own zone, ray-marched with shadow-map visibility (Klehm Sec. 5, Fig. 8).

A spot light (Klehm Sec. 3.2, local lights) takes the same steps on its own map (:mod:`.spot`,
:mod:`..rectify`, :mod:`.spot_lookups`). Settings:
:class:`~warpscatter.scattering.settings.ScatteringSettings` (``render.scattering.prefiltered``, ``fourier``,
``moments``; keys, defaults and ranges documented there and in the README's config reference).
"""

#: public name -> the pass or building block that defines it; imported on first use, so that a building block
#: (``prefix_sums``, ``filtered_lookups``, ...) imports without the passes that import it
_NAMES = {
    "EvaluateVariant": "evaluate",
    "Evaluation": "evaluate",
    "Prefiltered": "prefilter",
    "Rectified": "rectify",
    "add_debug_images": "debug",
    "coords_of_every_pixel": "evaluate",
    "evaluate_prefiltered_kernel": "evaluate",
    "evaluate_spot_kernel": "spot",
    "left_out_start": "lookups",
    "lit_ray_ends": "evaluate",
    "lit_ray_ends_kernel": "evaluate",
    "map_depth": "rectify",
    "map_visibility": "lookups",
    "mipped_visibility": "lookups",
    "pixel_coords": "evaluate",
    "pixel_coords_kernel": "evaluate",
    "pixel_phase_kernel": "evaluate",
    "prefilter_map": "prefilter",
    "ray_ends_lit": "lookups",
    "rectify_map": "rectify",
    "render": "method",
    "render_spot": "spot",
    "representation_visibility": "lookups",
    "resample_filtered": "rectify",
    "row_weights": "prefilter",
    "weights_extinction": "prefilter",
    "with_left_out_stretch": "lookups",
}


def __getattr__(name: str):
    if name in _NAMES:
        import importlib

        return getattr(importlib.import_module(f"{__name__}.{_NAMES[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = sorted(_NAMES)
