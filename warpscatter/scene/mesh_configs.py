"""The ``scene`` section: its meshes (a file or a procedural generator each), their placement and materials.

Warp-free settings models composed by :class:`warpscatter.config.Config` (which re-exports them); the scene they
describe is built by :func:`warpscatter.scene.build_scene`.
"""

from __future__ import annotations

import inspect
import math
from pathlib import Path
from typing import Annotated, Any, Literal, Optional, Union

from pydantic import BeforeValidator, Field, ValidationInfo, field_validator, model_validator

from ..schema import (
    MAX_COORD,
    MAX_GAIN,
    MAX_SCALE,
    MIN_SCALE,
    Albedo,
    Bool,
    Float,
    PathStr,
    Rotation,
    SettingsModel,
    Vec3,
    bounded_float,
    did_you_mean,
    existing_file,
    is_number,
    resolve_path,
    vec3,
    vec3_in,
)
from . import CASTER_ALPHA_TEST

#: Mesh file suffixes accepted in ``scene.meshes.N.path`` (loaded with trimesh).
MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")


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
        from .procedural import GENERATORS
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

    def no_caster(self) -> str:
        """Why no mesh casts a shadow (every visibility method's casters: not ``receiver_only``, opacity at least
        the alpha test's :data:`~warpscatter.scene.CASTER_ALPHA_TEST`), or "" when one does."""
        if all(m.receiver_only for m in self.meshes):
            return "every mesh is receiver_only"
        if all(m.receiver_only or m.material.opacity < CASTER_ALPHA_TEST for m in self.meshes):
            return (f"every mesh is receiver_only or has an opacity below {CASTER_ALPHA_TEST:g} (the alpha test: it "
                    "casts nothing)")
        return ""


__all__ = [
    "MESH_SUFFIXES",
    "LafortuneBRDFConfig",
    "LafortuneLobeConfig",
    "Material",
    "MeshEntry",
    "PhongBRDFConfig",
    "SceneConfig",
    "Transform",
]
