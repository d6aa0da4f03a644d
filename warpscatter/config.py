"""Typed pipeline configuration: YAML loading, ``--set`` overrides, validation and clear errors.

A config file (schema in ``CONVENTIONS.md`` and the README) is read with PyYAML, patched with
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

import difflib
import inspect
import math
import re
import types
import typing
from pathlib import Path
from typing import Annotated, Any, Literal, Optional, Union

import yaml
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PrivateAttr,
    Strict,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

__all__ = [
    "AOV_NAMES",
    "LIGHTING_METHODS",
    "MESH_SUFFIXES",
    "SCATTERING_METHODS",
    "CameraConfig",
    "Config",
    "ConfigError",
    "AreaLightConfig",
    "CSMBuildConfig",
    "DirectionalLightConfig",
    "EnvironmentLightConfig",
    "LafortuneBRDFConfig",
    "LightingConfig",
    "LinearLightConfig",
    "PhongBRDFConfig",
    "Material",
    "MediumConfig",
    "MeshEntry",
    "OutputConfig",
    "PhaseConfig",
    "RenderConfig",
    "ScatteringConfig",
    "SceneConfig",
    "ShadowMapConfig",
    "ShadowsConfig",
    "FourierConfig",
    "EpipolarConfig",
    "MomentsConfig",
    "PrefilteredConfig",
    "SpotLightConfig",
    "SurfacesConfig",
    "Transform",
    "load_config",
    "parse_override",
]

#: Scattering methods implemented so far (``render.scattering.method``).
SCATTERING_METHODS = ("raymarch", "fourier", "moments4", "moments6", "epipolar")
#: Monte-Carlo direct-lighting methods (``render.lighting.method``): coherent shadow maps and the ray-traced reference.
LIGHTING_METHODS = ("csm", "raytrace")
#: Light types only the lighting methods handle.
MC_LIGHT_TYPES = ("environment", "area", "linear")
#: Image outputs a render can write (``output.aovs``); ``color`` is always written.
AOV_NAMES = ("color", "scattering", "surface", "depth")
#: Mesh file suffixes accepted in ``scene.meshes.N.path`` (loaded with trimesh).
MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
#: Largest accepted image / shadow-map side, in pixels (guards against typos such as 19200).
MAX_IMAGE_SIDE = 16384


class ConfigError(Exception):
    """An invalid configuration: every problem as a ``key.path: reason`` line.

    Attributes:
        problems: the problem lines, in document order of discovery.
        source: the config file the problems were found in (None for in-memory configs).
    """

    def __init__(self, problems: list[str] | str, source: str | Path | None = None):
        self.problems = [problems] if isinstance(problems, str) else list(problems)
        self.source = Path(source) if source is not None else None
        super().__init__(str(self))

    def __str__(self) -> str:
        body = "\n".join(f"  {p}" for p in self.problems)
        head = f"{self.source}:" if self.source is not None else "invalid config:"
        return f"{head}\n{body}"


# ---- field types ---------------------------------------------------------------------------------


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _vec3(v: Any) -> tuple[float, float, float]:
    """Accept a list of 3 numbers; return a tuple of 3 finite floats."""
    if isinstance(v, (list, tuple)) and len(v) == 3 and all(_is_number(x) for x in v):
        out = tuple(float(x) for x in v)
        if not all(math.isfinite(x) for x in out):
            raise ValueError(f"must be finite, got {list(v)}")
        return out
    raise ValueError(f"expected a list of 3 numbers [x, y, z], got {v!r}")


def _nonzero_unit(v: tuple[float, float, float]) -> tuple[float, float, float]:
    n = math.sqrt(sum(x * x for x in v))
    if n == 0.0:
        raise ValueError("must be non-zero")
    return tuple(x / n for x in v)


def _nonzero(v: tuple[float, float, float]) -> tuple[float, float, float]:
    if not any(v):
        raise ValueError("must be non-zero")
    return v


def _nonnegative(v: tuple[float, float, float]) -> tuple[float, float, float]:
    if min(v) < 0.0:
        raise ValueError(f"every component must be >= 0, got {list(v)}")
    return v


def _unit_interval(v: tuple[float, float, float]) -> tuple[float, float, float]:
    if min(v) < 0.0 or max(v) > 1.0:
        raise ValueError(f"every component must lie in [0, 1], got {list(v)}")
    return v


def _path_string(v: Any) -> Any:
    if isinstance(v, Path):
        return v
    if not isinstance(v, str) or not v.strip():
        raise ValueError(f"expected a file path (string), got {v!r}")
    return v


Vec3 = Annotated[tuple[float, float, float], BeforeValidator(_vec3)]
Direction = Annotated[Vec3, AfterValidator(_nonzero_unit)]  # normalised on load
NonZeroVec3 = Annotated[Vec3, AfterValidator(_nonzero)]
RGB = Annotated[Vec3, AfterValidator(_nonnegative)]
Albedo = Annotated[Vec3, AfterValidator(_unit_interval)]
Float = Annotated[float, Strict(), Field(allow_inf_nan=False)]
Int = Annotated[int, Strict()]
Bool = Annotated[bool, Strict()]
PathStr = Annotated[Path, BeforeValidator(_path_string)]


def _context_dir(info: ValidationInfo) -> Path:
    ctx = info.context or {}
    d = ctx.get("config_dir")
    return Path(d).resolve() if d is not None else Path.cwd()


def _resolve(p: Path, info: ValidationInfo) -> Path:
    p = Path(p).expanduser()
    return p if p.is_absolute() else (_context_dir(info) / p).resolve()


def _existing_file(p: Path) -> Path:
    if not p.exists():
        raise ValueError(f"file not found: {p}")
    if not p.is_file():
        raise ValueError(f"not a file: {p}")
    return p


class _Model(BaseModel):
    # Section defaults are given as ``{}`` and validated like user input (validate_default), so they are
    # built inside the validation context: a default ``output.dir`` resolves against the config folder.
    model_config = ConfigDict(extra="forbid", validate_default=True)

    @model_validator(mode="before")
    @classmethod
    def _empty_sections(cls, data: Any) -> Any:
        """An empty section (``medium:`` with nothing under it) means its defaults, as if it were absent."""
        if not isinstance(data, dict):
            return data
        out = {}
        for k, v in data.items():
            field = cls.model_fields.get(k) if isinstance(k, str) else None
            annotation = _unwrap(field.annotation) if field is not None else None
            is_section = isinstance(annotation, type) and issubclass(annotation, BaseModel)
            if v is None and is_section and not field.is_required():
                continue
            out[k] = v
        return out


# ---- scene ---------------------------------------------------------------------------------------


class Transform(_Model):
    """Mesh placement: scale first, then rotation (X, then Y, then Z, degrees), then translation."""

    translate: Vec3 = (0.0, 0.0, 0.0)
    rotate_deg: Vec3 = (0.0, 0.0, 0.0)
    scale: Union[float, tuple[float, float, float]] = 1.0  # scalar or per-axis, > 0

    @field_validator("scale", mode="before")
    @classmethod
    def _check_scale(cls, v: Any) -> Any:
        if _is_number(v):
            values, out = [float(v)], float(v)
        elif isinstance(v, (list, tuple)):
            out = _vec3(v)
            values = list(out)
        else:
            raise ValueError(f"expected a number or a list of 3 numbers, got {v!r}")
        if not all(math.isfinite(x) and x > 0.0 for x in values):
            raise ValueError(f"must be > 0 (and finite), got {v!r}")
        return out

    @property
    def scale3(self) -> tuple[float, float, float]:
        """The scale as three per-axis factors."""
        s = self.scale
        return (s, s, s) if isinstance(s, float) else tuple(s)


class PhongBRDFConfig(_Model):
    """Normalized Phong lobe k_s (e + 2) / (2 pi) cos^e(alpha) beside the Lambert term (lighting methods only)."""

    type: Literal["phong"]
    specular: Albedo = (0.04, 0.04, 0.04)
    exponent: Annotated[Float, Field(ge=0.0, le=1.0e4)] = 32.0


class LafortuneLobeConfig(_Model):
    """One Lafortune lobe color [C_x u_x v_x + C_y u_y v_y + C_z u_z v_z]^exponent (local frame, z = normal)."""

    coefficients: Vec3
    exponent: Annotated[Float, Field(ge=0.0, le=1.0e4)]
    color: RGB = (1.0, 1.0, 1.0)


class LafortuneBRDFConfig(_Model):
    """Lafortune BRDF: the Lambert term (``albedo``) plus 1 to 4 generalized cosine lobes (lighting methods only)."""

    type: Literal["lafortune"]
    lobes: Annotated[list[LafortuneLobeConfig], Field(min_length=1, max_length=4)]


BRDFConfig = Annotated[Union[PhongBRDFConfig, LafortuneBRDFConfig], Field(discriminator="type")]


class Material(_Model):
    """Surface material: diffuse ``albedo`` (linear RGB in [0, 1]), ``opacity`` in (0, 1] and, for the lighting
    methods (``render.lighting``), an optional glossy ``brdf`` (phong or lafortune) beside the Lambert term."""

    albedo: Albedo = (0.5, 0.5, 0.5)
    opacity: Annotated[Float, Field(gt=0.0, le=1.0)] = 1.0
    brdf: Optional[BRDFConfig] = None

    def brdf_spec(self) -> dict:
        """This material as :meth:`warpscatter.csm.brdf.MaterialTable.from_specs` reads it."""
        spec: dict = {"albedo": self.albedo}
        if isinstance(self.brdf, PhongBRDFConfig):
            spec["phong"] = {"specular": self.brdf.specular, "exponent": self.brdf.exponent}
        elif isinstance(self.brdf, LafortuneBRDFConfig):
            spec["lafortune"] = [lobe.model_dump() for lobe in self.brdf.lobes]
        return spec


class MeshEntry(_Model):
    """One mesh of the scene: a file (``path``) or a procedural generator (``procedural`` + ``params``)."""

    path: PathStr | None = None
    procedural: str | None = None
    params: dict[str, Any] = Field(default_factory=dict)
    transform: Transform = Field(default_factory=dict)
    material: Material = Field(default_factory=dict)
    receiver_only: Bool = False  # receives shadows, casts none: left out of every shadow map, BVH and CSM

    @field_validator("path")
    @classmethod
    def _check_path(cls, v: Path | None, info: ValidationInfo) -> Path | None:
        if v is None:
            return v
        p = _existing_file(_resolve(v, info))
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
            raise ValueError(f"unknown generator {v!r}{_did_you_mean(v, generators)} (choose from {choices})")
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
                hint = _did_you_mean(unknown[0], accepted) if len(unknown) == 1 else ""
                raise ValueError(
                    f"unknown parameter(s) {', '.join(repr(u) for u in unknown)} for generator {name!r}{hint} "
                    f"(accepts: {', '.join(accepted) or 'none'})"
                )
        return v

    @model_validator(mode="after")
    def _one_source(self) -> MeshEntry:
        if (self.path is None) == (self.procedural is None):
            got = "both" if self.path is not None else "neither"
            raise ValueError(f"give exactly one of 'path' or 'procedural' (got {got})")
        return self


def _did_you_mean(word: str, choices) -> str:
    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _generators() -> dict[str, Any]:
    """The procedural generators (imported lazily: the module builds meshes with numpy/trimesh)."""
    try:
        from .scene.procedural import GENERATORS
    except ImportError as exc:
        raise ValueError(f"cannot check procedural generators: {exc}") from None
    return GENERATORS


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


class SceneConfig(_Model):
    """The scene: at least one mesh."""

    meshes: Annotated[list[MeshEntry], Field(min_length=1)]


class CameraConfig(_Model):
    """Pinhole camera (CONVENTIONS.md): lengths in scene units, ``fov_y`` in degrees, size in pixels."""

    position: Vec3
    look_at: Vec3
    up: NonZeroVec3 = (0.0, 1.0, 0.0)
    fov_y: Annotated[Float, Field(gt=0.0, lt=180.0)] = 45.0
    width: Annotated[Int, Field(ge=1, le=MAX_IMAGE_SIDE)] = 320
    height: Annotated[Int, Field(ge=1, le=MAX_IMAGE_SIDE)] = 180
    near: Annotated[Float, Field(gt=0.0)] = 0.1
    far: Annotated[Float, Field(gt=0.0)] = 100.0

    @model_validator(mode="after")
    def _check_geometry(self) -> CameraConfig:
        problems = []
        if not self.near < self.far:
            problems.append(f"near ({self.near}) must be < far ({self.far})")
        view = [b - a for a, b in zip(self.position, self.look_at, strict=True)]
        n_view = math.sqrt(sum(x * x for x in view))
        if n_view == 0.0:
            problems.append(f"position and look_at must differ (both {list(self.position)})")
        else:
            n_up = math.sqrt(sum(x * x for x in self.up))
            f = [x / n_view for x in view]
            u = [x / n_up for x in self.up]
            cross = (f[1] * u[2] - f[2] * u[1], f[2] * u[0] - f[0] * u[2], f[0] * u[1] - f[1] * u[0])
            if math.sqrt(sum(x * x for x in cross)) < 1e-6:
                problems.append(f"up {list(self.up)} is parallel to the viewing direction")
        if problems:
            raise ValueError("\n".join(problems))
        return self

    def to_camera(self):
        """Build the :class:`warpscatter.scene.camera.Camera` (imports Warp)."""
        from .scene.camera import Camera

        return Camera(self.position, self.look_at, self.up, self.fov_y, self.width, self.height, self.near, self.far)


# ---- lights --------------------------------------------------------------------------------------


class DirectionalLightConfig(_Model):
    """Directional light: ``direction`` light TRAVELS (unit after loading), RGB ``irradiance``."""

    type: Literal["directional"]
    direction: Direction
    irradiance: RGB = (1.0, 1.0, 1.0)


class SpotLightConfig(_Model):
    """Spot light at ``position`` with axis ``direction`` (unit), cone HALF-angle ``cone_deg``, intensity W/sr.

    ``texture`` (optional image file) modulates the emitted radiance over the cone.
    """

    type: Literal["spot"]
    position: Vec3
    direction: Direction
    cone_deg: Annotated[Float, Field(gt=0.0, le=89.0)] = 30.0
    intensity: RGB = (1.0, 1.0, 1.0)
    texture: PathStr | None = None

    @field_validator("texture")
    @classmethod
    def _check_texture(cls, v: Path | None, info: ValidationInfo) -> Path | None:
        return None if v is None else _existing_file(_resolve(v, info))


class EnvironmentLightConfig(_Model):
    """Distant lat-long environment map (``map``: an image file, row 0 = zenith, see assets/README.md) whose texels
    are radiance, times ``scale``; lighting methods only."""

    type: Literal["environment"]
    map: PathStr
    scale: Annotated[Float, Field(ge=0.0)] = 1.0

    @field_validator("map")
    @classmethod
    def _check_map(cls, v: Path, info: ValidationInfo) -> Path:
        return _existing_file(_resolve(v, info))


class AreaLightConfig(_Model):
    """Parallelogram light ``position`` + s ``u`` + t ``v`` (s, t in [0, 1]) emitting constant ``radiance`` (or its
    ``power`` in W) from the side u x v points to, or both sides (``two_sided``); lighting methods only."""

    type: Literal["area"]
    position: Vec3
    u: NonZeroVec3
    v: NonZeroVec3
    radiance: Optional[RGB] = None
    power: Optional[RGB] = None
    two_sided: Bool = False

    @model_validator(mode="after")
    def _check(self) -> AreaLightConfig:
        cross = (self.u[1] * self.v[2] - self.u[2] * self.v[1], self.u[2] * self.v[0] - self.u[0] * self.v[2],
                 self.u[0] * self.v[1] - self.u[1] * self.v[0])  # fmt: skip
        nu = math.sqrt(sum(x * x for x in self.u))
        nv = math.sqrt(sum(x * x for x in self.v))
        if math.sqrt(sum(x * x for x in cross)) <= 1e-9 * nu * nv:
            raise ValueError(f"u {list(self.u)} and v {list(self.v)} are parallel (the light has no area)")
        if self.radiance is not None and self.power is not None:
            raise ValueError("give radiance or power, not both")
        return self


class LinearLightConfig(_Model):
    """Segment light from ``start`` to ``end``, isotropic, ``intensity`` RGB per unit length (W sr^-1 unit^-1);
    lighting methods only."""

    type: Literal["linear"]
    start: Vec3
    end: Vec3
    intensity: RGB = (1.0, 1.0, 1.0)

    @model_validator(mode="after")
    def _check(self) -> LinearLightConfig:
        if self.start == self.end:
            raise ValueError(f"start and end must differ (both {list(self.start)})")
        return self


LightConfig = Annotated[
    Union[DirectionalLightConfig, SpotLightConfig, EnvironmentLightConfig, AreaLightConfig, LinearLightConfig],
    Field(discriminator="type"),
]


# ---- medium --------------------------------------------------------------------------------------


class PhaseConfig(_Model):
    """Phase function: ``isotropic`` or ``henyey_greenstein`` with asymmetry ``g`` in (-1, 1)."""

    type: Literal["isotropic", "henyey_greenstein"] = "isotropic"
    g: Annotated[Float, Field(gt=-1.0, lt=1.0)] = 0.0

    @model_validator(mode="after")
    def _g_only_for_hg(self) -> PhaseConfig:
        if self.type == "isotropic" and self.g != 0.0:
            raise ValueError(f"g ({self.g}) is only used by type henyey_greenstein (type is isotropic)")
        return self


class MediumConfig(_Model):
    """Homogeneous medium: extinction ``sigma_t`` (1/unit), scattering ``albedo`` rho, ``phase``."""

    sigma_t: Annotated[Float, Field(ge=0.0)] = 0.1
    albedo: Annotated[Float, Field(ge=0.0, le=1.0)] = 1.0
    phase: PhaseConfig = Field(default_factory=dict)

    def to_medium(self):
        """Build the :class:`warpscatter.scene.medium.Medium` (imports Warp)."""
        from .scene.medium import Medium

        return Medium(self.sigma_t, self.albedo, self.phase.type, self.phase.g)


# ---- render --------------------------------------------------------------------------------------


class ShadowMapConfig(_Model):
    """Shadow map: ``resolution`` (square side, or [width, height], each >= 16) and depth ``bias`` >= 0.

    ``bias`` is in texel sizes: a point counts as lit when its light-space depth is at most the stored
    caster depth plus ``bias`` times the world size of one texel.
    """

    resolution: Union[int, tuple[int, int]] = 1024
    bias: Annotated[Float, Field(ge=0.0)] = 1.0

    @field_validator("resolution", mode="before")
    @classmethod
    def _check_resolution(cls, v: Any) -> Any:
        sides = v if isinstance(v, (list, tuple)) else [v]
        if len(sides) not in (1, 2) or not all(isinstance(s, int) and not isinstance(s, bool) for s in sides):
            raise ValueError(f"expected an integer or [width, height], got {v!r}")
        if not all(16 <= s <= MAX_IMAGE_SIDE for s in sides):
            raise ValueError(f"each side must lie in [16, {MAX_IMAGE_SIDE}], got {v!r}")
        return tuple(sides) if isinstance(v, (list, tuple)) else v

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in texels."""
        r = self.resolution
        return (r, r) if isinstance(r, int) else tuple(r)


