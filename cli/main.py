"""``warpscatter`` command line: render, validate, bench, precompute and schema, thin over the library.

Exit codes: 0 success, 1 a failure while rendering or benchmarking, 2 an invalid config, override,
suite name or command line (nothing is written then), 130 interrupted.

Every command takes ``-v/--verbose`` (repeatable), ``-q/--quiet`` and ``--debug``; the commands that run kernels
also take ``--device`` and ``--threads``. Progress goes to stderr (a bar with the elapsed time and an ETA on a
terminal; otherwise a line at the start and then one every few seconds, or one per stage with ``-v``); results
go to stdout: by default a short report (a summary line, the timing table condensed to its longest stages, the
written files), with ``-v`` every stage and statistic. A render's warnings (e.g. a light that reaches no pixel) go
to stderr as ``warning: ...`` unless ``-q``. Warp's own messages (its start-up banner, module loads, the warning of
a machine without a CUDA driver) are shown with ``-v`` only.
"""

from __future__ import annotations

import importlib
import inspect
import json
import logging
import math
import os
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import TYPE_CHECKING

import click
from pydantic import ValidationError

from warpscatter import __version__, methods
from warpscatter.config import AOV_NAMES, Config, load_config
from warpscatter.csm import settings as csm_settings
from warpscatter.errors import ConfigError, WarpscatterError
from warpscatter.resources import bundled_config, in_package
from warpscatter.schema import format_validation_errors

if TYPE_CHECKING:
    from warpscatter.stages import Estimate

EXIT_FAILURE = 1
EXIT_INVALID = 2
EXIT_INTERRUPTED = 130

#: The suite ``warpscatter bench`` runs without a SUITE argument (the default of ``warpscatter.bench.run``; a test
#: checks that they agree) and its duration on two cores.
DEFAULT_SUITE = "reference"
DEFAULT_SUITE_DURATION = "about 2 minutes on two cores"

#: Seconds between progress lines when stderr is not a terminal (logs, CI).
PLAIN_PROGRESS_INTERVAL = 10.0
#: Rows of the default timing table (a render with more stages shows its longest ones and one row for the rest).
TIMING_ROWS = 6

log = logging.getLogger("warpscatter")

_set_option = click.option(
    "--set",
    "overrides",
    multiple=True,
    metavar="KEY=VALUE",
    help="Override a config value, e.g. --set camera.fov_y=40 --set scene.meshes.0.material.opacity=0.5 "
    "(VALUE is parsed as YAML; repeatable; relative paths resolve against the config file's folder, as in the "
    "config itself).",
)


def _common_options(kernels: bool):
    """-v / -q / --debug for every command; --device and --threads for those that run kernels."""

    def decorate(f):
        options = [
            click.option("-v", "--verbose", count=True, help="More messages: -v info, Warp's own messages "
                         "(module loads) and every stage and statistic of a render, -vv debug."),
            click.option("-q", "--quiet", is_flag=True, help="No progress, tables, notes or warnings: only errors "
                         "and the written files."),
            click.option("--debug", is_flag=True, help="Show the full traceback of an error."),
        ]
        if kernels:
            options += [
                click.option("--device", metavar="NAME", default=None, help="Warp device to run on: cpu (the "
                             "default, also WARPSCATTER_DEVICE) or cuda:0 ..."),
                click.option("--threads", type=click.IntRange(min=1), default=None, help="Threads for the "
                             "split CPU launches [default: WARPSCATTER_THREADS, else every usable core]."),
            ]
        for option in reversed(options):
            f = option(f)
        return f

    return decorate


def _executor_options(default: str):
    """--executor (``default``) / --workers / --address of the commands that run many renders."""
    return lambda f: _add_executor_options(f, default)


def _add_executor_options(f, default: str):
    from warpscatter.jobs import EXECUTORS

    options = [
        click.option("--executor", type=click.Choice(EXECUTORS), default=default, show_default=True,
                     help="Where frames and sweep cases render: inline (this process, one after the other), local "
                          "(worker processes), dask (Dask distributed: a LocalCluster, or --address)."),
        click.option("--workers", type=click.IntRange(min=1), default=None,
                     help="Worker processes of local / a dask LocalCluster [default: the usable cores]."),
        click.option("--address", metavar="ADDR", default=None,
                     help="Scheduler of a running Dask cluster (tcp://host:8786); needs --executor dask."),
    ]
    for option in reversed(options):
        f = option(f)
    return f


def _make_executor(kind: str, workers: int | None, address: str | None, tasks: int, debug: bool):
    from warpscatter.jobs import make_executor
    from warpscatter.parallel import thread_count

    if workers is None and kind != "inline" and not address:
        workers = max(1, min(thread_count(), tasks))
    try:
        return make_executor(kind, workers, address)
    except (ValueError, ImportError) as exc:
        _fail(str(exc), EXIT_INVALID, debug)
    except OSError as exc:  # the scheduler cannot be reached
        _fail(f"--address {address}: {exc}", EXIT_FAILURE, debug)


def _setup(verbose: int, quiet: bool, device: str | None = None, threads: int | None = None,
           kernels: bool = False) -> str | None:
    """Configure logging and, for commands that run kernels, Warp (its log level, start-up messages, the device and
    thread count); return the device name. Exits 2 for a device Warp does not have."""
    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    if not log.handlers:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(levelname)s: %(message)s"))
        log.addHandler(handler)
        log.propagate = False
    log.setLevel(level)
    if threads is not None:
        os.environ["WARPSCATTER_THREADS"] = str(threads)
    if not kernels:
        return None
    import warp as wp

    from warpscatter.wpinit import init

    wp.config.log_level = wp.LOG_INFO if verbose else wp.LOG_WARNING  # this process is ours: Warp quiet by default
    init(quiet_native=verbose < 2)
    name = device or os.environ.get("WARPSCATTER_DEVICE") or "cpu"
    try:
        wp.get_device(name)
    except Exception:
        names = ", ".join(str(d) for d in wp.get_devices())
        _fail(f"--device {name}: not a device of this machine (available: {names})", EXIT_INVALID)
    os.environ["WARPSCATTER_DEVICE"] = name  # the bench and precompute resolve the device through it
    return name


