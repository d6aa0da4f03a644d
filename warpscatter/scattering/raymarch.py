"""Reference single scattering by per-pixel ray marching (CONVENTIONS.md; Klehm 2014 Eq. 1).

For the ray of pixel (i, j) with unit direction d and hit distance s (the G-buffer's ``distance``):

    L_scat = sigma_s * integral_0^s f(cos_theta(x_t)) E(x_t) V(x_t) exp(-sigma_t t) dt,
    cos_theta = dot(omega_l(x_t), -d),

estimated with N stratified, jittered steps over the LIT part of the ray, [t_lo, t_hi] (Engelhardt 2010
Sec. 5.3: "we always ray march at a fixed step size restricted to the light frustum"): the whole [0, s] for a
directional light, the chord inside a spot light's cone clipped to [0, s] for a spot light
(:func:`lit_interval`; the cone is convex, so the chord is one interval). Stratum k =
[t_lo + k dt, t_lo + (k+1) dt], dt = (t_hi - t_lo) / N, contributes f E V at one point of it times the
EXACT transmittance integral over the stratum (:func:`~warpscatter.scene.medium.transmittance_integral`).
Outside [t_lo, t_hi] the integrand is 0, so the estimate is that of the whole ray, with all N steps where
light is. With V = 1 and a directional light the estimate is the analytic
sigma_s f E (1 - exp(-sigma_t s)) / sigma_t for any N; with occluders or a spot light it converges as N grows.
N is fixed per ray (the ``steps`` key), so the step length is (t_hi - t_lo) / N, shorter on short chords; the
paper fixes the step length instead (a count that varies per ray). Here ``steps`` keeps one meaning for every
method that marches rays.

The point in each stratum (``jitter``):
* ``per_pixel`` (default) — an independent uniform offset per stratum and ray (stratified jittered sampling,
  the random stream of the ray's pixel): unbiased per pixel, noise that decorrelates between pixels;
* ``fixed`` — one offset per frame shared by every stratum of every ray (the paper's fixed step): a regular
  step pattern that moves smoothly from pixel to pixel, so neighbouring rays err coherently (banding instead
  of noise) and sparse sampling with interpolation can be compared against per-pixel marching without the
  per-pixel noise. Unbiased over the seed, not per pixel.

Visibility V(x) is either
* ``exact`` — a shadow ray from x towards the light cast against the scene's BVH (``wp.Mesh``): the
  ground truth every fast method is measured against; or
* ``shadow_map`` — a hard (nearest-texel) lookup in the light's shadow map.
"""

from __future__ import annotations

import warp as wp

from ..parallel import launch_rows
from ..scene.camera import CameraParams, pixel_ray_direction
from ..scene.lights import LightParams, light_params, light_sample, light_texture_array
from ..scene.medium import phase_eval, transmittance_integral
from ..shadows.shadow_map import ShadowMapParams, shadow_visibility
from ..wpinit import default_device, module_options

module_options()

VISIBILITY_EXACT = 0
VISIBILITY_SHADOW_MAP = 1

#: Step patterns of :func:`march_along` (see the module doc).
JITTERS = ("per_pixel", "fixed")
JITTER_PER_PIXEL = wp.constant(0)
JITTER_FIXED = wp.constant(1)


@wp.struct
class MediumParams:
    """Homogeneous medium as kernels see it."""

    sigma_t: float  # extinction, 1/unit
    sigma_s: float  # scattering, 1/unit
    phase_id: int  # PHASE_ISOTROPIC or PHASE_HENYEY_GREENSTEIN
    g: float  # HG asymmetry


def medium_params(medium) -> MediumParams:
    p = MediumParams()
    p.sigma_t = float(medium.sigma_t)
    p.sigma_s = float(medium.sigma_s)
    p.phase_id = int(medium.phase_id)
    p.g = float(medium.g)
    return p


@wp.func
def exact_visibility(mesh: wp.uint64, x: wp.vec3, omega_l: wp.vec3, dist: float, eps: float) -> float:
    """1 if the segment from x towards the light (travel direction omega_l, light at ``dist``) is unblocked."""
    start = x - omega_l * eps
    q = wp.mesh_query_ray(mesh, start, -omega_l, wp.min(dist, 1.0e20))
    if q.result:
        return 0.0
    return 1.0