class PrefilteredConfig(_Model):
    """What the prefiltered methods (``fourier``, ``moments4``, ``moments6``) share: rectification, weights and the
    epipole fallback; see :class:`warpscatter.scattering.prefiltered.PrefilteredSettings`."""

    weighting: Literal["transmittance", "average"] = "transmittance"
    reference_ray: Literal["pixels", "optimal", "bisectrix", "mean"] = "pixels"
    guard_band: Annotated[Float, Field(ge=0.0, le=1.0)] = 0.1
    epipole_block: Annotated[Int, Field(ge=0)] = 32
    epipole_angle_deg: Annotated[Float, Field(ge=0.0, le=60.0)] = 8.0
    rectification: Literal["auto", "projective", "nonlinear"] = "auto"
    epipole_margin: Annotated[Float, Field(ge=0.0)] = 1.0
    regions: Annotated[Int, Field(ge=1, le=16)] = 8
    projective_weights: Literal["exact", "cross_ratio"] = "exact"
    splits: Annotated[Int, Field(ge=1, le=16)] = 1
    resample_filter: Literal["none", "moments"] = "none"  # Peters 2017 Sec. 5.2 (non-linear rectification)
    resample_filter_px: Optional[Annotated[Int, Field(ge=1, le=64)]] = None  # null: radial rectified texel footprint
    # empty the texels whose blocker shadows no pixel (warpscatter's; false: the papers'); auto: moment methods only
    caster_culling: Union[Literal["auto"], Bool] = "auto"
    caster_culling_bias: Annotated[Float, Field(ge=0.0, le=0.25)] = 1.0 / 64.0  # fraction of the depth range


