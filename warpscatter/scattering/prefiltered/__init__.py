"""Prefiltered single scattering on a rectified shadow map: the ``fourier`` (Klehm 2014), ``moments4`` and
``moments6`` (Peters 2017 Sec. 5) render methods. They share the rectification, the transmittance-weighted per-row
prefix sums, the per-pixel look-up and the epipole fallback; only the per-texel visibility representation differs:
M Fourier coefficients (Klehm Eq. 8) or 4 / 6 moments of the signed rectified depth with Algorithm 1 and adaptive
overestimation at evaluation (Peters Sec. 5.3-5.4).

:func:`render` runs the paper's steps as passes (stage names as in timings):

1. ``rectify`` (:mod:`.rectify`: projective, Klehm Sec. 4.2, or non-linear, Peters Sec. 5.1.1), then ``pixel_coords``
   and ``caster_culling`` (not in the papers: texels whose blockers shadow no look-up are emptied);
2. ``prefilter`` (:mod:`.prefilter`: Klehm Listings 1-3), with row mip levels and per-row depth bounds;
3. ``evaluate`` (:mod:`.evaluate`: Klehm Listing 4; building blocks in :mod:`.lookups`), sparse where it can;
4. ``epipole`` (:mod:`.epipole`: Klehm Sec. 5, Fig. 8), ray-marching what the look-up cannot answer.

A spot light (Klehm Sec. 3.2) takes the same steps on its own map (:mod:`.spot`, :mod:`.spot_lookups`). Settings:
:class:`~warpscatter.scattering.settings.ScatteringSettings`.
"""

#: public name -> the module defining it, imported on first use (a building block imports without the passes)
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