# ---- output helpers --------------------------------------------------------------------------------


def _isatty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def _format_eta(seconds: float) -> str:
    if seconds < 99.5:
        return f"{seconds:.0f} s"
    return f"{seconds / 60:.1f} min" if seconds < 5940 else f"{seconds / 3600:.1f} h"


def eta_text(stage: str | None, estimate: Estimate) -> str:
    """The ETA as the progress display words it: ``ETA 12 s`` (the whole run, later stages known from an earlier
    run), ``ETA 5 s for this stage`` (later stages unknown), or why it is unknown."""
    if estimate.seconds is None:
        if stage == "compile":
            return "ETA unknown: a compile reports no progress"
        return "ETA unknown: no progress reported yet"
    text = f"ETA {_format_eta(estimate.seconds)}"
    return text if estimate.complete else f"{text} for this stage"


class ProgressDisplay:
    """``progress(stage, fraction)`` callback drawing on stderr, with the time left from an
    :class:`~warpscatter.stages.EtaEstimator` (each stage's own measured rate; the stages still to come from
    ``expected``, e.g. the timings of the previous render of the same output).

    On a terminal: a tqdm bar per stage (percentage, the stage's elapsed time and the ETA; ``prefix`` in front, e.g.
    ``[2/3]`` of several configs), redrawn every second also while a stage reports nothing. Otherwise: a line when
    the first stage starts (with ``every_stage``, when each one starts), then at most one every ``interval``
    seconds with the running stage, its percentage and the ETA (a background thread writes it also for a stage that
    reports no progress, e.g. a long compile: ``still running``). Disabled: does nothing.

    Args:
        enabled: draw anything at all.
        stream: where to draw (default: stderr).
        interval: seconds between plain lines (default :data:`PLAIN_PROGRESS_INTERVAL`); 0 draws every report.
        prefix: text in front of the stage name.
        expected: stage -> seconds of an earlier run, in order (see :class:`~warpscatter.stages.EtaEstimator`).
        every_stage: without a terminal, a line for every stage that starts (``-v``).
    """

    def __init__(self, enabled: bool = True, stream=None, interval: float | None = None, prefix: str = "",
                 expected=None, every_stage: bool = False):
        from warpscatter.stages import EtaEstimator

        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.tty = enabled and _isatty(self.stream)
        self.interval = PLAIN_PROGRESS_INTERVAL if interval is None else interval
        self.prefix = prefix
        self.every_stage = every_stage
        self.eta = EtaEstimator(expected)
        self.stage: str | None = None
        self.started = False
        self.start = time.perf_counter()
        self.stage_start = self.start
        self.last_line = self.start
        self.fraction = 0.0
        self.bar = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._heart: threading.Thread | None = None

    def __call__(self, stage: str, fraction: float) -> None:
        if not self.enabled:
            return
        try:
            f = min(max(float(fraction), 0.0), 1.0) if math.isfinite(float(fraction)) else 0.0
            self._update(str(stage), f)
        except Exception:  # a display problem must never break a render
            self.enabled = False

    def _update(self, stage: str, fraction: float) -> None:
        with self._lock:
            self._draw(stage, fraction)
        if self._heart is None and (self.tty or self.interval > 0):
            self._heart = threading.Thread(target=self._heartbeat, name="warpscatter-progress", daemon=True)
            self._heart.start()

    def _eta_text(self, now: float) -> str:
        return eta_text(self.stage, self.eta.estimate(now))

    def _status(self, now: float) -> str:
        """The plain line of the running stage: its percentage and the ETA, or how long it has run."""
        if 0.0 < self.fraction < 1.0:
            return f"{self.prefix}{self.stage} {100 * self.fraction:3.0f}% ({self._eta_text(now)})"
        return f"{self.prefix}{self.stage} still running ({now - self.stage_start:.0f} s; {self._eta_text(now)})"

    def _write(self, now: float, text: str) -> None:
        self.stream.write(f"[{now - self.start:7.2f}s] {text}\n")
        self.stream.flush()
        self.last_line = now

    def _heartbeat(self) -> None:
        """While a stage runs: the bar redrawn every second (terminal), else a line every ``interval`` seconds."""
        while not self._stop.wait(min(self.interval, 1.0) if self.interval > 0 and not self.tty else 1.0):
            with self._lock:
                now = time.perf_counter()
                if not self.enabled or self.stage is None:
                    continue
                try:
                    if self.bar is not None:
                        self.bar.set_postfix_str(self._eta_text(now), refresh=True)
                    elif not self.tty and self.interval > 0 and now - self.last_line >= self.interval:
                        self._write(now, self._status(now))
                except Exception:  # a closed stream: the display ends, the work goes on
                    self.enabled = False
                    return

    def _draw(self, stage: str, fraction: float) -> None:
        now = time.perf_counter()
        self.eta.update(stage, fraction, now)
        self.fraction = fraction
        if stage != self.stage:
            self._close_bar()
            first, self.started = not self.started, True
            self.stage, self.stage_start = stage, now
            if self.tty:
                from tqdm import tqdm

                self.bar = tqdm(total=1000, desc=f"{self.prefix}{stage}"[:24], file=self.stream, leave=False,
                                dynamic_ncols=True, mininterval=0.1, postfix=self._eta_text(now),
                                bar_format="{desc:<24} {percentage:5.1f}% |{bar:20}| {elapsed}{postfix}")
            elif first or self.every_stage:
                self._write(now, f"{self.prefix}{stage}")
                return
        if self.bar is not None:
            self.bar.set_postfix_str(self._eta_text(now), refresh=False)
            self.bar.update(int(round(fraction * 1000)) - self.bar.n)
        elif now - self.last_line >= self.interval and 0.0 < fraction < 1.0:
            self._write(now, self._status(now))

    def _close_bar(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def close(self) -> None:
        """Remove the bar (terminal only) and stop the background lines."""
        self._stop.set()
        with self._lock:
            self._close_bar()
            self.stage = None


def _format_seconds(s: float) -> str:
    if s < 1e-3:
        return f"{s * 1e6:8.1f} us"
    if s < 1.0:
        return f"{s * 1e3:8.1f} ms"
    return f"{s:8.3f} s "


def timing_table(timings, max_rows: int | None = None) -> str:
    """Per-stage timing table: stage, time, share of the total, and a total row.

    Args:
        timings: stage -> seconds, in order.
        max_rows: with more stages than this, the ``max_rows - 1`` longest stages (in their order) and one row
            ``(N other stages)`` for the rest; None shows every stage.
    """
    rows = [(str(k), float(v)) for k, v in dict(timings or {}).items()]
    if not rows:
        return "(no timings)"
    total = sum(v for _, v in rows)
    if max_rows is not None and len(rows) > max(max_rows, 2):
        longest = set(sorted(range(len(rows)), key=lambda i: -rows[i][1])[:max(max_rows, 2) - 1])
        others = [v for i, (_, v) in enumerate(rows) if i not in longest]
        rows = [r for i, r in enumerate(rows) if i in longest] + [(f"({len(others)} other stages)", sum(others))]
    width = max(len("stage"), len("total"), *(len(k) for k, _ in rows))
    lines = [f"{'stage':<{width}}  {'time':>11}  {'share':>6}", "-" * (width + 21)]
    for k, v in rows:
        share = 100.0 * v / total if total > 0 else 0.0
        lines.append(f"{k:<{width}}  {_format_seconds(v)}  {share:5.1f}%")
    lines.append("-" * (width + 21))
    lines.append(f"{'total':<{width}}  {_format_seconds(total)}  {100.0 if total > 0 else 0.0:5.1f}%")
    return "\n".join(lines)


def _format_value(v) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_format_value(x) for x in v) + "]"
    return str(v)


