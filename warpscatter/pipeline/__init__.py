"""Config -> scene -> stages -> images and files, with per-stage timings.

:func:`render` is what ``warpscatter render`` runs: it builds the scene of a validated
:class:`~warpscatter.config.Config`, runs the classic pipeline (:mod:`.classic`: G-buffer, shadow map, the
scattering method of ``render.scattering.method``, surface shadows, shading) or, when ``render.lighting.method``
is set, the Monte-Carlo lighting pipeline (:mod:`.lighting`), and writes the outputs. This package is the only
place that reads the config; each stage is a library function taking arrays and settings. Stage names appear in
the CLI's timing table, in ``bench`` and in logs: ``scene`` (load/generate meshes), ``compile``, then the
pipeline's stages (:mod:`.classic`, :mod:`.lighting`), and ``write`` (EXR/PNG files).

Example::

    from warpscatter.config import load_config
    from warpscatter.pipeline import render

    result = render(load_config("configs/quickstart.yaml"), out_dir="out")
    result.images["color"], result.timings, result.stats
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from ..stages import ProgressFn, StageTimer
from ..wpinit import init
from .classic import render_images
from .common import check_finite, compile_kernels
from .frame import Frame
from .lighting import render_lighting


@dataclass
class RenderResult:
    """What a render produced: images (name -> float32 array), written files, stage timings (s), stats."""

    images: dict[str, np.ndarray]
    files: list[Path] = field(default_factory=list)
    timings: OrderedDict[str, float] = field(default_factory=OrderedDict)
    stats: dict = field(default_factory=dict)


def render(config, out_dir: Path | None = None, progress: ProgressFn | None = None, device=None,
           write: bool = True) -> RenderResult:
    """Render a validated :class:`~warpscatter.config.Config` and write its images.

    Args:
        config: the validated config.
        out_dir: output folder (default ``config.output.dir``).
        progress: optional ``progress(stage, fraction)`` callback.
        device: Warp device (default: ``WARPSCATTER_DEVICE`` or cpu).
        write: False skips the ``write`` stage (images are still returned).

    Returns:
        :class:`RenderResult` with images, written files, per-stage timings and stats.

    Raises:
        ConfigError: a file the config names does not fit (a CSM file of other occluders, say).
        NonFiniteImageError: an image with NaN or infinite pixels (a bug).
    """
    from ..csm.compress import CSMFileError
    from ..imageio import write_outputs
    from ..scene import build_scene

    init()
    timer = StageTimer(progress)
    with timer("scene"):
        scene = build_scene(config)
    out = Path(out_dir) if out_dir is not None else Path(config.output.dir)
    if config.render.lighting.method is not None:  # Monte-Carlo direct lighting (csm / raytrace), progressive

        def on_pass(images, done, total):  # rewrite the outputs as the image converges
            if write:
                with timer("write"):
                    write_outputs(out, config.output.name, images, config.output.aovs, config.output.exposure,
                                  compression=config.output.compression)

        try:
            images, stats = render_lighting(scene, config.render.lighting, timer, on_pass, device=device)
        except CSMFileError as exc:
            raise ConfigError(f"render.lighting.csm.file: {exc}") from None
    else:
        images, stats = render_images(scene, config.render, timer=timer, device=device, aovs=config.output.aovs)
    files: list[Path] = []
    if write:
        with timer("write"):
            files = write_outputs(out, config.output.name, images, config.output.aovs, config.output.exposure,
                                  compression=config.output.compression)
    return RenderResult(images=images, files=files, timings=timer.timings, stats=stats)


__all__ = ["Frame", "RenderResult", "StageTimer", "check_finite", "compile_kernels", "render", "render_images",
           "render_lighting"]
