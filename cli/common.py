"""What every command of the ``warpscatter`` application shares: options, set-up, progress display, formatting and
exits.

Exit codes: :data:`EXIT_FAILURE` (1) a failure while working, :data:`EXIT_INVALID` (2) an invalid config, override,
suite name or command line (nothing is written then), :data:`EXIT_INTERRUPTED` (130) interrupted. :func:`fail`
prints ``error: ...`` to stderr and exits with one of them.
"""

from __future__ import annotations

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

from warpscatter.config import Config, load_config
from warpscatter.errors import ConfigError, WarpscatterError
from warpscatter.io.resources import bundled_config
from warpscatter.scene.light_configs import format_value

if TYPE_CHECKING:
    from warpscatter.runtime.stages import Estimate

EXIT_FAILURE = 1
EXIT_INVALID = 2
EXIT_INTERRUPTED = 130

# ---- options and set-up -----------------------------------------------------------------------------

#: Seconds between progress lines when stderr is not a terminal (logs, CI).
PLAIN_PROGRESS_INTERVAL = 10.0
#: Rows of the default timing table (a render with more stages shows its longest ones and one row for the rest).
TIMING_ROWS = 6

log = logging.getLogger("warpscatter")

set_option = click.option(
    "--set",
    "overrides",
    multiple=True,
    metavar="KEY=VALUE",
    help="Override a config value, e.g. --set camera.fov_y=40 --set scene.meshes.0.material.opacity=0.5 "
    "(VALUE is parsed as YAML; repeatable; relative paths resolve against the config file's folder, as in the "
    "config itself).",
)


def common_options(kernels: bool):
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


def executor_options(default: str):
    """--executor (``default``) / --workers / --address of the commands that run many renders."""
    return lambda f: _add_executor_options(f, default)


def _add_executor_options(f, default: str):
    from warpscatter.runs.jobs import EXECUTORS

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


def make_executor(kind: str, workers: int | None, address: str | None, tasks: int, debug: bool):
    from warpscatter.runs.jobs import make_executor
    from warpscatter.runtime.parallel import thread_count

    if workers is None and kind != "inline" and not address:
        workers = max(1, min(thread_count(), tasks))
    try:
        return make_executor(kind, workers, address)
    except (ValueError, ImportError) as exc:
        fail(str(exc), EXIT_INVALID, debug)
    except OSError as exc:  # the scheduler cannot be reached
        fail(f"--address {address}: {exc}", EXIT_FAILURE, debug)


def setup(verbose: int, quiet: bool, device: str | None = None, threads: int | None = None,
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

    from warpscatter.errors import DeviceError
    from warpscatter.runtime.device import check_device, init

    wp.config.log_level = wp.LOG_INFO if verbose else wp.LOG_WARNING  # this process is ours: Warp quiet by default
    init(quiet_native=verbose < 2)
    name = device or os.environ.get("WARPSCATTER_DEVICE") or "cpu"
    try:
        check_device(name, "--device" if device else "WARPSCATTER_DEVICE")
    except DeviceError as e:
        fail(str(e), EXIT_INVALID)
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
    :class:`~warpscatter.runtime.stages.EtaEstimator` (each stage's own measured rate; the stages still to come from
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
        expected: stage -> seconds of an earlier run, in order (see :class:`~warpscatter.runtime.stages.EtaEstimator`).
        every_stage: without a terminal, a line for every stage that starts (``-v``).
    """

    def __init__(self, enabled: bool = True, stream=None, interval: float | None = None, prefix: str = "",
                 expected=None, every_stage: bool = False):
        from warpscatter.runtime.stages import EtaEstimator

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


def format_seconds(s: float) -> str:
    """A duration in us, ms or s, 11 characters wide (the timing table's column)."""
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
        lines.append(f"{k:<{width}}  {format_seconds(v)}  {share:5.1f}%")
    lines.append("-" * (width + 21))
    lines.append(f"{'total':<{width}}  {format_seconds(total)}  {100.0 if total > 0 else 0.0:5.1f}%")
    return "\n".join(lines)


def format_bytes(n: int) -> str:
    """A byte count in B, KiB, MiB or GiB."""
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
            text = format_bytes(value)
        elif str(key) in _SIZE_STATS and isinstance(value, (list, tuple)) and len(value) == 2:
            text = f"{value[0]} x {value[1]}"
        else:
            text = format_value(value)
        lines.append(f"{key}: {text}")
    return lines


# ---- errors and exits -------------------------------------------------------------------------------


def fail(message: str, code: int, debug: bool = False) -> None:
    """Print ``error: message`` to stderr (with ``debug`` the traceback first) and exit with ``code``."""
    if debug:
        traceback.print_exc(file=sys.stderr)
    click.echo(f"error: {message}", err=True)
    sys.exit(code)


def find_config(path: Path) -> Path:
    """A config file, or the name of a bundled config (``quickstart``: configs/quickstart.yaml of the checkout or of
    the installed package) when no such file exists here."""
    if path.exists() or path.suffix or len(path.parts) != 1:
        return path
    try:
        return bundled_config(path.name)
    except FileNotFoundError:
        return path


def load_or_exit(config_path: Path, overrides, debug: bool) -> Config:
    try:
        return load_config(config_path, list(overrides))
    except ConfigError as exc:
        fail(str(exc), EXIT_INVALID)
    except Exception as exc:  # a bug, not a user error: keep the traceback reachable
        fail(f"{type(exc).__name__}: {exc}", EXIT_FAILURE, debug)


def fail_error(exc: BaseException, debug: bool) -> None:
    """Exit for an exception of a command: a :class:`WarpscatterError` with its exit code, anything else 1."""
    if isinstance(exc, WarpscatterError):
        fail(str(exc), exc.exit_code, debug)
    fail(error_text(exc), EXIT_FAILURE, debug)


def error_text(exc: BaseException) -> str:
    """An exception as one line: the message of a ValueError or OSError, else the type and the message."""
    text = str(exc)
    if isinstance(exc, (ValueError, OSError)) and text:
        return text
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def resolve_out_dir(path: Path | None) -> Path | None:
    """An ``-o`` folder as an absolute path (None stays None); exits 2 when it is a file."""
    if path is None:
        return None
    out = Path(path).expanduser().resolve()
    if out.exists() and not out.is_dir():
        fail(f"-o {path}: not a directory", EXIT_INVALID)
    return out


def interrupted(progress: ProgressDisplay) -> None:
    """Close the progress display and exit 130 (Ctrl-C, SIGTERM)."""
    progress.close()
    fail("interrupted", EXIT_INTERRUPTED)


__all__ = [
    "EXIT_FAILURE",
    "EXIT_INTERRUPTED",
    "EXIT_INVALID",
    "ProgressDisplay",
    "common_options",
    "error_text",
    "eta_text",
    "executor_options",
    "fail",
    "fail_error",
    "find_config",
    "format_bytes",
    "format_seconds",
    "format_value",
    "interrupted",
    "load_or_exit",
    "make_executor",
    "resolve_out_dir",
    "set_option",
    "setup",
    "stats_lines",
    "timing_table",
]
