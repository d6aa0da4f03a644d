"""Sphinx configuration of the warpscatter documentation (MyST Markdown, the furo theme).

Build (warnings are errors, as in .ci/run)::

    pip install -e ".[docs]"
    sphinx-build -W --keep-going -b html docs docs/_build/html
"""

import io
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # autodoc imports warpscatter from the source tree when it is not installed

import warpscatter  # noqa: E402  (after the path)

project = "warpscatter"
author = "the warpscatter developers"
copyright = "the warpscatter developers"
release = warpscatter.__version__
version = release

extensions = [
    "myst_parser",  # the pages are Markdown
    "sphinx.ext.autodoc",  # the Python API from docstrings (docs/reference/api.md)
    "sphinx.ext.napoleon",  # ... written in the Google style (Args / Returns / Raises)
    "sphinx.ext.mathjax",  # $...$ in the method pages
    "sphinx_click",  # the command line reference from the click application (docs/reference/cli.md)
]

source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]

# ---- MyST ----
myst_enable_extensions = ["colon_fence", "dollarmath", "deflist", "attrs_inline", "attrs_block"]
myst_heading_anchors = 3  # [text](page.md#a-heading) links to headings up to ###

# ---- autodoc ----
autodoc_member_order = "bysource"
autodoc_typehints = "description"  # types in the parameter lists, not in long signatures
autodoc_default_options = {"show-inheritance": False}
napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_rtype = False
# Warp's @wp.func objects carry the Python function they wrap; document them as functions.
nitpicky = False

# ---- HTML ----
html_theme = "furo"
html_title = f"warpscatter {release}"
html_static_path = ["_static"]
html_theme_options = {"source_repository": "https://github.com/warpscatter/warpscatter/",
                      "source_branch": "main", "source_directory": "docs/"}

# ---- Warp's @wp.func building blocks in the API reference ----
# A ``@wp.func`` is a ``warp.Function`` object, not a Python function, so autodoc would not document it. While the
# docs build (nothing is compiled then), each module below has its ``@wp.func``s replaced by the Python functions
# they wrap (same name, signature and docstring), and only those are documented there: the modules' host functions
# and kernels are internal. ``docs/reference/api.md`` lists the modules with ``automodule``.
WARP_FUNC_MODULES = [
    "warpscatter.shadows.moments",
    "warpscatter.shadows.shadow_map",
    "warpscatter.shadows.surface",
    "warpscatter.shadows.msm",
    "warpscatter.shadows.soft",
    "warpscatter.scattering.marching",
    "warpscatter.scattering.prefiltered",
    "warpscatter.scattering.prefiltered.filtered_lookups",
    "warpscatter.scattering.rectify",
    "warpscatter.csm.query",
    "warpscatter.csm.brdf",
    "warpscatter.raster.raycast",
    "warpscatter.scene.camera",
    "warpscatter.scene.lights",
]
_WARP_FUNC_NAMES: dict[str, set] = {}


def _expose_warp_funcs() -> None:
    import importlib

    import warp as wp

    for name in WARP_FUNC_MODULES:
        module = importlib.import_module(name)
        names = set()
        public = getattr(module, "__all__", None)
        for attr, value in list(vars(module).items()):
            if attr.startswith("_") or not isinstance(value, wp.Function):
                continue
            if public is None and getattr(value.func, "__module__", None) != name:
                continue  # imported from elsewhere: documented in its own module
            if public is not None and attr not in public:
                continue
            value.func.__module__ = name  # documented where a user imports it from (the facades re-export)
            value.func.__warp_func__ = True
            setattr(module, attr, value.func)
            names.add(attr)
        _WARP_FUNC_NAMES[name] = names


def _skip_member(app, what, name, obj, skip, options):
    """In the modules of WARP_FUNC_MODULES, document the ``@wp.func``s (and constants) only."""
    if what == "module" and getattr(obj, "__module__", None) in _WARP_FUNC_NAMES:
        return not getattr(obj, "__warp_func__", False)
    return None


_ROLE = re.compile(r":[\w:.-]+:`([^`]*)`")
_PIPE = re.compile(r"(?<!\\)\|")  # |x| in the docstrings is an absolute value, never an RST substitution


def _rst_problems(lines: list) -> list:
    """The docutils warnings and errors of a docstring (Sphinx's own roles and directives aside)."""
    from docutils.core import publish_doctree
    from docutils.utils import Reporter

    stream = io.StringIO()
    text = _ROLE.sub(r"``\1``", "\n".join(lines))  # Sphinx's roles need its environment: checked by Sphinx itself
    text = "\n".join(line for line in text.splitlines() if not line.lstrip().startswith(".. "))
    publish_doctree(text, settings_overrides={"report_level": Reporter.WARNING_LEVEL,
                                                            "halt_level": Reporter.SEVERE_LEVEL + 1,
                                                            "warning_stream": stream})
    unknown = ("Unknown interpreted text role", "No role entry", "Unknown directive type", "No directive entry",
               'Trying "', "(Sphinx", 'Directive "')
    return [line for line in stream.getvalue().splitlines()
            if ("WARNING" in line or "ERROR" in line) and not any(u in line for u in unknown)]


def _docstring(app, what, name, obj, options, lines):
    """The project's docstrings are plain text with ``code`` spans and :func: roles: shown as RST where they parse
    cleanly, as a literal block where they do not (so the build's -W never fails on a docstring's layout); a
    module of WARP_FUNC_MODULES shows its first paragraph only (the rest describes its internals)."""
    if what == "module" and name in _WARP_FUNC_NAMES:
        del lines[next((i for i, line in enumerate(lines) if not line.strip()), len(lines)):]
    lines[:] = [line if line.lstrip().startswith(("|", "+")) else _PIPE.sub(r"\\|", line) for line in lines]
    if _rst_problems(lines):
        lines[:] = ["::", ""] + ["    " + line for line in lines]
    if getattr(obj, "__warp_func__", False):
        lines[:0] = ["*@wp.func* (call it from your own kernel).", ""]


def setup(app):
    _expose_warp_funcs()
    app.connect("autodoc-skip-member", _skip_member)
    app.connect("autodoc-process-docstring", _docstring)
