"""The method registry: every render method is one :class:`Method` record.

A record names the method, the paper it implements, the light types it renders, the settings it reads, what
the pipeline must build for it (a BVH for exact visibility, the light's shadow map, a ray-cast G-buffer), the
Warp modules it launches (compiled in the ``compile`` stage) and its entry point. Config validation takes the
method choices and the light rules from here, the pipeline looks the method up here (no method names in the
pipeline), and the README's method tables are checked against it.

Entry points (loaded on first use, so this module and config validation stay Warp-free):

* scattering methods: ``render(frame, settings, stage) -> (l_scat, info)`` with a
  :class:`~warpscatter.pipeline.frame.Frame` (scene, G-buffer, shadow map, BVH), the
  :class:`~warpscatter.scattering.settings.ScatteringSettings` and a :class:`~warpscatter.stages.StageTimer`;
  ``l_scat`` is an (H, W) ``wp.vec3`` array of in-scattered radiance, ``info`` a dict of statistics.
* lighting methods: ``render(scene, settings, stage, on_pass) -> (images, stats)`` with the
  :class:`~warpscatter.csm.settings.LightingSettings` (:mod:`warpscatter.pipeline.lighting`).

Adding a scattering method: its module (with ``render``), its settings model (a section of
``scattering/settings.py``), one record below, its test and its README section.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Callable

#: Light types of the classic pipeline (``render.scattering``) and of the Monte-Carlo lighting methods.
CLASSIC_LIGHTS = ("directional", "spot", "point")
MONTE_CARLO_LIGHTS = ("environment", "area", "linear", "volume")

#: Visibility sources a method can use.
VISIBILITY_CONFIGURABLE = "configurable"  # render.scattering.visibility: exact (BVH) or shadow_map
VISIBILITY_SHADOW_MAP = "shadow_map"  # always the light's shadow map
VISIBILITY_CSM = "csm"  # a coherent shadow map of the occluders
VISIBILITY_RAYS = "rays"  # wp.Mesh shadow rays


@dataclass(frozen=True)
class Method:
    """One render method.

    Attributes:
        name: the value of ``render.scattering.method`` / ``render.lighting.method``.
        kind: ``scattering`` (the classic pipeline) or ``lighting`` (Monte-Carlo direct lighting).
        paper: what it implements.
        summary: one line for listings.
        lights: the ``light.type`` values it renders.
        sections: the keys of its section (``render.scattering.<key>``) it reads besides the shared ones.
        visibility: one of the ``VISIBILITY_*`` constants.
        reference_gbuffer: with exact visibility, ray-cast the camera G-buffer too (the reference).
        modules: the Warp modules it launches.
        entry: ``"package.module:function"`` of its render function.
        debug_aovs: the debug outputs (:data:`warpscatter.config.DEBUG_AOVS`) it makes when the frame asks
            (:attr:`~warpscatter.pipeline.frame.Frame.aovs`), returned in ``info["debug_images"]``.
    """

    name: str
    kind: str
    paper: str
    summary: str
    lights: tuple[str, ...]
    sections: tuple[str, ...] = ()
    visibility: str = VISIBILITY_SHADOW_MAP
    reference_gbuffer: bool = False
    modules: tuple[str, ...] = ()
    entry: str = ""
    debug_aovs: tuple[str, ...] = ()

    def marches_exact(self, visibility: str) -> bool:
        """True when this method casts exact shadow rays for ``render.scattering.visibility``."""
        return self.visibility == VISIBILITY_CONFIGURABLE and visibility == "exact"

    def load(self) -> Callable:
        """The render function (imports its module, and Warp)."""
        module, _, name = self.entry.partition(":")
        return getattr(importlib.import_module(module), name)


_PREFILTERED_MODULES = ("warpscatter.scattering.rectify_nonlinear", "warpscatter.scattering.rectify_local",
                        "warpscatter.scattering.rectify_projective",
                        "warpscatter.scattering.prefix_sums", "warpscatter.scattering.filtered_lookups",
                        "warpscatter.scattering.caster_culling", "warpscatter.scattering.epipole_fallback",
                        "warpscatter.scattering.prefiltered", "warpscatter.scattering.prefiltered_spot")
_PREFILTERED_AOVS = ("rectified", "epipole_mask", "rectified_map", "mip_level", "evaluated_pixels")
_LIGHTING_MODULES = ("warpscatter.csm.brdf", "warpscatter.csm.compress", "warpscatter.csm.depthmaps",
                     "warpscatter.csm.query", "warpscatter.csm.environment", "warpscatter.csm.local_lights")

SCATTERING: dict[str, Method] = {m.name: m for m in (
    Method("raymarch", "scattering", "reference single scattering (CONVENTIONS integral)",
           "per-pixel ray marching; exact (ray-cast) visibility is the reference of every fast method",
           CLASSIC_LIGHTS, visibility=VISIBILITY_CONFIGURABLE, reference_gbuffer=True,
           modules=("warpscatter.scattering.raymarch",), entry="warpscatter.scattering.raymarch:render"),
    Method("fourier", "scattering", "Klehm et al. 2014, prefiltered single scattering",
           "rectified shadow map, Fourier basis, transmittance-weighted per-row prefix sums",
           CLASSIC_LIGHTS, sections=("prefiltered", "fourier"), modules=_PREFILTERED_MODULES,
           entry="warpscatter.scattering.prefiltered:render", debug_aovs=_PREFILTERED_AOVS),
    Method("moments4", "scattering", "Peters et al. 2017 Sec. 5, prefiltered single scattering with moments",
           "the prefiltered pipeline with 4 moments and Algorithm 1", CLASSIC_LIGHTS,
           sections=("prefiltered", "moments"), modules=_PREFILTERED_MODULES,
           entry="warpscatter.scattering.prefiltered:render", debug_aovs=_PREFILTERED_AOVS),
    Method("moments6", "scattering", "Peters et al. 2017 Sec. 5, prefiltered single scattering with moments",
           "the prefiltered pipeline with 6 moments and Algorithm 1", CLASSIC_LIGHTS,
           sections=("prefiltered", "moments"), modules=_PREFILTERED_MODULES,
           entry="warpscatter.scattering.prefiltered:render", debug_aovs=_PREFILTERED_AOVS),
    Method("epipolar", "scattering", "Engelhardt & Dachsbacher 2010, epipolar sampling",
           "ray marching at a few percent of the pixels on epipolar lines, bilateral upsampling", CLASSIC_LIGHTS,
           sections=("epipolar",), visibility=VISIBILITY_CONFIGURABLE,
           modules=("warpscatter.scattering.epipolar_textures", "warpscatter.scattering.epipolar_upsampling",
                    "warpscatter.scattering.epipolar"), entry="warpscatter.scattering.epipolar:render",
           debug_aovs=("epipolar_samples",)),
)}

LIGHTING: dict[str, Method] = {m.name: m for m in (
    Method("csm", "lighting", "Ritschel et al. 2007, coherent shadow maps",
           "Monte-Carlo direct lighting with coherent-shadow-map visibility", MONTE_CARLO_LIGHTS, sections=("csm",),
           visibility=VISIBILITY_CSM, modules=_LIGHTING_MODULES,
           entry="warpscatter.pipeline.lighting:render_lighting"),
    Method("raytrace", "lighting", "the reference of csm",
           "the same estimator with wp.Mesh shadow rays", MONTE_CARLO_LIGHTS, visibility=VISIBILITY_RAYS,
           modules=_LIGHTING_MODULES, entry="warpscatter.pipeline.lighting:render_lighting"),
)}

#: Warp modules every classic render launches (rasterizer, G-buffer, surface shadows and shading).
CLASSIC_MODULES = ("warpscatter.raster", "warpscatter.gbuffer", "warpscatter.shadows.msm", "warpscatter.shadows.soft",
                   "warpscatter.shadows.unseen_planes", "warpscatter.shading")
#: Warp modules every lighting render launches besides the method's.
LIGHTING_BASE_MODULES = ("warpscatter.raster", "warpscatter.gbuffer")


def get(kind: str, name: str) -> Method:
    """The record of method ``name`` of ``kind`` (``scattering`` or ``lighting``).

    Raises:
        ValueError: an unknown method, naming the choices.
    """
    table = SCATTERING if kind == "scattering" else LIGHTING
    if name not in table:
        raise ValueError(f"render.{kind}.method: unknown method {name!r} (choose from {', '.join(table)})")
    return table[name]


__all__ = [
    "CLASSIC_LIGHTS",
    "CLASSIC_MODULES",
    "LIGHTING",
    "LIGHTING_BASE_MODULES",
    "MONTE_CARLO_LIGHTS",
    "Method",
    "SCATTERING",
    "get",
]