def _format_bytes(n: int) -> str:
    for unit, size in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{n} B"


#: Statistics that are (width, height) sizes.
_SIZE_STATS = ("resolution", "shadow_map", "rectified_map")


def stats_lines(stats) -> list[str]:
    """A render's statistics as ``key: value`` lines: entries without a value left out, byte counts in KiB / MiB /
    GiB, sizes as ``W x H``, nested statistics indented."""
    lines = []
    for key, value in dict(stats or {}).items():
        if value is None:
            continue
        if isinstance(value, dict):
            inner = stats_lines(value)
            if inner:
                lines += [f"{key}:"] + [f"  {line}" for line in inner]
            continue
        if str(key).endswith("_bytes") and isinstance(value, int) and not isinstance(value, bool):
            text = _format_bytes(value)
        elif str(key) in _SIZE_STATS and isinstance(value, (list, tuple)) and len(value) == 2:
            text = f"{value[0]} x {value[1]}"
        else:
            text = _format_value(value)
        lines.append(f"{key}: {text}")
    return lines


def _fail(message: str, code: int, debug: bool = False) -> None:
    if debug:
        traceback.print_exc(file=sys.stderr)
    click.echo(f"error: {message}", err=True)
    sys.exit(code)


def _config_file(path: Path) -> Path:
    """A config file, or the name of a bundled config (``quickstart``: configs/quickstart.yaml of the checkout or of
    the installed package) when no such file exists here."""
    if path.exists() or path.suffix or len(path.parts) != 1:
        return path
    try:
        return bundled_config(path.name)
    except FileNotFoundError:
        return path


def _load(config_path: Path, overrides, debug: bool) -> Config:
    try:
        return load_config(config_path, list(overrides))
    except ConfigError as exc:
        _fail(str(exc), EXIT_INVALID)
    except Exception as exc:  # a bug, not a user error: keep the traceback reachable
        _fail(f"{type(exc).__name__}: {exc}", EXIT_FAILURE, debug)


def _fail_error(exc: BaseException, debug: bool) -> None:
    """Exit for an exception of a command: a :class:`WarpscatterError` with its exit code, anything else 1."""
    if isinstance(exc, WarpscatterError):
        _fail(str(exc), exc.exit_code, debug)
    _fail(_error_text(exc), EXIT_FAILURE, debug)


def _error_text(exc: BaseException) -> str:
    text = str(exc)
    if isinstance(exc, (ValueError, OSError)) and text:
        return text
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _out_dir(path: Path | None) -> Path | None:
    if path is None:
        return None
    out = Path(path).expanduser().resolve()
    if out.exists() and not out.is_dir():
        _fail(f"-o {path}: not a directory", EXIT_INVALID)
    return out



def _scattering_summary(sc) -> str:
    """What the scattering method of a ``render.scattering`` section marches with or stores."""
    from warpscatter import methods

    method = methods.get("scattering", sc.method)
    if method.visibility == methods.VISIBILITY_CONFIGURABLE:
        return f"visibility {sc.visibility}, {sc.march_steps} steps, {sc.march_jitter} jitter"
    options = f", {sc.prefiltered.mip_levels} row mip levels" if sc.prefiltered.mip_levels > 1 else ""
    warp = sc.prefiltered.depth_warp_for(sc.method, sc.shadow_map.size[0])
    options += f", depth warp {warp:g}" if warp != 0.0 else ""
    if sc.method == "fourier":
        return f"{sc.fourier.coefficients} coefficients, {sc.shadow_map.resolution}^2 maps{options}"
    return (f"{sc.num_moments} moments, {sc.filtered_bits_per_texel} bits per texel, {sc.shadow_map.resolution}^2 "
            f"maps{options}")


