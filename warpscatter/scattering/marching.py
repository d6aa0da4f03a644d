"""Marching single scattering along a ray: the estimator every marching method shares (CONVENTIONS.md;
Klehm 2014 Eq. 1).

For a ray origin + t d (unit d) ending at distance s, L_scat = sigma_s integral_0^s f(cos_theta) E V exp(-sigma_t t) dt
with cos_theta = dot(omega_l(x_t), -d), estimated with N (``steps``) stratified steps over the lit part of the ray
(:func:`lit_interval`; Engelhardt 2010 Sec. 5.3). Each stratum contributes f E V at one point times its exact
transmittance integral, so V = 1 under a directional light is exact for any N. N is fixed per ray (the paper fixes
the step length) so that ``steps`` means the same for every method.

Step patterns (``jitter``): ``per_pixel``, an independent offset per stratum and ray (unbiased per pixel); ``fixed``,
one offset per frame (the paper's fixed step), whose error moves smoothly between pixels. Visibility
(:class:`Visibility`): ``exact`` shadow rays against the casters' BVH (the reference) or a hard ``shadow_map`` look-up;
translucent casters pass 1 - opacity each. Given the pixels' normals, the shadow-map marcher shadows the samples the
map's bias would light behind an end surface facing away from the light (:func:`behind_end_surface`).

Kernels take the estimator's inputs as one :class:`Marcher` struct::

    from warpscatter.scattering import marching

    @wp.kernel
    def my_rays(m: marching.Marcher, origins: wp.array(dtype=wp.vec3), dirs: wp.array(dtype=wp.vec3),
                lengths: wp.array(dtype=float), out: wp.array(dtype=wp.vec3)):
        k = wp.tid()
        out[k] = marching.march_along(m, origins[k], dirs[k], lengths[k], k)

    m = marching.marcher_params(scene, steps=64, visibility=marching.visibility_params(scene, "exact", geometry))
"""

from __future__ import annotations

import weakref

import warp as wp

from ..runtime.device import default_device, module_options
from ..scene.camera import CameraParams, pixel_ray_direction
from ..scene.lights import LIGHT_DIRECTIONAL, LightParams, faces_away_from_light, light_params, light_sample
from ..scene.medium import (
    MediumParams,
    channel_decay,
    coloured_scattering,
    phase_eval,
    transmittance_integral,
    transmittance_integral_rgb,
)
from ..shadows.shadow_map import (
    PCF_RAMP_TEXELS,
    ShadowMapParams,
    TranslucentShadowDepths,
    narrowed_pcf_at,
    nearest_texel,
    orthographic_ray_coords,
    shadow_coords,
    shadow_visibility_at,
    texel_depth,
)
from .settings import JITTERS, VISIBILITY_MODES

module_options()

#: ``Visibility.mode``: exact shadow rays, or the light's shadow map.
VISIBILITY_EXACT = wp.constant(0)
VISIBILITY_SHADOW_MAP = wp.constant(1)
#: ``Marcher.jitter``: the step patterns (module doc).
JITTER_PER_PIXEL = wp.constant(0)
JITTER_FIXED = wp.constant(1)


@wp.struct
class Visibility:
    """Light visibility of medium points as kernels see it (build with :func:`visibility_params`)."""

    mode: int  # VISIBILITY_EXACT or VISIBILITY_SHADOW_MAP
    mesh: wp.uint64  # exact: the casters' BVH (wp.Mesh id)
    eps: float  # exact: the step past each translucent surface a shadow ray crosses (scene units)
    translucent: int  # 1 when some caster has opacity < 1 (V is then a transmittance in [0, 1])
    transmittance: wp.array(dtype=wp.float32)  # exact: 1 - opacity per caster triangle (the BVH's face order)
    sm: ShadowMapParams  # shadow_map: the map's transform (a 1x1 placeholder for exact)
    sm_depth: wp.array2d(dtype=wp.float32)  # shadow_map: linear depth of the nearest caster per texel
    sm_layers: TranslucentShadowDepths  # shadow_map, translucent: sm_depth with the opaque depths and transmittances
    sm_bias: float  # shadow_map: depth bias (scene units)


@wp.struct
class Marcher:
    """Everything the marching estimator reads besides the ray (build with :func:`marcher_params`)."""

    light: LightParams
    medium: MediumParams
    steps: int  # strata per ray, >= 1
    seed: int  # jitter seed
    jitter: int  # JITTER_PER_PIXEL or JITTER_FIXED
    vis: Visibility
    end_normals: wp.array2d(dtype=wp.vec3)  # (H, W) camera-facing normals of the pixels' end surfaces, or 1x1


