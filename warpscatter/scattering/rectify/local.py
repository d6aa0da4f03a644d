"""Non-linear rectification of a spot light's shadow map: prefiltered single scattering for local lights (Klehm 2014
Sec. 3.2, "Local Lights" and "Angular-dependency for Sources").

The epipolar planes of a light at L are the planes through the baseline to the camera C; light view space keeps its
origin at C with z along the baseline from the light to the camera, D = |C - L|. phi = atan2(y, x) is the ROW and
theta = atan2(r, z) the DEPTH as for a directional light (:mod:`.spherical`); the COLUMN is the angle at the light
psi = atan2(r, z + D), u = (psi - psi_lo) / psi_span. A view ray keeps phi and theta and runs from psi = 0 towards
psi = theta; along a light ray theta falls away from the light, so "behind the blocker" is again "larger depth"
(D -> infinity with psi D -> r is the directional case). The columns cover the spot cone's band around the baseline,
cut to the largest psi the view reaches.

Each texel (a light ray) keeps its casters as a directional supersampled texel does (:mod:`.taps`), and the spot's
emission over its footprint, relative to its peak, becomes its FILTER in [0, 1] per channel, which weights it in the
prefix sums (Klehm's "Angular-dependency for Sources"; a coloured texture needs one map per channel). The look-ups:
:mod:`..prefiltered.spot_lookups`.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import warp as wp

from ...runtime.device import default_device, module_options
from ...runtime.parallel import launch_rows
from ...scene.lights import LightParams, light_sample
from .bounds import NonlinearRectification
from .spherical import NonlinearRectParams
from .taps import (
    MAX_RADIAL_SAMPLES,
    SparseRectifiedDepth,
    SpotTapSource,
    TranslucentLayer,
    TwoDepthTexels,
    empty_tap_range,
    keep_tap,
    kept_taps_parts,
    part_mean,
    radial_taps,
    split_translucent_taps,
    spot_light_ray,
    spot_tap,
    translucent_layer,
)

module_options()

#: Light rays per side of a texel's footprint whose mean emission is the texel's filter (the cone's edge and the
#: texture box-filtered over the texel).
SPOT_FILTER_SAMPLES = wp.constant(3)
#: The sines (or cosines) of a texel's SPOT_FILTER_SAMPLES filter angles along one axis.
spot_filter_angles = wp.types.vector(length=int(SPOT_FILTER_SAMPLES), dtype=wp.float32)
#: Far-plane samples per side for the largest angle at the light that the view reaches.
FAR_PLANE_SAMPLES = 33


def spot_rectification(camera, light, rows: int = 1024, cols: int = 1024,
                       guard_band: float = 0.1) -> NonlinearRectification:
    """The rectification of spot ``light`` for ``camera`` (module doc).

    Raises:
        ValueError: when the light sits at the camera position (no baseline: the epipolar planes are undefined).
    """
    c = np.asarray(camera.position, np.float64)
    baseline = c - np.asarray(light.position, np.float64)
    d = float(np.linalg.norm(baseline))
    scale = max(float(np.linalg.norm(c)), float(camera.far), 1.0)
    if not d > 1e-9 * scale:
        raise ValueError("the spot light sits at the camera position: its epipolar planes are undefined "
                         "(move the light or use the ray marcher, render.scattering.method)")
    base = NonlinearRectification.from_camera(camera, baseline, guard_band=guard_band, rows=rows, cols=cols)
    ez = base.to_light[2]
    beta = math.acos(float(np.clip(np.dot(light.direction, ez), -1.0, 1.0)))
    cone = math.radians(light.outer_cone_deg)  # a square spot (a point light's face): its corners
    psi_lo, psi_hi = max(0.0, beta - cone), min(math.pi, beta + cone)
    s = np.linspace(0.0, 1.0, FAR_PLANE_SAMPLES)
    a, b = np.meshgrid(s, s, indexing="ij")
    q0, q1, q2, q3 = base.far_corners  # cyclic: q0 -> q1 -> q2 -> q3
    quad = ((1 - a) * (1 - b))[..., None] * q0 + (a * (1 - b))[..., None] * q1 + (a * b)[..., None] * q2 \
        + ((1 - a) * b)[..., None] * q3
    view_hi = float(np.max(np.arctan2(np.hypot(quad[..., 0], quad[..., 1]), quad[..., 2] + d)))
    # the sampled maximum may sit slightly inside the true one: one texel of margin
    psi_hi = min(psi_hi, view_hi + (view_hi - psi_lo) / cols if view_hi > psi_lo else view_hi)
    span = max(psi_hi - psi_lo, 1e-9)
    return dataclasses.replace(base, r_max=span, view_radius=0.0, light_distance=d, psi_lo=psi_lo)


@wp.func
def spot_casters_opaque(rect: NonlinearRectParams, light: LightParams, shadow_depth: wp.array2d(dtype=wp.float32),
                        world_to_clip: wp.mat44, samples: int, i: int, phi: float, to_world: wp.mat33):
    """:func:`~.taps.split_translucent_taps` for an opaque spot map, bit-identical, with the taps kept in registers
    for the split pass (as ``radial_opaque_texel``)."""
    inv = 1.0 / float(samples)
    lo, hi, w_caster, w_empty = empty_tap_range()
    s_caster = float(0.0)
    z_kept = radial_taps()
    w_kept = radial_taps()
    for k in range(wp.static(MAX_RADIAL_SAMPLES)):
        if k < samples:
            dk, c = spot_light_ray(rect, light, world_to_clip, i, k, inv, phi, to_world)
            if c[3] <= 0.0:  # behind the spot: no light there anyway (its filter is 0)
                w_empty += inv
            for t in range(4):
                w_kept[wp.static(4 * k + t)] = -1.0
                if c[3] > 0.0:
                    z_b, w, caster, x, y = spot_tap(rect, light.position, light.direction, dk, shadow_depth, c,
                                                    wp.static(t), inv)
                    lo, hi, w_caster, w_empty, s_caster, kept = keep_tap(lo, hi, w_caster, w_empty, s_caster, z_b,
                                                                         w, caster)
                    z_kept[wp.static(4 * k + t)] = z_b
                    w_kept[wp.static(4 * k + t)] = kept
    s1, wa, s2, wb = kept_taps_parts(z_kept, w_kept, 4 * samples, lo, hi, w_caster, w_empty, s_caster)
    return w_caster, w_empty, s1, wa, s2, wb


@wp.func
def spot_emission_filter(rect: NonlinearRectParams, light: LightParams, peak: wp.vec3, i: int, j: int,
                         to_world: wp.mat33) -> wp.vec3:
    """Texel (column i, row j)'s FILTER: its mean emission over SPOT_FILTER_SAMPLES^2 light rays of its footprint
    relative to each channel's ``peak`` (0: a dark channel), clamped to [0, 1]."""
    e_sum = wp.vec3(0.0, 0.0, 0.0)
    nf = SPOT_FILTER_SAMPLES
    sin_phi = spot_filter_angles()
    cos_phi = spot_filter_angles()
    for b in range(wp.static(SPOT_FILTER_SAMPLES)):
        phi_s = rect.phi_mid + ((float(j) + (float(b) + 0.5) / float(nf)) / float(rect.rows) - 0.5) * rect.phi_span
        sin_phi[b] = wp.sin(phi_s)
        cos_phi[b] = wp.cos(phi_s)
    for a in range(wp.static(SPOT_FILTER_SAMPLES)):
        psi_s = rect.psi_lo + (float(i) + (float(a) + 0.5) / float(nf)) / float(rect.cols) * rect.r_max
        sin_psi = wp.sin(psi_s)
        cos_psi = wp.cos(psi_s)
        for b in range(wp.static(SPOT_FILTER_SAMPLES)):
            ds = to_world * wp.vec3(sin_psi * cos_phi[b], sin_psi * sin_phi[b], cos_psi)
            e, omega, dist = light_sample(light, light.position + ds / wp.length(ds))
            e_sum += e
    f = wp.vec3(0.0, 0.0, 0.0)
    for k in range(3):
        if peak[k] > 0.0:
            f[k] = wp.clamp(e_sum[k] / (float(nf * nf) * peak[k]), 0.0, 1.0)
    return f


