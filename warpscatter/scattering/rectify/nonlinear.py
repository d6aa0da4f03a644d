"""Resampling a directional light's shadow map into the non-linear rectification (Peters 2017 Sec. 5.1.1, 5.2).

Each rectified texel (:mod:`.spherical`) is a light ray; its point closest to the camera is projected into the light's
orthographic shadow map, the stored caster is placed on the same light ray and its inclination converted to rectified
depth (Klehm 2014 Sec. 4.1: casters in front of the frustum clamp to 0, behind it to 1; empty texels and light rays off
the map give 1). The map is read nearest (:func:`resample_kernel`), supersampled (:func:`resample_radial_kernel`,
:mod:`.taps`) or, filtering during resampling (Peters 2017 Sec. 5.2, D.5), as a filtered 4-moment map whose first three
moments become two depths by Algorithm 2 (:func:`resample_moment_shadow_map`). With translucent casters every texel is
the two-depth distribution (1 - T) delta(nearest caster) + T delta(nearest opaque caster)
(:mod:`warpscatter.shadows.translucency`); two-depth results are :class:`~.taps.SparseRectifiedDepth`.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ...runtime.device import default_device, module_options
from ...runtime.parallel import launch_rows
from ...shadows import moments as mm
from ...shadows.msm import MomentShadowMap, MomentShadowParams, sample_bilinear4
from ...shadows.shadow_map import shadow_coords
from .bounds import NonlinearRectification
from .spherical import NonlinearRectParams, light_ray_point, rectified_blocker_depth, texel_light_ray
from .taps import (
    MAX_RADIAL_SAMPLES,
    OrthoShadowMap,
    RadialTapSource,
    SparseRectifiedDepth,
    TranslucentLayer,
    TwoDepthTexels,
    bilinear_footprint,
    empty_tap_range,
    footprint_tap,
    keep_tap,
    kept_taps_parts,
    map_array,
    nearest_map_texel,
    part_mean,
    radial_taps,
    split_translucent_taps,
    tap_caster,
    translucent_layer,
)

module_options()


#: Signed moment-map depths at or above 1 - EMPTY_DEPTH_TOLERANCE are the cleared far plane (no caster, Sec. 3.2).
EMPTY_DEPTH_TOLERANCE = wp.constant(1.0e-3)


@wp.func
def sentinel_gap_depth(z: float, d: float, caster_limit: float, d_limit: float) -> float:
    """Light-space depth of an Algorithm-2 depth z (linear d): d below the farthest caster (signed ``caster_limit``,
    linear ``d_limit``); beyond it, in the gap to the cleared far plane, the distance past the limit is stretched by
    1 / (1 - s), s the position in the gap, reaching infinity (no blocker) at 1 - EMPTY_DEPTH_TOLERANCE. No caster lies
    in the gap: a depth there is the empty +1 pulled down by a mixture of more than two depths, and read as a blocker
    at the far plane it drew a seam along an epipolar line."""
    z_empty = 1.0 - EMPTY_DEPTH_TOLERANCE
    if z <= caster_limit:
        return d
    keep = wp.max((z_empty - z) / wp.max(z_empty - caster_limit, 1.0e-30), 1.0e-30)  # 1 - s
    return d_limit + (d - d_limit) / keep


@wp.func
def stored_blocker_depth(
    rect: NonlinearRectParams,
    shadow_depth: wp.array2d(dtype=wp.float32),
    c: wp.vec4,
    p0_depth: float,
    depth_per_unit: float,
    empty_depth: float,
    u: float,
) -> float:
    """Rectified blocker depth of the light ray of column coordinate u through the point p0 at clip coordinates c
    (w = 1) and stored depth ``p0_depth``: the nearest texel's caster on that light ray (1: none, or off the map)."""
    inside, x, y = nearest_map_texel(shadow_depth, c)
    result = float(1.0)
    if inside:
        stored = shadow_depth[y, x]
        if wp.isfinite(stored) and stored < empty_depth:
            z_b = (stored - p0_depth) / depth_per_unit
            result = rectified_blocker_depth(rect, u, z_b)
    return result


@wp.func
def stored_transmittance(transmittance: wp.array2d(dtype=wp.float32), c: wp.vec4) -> float:
    """Transmittance of the translucent casters in the nearest shadow-map texel of clip coordinates c (the texel of
    :func:`stored_blocker_depth`; 1 off the map)."""
    inside, x, y = nearest_map_texel(transmittance, c)
    if inside:
        return transmittance[y, x]
    return 1.0