@wp.func
def inscatter_sample(light: LightParams, light_tex: wp.array2d(dtype=wp.vec3), med: MediumParams, x: wp.vec3,
                     d: wp.vec3, vis_mode: int, mesh: wp.uint64, eps: float, sm: ShadowMapParams,
                     sm_depth: wp.array2d(dtype=wp.float32), sm_bias: float) -> wp.vec3:
    """sigma_s f(cos_theta) E(x) V(x) at medium point x seen along unit view direction d (no transmittance)."""
    e, omega, dist = light_sample(light, light_tex, x)
    if e[0] + e[1] + e[2] <= 0.0:
        return wp.vec3(0.0, 0.0, 0.0)
    v = float(0.0)
    if vis_mode == 0:
        v = exact_visibility(mesh, x, omega, dist, eps)
    else:
        v = shadow_visibility(sm, sm_depth, x, sm_bias)
    if v <= 0.0:
        return wp.vec3(0.0, 0.0, 0.0)
    return e * (med.sigma_s * phase_eval(med.phase_id, med.g, wp.dot(omega, -d)) * v)


@wp.func
def lit_interval(light: LightParams, origin: wp.vec3, d: wp.vec3, s: float):
    """Part [t_lo, t_hi] of the ray origin + t d (unit d), t in [0, s], where the light can reach the medium.

    Directional lights: the whole [0, s]. Spot lights: the chord of the ray inside the forward cone
    {x: dot(normalize(x - position), direction) >= cos_cone} of :func:`~warpscatter.scene.lights.light_sample`,
    clipped to [0, s]; the cone (half-angle < 90 deg) is convex, so the chord is one interval. Solved in float64
    (the quadratic dot(w + t d, a)^2 = cos^2 |w + t d|^2, w = origin - apex, restricted to the forward half-space
    dot(w + t d, a) >= 0) and widened by 1e-5 (|w| + s) on both sides, so float32 cone tests at the ends never
    fall outside it (a wider interval only spreads the steps: the integrand is 0 outside the cone).

    Returns:
        (t_lo, t_hi): distances along the ray; t_hi <= t_lo when the ray never enters the light.
    """
    if light.kind == 0:
        return float(0.0), s
    w = wp.vec3d(wp.float64(origin[0] - light.position[0]), wp.float64(origin[1] - light.position[1]),
                 wp.float64(origin[2] - light.position[2]))
    dd = wp.vec3d(wp.float64(d[0]), wp.float64(d[1]), wp.float64(d[2]))
    dd = dd / wp.length(dd)
    a = wp.vec3d(wp.float64(light.direction[0]), wp.float64(light.direction[1]), wp.float64(light.direction[2]))
    a = a / wp.length(a)
    c2 = wp.float64(light.cos_cone) * wp.float64(light.cos_cone)
    zero = wp.float64(0.0)
    lo = zero
    hi = wp.float64(s)
    empty = bool(False)
    da = wp.dot(dd, a)
    wa = wp.dot(w, a)
    # ---- forward half-space dot(w + t d, a) >= 0 ----
    if da > zero:
        lo = wp.max(lo, -wa / da)
    elif da < zero:
        hi = wp.min(hi, -wa / da)
    elif wa < zero:
        empty = True
    # ---- double cone f(t) = A t^2 + 2 b t + C >= 0 ----
    qa = da * da - c2
    qb = wa * da - c2 * wp.dot(w, dd)
    qc = wa * wa - c2 * wp.dot(w, w)
    if wp.abs(qa) < wp.float64(1.0e-12):
        if qb > zero:
            lo = wp.max(lo, -qc / (wp.float64(2.0) * qb))
        elif qb < zero:
            hi = wp.min(hi, -qc / (wp.float64(2.0) * qb))
        elif qc < zero:
            empty = True
    else:
        disc = qb * qb - qa * qc
        if qa < zero:  # the direction lies outside the cone's angle: f >= 0 between the roots (or nowhere)
            if disc < zero:
                empty = True
            else:
                sq = wp.sqrt(disc)
                r1 = (-qb + sq) / qa  # qa < 0: r1 <= r2
                r2 = (-qb - sq) / qa
                lo = wp.max(lo, r1)
                hi = wp.min(hi, r2)
        elif disc > zero:  # inside the cone's angle: f >= 0 outside the roots; the forward nappe is one side
            sq = wp.sqrt(disc)
            if da > zero:
                lo = wp.max(lo, (-qb + sq) / qa)
            else:
                hi = wp.min(hi, (-qb - sq) / qa)
    if empty or lo > hi:
        return float(0.0), float(0.0)
    pad = wp.float64(1.0e-5) * (wp.length(w) + wp.float64(s))
    return float(wp.max(lo - pad, zero)), float(wp.min(hi + pad, wp.float64(s)))


