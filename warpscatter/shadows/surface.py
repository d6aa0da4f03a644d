"""Surface shadows: V_shadow(x) (RGB) per pixel for every ``render.shadows`` method: ``pcf``, ``msm`` (Peters et al.
2017 Sec. 2-3), ``msm_soft`` (Sec. 4), ``pcss``, the baselines ``msm2015``, ``vsm``, ``evsm`` (:mod:`.filterable`) or
``none``. :func:`prepare_shadows` builds :class:`SurfaceShadows`; :func:`surface_visibility` is the public look-up.
"""

from __future__ import annotations

import warp as wp

from ..runtime.device import default_device, module_options
from ..runtime.stages import StageTimer
from . import msm, soft
from .settings import ShadowsSettings
from .shadow_map import ShadowMapParams, TranslucentShadowDepths, shadow_pcf_surface

module_options()

#: ``SurfaceShadows.mode``: the shadow methods as kernels know them.
SHADOW_NONE = wp.constant(0)
SHADOW_PCF = wp.constant(1)
SHADOW_MSM = wp.constant(2)
SHADOW_MSM_SOFT = wp.constant(3)
SHADOW_PCSS = wp.constant(4)
#: ``render.shadows.method`` -> mode.
SHADOW_MODES = {"none": SHADOW_NONE, "pcf": SHADOW_PCF, "msm": SHADOW_MSM, "msm_soft": SHADOW_MSM_SOFT,
                "pcss": SHADOW_PCSS, "msm2015": SHADOW_MSM, "vsm": SHADOW_MSM, "evsm": SHADOW_MSM}


@wp.struct
class SurfaceShadows:
    """The arrays and parameters of the selected shadow method (1x1 placeholders for the others)."""

    mode: int
    sm: ShadowMapParams
    sm_depth: wp.array2d(dtype=wp.float32)
    sm_translucent: int  # pcf: 1 to read sm_layers
    sm_layers: TranslucentShadowDepths
    sm_bias: float  # scene units
    filter_px: int  # texels
    contact: int  # 1: every receiver casts: contact PCF on the map's silhouette
    msm: msm.MomentShadowParams
    msm_texels: wp.array3d(dtype=wp.vec4)
    msm_mips: wp.array2d(dtype=wp.vec4)
    soft: soft.SoftShadowParams
    sat: wp.array3d(dtype=wp.vec4ui)


@wp.func
def surface_visibility(sh: SurfaceShadows, x: wp.vec3, n: wp.vec3, dx: wp.vec3, dy: wp.vec3) -> wp.vec3:
    """RGB light visibility of surface point x (camera-facing normal n, pixel footprint dx, dy on its tangent plane)."""
    if sh.mode == SHADOW_PCF:
        # normal offset of one texel keeps lit surfaces out of their own shadow
        if sh.sm_translucent != 0:
            return wp.vec3(shadow_pcf_surface(sh.sm, sh.sm_layers, x, n, sh.sm.texel_world, sh.sm_bias,
                                              sh.filter_px, sh.contact))
        return wp.vec3(shadow_pcf_surface(sh.sm, sh.sm_depth, x, n, sh.sm.texel_world, sh.sm_bias, sh.filter_px,
                                          sh.contact))
    if sh.mode == SHADOW_MSM:
        return msm.msm_visibility_rgb_footprint(sh.msm, sh.msm_texels, sh.msm_mips, x, n, dx, dy)
    if sh.mode == SHADOW_MSM_SOFT:
        return soft.moment_soft_visibility_rgb(sh.soft, sh.sat, x, n)
    if sh.mode == SHADOW_PCSS:
        return wp.vec3(soft.pcss_visibility(sh.soft, sh.sm_depth, x, n))
    return wp.vec3(1.0, 1.0, 1.0)


def no_shadows(device=None) -> SurfaceShadows:
    """:class:`SurfaceShadows` of ``none`` (V = 1)."""
    return prepare_shadows(None, None, ShadowsSettings(method="none"), device=device)[0]