class FourierConfig(_Model):
    """The ``fourier`` method's representation (Klehm 2014): M coefficients, float32 or 8-bit storage."""

    coefficients: Annotated[Int, Field(ge=4, le=128)] = 32
    storage_bits: Literal[0, 8] = 0

    @field_validator("coefficients")
    @classmethod
    def _even(cls, v: int) -> int:
        if v % 2:
            raise ValueError(f"must be even (cos/sin pairs), got {v}")
        return v


class MomentsConfig(_Model):
    """The ``moments4``/``moments6`` methods' representation (Peters 2017 Sec. 5.3-5.4).

    ``storage_bits``: 64 or 128 for four moments; 64 (60 used), 96 or 192 for six (null: 64).
    ``overestimation``: ``adaptive`` (Sec. 5.3.1) or a fixed weight in [0, 1] between the lower and upper bound.
    """

    storage_bits: Optional[Literal[64, 96, 128, 192]] = None
    overestimation: Union[Literal["adaptive"], Annotated[Float, Field(ge=0.0, le=1.0)]] = "adaptive"


class EpipolarConfig(_Model):
    """The ``epipolar`` method (Engelhardt & Dachsbacher 2010); see
    :class:`warpscatter.scattering.epipolar.EpipolarSettings` for every key's meaning."""

    lines: Annotated[Int, Field(ge=8, le=16384)] = 1024
    initial_samples: Annotated[Int, Field(ge=2, le=1024)] = 16
    samples_per_line: Optional[Annotated[Int, Field(ge=2)]] = None
    depth_threshold: Annotated[Float, Field(gt=0.0)] = 0.05
    kernel: Literal["gaussian", "shepard", "threshold"] = "gaussian"
    taps: Annotated[Int, Field(ge=3, le=5)] = 3
    distance_falloff: Annotated[Float, Field(ge=0.0)] = 0.5
    depth_sigma: Annotated[Float, Field(gt=0.0)] = 0.1
    min_weight: Annotated[Float, Field(gt=0.0, le=1.0)] = 0.05
    outer_lines: Annotated[Int, Field(ge=0, le=64)] = 2
    prefilter_light_texture: Bool = False
    fallback_stride: Annotated[Int, Field(ge=1, le=256)] = 4
    max_epipole_distance: Annotated[Float, Field(gt=0.0)] = 1000.0

    @model_validator(mode="after")
    def _samples(self) -> EpipolarConfig:
        if self.samples_per_line is not None and self.samples_per_line < self.initial_samples:
            raise ValueError(f"samples_per_line ({self.samples_per_line}) must be >= initial_samples "
                             f"({self.initial_samples})")
        return self


