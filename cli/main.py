"""``warpscatter`` command line: render, validate, schema, bench, precompute, sweep and gallery, thin over the library.

Exit codes: 0 success, 1 a failure while rendering or benchmarking, 2 an invalid config, override,
suite name or command line (nothing is written then), 130 interrupted.

Every command takes ``-v/--verbose`` (repeatable), ``-q/--quiet`` and ``--debug``; the commands that run kernels
also take ``--device`` and ``--threads``. Progress goes to stderr (a bar with the elapsed time and an ETA on a
terminal; otherwise a line at the start and then one every few seconds, or one per stage with ``-v``); results
go to stdout: by default a short report (a summary line, the timing table condensed to its longest stages, the
written files), with ``-v`` every stage and statistic. A render's warnings (e.g. a light that reaches no pixel) go
to stderr as ``warning: ...`` unless ``-q``. Warp's own messages (its start-up banner, module loads, the warning of
a machine without a CUDA driver) are shown with ``-v`` only.

This module is the group and its registrations: each command is a module of this package (:mod:`.render`,
:mod:`.validate` with ``schema``, :mod:`.bench`, :mod:`.precompute`, :mod:`.sweep`, :mod:`.gallery`), and what they
share (options, set-up, progress display, formatting, exits) is :mod:`.common`.
"""

from __future__ import annotations

import click

from warpscatter import __version__

from .bench import DEFAULT_SUITE, bench
from .common import EXIT_INTERRUPTED, ProgressDisplay, eta_text, fail, timing_table
from .gallery import gallery
from .precompute import precompute
from .render import previous_timings, render
from .sweep import sweep
from .validate import schema, validate


class _Group(click.Group):
    """The group: an interrupt (Ctrl-C, SIGTERM) that no command handled itself, e.g. while a command loads its
    configs or starts Warp, exits 130 with ``error: interrupted`` as one during a render does (click would print
    ``Aborted!`` and exit 1)."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt:
            fail("interrupted", EXIT_INTERRUPTED)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
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
    from warpscatter.runtime.heap import keep_freed_memory_unless_disabled

    keep_freed_memory_unless_disabled()  # repeated frames reuse their buffers' pages (warpscatter.runtime.heap)


def _terminate_like_interrupt() -> None:
    """SIGTERM (a job scheduler, ``kill``) stops a command as Ctrl-C does: temporaries removed, previous outputs
    kept, exit code 130."""
    import signal
    import threading

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, interrupt)


for _command in (bench, gallery, precompute, render, schema, sweep, validate):
    main.add_command(_command)

#: The name the progress tests import (:func:`.render.previous_timings`).
_previous_timings = previous_timings

__all__ = ["DEFAULT_SUITE", "ProgressDisplay", "eta_text", "main", "timing_table"]

if __name__ == "__main__":
    main()
