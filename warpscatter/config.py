"""Typed pipeline configuration: YAML loading, ``--set`` overrides, validation and clear errors.

A config file (schema in ``docs/conventions.md`` and the README) is read with PyYAML, patched with
``KEY=VALUE`` overrides (``camera.fov_y=40``, ``scene.meshes.0.material.opacity=0.5``), and
validated by the pydantic v2 models below. Every model forbids unknown keys. Relative paths (mesh
files, spot-light textures, ``output.dir``) are resolved against the config file's folder into
absolute :class:`pathlib.Path` objects, and input files must exist.

Every problem is reported at once, as ``key.path: reason`` lines in a :class:`ConfigError`, e.g.::

    light.direction: must be non-zero (line 12)
    camera: near (5.0) must be < far (1.0) (line 7)
    scene.meshes.0.colour: unknown key (did you mean 'material'?) (line 4)

This module does not import Warp: validating a config is fast.
"""


from __future__ import annotations

import copy
import inspect
import math
import re
import string
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Annotated, Any, Literal, Optional, Union

import yaml
from pydantic import (
    BeforeValidator,
    Field,
    PrivateAttr,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from . import methods
from .animation import AnimationSettings, frame_name
from .csm.settings import LightingSettings
from .errors import ConfigError
from .scattering.settings import ScatteringSettings
from .schema import (
    MAX_COORD,
    MAX_DEPTH_RATIO,
    MAX_EMISSION,
    MAX_FOV_Y_DEG,
    MAX_GAIN,
    MAX_HG_G,
    MAX_IMAGE_SIDE,
    MAX_SCALE,
    MAX_SIGMA_T,
    MIN_CONE_DEG,
    MIN_FOV_DEG,
    MIN_LENGTH,
    MIN_SCALE,
    RGB,
    Albedo,
    Bool,
    Direction,
    Float,
    Int,
    NonZeroVec3,
    PathStr,
    Rotation,
    SettingsModel,
    Vec3,
    bounded_float,
    context_dir,
    did_you_mean,
    dotted,
    existing_file,
    format_validation_errors,
    is_number,
    length,
    resolve_path,
    scalar_or_rgb_type,
    unit,
    vec3,
    vec3_in,
)
from .shadows.settings import ShadowMapSettings, ShadowsSettings

__all__ = [
    "AOV_NAMES",
    "DEBUG_AOVS",
    "STANDARD_AOVS",
    "MESH_SUFFIXES",
    "AreaLightConfig",
    "CameraConfig",
    "Config",
    "ConfigError",
    "DirectionalLightConfig",
    "EnvironmentLightConfig",
    "LafortuneBRDFConfig",
    "LightingSettings",
    "LinearLightConfig",
    "Material",
    "MediumConfig",
    "MeshEntry",
    "OutputConfig",
    "PhaseConfig",
    "PhongBRDFConfig",
    "RenderSettings",
    "ScatteringSettings",
    "SceneConfig",
    "ShadowMapSettings",
    "ShadowsSettings",
    "SpotLightConfig",
    "SurfacesSettings",
    "Transform",
    "apply_overrides",
    "validated_config",
    "load_config",
    "parse_override",
    "read_config_data",
]

#: Image outputs a render writes by default (``output.aovs``); ``color`` is always written.
STANDARD_AOVS = ("color", "scattering", "surface", "depth")
#: Debug outputs (``output.aovs``, not written unless asked) that show why an image looks as it does, each made by
#: the scattering methods that list it (:attr:`warpscatter.methods.Method.debug_aovs`): ``rectified`` the per-pixel
#: rectified look-up coordinates (u, v, z_r), ``epipole_mask`` the weight of the ray-marched epipole region per pixel
#: (1: marched, 0: prefiltered), ``rectified_map`` the rectified depth map and the texels caster culling emptied
#: (map-sized, 2 channels), ``mip_level`` the row mip level each pixel's look-up reads (level + the share of the next;
#: ``prefiltered.mip_levels``); ``evaluated_pixels`` 1 where the prefiltered look-up ran, 0 where the pixel interpolated
#: its grid cell (``prefiltered.evaluate_stride``); ``epipolar_samples`` the ray-march steps taken at each pixel by
#: epipolar's marched samples and directly marched pixels (0: interpolated).
DEBUG_AOVS = ("rectified", "epipole_mask", "rectified_map", "mip_level", "evaluated_pixels", "epipolar_samples")
#: Image outputs a render can write (``output.aovs``).
AOV_NAMES = STANDARD_AOVS + DEBUG_AOVS
#: Mesh file suffixes accepted in ``scene.meshes.N.path`` (loaded with trimesh).
MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")


# ---- scene ---------------------------------------------------------------------------------------


_ScaleFactor = bounded_float(MIN_SCALE, MAX_SCALE)


def _check_scale(v: Any) -> Any:
    """A scale: one number or [x, y, z], each finite and in [MIN_SCALE, MAX_SCALE]."""
    if is_number(v):
        values, out = [float(v)], float(v)
    elif isinstance(v, (list, tuple)):
        out = vec3(v)
        values = list(out)
    else:
        raise ValueError(f"expected a number or a list of 3 numbers, got {v!r}")
    if not all(math.isfinite(x) and x > 0.0 for x in values):
        raise ValueError(f"must be > 0 (and finite), got {v!r}")
    if not all(MIN_SCALE <= x <= MAX_SCALE for x in values):
        raise ValueError(f"must lie in [{MIN_SCALE:g}, {MAX_SCALE:g}], got {v!r}")
    return out


_check_scale.type_text = f"number or [x, y, z], each {MIN_SCALE:g}–{MAX_SCALE:g}"


class Transform(SettingsModel):
    """Mesh placement: scale first, then rotation (X, then Y, then Z, degrees), then translation."""

    translate: Vec3 = Field((0.0, 0.0, 0.0), description="translation (scene units), applied last")
    rotate_deg: Rotation = Field((0.0, 0.0, 0.0), description="rotation about X, then Y, then Z (degrees, about the "
                                                                "mesh origin)")
    scale: Annotated[Union[_ScaleFactor, tuple[_ScaleFactor, _ScaleFactor, _ScaleFactor]],
                     BeforeValidator(_check_scale)] = Field(1.0, description="scale, scalar or per axis, applied first")

    @property
    def scale3(self) -> tuple[float, float, float]:
        """The scale as three per-axis factors."""
        s = self.scale
        return (s, s, s) if isinstance(s, float) else tuple(s)


class PhongBRDFConfig(SettingsModel):
    """Normalized Phong lobe k_s (e + 2) / (2 pi) cos^e(alpha) beside the Lambert term (lighting methods only)."""

    type: Literal["phong"] = Field(description="phong")
    specular: Albedo = Field((0.04, 0.04, 0.04), description="specular reflectance k_s (RGB in [0, 1])")
    exponent: Annotated[Float, Field(ge=0.0, le=1.0e4, description="Phong exponent e")] = 32.0


#: Largest |C_i| of a Lafortune lobe.
MAX_LOBE_COEFFICIENT = 100.0
_LobeCoefficients = vec3_in(-MAX_LOBE_COEFFICIENT, MAX_LOBE_COEFFICIENT,
                            f"[x, y, z], each in [-{MAX_LOBE_COEFFICIENT:g}, {MAX_LOBE_COEFFICIENT:g}]")
_LobeColor = vec3_in(0.0, MAX_GAIN, f"RGB, each 0–{MAX_GAIN:g}", interval=False)


class LafortuneLobeConfig(SettingsModel):
    """One Lafortune lobe color [C_x u_x v_x + C_y u_y v_y + C_z u_z v_z]^exponent (local frame, z = normal)."""

    coefficients: _LobeCoefficients = Field(description="C_x, C_y, C_z (the lobe's peak, the largest abs(C_i) to the "
                                                        f"power exponent, must be <= {MAX_GAIN:g})")
    exponent: Annotated[Float, Field(ge=0.0, le=1.0e4, description="lobe exponent")]
    color: _LobeColor = Field((1.0, 1.0, 1.0), description="lobe RGB weight")

    @model_validator(mode="after")
    def _finite_peak(self) -> LafortuneLobeConfig:
        peak = max(abs(c) for c in self.coefficients)
        if peak > 1.0 and self.exponent * math.log(peak) > math.log(MAX_GAIN):
            raise ValueError(f"the lobe's peak max(abs(C_i))^exponent = {peak:g}^{self.exponent:g} exceeds "
                             f"{MAX_GAIN:g} (lower the coefficients or the exponent)")
        return self


class LafortuneBRDFConfig(SettingsModel):
    """Lafortune BRDF: the Lambert term (``albedo``) plus 1 to 4 generalized cosine lobes (lighting methods only)."""

    type: Literal["lafortune"] = Field(description="lafortune")
    lobes: Annotated[list[LafortuneLobeConfig], Field(min_length=1, max_length=4, description="1 to 4 lobes")]


BRDFConfig = Annotated[Union[PhongBRDFConfig, LafortuneBRDFConfig], Field(discriminator="type")]


class Material(SettingsModel):
    """Surface material: diffuse ``albedo`` (linear RGB in [0, 1]), ``opacity`` in (0, 1] and, for the lighting
    methods (``render.lighting``), an optional glossy ``brdf`` (phong or lafortune) beside the Lambert term."""

    albedo: Albedo = Field((0.5, 0.5, 0.5), description="diffuse (Lambert) albedo, linear RGB in [0, 1]")
    opacity: Annotated[Float, Field(gt=0.0, le=1.0, description="opacity (< 1: a translucent occluder that passes "
                                                                "1 - opacity, in every scattering and surface-shadow "
                                                                "method; below 0.01 it casts nothing)")] = 1.0
    brdf: Optional[BRDFConfig] = Field(None, description="lighting methods only: a glossy phong or lafortune BRDF "
                                                         "beside the Lambert term")

    def brdf_spec(self) -> dict:
        """This material as :meth:`warpscatter.csm.brdf.MaterialTable.from_specs` reads it."""
        spec: dict = {"albedo": self.albedo}
        if isinstance(self.brdf, PhongBRDFConfig):
            spec["phong"] = {"specular": self.brdf.specular, "exponent": self.brdf.exponent}
        elif isinstance(self.brdf, LafortuneBRDFConfig):
            spec["lafortune"] = [lobe.model_dump() for lobe in self.brdf.lobes]
        return spec


class MeshEntry(SettingsModel):
    """One mesh of the scene: a file (``path``) or a procedural generator (``procedural`` + ``params``)."""

    path: PathStr | None = Field(None, description=f"a mesh file ({', '.join(MESH_SUFFIXES)}), relative to the "
                                                   "config file")
    procedural: str | None = Field(None, description="a generator of warpscatter.scene.procedural (ground_plane, "
                                                     "colonnade, fence, canopy, room_window, terrain)")
    params: dict[str, Any] = Field(default_factory=dict, description="the generator's keyword arguments (lengths "
                                   f"within [-{MAX_COORD:g}, {MAX_COORD:g}] scene units; counts as each generator "
                                   "states)")
    transform: Transform = Field(default_factory=dict, description="placement: scale, then rotation, then "
                                                                   "translation")
    material: Material = Field(default_factory=dict, description="surface material")
    receiver_only: Bool = Field(False, description="receives shadows, casts none: left out of every shadow map, BVH "
                                                   "and CSM")

    @field_validator("path")
    @classmethod
    def _check_path(cls, v: Path | None, info: ValidationInfo) -> Path | None:
        if v is None:
            return v
        p = existing_file(resolve_path(v, info))
        if p.suffix.lower() not in MESH_SUFFIXES:
            raise ValueError(f"unsupported mesh format '{p.suffix}' (supported: {', '.join(MESH_SUFFIXES)})")
        return p

    @field_validator("procedural")
    @classmethod
    def _check_generator(cls, v: str | None) -> str | None:
        if v is None:
            return v
        generators = _generators()
        if v not in generators:
            choices = ", ".join(sorted(generators)) or "none available"
            raise ValueError(f"unknown generator {v!r}{did_you_mean(v, generators)} (choose from {choices})")
        return v

    @field_validator("params")
    @classmethod
    def _check_params(cls, v: dict[str, Any], info: ValidationInfo) -> dict[str, Any]:
        if "procedural" not in info.data:  # the generator name itself is already reported as invalid
            return v
        name = info.data["procedural"]
        if name is None:
            if v:
                raise ValueError("only used with 'procedural'")
            return v
        accepted = _generator_parameters(_generators()[name])
        if accepted is not None:
            unknown = sorted(set(v) - set(accepted))
            if unknown:
                hint = did_you_mean(unknown[0], accepted) if len(unknown) == 1 else ""
                raise ValueError(
                    f"unknown parameter(s) {', '.join(repr(u) for u in unknown)} for generator {name!r}{hint} "
                    f"(accepts: {', '.join(accepted) or 'none'})"
                )
        problems = []
        for key in _length_parameters(_generators()[name]):
            if key not in v:
                continue
            values = v[key] if isinstance(v[key], (list, tuple)) else [v[key]]
            bad = [x for x in values if is_number(x) and not (math.isfinite(x) and abs(x) <= MAX_COORD)]
            if bad:
                problems.append(f"parameter {key!r}: each value must be finite and within [-{MAX_COORD:g}, "
                                f"{MAX_COORD:g}] (lengths in scene units), got {v[key]!r}")
        if problems:
            raise ValueError("\n".join(problems))
        return v

    @model_validator(mode="after")
    def _one_source(self) -> MeshEntry:
        if (self.path is None) == (self.procedural is None):
            got = "both" if self.path is not None else "neither"
            raise ValueError(f"give exactly one of 'path' or 'procedural' (got {got})")
        return self


def _generators() -> dict[str, Any]:
    """The procedural generators (imported lazily: the module builds meshes with numpy/trimesh)."""
    try:
        from .scene.procedural import GENERATORS
    except ImportError as exc:
        raise ValueError(f"cannot check procedural generators: {exc}") from None
    return GENERATORS


def _length_parameters(fn: Any) -> dict[str, Any]:
    """A generator's parameters whose defaults are floats or lists of floats (lengths in scene units, bounded by
    MAX_COORD here; the generators check their counts, seeds and lower bounds themselves)."""
    fn = getattr(fn, "__wrapped__", fn)
    try:
        params = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):
        return {}
    out = {}
    for p in params:
        d = p.default
        if isinstance(d, float) or (isinstance(d, (list, tuple)) and d and all(isinstance(x, float) for x in d)):
            out[p.name] = d
    return out