@wp.kernel
def resample_kernel(rect: NonlinearRectParams, sm: OrthoShadowMap, out: wp.array2d(dtype=wp.float32), offset: int):
    # nearest look-up: out (rows, cols) = the rectified blocker depth in [0, 1] of each texel's light ray
    j, i = wp.tid()
    j += offset
    u, p0 = texel_light_ray(rect, i, j)
    p0h = wp.vec4(p0[0], p0[1], p0[2], 1.0)
    out[j, i] = stored_blocker_depth(rect, sm.depth, sm.world_to_clip * p0h, wp.dot(sm.depth_row, p0h),
                                     sm.depth_per_unit, sm.empty_depth, u)


@wp.kernel
def resample_translucent_kernel(rect: NonlinearRectParams, sm: OrthoShadowMap, layer: TranslucentLayer,
                                out: TwoDepthTexels, offset: int):
    # resample_kernel for both depths: z1 the nearest caster, z2 the nearest opaque one, w2 the light passed to it
    j, i = wp.tid()
    j += offset
    u, p0 = texel_light_ray(rect, i, j)
    p0h = wp.vec4(p0[0], p0[1], p0[2], 1.0)
    c = sm.world_to_clip * p0h
    d0 = wp.dot(sm.depth_row, p0h)
    out.z1[j, i] = stored_blocker_depth(rect, sm.depth, c, d0, sm.depth_per_unit, sm.empty_depth, u)
    out.z2[j, i] = stored_blocker_depth(rect, layer.opaque_depth, c, d0, sm.depth_per_unit, sm.empty_depth, u)
    out.w2[j, i] = stored_transmittance(layer.transmittance, c)


@wp.func
def radial_texel_depths(rect: NonlinearRectParams, i: int, w_caster: float, w_empty: float, s1: float, w1: float,
                        s2: float, w2: float):
    """(z1, z2, weight of z2) of a supersampled texel of column i from its parts' sums (s1, w1), (s2, w2)
    (:func:`tap_split`), each mean z_b placed at the centre column; one caster part and empty taps give the casters'
    depth and 1 with the empty weight; no caster (1, 1, 0)."""
    u_mid = (float(i) + 0.5) / float(rect.cols)
    z1 = float(1.0)
    z2 = float(1.0)
    share = float(0.0)
    if w_caster > 0.0:
        if w1 > 0.0:
            z1 = rectified_blocker_depth(rect, u_mid, part_mean(s1, w1))
        if w2 > 0.0:  # two caster depths
            z2 = rectified_blocker_depth(rect, u_mid, part_mean(s2, w2))
            share = w2 / (w1 + w2)
        else:  # the casters' depth, and the empty taps at depth 1
            share = w_empty / (w_caster + w_empty)
            if share <= 0.0:
                z2 = z1
    return z1, z2, share


@wp.func
def radial_row(rect: NonlinearRectParams, world_to_clip: wp.mat44, depth_row: wp.vec4, j: int):
    """(c0, ca, d0, da) of row j's light-ray points p(u) = origin + u a: clip coordinates c0 + u ca, stored depth
    d0 + u da."""
    v = (float(j) + 0.5) / float(rect.rows)
    a = light_ray_point(rect, 1.0, v) - rect.origin
    o = wp.vec4(rect.origin[0], rect.origin[1], rect.origin[2], 1.0)
    av = wp.vec4(a[0], a[1], a[2], 0.0)
    return world_to_clip * o, world_to_clip * av, wp.dot(depth_row, o), wp.dot(depth_row, av)


@wp.func
def radial_opaque_texel(rect: NonlinearRectParams, shadow_depth: wp.array2d(dtype=wp.float32), c0: wp.vec4,
                        ca: wp.vec4, d0: float, da: float, depth_per_unit: float, empty_depth: float, samples: int,
                        i: int):
    """(z1, z2, share) of :func:`radial_texel_depths` for texel column i of an opaque map's row (:func:`radial_row`);
    the taps are kept at static indices (registers) for the split pass."""
    inv = 1.0 / float(samples)
    lo, hi, w_caster, w_empty = empty_tap_range()
    s_caster = float(0.0)
    z_kept = radial_taps()
    w_kept = radial_taps()
    for k in range(wp.static(MAX_RADIAL_SAMPLES)):
        if k < samples:
            u = (float(i) + (float(k) + 0.5) * inv) / float(rect.cols)
            x, y, ax, ay = bilinear_footprint(shadow_depth, c0 + ca * u)
            d = d0 + da * u
            for t in range(4):
                xt, yt, wx, wy = footprint_tap(x, y, ax, ay, wp.static(t))
                z_b, caster = tap_caster(shadow_depth, xt, yt, d, depth_per_unit, empty_depth)
                lo, hi, w_caster, w_empty, s_caster, kept = keep_tap(lo, hi, w_caster, w_empty, s_caster, z_b,
                                                                     inv * wx * wy, caster)
                z_kept[wp.static(4 * k + t)] = z_b
                w_kept[wp.static(4 * k + t)] = kept
    s1, w1, s2, w2 = kept_taps_parts(z_kept, w_kept, 4 * samples, lo, hi, w_caster, w_empty, s_caster)
    return radial_texel_depths(rect, i, w_caster, w_empty, s1, w1, s2, w2)