class ScatteringConfig(_Model):
    """Single-scattering technique and its parameters."""

    method: Literal[SCATTERING_METHODS] = "raymarch"  # type: ignore[valid-type]
    visibility: Literal["exact", "shadow_map"] = "exact"
    steps: Annotated[Int, Field(ge=1)] = 128
    seed: Int = 0
    jitter: Literal["per_pixel", "fixed"] = "per_pixel"  # raymarch / epipolar step pattern (raymarch.py module doc)
    shadow_map: ShadowMapConfig = Field(default_factory=dict)
    prefiltered: PrefilteredConfig = Field(default_factory=dict)
    fourier: FourierConfig = Field(default_factory=dict)
    moments: MomentsConfig = Field(default_factory=dict)
    epipolar: EpipolarConfig = Field(default_factory=dict)

    @model_validator(mode="after")
    def _moment_storage(self) -> ScatteringConfig:
        bits = self.moments.storage_bits
        allowed = {"moments4": (64, 128), "moments6": (64, 96, 192)}.get(self.method)
        if allowed and bits is not None and bits not in allowed:
            raise ValueError(f"moments.storage_bits {bits} is not a {self.method} mode (choose from "
                             f"{', '.join(map(str, allowed))})")
        if allowed and self.prefiltered.splits != 1:
            raise ValueError("prefiltered.splits > 1 is implemented for the fourier method only")
        return self


