"""The Python API: render a config given as a file, a dict or a :class:`~warpscatter.config.Config`.

::

    import warpscatter

    result = warpscatter.render("configs/quickstart.yaml", overrides={"camera.width": 640, "camera.height": 360})
    result.images["color"]      # (H, W, 3) float32, linear RGB, row 0 = top
    result.timings, result.stats

    cfg = warpscatter.load_config({"scene": {...}, "camera": {...}, "light": {...}})
    result = warpscatter.render(cfg, out_dir="out")   # also writes NAME.exr, NAME.png, the AOVs and NAME.json

A :class:`Config` (possibly changed in place) is validated again before any work.
"""

from __future__ import annotations

import copy
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from .config import Config, apply_overrides, validated_config
from .config import load_config as _load_file

ConfigSource = str | Path | Mapping[str, Any] | Config
Overrides = Iterable[str] | Mapping[str, Any]


def load_config(source: ConfigSource, overrides: Overrides = (), *, config_dir: str | Path | None = None) -> Config:
    """A validated config from a YAML file, a dict or a :class:`Config`, with overrides applied.

    Args:
        source: a YAML file path, a plain dict (as the YAML would read), or a config.
        overrides: ``KEY=VALUE`` strings (``"camera.fov_y=40"``, the value parsed as YAML) or a mapping of dotted
            keys to values (``{"camera.fov_y": 40, "scene.meshes.0.material.opacity": 0.5}``), applied in order.
        config_dir: the folder relative paths of a dict resolve against (default: the current folder; a file's
            own folder for a file, the original folder for a config).

    Returns:
        A new validated :class:`Config`.

    Raises:
        ConfigError: every problem as a ``key.path: reason`` line (exit code 2 in the CLI).
    """
    if isinstance(source, (str, Path)):
        return _load_file(source, overrides)
    if isinstance(source, Config):
        data, base, origin = source.model_dump(), config_dir or source.config_dir, source.source
    elif isinstance(source, Mapping):
        data, base, origin = copy.deepcopy(dict(source)), config_dir, None
    else:
        raise TypeError(f"config: expected a file path, a dict or a Config, got {type(source).__name__}")
    apply_overrides(data, overrides, origin)
    return validated_config(data, base, origin)


def render(config: ConfigSource, overrides: Overrides = (), *, out_dir: str | Path | None = None, device=None,
           progress=None, verbose: bool = False):
    """Render a config and return its images; write the output files only when ``out_dir`` is given.

    Args:
        config: a YAML file path, a plain dict or a :class:`Config` (validated again: it may have changed in place).
        overrides: as in :func:`load_config`.
        out_dir: write ``NAME.exr``, ``NAME.png``, the AOVs of ``output.aovs`` and the ``NAME.json`` sidecar here
            (``NAME`` is :attr:`Config.output_name`); None (default) writes nothing.
        device: a Warp device or its name; None: ``WARPSCATTER_DEVICE`` if set, else Warp's ``wp.get_device()``.
        progress: optional ``progress(stage, fraction)`` callback.
        verbose: let Warp print its banner and module loads as it does by default. Quiet (default): they go to the
            ``warpscatter.warp`` logger (INFO), the no-CUDA-driver warning to ``warpscatter`` (DEBUG); Warp's
            warnings and errors still show (:func:`.runtime.device.warp_messages`).

    Returns:
        :class:`~warpscatter.pipeline.RenderResult`: ``images`` (name -> float32 numpy array: ``color``,
        ``scattering``, ``surface``, ``depth`` ...), ``timings`` (stage -> seconds), ``stats``, ``files``, the
        validated ``config`` and the ``device`` it ran on.

    Raises:
        ConfigError: an invalid config or override (nothing is rendered).
        DeviceError: ``device`` (or ``WARPSCATTER_DEVICE``) names a device this machine does not have.
        ImageWriteError: an output file could not be written (the previous files are left as they were).
    """
    cfg = config.revalidated() if isinstance(config, Config) and not overrides else load_config(config, overrides)
    from .runtime.device import default_device, warp_messages

    with warp_messages(verbose):
        from .pipeline import render as render_config

        device = default_device(device)  # a device this machine lacks is refused before any work
        return render_config(cfg, out_dir=out_dir, progress=progress, device=device, write=out_dir is not None)


def clear_caches() -> None:
    """Drop what this process keeps between renders: loaded and generated meshes, BVHs of exact visibility and
    built coherent shadow maps (they are rebuilt when needed; a long-lived process calls this to free memory)."""
    from .csm.occluders import clear_csm_cache
    from .raster.raycast import clear_bvh_cache
    from .scene.meshes import clear_mesh_cache

    clear_mesh_cache()
    clear_bvh_cache()
    clear_csm_cache()


__all__ = ["ConfigSource", "Overrides", "clear_caches", "load_config", "render"]
