"""The shape of the code (issue #51), kept when the next feature lands: kernels take a few structs, files stay short,
no module imports from a layer above its own, comments and docstrings stay at most a fifth of the library, and the
module paths from before the packages still import.

The layers, lowest first (docs/guide/architecture.md draws them). A module belongs to the layer of the longest
prefix below that names it; a module that matches none fails :func:`test_every_module_has_a_layer`, so a new module
is placed on purpose.
"""

from __future__ import annotations

import ast
import io
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: Python package -> its source folder (the CLI installs as warpscatter.cli from the top-level cli/ folder).
SOURCES = {"warpscatter": ROOT / "warpscatter", "warpscatter.cli": ROOT / "cli"}

LAYERS: list[tuple[str, tuple[str, ...]]] = [
    # what every layer may use: errors, validation types, Warp set-up, threads, timing, files and their metadata
    ("runtime", ("warpscatter", "warpscatter.errors", "warpscatter.schema", "warpscatter.moved", "warpscatter.runtime",
                 "warpscatter.io")),
    # the techniques' settings models and the method registry: no Warp
    ("settings", ("warpscatter.scattering.settings", "warpscatter.shadows.settings", "warpscatter.csm.settings",
                  "warpscatter.methods")),
    # camera, lights, medium, meshes on the host, and their kernel-side parameters
    ("scene", ("warpscatter.scene",)),
    # the scene on the device: rasterizer, ray casting, G-buffer
    ("raster", ("warpscatter.scene.geometry", "warpscatter.raster")),
    # the papers: shadow maps, single scattering, coherent shadow maps; surface shading
    ("techniques", ("warpscatter.shadows", "warpscatter.scattering", "warpscatter.csm", "warpscatter.shading")),
    # a whole config: the models composed, YAML and overrides, animation tracks, the generated reference
    ("config", ("warpscatter.config", "warpscatter.scene.light_configs", "warpscatter.scene.mesh_configs")),
    # config -> scene -> stages -> images and files
    ("pipeline", ("warpscatter.pipeline",)),
    # what users call: the API, animations, sweeps, executors, benchmarks, the gallery
    ("runs", ("warpscatter.api", "warpscatter.runs", "warpscatter.bench")),
    ("cli", ("warpscatter.cli", "warpscatter.__main__")),
]
MAX_KERNEL_PARAMETERS = 12
MAX_FILE_LINES = 800
#: Comment and docstring lines over the library's non-blank lines (issue #51: prose where code should speak).
MAX_COMMENT_SHARE = 0.20