def _summary(config: Config) -> list[str]:
    meshes = config.scene.meshes
    procedural = [m.procedural for m in meshes if m.procedural]
    kinds = f"{len(meshes) - len(procedural)} file(s)"
    if procedural:
        kinds += f", procedural: {', '.join(procedural)}"
    cam = config.camera
    light = config.light
    if light.type == "directional":
        light_text = (
            f"directional, direction {_format_value(light.direction)}, irradiance {_format_value(light.irradiance)}"
        )
    elif light.type == "environment":
        light_text = f"environment map {light.map}, scale {light.scale:g}"
    elif light.type == "area":
        emit = f"power {_format_value(light.power)}" if light.power is not None else \
            f"radiance {_format_value(light.radiance or (1.0, 1.0, 1.0))}"
        light_text = (f"area at {_format_value(light.position)}, edges {_format_value(light.u)} x "
                      f"{_format_value(light.v)}, {emit}" + (", two-sided" if light.two_sided else "")
                      + (f", texture {light.texture}" if light.texture else ""))
    elif light.type == "volume":
        emit = (f"power {_format_value(light.power)}" if light.power is not None else
                f"intensity {_format_value(light.intensity or (1.0, 1.0, 1.0))} per unit volume")
        light_text = (f"volume at {_format_value(light.position)}, edges {_format_value(light.u)} x "
                      f"{_format_value(light.v)} x {_format_value(light.w)}, {emit}")
    elif light.type == "point":
        light_text = (f"point at {_format_value(light.position)}, intensity {_format_value(light.intensity)} (six "
                      f"cube-face spots)")
    elif light.type == "linear":
        light_text = (f"linear {_format_value(light.start)} -> {_format_value(light.end)}, intensity "
                      f"{_format_value(light.intensity)} per unit length")
    else:
        light_text = (
            f"spot at {_format_value(light.position)}, direction {_format_value(light.direction)}, "
            f"cone {light.cone_deg:g} deg, intensity {_format_value(light.intensity)}"
            + (f", texture {light.texture}" if light.texture else "")
        )
    med = config.medium
    phase = med.phase.type + (f" (g {med.phase.g:g})" if med.phase.type == "henyey_greenstein" else "")
    sc = config.render.scattering
    lt = config.render.lighting
    out = config.output
    extra = [a for a in AOV_NAMES if a in out.aovs and a != "color"]
    return [
        f"  scene:   {len(meshes)} mesh(es) ({kinds})",
        f"  camera:  {cam.width}x{cam.height}"
        f"{f' ({cam.supersample}x{cam.supersample} rays a pixel)' if cam.supersample > 1 else ''}, fov_y "
        f"{cam.fov_y:g} deg, {_format_value(cam.position)} -> {_format_value(cam.look_at)}, near {cam.near:g}, "
        f"far {cam.far:g}",
        f"  light:   {light_text}",
        f"  medium:  sigma_t {_format_value(med.sigma_t)}, albedo {_format_value(med.albedo)}, phase {phase}",
        *([f"  surfaces: sky fill {_format_value(config.render.surfaces.ambient)}"]
          if any(config.render.surfaces.ambient) else []),
        f"  method:  {sc.method} ({_scattering_summary(sc)})" if lt.method is None else
        f"  method:  lighting {lt.method} ({lt.samples} strata x {lt.passes} passes, filter {lt.filter}"
        f"{', CSM file ' + str(lt.csm.file) if lt.csm.file else ''})",
        f"  output:  {out.dir / config.output_name}.exr/.png/.json" + (f" + {', '.join(extra)}" if extra else ""),
    ]


def _default_suite(run) -> str | None:
    try:
        default = inspect.signature(run).parameters["suite"].default
    except (KeyError, TypeError, ValueError):
        return None
    return default if isinstance(default, str) else None


def _interrupted(progress: ProgressDisplay) -> None:
    progress.close()
    _fail("interrupted", EXIT_INTERRUPTED)


# ---- commands --------------------------------------------------------------------------------------


class _Commands(click.Group):
    """The application's commands: those defined in this module, and those of other modules of the package
    (:data:`LAZY`), imported when first listed or run, so that such a module may import this one's helpers."""

    LAZY = {"gallery": ("warpscatter.cli.gallery", "gallery")}

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*super().list_commands(ctx), *self.LAZY})

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name in self.LAZY and name not in self.commands:
            module, attr = self.LAZY[name]
            self.add_command(getattr(importlib.import_module(module), attr), name)
        return super().get_command(ctx, name)


@click.group(cls=_Commands, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, "--version", prog_name="warpscatter", message="%(prog)s %(version)s")
@click.option("--debug", "debug", is_flag=True, help="Show full tracebacks of errors (any command).")
@click.pass_context
def main(ctx: click.Context, debug: bool) -> None:
    """Shadows and single scattering in participating media, as NVIDIA Warp kernels.

    Every command takes -v/-q/--debug; render, sweep, bench and precompute also --device and --threads.
    Exit codes: 0 done, 1 a failure while working, 2 invalid input (nothing written), 130 interrupted.
    """
    ctx.obj = {"debug": debug}
    _terminate_like_interrupt()
    from warpscatter.heap import keep_freed_memory_unless_disabled

    keep_freed_memory_unless_disabled()  # repeated frames reuse their buffers' pages (warpscatter.heap)


def _terminate_like_interrupt() -> None:
    """SIGTERM (a job scheduler, ``kill``) stops a command as Ctrl-C does: temporaries removed, previous outputs
    kept, exit code 130."""
    import signal
    import threading

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, interrupt)


def _own_method_and_name(path: Path, overrides) -> tuple[str | None, str | None]:
    """The method and output name a config file (with its --set overrides) asks for itself, or (None, None) when it
    cannot be read (loading it then reports why)."""
    from warpscatter.config import OutputConfig, apply_overrides, read_config_data
    from warpscatter.scattering.settings import ScatteringSettings

    try:
        data, _ = read_config_data(path)
        apply_overrides(data, list(overrides))
    except ConfigError:
        return None, None
    render = data.get("render") if isinstance(data.get("render"), dict) else {}
    section = {k: (v if isinstance(v, dict) else {}) for k, v in render.items()}
    method = (section.get("lighting", {}).get("method") or section.get("scattering", {}).get("method")
              or ScatteringSettings.model_fields["method"].default)
    output = data.get("output") if isinstance(data.get("output"), dict) else {}
    return str(method), str(output.get("name") or OutputConfig.model_fields["name"].default)