@wp.func
def spot_texel_depths(w_caster: float, w_empty: float, s1: float, wa: float, s2: float, wb: float):
    """:func:`~.nonlinear.radial_texel_depths` for a spot texel, whose taps hold rectified depths already."""
    z1 = float(1.0)
    z2 = float(1.0)
    w2 = float(0.0)
    if w_caster > 0.0:
        if wa > 0.0:
            z1 = part_mean(s1, wa)
        if wb > 0.0:
            z2 = part_mean(s2, wb)
            w2 = wb / (wa + wb)
        else:
            w2 = w_empty / (w_caster + w_empty)
            if w2 <= 0.0:
                z2 = z1
    return z1, z2, w2


@wp.kernel
def resample_spot_kernel(
    rect: NonlinearRectParams,
    light: LightParams,
    shadow_depth: wp.array2d(dtype=wp.float32),  # (H, W) the spot map: distance along its axis, +inf empty
    world_to_clip: wp.mat44,  # the spot's perspective world -> clip
    peak: wp.vec3,  # each channel's largest emission at unit distance (0: a dark channel)
    samples: int,  # light rays per texel along psi for its casters (1..MAX_RADIAL_SAMPLES)
    out: TwoDepthTexels,
    out_filter: wp.array2d(dtype=wp.vec3),  # (rows, cols) the emission relative to its peak, per channel
    offset: int,
):
    j, i = wp.tid()
    j += offset
    to_world = wp.transpose(rect.to_light)
    phi = rect.phi_mid + ((float(j) + 0.5) / float(rect.rows) - 0.5) * rect.phi_span
    out_filter[j, i] = spot_emission_filter(rect, light, peak, i, j, to_world)
    w_caster, w_empty, s1, wa, s2, wb = spot_casters_opaque(rect, light, shadow_depth, world_to_clip, samples, i, phi,
                                                            to_world)
    z1, z2, w2 = spot_texel_depths(w_caster, w_empty, s1, wa, s2, wb)
    out.z1[j, i] = z1
    out.z2[j, i] = z2
    out.w2[j, i] = w2