class SurfacesConfig(_Model):
    """Surface shading switch (false: surfaces render black)."""

    enabled: Bool = True


class ShadowsConfig(_Model):
    """Surface shadows: ``pcf``, moment shadow maps ``msm`` (filtered hard shadows, translucent occluders),
    moment soft shadows ``msm_soft``, their brute-force reference ``pcss``, or ``none`` (Peters 2017 Sec. 2-4).

    ``filter_px`` is the PCF box or the MSM Gaussian width in texels; ``storage`` the MSM bits per texel
    (64: Theta_4* in 16-bit fixed point, 128: float32; ``msm_soft`` always uses 128); ``supersampling`` the
    depth samples per texel and axis of the moment map; ``coloured`` one map per RGB channel for tinted
    translucency; ``light_angle_deg`` (directional, full angle) or ``light_size`` (spot, scene units) the
    area light of the soft methods; ``max_kernel_px`` their widest region side (n_t = max_kernel_px^2);
    ``sampling`` the ``msm`` look-up: ``bilinear`` or ``mipmap`` (trilinear in the moment map's mip chain at the
    level of each pixel's footprint in shadow-map texels).
    """

    method: Literal["pcf", "msm", "msm_soft", "pcss", "none"] = "pcf"
    filter_px: Annotated[Int, Field(ge=1, le=64)] = 3
    storage: Literal[64, 128] = 64
    supersampling: Annotated[Int, Field(ge=1, le=8)] = 2
    coloured: Bool = False
    max_translucent_layers: Annotated[Int, Field(ge=1, le=64)] = 16
    light_angle_deg: Annotated[Float, Field(gt=0.0, lt=180.0)] = 1.0
    light_size: Annotated[Float, Field(gt=0.0)] = 0.5
    max_kernel_px: Annotated[Int, Field(ge=4, le=256)] = 28
    sampling: Literal["bilinear", "mipmap"] = "bilinear"  # msm look-ups: level 0, or trilinear at the pixel footprint


