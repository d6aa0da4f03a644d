"""Warp-free building blocks of every settings model: the strict base model, field types, key-path errors.

Each technique's keys are a pydantic model beside it, built from :class:`SettingsModel` and these field types, and
:mod:`warpscatter.config` composes them; ``Field(description=...)`` and the types' bounds feed the JSON schema and
docs/reference/config.md. Every numeric key has both bounds, chosen so that float32 arithmetic (largest 3.4e38,
24-bit mantissa) stays finite and meaningful. :func:`format_validation_errors` gives ``key.path: reason`` lines.
"""

from __future__ import annotations

import difflib
import math
import re
import types
import typing
from pathlib import Path
from typing import Annotated, Any, Union

from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    Strict,
    ValidationError,
    ValidationInfo,
    model_validator,
)

#: Largest accepted image / shadow-map side, in pixels (guards against typos such as 19200).
MAX_IMAGE_SIDE = 16384


#: Largest |component| and length in scene units; 4 MAX_COORD^2 and its products with MAX_SIGMA_T fit float32.
MAX_COORD = 1.0e6
#: Smallest positive length in scene units: squares of shorter ones approach float32's smallest normals.
MIN_LENGTH = 1.0e-6
#: Largest camera far / near: float32 depths hold 24 bits, so a larger ratio cannot order surfaces near far.
MAX_DEPTH_RATIO = 1.0e7
#: Field of view limits (degrees): the pixel footprint grows without bound towards 180; 0.01 nears float32's step.
MIN_FOV_DEG = 0.01
MAX_FOV_Y_DEG = 170.0
#: Smallest cone half-angle of a spot light (degrees): its projection divides by tan(cone_deg).
MIN_CONE_DEG = 0.01
#: Largest extinction sigma_t (1 / scene unit): a mean free path of 1e-4 units; sigma_t x MAX_COORD = 1e10.
MAX_SIGMA_T = 1.0e4
#: Largest |g| of the Henyey-Greenstein phase function: 1 + g^2 - 2 g cos cancels in float32 from |g| ~ 0.9999.
MAX_HG_G = 0.99
#: Largest component of a light's irradiance, intensity, radiance or power, and of an environment map's scale.
MAX_EMISSION = 1.0e6
#: Largest dimensionless factor (PNG exposure, a Lafortune lobe's colour and peak).
MAX_GAIN = 1.0e6
#: Largest |rotation angle| of a transform (degrees): 27.7 turns.
MAX_ROTATION_DEG = 1.0e4
#: Mesh scale factors (per axis).
MIN_SCALE = 1.0e-6
MAX_SCALE = 1.0e6
#: Random seeds: 0 .. 2^31 - 1 (the kernels' 32-bit seeds).
MAX_SEED = 2**31 - 1
#: Most ray-march steps per ray.
MAX_STEPS = 65536
#: Largest frame number of an animation (frames and keyframes); at most :data:`MAX_FRAMES` frames.
MAX_FRAME = 1_000_000
MAX_FRAMES = 100_000




def is_number(x: Any) -> bool:
    """True for int and float values, not bool."""
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def vec3(v: Any) -> tuple[float, float, float]:
    """Accept a list of 3 numbers; return a tuple of 3 finite floats."""
    if isinstance(v, (list, tuple)) and len(v) == 3 and all(is_number(x) for x in v):
        out = tuple(float(x) for x in v)
        if not all(math.isfinite(x) for x in out):
            raise ValueError(f"must be finite, got {list(v)}")
        return out
    raise ValueError(f"expected a list of 3 numbers [x, y, z], got {v!r}")


def length(v) -> float:
    """|v| without overflow or underflow (``math.hypot`` only where plain sqrt is not exact enough)."""
    n = math.sqrt(sum(x * x for x in v))
    return n if 1e-150 < n < 1e150 else math.hypot(*v)


