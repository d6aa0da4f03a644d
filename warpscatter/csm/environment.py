"""Monte-Carlo direct lighting from an environment map with coherent-shadow-map visibility (Ritschel 2007, Sec. 5).

Solves the direct lighting equation of Sec. 5,

    L(x, wo) = integral over the sphere of f_r(x, wo, wi) L_in(wi) V(x, wi) max(cos theta_i, 0) dwi,

for surface points (a G-buffer: positions, normals, materials) lit by a distant lat-long environment map
(:class:`~warpscatter.scene.environment_map.EnvironmentMap`, importance-sampled by inverse CDFs P_L^-1):

- BRDFs (Sec. 5.1, P_f^-1), in :mod:`.brdf`: Lambert, normalized Phong and Lafortune lobes, importance sampled
  with the diffuse / lobe choice by Russian roulette (:class:`~warpscatter.csm.brdf.MaterialTable`).
- Estimator: per point S = s^2 strata of a jittered s x s grid (a per-point random pattern, Sec. 5.1 "Random
  Numbers"); each stratum draws one environment sample and one BRDF sample, combined with multiple importance
  sampling (balance heuristic [VG95]): each sample contributes f L V cos / (p_env + p_brdf).
- Visibility (:mod:`.direct_lighting`): a lat-long CSM (points in its object space, Sec. 3.3 / 4.1), a
  ``wp.Mesh`` shadow ray (the reference), or none. Both samples of a stratum use the same directions whatever the
  visibility source, so ``csm`` and ``raytrace`` images differ by the visibility query alone.

Radiance units follow the environment map (its texels are radiance L_in).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..scene.environment_map import EnvData, EnvironmentMap, env_lookup_uv, env_pdf_uv, env_sample_uv
from ..wpinit import module_options
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
    """V(p, d) in [0, 1] towards a distant direction ``d`` with lat-long parameters ``uv`` (= latlong_param(d), which
    the caller already has): the lat-long CSM query of p + eps n (Sec. 3.3; ``xi`` uniform in [0, 1)^4 for the
    roulette filter) for VIS_CSM, a shadow ray from p + eps n for VIS_MESH, else 1.

    Inlined into its callers (as every per-sample function of the estimators): the visibility struct holds a dozen
    arrays, which an out-of-line call would copy twice per sample on the CPU."""
    if vis.mode == VIS_CSM:
        return csm_visibility_filtered_uv(vis.latlong, p + vis.eps * n, uv, vis.bias, vis.filter_mode, xi)
    if vis.mode == VIS_OBJECTS:
        return objects_visibility(vis, p + vis.eps * n, d, xi)
    if vis.mode == VIS_MESH:
        if shadow_ray_blocked(vis.mesh, p + vis.eps * n, d, 1.0e30):
            return 0.0
    return 1.0


# ---- kernels ---------------------------------------------------------------------------------------


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

    The material's per-point part (frame, lobe axes and weights) is computed once per point (:func:`shading_point`).
    The lat-long CSM is queried with lat-long parameters the estimator already has: an environment sample's own
    (u, v) (its direction is env_direction(u, v); recomputing them from the direction would only add an atan2, an
    acos and their rounding), a BRDF sample's latlong_param, which also serves its map look-up and density."""
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


# ---- host side -------------------------------------------------------------------------------------


def shade_environment(points, normals, albedo, env: EnvironmentMap, **options) -> np.ndarray:
    """Direct lighting from an environment map at surface points (Ritschel 2007 Sec. 5), one Monte-Carlo pass:
    :func:`~warpscatter.csm.direct_lighting.shade_direct` with ``env`` (each stratum draws one environment and one
    BRDF sample, 2 S directions combined by the balance heuristic; ``csm`` must be a lat-long CSM).

    Raises:
        ValueError: ``env`` is not an :class:`~warpscatter.scene.environment_map.EnvironmentMap`, or as
            :func:`~warpscatter.csm.direct_lighting.shade_direct`.
    """
    if not isinstance(env, EnvironmentMap):
        raise ValueError(f"env must be an EnvironmentMap, got {type(env).__name__}")
    return shade_direct(points, normals, albedo, env, **options)


__all__ = ["distant_visibility_uv", "shade_environment", "shade_environment_kernel"]