@wp.func
def march_along(origin: wp.vec3, d: wp.vec3, s: float, stream: int, light: LightParams,
                light_tex: wp.array2d(dtype=wp.vec3), med: MediumParams, steps: int, seed: int, jitter: int,
                vis_mode: int, mesh: wp.uint64, eps: float, sm: ShadowMapParams,
                sm_depth: wp.array2d(dtype=wp.float32), sm_bias: float) -> wp.vec3:
    """L_scat along the ray origin + t d (unit d), t in [0, s]: ``steps`` strata over :func:`lit_interval`.

    ``jitter`` JITTER_PER_PIXEL draws one offset per stratum from the random stream (``seed``, ``stream``);
    JITTER_FIXED uses one offset per frame (stream 0 of ``seed``) for every stratum of every ray (module doc).
    """
    t_lo, t_hi = lit_interval(light, origin, d, s)
    acc = wp.vec3(0.0, 0.0, 0.0)
    if t_hi <= t_lo:
        return acc
    dt = (t_hi - t_lo) / float(steps)
    rng = wp.rand_init(seed, stream)
    if jitter == JITTER_FIXED:
        rng = wp.rand_init(seed, 0)
    u = wp.randf(rng)
    for k in range(steps):
        t0 = t_lo + float(k) * dt
        if jitter == JITTER_PER_PIXEL and k > 0:
            u = wp.randf(rng)
        x = origin + d * (t0 + u * dt)
        c = inscatter_sample(light, light_tex, med, x, d, vis_mode, mesh, eps, sm, sm_depth, sm_bias)
        if c[0] + c[1] + c[2] > 0.0:
            acc += c * transmittance_integral(med.sigma_t, t0, t0 + dt)
    return acc


@wp.func
def march_ray(cam: CameraParams, i: int, j: int, s: float, light: LightParams, light_tex: wp.array2d(dtype=wp.vec3),
              med: MediumParams, steps: int, seed: int, jitter: int, vis_mode: int, mesh: wp.uint64, eps: float,
              sm: ShadowMapParams, sm_depth: wp.array2d(dtype=wp.float32), sm_bias: float) -> wp.vec3:
    """L_scat of pixel (i, j) whose ray ends at distance s (:func:`march_along` from the camera; see the module doc)."""
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    return march_along(cam.position, d, s, j * cam.width + i, light, light_tex, med, steps, seed, jitter, vis_mode,
                       mesh, eps, sm, sm_depth, sm_bias)


@wp.kernel
def raymarch_kernel(
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    light: LightParams,
    light_tex: wp.array2d(dtype=wp.vec3),
    med: MediumParams,
    steps: int,
    seed: int,
    jitter: int,  # JITTER_PER_PIXEL or JITTER_FIXED
    vis_mode: int,
    mesh: wp.uint64,
    eps: float,
    sm: ShadowMapParams,
    sm_depth: wp.array2d(dtype=wp.float32),
    sm_bias: float,
    x0: int,  # pixel region origin (column, row); the launch covers the region's rows x columns
    y0: int,
    out: wp.array2d(dtype=wp.vec3),
    offset: int,
):
    j, i = wp.tid()
    j += offset + y0
    i += x0
    out[j, i] = march_ray(cam, i, j, distance[j, i], light, light_tex, med, steps, seed, jitter, vis_mode, mesh, eps,
                          sm, sm_depth, sm_bias)