def _modules() -> list[tuple[str, Path]]:
    out = []
    for package, folder in SOURCES.items():
        for path in sorted(folder.rglob("*.py")):
            parts = path.relative_to(folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out.append((".".join((package, *parts)), path))
    return out


def layer_of(module: str) -> int | None:
    """Index into :data:`LAYERS` of a module (the longest matching prefix), or None."""
    best = None
    for k, (_, prefixes) in enumerate(LAYERS):
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and (best is None or len(p) > best[1]):
                best = (k, len(p))
    return None if best is None else best[0]


def imported_modules(module: str, path: Path) -> set[str]:
    """The warpscatter modules ``module`` imports, at module level or inside functions."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
                names = [f"{target}.{a.name}" for a in node.names] if not node.module else [target]
            else:
                names = [node.module or ""]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        out.update(n for n in names if n == "warpscatter" or n.startswith("warpscatter."))
    return out


def _is_kernel(node: ast.expr) -> bool:
    """``wp.kernel`` or ``wp.kernel(...)`` (a decorator, or the callee of a factory's call)."""
    target = node.func if isinstance(node, ast.Call) else node
    return isinstance(target, ast.Attribute) and target.attr == "kernel"


def test_every_module_has_a_layer():
    unplaced = [m for m, _ in _modules() if layer_of(m) is None]
    assert not unplaced, f"place these modules in a layer of tests/test_structure.py: {unplaced}"


def test_no_import_up_the_layers():
    upward = []
    for module, path in _modules():
        own = layer_of(module)
        for target in sorted(imported_modules(module, path)):
            layer = layer_of(target)
            if layer is not None and own is not None and layer > own:
                upward.append(f"{module} ({LAYERS[own][0]}) imports {target} ({LAYERS[layer][0]})")
    assert not upward, "imports up the layers:\n" + "\n".join(upward)


def _kernel_functions(tree: ast.Module) -> list[ast.FunctionDef]:
    """The functions of a module that become kernels: decorated with ``@wp.kernel`` or passed to a ``wp.kernel(...)``
    call (the kernel factories that specialise a kernel per variant)."""
    passed = {node.args[0].id for node in ast.walk(tree) if isinstance(node, ast.Call) and _is_kernel(node.func)
              and node.args and isinstance(node.args[0], ast.Name)}
    return [node for node in ast.walk(tree) if isinstance(node, ast.FunctionDef)
            and (any(_is_kernel(d) for d in node.decorator_list) or node.name in passed)]


def test_no_kernel_takes_more_than_12_parameters():
    wide = []
    for module, path in _modules():
        for node in _kernel_functions(ast.parse(path.read_text(encoding="utf-8"))):
            if len(node.args.args) > MAX_KERNEL_PARAMETERS:
                wide.append(f"{module}.{node.name}: {len(node.args.args)} parameters")
    assert not wide, (f"kernels over {MAX_KERNEL_PARAMETERS} parameters (pass a few @wp.struct arguments, choose "
                      "variants on the host or with wp.static):\n" + "\n".join(wide))


def test_no_library_file_is_over_800_lines():
    long = [f"{p.relative_to(ROOT)}: {n} lines" for _, p in _modules()
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_FILE_LINES]
    assert not long, f"files over {MAX_FILE_LINES} lines (split them by idea):\n" + "\n".join(long)


@pytest.mark.parametrize(("module", "expected"), [
    ("warpscatter.scene.camera", "scene"), ("warpscatter.scene.geometry", "raster"),
    ("warpscatter.scattering.settings", "settings"), ("warpscatter.scattering.marching", "techniques"),
    ("warpscatter.cli.render", "cli"), ("warpscatter", "runtime"),
])
def test_the_longest_prefix_decides_the_layer(module, expected):
    assert LAYERS[layer_of(module)][0] == expected


def test_kernel_factories_are_counted():
    tree = ast.parse("import warp as wp\ndef make():\n    def k(a: int, b: int):\n        pass\n"
                     "    return wp.kernel(k)\n@wp.kernel\ndef d(x: int):\n    pass\n")
    assert sorted(f.name for f in _kernel_functions(tree)) == ["d", "k"]


@pytest.mark.parametrize("old", sorted(__import__("warpscatter.moved", fromlist=["MOVED"]).MOVED))
def test_old_module_paths_still_import(old):
    """A module path from before the packages imports as the module at its new path, with a DeprecationWarning that
    names the new path; the new module keeps its own name and spec."""
    import importlib
    import sys
    import warnings

    from warpscatter.moved import MOVED

    sys.modules.pop(old, None)
    new = importlib.import_module(MOVED[old])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        module = importlib.import_module(old)
    assert module is new
    assert module.__name__ == MOVED[old] and module.__spec__.name == MOVED[old]
    assert any(issubclass(w.category, DeprecationWarning) and MOVED[old] in str(w.message) for w in caught)


def test_packages_that_took_a_module_name_forward_its_attributes():
    """``warpscatter.raster`` and ``warpscatter.scattering.epipolar`` were modules, and the CSM reader was in
    ``csm.compress``: their names still resolve."""
    import warnings

    import warpscatter.raster
    import warpscatter.scattering.epipolar
    from warpscatter.raster import rasterizer
    from warpscatter.scattering.epipolar import method

    with pytest.warns(DeprecationWarning, match="warpscatter.raster.rasterizer.empty_array"):
        assert warpscatter.raster.empty_array is rasterizer.empty_array
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert warpscatter.scattering.epipolar.render is method.render  # the method's entry: no warning
    with pytest.raises(AttributeError):
        warpscatter.raster.no_such_name  # noqa: B018
    from warpscatter.csm import compress, files  # the CSM file reader left compress.py for files.py

    with pytest.warns(DeprecationWarning, match="warpscatter.csm.files.load_csm"):
        assert compress.load_csm is files.load_csm


def comment_lines(source: str) -> tuple[int, int]:
    """(comment and docstring lines, non-blank lines) of a module: a line counts as comment when it holds a comment
    token (a code line with a trailing comment too) or lies in a string statement of a module, class or function body
    (docstrings, attribute docstrings)."""
    marked = {tok.start[0] for tok in tokenize.generate_tokens(io.StringIO(source).readline)
              if tok.type == tokenize.COMMENT}
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            for stmt in node.body:
                if isinstance(stmt, ast.Expr) and isinstance(stmt.value, ast.Constant) \
                        and isinstance(stmt.value.value, str):
                    marked.update(range(stmt.lineno, stmt.end_lineno + 1))
    nonblank = [k for k, line in enumerate(source.splitlines(), 1) if line.strip()]
    return sum(1 for k in nonblank if k in marked), len(nonblank)


def test_comments_are_at_most_a_fifth_of_the_library():
    """Comments state what, units, conventions and why; measurements live in docs/ (design/, benchmarks.md)."""
    counts = [comment_lines(path.read_text(encoding="utf-8")) for _, path in _modules()
              if path.is_relative_to(SOURCES["warpscatter"])]
    comments, lines = sum(c for c, _ in counts), sum(n for _, n in counts)
    assert comments / lines <= MAX_COMMENT_SHARE, f"{comments} of {lines} non-blank lines are comments or docstrings"