class CSMBuildConfig(_Model):
    """The coherent shadow map of the lighting methods: a ``file`` from ``warpscatter precompute`` (.npz), or built
    on the fly from the scene's occluders with these parameters (``maps`` lat-long N1 x N2 for environment lights,
    ``light_samples`` n1 x n2 cube-map points for area lights, n1 for linear lights)."""

    file: Optional[PathStr] = None
    maps: tuple[Annotated[Int, Field(ge=1, le=1024)], Annotated[Int, Field(ge=1, le=1024)]] = (64, 32)
    light_samples: tuple[Annotated[Int, Field(ge=1, le=256)], Annotated[Int, Field(ge=1, le=256)]] = (8, 8)
    resolution: Annotated[Int, Field(ge=8, le=4096)] = 128
    enumeration: Literal["hilbert", "zigzag", "scanline"] = "hilbert"
    layers: Literal["z1z2", "z1z3"] = "z1z2"
    far: Literal["sphere", "infinite"] = "sphere"
    batch: Annotated[Int, Field(ge=1, le=4096)] = 64
    local_lights: Literal["cube", "semi_local"] = "cube"  # area / linear lights: cube maps, or lat-long (Sec. 4.3)

    @field_validator("file")
    @classmethod
    def _check_file(cls, v: Path | None, info: ValidationInfo) -> Path | None:
        if v is None:
            return v
        p = _existing_file(_resolve(v, info))
        if p.suffix != ".npz":
            raise ValueError(f"a CSM file from 'warpscatter precompute' ends in .npz, got {p.name}")
        return p


class LightingConfig(_Model):
    """Monte-Carlo direct lighting (Ritschel 2007 Sec. 5) of environment, area and linear lights: ``csm`` (coherent
    shadow maps) or ``raytrace`` (wp.Mesh shadow rays, the reference); null: the classic pipeline."""

    method: Optional[Literal[LIGHTING_METHODS]] = None  # type: ignore[valid-type]
    samples: Annotated[Int, Field(ge=1, le=65536)] = 16
    passes: Annotated[Int, Field(ge=1, le=100000)] = 8
    seed: Int = 0
    filter: Literal["nearest", "pcf", "roulette"] = "roulette"
    bias: Optional[Annotated[Float, Field(ge=0.0)]] = None
    normal_offset: Optional[Annotated[Float, Field(ge=0.0)]] = None
    write_every: Annotated[Int, Field(ge=0)] = 1
    background: Bool = True
    csm: CSMBuildConfig = Field(default_factory=dict)

    @field_validator("samples")
    @classmethod
    def _square(cls, v: int) -> int:
        if math.isqrt(v) ** 2 != v:
            raise ValueError(f"must be a perfect square (a jittered s x s grid of strata), got {v}")
        return v


class RenderConfig(_Model):
    """Render settings."""

    scattering: ScatteringConfig = Field(default_factory=dict)
    surfaces: SurfacesConfig = Field(default_factory=dict)
    shadows: ShadowsConfig = Field(default_factory=dict)
    lighting: LightingConfig = Field(default_factory=dict)


# ---- output --------------------------------------------------------------------------------------


class OutputConfig(_Model):
    """Where results go: ``dir`` (relative to the config file), file stem ``name``, ``aovs``, PNG ``exposure``."""

    dir: PathStr = Path("out")
    name: str = "render"
    aovs: list[Literal["color", "scattering", "surface", "depth"]] = Field(default_factory=lambda: list(AOV_NAMES))
    exposure: Annotated[Float, Field(gt=0.0)] = 1.0

    @field_validator("dir")
    @classmethod
    def _resolve_dir(cls, v: Path, info: ValidationInfo) -> Path:
        p = _resolve(v, info)
        if p.exists() and not p.is_dir():
            raise ValueError(f"not a directory: {p}")
        return p

    @field_validator("name")
    @classmethod
    def _plain_stem(cls, v: str) -> str:
        if not v or v in (".", "..") or v != v.strip() or any(c in v for c in '/\\:*?"<>|\0'):
            raise ValueError(f"must be a plain file stem (no folders or special characters), got {v!r}")
        return v

    @field_validator("aovs")
    @classmethod
    def _dedupe(cls, v: list[str]) -> list[str]:
        return list(dict.fromkeys(v))


# ---- the whole config ----------------------------------------------------------------------------


