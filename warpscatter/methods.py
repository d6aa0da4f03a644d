"""The method registry: every render method is one :class:`Method` record, its entry point loaded on first use (so
validation stays Warp-free). Scattering methods: ``render(frame, settings, stage) -> (l_scat, info)``, ``l_scat`` an
(H, W) ``wp.vec3`` array; lighting methods: ``render(scene, settings, stage, on_pass) -> (images, stats)``. A new
method: its module, its settings section, a record here (with a ``validate`` hook), a test and a README section.
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass
from typing import Any, Callable

#: Light types of the classic pipeline (``render.scattering``) and of the Monte-Carlo lighting methods.
CLASSIC_LIGHTS = ("directional", "spot", "point")
MONTE_CARLO_LIGHTS = ("environment", "area", "linear", "volume")

#: Visibility sources a method can use.
VISIBILITY_CONFIGURABLE = "configurable"  # render.scattering.visibility: exact (BVH) or shadow_map
VISIBILITY_SHADOW_MAP = "shadow_map"  # always the light's shadow map
VISIBILITY_CSM = "csm"  # a coherent shadow map of the occluders
VISIBILITY_RAYS = "rays"  # wp.Mesh shadow rays


def _no_rules(config: Any) -> list[str]:
    return []


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
        debug_aovs: the debug outputs it makes when asked, returned in ``info["debug_images"]``.
        validate: the method's own rules: ``validate(config) -> problems`` (``key.path: reason`` lines).
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
    validate: Callable[[Any], list[str]] = _no_rules

    def marches_exact(self, visibility: str) -> bool:
        """True when this method casts exact shadow rays for ``render.scattering.visibility``."""
        return self.visibility == VISIBILITY_CONFIGURABLE and visibility == "exact"

    def load(self) -> Callable:
        """The render function (imports its module, and Warp)."""
        module, _, name = self.entry.partition(":")
        return getattr(importlib.import_module(module), name)




def _prefiltered_rules(config: Any) -> list[str]:
    """What the prefiltered methods cannot do under a spot or point light (a point light is six spots)."""
    if config.light.type not in ("spot", "point"):
        return []
    s = config.render.scattering
    problems = []
    if s.prefiltered.rectification == "projective":
        problems.append("render.scattering.prefiltered.rectification: 'projective' needs a directional light; a "
                        "spot light uses the non-linear rectification (auto or nonlinear)")
    if s.prefiltered.splits > 1:
        problems.append("render.scattering.prefiltered.splits: a spot light's look-ups need whole rows (1)")
    if s.method != "fourier" and s.moments.overestimation == "adaptive":
        problems.append("render.scattering.moments.overestimation: 'adaptive' weighs a directional light's "
                        "direction (Peters 2017 Sec. 5.3.1); give a number for a spot light")
    camera = config.camera.position
    if math.dist(camera, config.light.position) <= 1e-6 * max(1.0, math.hypot(*camera)):
        problems.append(f"light.position: the light sits at the camera position, where render.scattering.method "
                        f"{s.method!r} has no epipolar planes (move it, or use raymarch or epipolar)")
    return problems


def _epipolar_rules(config: Any) -> list[str]:
    """Epipolar lines run between two border points: an image of at least 2 x 2 pixels."""
    cam = config.camera
    if min(cam.width, cam.height) >= 2:
        return []
    return [f"camera.width / camera.height: render.scattering.method 'epipolar' needs an image of at least 2x2 "
            f"pixels (its lines run between two border points), got {cam.width}x{cam.height}"]


def _csm_objects_rules(config: Any) -> list[str]:
    """``render.lighting.csm.objects: per_mesh`` (one CSM per mesh) against a whole scene's CSM file and cube maps."""
    csm = config.render.lighting.csm
    if csm.objects != "per_mesh":
        return []
    problems = []
    if csm.file is not None:
        problems.append("render.lighting.csm.objects: per_mesh builds one CSM per mesh; a precomputed "
                        "render.lighting.csm.file holds the whole scene's (remove one of them)")
    if config.light.type in ("area", "linear") and csm.local_lights == "cube":
        problems.append("render.lighting.csm.objects: per_mesh needs render.lighting.csm.local_lights: "
                        "semi_local for an area or linear light (cube maps sit at the light's points in "
                        "world space, which a moving mesh would invalidate)")
    return problems