@wp.struct
class EndSurface:
    """The surface a ray ends on, as the shadow-map marcher's bias guard sees it (:func:`end_surface`)."""

    active: int  # 1: the ray ends on a surface facing away from the light, and V comes from an opaque shadow map
    point: wp.vec3  # the end point
    normal: wp.vec3  # its camera-facing unit normal
    omega: wp.vec3  # the direction light travels at the end point
    zone: float  # the map's bias plus two texels at the end point (scene units): depth where the bias may light


# ---- building blocks (public @wp.func API) ---------------------------------------------------------


@wp.func
def exact_visibility(mesh: wp.uint64, x: wp.vec3, omega_l: wp.vec3, dist: float, eps: float) -> float:
    """1 if the segment from x towards the light (travel direction omega_l, light at ``dist``) is unblocked; the
    shadow ray starts ``eps`` towards the light (0 for a medium point)."""
    start = x - omega_l * eps
    q = wp.mesh_query_ray(mesh, start, -omega_l, wp.min(dist, 1.0e20))
    if q.result:
        return 0.0
    return 1.0


#: Most translucent surfaces an exact shadow ray passes through (beyond them it counts as blocked).
MAX_TRANSLUCENT_LAYERS = wp.constant(16)


@wp.func
def exact_transmittance(vis: Visibility, x: wp.vec3, omega_l: wp.vec3, dist: float) -> float:
    """Light transmittance from x towards the light: the product of 1 - opacity of every caster surface crossed
    (Peters 2017 Sec. 3), 0 at an opaque one or after :data:`MAX_TRANSLUCENT_LAYERS` surfaces."""
    start = x
    left = wp.min(dist, 1.0e20)
    t = float(1.0)
    for _layer in range(int(MAX_TRANSLUCENT_LAYERS)):  # int(): a loop, not 16 unrolled BVH queries
        q = wp.mesh_query_ray(vis.mesh, start, -omega_l, left)
        if not q.result:
            return t
        t = t * vis.transmittance[q.face]
        if t <= 0.0:
            return 0.0
        step = q.t + vis.eps  # past the surface, on towards the light
        start = start - omega_l * step
        left = left - step
        if left <= 0.0:
            return t
    return 0.0


@wp.func
def map_visibility_at(vis: Visibility, c: wp.vec3) -> float:
    """Shadow-map V at map coordinates c = (u, v, depth): hard, or the translucent casters' transmittance."""
    if vis.translucent != 0:
        return shadow_visibility_at(vis.sm, vis.sm_layers, c, vis.sm_bias)
    return shadow_visibility_at(vis.sm, vis.sm_depth, c, vis.sm_bias)


@wp.func
def map_pcf_at(vis: Visibility, c: wp.vec3) -> float:
    """:func:`map_visibility_at` with 2 x 2 PCF whose weights are narrowed to a ramp of
    :data:`~warpscatter.shadows.shadow_map.PCF_RAMP_TEXELS` at texel borders: smooth without blurring silhouettes."""
    if vis.translucent != 0:
        return narrowed_pcf_at(vis.sm, vis.sm_layers, c, vis.sm_bias, PCF_RAMP_TEXELS)
    return narrowed_pcf_at(vis.sm, vis.sm_depth, c, vis.sm_bias, PCF_RAMP_TEXELS)


@wp.func
def point_visibility(vis: Visibility, x: wp.vec3, omega_l: wp.vec3, dist: float) -> float:
    """V(x) in [0, 1] of medium point x for light travelling along omega_l from ``dist`` away. An exact shadow ray
    starts at x itself: an offset start would pass through a surface closer than the offset (bright pixels)."""
    if vis.mode == VISIBILITY_EXACT:
        if vis.translucent != 0:
            return exact_transmittance(vis, x, omega_l, dist)
        return exact_visibility(vis.mesh, x, omega_l, dist, 0.0)
    return map_visibility_at(vis, shadow_coords(vis.sm, x))