class Config(_Model):
    """A validated pipeline configuration (see the module docstring and CONVENTIONS.md).

    ``config_dir`` (the folder relative paths were resolved against) and ``source`` (the file, if
    any) are kept as private attributes and never dumped.
    """

    scene: SceneConfig
    camera: CameraConfig
    light: LightConfig
    medium: MediumConfig = Field(default_factory=dict)
    render: RenderConfig = Field(default_factory=dict)
    output: OutputConfig = Field(default_factory=dict)

    _config_dir: Path = PrivateAttr(default_factory=Path.cwd)
    _source: Path | None = PrivateAttr(default=None)

    @model_validator(mode="after")
    def _lighting_fits_light(self) -> Config:
        lighting = self.render.lighting.method
        problems = []
        if lighting is None:
            if self.light.type in MC_LIGHT_TYPES:
                problems.append(f"light.type {self.light.type!r} needs render.lighting.method csm or raytrace "
                                f"(Monte-Carlo direct lighting)")
            for k, mesh in enumerate(self.scene.meshes):
                if mesh.material.brdf is not None:
                    problems.append(f"scene.meshes.{k}.material.brdf is used by render.lighting.method csm or "
                                    f"raytrace only (the classic surfaces are Lambertian)")
        elif self.light.type not in MC_LIGHT_TYPES:
            problems.append(f"render.lighting.method {lighting!r} lights {', '.join(MC_LIGHT_TYPES)} lights "
                            f"(light.type is {self.light.type!r}; use render.scattering for it)")
        elif all(m.receiver_only for m in self.scene.meshes) and self.render.lighting.csm.file is None \
                and lighting == "csm":
            problems.append("render.lighting: every mesh is receiver_only, so there is no occluder to build a CSM of")
        if lighting is None and all(m.receiver_only for m in self.scene.meshes):
            problems.append("scene.meshes: every mesh is receiver_only, so nothing casts a shadow (drop the flag "
                            "from the casters)")
        if problems:
            raise ValueError("\n".join(problems))
        return self

    @model_validator(mode="after")
    def _method_fits_light(self) -> Config:
        method = self.render.scattering.method
        lighting = self.render.lighting.method
        if lighting is not None:  # render.scattering and render.shadows are not used by the lighting methods
            problems = []
            if method != "raymarch":
                problems.append(f"render.scattering.method {method!r} is not used by render.lighting.method "
                                f"{lighting!r} (it renders no in-scattering); remove it or set "
                                f"render.lighting.method=null")
            if self.render.shadows.method != "pcf":
                problems.append(f"render.shadows.method {self.render.shadows.method!r} is not used by "
                                f"render.lighting.method {lighting!r} (its visibility is the CSM or shadow rays)")
            if problems:
                raise ValueError("\n".join(problems))
            return self
        if method in ("fourier", "moments4", "moments6") and self.light.type != "directional":
            raise ValueError(f"render.scattering.method {method!r} needs a directional light (light.type is "
                             f"{self.light.type!r})")
        return self

    @model_validator(mode="after")
    def _remember_dir(self, info: ValidationInfo) -> Config:
        self._config_dir = _context_dir(info)
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

    @classmethod
    def from_dict(cls, data: dict, config_dir: str | Path | None = None) -> Config:
        """Validate a plain dict; relative paths resolve against ``config_dir`` (default: cwd).

        Raises:
            ConfigError: listing every problem as ``key.path: reason``.
        """
        try:
            return cls.model_validate(data, context={"config_dir": config_dir})
        except ValidationError as exc:
            raise ConfigError(format_validation_errors(exc)) from None

    def model_dump_yaml(self) -> str:
        """The resolved config (absolute paths, defaults filled in, directions normalised) as YAML."""
        return yaml.safe_dump(self.model_dump(mode="json", exclude_none=True), sort_keys=False, default_flow_style=None)


# ---- YAML ----------------------------------------------------------------------------------------