def _render_config(path: Path, overrides, method: str | None, name: str | None, seed: int | None,
                   debug: bool) -> Config:
    """One config of ``render``, loaded with its overrides, --method, --name and --seed applied before validation
    (exit 2 when invalid), as --set would apply them.

    Where --method changes the method, the name is the config's own (neither --name nor --set output.name) and it
    does not hold ``{method}``, ``_{method}`` is appended to it: the render does not overwrite the config's own
    outputs."""
    path = _config_file(path)
    own_method, own_name = _own_method_and_name(path, overrides)
    extra = []
    if method:
        extra.append(f"render.{'lighting' if method in methods.LIGHTING else 'scattering'}.method={method}")
    named = name is not None or any(o.partition("=")[0].strip() == "output.name" for o in overrides)
    if name is not None:
        extra.append(f"output.name={json.dumps(name)}")
    elif method and own_name and method != own_method and not named and "{method}" not in own_name:
        extra.append(f"output.name={json.dumps(own_name + '_{method}')}")
    if seed is not None:
        lighting = method in methods.LIGHTING if method else own_method in methods.LIGHTING
        extra.append(f"render.{'lighting' if lighting else 'scattering'}.seed={seed}")
    return _load(path, [*overrides, *extra], debug)


@main.command()
@click.argument("config_paths", metavar="CONFIG...", nargs=-1, required=True,
                type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output-dir", "output_dir", type=click.Path(path_type=Path),
              help="Write outputs here (relative to the current folder) instead of output.dir (relative to the "
                   "config file).")
@_set_option
@click.option("--method", metavar="NAME", help="Scattering method (same as --set render.scattering.method=NAME), or "
              "a lighting method csm / raytrace (same as --set render.lighting.method=NAME); appends _NAME to the "
              "config's output name unless its method is NAME, the name holds {method} or --name is given.")
@click.option("--name", "name", metavar="TEMPLATE", help="Output file stem (output.name), a template: {config} the "
              "config file's stem, {method} the method, e.g. --name '{config}_{method}'.")
@click.option("--seed", type=int, default=None, help="Seed of the jitter / Monte-Carlo patterns (render.scattering."
              "seed, or render.lighting.seed for csm / raytrace); the same seed gives the same image.")
@click.option("--frames", metavar="A:B", default=None, help="Animated configs: the frames to render (A:B inclusive, "
              "A:B:STEP or A,B,C) [default: all].")
@click.option("--force", is_flag=True, help="Animated configs: render frames again even where their files exist "
              "from the same config (by default a run resumes).")
@click.option("--preview", type=click.Choice(("auto", "mp4", "gif", "none")), default=None,
              help="Animated configs: the preview movie [default: animation.preview].")
@_executor_options("local")
@_common_options(kernels=True)
@click.pass_context
def render(ctx, config_paths, output_dir, overrides, method, name, seed, frames, force, preview, executor, workers,
           address, verbose, quiet, debug, device, threads):
    """Render the pipelines described by one or more CONFIG files (YAML; or the name of a bundled config, e.g.
    quickstart).

    Writes, per config, NAME.exr, NAME.png, the AOVs of output.aovs (NAME.scattering.exr, NAME.surface.exr,
    NAME.depth.exr) and NAME.json (what made them: the resolved config, versions, timings, statistics) into
    output.dir or -o DIR, then prints a summary, the timings of the longest stages and the written files (-v: every
    stage and the statistics). A render's warnings, e.g. a light that reaches no pixel, go to stderr as
    "warning: ..." unless -q. Every config is checked before the first render.

    A config with an animation section renders its frames (NAME.0001.exr ...) through --executor, skipping the
    frames already rendered from the same config, then writes a preview (NAME.mp4 or NAME.gif).
    """
    debug = debug or ctx.obj.get("debug", False)
    _setup(verbose, quiet)
    out_dir = _out_dir(output_dir)
    configs = [_render_config(p, overrides, method, name, seed, debug) for p in config_paths]
    for path, config in zip(config_paths, configs, strict=True):
        if out_dir is None and in_package(config.output.dir):  # a bundled config of a wheel install
            config.output.dir = Path.cwd() / "out"
            if not quiet:
                click.echo(f"note: {path} is bundled inside the installed package: writing to {config.output.dir} "
                           f"(give -o DIR to choose)", err=True)
        elif out_dir is not None:  # the sidecar then records where the files went
            config.output.dir = out_dir
    targets: dict[Path, Path] = {}
    for path, config in zip(config_paths, configs, strict=True):
        target = (out_dir or config.output.dir) / config.output_name
        if target in targets:
            _fail(f"{targets[target]} and {path} would both write {target}.*: give them different output.name "
                  f"values (e.g. --name '{{config}}_{{method}}')", EXIT_INVALID)
        targets[target] = path
    device = _setup(verbose, quiet, device, threads, kernels=True)

    frame_lists = {}
    for path, config in zip(config_paths, configs, strict=True):
        if config.animation is not None:
            from warpscatter.sequence import parse_frames

            try:
                frame_lists[path] = parse_frames(frames, *config.animation.frame_range)
                for f in frame_lists[path]:  # every frame's config is checked before the first render
                    config.at_frame(f)
            except ValueError as exc:
                _fail(f"{path}: {exc}", EXIT_INVALID)
            except ConfigError as exc:
                _fail(str(ConfigError(exc.problems, path)), EXIT_INVALID)
    if frames and not frame_lists:
        _fail("--frames: none of the configs has an animation section", EXIT_INVALID)

    pipeline = importlib.import_module("warpscatter.pipeline")
    failures = []
    for k, (path, config) in enumerate(zip(config_paths, configs, strict=True)):
        prefix = f"[{k + 1}/{len(configs)}] " if len(configs) > 1 else ""
        expected = None if quiet or path in frame_lists else _previous_timings(out_dir or config.output.dir,
                                                                               config.output_name)
        progress = ProgressDisplay(enabled=not quiet, prefix=prefix, expected=expected, every_stage=verbose > 0)
        if path in frame_lists:
            code = _render_animation(config, frame_lists[path], out_dir, progress, quiet, debug, force, preview,
                                     (executor, workers, address))
            if code:
                failures.append(code)
            continue
        try:
            result = pipeline.render(config, out_dir=out_dir, progress=progress, device=device)
        except KeyboardInterrupt:
            _interrupted(progress)
        except Exception as exc:
            progress.close()
            if len(configs) == 1:
                _fail_error(exc, debug)
            if debug:
                traceback.print_exc(file=sys.stderr)
            click.echo(f"error: {path}: {_error_text(exc)}", err=True)
            failures.append(exc.exit_code if isinstance(exc, WarpscatterError) else EXIT_FAILURE)
            continue
        progress.close()
        files = [Path(f) for f in getattr(result, "files", [])]
        lines = stats_lines(getattr(result, "stats", {}))
        if not quiet:
            if len(configs) > 1:
                click.echo(f"{prefix}{path}")
            click.echo(_render_summary(config, device, files, len(lines) if not verbose else 0))
            click.echo(timing_table(getattr(result, "timings", {}), max_rows=None if verbose else TIMING_ROWS))
            if lines and verbose:
                click.echo("stats:")
                for line in lines:
                    click.echo(f"  {line}")
            if files:
                click.echo("wrote:")
        for f in files:
            click.echo(f"  {f}" if not quiet else str(f))
        if not quiet:
            for text in getattr(result, "warnings", None) or []:
                click.echo(f"warning: {text}", err=True)
    if failures:
        _fail(f"{len(failures)} of {len(configs)} configs failed", failures[0])