def _generator_parameters(fn: Any) -> list[str] | None:
    """Keyword names a generator accepts, or None when it takes ``**kwargs`` (or cannot be inspected)."""
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):
        return None
    names = []
    for p in sig.parameters.values():
        if p.kind is inspect.Parameter.VAR_KEYWORD:
            return None
        if p.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY):
            names.append(p.name)
    return names


class SceneConfig(SettingsModel):
    """The scene: at least one mesh."""

    meshes: Annotated[list[MeshEntry], Field(min_length=1, description="one or more meshes, each a path or a "
                                                                         "procedural generator")]


#: The largest ``camera.supersample`` (an 8 x 8 grid: 64 rays a pixel).
MAX_SUPERSAMPLE = 8


class CameraConfig(SettingsModel):
    """Pinhole camera (CONVENTIONS.md): lengths in scene units, ``fov_y`` in degrees, size in pixels."""

    position: Vec3 = Field(description="camera position (scene units)")
    look_at: Vec3 = Field(description=f"point the camera looks at (at least {MIN_LENGTH:g} from position)")
    up: Direction = Field((0.0, 1.0, 0.0), description="up direction (not parallel to the view; normalised on load)")
    fov_y: Annotated[Float, Field(ge=MIN_FOV_DEG, le=MAX_FOV_Y_DEG, description=(
        f"vertical field of view (degrees); at most {MAX_FOV_Y_DEG:g}: towards 180, tan(fov_y / 2) and the pixel "
        "footprint grow without bound"))] = 45.0
    width: Annotated[Int, Field(ge=1, le=MAX_IMAGE_SIDE, description="image width (pixels)")] = 320
    height: Annotated[Int, Field(ge=1, le=MAX_IMAGE_SIDE, description="image height (pixels)")] = 180
    near: Annotated[Float, Field(gt=0.0, le=MAX_COORD, description="near clip distance (scene units), < far, >= "
                                                                   f"far / {MAX_DEPTH_RATIO:g}")] = 0.1
    far: Annotated[Float, Field(ge=MIN_LENGTH, le=MAX_COORD, description=(
        f"far clip distance (scene units); rays that hit nothing end there; far / near <= {MAX_DEPTH_RATIO:g} "
        "(float32 depth precision)"))] = 100.0
    supersample: Annotated[Int, Field(ge=1, le=MAX_SUPERSAMPLE, description=(
        "anti-aliasing: each pixel is the mean of supersample x supersample rays on an ordered sub-pixel grid (the "
        "frame is rendered at supersample times the width and height and box-filtered; the cost grows with the "
        "square). 1: one ray through each pixel centre (CONVENTIONS)"))] = 1

    @model_validator(mode="after")
    def _check_geometry(self) -> CameraConfig:
        problems = []
        if max(self.width, self.height) * self.supersample > MAX_IMAGE_SIDE:
            problems.append(f"{'width' if self.width >= self.height else 'height'} x supersample = "
                            f"{max(self.width, self.height) * self.supersample} must be <= {MAX_IMAGE_SIDE} (the "
                            "frame is rendered at that size)")
        if not self.near < self.far:
            problems.append(f"near ({self.near}) must be < far ({self.far})")
        elif self.far / self.near > MAX_DEPTH_RATIO:
            problems.append(f"far / near = {self.far / self.near:g} must be <= {MAX_DEPTH_RATIO:g} (float32 depths "
                            f"hold 24 bits): raise near or lower far")
        view = [b - a for a, b in zip(self.position, self.look_at, strict=True)]
        n_view = length(view)
        if n_view == 0.0:
            problems.append(f"position and look_at must differ (both {list(self.position)})")
        elif n_view < MIN_LENGTH:
            problems.append(f"position and look_at must be at least {MIN_LENGTH:g} apart (they are {n_view:g})")
        else:
            f, u = unit(view), unit(self.up)
            cross = (f[1] * u[2] - f[2] * u[1], f[2] * u[0] - f[0] * u[2], f[0] * u[1] - f[1] * u[0])
            if math.sqrt(sum(x * x for x in cross)) < 1e-6:
                problems.append(f"up {list(self.up)} is parallel to the viewing direction look_at - position "
                                f"({[round(x, 6) for x in view]}): give another up")
        if problems:
            raise ValueError("\n".join(problems))
        return self


