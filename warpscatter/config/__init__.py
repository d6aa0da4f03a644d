"""Typed pipeline configuration: the whole config's models, validation and clear errors.

A YAML config (schema: ``docs/conventions.md``) is patched with ``KEY=VALUE`` overrides (:mod:`.files`, re-exported
here) and validated by these pydantic v2 models, which compose the techniques' and the scene's settings models; a
method's own rules are its registry record's (:attr:`warpscatter.methods.Method.validate`). Unknown keys are refused,
relative paths resolve against the config file's folder, and every problem is reported at once as
``key.path: reason`` lines in a :class:`ConfigError`. No Warp import: validating is fast.
"""


from __future__ import annotations

import copy
import math
import string
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Annotated, Any, Literal, Optional

import yaml
from pydantic import (
    Field,
    PrivateAttr,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from .. import methods
from ..csm.settings import LightingSettings
from ..errors import ConfigError
from ..scattering.settings import ScatteringSettings
from ..scene.light_configs import (
    LIGHT_CONFIGS,
    SUN_FORMS,
    AreaLightConfig,
    DirectionalLightConfig,
    EnvironmentLightConfig,
    LightConfig,
    LinearLightConfig,
    PointLightConfig,
    SpotLightConfig,
    VolumeLightConfig,
    format_value,
    sun_direction,
)
from ..scene.mesh_configs import (
    MESH_SUFFIXES,
    LafortuneBRDFConfig,
    Material,
    MeshEntry,
    PhongBRDFConfig,
    SceneConfig,
    Transform,
)
from ..schema import (
    MAX_COORD,
    MAX_DEPTH_RATIO,
    MAX_FOV_Y_DEG,
    MAX_GAIN,
    MAX_HG_G,
    MAX_IMAGE_SIDE,
    MAX_SIGMA_T,
    MIN_FOV_DEG,
    MIN_LENGTH,
    RGB,
    Bool,
    Direction,
    Float,
    Int,
    PathStr,
    SettingsModel,
    Vec3,
    context_dir,
    format_validation_errors,
    length,
    resolve_path,
    scalar_or_rgb_type,
    unit,
)
from ..shadows.settings import ShadowMapSettings, ShadowsSettings
from .animation import AnimationSettings, frame_name
from .files import MAX_YAML_NODES, apply_overrides, key_lines, parse_override, read_config_data, value_at

__all__ = [
    "AOV_NAMES",
    "DEBUG_AOVS",
    "LIGHT_CONFIGS",
    "MAX_YAML_NODES",
    "MESH_SUFFIXES",
    "STANDARD_AOVS",
    "SUN_FORMS",
    "AreaLightConfig",
    "CameraConfig",
    "Config",
    "ConfigError",
    "DirectionalLightConfig",
    "EnvironmentLightConfig",
    "LafortuneBRDFConfig",
    "LightConfig",
    "LightingSettings",
    "LinearLightConfig",
    "Material",
    "MediumConfig",
    "MeshEntry",
    "OutputConfig",
    "PhaseConfig",
    "PhongBRDFConfig",
    "PointLightConfig",
    "RenderSettings",
    "ScatteringSettings",
    "SceneConfig",
    "ShadowMapSettings",
    "ShadowsSettings",
    "SpotLightConfig",
    "SurfacesSettings",
    "Transform",
    "VolumeLightConfig",
    "apply_overrides",
    "format_value",
    "load_config",
    "parse_override",
    "read_config_data",
    "sun_direction",
    "validated_config",
]

#: Image outputs a render writes by default (``output.aovs``); ``color`` is always written.
STANDARD_AOVS = ("color", "scattering", "surface", "depth")
#: Debug outputs (``output.aovs``, written only when asked) of the scattering methods that list them in
#: :attr:`warpscatter.methods.Method.debug_aovs` (described in docs/guide/outputs.md and the method pages).
DEBUG_AOVS = ("rectified", "epipole_mask", "rectified_map", "mip_level", "evaluated_pixels", "epipolar_samples")
#: Image outputs a render can write (``output.aovs``).
AOV_NAMES = STANDARD_AOVS + DEBUG_AOVS


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




#: Lossless EXR compressions of ``output.compression``, as :data:`..io.images.EXR_COMPRESSIONS` (kept here
#: so that validating needs no OpenImageIO; timings in docs/design/csm-core.md).
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


#: The ``light.type`` values, in the order of :data:`~warpscatter.scene.light_configs.LIGHT_CONFIGS`.
_LIGHT_NAMES = [typing.get_args(m.model_fields["type"].annotation)[0] for m in LIGHT_CONFIGS]




class Config(SettingsModel):
    """A validated pipeline configuration; ``config_dir`` and ``source`` are private and never dumped."""

    scene: SceneConfig = Field(description="the meshes")
    camera: CameraConfig = Field(description="the pinhole camera")
    light: LightConfig = Field(description="the light: " + ", ".join(_LIGHT_NAMES[:-1]) + " or " + _LIGHT_NAMES[-1])
    medium: MediumConfig = Field(default_factory=dict, description="the homogeneous medium")
    render: RenderSettings = Field(default_factory=dict, description="the methods and their settings")
    output: OutputConfig = Field(default_factory=dict, description="where and what to write")
    animation: Optional[AnimationSettings] = Field(
        None, description="a sequence: frame range, rate and keyframed tracks over config keys "
                          "(warpscatter.config.animation)")

    _config_dir: Path = PrivateAttr(default_factory=Path.cwd)
    _source: Path | None = PrivateAttr(default=None)

    @model_validator(mode="after")
    def _methods_fit(self) -> Config:
        """The method renders this light and scene: the shared rules here, the method's own from its registry record
        (:attr:`warpscatter.methods.Method.validate`); the first group with a problem is reported."""
        lighting = self.render.lighting.method
        record = methods.get("lighting" if lighting is not None else "scattering",
                             lighting or self.render.scattering.method)
        own = record.validate(self)
        for problems in (self._lighting_problems(own if lighting is not None else []), self._debug_aov_problems(),
                         self._scattering_problems(own if lighting is None else [])):
            if problems:
                raise ValueError("\n".join(problems))
        return self

    def _lighting_problems(self, own: list[str]) -> list[str]:
        """The light against ``render.lighting``: Monte-Carlo lights need a lighting method, which lights only
        them; ``own``: the lighting method's own rules; without one, something must cast a shadow."""
        lighting = self.render.lighting.method
        problems = []
        if lighting is None:
            if self.light.type in methods.MONTE_CARLO_LIGHTS:
                problems.append(f"light.type {self.light.type!r} needs render.lighting.method "
                                f"{' or '.join(methods.LIGHTING)} (Monte-Carlo direct lighting)")
            for k, mesh in enumerate(self.scene.meshes):
                if mesh.material.brdf is not None:
                    problems.append(f"scene.meshes.{k}.material.brdf is used by render.lighting.method "
                                    f"{' or '.join(methods.LIGHTING)} only (the classic surfaces are Lambertian)")
        elif self.light.type not in methods.LIGHTING[lighting].lights:
            problems.append(f"render.lighting.method {lighting!r} lights {', '.join(methods.LIGHTING[lighting].lights)}"
                            f" lights (light.type is {self.light.type!r}; use render.scattering for it)")
        problems += own
        no_caster = self.scene.no_caster()
        if lighting is None and no_caster:
            every = all(m.receiver_only for m in self.scene.meshes)
            problems.append(f"scene.meshes: {no_caster}, so nothing casts a shadow (drop the flag from the casters"
                            f"{'' if every else ' or raise their opacity'})")
        return problems

    def _debug_aov_problems(self) -> list[str]:
        """The debug outputs of ``output.aovs`` are made by the scattering method."""
        debug = [a for a in self.output.aovs if a in DEBUG_AOVS]
        if not debug:
            return []
        if self.render.lighting.method is not None:
            return [f"output.aovs: {', '.join(debug)} are debug outputs of the scattering methods "
                    f"(render.lighting.method is {self.render.lighting.method!r})"]
        method = methods.get("scattering", self.render.scattering.method)
        missing = [a for a in debug if a not in method.debug_aovs]
        if not missing:
            return []
        makers = sorted({m.name for m in methods.SCATTERING.values() if set(missing) <= set(m.debug_aovs)})
        return [f"output.aovs: {', '.join(missing)} {'is' if len(missing) == 1 else 'are'} made by "
                f"{', '.join(makers) or 'no method'}, not by render.scattering.method {method.name!r}"]

    def _scattering_problems(self, own: list[str]) -> list[str]:
        """The sections a lighting method does not use are left at their defaults; a scattering method renders the
        light; ``own``: the scattering method's own rules."""
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
            return problems
        lights = methods.SCATTERING[method].lights
        if self.light.type not in lights and self.light.type not in methods.MONTE_CARLO_LIGHTS:
            return [f"render.scattering.method {method!r} needs a {' or '.join(lights)} light (light.type is "
                    f"{self.light.type!r})"]
        return own

    @model_validator(mode="after")
    def _tracks_fit(self, info: ValidationInfo) -> Config:
        """Every keyframe of every track gives a valid config (frames between keys are validated when rendered)."""
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
        """The config of one animation frame: every track's value applied, no ``animation``, name ``NAME.FFFF``.

        Raises:
            ValueError: the config has no ``animation``.
            ConfigError: the frame's values make an invalid config.
        """
        if self.animation is None:
            raise ValueError("at_frame: the config has no animation section")
        data = self.model_dump(exclude={"animation"})
        integer = frozenset(k for k in self.animation.tracks
                            if _integer_field(k) or (_integer_field(k) is None and _is_int(value_at(data, k))))
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
        """A copy; with ``update`` (top-level keys) validated like a loaded config (unlike pydantic's ``model_copy``):
        :class:`ConfigError` lists every problem of the updated config."""
        if not update:
            return super().model_copy(deep=deep)
        data = {**self.model_dump(), **update}
        return validated_config(data, self._config_dir, self._source)

    def revalidated(self) -> Config:
        """This config validated again as a whole (after in-place assignments): a new, valid config, else a
        :class:`ConfigError` listing every problem."""
        return validated_config(self.model_dump(), self._config_dir, self._source)

    @classmethod
    def from_dict(cls, data: dict, config_dir: str | Path | None = None) -> Config:
        """Validate a plain dict (:class:`ConfigError` lists every problem); relative paths resolve against
        ``config_dir`` (default: cwd)."""
        return validated_config(data, config_dir)

    def model_dump_yaml(self) -> str:
        """The resolved config (absolute paths, defaults filled in, directions normalised) as YAML."""
        return yaml.safe_dump(self.model_dump(mode="json", exclude_none=True), sort_keys=False, default_flow_style=None)


def _integer_field(dotted_key: str) -> bool | None:
    """Whether a dotted config key is an integer field, from the models' annotations; None where they cannot tell."""
    from ..schema import unwrap

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
    """Validate config data; relative paths resolve against ``config_dir`` (default: cwd). :class:`ConfigError` lists
    every problem as ``key.path: reason`` (with YAML line numbers where given)."""
    try:
        return Config.model_validate(data, context={"config_dir": config_dir, "source": source})
    except ValidationError as exc:
        raise ConfigError(format_validation_errors(exc, Config, key_lines, overridden), named or source) from None




def load_config(path: str | Path, overrides: Iterable[str] | Mapping[str, Any] = ()) -> Config:
    """Read, override and validate a YAML config file.

    Args:
        path: the YAML file; relative paths inside it resolve against its folder.
        overrides: ``KEY=VALUE`` strings applied in order before validation (``camera.position=[0,1,2]``), or a
            mapping of dotted keys to values; relative paths in them resolve against the config file's folder too.

    Returns:
        The validated :class:`Config`, with absolute paths and ``config_dir`` set.

    Raises:
        ConfigError: the file cannot be read or parsed, an override is malformed, or the config is invalid; the
            message names the file and lists every problem as ``key.path: reason``.
    """
    path = Path(path)
    data, text = read_config_data(path)
    overridden = apply_overrides(data, overrides, path)
    return validated_config(data, path.resolve().parent, path.resolve(), key_lines(text), overridden, named=path)