@wp.func
def inscatter_sample(m: Marcher, x: wp.vec3, d: wp.vec3) -> wp.vec3:
    """sigma_s f(cos_theta) E(x) V(x) at medium point x seen along unit view direction d (no transmittance)."""
    e, omega, dist = light_sample(m.light, x)
    if e[0] + e[1] + e[2] <= 0.0:
        return wp.vec3(0.0, 0.0, 0.0)
    v = point_visibility(m.vis, x, omega, dist)
    if v <= 0.0:
        return wp.vec3(0.0, 0.0, 0.0)
    if m.medium.coloured != 0:
        return wp.cw_mul(e, m.medium.sigma_s_rgb) * (phase_eval(m.medium.phase_id, m.medium.g, wp.dot(omega, -d)) * v)
    return e * (m.medium.sigma_s * phase_eval(m.medium.phase_id, m.medium.g, wp.dot(omega, -d)) * v)


@wp.func
def square_lit_interval(light: LightParams, w: wp.vec3d, dd: wp.vec3d, s: float):
    """:func:`lit_interval` of a square spot (a point light's cube face): the ray w + t dd (apex-relative, float64)
    clipped by the pyramid's four planes."""
    t = wp.float64(light.tan_cone)
    f = wp.vec3d(wp.float64(light.direction[0]), wp.float64(light.direction[1]), wp.float64(light.direction[2]))
    r = wp.vec3d(wp.float64(light.right[0]), wp.float64(light.right[1]), wp.float64(light.right[2]))
    u = wp.vec3d(wp.float64(light.up[0]), wp.float64(light.up[1]), wp.float64(light.up[2]))
    zero = wp.float64(0.0)
    lo = zero
    hi = wp.float64(s)
    empty = bool(False)
    for k in range(4):
        side = r
        if k >= 2:
            side = u
        if k % 2 == 1:
            side = -side
        n = side - t * f  # the half-space dot(x, n) <= 0
        g0 = wp.dot(w, n)
        g1 = wp.dot(dd, n)
        if g1 > zero:
            hi = wp.min(hi, -g0 / g1)
        elif g1 < zero:
            lo = wp.max(lo, -g0 / g1)
        elif g0 > zero:
            empty = True
    if empty or lo > hi:
        return float(0.0), float(0.0)
    pad = wp.float64(1.0e-5) * (wp.length(w) + wp.float64(s))
    return float(wp.max(lo - pad, zero)), float(wp.min(hi + pad, wp.float64(s)))


@wp.func
def lit_interval(light: LightParams, origin: wp.vec3, d: wp.vec3, s: float):
    """Part (t_lo, t_hi) of the ray origin + t d (unit d), t in [0, s], that the light reaches: [0, s] for directional
    lights; for spot lights the chord inside the forward cone, solved in float64 and widened by 1e-5 (|w| + s) so that
    float32 cone tests at its ends stay inside. t_hi <= t_lo when the ray never enters the light."""
    if light.kind == LIGHT_DIRECTIONAL:
        return float(0.0), s
    w = wp.vec3d(wp.float64(origin[0] - light.position[0]), wp.float64(origin[1] - light.position[1]),
                 wp.float64(origin[2] - light.position[2]))
    dd = wp.vec3d(wp.float64(d[0]), wp.float64(d[1]), wp.float64(d[2]))
    dd = dd / wp.length(dd)
    if light.square != 0:
        return square_lit_interval(light, w, dd, s)
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
def end_surface(m: Marcher, origin: wp.vec3, d: wp.vec3, s: float, n_end: wp.vec3) -> EndSurface:
    """The bias guard of a ray ending at distance s on a surface with camera-facing normal n_end (zero: none)."""
    return end_surface_at(m.vis, m.light, origin + d * s, n_end)


@wp.func
def end_surface_at(vis: Visibility, light: LightParams, point: wp.vec3, n_end: wp.vec3) -> EndSurface:
    """:func:`end_surface` of the end point ``point`` from the visibility and the light alone."""
    e = EndSurface()
    e.active = 0
    if vis.mode != VISIBILITY_SHADOW_MAP or vis.translucent != 0:
        return e
    e.point = point
    if not faces_away_from_light(light, e.point, n_end):
        return e  # no surface, or the side the camera sees faces the light
    _radiance, omega, _distance = light_sample(light, e.point)
    texel = vis.sm.texel_world
    if vis.sm.perspective != 0:
        texel = texel * wp.max(shadow_coords(vis.sm, e.point)[2], 0.0)
    e.active = 1
    e.normal = n_end
    e.omega = omega
    e.zone = vis.sm_bias + 2.0 * texel
    return e