@wp.kernel
def resample_spot_translucent_kernel(
    rect: NonlinearRectParams,
    light: LightParams,
    shadow_depth: wp.array2d(dtype=wp.float32),
    layer: TranslucentLayer,
    world_to_clip: wp.mat44,
    peak: wp.vec3,
    samples: int,
    out: TwoDepthTexels,
    out_filter: wp.array2d(dtype=wp.vec3),
    offset: int,
):
    # resample_spot_kernel for a spot map with translucent casters: two parts per tap (split_translucent_taps)
    j, i = wp.tid()
    j += offset
    to_world = wp.transpose(rect.to_light)
    src = SpotTapSource()
    src.rect = rect
    src.light = light
    src.depth = shadow_depth
    src.layer = layer
    src.world_to_clip = world_to_clip
    src.phi = rect.phi_mid + ((float(j) + 0.5) / float(rect.rows) - 0.5) * rect.phi_span
    src.to_world = to_world
    out_filter[j, i] = spot_emission_filter(rect, light, peak, i, j, to_world)
    w_caster, w_empty, s1, wa, s2, wb = split_translucent_taps(src, samples, i)
    z1, z2, w2 = spot_texel_depths(w_caster, w_empty, s1, wa, s2, wb)
    out.z1[j, i] = z1
    out.z2[j, i] = z2
    out.w2[j, i] = w2


def emission_peaks(light) -> np.ndarray:
    """Each colour channel's largest emission at unit distance (W/sr): the intensity times the texture's largest
    texel of that channel."""
    intensity = np.asarray(light.intensity, np.float64)
    if light.texture is None:
        return intensity
    return intensity * np.asarray(light.texture, np.float64)[..., :3].reshape(-1, 3).max(axis=0)


