"""Per-ray transmittance weights for the prefiltered look-ups (warpscatter's, not in the papers): a quadrature over
one reference-weighted prefix sum.

Klehm 2014 Sec. 3.2 weights a row's prefix sums by ONE reference ray's transmittance, u_i = exp(-tau_j i), but a
texel's world length Delta_perp / sin(theta) differs between the slice's rays. A ray instead reads the same texture
at K cuts c_1 < ... < c_K (its end) at equal shares of its own weight: with A_k the stored prefix mean through c_k,
D_k the reference weight sum and E_k the ray's own (both (1 - exp(-tau (c + 1))) / tau), its visibility mean is

    sum_k A_k D_k (r_k - r_{k+1}) / E_K,   r_k = (E_k - E_{k-1}) / (D_k - D_{k-1}),   r_{K+1} = 0,

a convex combination of stored texels when the reference decays slowest (``reference_ray: least``). K = 1 is Klehm's
look-up. Derivation: docs/design/prefiltered.md; the look-ups: :func:`~.filtered_lookups.segment_lookup`.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ...runtime.device import module_options
from ..settings import MAX_SEGMENTS

module_options()

segment_columns = wp.types.vector(length=MAX_SEGMENTS, dtype=wp.int32)
segment_sums = wp.types.vector(length=MAX_SEGMENTS + 1, dtype=wp.float32)


@wp.struct
class RayWeights:
    """How a look-up weights a view ray's texels (module doc): ``segments`` K per ray (1: the reference ray's
    weights), or with ``segment_depth`` > 0 the most (:func:`segment_count`); ``optical_step`` (rows,): the
    prefilter's tau_j per column; ``tau_perp``: sigma_t Delta_perp of a ray perpendicular to the light; ``theta_hi``,
    ``theta_len``: the rectification's depth bounds (z_r -> inclination theta); ``end_offset``: texels the look-up ends
    before the ray's end (the end surface's texel is its own blocker); ``cols``: the map's columns (texels beyond are
    lit, :func:`inside_map_fraction`)."""

    segments: int
    segment_depth: float
    optical_step: wp.array(dtype=wp.float32)
    tau_perp: float
    theta_hi: float
    theta_len: float
    end_offset: float
    cols: int


@wp.struct
class ChannelRayWeights:
    """The :class:`RayWeights` of each colour channel of a coloured medium (the same texture and reference weights,
    each channel's own extinction in ``tau_perp``)."""

    r: RayWeights
    g: RayWeights
    b: RayWeights


@wp.func
def segment_count(weights: RayWeights, tau_ray: float, j0: int, j1: int, x: float) -> int:
    """Segments of a ray with optical step tau_ray ending at prefix column x in rows j0, j1: ``weights.segments``, or
    with ``segment_depth`` > 0 one plus one per segment_depth of its optical-depth mismatch with the slower row
    reference, (tau_ray - tau_ref)(x + 1), at most ``segments`` (a ray decaying like its reference needs one)."""
    if weights.segment_depth <= 0.0:
        return weights.segments
    tau_ref = wp.min(weights.optical_step[j0], weights.optical_step[j1])
    mismatch = (tau_ray - tau_ref) * (x + 1.0)
    if mismatch <= 0.0:
        return 1
    return wp.min(1 + int(mismatch / weights.segment_depth), weights.segments)


@wp.func
def weight_sum(tau: float, n: float) -> float:
    """sum of the Eq. 12 texel weights over the first n texels of a ray with optical step tau:
    (1 - exp(-tau n)) / tau, = n at tau = 0 (series below tau n = 0.01, no cancellation)."""
    y = tau * n
    if y < 0.01:
        return n * (1.0 - y * (0.5 - y * (1.0 / 6.0 - y * (1.0 / 24.0))))
    return (1.0 - wp.exp(-y)) / tau


@wp.func
def ray_optical_step(weights: RayWeights, z_r: float) -> float:
    """sigma_t Delta of the view ray of rectified depth z_r: tau_perp / sin(theta), theta = theta_hi - z_r theta_len
    (rays within 1e-4 of the light axis are capped; they end inside the ray-marched epipole region)."""
    theta = weights.theta_hi - z_r * weights.theta_len
    return weights.tau_perp / wp.max(wp.sin(theta), 1.0e-4)


@wp.func
def inside_map_fraction(weights: RayWeights, u: float, z_r: float) -> float:
    """Share of the ray's own transmittance weight inside the map for a view ray ending at column coordinate u (1 when
    it ends inside; beyond a map fitted to the casters, ``map_radius: casters``, the texels are lit)."""
    n_end = u * float(weights.cols) - weights.end_offset  # texels through the look-up's end
    n_map = float(weights.cols)
    if n_end <= n_map:
        return 1.0
    tau = ray_optical_step(weights, z_r)
    return weight_sum(tau, n_map) / weight_sum(tau, n_end)


@wp.func
def looked_up_share(weights: RayWeights, u: float, z_r: float) -> float:
    """Share of the ray's own transmittance weight its look-up reads (the ``end_offset`` texels before its end left
    out), for a view ray ending at column coordinate u inside the map; 0 when it reads none."""
    n_full = u * float(weights.cols)
    n_cut = n_full - weights.end_offset
    if n_cut <= 0.0:
        return 0.0
    tau = ray_optical_step(weights, z_r)
    return weight_sum(tau, n_cut) / weight_sum(tau, n_full)


@wp.func
def ray_end(tau: float, x: float):
    """The ray's own weight through continuous prefix column x: (E(x) = (1 - exp(-tau (x + 1))) / tau, its decay
    1 - exp(-tau (x + 1)) = tau E(x)); one exp, shared by the cuts (:func:`ray_cut`)."""
    n = x + 1.0
    y = tau * n
    if y < 0.01:
        e = n * (1.0 - y * (0.5 - y * (1.0 / 6.0 - y * (1.0 / 24.0))))
        return e, tau * e
    decay = 1.0 - wp.exp(-y)
    return decay / tau, decay


@wp.func
def ray_cut(tau: float, x: float, share: float, decay_end: float):
    """(c, E(c)): the last whole column before the ray's own weight through column x reaches ``share`` of its total
    (``decay_end`` from :func:`ray_end`), and the ray's weight sum through c. One log: exp(-tau (c + 1)) is
    (1 - share decay_end) exp(tau (n - c - 1)), a series of an argument below tau."""
    n = share * (x + 1.0)
    t_n = 1.0 - share * decay_end
    if tau * (x + 1.0) >= 1.0e-3:
        n = -wp.log(t_n) / tau
    c1 = wp.floor(n)
    y = tau * c1
    if y < 0.01:
        return int(c1) - 1, c1 * (1.0 - y * (0.5 - y * (1.0 / 6.0 - y * (1.0 / 24.0))))
    g = tau * (n - c1)
    grow = float(0.0)
    if g < 0.05:
        grow = 1.0 + g * (1.0 + g * (0.5 + g * (1.0 / 6.0 + g * (1.0 / 24.0))))
    else:
        grow = wp.exp(g)
    return int(c1) - 1, (1.0 - t_n * grow) / tau


def ray_weights(segments: int, optical_step, rect=None, sigma_t: float = 0.0, end_offset: float = 0.0,
                device=None, cols: int | None = None, segment_depth: float = 0.0) -> RayWeights:
    """Kernel-side :class:`RayWeights` (fields as there): ``optical_step`` None is average visibility; ``rect``, the
    texture's :class:`~..rectify.NonlinearRectification`, is needed for K > 1; ``sigma_t`` in 1/unit; ``cols``
    defaults to ``rect.cols`` (without either, no ray reaches past the map)."""
    if not 1 <= int(segments) <= MAX_SEGMENTS:
        raise ValueError(f"segments must be in [1, {MAX_SEGMENTS}], got {segments}")
    if not (np.isfinite(end_offset) and end_offset >= 0.0):
        raise ValueError(f"end_offset must be finite and >= 0, got {end_offset}")
    if not (np.isfinite(segment_depth) and segment_depth >= 0.0):
        raise ValueError(f"segment_depth must be finite and >= 0, got {segment_depth}")
    w = RayWeights()
    w.segments = int(segments)
    w.segment_depth = float(segment_depth)
    w.end_offset = float(end_offset)
    w.tau_perp, w.theta_hi, w.theta_len = 0.0, 0.0, 1.0
    w.cols = int(cols if cols is not None else (rect.cols if rect is not None else 2**30))
    if segments > 1 and rect is None:
        raise ValueError("segments > 1 needs the non-linear rectification of the texture")
    if rect is not None:
        w.tau_perp = float(sigma_t * rect.delta_perp)
        w.theta_hi, w.theta_len = float(rect.theta_hi), float(rect.theta_len)
    rows = 1 if optical_step is None else len(optical_step)
    tau = np.zeros(rows, np.float32) if optical_step is None else np.asarray(optical_step, np.float32)
    w.optical_step = wp.array(np.ascontiguousarray(tau), dtype=wp.float32, device=device)
    return w


__all__ = [
    "MAX_SEGMENTS",
    "ChannelRayWeights",
    "RayWeights",
    "inside_map_fraction",
    "looked_up_share",
    "ray_cut",
    "ray_end",
    "ray_optical_step",
    "ray_weights",
    "segment_columns",
    "segment_count",
    "segment_sums",
    "weight_sum",
]
