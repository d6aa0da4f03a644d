"""The generated config reference (docs/reference/config.md) against the settings models, the registry and the
procedural generators (warpscatter.config.reference): every key documented, nothing stale, the example config valid,
every method named in the README's method list and in a heading of docs/methods/."""

import re
import typing
from pathlib import Path

import pytest
import yaml
from pydantic import BaseModel

from warpscatter import methods
from warpscatter.config import Config, reference

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text(encoding="utf-8")
PAGE = (ROOT / reference.REFERENCE_PAGE).read_text(encoding="utf-8")


def _models(model: type[BaseModel], seen=None) -> set:
    """Every settings model reachable from ``model`` (sections, list items, union members)."""
    seen = set() if seen is None else seen
    if model in seen:
        return seen
    seen.add(model)
    for field in model.model_fields.values():
        stack = [field.annotation]
        while stack:
            tp = stack.pop()
            if isinstance(tp, type) and issubclass(tp, BaseModel):
                _models(tp, seen)
            stack.extend(typing.get_args(tp))
    return seen


def test_every_key_has_a_description():
    missing = [f"{m.__name__}.{name}" for m in _models(Config) for name, f in m.model_fields.items()
               if not (f.description or "").strip()]
    assert not missing, f"keys without Field(description=...): {missing}"


@pytest.mark.parametrize("name", list(reference.BLOCKS))
def test_generated_blocks_are_current(name):
    got = reference.readme_block(PAGE, name)
    assert got is not None, f"{reference.REFERENCE_PAGE} lacks the <!-- generated: {name} --> block"
    assert got == reference.BLOCKS[name](), (f"{reference.REFERENCE_PAGE}: block {name!r} is stale: "
                                             f"python -m warpscatter.config.reference {reference.REFERENCE_PAGE}")


def test_generator_reference_lists_every_parameter():
    import inspect

    from warpscatter.scene import procedural

    text = reference.generator_reference()
    for name in procedural.generator_names():
        section = text.split(f"### `{name}`")[1].split("\n### ")[0]
        for p in inspect.signature(procedural._lookup(name)).parameters:
            row = re.search(rf"^\| `{p}` \|(.*)\|$", section, re.M)
            assert row, f"generator {name}: parameter {p} missing"
            assert row.group(1).split("|")[-1].strip(), f"generator {name}: parameter {p} has no meaning (Args:)"


def test_config_reference_lists_every_key_of_the_json_schema():
    # an independent walk: every property path in Config's JSON schema is a row of the reference
    schema = Config.model_json_schema()
    defs = schema.get("$defs", {})
    rows = set(re.findall(r"^\| `([^`]+)`", reference.config_reference(), re.M))
    keys = {re.sub(r" \(\w+\)$", "", r) for r in rows}

    def walk(node, path, out):
        node = defs[node["$ref"].split("/")[-1]] if "$ref" in node else node
        for alt in node.get("anyOf", []) + node.get("oneOf", []):
            walk(alt, path, out)
        if node.get("type") == "array" and isinstance(node.get("items"), dict):
            walk(node["items"], f"{path}.N", out)
        for name, sub in node.get("properties", {}).items():
            sub_path = f"{path}.{name}" if path else name
            resolved = defs[sub["$ref"].split("/")[-1]] if "$ref" in sub else sub
            if "properties" not in resolved or name == "params":
                out.add(sub_path)
            walk(sub, sub_path, out)

    want = set()
    walk(schema, "", want)
    missing = [k for k in want if k not in keys and not any(r.startswith(k + ".") for r in keys)]
    assert not missing, f"keys missing from the reference: {sorted(missing)}"


def test_reference_example_config_is_valid():
    block = re.search(r"```yaml\n(.*?)```", PAGE, re.S).group(1)
    config = Config.from_dict(yaml.safe_load(block), config_dir=ROOT / "configs")
    assert config.render.scattering.method == "moments6" and config.scene.meshes[1].receiver_only


def test_every_registered_method_is_named_in_the_readme_and_has_a_docs_heading():
    # the README's one-line-per-method list (its "methods" section) and a heading of a docs/methods/ page
    section = re.search(r"^## [^\n]*[Mm]ethods[^\n]*\n(.*?)(?=^## )", README, re.S | re.M)
    assert section, "README has no section on the methods (a `## ... methods` heading)"
    headings = "\n".join(line for page in sorted((ROOT / "docs" / "methods").glob("*.md"))
                         for line in page.read_text(encoding="utf-8").splitlines() if line.startswith("#"))
    for table in (methods.SCATTERING, methods.LIGHTING):
        for name in table:
            assert f"`{name}`" in section.group(1), f"README's method list does not name `{name}`"
            assert f"`{name}`" in headings, f"no heading of docs/methods/*.md names `{name}`"


def test_describe_type():
    from typing import Annotated, Literal, Optional

    from pydantic import Field

    assert reference.describe_type(Literal["a", "b"]) == "`a` \\| `b`"
    assert reference.describe_type(Annotated[int, Field(ge=1, le=8)]) == "int 1–8"
    assert reference.describe_type(Optional[Annotated[float, Field(gt=0.0)]]) == "number > 0 or null"
