"""Per-ray transmittance weights for the prefiltered look-ups: a quadrature over one reference-weighted prefix sum.

Klehm 2014 Sec. 3.2 weights the prefix sums of a row (epipolar slice) by the transmittance of ONE reference ray,
u_i = exp(-tau_j i) with tau_j = sigma_t Delta_ref, because a texel's world length Delta = Delta_perp / sin(theta)
differs between the slice's view rays. Every other ray then weights its texels with the wrong decay. Near the epipole
(sin(theta) -> 0) and in optically thick views the error dominates the method's (with exact hard visibility on the
rectified map, several times the error of each ray's own weights: docs/benchmarks.md, "Per-ray weights").

warpscatter's correction (not in the papers) reads the SAME texture a few more times. Let A(c) be the stored
normalised prefix mean through column c and D(c) = sum_{i<=c} w_i its reference weight sum (analytic:
(1 - exp(-tau_j (c + 1))) / tau_j for the uniform columns of the non-linear rectification). The ray's own
weight sum E(c) is the same expression with its own tau = sigma_t Delta_perp / sin(theta). Cut the ray at
columns c_1 < ... < c_K = (its end) into K segments and assume the visibility mean inside a segment is the
reference-weighted one, a_k = (D_k A_k - D_{k-1} A_{k-1}) / (D_k - D_{k-1}); the ray's mean is then

    sum_k a_k (E_k - E_{k-1}) / E_K = sum_k A_k D_k (r_k - r_{k+1}) / E_K,   r_k = (E_k - E_{k-1}) / (D_k - D_{k-1}),

with r_{K+1} = 0 (summation by parts). The tap weights sum to one, and when the reference has the slice's least
optical step (``reference_ray: least``, the ray closest to the light-perpendicular) every ray decays at least as
fast, r_k falls with k and the weights are a CONVEX combination of stored texels: filtered Fourier vectors and
moment vectors stay valid, and no cancellation amplifies 8- or 10-bit quantisation. The cuts split the ray's own
weight into K equal shares (where its transmittance changes, not where the columns are). One segment is
Klehm's look-up exactly.

Kernel side: :class:`RayWeights` (per frame) and the weight sums and cuts below; the look-ups
(:func:`~.filtered_lookups.add_segment_row_taps`) add the K + 1 taps of each of the two bilinear rows and
reconstruct once.
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
    """How a look-up weights a view ray's texels (see the module doc).

    segments: K segments per ray (1: the reference ray's weights, Klehm 2014), or with segment_depth > 0 the most a ray
    uses: it takes one more segment per segment_depth of optical-depth mismatch with its row's reference
    (:func:`segment_count`); optical_step: (rows,) the prefilter's
    tau_j per column; tau_perp: sigma_t Delta_perp, the optical step of a ray perpendicular to the light;
    theta_hi, theta_len: the non-linear rectification's depth bounds (z_r -> the ray's inclination theta);
    end_offset: texels the look-up ends before the ray's end point (the texel of the surface it ends on is its own
    blocker: read half in, it shadows or lights the ray's last texel by chance); cols: the map's columns (a ray
    reaching past them, u > 1, has its texels beyond the map counted as lit: :func:`inside_map_fraction`).
    """

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
    """Segments of a ray with optical step tau_ray whose look-up ends at prefix column x in rows j0, j1:
    ``weights.segments``, or with ``segment_depth`` > 0 one plus one per segment_depth of the optical depth by which
    the ray's decay over its texels exceeds the slower-decaying row reference's, (tau_ray - tau_ref)(x + 1), at most
    ``segments``. Inside a segment the ray's weight per reference weight varies by about that depth; a ray decaying
    like its reference is exact with one."""
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
    """Share of the ray's own transmittance weight that lies inside the map, for a view ray ending at column
    coordinate u (1 when it ends inside). A non-linear map fitted to the casters (``map_radius: casters``) ends
    where the farthest caster is; a ray reaching beyond has only lit texels there."""
    n_end = u * float(weights.cols) - weights.end_offset  # texels through the look-up's end
    n_map = float(weights.cols)
    if n_end <= n_map:
        return 1.0
    tau = ray_optical_step(weights, z_r)
    return weight_sum(tau, n_map) / weight_sum(tau, n_end)


@wp.func
def looked_up_share(weights: RayWeights, u: float, z_r: float) -> float:
    """Share of the ray's own transmittance weight that its look-up reads, for a view ray ending at column coordinate
    u inside the map: its texels through u cols - end_offset of those through u cols (the end_offset texels before its
    end point are left out); 0 when the look-up reads none."""
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
    """The cut where the ray's own weight through continuous column x reaches ``share`` of its total (``decay_end``
    from :func:`ray_end`): (c, E(c)), the last whole column c before it (prefix through c) and the ray's weight sum
    through c. One log; exp(-tau (c + 1)) comes from the exact share position's exp(-tau n) = 1 - share decay_end
    times exp(tau (n - c - 1)), a series of an argument below tau."""
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
    """Kernel-side :class:`RayWeights`.

    Args:
        segments: K >= 1 (K > 1 needs ``rect``, a non-linear rectification).
        optical_step: (rows,) the prefilter's tau_j (or None: average visibility, tau_j = 0).
        rect: the :class:`~..rectify.NonlinearRectification` of the texture (K > 1, and for the lit texels
            beyond a map fitted to the casters), or None.
        sigma_t: extinction (1/unit).
        end_offset: texels the look-up ends before the ray's end point (>= 0).
        device: Warp device.
        cols: the map's columns (default ``rect.cols``; without either, no ray reaches past the map).
        segment_depth: > 0: ``segments`` is the most a ray uses, one per this much optical-depth mismatch with its
            row's reference (:func:`segment_count`); 0: every ray uses ``segments``.
    """
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
