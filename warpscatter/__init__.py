"""warpscatter: real-time shadows and single scattering in participating media as NVIDIA Warp kernels.

The Python API (:mod:`warpscatter.api`)::

    import warpscatter

    result = warpscatter.render("configs/quickstart.yaml", overrides={"camera.width": 640})
    result.images["color"], result.timings, result.stats

The library is importable without the CLI and importing it changes none of Warp's settings. Kernel modules expose
their ``@wp.func`` building blocks as public API so that user kernels can call them (docs/guide/kernels.md maps the
code); the settings models (``warpscatter.config`` and each technique's ``settings`` module) and the method registry
(``warpscatter.methods``) import no Warp, and ``import warpscatter`` imports nothing heavy until :func:`render` or
:func:`load_config` is used.
"""

__version__ = "0.1.0"

from . import moved as _moved  # noqa: E402  (module paths from before issue #51 still import, with a warning)

_moved.install()

_LAZY = {
    "render": "warpscatter.api",
    "load_config": "warpscatter.api",
    "clear_caches": "warpscatter.api",
    "Config": "warpscatter.config",
    "ConfigError": "warpscatter.errors",
    "RenderResult": "warpscatter.pipeline",
    "render_animation": "warpscatter.runs.animation",
    "load_sweep": "warpscatter.runs.sweep",
    "run_sweep": "warpscatter.runs.sweep",
    "make_executor": "warpscatter.runs.jobs",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'warpscatter' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *_LAZY])


__all__ = ["Config", "ConfigError", "RenderResult", "__version__", "clear_caches", "load_config", "load_sweep",
           "make_executor", "render", "render_animation", "run_sweep"]