def prepare_shadows(scene, shadow_map, settings: ShadowsSettings, *, bias_texels: float = 1.0,
                    timer: StageTimer | None = None, device=None) -> tuple[SurfaceShadows, dict]:
    """Build what the selected shadow method reads per pixel.

    Args:
        scene: the :class:`~warpscatter.scene.Scene` (its casters and materials feed the moment maps).
        shadow_map: the light's :class:`~warpscatter.shadows.shadow_map.ShadowMap` (None: no shadows).
        settings: :class:`~warpscatter.shadows.settings.ShadowsSettings` (``render.shadows``).
        bias_texels: depth bias in texel sizes (``render.scattering.shadow_map.bias``).
        timer: the :class:`~..runtime.stages.StageTimer`.
        device: Warp device.

    Returns:
        (SurfaceShadows, info dict of statistics).
    """
    device = default_device(device)
    mode = SHADOW_MODES[settings.method] if shadow_map is not None else SHADOW_NONE
    sh = SurfaceShadows()
    sh.mode = mode
    if shadow_map is not None:
        sh.sm, sh.sm_depth = shadow_map.params(), shadow_map.device_depth(device)
        bias = bias_texels * shadow_map.texel_world
    else:
        sh.sm, sh.sm_depth, bias = ShadowMapParams(), wp.zeros((1, 1), dtype=wp.float32, device=device), 0.0
        sh.sm.width = sh.sm.height = 1
    sh.sm_translucent = int(shadow_map is not None and shadow_map.translucent and mode == SHADOW_PCF)
    if sh.sm_translucent:
        sh.sm_layers = shadow_map.device_layers(sh.sm_depth, device)
    else:
        sh.sm_layers = TranslucentShadowDepths()
        sh.sm_layers.depth = sh.sm_layers.opaque = sh.sm_layers.transmittance = sh.sm_depth
    sh.sm_bias = float(bias)
    sh.filter_px = int(settings.filter_px)
    # with receiver_only materials an empty texel may be lit ground, not an outline
    sh.contact = int(scene is not None and bool(scene.caster_mask().all()))
    sh.msm = msm.MomentShadowParams()
    sh.msm_texels = wp.zeros((1, 1, 1), dtype=wp.vec4, device=device)
    sh.msm_mips = wp.zeros((1, 1), dtype=wp.vec4, device=device)
    sh.soft = soft.SoftShadowParams()
    sh.sat = wp.zeros((1, 1, 1), dtype=wp.vec4ui, device=device)
    info = {"shadows": settings.method if mode else "none"}
    size = {"light_size": settings.light_size} if shadow_map is not None and shadow_map.perspective else {
        "light_angle_deg": settings.light_angle_deg}
    if mode == SHADOW_MSM:
        m = msm.render_moment_shadow_map(scene, shadow_map, supersampling=settings.supersampling, bits=settings.storage,
                                         filter_px=settings.filter_px, coloured=settings.coloured,
                                         max_translucent_layers=settings.max_translucent_layers,
                                         mipmap=settings.sampling == "mipmap", method=settings.method,
                                         evsm_exponents=settings.evsm_exponents, timer=timer, device=device)
        sh.msm, sh.msm_texels, sh.msm_mips = m.params(depth_bias=bias), m.texels, m.mip_arrays(device)
        info.update(msm_bits=m.bits, msm_bytes=m.nbytes, translucent_layers=m.translucent_layers,
                    msm_sampling=settings.sampling)
        if settings.method == "evsm":
            info["evsm_exponents"] = list(m.exponents)
    elif mode == SHADOW_MSM_SOFT:
        table = soft.render_soft_shadow_map(scene, shadow_map, supersampling=settings.supersampling,
                                            max_kernel_px=settings.max_kernel_px, coloured=settings.coloured,
                                            max_translucent_layers=settings.max_translucent_layers, timer=timer,
                                            device=device)
        sh.soft, sh.sat = table.params(depth_bias=bias, **size), table.table
        info.update(sat_bytes=table.nbytes, translucent_layers=table.msm.translucent_layers)
    elif mode == SHADOW_PCSS:
        sh.soft = soft.soft_shadow_params(shadow_map, max_kernel_px=settings.max_kernel_px, depth_bias=bias, **size)
    return sh, info


__all__ = [
    "SHADOW_MODES",
    "SHADOW_MSM",
    "SHADOW_MSM_SOFT",
    "SHADOW_NONE",
    "SHADOW_PCF",
    "SHADOW_PCSS",
    "SurfaceShadows",
    "no_shadows",
    "prepare_shadows",
    "surface_visibility",
]