def _previous_timings(folder: Path, name: str) -> dict | None:
    """The stage timings of the previous render of the same output (``timings_s`` of its ``NAME.json``), or None:
    what the progress display expects of the stages still to come."""
    try:
        timings = json.loads((Path(folder) / f"{name}.json").read_text(encoding="utf-8")).get("timings_s")
    except (OSError, ValueError, AttributeError):
        return None
    return timings if isinstance(timings, dict) and timings else None


def _render_summary(config: Config, device: str | None, files: list[Path], hidden_stats: int) -> str:
    """The first line of a render's report: output name, method, size, device, and where the statistics are when
    they are not shown (``hidden_stats`` of them)."""
    lt, sc = config.render.lighting, config.render.scattering
    text = f"{config.output_name}: {lt.method or sc.method}, {config.camera.width} x {config.camera.height}"
    text += f" on {device}" if device else ""
    if hidden_stats:
        sidecar = next((f.name for f in files if f.suffix == ".json"), None)
        text += f" ({hidden_stats} statistic{'s' if hidden_stats != 1 else ''}: -v" + (f" or {sidecar})" if sidecar
                                                                                    else ")")
    return text


def _render_animation(config, frames, out_dir, progress, quiet, debug, force, preview, executor_args) -> int:
    """Render one animated config's frames; print what was rendered, skipped and failed; return an exit code."""
    from warpscatter.sequence import render_animation

    kind, workers, address = executor_args
    executor = _make_executor(kind, workers, address, len(frames), debug)
    try:
        with executor:
            result = render_animation(config, out_dir, frames=frames, executor=executor, resume=not force,
                                      preview=preview, progress=progress)
    except KeyboardInterrupt:
        _interrupted(progress)
    finally:
        progress.close()
    rendered = result.rendered
    if not quiet:
        fps = len(rendered) / result.seconds if rendered and result.seconds > 0 else 0.0
        click.echo(f"{config.output_name}: {len(rendered)} frame(s) rendered, {len(result.skipped)} already done, "
                   f"{len(result.failed)} failed; {result.seconds:.1f} s ({fps:.2f} frames/s) on {result.executor}")
        if rendered:
            per_frame = sorted(sum(r.timings.values()) for r in rendered)
            click.echo(f"  render time per frame: median {per_frame[len(per_frame) // 2] * 1e3:.1f} ms")
        for note in result.notes:
            click.echo(f"  note: {note}")
    for r in result.failed:
        click.echo(f"error: frame {r.label}: {r.error}", err=True)
        if debug and r.details:
            click.echo(r.details, err=True)
    files = [f for r in rendered for f in r.files] + ([str(result.preview)] if result.preview else [])
    if not quiet and files:
        click.echo("wrote:")
    for f in files:
        click.echo(f"  {f}" if not quiet else str(f))
    return EXIT_FAILURE if result.failed else 0