# ---- lights --------------------------------------------------------------------------------------


#: The ways a directional light's orientation may be given; exactly one per light (see DirectionalLightConfig).
SUN_FORMS = ("direction", "toward_sun", "azimuth_deg + elevation_deg")


def sun_direction(azimuth_deg: float, elevation_deg: float) -> tuple[float, float, float]:
    """Unit vector from the scene TOWARD the sun: ``elevation_deg`` above the horizon (the XZ plane), ``azimuth_deg``
    about +Y, 0 toward +Z and 90 toward +X."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return (math.sin(az) * math.cos(el), math.sin(el), math.cos(az) * math.cos(el))


class DirectionalLightConfig(SettingsModel):
    """Directional light (a sun) with RGB ``irradiance``, oriented by exactly one of: ``direction`` (the way the
    light TRAVELS, CONVENTIONS.md), ``toward_sun`` (from the scene toward the sun, i.e. -direction), or
    ``azimuth_deg`` with ``elevation_deg`` (the sun's position in the sky). Every form becomes ``direction`` on load
    (unit), which is what the resolved config and the renderers hold."""

    type: Literal["directional"] = Field(description="directional")
    direction: Optional[Direction] = Field(None, description="direction the light TRAVELS, from the sun into the "
                                           "scene (normalised on load); or give toward_sun, or azimuth_deg and "
                                           "elevation_deg")
    toward_sun: Optional[Direction] = Field(None, description="direction from the scene toward the sun (= -direction;"
                                            " replaced by direction on load)")
    azimuth_deg: Optional[Annotated[Float, Field(ge=-360.0, le=360.0)]] = Field(
        None, description="the sun's azimuth (degrees) about +Y: 0 toward +Z, 90 toward +X; with elevation_deg "
                          "(replaced by direction on load)")
    elevation_deg: Optional[Annotated[Float, Field(ge=-90.0, le=90.0)]] = Field(
        None, description="the sun's elevation above the horizon (the XZ plane, degrees); negative: below it, "
                          "lighting from underneath")
    irradiance: RGB = Field((1.0, 1.0, 1.0), description="RGB irradiance on a plane facing the light")

    @model_validator(mode="after")
    def _one_orientation(self) -> DirectionalLightConfig:
        given = [name for name, set_ in (("direction", self.direction is not None),
                                         ("toward_sun", self.toward_sun is not None),
                                         ("azimuth_deg + elevation_deg",
                                          self.azimuth_deg is not None or self.elevation_deg is not None)) if set_]
        if len(given) != 1:
            raise ValueError(f"give exactly one of {', '.join(SUN_FORMS)} (got "
                             f"{' and '.join(given) if given else 'none'})")
        if given[0] == "azimuth_deg + elevation_deg":
            if self.azimuth_deg is None or self.elevation_deg is None:
                missing = "azimuth_deg" if self.azimuth_deg is None else "elevation_deg"
                raise ValueError(f"{missing} is missing: the sun's position needs azimuth_deg and elevation_deg")
            self.direction = tuple(0.0 - c for c in sun_direction(self.azimuth_deg, self.elevation_deg))
        elif given[0] == "toward_sun":
            self.direction = tuple(0.0 - c for c in self.toward_sun)
        self.toward_sun = self.azimuth_deg = self.elevation_deg = None
        return self


class SpotLightConfig(SettingsModel):
    """Spot light at ``position`` with axis ``direction`` (unit), cone HALF-angle ``cone_deg``, intensity W/sr.

    ``texture`` (optional image file) modulates the emitted radiance over the cone.
    """

    type: Literal["spot"] = Field(description="spot")
    position: Vec3 = Field(description="light position (scene units)")
    direction: Direction = Field(description="cone axis (normalised on load)")
    cone_deg: Annotated[Float, Field(ge=MIN_CONE_DEG, le=89.0, description="cone HALF-angle (degrees)")] = 30.0
    intensity: RGB = Field((1.0, 1.0, 1.0), description="RGB intensity (W/sr); irradiance falls off as 1/d^2")
    texture: PathStr | None = Field(None, description="an image modulating the light over the cone's square")

    @field_validator("texture")
    @classmethod
    def _check_texture(cls, v: Path | None, info: ValidationInfo) -> Path | None:
        return None if v is None else existing_file(resolve_path(v, info))


class PointLightConfig(SettingsModel):
    """Point light at ``position`` shining ``intensity`` W/sr in every direction (rendered as six 90-degree spots,
    one per cube face, each with its own shadow map)."""

    type: Literal["point"] = Field(description="point")
    position: Vec3 = Field(description="light position (scene units)")
    intensity: RGB = Field((1.0, 1.0, 1.0), description="RGB intensity (W/sr); irradiance falls off as 1/d^2")


class EnvironmentLightConfig(SettingsModel):
    """Distant lat-long environment map (``map``: an image file, row 0 = zenith, see assets/README.md) whose texels
    are radiance, times ``scale``; lighting methods only."""

    type: Literal["environment"] = Field(description="environment")
    map: PathStr = Field(description="a lat-long radiance image (row 0 = zenith)")
    scale: Annotated[Float, Field(ge=0.0, le=MAX_EMISSION, description="factor on the map's radiance")] = 1.0

    @field_validator("map")
    @classmethod
    def _check_map(cls, v: Path, info: ValidationInfo) -> Path:
        return existing_file(resolve_path(v, info))


class AreaLightConfig(SettingsModel):
    """Parallelogram light ``position`` + s ``u`` + t ``v`` (s, t in [0, 1]) emitting constant ``radiance`` (or its
    ``power`` in W) from the side u x v points to, or both sides (``two_sided``); lighting methods only."""

    type: Literal["area"] = Field(description="area")
    position: Vec3 = Field(description="the corner y(0, 0) of the parallelogram (scene units)")
    u: NonZeroVec3 = Field(description="first edge vector")
    v: NonZeroVec3 = Field(description="second edge vector (not parallel to u); the light emits towards u x v")
    radiance: Optional[RGB] = Field(None, description="RGB radiance L_e (null and no power: [1, 1, 1])")
    power: Optional[RGB] = Field(None, description="RGB power (W) instead of the radiance (the radiance it gives, P / "
                                                   f"(pi A), must be <= {MAX_EMISSION:g} too)")
    two_sided: Bool = Field(False, description="emit from both sides")
    texture: PathStr | None = Field(None, description="an image modulating the radiance over the parallelogram "
                                                      "(row 0 = the edge at v, columns along u; with power: "
                                                      "divided by its mean)")

    @field_validator("texture")
    @classmethod
    def _check_texture(cls, v: Path | None, info: ValidationInfo) -> Path | None:
        return None if v is None else existing_file(resolve_path(v, info))

    @model_validator(mode="after")
    def _check(self) -> AreaLightConfig:
        cross = (self.u[1] * self.v[2] - self.u[2] * self.v[1], self.u[2] * self.v[0] - self.u[0] * self.v[2],
                 self.u[0] * self.v[1] - self.u[1] * self.v[0])
        nu, nv, area = length(self.u), length(self.v), length(cross)
        # the second test is the scene's (warpscatter.scene.lights.AreaLight): a sliver counts as no area either
        if area <= 1e-9 * nu * nv or area <= 1e-12 * max(nu, nv) ** 2:
            raise ValueError(f"u {list(self.u)} and v {list(self.v)} are parallel (the light has no area)")
        if self.radiance is not None and self.power is not None:
            raise ValueError("give radiance or power, not both")
        if self.power is not None:
            radiance = max(self.power) / ((2.0 if self.two_sided else 1.0) * math.pi * area)
            if radiance > MAX_EMISSION:
                raise ValueError(f"power: gives the radiance P / ({'2 ' if self.two_sided else ''}pi A) = "
                                 f"{radiance:g}, more than {MAX_EMISSION:g} (a larger light or less power)")
        return self


class LinearLightConfig(SettingsModel):
    """Segment light from ``start`` to ``end``, isotropic, ``intensity`` RGB per unit length (W sr^-1 unit^-1);
    lighting methods only."""

    type: Literal["linear"] = Field(description="linear")
    start: Vec3 = Field(description="segment start (scene units)")
    end: Vec3 = Field(description=f"segment end (at least {MIN_LENGTH:g} from start)")
    intensity: RGB = Field((1.0, 1.0, 1.0), description="RGB intensity per unit length (W sr^-1 unit^-1)")

    @model_validator(mode="after")
    def _check(self) -> LinearLightConfig:
        if self.start == self.end:
            raise ValueError(f"start and end must differ (both {list(self.start)})")
        d = length([b - a for a, b in zip(self.start, self.end, strict=True)])
        if d < MIN_LENGTH:
            raise ValueError(f"start and end must be at least {MIN_LENGTH:g} apart (they are {d:g})")
        return self


class VolumeLightConfig(SettingsModel):
    """Parallelepiped light ``position`` + s ``u`` + t ``v`` + r ``w`` (s, t, r in [0, 1]), an isotropic emitter of
    ``intensity`` RGB per unit volume (W sr^-1 unit^-3) or of ``power`` W (Ritschel 2007's volumetric lights);
    lighting methods only, its visibility semi-local or ray-cast."""

    type: Literal["volume"] = Field(description="volume")
    position: Vec3 = Field(description="the corner y(0, 0, 0) (scene units)")
    u: NonZeroVec3 = Field(description="first edge vector")
    v: NonZeroVec3 = Field(description="second edge vector")
    w: NonZeroVec3 = Field(description="third edge vector (u, v, w not coplanar)")
    intensity: Optional[RGB] = Field(None, description="RGB intensity per unit volume (null and no power: [1, 1, 1])")
    power: Optional[RGB] = Field(None, description="RGB power (W) instead: intensity = P / (4 pi V), at most "
                                                   f"{MAX_EMISSION:g}")

    @model_validator(mode="after")
    def _check(self) -> VolumeLightConfig:
        u, v, w = self.u, self.v, self.w
        vol = abs(u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
                  + u[2] * (v[0] * w[1] - v[1] * w[0]))
        if vol <= 1e-9 * length(u) * length(v) * length(w):
            raise ValueError(f"u {list(u)}, v {list(v)} and w {list(w)} are coplanar (the light has no volume)")
        if self.intensity is not None and self.power is not None:
            raise ValueError("give intensity or power, not both")
        if self.power is not None and max(self.power) / (4.0 * math.pi * vol) > MAX_EMISSION:
            raise ValueError(f"power: gives the intensity P / (4 pi V) = {max(self.power) / (4.0 * math.pi * vol):g}, "
                             f"more than {MAX_EMISSION:g}")
        return self


LightConfig = Annotated[
    Union[DirectionalLightConfig, SpotLightConfig, PointLightConfig, EnvironmentLightConfig, AreaLightConfig,
          LinearLightConfig, VolumeLightConfig],
    Field(discriminator="type"),
]


# ---- medium --------------------------------------------------------------------------------------


class PhaseConfig(SettingsModel):
    """Phase function: ``isotropic`` or ``henyey_greenstein`` with asymmetry ``g`` in (-1, 1)."""

    type: Literal["isotropic", "henyey_greenstein"] = Field("isotropic", description="isotropic or "
                                                                                    "henyey_greenstein")
    g: Annotated[Float, Field(ge=-MAX_HG_G, le=MAX_HG_G, description=(
        f"Henyey-Greenstein asymmetry; g > 0 scatters forward; within +-{MAX_HG_G:g}: beyond, the phase function's "
        "denominator (1 - g)^2 cancels to 0 in float32"))] = 0.0

    @model_validator(mode="after")
    def _g_only_for_hg(self) -> PhaseConfig:
        if self.type == "isotropic" and self.g != 0.0:
            raise ValueError(f"g ({self.g}) is only used by type henyey_greenstein (type is isotropic)")
        return self


class MediumConfig(SettingsModel):
    """Homogeneous medium: extinction ``sigma_t`` (1/unit), scattering ``albedo`` rho, ``phase``; either may be RGB
    (coloured fog)."""

    sigma_t: Annotated[scalar_or_rgb_type(0.0, MAX_SIGMA_T), Field(description=(
        f"extinction sigma_t (1/scene unit); [r, g, b] for a coloured medium; at most {MAX_SIGMA_T:g} (a mean free "
        "path of 1e-4 units; sigma_t times any distance stays finite in float32)"))] = 0.1
    albedo: Annotated[scalar_or_rgb_type(0.0, 1.0), Field(
        description="scattering albedo rho (sigma_s = rho sigma_t, per channel)")] = 1.0
    phase: PhaseConfig = Field(default_factory=dict, description="phase function")


# ---- render --------------------------------------------------------------------------------------


class SurfacesSettings(SettingsModel):
    """Surface shading: on or off, and a sky fill."""

    enabled: Bool = Field(True, description="false: surfaces render black (only L_scat remains)")
    ambient: RGB = Field((0.0, 0.0, 0.0), description=(
        "RGB radiance of a uniform sky that lights every surface unshadowed (adds albedo * ambient, seen through "
        "the medium), so that a wall in shadow is not pure black; the scattering integral is unchanged. 0: the "
        "light alone (CONVENTIONS). Classic pipeline only: the lighting methods light surfaces with their own "
        "lights"))


class RenderSettings(SettingsModel):
    """Render settings: each technique's section is its own settings model (:mod:`warpscatter.scattering.settings`,
    :mod:`warpscatter.shadows.settings`, :mod:`warpscatter.csm.settings`)."""

    scattering: ScatteringSettings = Field(default_factory=dict, description="single scattering (the classic pipeline)")
    surfaces: SurfacesSettings = Field(default_factory=dict, description="surface shading")
    shadows: ShadowsSettings = Field(default_factory=dict, description="surface shadows (the classic pipeline)")
    lighting: LightingSettings = Field(default_factory=dict, description="Monte-Carlo direct lighting")


# ---- output --------------------------------------------------------------------------------------


#: Lossless EXR compressions of ``output.compression`` (OpenImageIO names; the same tuple as
#: :data:`warpscatter.imageio.EXR_COMPRESSIONS`, kept here so that validating needs no OpenImageIO).
#: The four float32 EXRs of a 1280x720 render take (two shared cores, one after the other): none 0.17-0.21 s
#: for 36.9 MB, rle 0.24 s / 24.6 MB, zips 0.47-0.70 s / 24.3 MB, zip 0.83-1.17 s / 22.6 MB, piz 1.9-2.8 s / 20.6 MB.
EXR_COMPRESSIONS = ("none", "rle", "zips", "zip", "piz")


#: The fields of the ``output.name`` template: the config file's stem and the method that renders.
NAME_FIELDS = ("config", "method")


class OutputConfig(SettingsModel):
    """Where results go: ``dir`` (relative to the config file), file stem ``name``, ``aovs``, PNG ``exposure``,
    EXR ``compression``."""

    dir: PathStr = Field(Path("out"), description="output folder, relative to the config file")
    name: str = Field("{config}", description="file stem of the outputs, a template: {config} is the config file's "
                      "stem (render for a config built from a dict), {method} the scattering or lighting method")
    aovs: list[Literal[AOV_NAMES]] = Field(  # type: ignore[valid-type]
        default_factory=lambda: list(STANDARD_AOVS), description="images to write besides NAME.exr/.png; the "
        "debug outputs " + ", ".join(DEBUG_AOVS) + " need a method that makes them (the prefiltered ones; "
        "epipolar_samples: epipolar)")
    exposure: Annotated[Float, Field(gt=0.0, le=MAX_GAIN, description="PNG preview exposure (linear factor)")] = 1.0
    compression: Literal[EXR_COMPRESSIONS] = Field(  # type: ignore[valid-type]
        "none", description="EXR compression, all lossless: none is the fastest to write; rle makes the files a "
                            "third smaller for 1.3-2x the time, zips, zip and piz 34-44 % smaller for 2-8x")

    layered: Bool = Field(False, description="true: one multi-layer NAME.exr holds the colour and every image-sized "
                          "output of aovs (channels R, G, B, scattering.R ..., depth.Z) instead of one EXR each")

    @field_validator("dir")
    @classmethod
    def _resolve_dir(cls, v: Path, info: ValidationInfo) -> Path:
        p = resolve_path(v, info)
        if p.exists() and not p.is_dir():
            raise ValueError(f"not a directory: {p}")
        return p

    @field_validator("name")
    @classmethod
    def _plain_stem(cls, v: str) -> str:
        if not v or v in (".", "..") or v != v.strip() or any(c in v for c in '/\\:*?"<>|\0'):
            raise ValueError(f"must be a plain file stem (no folders or special characters), got {v!r}")
        try:
            fields = {f for _, f, _, _ in string.Formatter().parse(v) if f is not None}
        except ValueError as exc:
            raise ValueError(f"not a valid template ({exc}): write {{{{ and }}}} for literal braces") from None
        unknown = sorted(fields - set(NAME_FIELDS))
        if unknown:
            raise ValueError(f"unknown template field(s) {', '.join('{' + f + '}' for f in unknown)} "
                             f"(use {', '.join('{' + f + '}' for f in NAME_FIELDS)})")
        return v

    @field_validator("aovs")
    @classmethod
    def _dedupe(cls, v: list[str]) -> list[str]:
        return list(dict.fromkeys(v))


# ---- the whole config ----------------------------------------------------------------------------


class Config(SettingsModel):
    """A validated pipeline configuration (see the module docstring and CONVENTIONS.md).

    ``config_dir`` (the folder relative paths were resolved against) and ``source`` (the file, if
    any) are kept as private attributes and never dumped.
    """

    scene: SceneConfig = Field(description="the meshes")
    camera: CameraConfig = Field(description="the pinhole camera")
    light: LightConfig = Field(description="the light: directional, spot, point, environment, area, linear or "
                                           "volume")
    medium: MediumConfig = Field(default_factory=dict, description="the homogeneous medium")
    render: RenderSettings = Field(default_factory=dict, description="the methods and their settings")
    output: OutputConfig = Field(default_factory=dict, description="where and what to write")
    animation: Optional[AnimationSettings] = Field(
        None, description="a sequence: frame range, rate and keyframed tracks over config keys "
                          "(warpscatter.animation)")

    _config_dir: Path = PrivateAttr(default_factory=Path.cwd)
    _source: Path | None = PrivateAttr(default=None)

    @model_validator(mode="after")
    def _lighting_fits_light(self) -> Config:
        from .scene import CASTER_ALPHA_TEST  # numpy only, no Warp

        lighting = self.render.lighting.method
        monte_carlo = methods.MONTE_CARLO_LIGHTS
        problems = []
        # the casters of every visibility method: not receiver_only and opaque enough for the alpha test
        all_receivers = all(m.receiver_only for m in self.scene.meshes)
        no_caster = ""
        if all_receivers:
            no_caster = "every mesh is receiver_only"
        elif all(m.receiver_only or m.material.opacity < CASTER_ALPHA_TEST for m in self.scene.meshes):
            no_caster = (f"every mesh is receiver_only or has an opacity below {CASTER_ALPHA_TEST:g} (the alpha test: "
                         "it casts nothing)")
        if lighting is None:
            if self.light.type in monte_carlo:
                problems.append(f"light.type {self.light.type!r} needs render.lighting.method "
                                f"{' or '.join(methods.LIGHTING)} (Monte-Carlo direct lighting)")
            for k, mesh in enumerate(self.scene.meshes):
                if mesh.material.brdf is not None:
                    problems.append(f"scene.meshes.{k}.material.brdf is used by render.lighting.method "
                                    f"{' or '.join(methods.LIGHTING)} only (the classic surfaces are Lambertian)")
        elif self.light.type not in methods.LIGHTING[lighting].lights:
            problems.append(f"render.lighting.method {lighting!r} lights {', '.join(methods.LIGHTING[lighting].lights)}"
                            f" lights (light.type is {self.light.type!r}; use render.scattering for it)")
        elif no_caster and self.render.lighting.csm.file is None \
                and methods.LIGHTING[lighting].visibility == methods.VISIBILITY_CSM:
            problems.append(f"render.lighting: {no_caster}, so there is no occluder to build a CSM of")
        csm = self.render.lighting.csm
        if lighting is not None and csm.objects == "per_mesh":
            if csm.file is not None:
                problems.append("render.lighting.csm.objects: per_mesh builds one CSM per mesh; a precomputed "
                                "render.lighting.csm.file holds the whole scene's (remove one of them)")
            if self.light.type in ("area", "linear") and csm.local_lights == "cube":
                problems.append("render.lighting.csm.objects: per_mesh needs render.lighting.csm.local_lights: "
                                "semi_local for an area or linear light (cube maps sit at the light's points in "
                                "world space, which a moving mesh would invalidate)")
        if lighting is None and no_caster:
            problems.append(f"scene.meshes: {no_caster}, so nothing casts a shadow (drop the flag from the casters"
                            f"{'' if all_receivers else ' or raise their opacity'})")
        if problems:
            raise ValueError("\n".join(problems))
        return self

    @model_validator(mode="after")
    def _debug_aovs_have_a_maker(self) -> Config:
        debug = [a for a in self.output.aovs if a in DEBUG_AOVS]
        if not debug:
            return self
        if self.render.lighting.method is not None:
            raise ValueError(f"output.aovs: {', '.join(debug)} are debug outputs of the scattering methods "
                             f"(render.lighting.method is {self.render.lighting.method!r})")
        method = methods.get("scattering", self.render.scattering.method)
        missing = [a for a in debug if a not in method.debug_aovs]
        if missing:
            makers = sorted({m.name for m in methods.SCATTERING.values() if set(missing) <= set(m.debug_aovs)})
            raise ValueError(f"output.aovs: {', '.join(missing)} {'is' if len(missing) == 1 else 'are'} made by "
                             f"{', '.join(makers) or 'no method'}, not by render.scattering.method "
                             f"{method.name!r}")
        return self

    @model_validator(mode="after")
    def _method_fits_light(self) -> Config:
        method = self.render.scattering.method
        lighting = self.render.lighting.method
        if lighting is not None:  # render.scattering and render.shadows are not used by the lighting methods
            problems = []
            if method != ScatteringSettings.model_fields["method"].default:
                problems.append(f"render.scattering.method {method!r} is not used by render.lighting.method "
                                f"{lighting!r} (it renders no in-scattering); remove it or set "
                                f"render.lighting.method=null")
            if self.render.shadows.method != ShadowsSettings.model_fields["method"].default:
                problems.append(f"render.shadows.method {self.render.shadows.method!r} is not used by "
                                f"render.lighting.method {lighting!r} (its visibility is the CSM or shadow rays)")
            if any(self.render.surfaces.ambient):
                problems.append(f"render.surfaces.ambient is not used by render.lighting.method {lighting!r} (its "
                                "surfaces are lit by the light; an environment light is a sky)")
            if problems:
                raise ValueError("\n".join(problems))
            return self
        lights = methods.SCATTERING[method].lights
        if self.light.type not in lights and self.light.type not in methods.MONTE_CARLO_LIGHTS:
            raise ValueError(f"render.scattering.method {method!r} needs a {' or '.join(lights)} light (light.type is "
                             f"{self.light.type!r})")
        if self.light.type in ("spot", "point") and "prefiltered" in methods.SCATTERING[method].sections:
            self._check_prefiltered_spot(method)
        if method == "epipolar" and min(self.camera.width, self.camera.height) < 2:
            raise ValueError(f"camera.width / camera.height: render.scattering.method 'epipolar' needs an image of at "
                             f"least 2x2 pixels (its lines run between two border points), got "
                             f"{self.camera.width}x{self.camera.height}")
        return self

    def _check_prefiltered_spot(self, method: str) -> None:
        """What the prefiltered methods cannot do under a spot or point light (warpscatter.scattering.prefiltered_spot;
        a point light is six spots)."""
        s = self.render.scattering
        problems = []
        if s.prefiltered.rectification == "projective":
            problems.append("render.scattering.prefiltered.rectification: 'projective' needs a directional light; a "
                            "spot light uses the non-linear rectification (auto or nonlinear)")
        if s.prefiltered.splits > 1:
            problems.append("render.scattering.prefiltered.splits: a spot light's look-ups need whole rows (1)")
        if method != "fourier" and s.moments.overestimation == "adaptive":
            problems.append("render.scattering.moments.overestimation: 'adaptive' weighs a directional light's "
                            "direction (Peters 2017 Sec. 5.3.1); give a number for a spot light")
        gap = math.dist(self.camera.position, self.light.position)
        if gap <= 1e-6 * max(1.0, math.hypot(*self.camera.position)):
            problems.append(f"light.position: the light sits at the camera position, where render.scattering.method "
                            f"{method!r} has no epipolar planes (move it, or use raymarch or epipolar)")
        if problems:
            raise ValueError("\n".join(problems))

    @model_validator(mode="after")
    def _tracks_fit(self, info: ValidationInfo) -> Config:
        """Every keyframe of every track gives a valid config (relative paths against the config's folder; the
        frames between keys are validated when rendered: :meth:`at_frame`, every frame before the first render)."""
        if self.animation is None:
            return self
        config_dir = context_dir(info)
        base = self.model_dump(exclude={"animation"})
        problems = []
        for key, track in self.animation.tracks.items():
            for frame, value in track.keys.items():
                data = copy.deepcopy(base)
                try:
                    apply_overrides(data, {key: value})
                    Config.model_validate(data, context={"config_dir": config_dir})
                except ConfigError as exc:
                    problems += [f"animation.tracks.{key} (frame {frame}): {p.removeprefix('--set ')}"
                                 for p in exc.problems]
                except ValidationError as exc:
                    problems += [f"animation.tracks.{key} (frame {frame}): {p}"
                                 for p in format_validation_errors(exc, Config)]
        if problems:
            raise ValueError("\n".join(problems))
        return self

    def at_frame(self, frame: int) -> Config:
        """The config of one frame of the animation: every track's value at ``frame`` applied, no ``animation``
        section, and the output name ``NAME.FFFF`` (:func:`warpscatter.animation.frame_name`).

        Raises:
            ValueError: the config has no ``animation``.
            ConfigError: the frame's values make an invalid config.
        """
        if self.animation is None:
            raise ValueError("at_frame: the config has no animation section")
        data = self.model_dump(exclude={"animation"})
        integer = frozenset(k for k in self.animation.tracks
                            if _integer_field(k) or (_integer_field(k) is None and _is_int(_value_at(data, k))))
        apply_overrides(data, self.animation.values_at(frame, integer), self._source)
        data["output"]["name"] = frame_name(self.output_name, frame).replace("{", "{{").replace("}", "}}")
        return validated_config(data, self._config_dir, self._source)

    @model_validator(mode="after")
    def _remember_dir(self, info: ValidationInfo) -> Config:
        self._config_dir = context_dir(info)
        self._source = (info.context or {}).get("source")
        return self

    @property
    def config_dir(self) -> Path:
        """Absolute folder that relative paths in the config were resolved against."""
        return self._config_dir

    @property
    def source(self) -> Path | None:
        """The config file this was loaded from (None when built from a dict)."""
        return self._source

    @property
    def method(self) -> str:
        """The method that renders: ``render.lighting.method`` when set, else ``render.scattering.method``."""
        return self.render.lighting.method or self.render.scattering.method

    @property
    def output_name(self) -> str:
        """The file stem of the outputs: ``output.name`` with its template fields filled in (``{config}``: the
        config file's stem, ``render`` for a config built from a dict; ``{method}``: :attr:`method`)."""
        stem = self._source.stem if self._source is not None else "render"
        return self.output.name.format(config=stem, method=self.method)

    def model_copy(self, *, update: dict[str, Any] | None = None, deep: bool = False) -> Config:
        """A copy; with ``update`` (top-level keys, e.g. ``{"camera": {...}}``) the result is validated like a
        loaded config (pydantic's own ``model_copy`` would skip validation).

        Raises:
            ConfigError: listing every problem of the updated config as ``key.path: reason``.
        """
        if not update:
            return super().model_copy(deep=deep)
        data = {**self.model_dump(), **update}
        return validated_config(data, self._config_dir, self._source)

    def revalidated(self) -> Config:
        """This config validated again as a whole (after fields were assigned in place, which pydantic does not
        check); returns a new, valid config.

        Raises:
            ConfigError: listing every problem as ``key.path: reason``.
        """
        return validated_config(self.model_dump(), self._config_dir, self._source)

    @classmethod
    def from_dict(cls, data: dict, config_dir: str | Path | None = None) -> Config:
        """Validate a plain dict; relative paths resolve against ``config_dir`` (default: cwd).

        Raises:
            ConfigError: listing every problem as ``key.path: reason``.
        """
        return validated_config(data, config_dir)

    def model_dump_yaml(self) -> str:
        """The resolved config (absolute paths, defaults filled in, directions normalised) as YAML."""
        return yaml.safe_dump(self.model_dump(mode="json", exclude_none=True), sort_keys=False, default_flow_style=None)


def _value_at(data: Any, dotted_key: str) -> Any:
    """The value at a dotted key (``scene.meshes.0.transform.scale``) of config data, or None where there is none."""
    node = data
    for part in dotted_key.split("."):
        if isinstance(node, dict):
            node = node.get(part)
        elif isinstance(node, list) and part.isdigit() and int(part) < len(node):
            node = node[int(part)]
        else:
            return None
    return node


def _integer_field(dotted_key: str) -> bool | None:
    """Whether a dotted config key is an integer field (``camera.width``, ``render.scattering.epipolar.lines``;
    optional ones too), from the settings models' annotations; None where the models cannot tell (a generator's
    ``params``, a union of several types)."""
    from .schema import unwrap

    model: Any = Config
    tp: Any = None
    for part in dotted_key.split("."):
        if part.isdigit() and tp is not None and typing.get_origin(unwrap(tp)) is list:
            tp = typing.get_args(unwrap(tp))[0]
            model = unwrap(tp)
            continue
        fields = getattr(model, "model_fields", None)
        if not fields or part not in fields:
            return None
        tp = fields[part].annotation
        model = unwrap(tp)
    tp = unwrap(tp)
    if tp is int:
        return True
    return False if isinstance(tp, type) or typing.get_origin(tp) is not None else None


def _is_int(value: Any) -> bool:
    """An integer value (not a bool), or a list of them: an integer key that animation tracks round to."""
    if isinstance(value, (list, tuple)):
        return bool(value) and all(_is_int(v) for v in value)
    return isinstance(value, int) and not isinstance(value, bool)


def validated_config(data: Any, config_dir: str | Path | None, source: Path | None = None,
                     key_lines: dict[tuple, int] | None = None, overridden: tuple = (),
                     named: Path | None = None) -> Config:
    """Validate config data; relative paths resolve against ``config_dir`` (default: cwd).

    Raises:
        ConfigError: listing every problem as ``key.path: reason`` (with YAML line numbers where given).
    """
    try:
        return Config.model_validate(data, context={"config_dir": config_dir, "source": source})
    except ValidationError as exc:
        raise ConfigError(format_validation_errors(exc, Config, key_lines, overridden), named or source) from None


# ---- YAML ----------------------------------------------------------------------------------------

#: The most nodes a YAML document (a config, a sweep file, a ``--set`` value) may hold once its aliases are
#: expanded: every scalar, list and mapping counts, each ``*alias`` as the whole node it refers to. The bundled
#: configs hold 100-200; the limit stops alias bombs ("billion laughs": nine levels of ten aliases each expand a
#: few hundred bytes to 10^9 nodes) while composing, before anything is built, validated or copied.
MAX_YAML_NODES = 100_000

_NAME_TAGS = ("tag:yaml.org,2002:str", "tag:yaml.org,2002:merge")


class _YAMLKeyError(yaml.MarkedYAMLError):
    """A mapping key the config cannot use, found after composing; ``key_path`` is where it is."""

    def __init__(self, key_path: tuple, problem: str, mark):
        super().__init__(problem=problem, problem_mark=mark)
        self.key_path = key_path


class _Loader(yaml.SafeLoader):
    """SafeLoader that rejects duplicate keys, reads ``1e-3`` as a float (as YAML 1.2 does), and refuses documents
    that cannot be plain config data.

    Alias bombs: while composing, every node's expanded size (itself plus, recursively, everything below it, an
    alias counting as the whole node it refers to) is computed once, so a running total of the document's expanded
    size costs O(1) per node and alias; the document is refused as soon as the total passes
    :data:`MAX_YAML_NODES` (a ``ComposerError`` at the alias or node that passed it), and so are recursive aliases
    (an alias inside the node it refers to). A budget on the expanded size, rather than a limit on alias depth,
    bounds exactly what costs time and memory later (building the data, validating it, copying it, walking it for
    line numbers) and keeps aliases usable for what they are for: sharing a material or a transform between entries.

    Keys: a list or a mapping as a mapping key (``{[1, 2]: 3}``) is refused with its key path (``_YAMLKeyError``);
    with ``string_keys_at_top`` (config and sweep files) so is a top-level key that is not a string (``1: x``).
    Numbers stay allowed as keys below the top level (animation keyframes are ``frame: value``).
    """

    string_keys_at_top = False

    def compose_document(self):
        self._sizes: dict[int, int] = {}
        self._expanded = 0
        node = super().compose_document()
        self._sizes = {}
        if node is not None:
            self._check_keys(node)
        return node

    def compose_node(self, parent, index):
        alias = self.peek_event() if self.check_event(yaml.AliasEvent) else None
        node = super().compose_node(parent, index)
        if alias is not None:
            size = self._sizes.get(id(node))
            if size is None:
                raise yaml.composer.ComposerError(
                    None, None, f"alias *{alias.anchor} is inside the node it refers to (a recursive structure)",
                    alias.start_mark)
            mark = alias.start_mark
        else:
            if isinstance(node, yaml.MappingNode):
                size = 1 + sum(self._sizes[id(k)] + self._sizes[id(v)] for k, v in node.value)
            elif isinstance(node, yaml.SequenceNode):
                size = 1 + sum(self._sizes[id(v)] for v in node.value)
            else:
                size = 1
            self._sizes[id(node)] = size
            mark = node.start_mark
        self._expanded += size if alias is not None else 1
        if self._expanded > MAX_YAML_NODES:
            what = f"alias *{alias.anchor} ({size} nodes)" if alias is not None else "this node"
            raise yaml.composer.ComposerError(
                None, None, f"the document holds more than {MAX_YAML_NODES} nodes with its aliases expanded (at "
                f"{what}); refusing it (an alias bomb?)", mark)
        return node

    def _check_keys(self, root) -> None:
        """Refuse collection keys (anywhere) and non-string top-level keys, naming the key path."""
        seen: set[int] = set()
        stack = [(root, ())]
        while stack:
            node, path = stack.pop()
            if id(node) in seen:
                continue
            seen.add(id(node))
            if isinstance(node, yaml.SequenceNode):
                stack.extend((v, (*path, i)) for i, v in reversed(list(enumerate(node.value))))
            elif isinstance(node, yaml.MappingNode):
                children = []
                for k, v in node.value:
                    if not isinstance(k, yaml.ScalarNode):
                        kind = "list" if isinstance(k, yaml.SequenceNode) else "mapping"
                        raise _YAMLKeyError((*path, "[key]"), f"a key must be a name, not a {kind}", k.start_mark)
                    if not path and self.string_keys_at_top and k.tag not in _NAME_TAGS:
                        raise _YAMLKeyError((k.value,), f"a top-level key must be a section name (a string), got "
                                            f"{k.value}", k.start_mark)
                    children.append((v, (*path, k.value)))
                stack.extend(reversed(children))

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=True)
                if not isinstance(key, typing.Hashable):
                    raise yaml.constructor.ConstructorError(None, None, f"a key must be a name, not {key!r}",
                                                            key_node.start_mark)
                if key in seen:
                    raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", key_node.start_mark)
                seen.add(key)
        return super().construct_mapping(node, deep=deep)


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


class _ConfigLoader(_Loader):
    """:class:`_Loader` of whole config and sweep files: top-level keys are section names."""

    string_keys_at_top = True



def _yaml_problem(exc: yaml.YAMLError) -> str:
    mark = getattr(exc, "problem_mark", None)
    what = " ".join(str(x) for x in (getattr(exc, "context", None), getattr(exc, "problem", None)) if x) or str(exc)
    if isinstance(exc, _YAMLKeyError):
        line = f" (line {mark.line + 1})" if mark is not None else ""
        return f"{dotted(exc.key_path) if exc.key_path else 'config'}: {what}{line}"
    if mark is not None:
        return f"line {mark.line + 1}, column {mark.column + 1}: YAML error: {what}"
    return f"YAML error: {what}"


def _key_lines(text: str) -> dict[tuple, int]:
    """Map each key path in a YAML document to its 1-based line (for error messages)."""
    lines: dict[tuple, int] = {}

    def walk(node, path):
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                p = (*path, k.value)
                lines[p] = k.start_mark.line + 1
                walk(v, p)
        elif isinstance(node, yaml.SequenceNode):
            for i, v in enumerate(node.value):
                p = (*path, i)
                lines[p] = v.start_mark.line + 1
                walk(v, p)

    try:
        walk(yaml.compose(text, Loader=_Loader), ())
    except yaml.YAMLError:
        pass
    return lines


# ---- overrides -----------------------------------------------------------------------------------


def parse_override(text: str) -> tuple[tuple[str | int, ...], Any]:
    """Split ``a.b.0.c=value`` into a key path and a YAML-parsed value.

    Digits in the key select list items; the index one past the end appends an item
    (``scene.meshes.1.procedural=colonnade`` adds a second mesh). The value is parsed as YAML (``0.5`` -> float,
    ``[0, 1, 2]`` -> list, ``raymarch`` -> str, ``true`` -> bool), by the loader of config files (:class:`_Loader`:
    duplicate keys, lists or mappings as keys and alias bombs beyond :data:`MAX_YAML_NODES` are refused).

    Raises:
        ValueError: when the text is not ``KEY=VALUE`` or the value is not valid YAML or not plain config data.
    """
    key, sep, raw = text.partition("=")
    key = key.strip()
    if not sep or not key:
        raise ValueError("expected KEY=VALUE, e.g. camera.fov_y=40")
    parts = key.split(".")
    if any(not p for p in parts):
        raise ValueError(f"empty segment in key {key!r}")
    path = tuple(int(p) if p.isdigit() else p for p in parts)
    try:
        value = yaml.load(raw, Loader=_Loader) if raw.strip() else None
    except _YAMLKeyError as exc:
        raise ValueError(f"{dotted(path + exc.key_path)}: {exc.problem}") from None
    except yaml.YAMLError as exc:
        raise ValueError(f"value is not valid YAML ({_yaml_problem(exc)})") from None
    return path, value


def _apply_override(data: dict, path: tuple, value: Any) -> None:
    node: Any = data
    for depth, seg in enumerate(path[:-1]):
        here = dotted(path[: depth + 1])
        if isinstance(node, dict):
            if isinstance(seg, int):
                seg = str(seg)
            if node.get(seg) is None:
                node[seg] = [] if isinstance(path[depth + 1], int) else {}
            node = node[seg]
        elif isinstance(node, list):
            if isinstance(seg, int) and seg == len(node):  # one past the end appends a new item
                node.append([] if isinstance(path[depth + 1], int) else {})
            node = node[_list_index(node, seg, dotted(path[:depth]))]
        else:
            raise ValueError(f"{dotted(path[:depth])} is not a mapping, cannot set {here}")
    last = path[-1]
    if isinstance(node, dict):
        node[str(last)] = value
    elif isinstance(node, list):
        idx = len(node) if isinstance(last, int) and last == len(node) else _list_index(node, last, dotted(path[:-1]))
        if idx == len(node):
            node.append(value)
        else:
            node[idx] = value
    else:
        raise ValueError(f"{dotted(path[:-1])} is not a mapping, cannot set {dotted(path)}")


def _list_index(node: list, seg, where: str) -> int:
    if not isinstance(seg, int):
        raise ValueError(f"{where} is a list: use an item index, not {seg!r}")
    if seg >= len(node):
        raise ValueError(f"index {seg} out of range ({where} has {len(node)} item(s))")
    return seg


# ---- loading -------------------------------------------------------------------------------------


#: The keys of each way of orienting a directional light (:data:`SUN_FORMS`).
_SUN_FORM_KEYS = (("direction",), ("toward_sun",), ("azimuth_deg", "elevation_deg"))


def _drop_other_sun_forms(data: dict, key_path: tuple, value) -> None:
    """An override that orients a directional light one way replaces the config's other way: ``--set
    light.azimuth_deg=40`` on a config that gives ``light.direction`` drops that direction (also for animation
    tracks), instead of failing with two orientations."""
    if len(key_path) != 2 or key_path[0] != "light" or value is None \
            or not any(key_path[1] in keys for keys in _SUN_FORM_KEYS):
        return
    light = data.get("light")
    if not isinstance(light, dict) or light.get("type") != "directional":
        return
    for keys in _SUN_FORM_KEYS:
        if key_path[1] not in keys:
            for k in keys:
                light.pop(k, None)


def apply_overrides(data: dict, overrides: Iterable[str] | Mapping[str, Any] = (),
                    source: str | Path | None = None) -> tuple[tuple, ...]:
    """Apply overrides to config data in place, in order, and return their key paths.

    Args:
        data: the config as plain data (a dict of dicts and lists).
        overrides: ``KEY=VALUE`` strings (the value parsed as YAML: ``camera.position=[0,1,2]``), or a mapping of
            dotted keys to values (``{"camera.width": 64, "scene.meshes.0.material.opacity": 0.5}``).
        source: the config file, named in errors.

    Raises:
        ConfigError: every malformed override, as ``--set KEY=VALUE: reason`` lines.
    """
    if isinstance(overrides, str):
        overrides = [overrides]
    items = overrides.items() if isinstance(overrides, Mapping) else ((o, None) for o in overrides)
    problems, overridden = [], []
    for item, value in items:
        text = f"{item}={value!r}" if isinstance(overrides, Mapping) else str(item)
        try:
            if isinstance(overrides, Mapping):
                key_path, _ = parse_override(f"{item}=")
            else:
                key_path, value = parse_override(item)
            _apply_override(data, key_path, value)
            _drop_other_sun_forms(data, key_path, value)
            overridden.append(key_path)
        except ValueError as exc:
            problems.append(f"--set {text}: {exc}")
    if problems:
        raise ConfigError(problems, source)
    return tuple(overridden)


def read_config_data(path: str | Path) -> tuple[dict, str]:
    """Read a YAML config file as plain data, with its text (for line numbers).

    The loader (:class:`_ConfigLoader`) refuses duplicate keys, lists or mappings as keys, top-level keys that are
    not strings, recursive aliases and documents of more than :data:`MAX_YAML_NODES` nodes with their aliases
    expanded (alias bombs), the last while composing: a refused document costs time in proportion to its text.

    Raises:
        ConfigError: the file cannot be read, is not YAML, is refused by the loader (file and line named) or is
            not a mapping at the top level.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {path.resolve()}", path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read config: {exc}", path) from None
    try:
        data = yaml.load(text, Loader=_ConfigLoader)
    except yaml.YAMLError as exc:
        raise ConfigError(_yaml_problem(exc), path) from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"config: expected a mapping at the top level, got {type(data).__name__}", path)
    return data, text


def load_config(path: str | Path, overrides: Iterable[str] | Mapping[str, Any] = ()) -> Config:
    """Read, override and validate a YAML config file.

    Args:
        path: the YAML file; relative paths inside it resolve against its folder.
        overrides: ``KEY=VALUE`` strings applied in order before validation
            (``camera.position=[0,1,2]``, ``scene.meshes.0.material.opacity=0.5``), or a mapping of dotted keys
            to values; relative paths in them resolve against the config file's folder too.

    Returns:
        The validated :class:`Config`, with absolute paths and ``config_dir`` set.

    Raises:
        ConfigError: the file cannot be read or parsed, an override is malformed, or the config is
            invalid; the message names the file and lists every problem as ``key.path: reason``.
    """
    path = Path(path)
    data, text = read_config_data(path)
    overridden = apply_overrides(data, overrides, path)
    return validated_config(data, path.resolve().parent, path.resolve(), _key_lines(text), overridden, named=path)