@wp.kernel
def resample_radial_kernel(rect: NonlinearRectParams, sm: OrthoShadowMap, samples: int, span: int,
                           out: TwoDepthTexels, offset: int):
    # ``samples`` points over each texel's radial extent [i, i + 1) / cols, four bilinear taps each, condensed to two
    # depths (taps module doc); a thread takes ``span`` texels of a row (radial_span) and sets the row up once
    j, g = wp.tid()
    j += offset
    c0, ca, d0, da = radial_row(rect, sm.world_to_clip, sm.depth_row, j)
    for i in range(g * span, wp.min(g * span + span, rect.cols)):
        z1, z2, share = radial_opaque_texel(rect, sm.depth, c0, ca, d0, da, sm.depth_per_unit, sm.empty_depth,
                                            samples, i)
        out.z1[j, i] = z1
        out.z2[j, i] = z2
        out.w2[j, i] = share


@wp.kernel
def resample_radial_translucent_kernel(rect: NonlinearRectParams, sm: OrthoShadowMap, layer: TranslucentLayer,
                                       samples: int, span: int, out: TwoDepthTexels, offset: int):
    # resample_radial_kernel with translucent casters: each tap is two parts (split_translucent_taps)
    j, g = wp.tid()
    j += offset
    src = RadialTapSource()
    src.rect = rect
    src.sm = sm
    src.layer = layer
    c0, ca, d0, da = radial_row(rect, sm.world_to_clip, sm.depth_row, j)
    src.c0 = c0
    src.ca = ca
    src.d0 = d0
    src.da = da
    for i in range(g * span, wp.min(g * span + span, rect.cols)):
        w_caster, w_empty, s1, w1, s2, w2 = split_translucent_taps(src, samples, i)
        z1, z2, share = radial_texel_depths(rect, i, w_caster, w_empty, s1, w1, s2, w2)
        out.z1[j, i] = z1
        out.z2[j, i] = z2
        out.w2[j, i] = share


@wp.kernel
def resample_moments_kernel(
    rect: NonlinearRectParams,
    mp: MomentShadowParams,
    texels: wp.array3d(dtype=wp.vec4),  # (C, H, W) filtered stored moments; channel 0 is used
    out: TwoDepthTexels,
    caster_limit: float,  # signed depth of the farthest caster (sentinel_gap_depth)
    offset: int,
):
    # Peters 2017 Sec. 5.2 / D.5: filtered moment sample -> Algorithm 2 -> two rectified depths
    j, i = wp.tid()
    j += offset
    u, p0 = texel_light_ray(rect, i, j)
    c = shadow_coords(mp.sm, p0)  # (u_s, v_s, linear light depth of p0)
    z1 = float(1.0)
    z2 = float(1.0)
    w2 = float(0.0)
    if c[0] >= 0.0 and c[1] >= 0.0 and c[0] < 1.0 and c[1] < 1.0:
        b = mm.load_moments4(sample_bilinear4(texels, 0, c[0], c[1]), mp.storage)
        depths, weights = mm.two_depth_distribution(wp.vec3(b[0], b[1], b[2]))
        w2 = weights[1]
        for k in range(2):
            r = float(1.0)
            z = depths[k]
            if z < 1.0 - EMPTY_DEPTH_TOLERANCE:
                d = (z - mp.depth_offset) / mp.depth_scale  # linear light-space depth of the blocker
                d = sentinel_gap_depth(z, d, caster_limit, (caster_limit - mp.depth_offset) / mp.depth_scale)
                r = rectified_blocker_depth(rect, u, d - c[2])
            if k == 0:
                z1 = r
            else:
                z2 = r
    out.z1[j, i] = z1
    out.z2[j, i] = z2
    out.w2[j, i] = w2