def coloured_emission(light) -> bool:
    """True when the spot's texture has colour (its channels differ): one filtered map per channel."""
    if light.texture is None:
        return False
    tex = np.asarray(light.texture, np.float64)[..., :3]
    return not bool(np.allclose(tex, tex[..., :1], rtol=0.0, atol=1e-6))


def resample_spot_shadow_map(rect: NonlinearRectification, shadow_map, light, lparams: LightParams, device=None):
    """(:class:`~.taps.SparseRectifiedDepth`, (rows, cols, 3) numpy filter in [0, 1]) of a spot ``light`` (its
    ``lparams`` on ``device``) and its perspective, linear-depth ``shadow_map`` in :func:`spot_rectification`'s
    ``rect`` (module doc)."""
    device = default_device(device)
    peak = emission_peaks(light).astype(np.float32)
    sm = shadow_map.device_depth(device)
    shape = (rect.rows, rect.cols)
    result = SparseRectifiedDepth.empty(shape, device)
    emission = wp.empty(shape, dtype=wp.vec3, device=device)
    m = wp.mat44(*np.asarray(shadow_map.view_projection, np.float64).astype(np.float32).ravel())
    # one light ray per spot-map texel the rectified texel spans along psi (the spot map's texel angle at its axis)
    texel_angle = 2.0 * math.tan(math.radians(light.cone_deg)) / shadow_map.depth.shape[1]
    samples = int(np.clip(math.ceil(rect.r_max / rect.cols / texel_angle - 1e-6), 1, MAX_RADIAL_SAMPLES))
    tail = [m, wp.vec3(*peak), samples, result.texels(), emission]
    if shadow_map.translucent:
        uploaded = shadow_map.device_layers(sm, device)
        layer = translucent_layer(uploaded.opaque, uploaded.transmittance, sm.shape, device)
        launch_rows(resample_spot_translucent_kernel, shape, [rect.params(), lparams, sm, layer, *tail], device=device)
    else:
        launch_rows(resample_spot_kernel, shape, [rect.params(), lparams, sm, *tail], device=device)
    return result, emission.numpy()


#: Rows on each side whose largest inclination a row's reference ray also covers (a look-up blends two rows).
REFERENCE_ROW_REACH = 2


def spot_texel_weights(rect: NonlinearRectification, sigma_t: float, medium=None) -> np.ndarray:
    """(rows, cols) prefilter weights of a spot light's map: dpsi exp(-sigma_t t_ref(psi)), t_ref = D sin(psi) /
    sin(theta_ref - psi) (0 for psi >= theta_ref), along the reference ray of largest inclination theta_ref of the row
    and its REFERENCE_ROW_REACH neighbours (every other ray decays faster, as ``least``), times its phase function
    f(-cos(theta_ref - psi)) when ``medium`` is given."""
    if not (np.isfinite(sigma_t) and sigma_t >= 0.0):
        raise ValueError(f"sigma_t must be finite and >= 0, got {sigma_t}")
    _, theta_hi = rect.slice_inclination_range(rect.row_azimuths())
    reach = REFERENCE_ROW_REACH
    padded = np.pad(theta_hi, reach, mode="wrap" if rect.full_circle else "edge")
    theta_ref = np.max(np.lib.stride_tricks.sliding_window_view(padded, 2 * reach + 1), axis=1)
    theta_ref = np.minimum(theta_ref + 0.5 * rect.guard_band * (rect.theta_max - rect.theta_min), math.pi)
    dpsi = rect.r_max / rect.cols
    psi = rect.psi_lo + (np.arange(rect.cols) + 0.5) * dpsi
    gap = theta_ref[:, None] - psi[None, :]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t = rect.light_distance * np.sin(psi)[None, :] / np.sin(gap)
        w = np.where(gap > 1e-9, dpsi * np.exp(-sigma_t * np.where(gap > 1e-9, t, 0.0)), 0.0)
    if medium is not None:
        w = w * medium.phase_value(-np.cos(gap))
    return w


__all__ = ["coloured_emission", "emission_peaks", "resample_spot_kernel", "resample_spot_shadow_map",
           "resample_spot_translucent_kernel",
           "spot_rectification", "spot_texel_weights"]
