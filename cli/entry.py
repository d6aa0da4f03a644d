"""The ``warpscatter`` console script and ``python -m warpscatter``: a SIGTERM while Python still imports the command
line (about a second) exits 130 with ``error: interrupted``, as one during a command does; then the click application
(:mod:`.main`) runs. Kept apart so that importing :mod:`.main` (tests, docs) installs no signal handler."""

from __future__ import annotations

import signal
import sys


def _terminated_during_start_up(signum, frame):
    sys.stderr.write("error: interrupted\n")
    raise SystemExit(130)


def run() -> None:
    if signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _terminated_during_start_up)  # the command's own handler replaces it
    from .main import main

    main()