@wp.func
def behind_end_surface(e: EndSurface, vis: Visibility, x: wp.vec3) -> bool:
    """Whether medium point x lies behind the ray's end surface within ``e.zone`` along the light and its map texel
    holds a caster no deeper than that plane: the surface itself shadows x."""
    if e.active == 0:
        return False
    h = wp.dot(x - e.point, e.normal) / wp.dot(e.omega, e.normal)  # back along the light ray to the plane
    if h < 0.0 or h > e.zone:
        return False
    i, j = nearest_texel(vis.sm, shadow_coords(vis.sm, x))
    if i < 0:
        return False
    plane_depth = shadow_coords(vis.sm, x - e.omega * h)[2]  # the plane's depth on x's light ray
    return texel_depth(vis.sm_depth, j, i) <= plane_depth + e.zone


@wp.func
def stretch_visibility(vis: Visibility, end: EndSurface, origin: wp.vec3, d: wp.vec3, t0: float, t1: float,
                       sigma_t: float, max_samples: int) -> float:
    """Transmittance-weighted mean shadow-map visibility of the stretch [t0, t1] of a ray ending on ``end``: one
    2 x 2 PCF sample (:func:`map_pcf_at`; hard look-ups streak) per map texel of its length, at most ``max_samples``."""
    n = wp.clamp(int(wp.ceil((t1 - t0) / wp.max(vis.sm.texel_world, 1.0e-12))), 1, max_samples)
    dt = (t1 - t0) / float(n)
    decay = wp.exp(-sigma_t * dt)
    w = float(1.0)  # relative to the first sample's (no underflow in a dense medium)
    acc = float(0.0)
    wsum = float(0.0)
    for k in range(n):
        x = origin + d * (t0 + (float(k) + 0.5) * dt)
        wsum += w
        if not behind_end_surface(end, vis, x):
            acc += w * map_pcf_at(vis, shadow_coords(vis.sm, x))
        w *= decay
    return acc / wsum


@wp.func
def march_directional_shadow_map(m: Marcher, origin: wp.vec3, d: wp.vec3, dt: float, u: float,
                                 rng: wp.uint32, end: EndSurface) -> wp.vec3:
    """:func:`march_along`'s strata for a directional light and an orthographic map: E, omega_l and the phase are
    constant, the map coordinates affine in t and the transmittance integrals geometric, so a step is a texel fetch
    and a few multiply-adds; the same estimate up to rounding."""
    acc = wp.vec3(0.0, 0.0, 0.0)
    e = m.light.radiance
    if e[0] + e[1] + e[2] <= 0.0:
        return acc
    e = e * (m.medium.sigma_s * phase_eval(m.medium.phase_id, m.medium.g, wp.dot(m.light.direction, -d)))
    sm = m.vis.sm
    c0, dc = orthographic_ray_coords(sm, origin, d)
    stratum = transmittance_integral(m.medium.sigma_t, 0.0, dt)  # of the first stratum; then times decay^k
    decay = wp.exp(-m.medium.sigma_t * dt)
    for k in range(m.steps):
        t0 = float(k) * dt
        if m.jitter == JITTER_PER_PIXEL and k > 0:
            u = wp.randf(rng)
        t = t0 + u * dt
        v = map_visibility_at(m.vis, c0 + dc * t)
        if v > 0.0 and not behind_end_surface(end, m.vis, origin + d * t):
            acc += e * (v * stratum)
        stratum *= decay
    return acc


@wp.func
def march_along(m: Marcher, origin: wp.vec3, d: wp.vec3, s: float, stream: int) -> wp.vec3:
    """L_scat along the ray origin + t d (unit d), t in [0, s]: ``m.steps`` strata over :func:`lit_interval`, no end
    surface known."""
    return march_to_surface(m, origin, d, s, wp.vec3(0.0, 0.0, 0.0), stream)


