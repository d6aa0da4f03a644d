"""Monte-Carlo direct lighting from an environment map with coherent-shadow-map visibility (Ritschel 2007, Sec. 5).

Solves L(x, wo) = integral of f_r(x, wo, wi) L_in(wi) V(x, wi) max(cos theta_i, 0) dwi for surface points lit by an
importance-sampled lat-long environment map (P_L^-1; radiance units follow the map). Per point S = s^2 jittered
strata (Sec. 5.1), each drawing one environment and one BRDF sample (:mod:`.brdf`), combined by the balance
heuristic [VG95]: f L V cos / (p_env + p_brdf). Both samples use the same directions whatever the visibility source,
so ``csm`` and ``raytrace`` images differ by the visibility query alone.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..runtime.device import module_options
from ..scene.environment_map import EnvData, EnvironmentMap, env_lookup_uv, env_pdf_uv, env_sample_uv
from .brdf import MaterialData, shading_eval, shading_pdf, shading_point, shading_sample
from .depthmaps import latlong_param
from .direct_lighting import (
    VIS_CSM,
    VIS_MESH,
    VIS_OBJECTS,
    LightVisibility,
    SurfacePoints,
    objects_visibility,
    shade_direct,
    shadow_ray_blocked,
    stratum_random_numbers,
    stratum_sample,
    surface_point,
)
from .query import csm_visibility_filtered_uv

module_options()


@wp.func(inline=True)
def distant_visibility_uv(vis: LightVisibility, p: wp.vec3, n: wp.vec3, d: wp.vec3, uv: wp.vec2,
                          xi: wp.vec4) -> float:
    """V(p, d) in [0, 1] towards distant direction ``d`` with lat-long parameters ``uv``: the CSM query of p + eps n
    (VIS_CSM), a shadow ray (VIS_MESH), else 1. Inlined: the visibility struct holds a dozen arrays."""
    if vis.mode == VIS_CSM:
        return csm_visibility_filtered_uv(vis.latlong, p + vis.eps * n, uv, vis.bias, vis.filter_mode, xi)
    if vis.mode == VIS_OBJECTS:
        return objects_visibility(vis, p + vis.eps * n, d, xi)
    if vis.mode == VIS_MESH:
        if shadow_ray_blocked(vis.mesh, p + vis.eps * n, d, 1.0e30):
            return 0.0
    return 1.0




@wp.kernel
def shade_environment_kernel(
    surf: SurfacePoints,
    mat: MaterialData,
    env: EnvData,
    strata: int,
    vis: LightVisibility,
    seed: int,
    out: wp.array(dtype=wp.vec3),
    offset: int,
):
    """out[k] = one stratified MIS estimate (s^2 strata) of the reflected radiance of point k towards view_dirs[k].
    The CSM is queried with the (u, v) the estimator already has (saves an atan2 and an acos per sample)."""
    k = wp.tid() + offset
    rng = wp.rand_init(seed, k)  # a different pattern per point and per pass (seed)
    p, n, wo, m = surface_point(surf, k)
    sp = shading_point(mat, m, n, wo)
    total = wp.vec3(0.0)
    count = strata * strata
    for s in range(count):
        j_env, j_brdf, choice, xi_env, xi_brdf, rng = stratum_random_numbers(rng)
        # ---- environment sample (P_L^-1), balance heuristic: f L V cos / (p_env + p_brdf) ----
        d, radiance, pe, uv = env_sample_uv(env, stratum_sample(s, strata, j_env))
        c = wp.dot(n, d)
        if pe > 0.0 and c > 0.0:
            f = shading_eval(sp, d)
            if wp.length_sq(f) > 0.0 and wp.length_sq(radiance) > 0.0:
                v = distant_visibility_uv(vis, p, n, d, uv, xi_env)
                total += wp.cw_mul(f, radiance) * (v * c / (pe + shading_pdf(sp, d)))
        # ---- BRDF sample (P_f^-1 with the diffuse / lobe roulette) ----
        wi = shading_sample(sp, stratum_sample(s, strata, j_brdf), choice)
        c = wp.dot(n, wi)
        if c > 0.0:
            pb = shading_pdf(sp, wi)
            if pb > 0.0:
                f = shading_eval(sp, wi)
                uv = latlong_param(wi)
                radiance = env_lookup_uv(env, uv)
                if wp.length_sq(f) > 0.0 and wp.length_sq(radiance) > 0.0:
                    v = distant_visibility_uv(vis, p, n, wi, uv, xi_brdf)
                    total += wp.cw_mul(f, radiance) * (v * c / (pb + env_pdf_uv(env, wi, uv)))
    out[k] = total / float(count)




def shade_environment(points, normals, albedo, env: EnvironmentMap, **options) -> np.ndarray:
    """Direct lighting from an environment map at surface points (Ritschel 2007 Sec. 5), one pass of
    :func:`~warpscatter.csm.direct_lighting.shade_direct` (arguments and errors; ``csm`` must be lat-long), checking
    that ``env`` is an :class:`~warpscatter.scene.environment_map.EnvironmentMap` first."""
    if not isinstance(env, EnvironmentMap):
        raise ValueError(f"env must be an EnvironmentMap, got {type(env).__name__}")
    return shade_direct(points, normals, albedo, env, **options)


__all__ = ["distant_visibility_uv", "shade_environment", "shade_environment_kernel"]
