"""Rendering an animated config: every frame's output set (``NAME.0001.exr`` ..., bit-identical with any executor),
skipping frames already rendered with the same config, then a preview movie from the PNGs (docs/guide/runs.md)."""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config.animation import FRAME_DIGITS, frame_name
from ..schema import MAX_FRAMES
from .jobs import Executor, InlineExecutor, TaskResult, run_tasks, task_for

log = logging.getLogger("warpscatter")


@dataclass
class AnimationResult:
    """What :func:`render_animation` did: per-frame results, the preview file (or None), frames per second, wall s."""

    frames: list[TaskResult]
    preview: Path | None = None
    seconds: float = 0.0
    executor: str = ""
    notes: list[str] = field(default_factory=list)

    @property
    def rendered(self) -> list[TaskResult]:
        return [r for r in self.frames if r.ok and not r.skipped]

    @property
    def skipped(self) -> list[TaskResult]:
        return [r for r in self.frames if r.skipped]

    @property
    def failed(self) -> list[TaskResult]:
        return [r for r in self.frames if not r.ok]


def parse_frames(text: str | None, first: int, last: int) -> list[int]:
    """``--frames`` text: ``A:B`` (inclusive), ``A:B:STEP``, ``A,B,C`` or ``N``, within [first, last].

    A range is checked against [first, last] arithmetically before any list is built: the list is never longer than
    the animation (at most :data:`~warpscatter.schema.MAX_FRAMES` frames), whatever the text asks for.

    Raises:
        ValueError: malformed, or outside the animation's range.
    """
    if not text:
        return list(range(first, last + 1))
    shown = text if len(text) <= 60 else text[:57] + "..."
    malformed = ValueError(f"--frames: expected A:B, A:B:STEP or A,B,C with integers, got {shown!r}")
    outside = ValueError(f"--frames {shown}: the animation has frames {first}..{last}")
    items = text.split(":") if ":" in text else text.split(",")
    if len(items) > MAX_FRAMES:  # more numbers than any animation has frames
        raise ValueError(f"--frames: at most {MAX_FRAMES} frame numbers, got {len(items)}")
    try:
        numbers = [int(p) for p in items]
    except ValueError:
        raise malformed from None
    if ":" in text:
        if len(numbers) not in (2, 3) or (len(numbers) == 3 and numbers[2] < 1):
            raise malformed
        start, stop = numbers[0], numbers[1]
        if start > stop or start < first or stop > last:  # checked arithmetically: no list of an unbounded range
            raise outside
        return list(range(start, stop + 1, numbers[2] if len(numbers) == 3 else 1))
    if any(not first <= f <= last for f in numbers):
        raise outside
    return numbers


def preview_format(requested: str) -> str:
    """The preview written for ``animation.preview`` (``auto``: mp4 with imageio-ffmpeg, else gif, else none)."""
    if requested != "auto":
        return requested
    try:
        import imageio_ffmpeg  # noqa: F401

        return "mp4"
    except ImportError:
        pass
    try:
        import imageio  # noqa: F401

        return "gif"
    except ImportError:
        return "none"


def write_preview(pngs: list[Path], target: Path, fps: float) -> Path:
    """Write the PNG frames as a movie (``warpscatter.mp4`` H.264 or ``warpscatter.gif``), atomically.

    Raises:
        ImportError: imageio (and, for mp4, imageio-ffmpeg) is not installed.
        ImageWriteError: the frames cannot make a movie or the file cannot be written.
    """
    import imageio.v2 as iio

    from ..io.output_sets import write_file_atomic

    if target.suffix == ".mp4":
        import imageio_ffmpeg  # noqa: F401  (a clear ImportError before any work)

        def write(tmp: Path) -> None:
            with iio.get_writer(tmp, fps=fps, codec="libx264", quality=8, macro_block_size=2,
                                ffmpeg_log_level="error") as writer:
                for p in pngs:  # H.264 in yuv420p needs even sizes: an odd last row / column is repeated
                    image = iio.imread(p)
                    pad = ((0, image.shape[0] % 2), (0, image.shape[1] % 2)) + ((0, 0),) * (image.ndim - 2)
                    writer.append_data(np.pad(image, pad, mode="edge"))
    else:
        def write(tmp: Path) -> None:
            iio.mimsave(tmp, [iio.imread(p) for p in pngs], duration=1000.0 / fps, loop=0)

    return write_file_atomic(target, write)


