"""Config files and ``--set`` overrides: YAML read into plain data with a strict loader, and ``KEY=VALUE`` overrides
applied to it (validated by :mod:`warpscatter.config`, which re-exports these names). No Warp import.
"""

from __future__ import annotations

import re
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import yaml

from ..errors import ConfigError
from ..scene.light_configs import LIGHT_TYPES
from ..schema import dotted

#: The most nodes a YAML document may hold with its aliases expanded (bundled configs: 100-200): stops alias bombs
#: while composing, before anything is built.
MAX_YAML_NODES = 100_000
#: The deepest nesting of lists and mappings a YAML document may have (bundled configs: 6): PyYAML composes nodes
#: recursively, so a document nested some 300 levels deep would otherwise end in a RecursionError.
MAX_YAML_DEPTH = 64

_NAME_TAGS = ("tag:yaml.org,2002:str", "tag:yaml.org,2002:merge")


class _YAMLKeyError(yaml.MarkedYAMLError):
    """A mapping key the config cannot use, found after composing; ``key_path`` is where it is."""

    def __init__(self, key_path: tuple, problem: str, mark):
        super().__init__(problem=problem, problem_mark=mark)
        self.key_path = key_path


class _Loader(yaml.SafeLoader):
    """SafeLoader that rejects duplicate keys, reads ``1e-3`` as a float (YAML 1.2), and refuses documents that cannot
    be plain config data: collection keys (with their key path), non-string top-level keys with ``string_keys_at_top``
    (numbers stay allowed below: animation keyframes), and alias bombs: each node's expanded size is computed once
    while composing and the document is refused when the total passes :data:`MAX_YAML_NODES` (or an alias recurses),
    a budget that bounds exactly what costs time later and keeps aliases usable for sharing; and documents nested
    deeper than :data:`MAX_YAML_DEPTH` (refused before the composer's recursion can overflow the stack).
    """

    string_keys_at_top = False

    def compose_document(self):
        self._sizes: dict[int, int] = {}
        self._expanded = 0
        self._depth = 0
        node = super().compose_document()
        self._sizes = {}
        if node is not None:
            self._check_keys(node)
        return node

    def compose_node(self, parent, index):
        alias = self.peek_event() if self.check_event(yaml.AliasEvent) else None
        if self.check_event(yaml.CollectionStartEvent):
            if self._depth >= MAX_YAML_DEPTH:
                raise yaml.composer.ComposerError(
                    None, None, f"the document nests lists and mappings more than {MAX_YAML_DEPTH} levels deep; "
                    "refusing it", self.peek_event().start_mark)
            self._depth += 1
            try:
                node = super().compose_node(parent, index)
            finally:
                self._depth -= 1
        else:
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


def key_lines(text: str) -> dict[tuple, int]:
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




def parse_override(text: str) -> tuple[tuple[str | int, ...], Any]:
    """Split ``a.b.0.c=value`` into a key path and a YAML-parsed value (digits select list items; one past the end
    appends). The value goes through the config loader.

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




def _drop_replaced_keys(data: dict, key_path: tuple, value) -> None:
    """An override of a ``light`` key drops the keys it replaces (``light.azimuth_deg`` drops ``light.direction``)."""
    if len(key_path) != 2 or key_path[0] != "light" or value is None:
        return
    light = data.get("light")
    kind = light.get("type") if isinstance(light, dict) else None
    model = LIGHT_TYPES.get(kind) if isinstance(kind, str) else None
    if model is not None:
        for k in model.keys_replaced_by(str(key_path[1])):
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
            _drop_replaced_keys(data, key_path, value)
            overridden.append(key_path)
        except ValueError as exc:
            problems.append(f"--set {text}: {exc}")
    if problems:
        raise ConfigError(problems, source)
    return tuple(overridden)


def value_at(data: Any, dotted_key: str) -> Any:
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


def read_config_data(path: str | Path) -> tuple[dict, str]:
    """Read a YAML config file as plain data, with its text (for line numbers), through the strict loader.

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


__all__ = ["MAX_YAML_DEPTH", "MAX_YAML_NODES", "apply_overrides", "key_lines", "parse_override", "read_config_data",
           "value_at"]