def radial_span(cols: int, device) -> int:
    """Texels of a rectified row one thread of the supersampled resampling takes: the whole row on the CPU (the row's
    setup runs once), one on CUDA (a GPU needs the threads more). Any span gives the same texels."""
    return max(1, int(cols)) if wp.get_device(device).is_cpu else 1


def resample_shadow_map(rect: NonlinearRectification, shadow_depth, world_to_clip, *, depth: str = "ndc",
                        world_to_view=None, radial_samples: int = 0, translucency=None, device=None):
    """Resample an orthographic light shadow map into the rectified blocker-depth map (Peters 2017 Sec. 5.1.1; module
    doc).

    Args:
        rect: the rectification (its rows x cols is the output size).
        shadow_depth: (H, W) float32 numpy or Warp array of light-space depth, row 0 = NDC y = +1.
        world_to_clip: (4, 4) OpenGL-style orthographic world -> clip matrix of the shadow map
            (``projection @ view``), NDC z in [-1, 1], depth growing along the light direction.
        depth: what the texels store: ``"ndc"`` NDC z in [-1, 1], ``"window"`` (NDC z + 1) / 2 (both >= 1 empty), or
            ``"linear"`` the distance along the light from the light view's origin, -z of ``world_to_view``
            (:class:`~warpscatter.shadows.shadow_map.ShadowMap`'s convention); non-finite values are empty.
        world_to_view: (4, 4) light view matrix, required for ``depth="linear"``.
        radial_samples: 0: one nearest depth at each texel's centre (it aliases into radial streaks); 1 to
            :data:`MAX_RADIAL_SAMPLES`: that many points over the texel's radial extent, four bilinear taps each,
            condensed to two depths (:func:`resample_radial_kernel`).
        translucency: None, or the map's translucent layer (opaque depth, transmittance): two (H, W) arrays, the
            depth in the same kind as ``shadow_depth``.
        device: Warp device.

    Returns:
        (rows, cols) float32 Warp array of rectified blocker depth in [0, 1]; with ``radial_samples`` > 0 or
        ``translucency`` a :class:`SparseRectifiedDepth`.

    Raises:
        ValueError: on a matrix that is not an orthographic projection along the light direction, a bad
            ``depth`` kind or a shadow map that is not 2D.
    """
    device = default_device(device)
    m = np.asarray(world_to_clip, dtype=np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise ValueError(f"world_to_clip must be a finite 4x4 matrix, got shape {m.shape}")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise ValueError("world_to_clip must be orthographic (last row 0 0 0 1) for a directional light")
    light = rect.light_direction
    xy_drift = np.abs(m[:2, :3] @ light) / np.maximum(np.linalg.norm(m[:2, :3], axis=1), 1e-300)
    if np.any(xy_drift > 1e-5):
        raise ValueError("world_to_clip must project along the light direction (light rays map to one texel)")
    if depth == "ndc":
        row, empty = m[2], 1.0
    elif depth == "window":
        row, empty = 0.5 * m[2] + np.array([0.0, 0.0, 0.0, 0.5]), 1.0
    elif depth == "linear":
        if world_to_view is None:
            raise ValueError("world_to_view is required for depth='linear'")
        v = np.asarray(world_to_view, dtype=np.float64)
        if v.shape != (4, 4):
            raise ValueError(f"world_to_view must be a 4x4 matrix, got shape {v.shape}")
        row, empty = -v[2], np.inf
    else:
        raise ValueError(f"depth must be 'ndc', 'window' or 'linear', got {depth!r}")
    if int(radial_samples) != radial_samples or not 0 <= radial_samples <= MAX_RADIAL_SAMPLES:
        raise ValueError(f"radial_samples must be an integer in 0..{MAX_RADIAL_SAMPLES}, got {radial_samples}")
    per_unit = float(row[:3] @ light)
    if not per_unit > 0.0:
        raise ValueError("shadow-map depth must grow along the light direction (check world_to_clip / world_to_view)")
    sm = OrthoShadowMap()
    sm.depth = map_array(shadow_depth, "shadow_depth", device)
    sm.world_to_clip = wp.mat44(*m.astype(np.float32).ravel())
    sm.depth_row = wp.vec4(*row.astype(np.float32))
    sm.depth_per_unit = per_unit
    sm.empty_depth = float(empty)
    layer = None if translucency is None else translucent_layer(*translucency, sm.depth.shape, device)
    shape = (rect.rows, rect.cols)
    if radial_samples == 0 and layer is None:
        out = wp.empty(shape, dtype=wp.float32, device=device)
        launch_rows(resample_kernel, shape, [rect.params(), sm, out], device=device)
        return out
    result = SparseRectifiedDepth.empty(shape, device)
    if radial_samples == 0:
        launch_rows(resample_translucent_kernel, shape, [rect.params(), sm, layer, result.texels()], device=device)
        return result
    span = radial_span(rect.cols, device)
    dim = (rect.rows, (rect.cols + span - 1) // span)
    if layer is None:  # an opaque map keeps its taps for the split pass (taps module doc)
        launch_rows(resample_radial_kernel, dim, [rect.params(), sm, int(radial_samples), span, result.texels()],
                    device=device)
    else:
        launch_rows(resample_radial_translucent_kernel, dim,
                    [rect.params(), sm, layer, int(radial_samples), span, result.texels()], device=device)
    return result


def resample_footprint_texels(rect: NonlinearRectification, texel_world: float) -> float:
    """Radial width Delta_r = r_max / cols of a rectified texel's footprint in the light plane, in shadow-map texels of
    world size ``texel_world``: the finer side (the azimuthal one, u r_max phi_span / rows, grows with u), the default
    width of the moments filter's Gaussian (``resample_filter_px``), which so blurs nothing the rows resolve."""
    if not (np.isfinite(texel_world) and texel_world > 0.0):
        raise ValueError(f"texel_world must be finite and > 0, got {texel_world}")
    return float(rect.r_max / rect.cols / texel_world)


def radial_samples_for(rect: NonlinearRectification, texel_world: float) -> int:
    """Radial sub-samples of ``resample_filter: supersample`` (:func:`resample_shadow_map`): one per shadow-map texel
    a rectified texel spans radially (:func:`resample_footprint_texels`, rounded up), 1 to
    :data:`MAX_RADIAL_SAMPLES`."""
    return int(np.clip(math.ceil(resample_footprint_texels(rect, texel_world) - 1e-6), 1, MAX_RADIAL_SAMPLES))


def resample_moment_shadow_map(rect: NonlinearRectification, msm: MomentShadowMap, farthest_caster: float | None = None,
                               device=None) -> SparseRectifiedDepth:
    """Filtering during resampling (Peters 2017 Sec. 5.2, Algorithm 2, D.5): rectify a filtered moment shadow map.

    A bilinear sample of ``msm`` at each texel's light-ray point gives w_1 delta_{z_1} + w_2 delta_{z_2} by Algorithm 2
    (non-positive variance: delta_{b_1}); both depths go to rectified depth as in :func:`resample_shadow_map`, depths
    of the cleared far plane (z >= 1 - EMPTY_DEPTH_TOLERANCE) and light rays off the map to 1.

    Args:
        rect: the rectification (its rows x cols is the output size).
        msm: a :class:`~warpscatter.shadows.msm.MomentShadowMap` of an ORTHOGRAPHIC light view along the
            rectification's light direction (channel 0 is used), filtered as wanted.
        farthest_caster: linear light-space depth of the farthest caster (e.g. the plain map's largest finite
            depth), or None (the far plane); depths beyond it go continuously to infinity (:func:`sentinel_gap_depth`).
        device: Warp device.

    Returns:
        :class:`SparseRectifiedDepth` of shape (rows, cols).

    Raises:
        ValueError: for a perspective map or one whose view does not look along the light direction.
    """
    device = default_device(device)
    sm = msm.shadow_map
    if sm.perspective:
        raise ValueError("msm: filtering during resampling needs an orthographic (directional-light) moment map")
    forward = -np.asarray(sm.view, np.float64)[2, :3]
    if np.linalg.norm(np.cross(forward / np.linalg.norm(forward), rect.light_direction)) > 1e-5:
        raise ValueError("msm: its light view must look along the rectification's light direction")
    params = msm.params(normal_offset_texels=0.0)
    texels = msm.texels if msm.texels.device == wp.get_device(device) else msm.texels.to(device)
    shape = (rect.rows, rect.cols)
    result = SparseRectifiedDepth.empty(shape, device)
    z_empty = 1.0 - float(EMPTY_DEPTH_TOLERANCE)
    limit = z_empty
    if farthest_caster is not None and np.isfinite(farthest_caster):
        g = msm.geometry
        limit = float(np.clip(g.depth_scale * float(farthest_caster) + g.depth_offset, -1.0, z_empty))
    launch_rows(resample_moments_kernel, shape, [rect.params(), params, texels, result.texels(), limit],
                device=device)
    return result