def render_animation(config, out_dir: str | Path | None = None, *, frames: list[int] | None = None,
                     executor: Executor | None = None, resume: bool = True, preview: str | None = None,
                     progress: Callable[[str, float], None] | None = None, device=None,
                     verbose: bool = False) -> AnimationResult:
    """Render the frames of an animated config and its preview.

    Args:
        config: a validated :class:`~warpscatter.config.Config` with an ``animation`` section.
        out_dir: output folder (default ``config.output.dir``).
        frames: the frame numbers to render (default: all).
        executor: where the frames render (default: this process, one after the other).
        resume: skip frames already rendered with the same config (their sidecar says so).
        preview: override ``animation.preview`` (``auto``, ``mp4``, ``gif``, ``none``).
        progress: ``progress(stage, fraction)``, called once per finished frame.
        device: the Warp device every frame renders on (default: :func:`..runtime.device.default_device`).
        verbose: show Warp's own messages (its banner, module loads), as :func:`warpscatter.render` does.

    Returns:
        :class:`AnimationResult`; failed frames are in it with their errors (the others render on).

    Raises:
        ValueError: the config has no animation.
        ConfigError: a frame's values make an invalid config (checked for every frame before any render).
    """
    from ..runtime.device import warp_messages

    with warp_messages(verbose):
        return _render_animation(config, out_dir, frames, executor, resume, preview, progress, device)


def _render_animation(config, out_dir, frames, executor, resume, preview, progress, device) -> AnimationResult:
    if config.animation is None:
        raise ValueError("render_animation: the config has no animation section")
    t0 = time.perf_counter()
    out = Path(out_dir) if out_dir is not None else Path(config.output.dir)
    from ..runtime.device import default_device

    numbers = list(dict.fromkeys(frames or config.animation.frame_numbers))  # each frame once
    # the caller's device travels only when asked for: a worker otherwise renders on its own default
    device = default_device(device) if device is not None or os.environ.get("WARPSCATTER_DEVICE") else None
    tasks = [task_for(frame_config, frame_config.output_name, out, device=device)
             for frame_config in (config.at_frame(f) for f in numbers)]
    executor = executor or InlineExecutor()
    results = run_tasks(tasks, executor, skip_finished=resume, progress=progress, stage="frames")
    result = AnimationResult(frames=results, executor=executor.describe())
    kind = preview_format(preview or config.animation.preview)
    all_frames = config.animation.frame_numbers
    name = config.output_name
    pngs = [out / f"{frame_name(name, f)}.png" for f in all_frames]
    if kind != "none" and not result.failed and all(p.is_file() for p in pngs):
        if progress is not None:
            progress("preview", 0.0)
        command = (f"ffmpeg -framerate {config.animation.fps:g} -i {out / name}.%0{FRAME_DIGITS}d.png -pix_fmt "
                   f"yuv420p {out / name}.mp4")
        try:
            result.preview = write_preview(pngs, out / f"{name}.{kind}", config.animation.fps)
        except ImportError as exc:
            result.notes.append(f"no {kind} preview ({exc}); install the video extra, or run: {command}")
        except Exception as exc:  # the frames are written: a preview that fails is a note, not a failed render
            result.notes.append(f"no {kind} preview: {exc} (the frames are written; e.g. frames of different sizes "
                                f"make no movie)")
        if progress is not None:
            progress("preview", 1.0)
    elif kind != "none":
        result.notes.append("no preview: not every frame of the animation has been rendered")
    result.seconds = time.perf_counter() - t0
    return result


__all__ = ["AnimationResult", "parse_frames", "preview_format", "render_animation", "write_preview"]