def unit(v) -> tuple[float, ...]:
    """``v / |v|`` for any finite non-zero ``v`` (however large or small its components); ValueError for zero."""
    n = length(v)
    if n == 0.0:
        raise ValueError("must be non-zero")
    return tuple(x / n for x in v)


def _nonzero_unit(v: tuple[float, float, float]) -> tuple[float, float, float]:
    n = length(v)
    if n == 0.0:
        raise ValueError("must be non-zero")
    if abs(n - 1.0) <= 4e-16 * 3:  # already unit (a validated config validated again): keep it bit for bit
        return tuple(v)
    return tuple(x / n for x in v)


def _nonzero(v: tuple[float, float, float]) -> tuple[float, float, float]:
    if not any(v):
        raise ValueError("must be non-zero")
    return v


def _min_length(v: tuple[float, float, float]) -> tuple[float, float, float]:
    if 0.0 < length(v) < MIN_LENGTH:
        raise ValueError(f"must be at least {MIN_LENGTH:g} long, got {list(v)}")
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


def scalar_or_rgb(lo: float, hi: float | None = None, what: str = "number"):
    """A BeforeValidator accepting one number or a list of 3 [r, g, b] in [lo, hi]; ``type_text`` for the docs."""

    def check(v: Any):
        if is_number(v):
            parts, out = [float(v)], float(v)
        elif isinstance(v, (list, tuple)) and len(v) == 3 and all(is_number(x) for x in v):
            parts = [float(x) for x in v]
            out = tuple(parts)
        else:
            raise ValueError(f"expected a number or a list of 3 numbers [r, g, b], got {_short(v)}")
        if not all(math.isfinite(x) for x in parts):
            raise ValueError(f"must be finite, got {_short(v)}")
        if min(parts) < lo:
            raise ValueError(f"must be >= {lo:g} (got {_short(v)})")
        if hi is not None and max(parts) > hi:
            raise ValueError(f"must be <= {hi:g} (got {_short(v)})")
        return out

    check.type_text = f"{what} or [r, g, b], each " + (f">= {lo:g}" if hi is None else f"{lo:g}–{hi:g}")
    return BeforeValidator(check)


def scalar_or_rgb_type(lo: float, hi: float, what: str = "number") -> Any:
    """The type of one number or a list of 3 [r, g, b], each in [lo, hi] (:func:`scalar_or_rgb`)."""
    item = bounded_float(lo, hi)
    return Annotated[Union[item, tuple[item, item, item]], scalar_or_rgb(lo, hi, what)]


def bounded_float(lo: float, hi: float) -> Any:
    """A float in [lo, hi] (its JSON schema states the bounds)."""
    return Annotated[float, Field(ge=lo, le=hi)]


def vec3_in(lo: float, hi: float, type_text: str, *after: Any, interval: bool = True) -> Any:
    """The type of a list of 3 finite numbers [x, y, z], each in [lo, hi], then ``after`` validators; range errors
    name the whole vector."""

    def check(v: Any) -> tuple[float, float, float]:
        out = vec3(v)
        if interval and (min(out) < lo or max(out) > hi):
            raise ValueError(f"every component must lie in [{lo:g}, {hi:g}], got {_short(list(v))}")
        if min(out) < lo:
            raise ValueError(f"every component must be >= {lo:g}, got {_short(list(v))}")
        if max(out) > hi:
            raise ValueError(f"every component must be <= {hi:g}, got {_short(list(v))}")
        return out

    check.type_text = type_text
    item = bounded_float(lo, hi)
    return Annotated[(tuple[item, item, item], BeforeValidator(check), *after)]


_C = f"{MAX_COORD:g}"
#: A point, a translation (scene units): each component within +-MAX_COORD.
Vec3 = vec3_in(-MAX_COORD, MAX_COORD, f"[x, y, z], each in [-{_C}, {_C}]")
#: A direction, normalised on load (without overflow); components within +-MAX_COORD.
Direction = vec3_in(-MAX_COORD, MAX_COORD, f"direction [x, y, z] (normalised), each in [-{_C}, {_C}]",
                    AfterValidator(_nonzero_unit))
