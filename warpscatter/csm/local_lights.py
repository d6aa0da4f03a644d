"""Monte-Carlo direct lighting from local area and linear lights with coherent-shadow-map visibility
(Ritschel 2007, Sec. 4.2 and 5.1).

Lights (scene units, linear RGB): a parallelogram y(s, t) = corner + s u + t v of radiance L_e (times its texture),
a segment of intensity I per unit length, or a parallelepiped of intensity I per unit volume (d = 3; only light
sampling contributes). Sampling by radiance (Sec. 5.1): uniform in (s, t) or s, a textured light by its texels, the
S strata stratifying (s, t); an area sample's solid-angle density is d^2 / (A |cos theta_l|). Area lights combine one
light and one BRDF sample per stratum with the balance heuristic [VG95]; linear lights: f I V cos(theta_x) / d^2 * l.

Visibility: the light's ``"cube"`` CSM (Sec. 3.3 / 4.2, built on the same light so (s, t) index its samples), a
lat-long CSM towards y - x (semi-local, Sec. 4.3: the light outside the occluders' hull), a shadow ray, or none.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..runtime.device import module_options
from ..scene.lights import (
    LOCAL_LIGHT_LINEAR,
    LOCAL_LIGHT_VOLUME,
    AreaLight,
    LinearLight,
    LocalLightData,
    VolumeLight,
    area_light_intersect,
    area_light_pdf,
    area_light_point,
    area_light_radiance,
    area_light_sample_st,
)
from .brdf import MaterialData, shading_eval, shading_pdf, shading_point, shading_sample
from .compress import KIND_CUBE, CoherentShadowMap
from .direct_lighting import (
    VIS_CSM,
    VIS_MESH,
    VIS_OBJECTS,
    VIS_SEMI_LOCAL,
    LightVisibility,
    SurfacePoints,
    objects_visibility,
    shade_direct,
    shadow_ray_blocked,
    stratum_random_numbers,
    stratum_sample,
    surface_point,
)
from .query import csm_local_visibility_filtered, csm_visibility_filtered

module_options()


@wp.func(inline=True)
def local_visibility(vis: LightVisibility, x: wp.vec3, n: wp.vec3, y: wp.vec3, st: wp.vec2, xi: wp.vec4) -> float:
    """V between surface point ``x`` and the light point ``y`` of parameters ``st`` for each visibility mode (shadow
    rays stop just short of y)."""
    o = x + vis.eps * n
    if vis.mode == VIS_CSM:
        return csm_local_visibility_filtered(vis.cube, o, st, vis.bias, vis.filter_mode, xi)
    if vis.mode == VIS_SEMI_LOCAL:
        return csm_visibility_filtered(vis.latlong, o, y - o, vis.bias, vis.filter_mode, xi)
    if vis.mode == VIS_OBJECTS:
        return objects_visibility(vis, o, y - o, xi)
    if vis.mode == VIS_MESH:
        w = y - o
        dist = wp.length(w)
        if dist > 0.0 and shadow_ray_blocked(vis.mesh, o, w / dist, dist * (1.0 - 1.0e-4)):
            return 0.0
    return 1.0




@wp.kernel
def shade_local_light_kernel(
    surf: SurfacePoints,
    mat: MaterialData,
    light: LocalLightData,
    strata: int,
    vis: LightVisibility,
    seed: int,
    out: wp.array(dtype=wp.vec3),
    offset: int,
):
    """out[k] = one stratified estimate of the radiance reflected at point k from the local light."""
    k = wp.tid() + offset
    rng = wp.rand_init(seed, k)
    x, n, wo, m = surface_point(surf, k)
    sp = shading_point(mat, m, n, wo)
    total = wp.vec3(0.0)
    count = strata * strata
    for s in range(count):
        j_light, j_brdf, choice, xi_light, xi_brdf, rng = stratum_random_numbers(rng)
        if light.kind == LOCAL_LIGHT_VOLUME or light.kind == LOCAL_LIGHT_LINEAR:
            # no surface to hit: light sampling only (volume: r from the stratum's third number)
            st = stratum_sample(s, strata, j_light)
            y = light.origin + st[0] * light.edge_u + st[1] * light.edge_v + choice * light.normal
            if light.kind == LOCAL_LIGHT_LINEAR:
                st = wp.vec2((float(s) + j_light[0]) / float(count), 0.5)
                y = light.origin + st[0] * light.edge_u
            w = y - x
            d2 = wp.dot(w, w)
            if d2 > 0.0:
                d = w / wp.sqrt(d2)
                c = wp.dot(n, d)
                if c > 0.0:
                    f = shading_eval(sp, d)
                    if wp.length_sq(f) > 0.0:
                        v = local_visibility(vis, x, n, y, st, xi_light)
                        total += wp.cw_mul(f, light.emission) * (v * c * light.size / d2)
        else:
            # ---- area light sample (uniform in (s, t)), balance heuristic ----
            st = area_light_sample_st(light, stratum_sample(s, strata, j_light))
            y = area_light_point(light, st)
            w = y - x
            d2 = wp.dot(w, w)
            if d2 > 0.0:
                d = w / wp.sqrt(d2)
                c = wp.dot(n, d)
                pl = area_light_pdf(light, x, y, st)
                le = area_light_radiance(light, -d, st)
                if c > 0.0 and pl > 0.0 and wp.length_sq(le) > 0.0:
                    f = shading_eval(sp, d)
                    if wp.length_sq(f) > 0.0:
                        v = local_visibility(vis, x, n, y, st, xi_light)
                        total += wp.cw_mul(f, le) * (v * c / (pl + shading_pdf(sp, d)))
            # ---- BRDF sample: counts where its ray hits the light ----
            wi = shading_sample(sp, stratum_sample(s, strata, j_brdf), choice)
            c = wp.dot(n, wi)
            if c > 0.0:
                pb = shading_pdf(sp, wi)
                r, sth = area_light_intersect(light, x, wi)
                if pb > 0.0 and r > 0.0:
                    le = area_light_radiance(light, -wi, sth)
                    yh = x + r * wi
                    f = shading_eval(sp, wi)
                    if wp.length_sq(le) > 0.0 and wp.length_sq(f) > 0.0:
                        v = local_visibility(vis, x, n, yh, sth, xi_brdf)
                        total += wp.cw_mul(f, le) * (v * c / (pb + area_light_pdf(light, x, yh, sth)))
    out[k] = total / float(count)




def shade_local_light(points, normals, albedo, light: AreaLight | LinearLight | VolumeLight, **options) -> np.ndarray:
    """Direct lighting from an area, linear or volume light at surface points (Ritschel 2007 Sec. 4.2, 5), one pass
    of :func:`~warpscatter.csm.direct_lighting.shade_direct` (arguments and errors; ``csm``: the light's cube CSM or
    a lat-long CSM), checking the light's type first."""
    if not isinstance(light, (AreaLight, LinearLight, VolumeLight)):
        raise ValueError(f"light must be an AreaLight, LinearLight or VolumeLight, got {type(light).__name__}")
    return shade_direct(points, normals, albedo, light, **options)


def check_light_csm(csm, light) -> None:
    """Raises ValueError unless ``csm`` is a cube CSM whose sample points lie on ``light`` as
    ``light.sample_points(n1, n2)`` places them (so light parameters (s, t) select the right samples)."""
    if not isinstance(csm, CoherentShadowMap) or csm.kind != KIND_CUBE:
        raise ValueError("csm must be a cube CoherentShadowMap of the light (build_cube_csm)")
    want = light.sample_points(csm.n1, csm.n2).reshape(-1, 3)
    got = np.asarray(csm.light_samples, np.float64).reshape(-1, 3)
    scale = max(float(np.abs(want).max()), 1.0)
    if got.shape != want.shape or np.abs(got - want).max() > 1e-5 * scale:
        raise ValueError(f"the CSM's {csm.n1} x {csm.n2} light samples do not lie on this light (built for another "
                         f"light or placement)")


__all__ = ["check_light_csm", "local_visibility", "shade_local_light", "shade_local_light_kernel"]