@wp.func
def march_to_surface(m: Marcher, origin: wp.vec3, d: wp.vec3, s: float, n_end: wp.vec3, stream: int) -> wp.vec3:
    """:func:`march_along` for a ray ending on a surface with camera-facing unit normal n_end (zero: none)."""
    end = end_surface(m, origin, d, s, n_end)
    t_lo, t_hi = lit_interval(m.light, origin, d, s)
    acc = wp.vec3(0.0, 0.0, 0.0)
    if t_hi <= t_lo:
        return acc
    dt = (t_hi - t_lo) / float(m.steps)
    rng = wp.rand_init(m.seed, stream)
    if m.jitter == JITTER_FIXED:
        rng = wp.rand_init(m.seed, 0)
    u = wp.randf(rng)
    if (m.light.kind == LIGHT_DIRECTIONAL and m.vis.mode == VISIBILITY_SHADOW_MAP and m.vis.sm.perspective == 0
            and m.medium.coloured == 0):
        return march_directional_shadow_map(m, origin, d, dt, u, rng, end)
    for k in range(m.steps):
        t0 = t_lo + float(k) * dt
        if m.jitter == JITTER_PER_PIXEL and k > 0:
            u = wp.randf(rng)
        x = origin + d * (t0 + u * dt)
        if behind_end_surface(end, m.vis, x):
            continue
        c = inscatter_sample(m, x, d)
        if c[0] + c[1] + c[2] > 0.0:
            if m.medium.coloured != 0:
                acc += wp.cw_mul(c, transmittance_integral_rgb(m.medium, t0, t0 + dt))
            else:
                acc += c * transmittance_integral(m.medium.sigma_t, t0, t0 + dt)
    return acc


@wp.func
def texel_steps(m: Marcher, origin: wp.vec3, d: wp.vec3, s: float, per_texel: float, least: int) -> int:
    """Strata for the ray by the n shadow-map texels its lit part crosses (a spot's: of the finer of map and texture),
    ceil(per_texel n) within [min(least, m.steps), m.steps]: a hard look-up is constant over a texel but for one depth
    crossing. ``m.steps`` with exact visibility and for per_texel <= 0."""
    if per_texel <= 0.0 or m.vis.mode != VISIBILITY_SHADOW_MAP:
        return m.steps
    texels = float(0.0)
    if m.vis.sm.perspective == 0:
        if m.light.kind != LIGHT_DIRECTIONAL:
            return m.steps
        _c0, dc = orthographic_ray_coords(m.vis.sm, origin, d)
        per_length = wp.abs(dc[0]) * float(m.vis.sm.width) + wp.abs(dc[1]) * float(m.vis.sm.height)
        texels = per_length * wp.min(s, 1.0e30)  # a sky ray's s may be +inf (and 0 * inf is NaN)
    else:
        t_lo, t_hi = lit_interval(m.light, origin, d, s)
        if t_hi <= t_lo:
            return wp.min(least, m.steps)  # the ray never enters the light: its march adds nothing
        a = shadow_coords(m.vis.sm, origin + d * t_lo)
        b = shadow_coords(m.vis.sm, origin + d * t_hi)
        if a[0] < 0.0 and a[1] < 0.0 or b[0] < 0.0 and b[1] < 0.0:
            return m.steps  # an end at or behind the light's plane (shadow_coords' marker): no projected segment
        cols = float(m.vis.sm.width)
        rows = float(m.vis.sm.height)
        if m.light.has_texture != 0:  # the texture's colours change along the ray too
            cols = wp.max(cols, float(m.light.texture.shape[1]))
            rows = wp.max(rows, float(m.light.texture.shape[0]))
        texels = wp.abs(b[0] - a[0]) * cols + wp.abs(b[1] - a[1]) * rows
    n = int(wp.min(wp.ceil(per_texel * texels), float(m.steps)))  # capped in float: int() of 1e30 overflows
    return wp.clamp(n, wp.min(least, m.steps), m.steps)


@wp.func
def march_ray(cam: CameraParams, i: int, j: int, s: float, m: Marcher) -> wp.vec3:
    """L_scat of pixel (i, j) whose ray ends at distance s (:func:`march_to_surface`)."""
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    return march_to_surface(m, cam.position, d, s, pixel_end_normal(m, i, j), j * cam.width + i)


@wp.func
def pixel_end_normal(m: Marcher, i: int, j: int) -> wp.vec3:
    """The camera-facing normal of pixel (i, j)'s end surface from ``m.end_normals`` (zero without them)."""
    if m.end_normals.shape[0] <= j or m.end_normals.shape[1] <= i:
        return wp.vec3(0.0, 0.0, 0.0)
    return m.end_normals[j, i]