class _Loader(yaml.SafeLoader):
    """SafeLoader that rejects duplicate keys and reads ``1e-3`` as a float (as YAML 1.2 does)."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=True)
                if isinstance(key, typing.Hashable) and key in seen:
                    raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", key_node.start_mark)
                seen.add(key)
        return super().construct_mapping(node, deep=deep)


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def _yaml_problem(exc: yaml.YAMLError) -> str:
    mark = getattr(exc, "problem_mark", None)
    what = " ".join(str(x) for x in (getattr(exc, "context", None), getattr(exc, "problem", None)) if x) or str(exc)
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
    ``[0, 1, 2]`` -> list, ``raymarch`` -> str, ``true`` -> bool).

    Raises:
        ValueError: when the text is not ``KEY=VALUE`` or the value is not valid YAML.
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
    except yaml.YAMLError as exc:
        raise ValueError(f"value is not valid YAML ({_yaml_problem(exc)})") from None
    return path, value


def _dotted(path) -> str:
    return ".".join(str(p) for p in path)


def _apply_override(data: dict, path: tuple, value: Any) -> None:
    node: Any = data
    for depth, seg in enumerate(path[:-1]):
        here = _dotted(path[: depth + 1])
        if isinstance(node, dict):
            if isinstance(seg, int):
                seg = str(seg)
            if node.get(seg) is None:
                node[seg] = [] if isinstance(path[depth + 1], int) else {}
            node = node[seg]
        elif isinstance(node, list):
            if isinstance(seg, int) and seg == len(node):  # one past the end appends a new item
                node.append([] if isinstance(path[depth + 1], int) else {})
            node = node[_list_index(node, seg, _dotted(path[:depth]))]
        else:
            raise ValueError(f"{_dotted(path[:depth])} is not a mapping, cannot set {here}")
    last = path[-1]
    if isinstance(node, dict):
        node[str(last)] = value
    elif isinstance(node, list):
        idx = len(node) if isinstance(last, int) and last == len(node) else _list_index(node, last, _dotted(path[:-1]))
        if idx == len(node):
            node.append(value)
        else:
            node[idx] = value
    else:
        raise ValueError(f"{_dotted(path[:-1])} is not a mapping, cannot set {_dotted(path)}")


def _list_index(node: list, seg, where: str) -> int:
    if not isinstance(seg, int):
        raise ValueError(f"{where} is a list: use an item index, not {seg!r}")
    if seg >= len(node):
        raise ValueError(f"index {seg} out of range ({where} has {len(node)} item(s))")
    return seg


# ---- validation errors ---------------------------------------------------------------------------


def _unwrap(tp):
    """Strip Annotated / Optional layers from a type annotation."""
    while True:
        origin = typing.get_origin(tp)
        if origin is Annotated:
            tp = typing.get_args(tp)[0]
        elif origin in (Union, types.UnionType):
            args = [a for a in typing.get_args(tp) if a is not type(None)]
            if len(args) == 1:
                tp = args[0]
            else:
                return tp
        else:
            return tp


def _display_loc(loc: tuple) -> tuple[tuple, type | None]:
    """Drop discriminated-union tag segments from a pydantic error location.

    Returns the user-facing key path and the model class at its end (None when not a model).
    """
    out: list = []
    tp: Any = Config
    for seg in loc:
        tp = _unwrap(tp)
        if typing.get_origin(tp) in (Union, types.UnionType):
            members = {}
            for m in typing.get_args(tp):
                m = _unwrap(m)
                if isinstance(m, type) and issubclass(m, BaseModel) and "type" in m.model_fields:
                    for tag in typing.get_args(_unwrap(m.model_fields["type"].annotation)):
                        members[tag] = m
            if seg in members:  # a union tag, not a key the user wrote
                tp = members[seg]
                continue
            tp = None
        out.append(seg)
        if isinstance(tp, type) and issubclass(tp, BaseModel) and isinstance(seg, str) and seg in tp.model_fields:
            tp = tp.model_fields[seg].annotation
        elif typing.get_origin(tp) is list and isinstance(seg, int):
            tp = typing.get_args(tp)[0]
        else:
            tp = None
    tp = _unwrap(tp) if tp is not None else None
    return tuple(out), tp if isinstance(tp, type) and issubclass(tp, BaseModel) else None


def _short(value: Any) -> str:
    r = repr(value)
    return r if len(r) <= 60 else r[:57] + "..."


def _reason(err: dict) -> str:
    kind, ctx, value = err["type"], err.get("ctx") or {}, err.get("input")
    if kind == "extra_forbidden":
        return "unknown key"
    if kind == "missing":
        return "required key missing"
    if kind in ("value_error", "assertion_error"):
        return str(ctx.get("error", err["msg"]))
    if kind == "literal_error":
        return f"must be one of {ctx.get('expected')} (got {_short(value)})"
    if kind == "union_tag_invalid":
        return f"unknown type {ctx.get('tag')!r} (choose from {ctx.get('expected_tags')})"
    if kind == "union_tag_not_found":
        return "required key missing"
    bounds = {"greater_than": ">", "greater_than_equal": ">=", "less_than": "<", "less_than_equal": "<="}
    if kind in bounds:
        bound = next(iter(ctx.values()), "?")
        bound = f"{bound:g}" if _is_number(bound) else bound
        return f"must be {bounds[kind]} {bound} (got {_short(value)})"
    expected = {
        "int_type": "an integer",
        "int_parsing": "an integer",
        "int_from_float": "an integer",
        "float_type": "a number",
        "float_parsing": "a number",
        "bool_type": "true or false",
        "bool_parsing": "true or false",
        "string_type": "a string",
        "list_type": "a list",
        "dict_type": "a mapping (key: value)",
        "model_type": "a mapping (key: value)",
        "model_attributes_type": "a mapping (key: value)",
    }
    if kind in expected:
        return f"expected {expected[kind]}, got {_short(value)}"
    if kind == "finite_number":
        return f"must be finite (got {_short(value)})"
    if kind == "too_short":
        return f"needs at least {ctx.get('min_length')} item(s)"
    if kind == "too_long":
        return f"takes at most {ctx.get('max_length')} item(s)"
    return err["msg"]


def format_validation_errors(
    exc: ValidationError, key_lines: dict[tuple, int] | None = None, overridden: tuple = ()
) -> list[str]:
    """Turn a pydantic ValidationError into ``key.path: reason`` lines.

    Args:
        exc: the error raised by :meth:`Config.model_validate`.
        key_lines: optional map key path -> line in the YAML file, to append ``(line N)``.
        overridden: key paths set with ``--set``; problems under them are marked ``(from --set)``.
    """
    key_lines = key_lines or {}
    problems: list[str] = []
    for err in exc.errors(include_url=False):
        loc, _ = _display_loc(tuple(err["loc"]))
        parent_loc, parent_model = _display_loc(tuple(err["loc"])[:-1])
        reason = _reason(err)
        if err["type"] in ("union_tag_invalid", "union_tag_not_found"):
            loc = (*loc, "type")
        if err["type"] == "extra_forbidden" and parent_model is not None:
            reason += _did_you_mean(loc[-1], parent_model.model_fields)
        where = ""
        if any(loc[: len(o)] == o for o in overridden):
            where = " (from --set)"
        else:
            for n in range(len(loc), 0, -1):
                if loc[:n] in key_lines:
                    where = f" (line {key_lines[loc[:n]]})"
                    break
        key = _dotted(loc) or "config"
        for line in reason.splitlines() or [""]:
            problems.append(f"{key}: {line}{where}")
    return problems


# ---- loading -------------------------------------------------------------------------------------


def load_config(path: str | Path, overrides: list[str] | tuple[str, ...] = ()) -> Config:
    """Read, override and validate a YAML config file.

    Args:
        path: the YAML file; relative paths inside it resolve against its folder.
        overrides: ``KEY=VALUE`` strings applied in order before validation
            (``camera.position=[0,1,2]``, ``scene.meshes.0.material.opacity=0.5``).

    Returns:
        The validated :class:`Config`, with absolute paths and ``config_dir`` set.

    Raises:
        ConfigError: the file cannot be read or parsed, an override is malformed, or the config is
            invalid; the message names the file and lists every problem as ``key.path: reason``.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {path.resolve()}", path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read config: {exc}", path) from None
    try:
        data = yaml.load(text, Loader=_Loader)
    except yaml.YAMLError as exc:
        raise ConfigError(_yaml_problem(exc), path) from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"config: expected a mapping at the top level, got {type(data).__name__}", path)

    problems, overridden = [], []
    for text_override in overrides:
        try:
            key_path, value = parse_override(text_override)
            _apply_override(data, key_path, value)
            overridden.append(key_path)
        except ValueError as exc:
            problems.append(f"--set {text_override}: {exc}")
    if problems:
        raise ConfigError(problems, path)

    config_dir = path.resolve().parent
    try:
        return Config.model_validate(data, context={"config_dir": config_dir, "source": path.resolve()})
    except ValidationError as exc:
        raise ConfigError(format_validation_errors(exc, _key_lines(text), tuple(overridden)), path) from None