def raymarch(scene, gbuffer, *, steps: int = 128, visibility: str = "exact", geometry=None, shadow_map=None,
             seed: int = 0, jitter: str = "per_pixel", shadow_bias_texels: float = 1.0, region=None,
             out: wp.array | None = None, progress=None, device=None) -> wp.array:
    """Ray-march single scattering for every camera pixel.

    Args:
        scene: the :class:`~warpscatter.scene.Scene` (camera, light, medium).
        gbuffer: :class:`~warpscatter.gbuffer.GBuffer` giving each pixel's hit distance s.
        steps: stratified jittered steps per ray (>= 1).
        visibility: ``"exact"`` (needs ``geometry``, ray casts) or ``"shadow_map"`` (needs ``shadow_map``).
        geometry: :class:`~warpscatter.scene.DeviceGeometry` for exact visibility.
        shadow_map: :class:`~warpscatter.shadows.shadow_map.ShadowMap` for shadow-map visibility.
        seed: jitter seed (same seed, same image).
        jitter: step pattern, ``"per_pixel"`` (stratified jitter per ray) or ``"fixed"`` (one offset per frame,
            the paper's fixed step); see the module doc.
        shadow_bias_texels: shadow-map depth bias in texel sizes (world units = bias * texel size).
        region: optional pixel rectangle (x0, y0, width, height) to march; other pixels of ``out`` are kept.
        out: optional (H, W) vec3 array to write into (allocated when None).
        progress: optional ``progress(fraction)`` callback (rows done / rows).
        device: Warp device.

    Returns:
        (H, W) wp.array of vec3: L_scat in linear RGB radiance.
    """
    device = default_device(device)
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    jitter_id = jitter_mode(jitter)
    cam = scene.camera
    vis_mode, mesh_id, eps, sm_params, sm_depth, bias = visibility_inputs(scene, visibility, geometry, shadow_map,
                                                                          shadow_bias_texels, device)
    if out is None:
        out = wp.zeros((cam.height, cam.width), dtype=wp.vec3, device=device)
    x0, y0, w, h = region if region is not None else (0, 0, cam.width, cam.height)
    if not (0 <= x0 and 0 <= y0 and w >= 0 and h >= 0 and x0 + w <= cam.width and y0 + h <= cam.height):
        raise ValueError(f"region {region} must lie inside the {cam.width}x{cam.height} image")
    launch_rows(raymarch_kernel, (h, w),
                [cam.params(), gbuffer.distance, light_params(scene.light), light_texture_array(scene.light, device),
                 medium_params(scene.medium), int(steps), int(seed), jitter_id, vis_mode, mesh_id, eps, sm_params,
                 sm_depth, float(bias), int(x0), int(y0), out], device=device, progress=progress)
    return out


def jitter_mode(jitter: str) -> int:
    """Kernel id of a step pattern name (:data:`JITTERS`); ValueError naming the choices otherwise."""
    if jitter not in JITTERS:
        raise ValueError(f"jitter must be one of {', '.join(JITTERS)}, got {jitter!r}")
    return JITTERS.index(jitter)


def visibility_inputs(scene, visibility: str, geometry, shadow_map, shadow_bias_texels: float, device):
    """Kernel inputs of a visibility mode: (vis_mode, mesh id, eps, shadow-map params, depth, bias in world units).

    ``exact`` needs ``geometry`` (the BVH of its casters, :attr:`~warpscatter.scene.DeviceGeometry.shadow_mesh`,
    is built on first use); ``shadow_map`` needs ``shadow_map``. ``eps`` is
    the shadow-ray start offset, 1e-5 of the scene's extent. Shared by every method that marches rays.
    """
    if visibility not in ("exact", "shadow_map"):
        raise ValueError(f"visibility must be 'exact' or 'shadow_map', got {visibility!r}")
    lo, hi = scene.bounds()
    eps = 1e-5 * float(max(1.0, abs(lo).max(), abs(hi).max()))
    if visibility == "exact":
        if geometry is None:
            raise ValueError("geometry: exact visibility needs the scene's DeviceGeometry")
        p = ShadowMapParams()
        p.width = p.height = 1
        return VISIBILITY_EXACT, geometry.shadow_mesh.id, eps, p, wp.zeros((1, 1), dtype=wp.float32, device=device), 0.0
    if shadow_map is None:
        raise ValueError("shadow_map: shadow_map visibility needs a rendered ShadowMap")
    return (VISIBILITY_SHADOW_MAP, wp.uint64(0), eps, shadow_map.params(), shadow_map.device_depth(device),
            float(shadow_bias_texels * shadow_map.texel_world))