def _csm_rules(config: Any) -> list[str]:
    """A CSM needs an occluder (unless it is read from a file), and the per-mesh rules."""
    no_caster = config.scene.no_caster()
    problems = []
    if config.light.type in MONTE_CARLO_LIGHTS and no_caster and config.render.lighting.csm.file is None:
        problems.append(f"render.lighting: {no_caster}, so there is no occluder to build a CSM of")
    return problems + _csm_objects_rules(config)


_PREFILTERED_MODULES = ("warpscatter.scattering.rectify.nonlinear", "warpscatter.scattering.rectify.local",
                        "warpscatter.scattering.rectify.projective",
                        "warpscatter.scattering.prefiltered.prefix_sums",
                        "warpscatter.scattering.prefiltered.filtered_lookups",
                        "warpscatter.scattering.rectify.caster_culling",
                        "warpscatter.scattering.prefiltered.epipole_regions",
                        "warpscatter.scattering.prefiltered.evaluate",
                        "warpscatter.scattering.prefiltered.spot_lookups")
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
           entry="warpscatter.scattering.prefiltered:render", debug_aovs=_PREFILTERED_AOVS,
           validate=_prefiltered_rules),
    Method("moments4", "scattering", "Peters et al. 2017 Sec. 5, prefiltered single scattering with moments",
           "the prefiltered pipeline with 4 moments and Algorithm 1", CLASSIC_LIGHTS,
           sections=("prefiltered", "moments"), modules=_PREFILTERED_MODULES,
           entry="warpscatter.scattering.prefiltered:render", debug_aovs=_PREFILTERED_AOVS,
           validate=_prefiltered_rules),
    Method("moments6", "scattering", "Peters et al. 2017 Sec. 5, prefiltered single scattering with moments",
           "the prefiltered pipeline with 6 moments and Algorithm 1", CLASSIC_LIGHTS,
           sections=("prefiltered", "moments"), modules=_PREFILTERED_MODULES,
           entry="warpscatter.scattering.prefiltered:render", debug_aovs=_PREFILTERED_AOVS,
           validate=_prefiltered_rules),
    Method("epipolar", "scattering", "Engelhardt & Dachsbacher 2010, epipolar sampling",
           "ray marching at a few percent of the pixels on epipolar lines, bilateral upsampling", CLASSIC_LIGHTS,
           sections=("epipolar",), visibility=VISIBILITY_CONFIGURABLE,
           modules=("warpscatter.scattering.epipolar.textures", "warpscatter.scattering.epipolar.upsampling",
                    "warpscatter.scattering.epipolar.method"), entry="warpscatter.scattering.epipolar.method:render",
           debug_aovs=("epipolar_samples",), validate=_epipolar_rules),
)}

LIGHTING: dict[str, Method] = {m.name: m for m in (
    Method("csm", "lighting", "Ritschel et al. 2007, coherent shadow maps",
           "Monte-Carlo direct lighting with coherent-shadow-map visibility", MONTE_CARLO_LIGHTS, sections=("csm",),
           visibility=VISIBILITY_CSM, modules=_LIGHTING_MODULES,
           entry="warpscatter.pipeline.lighting:render_lighting", validate=_csm_rules),
    Method("raytrace", "lighting", "the reference of csm",
           "the same estimator with wp.Mesh shadow rays", MONTE_CARLO_LIGHTS, visibility=VISIBILITY_RAYS,
           modules=_LIGHTING_MODULES, entry="warpscatter.pipeline.lighting:render_lighting",
           validate=_csm_objects_rules),
)}

#: Warp modules every classic render launches (rasterizer, G-buffer, surface shadows and shading).
CLASSIC_MODULES = ("warpscatter.raster.rasterizer", "warpscatter.raster.gbuffer", "warpscatter.shadows.msm",
                   "warpscatter.shadows.soft", "warpscatter.shadows.unseen_planes", "warpscatter.shading")
#: Warp modules every lighting render launches besides the method's.
LIGHTING_BASE_MODULES = ("warpscatter.raster.rasterizer", "warpscatter.raster.gbuffer")


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