#: An edge vector (scene units): non-zero, at least MIN_LENGTH long, components within +-MAX_COORD.
NonZeroVec3 = vec3_in(-MAX_COORD, MAX_COORD, f"[x, y, z], non-zero, each in [-{_C}, {_C}]",
                      AfterValidator(_nonzero), AfterValidator(_min_length))
#: Rotation angles about X, Y, Z (degrees).
Rotation = vec3_in(-MAX_ROTATION_DEG, MAX_ROTATION_DEG,
                   f"[x, y, z] degrees, each in [-{MAX_ROTATION_DEG:g}, {MAX_ROTATION_DEG:g}]")
#: A light's RGB irradiance, intensity, radiance or power: each in [0, MAX_EMISSION].
RGB = vec3_in(0.0, MAX_EMISSION, f"RGB, each 0–{MAX_EMISSION:g}", interval=False)
#: A reflectance: RGB in [0, 1].
Albedo = vec3_in(0.0, 1.0, "RGB in [0, 1]")
Float = Annotated[float, Strict(), Field(allow_inf_nan=False)]
Int = Annotated[int, Strict()]


def _seed(v: Any) -> Any:
    return v  # the bounds are the Field's; this names them for the config reference


_seed.type_text = f"int 0–{MAX_SEED} (2^31 - 1)"
#: A random seed, 0 .. MAX_SEED.
Seed = Annotated[Int, Field(ge=0, le=MAX_SEED), BeforeValidator(_seed)]
Bool = Annotated[bool, Strict()]
PathStr = Annotated[Path, BeforeValidator(_path_string)]


def context_dir(info: ValidationInfo) -> Path:
    """The folder relative paths resolve against: the validation context's ``config_dir``, else the cwd."""
    ctx = info.context or {}
    d = ctx.get("config_dir")
    return Path(d).resolve() if d is not None else Path.cwd()


def resolve_path(p: Path, info: ValidationInfo) -> Path:
    """``p`` made absolute against :func:`context_dir` (``~`` expanded)."""
    p = Path(p).expanduser()
    return p if p.is_absolute() else (context_dir(info) / p).resolve()


def existing_file(p: Path) -> Path:
    """``p`` when it is an existing file; ValueError (a config problem) otherwise."""
    if not p.exists():
        raise ValueError(f"file not found: {p}")
    if not p.is_file():
        raise ValueError(f"not a file: {p}")
    return p


class SettingsModel(BaseModel):
    """Base of every settings model: unknown keys are errors, defaults are validated, an empty section = defaults."""

    # Defaults validated inside the validation context, so a default ``output.dir`` resolves against the config folder.
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
            annotation = unwrap(field.annotation) if field is not None else None
            is_section = isinstance(annotation, type) and issubclass(annotation, BaseModel)
            if v is None and is_section and not field.is_required():
                continue
            out[k] = v
        return out


def did_you_mean(word: str, choices) -> str:
    """`` (did you mean 'x'?)`` for the closest of ``choices`` to ``word``, or an empty string."""
    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def dotted(path) -> str:
    """A key path as written in configs and errors: ``render.scattering.steps``, ``scene.meshes.0.path``."""
    return ".".join(str(p) for p in path)




def unwrap(tp):
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