@wp.func
def march_screen_point(cam: CameraParams, x: float, y: float, s: float, m: Marcher) -> wp.vec3:
    """L_scat along the camera ray through screen point (x, y) (pixels) ending at distance s; random stream and end
    normal of the pixel containing (x, y), so a pixel centre reproduces :func:`march_ray` bit for bit."""
    d = pixel_ray_direction(cam, x, y)
    pi = wp.clamp(int(wp.floor(x)), 0, cam.width - 1)
    pj = wp.clamp(int(wp.floor(y)), 0, cam.height - 1)
    return march_to_surface(m, cam.position, d, s, pixel_end_normal(m, pi, pj), pj * cam.width + pi)


#: struct -> owner of the BVH its ``mesh`` id points to (a Warp struct holds a wp.Mesh only as an id).
_BVH_OWNERS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def jitter_mode(jitter: str) -> int:
    """Kernel id of a step pattern name (:data:`~.settings.JITTERS`); ValueError naming the choices otherwise."""
    if jitter not in JITTERS:
        raise ValueError(f"jitter must be one of {', '.join(JITTERS)}, got {jitter!r}")
    return JITTERS.index(jitter)


def shadow_ray_offset(scene) -> float:
    """The exact visibility's step past each translucent surface a shadow ray crosses (and a surface point's start
    offset for callers of :func:`exact_visibility`): 1e-5 of the scene's extent (scene units)."""
    lo, hi = scene.bounds()
    return 1e-5 * float(max(1.0, abs(lo).max(), abs(hi).max()))


def visibility_params(scene, visibility: str, geometry=None, shadow_map=None, shadow_bias_texels: float = 1.0,
                      device=None) -> Visibility:
    """:class:`Visibility` of a mode for every method that marches rays: ``"exact"`` needs ``geometry``
    (:class:`~warpscatter.scene.DeviceGeometry`; its casters' BVH is built on first use), ``"shadow_map"`` needs
    ``shadow_map`` (:class:`~warpscatter.shadows.shadow_map.ShadowMap`, depth bias ``shadow_bias_texels`` texels).
    ValueError for an unknown mode or its input missing."""
    device = default_device(device)
    if visibility not in VISIBILITY_MODES:
        raise ValueError(f"visibility must be 'exact' or 'shadow_map', got {visibility!r}")
    v = Visibility()
    v.eps = shadow_ray_offset(scene)
    if visibility == "exact":
        if geometry is None:
            raise ValueError("geometry: exact visibility needs the scene's DeviceGeometry")
        v.mode = VISIBILITY_EXACT
        v.mesh = geometry.shadow_mesh.id
        v.translucent = int(geometry.translucent_casters)
        v.transmittance = geometry.caster_transmittance
        _BVH_OWNERS[v] = geometry
        v.sm = ShadowMapParams()
        v.sm.width = v.sm.height = 1
        v.sm_depth = wp.zeros((1, 1), dtype=wp.float32, device=device)
        v.sm_layers = TranslucentShadowDepths()
        v.sm_layers.depth = v.sm_layers.opaque = v.sm_layers.transmittance = v.sm_depth
        v.sm_bias = 0.0
        return v
    if shadow_map is None:
        raise ValueError("shadow_map: shadow_map visibility needs a rendered ShadowMap")
    v.mode = VISIBILITY_SHADOW_MAP
    v.mesh = wp.uint64(0)
    v.translucent = int(shadow_map.translucent)
    v.transmittance = wp.zeros(1, dtype=wp.float32, device=device)
    v.sm = shadow_map.params()
    v.sm_depth = shadow_map.device_depth(device)
    v.sm_layers = shadow_map.device_layers(v.sm_depth, device)
    v.sm_bias = float(shadow_bias_texels * shadow_map.texel_world)
    return v


def marcher_params(scene, *, steps: int, visibility: Visibility, seed: int = 0, jitter: str = "per_pixel",
                   light_texture: wp.array | None = None, end_normals: wp.array | None = None, device=None) -> Marcher:
    """:class:`Marcher` of a scene's light (directional or spot) and medium, with ``steps`` (>= 1) strata per ray, the
    ``visibility`` of :func:`visibility_params` and the step pattern ``jitter`` (module doc). ``light_texture``: a spot
    texture to march with instead of the light's own (a prefiltered copy); ``end_normals``: (H, W) camera-facing unit
    normals of the pixels' end surfaces (the G-buffer's ``normal``) for the bias guard of :func:`march_ray`, None: no
    guard. ValueError for steps < 1 or an unknown step pattern."""
    if isinstance(steps, bool) or int(steps) != steps or steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    m = Marcher()
    m.light = light_params(scene.light, device, texture=light_texture)
    m.medium = scene.medium.params()
    m.steps = int(steps)
    m.seed = int(seed)
    m.jitter = jitter_mode(jitter)
    m.vis = visibility
    m.end_normals = end_normals if end_normals is not None else wp.zeros((1, 1), dtype=wp.vec3,
                                                                         device=default_device(device))
    if visibility in _BVH_OWNERS:
        _BVH_OWNERS[m] = _BVH_OWNERS[visibility]  # the struct is copied into m: m keeps the BVH alive too
    return m


