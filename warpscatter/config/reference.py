"""The config reference of the docs, generated from the settings models, the method registry and the generators.

Every key of a config is written once, in a settings model with its type, range, default and ``Field(description=...)``;
:func:`config_reference` turns the models into Markdown tables (one per section), :func:`method_table` lists the
registry (:mod:`warpscatter.methods`) and :func:`generator_reference` the parameters of the procedural generators
(:data:`warpscatter.scene.procedural.GENERATORS`: their signatures and the ``Args:`` sections of their docstrings).
``docs/reference/config.md`` holds them between ``<!-- generated: NAME -->`` markers; a test fails when they differ
from what the code says. No Warp import. Regenerate with::

    python -m warpscatter.config.reference docs/reference/config.md
"""

from __future__ import annotations

import re
import sys
import types
import typing
from pathlib import Path
from typing import Annotated, Any, Literal, Union

from annotated_types import Ge, Gt, Le, Lt, MaxLen, MinLen
from pydantic import AfterValidator, BaseModel, BeforeValidator
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

from .. import methods

#: Validators of the vector field types (:mod:`warpscatter.schema`) -> how the reference names them.
_VECTOR_KINDS = {"_nonzero_unit": "direction [x, y, z] (normalised)", "_nonzero": "[x, y, z], non-zero",
                 "_nonnegative": "RGB, each >= 0", "_unit_interval": "RGB in [0, 1]"}


def _bounds(metadata) -> str:
    """``1–64``, ``>= 0``, ``(0, 180)`` ... from annotated-types constraints."""
    lo = hi = None
    lo_open = hi_open = False
    for m in metadata:
        if isinstance(m, Ge):
            lo = m.ge
        elif isinstance(m, Gt):
            lo, lo_open = m.gt, True
        elif isinstance(m, Le):
            hi = m.le
        elif isinstance(m, Lt):
            hi, hi_open = m.lt, True
    fmt = "{:g}".format
    if lo is not None and hi is not None:
        if not lo_open and not hi_open:
            return f"{fmt(lo)}–{fmt(hi)}"
        return f"{'(' if lo_open else '['}{fmt(lo)}, {fmt(hi)}{')' if hi_open else ']'}"
    if lo is not None:
        return f"{'>' if lo_open else '>='} {fmt(lo)}"
    if hi is not None:
        return f"{'<' if hi_open else '<='} {fmt(hi)}"
    return ""


def _constraints(tp) -> tuple[Any, list]:
    """(bare type, constraint metadata) of an annotation, unwrapping Annotated and FieldInfo layers."""
    metadata: list = []
    while typing.get_origin(tp) is Annotated:
        args = typing.get_args(tp)
        tp = args[0]
        for a in args[1:]:
            metadata.extend(a.metadata if isinstance(a, FieldInfo) else [a])
    return tp, metadata


