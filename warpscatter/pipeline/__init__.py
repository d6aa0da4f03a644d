"""Config -> scene -> stages -> images and files, with per-stage timings.

:func:`render` (``warpscatter render``; the Python API over it is :func:`warpscatter.render`) builds the scene of a
validated :class:`~warpscatter.config.Config`, runs the classic pipeline (:mod:`.classic`) or, when
``render.lighting.method`` is set, the Monte-Carlo lighting pipeline (:mod:`.lighting`), and writes the outputs. This
package is the only place that reads the config. Stage names (the CLI's timing table, ``bench``, logs): ``scene``,
``compile``, the pipeline's own stages, ``write``.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import __version__
from ..config import Config
from ..errors import ConfigError
from ..io.images import OWN_SIZE_AOVS
from ..runtime.device import default_device
from ..runtime.stages import ProgressFn, StageTimer
from .classic import render_images
from .common import check_finite, compile_kernels
from .frame import Frame
from .lighting import render_lighting
from .memory import check_memory
from .supersample import box_filter, supersampled_scene


@dataclass
class RenderResult:
    """What a render produced.

    Attributes:
        images: output name -> float32 array, row 0 = top (``color``, ``surface``, ``depth``, ``scattering``, debug).
        files: the written files (empty when nothing was written).
        timings: stage -> seconds, in order.
        stats: the method's statistics (sizes, counts).
        config, device: the validated config that was rendered and the Warp device it ran on.
        warnings: what a user should know about the image, e.g. why it is dark (also in the stats and sidecar).
    """

    images: dict[str, np.ndarray]
    files: list[Path] = field(default_factory=list)
    timings: OrderedDict[str, float] = field(default_factory=OrderedDict)
    stats: dict = field(default_factory=dict)
    config: Config | None = None
    device: str | None = None
    warnings: list[str] = field(default_factory=list)


def sidecar(config: Config, device: str, timings: dict, stats: dict, files: list[str], complete: bool = True) -> dict:
    """The ``NAME.json`` beside a render's images: what made them (config, method, seed, device, threads,
    :func:`~warpscatter.io.provenance.provenance`) and what it measured (stage timings without ``write``, stats).
    ``complete`` is False for a progressive render's intermediate outputs (a resumed run renders them again)."""
    from ..io.provenance import provenance
    from ..runtime.parallel import thread_count

    lighting = config.render.lighting
    seed = lighting.seed if lighting.method is not None else config.render.scattering.seed
    return {"name": config.output_name, "complete": complete, "method": config.method, "config_file": config.source,
            **provenance(),
            "device": device, "threads": thread_count(), "seed": seed, "files": files,
            "timings_s": {k: v for k, v in timings.items() if k != "write"}, "stats": stats,
            "config": config.model_dump(mode="json")}


def exr_metadata(config: Config, camera) -> dict:
    """EXR header attributes: the camera matrices (``worldToCamera``, ``worldToNDC``), method, version, config."""
    return {**camera.exr_matrices(), "warpscatter:method": config.method,
            "warpscatter:config": config.model_dump_yaml(), "warpscatter:version": __version__}


def render(config: Config, out_dir: Path | None = None, progress: ProgressFn | None = None, device=None,
           write: bool = True) -> RenderResult:
    """Render a :class:`~warpscatter.config.Config` (validated again first) and write its outputs.

    Args:
        out_dir: output folder (default ``config.output.dir``).
        progress, device: ``progress(stage, fraction)`` or None; Warp device (default ``WARPSCATTER_DEVICE`` or Warp's).
        write: False skips the ``write`` stage (images are still returned).

    Returns:
        :class:`RenderResult`. The files are ``NAME.exr``, ``NAME.png``, the AOVs of ``output.aovs`` (the lighting
        methods make no ``scattering``) and the ``NAME.json`` sidecar, ``NAME`` being :attr:`Config.output_name`.

    Raises:
        ConfigError: the config is invalid, or a file it names does not fit (a CSM file of other occluders, say).
        NonFiniteImageError: an image with NaN or infinite pixels (a bug).
    """
    from ..csm.files import CSMFileError
    from ..io.images import write_outputs
    from ..io.output_sets import check_output_target
    from ..scene import build_scene, object_meshes

    config = config.revalidated()
    if config.animation is not None:
        raise ConfigError("animation: the config is a sequence: render its frames with "
                          "warpscatter.render_animation(config) (or one frame: config.at_frame(n))", config.source)
    check_memory(config)  # before any work: the estimated peak against the memory available (memory.py)
    if out_dir is not None:
        config.output.dir = Path(out_dir).resolve()  # the sidecar records where the files went
    if write:  # before any work: the folder can hold the set, the name is not reserved and fits (exit 2)
        check_output_target(config.output.dir, config.output_name, config.output.aovs)
    device = default_device(device)
    timer = StageTimer(progress)
    s = config.camera.supersample
    with timer("scene"):
        scene = supersampled_scene(build_scene(config), s)  # anti-aliasing: the larger frame, box-filtered below
    frame = (scene.camera.height, scene.camera.width)
    out = Path(out_dir) if out_dir is not None else Path(config.output.dir)
    name, output = config.output_name, config.output
    lighting = config.render.lighting.method is not None
    aovs = [a for a in output.aovs if not (lighting and a == "scattering")]  # no in-scattering: no all-zero file
    metadata = exr_metadata(config, scene.camera)

    def write_files(images, stats, complete: bool = True) -> list[Path]:
        files = [f"{name}.exr", f"{name}.png"]  # the names the sidecar lists (written with it, all or nothing)
        files += [f"{name}.{a}.exr" for a in aovs if a != "color" and (not output.layered or a in OWN_SIZE_AOVS)]
        files += [f"{name}.json"]
        with timer("write"):
            return write_outputs(out, name, {k: v for k, v in images.items() if k in aovs or k == "color"}, aovs,
                                 output.exposure, compression=output.compression, metadata=metadata,
                                 sidecar=sidecar(config, device, timer.timings, stats, files, complete),
                                 layered=output.layered)

    if lighting:

        def on_pass(images, done, total):  # rewrite the outputs as the image converges
            if write:
                write_files(box_filter(images, s, frame), {"passes_done": done}, complete=False)

        try:
            objects = object_meshes(config) if config.render.lighting.csm.objects == "per_mesh" else None
            images, stats = render_lighting(scene, config.render.lighting, timer, on_pass, device=device,
                                            objects=objects)
        except CSMFileError as exc:
            raise ConfigError(f"render.lighting.csm.file: {exc}") from None
        images.pop("scattering", None)
    else:
        images, stats = render_images(scene, config.render, timer=timer, device=device, aovs=output.aovs)
    if s > 1:
        with timer("antialias"):
            images = box_filter(images, s, frame)
        stats["supersample"] = s
        stats["resolution"] = [config.camera.width, config.camera.height]
    files = write_files(images, stats) if write else []
    return RenderResult(images=images, files=files, timings=timer.timings, stats=stats, config=config, device=device,
                        warnings=list(stats.get("warnings", [])))


__all__ = ["Frame", "RenderResult", "StageTimer", "check_finite", "compile_kernels", "render", "render_images",
           "render_lighting", "sidecar"]