@wp.func
def march_transmittance_strata(m: Marcher, origin: wp.vec3, d: wp.vec3, s: float, n_end: wp.vec3,
                               stream: int) -> wp.vec3:
    """L_scat along the ray (directional light, orthographic map) with ``m.steps`` strata of EQUAL transmittance
    weight, so that no stratum (one flipping texel) carries more than 1 / N: a sample at p in [0, 1) sits at
    t = -ln(1 - p (1 - exp(-sigma_t s))) / sigma_t; coloured media reweight per channel by exp(-(sigma_c - sigma_t) t)
    (a ratio estimator). Visibility: 2 x 2 PCF (:func:`map_pcf_at`); n_end as in :func:`march_to_surface`."""
    end = end_surface(m, origin, d, s, n_end)
    acc = wp.vec3(0.0, 0.0, 0.0)
    e = m.light.radiance
    if s <= 0.0 or e[0] + e[1] + e[2] <= 0.0:
        return acc
    sigma = m.medium.sigma_t
    e = e * (m.medium.sigma_s * phase_eval(m.medium.phase_id, m.medium.g, wp.dot(m.light.direction, -d)))
    sm = m.vis.sm
    c0, dc = orthographic_ray_coords(sm, origin, d)
    x = sigma * s
    a = 1.0 - wp.exp(-x)  # weight of the whole ray, relative to an infinite one
    rng = wp.rand_init(m.seed, stream)
    if m.jitter != JITTER_PER_PIXEL:
        rng = wp.rand_init(m.seed, 0)
    u = wp.randf(rng)
    inv_n = 1.0 / float(m.steps)
    lit = float(0.0)
    lit_rgb = wp.vec3(0.0, 0.0, 0.0)  # coloured: per-channel weighted visibility and weight sums
    sum_rgb = wp.vec3(0.0, 0.0, 0.0)
    for k in range(m.steps):
        if m.jitter == JITTER_PER_PIXEL and k > 0:
            u = wp.randf(rng)
        p = (float(k) + u) * inv_n
        t = p * s  # thin media: the weight is uniform in t
        if x > 1.0e-3:
            t = -wp.log(wp.max(1.0 - p * a, 1.0e-30)) / sigma
        v = map_pcf_at(m.vis, c0 + dc * wp.min(t, s))
        if v > 0.0 and behind_end_surface(end, m.vis, origin + d * wp.min(t, s)):
            v = 0.0
        lit += v
        if m.medium.coloured != 0:
            w = channel_decay(m.medium, wp.min(t, s), sigma)
            lit_rgb += w * v
            sum_rgb += w
    if m.medium.coloured != 0:
        e_rgb = coloured_scattering(m.medium, m.light.radiance, 0.0, s) * phase_eval(
            m.medium.phase_id, m.medium.g, wp.dot(m.light.direction, -d))
        return wp.cw_mul(e_rgb, wp.cw_div(lit_rgb, sum_rgb))
    return e * (transmittance_integral(sigma, 0.0, s) * lit * inv_n)


__all__ = [
    "JITTER_FIXED",
    "JITTER_PER_PIXEL",
    "VISIBILITY_EXACT",
    "VISIBILITY_SHADOW_MAP",
    "Marcher",
    "Visibility",
    "exact_visibility",
    "inscatter_sample",
    "jitter_mode",
    "lit_interval",
    "map_visibility_at",
    "march_along",
    "march_to_surface",
    "behind_end_surface",
    "end_surface",
    "end_surface_at",
    "EndSurface",
    "pixel_end_normal",
    "stretch_visibility",
    "march_ray",
    "march_screen_point",
    "marcher_params",
    "march_transmittance_strata",
    "texel_steps",
    "point_visibility",
    "shadow_ray_offset",
    "visibility_params",
]