def describe_type(annotation, metadata=()) -> str:
    """A short human description of a field's type and range (Markdown)."""
    tp, inner = _constraints(annotation)
    metadata = [*metadata, *inner]
    validators = [m.func.__name__ for m in metadata if isinstance(m, (AfterValidator, BeforeValidator))]
    texts = [m.func.type_text for m in metadata if hasattr(getattr(m, "func", None), "type_text")]
    if texts:
        return texts[0]
    origin = typing.get_origin(tp)
    if origin in (Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        text = " \\| ".join(describe_type(a) for a in args)
        return f"{text} or null" if len(args) < len(typing.get_args(tp)) else text
    if origin is Literal:
        return " \\| ".join(f"`{str(v).lower() if isinstance(v, bool) else v}`" for v in typing.get_args(tp))
    if "vec3" in validators or (origin is tuple and typing.get_args(tp) == (float, float, float)):
        kinds = [_VECTOR_KINDS[v] for v in validators if v in _VECTOR_KINDS]
        return kinds[0] if kinds else "[x, y, z]"
    if "_path_string" in validators or tp is Path:
        return "file path"
    if origin is tuple:
        parts = [describe_type(a) for a in typing.get_args(tp)]
        return f"[{', '.join(parts)}]"
    if origin is list:
        (item,) = typing.get_args(tp)
        lengths = {type(m): m for m in metadata if isinstance(m, (MinLen, MaxLen))}
        n = ""
        if MinLen in lengths or MaxLen in lengths:
            n = f", {lengths[MinLen].min_length if MinLen in lengths else 0}–" \
                f"{lengths[MaxLen].max_length if MaxLen in lengths else 'n'} items"
        return f"list of {describe_type(item)}{n}"
    if origin is dict:
        return "mapping"
    names = {bool: "bool", int: "int", float: "number", str: "string"}
    name = names.get(tp, getattr(tp, "__name__", str(tp)))
    bounds = _bounds(metadata)
    return f"{name} {bounds}" if bounds else name


def _default(field: FieldInfo) -> str:
    if field.default is PydanticUndefined and field.default_factory is None:
        return "required"
    return _py_default(field.default_factory() if field.default is PydanticUndefined else field.default)


def _default_item(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _is_model(tp) -> bool:
    tp, _ = _constraints(tp)
    return isinstance(tp, type) and issubclass(tp, BaseModel)


def _model_union(tp) -> list:
    """The member models of a (possibly optional) union of models, else []."""
    tp, _ = _constraints(tp)
    if typing.get_origin(tp) not in (Union, types.UnionType):
        return []
    args = [a for a in typing.get_args(tp) if a is not type(None)]
    if len(args) == 1:
        return _model_union(args[0])
    return [_constraints(a)[0] for a in args if _is_model(a)]


def _tag(model) -> str:
    """The ``type`` value of a member of a discriminated union."""
    return typing.get_args(_constraints(model.model_fields["type"].annotation)[0])[0]


def summary(model) -> str:
    """The first paragraph of a model's docstring on one line, with Markdown code spans."""
    first = (model.__doc__ or "").strip().split("\n\n")[0]
    return " ".join(first.split()).replace("``", "`")


def _rows(model: type[BaseModel], prefix: str) -> list[tuple[str, str, str, str]]:
    """(key, type, default, meaning) of every leaf key of ``model`` under ``prefix`` (nested sections inline)."""
    rows = []
    for name, field in model.model_fields.items():
        key = f"{prefix}.{name}" if prefix else name
        tp, _ = _constraints(field.annotation)
        if _is_model(tp):
            rows += _rows(tp, key)
            continue
        if typing.get_origin(tp) is list and _is_model(typing.get_args(tp)[0]):
            _, meta = _constraints(field.annotation)
            at_least = next((m.min_length for m in [*field.metadata, *meta] if isinstance(m, MinLen)), 0)
            rows.append((key, f"list of mappings (>= {at_least}), keys `{key}.N.*` below", _default(field),
                         field.description or ""))
            rows += _rows(typing.get_args(tp)[0], f"{key}.N")
            continue
        union = _model_union(field.annotation)
        if union:  # a discriminated union of models (BRDFs): one block of keys per ``type``
            optional = " or null" if field.default is None else ""
            rows.append((f"{key}.type", " \\| ".join(f"`{_tag(m)}`" for m in union) + optional, _default(field),
                         field.description or ""))
            for m in union:
                rows += [(f"{k} ({_tag(m)})", t, d, why) for k, t, d, why in _rows(m, key) if not k.endswith(".type")]
            continue
        rows.append((key, describe_type(field.annotation, field.metadata), _default(field), field.description or ""))
    return rows


def settings_table(model: type[BaseModel], prefix: str = "", skip=()) -> str:
    """A Markdown table of every key of ``model`` (keys under ``prefix``; ``skip``: keys left out)."""
    lines = ["| key | type | default | meaning |", "| --- | --- | --- | --- |"]
    for key, tp, default, why in _rows(model, prefix):
        if key in skip:
            continue
        lines.append(f"| `{key}` | {tp} | {default} | {why} |")
    return "\n".join(lines)


def config_reference() -> str:
    """The config reference: one table per top-level section, one per light type."""
    from . import Config, LightConfig

    parts = []
    for name, field in Config.model_fields.items():
        if name == "light":
            for m in _model_union(LightConfig):
                parts.append(f"`light` with `type: {_tag(m)}` — {summary(m)}\n\n"
                             + settings_table(m, "light"))
            continue
        tp, _ = _constraints(field.annotation)
        if name == "render":
            for sub, sub_field in tp.model_fields.items():
                parts.append(f"`render.{sub}` — {sub_field.description}\n\n"
                             + settings_table(_constraints(sub_field.annotation)[0], f"render.{sub}"))
            continue
        if not _is_model(tp):  # an optional section (animation): its model
            tp = next(a for a in typing.get_args(tp) if _is_model(a))
        parts.append(f"`{name}` — {summary(tp)}\n\n" + settings_table(tp, name))
    return "\n\n".join(parts)


def method_table() -> str:
    """The registry as a Markdown table: method, section, paper, lights, visibility, settings."""
    visibility = {methods.VISIBILITY_CONFIGURABLE: "exact (BVH) or shadow map",
                  methods.VISIBILITY_SHADOW_MAP: "shadow map", methods.VISIBILITY_CSM: "coherent shadow map",
                  methods.VISIBILITY_RAYS: "shadow rays (BVH)"}
    lines = ["| method | key | implements | lights | visibility | its settings |",
             "| --- | --- | --- | --- | --- | --- |"]
    for table in (methods.SCATTERING, methods.LIGHTING):
        for m in table.values():
            sections = ", ".join(f"`render.{m.kind}.{s}`" for s in m.sections) or "the shared keys"
            lines.append(f"| `{m.name}` | `render.{m.kind}.method` | {m.paper} | {', '.join(m.lights)} | "
                         f"{visibility[m.visibility]} | {sections} |")
    return "\n".join(lines)


def _args_section(doc: str) -> dict[str, str]:
    """name -> description (one line) of the ``Args:`` section of a Google-style docstring."""
    out: dict[str, str] = {}
    lines = doc.splitlines()
    try:
        start = next(i for i, line in enumerate(lines) if line.strip() == "Args:")
    except StopIteration:
        return out
    indent = None
    name = None
    for line in lines[start + 1:]:
        if not line.strip():
            continue
        depth = len(line) - len(line.lstrip())
        if indent is None:
            indent = depth
        if depth < indent:  # the next section (Returns:, Raises:) or the end of Args
            break
        m = re.match(r"\s*(\w+)(?: \([^)]*\))?:\s*(.*)", line)
        if depth == indent and m:
            name = m.group(1)
            out[name] = m.group(2).strip()
        elif name is not None:
            out[name] += " " + line.strip()
    return out


def _py_type(annotation, default) -> str:
    """bool / int / number / list ... of a generator parameter (its annotation may be a string under PEP 563)."""
    text = annotation if isinstance(annotation, str) else getattr(annotation, "__name__", str(annotation))
    if isinstance(default, (tuple, list)) and default:
        items = {"int" if isinstance(v, int) and not isinstance(v, bool) else "number" for v in default}
        return f"list of {len(default)} {items.pop() if len(items) == 1 else 'numbers'}{'s' if len(items) == 0 else ''}"
    return {"float": "number", "str": "string"}.get(text, text)


#: The range a generator's ``Args:`` line states in parentheses: ``(1..64 each)``, ``(> 0)``, ``(>= 0; ...)``.
_RANGE = re.compile(r"\s*\(((?:[^()]*\d\.\.[^()]*)|(?:[<>]=?[^()]*))\)")


def _split_range(meaning: str) -> tuple[str, str]:
    """(range, meaning without it) of a generator parameter's description."""
    m = _RANGE.search(meaning)
    if not m:
        return "", meaning
    text = (meaning[:m.start()] + meaning[m.end():]).replace(" ,", ",").replace(" ;", ";").strip()
    return m.group(1).replace("..", "–"), text


def _py_default(value) -> str:
    """A default value as the reference writes it: YAML's null / true / false, ``%g`` numbers, ``[a, b]`` lists."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(_default_item(v) for v in value) + "]"
    return "null" if value is None else str(value)


def generator_table(name: str) -> str:
    """A Markdown table of the parameters (``params:`` keys) of procedural generator ``name``."""
    import inspect

    from ..scene import procedural

    fn = procedural._lookup(name)
    doc = inspect.getdoc(fn) or ""
    args = _args_section(doc)
    lines = ["| parameter | type | range | default | meaning |", "| --- | --- | --- | --- | --- |"]
    for p in inspect.signature(fn).parameters.values():
        bounds, meaning = _split_range(args.get(p.name, ""))
        row = [f"`{p.name}`", _py_type(p.annotation, p.default), bounds, _py_default(p.default), meaning]
        lines.append("| " + " | ".join(cell.replace("|", "\\|") if i else cell for i, cell in enumerate(row)) + " |")
    return "\n".join(lines)


def generator_reference() -> str:
    """One section per procedural generator: its first docstring paragraph and its parameter table."""
    import inspect

    from ..scene import procedural

    parts = []
    for name in procedural.generator_names():
        first = (inspect.getdoc(procedural._lookup(name)) or "").split("\n\n")[0]
        parts.append(f"### `{name}`\n\n{' '.join(first.split())}\n\n{generator_table(name)}")
    return "\n\n".join(parts)


#: Generated blocks of the config reference page: name -> generator.
BLOCKS = {"config reference": config_reference, "methods": method_table, "generators": generator_reference}

#: The page that holds the generated blocks (relative to the repository root).
REFERENCE_PAGE = "docs/reference/config.md"


def _pattern(name: str) -> re.Pattern:
    return re.compile(rf"(<!-- generated: {re.escape(name)} -->\n)(.*?)(<!-- end generated -->)", re.S)


def readme_block(text: str, name: str) -> str | None:
    """The current content of generated block ``name`` in a page's text (None when the markers are missing)."""
    m = _pattern(name).search(text)
    return m.group(2).rstrip("\n") if m else None


def update_readme(path: Path) -> bool:
    """Rewrite every generated block of the page at ``path``; True when something changed."""
    text = Path(path).read_text(encoding="utf-8")
    new = text
    for name, make in BLOCKS.items():
        new = _pattern(name).sub(lambda m, make=make: m.group(1) + make() + "\n" + m.group(3), new)
    if new != text:
        Path(path).write_text(new, encoding="utf-8")
    return new != text


__all__ = ["BLOCKS", "REFERENCE_PAGE", "config_reference", "describe_type", "generator_reference", "generator_table",
           "method_table", "readme_block", "settings_table", "update_readme"]


if __name__ == "__main__":
    for arg in sys.argv[1:] or [REFERENCE_PAGE]:
        print(f"{arg}: {'updated' if update_readme(Path(arg)) else 'up to date'}")
