"""The ``prefilter`` pass (Klehm 2014 Sec. 3, Listings 1-3; Peters 2017 Sec. 5): the rectified depth's Fourier basis
or moments in per-row prefix sums (:mod:`.prefix_sums`), weighted by the transmittance along each row's reference ray
(per texel on the projective map's uneven columns, Eq. 12), in the configured storage, with row mip levels
(:mod:`.row_mips`) and per-row depth bounds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..rectify.bounds import NonlinearRectification
from ..rectify.projective import column_lengths, cross_ratio_factors
from ..rectify.reference_rays import reference_ray, reference_rays
from ..settings import PrefilteredSettings, ScatteringSettings
from .filtered_lookups import DepthBounds, depth_bounds_of
from .prefix_sums import prefilter_moments, prefilter_weighted
from .row_mips import RowMipChain, row_mip_chain
from .textures import FilteredBasis, FilteredMoments


@dataclass
class Prefiltered:
    """The ``prefilter`` pass's result: the filtered map and how rays weight it."""

    texture: FilteredBasis | FilteredMoments  # with its row mip levels stacked along its rows
    bounds: DepthBounds  # per-row prefix depth bounds, mip levels included
    chain: RowMipChain  # the row mip levels (and each row's reference optical step)
    segments: int  # per-ray look-up segments (ray_weights)
    segment_depth: float  # their depth (0: one segment)
    depth_warp: float  # the depth warp of the basis
    sigma_ref: float  # extinction of the prefix sums' weights (1/unit, weights_extinction)
    light_behind: bool  # the light travels the way the camera looks (the sun behind it)
    info: dict  # the weights' description (row_weights)


def prefilter_map(rectified, settings: ScatteringSettings, scene, device) -> Prefiltered:
    """Prefilter a frame's :class:`~.rectify.Rectified` map (module doc)."""
    p, rect, cam, medium = settings.prefiltered, rectified.rect, scene.camera, scene.medium
    cols = settings.shadow_map.size[0]
    # the sun behind the camera: the moment methods' segments are adaptive
    light_behind = bool(np.dot(scene.light.direction, cam.forward) > 0.0)
    segments = p.segments_for(rectified.nonlinear, medium.coloured, settings.method, light_behind)
    segment_depth = p.segment_depth_for(settings.method, light_behind, medium.coloured) if segments > 1 else 0.0
    depth_warp = p.depth_warp_for(settings.method, cols)
    sigma_ref = weights_extinction(medium, segments)
    tau, lengths, info = row_weights(rect, p, sigma_ref, cam, segments)
    if settings.method == "fourier":
        texture = prefilter_weighted(rectified.depth, settings.fourier.coefficients, tau, lengths, splits=p.splits,
                                     bits=settings.fourier.storage_bits, depth_warp=depth_warp, device=device)
    else:
        texture = prefilter_moments(rectified.depth, settings.num_moments, tau, lengths,
                                    storage_bits=settings.moment_storage_bits, depth_warp=depth_warp, device=device)
    bounds = depth_bounds_of(rectified.depth, p.depth_bounds, device)
    chain = row_mip_chain(texture, tau, bounds.bounds, p.mip_levels, device)
    bounds.bounds = chain.bounds
    return Prefiltered(chain.texture, bounds, chain, segments, segment_depth, depth_warp, sigma_ref, light_behind,
                       info)


def row_weights(rect, settings: PrefilteredSettings, sigma_t: float, camera=None,
                segments: int = 1) -> tuple[np.ndarray, np.ndarray | None, dict]:
    """(optical_step (rows,) float32, column_length (cols,) float64 or None, info) of the prefilter weights (Klehm
    2014 Sec. 3.2, Eq. 11-12). Non-linear map: uniform columns, tau_j = sigma_t Delta_ref. Projective: l_i = dX_i /
    dX_0 (exact, or Eq. 12's Delta d^i) and tau_j = sigma_t dX_0 sqrt(1 + s^2 + zeta_ref^2). ``camera``: for the
    ``"pixels"`` reference ray; ``segments`` picks auto's (:meth:`~..settings.PrefilteredSettings.reference_for`)."""
    transmittance = settings.weighting == "transmittance"
    reference = settings.reference_for(segments)
    if isinstance(rect, NonlinearRectification):
        tau = reference_ray(rect, reference, camera).optical_steps(sigma_t) if transmittance else None
        return tau, None, {"reference_ray": reference}
    lengths = column_lengths(rect, "exact" if settings.projective_weights == "exact" else "cross_ratio")
    info = {"reference_ray": reference, "projective_weights": settings.projective_weights}
    if settings.projective_weights == "cross_ratio":
        info["cross_ratio_d"] = [round(float(d), 6) for d in cross_ratio_factors(rect)[0]]
    tau = np.zeros(rect.rows, np.float32)
    if transmittance:
        scale = reference_rays(rect, reference, camera).length_scale
        tau = (sigma_t * lengths[0] * scale).astype(np.float32)
    return tau, lengths / lengths[0], info


def weights_extinction(medium, segments: int) -> float:
    """The extinction (1/unit) of the prefix sums' weights: a grey medium's own; a coloured medium's least channel's
    with per-ray segments (every channel then decays at least as fast: convex taps, :mod:`.ray_weights`), else the
    channels' mean."""
    if medium.coloured and segments > 1:
        return float(min(medium.sigma_t_rgb))
    return medium.extinction


__all__ = ["Prefiltered", "prefilter_map", "row_weights", "weights_extinction"]