def _display_loc(loc: tuple, root: type[BaseModel]) -> tuple[tuple, type | None, bool]:
    """Drop union segments (discriminator tags, alternative names) from a pydantic error location under ``root``:
    the user-facing key path, the model class at its end (or None) and whether the error is one alternative of a
    plain union."""
    out: list = []
    tp: Any = root
    alternative = False
    for seg in loc:
        tp = unwrap(tp)
        if typing.get_origin(tp) in (Union, types.UnionType):
            members = {}
            for m in typing.get_args(tp):
                m = unwrap(m)
                if isinstance(m, type) and issubclass(m, BaseModel) and "type" in m.model_fields:
                    for tag in typing.get_args(unwrap(m.model_fields["type"].annotation)):
                        members[tag] = m
            if seg in members:  # a union tag, not a key the user wrote
                tp = members[seg]
                continue
            if not members and isinstance(seg, str):  # the name of an alternative of a plain union: not a key
                tp, alternative = None, True
                continue
            tp = None
        out.append(seg)
        if isinstance(tp, type) and issubclass(tp, BaseModel) and isinstance(seg, str) and seg in tp.model_fields:
            tp = tp.model_fields[seg].annotation
        elif typing.get_origin(tp) is list and isinstance(seg, int):
            tp = typing.get_args(tp)[0]
        else:
            tp = None
    tp = unwrap(tp) if tp is not None else None
    return tuple(out), tp if isinstance(tp, type) and issubclass(tp, BaseModel) else None, alternative


def _merge_alternatives(reasons: list[str]) -> str:
    """One reason for the errors of a plain union's alternatives (``must be one of 'adaptive' or must be <= 1``)."""
    got = {m.group(1) for r in reasons if (m := re.search(r" \(got (.*)\)$", r))}
    if len(got) == 1 and all(re.search(r" \(got .*\)$", r) for r in reasons):
        return " or ".join(re.sub(r" \(got .*\)$", "", r) for r in reasons) + f" (got {got.pop()})"
    return " or ".join(reasons)


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
        if isinstance(bound, int) and not isinstance(bound, bool):
            bound = str(bound)  # exact: "%g" would print 2^31 - 1 as 2.14748e+09, below the seeds it allows
        elif is_number(bound):
            bound = f"{bound:g}"
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
    exc: ValidationError, root: type[BaseModel], key_lines: dict[tuple, int] | None = None, overridden: tuple = ()
) -> list[str]:
    """Turn a pydantic ValidationError into ``key.path: reason`` lines.

    Args:
        exc: the error raised by ``root.model_validate``.
        root: the model that was validated (key paths start at it).
        key_lines: optional map key path -> line in the YAML file, to append ``(line N)``.
        overridden: key paths set with ``--set``; problems under them are marked ``(from --set)``.
    """
    key_lines = key_lines or {}
    problems: list[str] = []
    errors, alternatives = [], {}
    for err in exc.errors(include_url=False):
        loc, _, alternative = _display_loc(tuple(err["loc"]), root)
        if alternative and err["type"] not in ("union_tag_invalid", "union_tag_not_found"):
            if loc not in alternatives:
                alternatives[loc] = []
                errors.append((err, loc))
            alternatives[loc].append(_reason(err))
        else:
            errors.append((err, None))
    for err, merged in errors:
        loc, _, _ = _display_loc(tuple(err["loc"]), root)
        _, parent_model, _ = _display_loc(tuple(err["loc"])[:-1], root)
        reason = _reason(err) if merged is None else _merge_alternatives(alternatives[merged])
        if err["type"] in ("union_tag_invalid", "union_tag_not_found"):
            loc = (*loc, "type")
        if err["type"] == "extra_forbidden" and parent_model is not None:
            reason += did_you_mean(loc[-1], parent_model.model_fields)
        where = ""
        if any(loc[: len(o)] == o for o in overridden):
            where = " (from --set)"
        else:
            for n in range(len(loc), 0, -1):
                if loc[:n] in key_lines:
                    where = f" (line {key_lines[loc[:n]]})"
                    break
        key = dotted(loc)
        for line in reason.splitlines() or [""]:
            # a check of the whole config names its keys itself ("render.scattering.method 'x' needs ...")
            named = not key and re.match(r"[a-z_]+(\.[\w]+)+[: ]", line)
            problems.append(f"{line}{where}" if named else f"{key or 'config'}: {line}{where}")
    return problems