@main.command()
@click.argument("sweep_path", metavar="SWEEP", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output-dir", "output_dir", type=click.Path(path_type=Path), default=Path("sweep-out"),
              show_default=True, help="Folder for NAME.json, NAME.csv, the chart and (images: true) the images.")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Override a config value in every case and reference (added to the sweep's set; repeatable).")
@_executor_options("inline")
@_common_options(kernels=True)
@click.pass_context
def sweep(ctx, sweep_path, output_dir, overrides, executor, workers, address, verbose, quiet, debug, device,
          threads):
    """Render every case of a SWEEP file (configs x a grid of overrides), time each, compare it with the sweep's
    reference, and write one table (NAME.json, NAME.csv) and the error-vs-time chart.

    A failed case is reported with its error; the others go on (exit 1 when any failed).
    """
    from warpscatter.config import parse_override
    from warpscatter.sweep import load_sweep, rows_table, run_sweep, sweep_cases

    debug = debug or ctx.obj.get("debug", False)
    _setup(verbose, quiet)
    extra = {}
    for text in overrides:
        try:
            key, value = parse_override(text)
        except ValueError as exc:
            _fail(f"--set {text}: {exc}", EXIT_INVALID)
        extra[".".join(map(str, key))] = value
    try:
        settings = load_sweep(sweep_path, extra)
        cases, _ = sweep_cases(settings)
    except ConfigError as exc:
        _fail(str(ConfigError(exc.problems, sweep_path)), EXIT_INVALID)
    out_dir = _out_dir(output_dir)
    _setup(verbose, quiet, device, threads, kernels=True)
    pool = _make_executor(executor, workers, address, len(cases), debug)
    progress = ProgressDisplay(enabled=not quiet, every_stage=verbose > 0)
    try:
        with pool:
            result = run_sweep(settings, out_dir, executor=pool, progress=progress)
    except KeyboardInterrupt:
        _interrupted(progress)
    except Exception as exc:
        progress.close()
        _fail_error(exc, debug)
    progress.close()
    if not quiet:
        click.echo(f"{len(result.rows)} case(s) on {pool.describe()}")
        click.echo(rows_table(result.rows))
        click.echo("wrote:")
    for f in result.files:
        click.echo(f"  {f}" if not quiet else str(f))
    if result.failed:
        _fail(f"{len(result.failed)} of {len(result.rows)} cases failed", EXIT_FAILURE)


@main.command()
@click.argument("config_path", metavar="CONFIG", type=click.Path(dir_okay=False, path_type=Path))
@_set_option
@click.option("--dump", is_flag=True, help="Print the whole resolved config (defaults, absolute paths) as YAML.")
@_common_options(kernels=False)
@click.pass_context
def validate(ctx, config_path: Path, overrides, dump: bool, verbose, quiet, debug: bool) -> None:
    """Check CONFIG (and --set overrides) without rendering; print a summary or every problem."""
    _setup(verbose, quiet)
    config = _load(_config_file(config_path), overrides, debug or ctx.obj.get("debug", False))
    if dump:
        click.echo(config.model_dump_yaml(), nl=False)
        return
    click.echo(f"ok: {config.source or config_path}")
    if not quiet:
        for line in _summary(config):
            click.echo(line)


@main.command()
@click.option("-o", "--output", "output", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the schema to this file instead of stdout.")
@_common_options(kernels=False)
def schema(output, verbose, quiet, debug) -> None:
    """Print the JSON schema of a config (every key with its type, range, default and description).

    Point an editor's YAML language server at it for completion and checks, e.g. a first line
    `# yaml-language-server: $schema=warpscatter.schema.json`.
    """
    _setup(verbose, quiet)
    text = json.dumps(Config.model_json_schema(), indent=2) + "\n"
    if output is None:
        click.echo(text, nl=False)
        return
    from warpscatter.imageio import write_file_atomic

    try:
        output.parent.mkdir(parents=True, exist_ok=True)
        write_file_atomic(output, lambda tmp: tmp.write_text(text, encoding="utf-8"))
    except OSError as exc:
        _fail(f"-o {output}: {exc}", EXIT_FAILURE, debug)
    if not quiet:
        click.echo(f"wrote:\n  {output}")


@main.command()
@click.argument("suite", required=False)
@click.argument("reports", nargs=-1, type=click.Path(dir_okay=False, exists=True, path_type=Path))
@click.option("--repeats", type=click.IntRange(min=1), default=5, show_default=True,
              help="Timed runs per case (pareto: interleaved rounds over all of a scene's cases).")
@click.option("--warmup", type=click.IntRange(min=0), default=1, show_default=True, help="Untimed runs first.")
@click.option(
    "-o",
    "--output-dir",
    "output_dir",
    type=click.Path(path_type=Path),
    help="Folder for the reports (JSON, CSV, PNG charts); default: bench-out in the current folder.",
)
@click.option("--quick", is_flag=True, help="Smaller sizes and fewer cases (a smoke run).")
@click.option("--list", "list_suites", is_flag=True, help="List the suites and exit.")
@_common_options(kernels=True)
@click.pass_context
def bench(ctx, suite, reports, repeats: int, warmup: int, output_dir: Path, quick: bool, list_suites: bool,
          verbose, quiet, debug: bool, device, threads):
    """Run benchmark SUITE (or "all"): per-stage times (median and spread of the repeats), memory, and the error
    against the exact reference; writes JSON, CSV and charts.

    Without SUITE: the reference suite (ray marching at 1920x1080, about 2 minutes on two cores). --list shows
    every suite with what it measures. "bench compare A.json B.json" compares two reports case by case.
    """
    debug = debug or ctx.obj.get("debug", False)
    _setup(verbose, quiet)
    if suite == "compare":
        if len(reports) != 2:
            _fail("bench compare: give two report files (bench compare A.json B.json)", EXIT_INVALID)
        from warpscatter.bench.compare import compare_reports

        try:
            click.echo(compare_reports(*reports))
        except ValueError as exc:
            _fail(str(exc), EXIT_INVALID, debug)
        return
    if reports:
        _fail(f"unexpected arguments {' '.join(map(str, reports))} (report files go with: bench compare A B)",
              EXIT_INVALID)
    device = _setup(verbose, quiet, device, threads, kernels=True)
    try:
        bench_module = importlib.import_module("warpscatter.bench")
        suites = dict(bench_module.SUITES)
    except Exception as exc:
        _fail(_error_text(exc), EXIT_FAILURE, debug)
    if list_suites:
        width = max((len(n) for n in suites), default=0)
        for suite_name, suite_record in suites.items():
            click.echo(f"{suite_name:<{width}}  {suite_record.description}")
        return
    if suite is None:
        suite = _default_suite(bench_module.run) or next(iter(suites), None)
        if not quiet:
            click.echo(f"running the default suite {suite!r} ({DEFAULT_SUITE_DURATION}; warpscatter bench --list "
                       f"shows the others)", err=True)
    if suite not in suites and suite != "all":
        _fail(f"unknown suite {suite!r} (choose from: {', '.join([*suites, 'all', 'compare'])})", EXIT_INVALID)
    out_dir = _out_dir(output_dir)

    progress = ProgressDisplay(enabled=not quiet, every_stage=verbose > 0)
    try:
        report = bench_module.run(
            suite, repeats=repeats, warmup=warmup, out_dir=out_dir, quick=quick, progress=progress
        )
    except KeyboardInterrupt:
        _interrupted(progress)
    except Exception as exc:
        progress.close()
        _fail(_error_text(exc), EXIT_FAILURE, debug)
    progress.close()
    if not quiet:
        click.echo(report.table())
        click.echo("wrote:")
    for f in list(getattr(report, "files", [])):
        click.echo(f"  {f}" if not quiet else str(f))


def _grid(text: str | None, option: str) -> tuple[int, int] | None:
    """``N1xN2`` as two positive integers (None stays None)."""
    if text is None:
        return None
    try:
        n1, n2 = (int(x) for x in text.lower().split("x"))
        if n1 < 1 or n2 < 1:
            raise ValueError
    except ValueError:
        _fail(f"{option}: expected N1xN2 with positive integers, got {text!r}", EXIT_INVALID)
    return n1, n2


_CSM = csm_settings.CSMBuildSettings.model_fields


def _default(name: str) -> str:
    d = _CSM[name].default
    return "x".join(map(str, d)) if isinstance(d, tuple) else str(d)


@main.command()
@click.argument("source", type=click.Path(path_type=Path))
@click.option("-o", "--output", "output", type=click.Path(path_type=Path), required=True,
              help="The .npz file to write, or a folder to write SOURCE_STEM.csm.npz into (written to a temporary "
                   "name, then renamed).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help="Config overrides (SOURCE = config).")
@click.option("--maps", default=None, metavar="N1xN2",
              help=f"Lat-long grid of map directions (azimuth x polar cells) [default: the config's "
                   f"render.lighting.csm.maps, else {_default('maps')}].")
@click.option("--resolution", type=click.IntRange(min=csm_settings.MIN_RESOLUTION, max=csm_settings.MAX_RESOLUTION),
              default=None, help=f"Depth-map resolution M [default: the config's, else {_default('resolution')}].")
@click.option("--enumeration", type=click.Choice(csm_settings.ENUMERATIONS), default=None,
              help=f"Order of the maps along the compressed sequence [default: the config's, else "
                   f"{_default('enumeration')}].")
@click.option("--layers", type=click.Choice(csm_settings.DEPTH_LAYERS), default=None,
              help=f"Depths kept per texel: first and second surface, or first and third (closed meshes) [default: "
                   f"the config's, else {_default('layers')}].")
@click.option("--far", type=click.Choice(csm_settings.FAR_MODES), default=None,
              help=f"Far depth of texels without a second surface: the bounding sphere, or infinity [default: the "
                   f"config's, else {_default('far')}].")
@click.option("--batch", type=click.IntRange(min=1, max=csm_settings.MAX_BATCH), default=None,
              help=f"Maps rendered and compressed per batch (memory ~ M^2 x batch) [default: the config's, else "
                   f"{_default('batch')}].")
@click.option("--light-samples", "light_samples", default=None, metavar="N1xN2",
              help=f"Config with an area / linear light: depth cube maps at N1xN2 points of the light (N1 for "
                   f"linear) [default: the config's, else {_default('light_samples')}].")
@_common_options(kernels=True)
@click.pass_context
def precompute(ctx, source: Path, output: Path, overrides, maps, resolution, enumeration, layers, far, batch,
               light_samples, verbose, quiet, debug: bool, device, threads):
    """Build and save a coherent shadow map (Ritschel 2007) for SOURCE: a mesh file, or a config's scene.

    From a config, the CSM holds the scene's occluders (meshes not marked receiver_only) in world space, ready
    for render.lighting.csm.file: depth cube maps at the light's sample points for an area or linear light
    (unless render.lighting.csm.local_lights is semi_local), else lat-long maps. Options not given take the
    config's render.lighting.csm values (a mesh file: their defaults).
    """
    debug = debug or ctx.obj.get("debug", False)
    given = {"maps": _grid(maps, "--maps"), "light_samples": _grid(light_samples, "--light-samples"),
             "resolution": resolution, "enumeration": enumeration, "layers": layers, "far": far, "batch": batch}
    _setup(verbose, quiet, device, threads, kernels=True)
    if output.is_dir() or str(output).endswith(("/", os.sep)):
        output = output / f"{source.stem}.csm.npz"
    if output.suffix != ".npz":
        _fail(f"-o: the CSM file must end in .npz (or be a folder), got {output}", EXIT_INVALID)
    if not source.is_file():
        _fail(f"{source}: file not found", EXIT_INVALID)
    light, base = None, csm_settings.CSMBuildSettings()
    try:
        if source.suffix in (".yaml", ".yml"):
            from warpscatter.csm.occluders import scene_occluders
            from warpscatter.scene import build_scene

            config = load_config(source, list(overrides))
            scene = build_scene(config)
            vertices, triangles = scene_occluders(scene)
            if len(triangles) == 0:
                _fail(f"{source}: every mesh is receiver_only: no occluder to build a CSM of", EXIT_INVALID)
            light, base = scene.light, config.render.lighting.csm
        else:
            from warpscatter.scene.meshes import load_mesh

            mesh = load_mesh(source)
            vertices, triangles = mesh.vertices, mesh.triangles
    except ConfigError as exc:
        _fail(str(exc), EXIT_INVALID)
    except Exception as exc:
        _fail(f"{source}: {_error_text(exc)}", EXIT_INVALID, debug)
    try:
        settings = csm_settings.CSMBuildSettings.model_validate(
            {**base.model_dump(), "file": None, **{k: v for k, v in given.items() if v is not None}})
    except ValidationError as exc:
        problems = format_validation_errors(exc, csm_settings.CSMBuildSettings)
        _fail("\n".join(f"--{p.replace('_', '-')}" for p in problems), EXIT_INVALID)
    from warpscatter.csm import save_csm
    from warpscatter.csm.compress import KIND_CUBE
    from warpscatter.csm.occluders import prepare_csm

    progress = ProgressDisplay(enabled=not quiet, every_stage=verbose > 0)
    try:
        t0 = time.perf_counter()
        csm = prepare_csm(light, settings, vertices, triangles,
                          progress=lambda f: progress("depth maps + compression", f))
        output.parent.mkdir(parents=True, exist_ok=True)
        save_csm(csm, output)
    except KeyboardInterrupt:
        progress.close()
        _fail("interrupted", EXIT_INTERRUPTED)
    except Exception as exc:
        progress.close()
        _fail_error(exc, debug)
    progress.close()
    st = csm.stats
    what = (f"6 x {csm.n1}x{csm.n2} cube maps of the {light.kind} light" if csm.kind == KIND_CUBE
            else f"{csm.n1}x{csm.n2} maps")
    if not quiet:
        click.echo(f"coherent shadow map: {len(triangles)} triangles, N = {what} of {csm.resolution}^2, "
                   f"{settings.enumeration}")
        click.echo(f"  segments {st.num_segments} ({st.segments_per_texel:.1f} per texel), "
                   f"{st.compressed_bytes / 2**20:.1f} MiB, ratio {st.ratio:.1f}:1 against float32 maps")
        click.echo(f"  render {st.seconds_render:.1f} s, compress {st.seconds_compress:.1f} s, "
                   f"total {time.perf_counter() - t0:.1f} s, peak working memory "
                   f"{_format_bytes(st.peak_working_bytes)}")
    click.echo(str(output) if quiet else f"wrote:\n  {output}")


if __name__ == "__main__":
    main()
