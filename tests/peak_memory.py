"""Peak resident memory of a child process, measured inside it: ``VmHWM`` of ``/proc/self/status``, which belongs to
the child's own address space. ``ru_maxrss`` would not do: Linux keeps it across ``execve``, so a child started by a
pytest process that already holds 1.5 GB reports at least that much whatever it used itself."""

from __future__ import annotations

import re
import subprocess
import sys

#: A Python expression: this process's peak resident memory in bytes (Linux).
PEAK_BYTES = "int(next(l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM:'))) * 1024"

_REPORT = re.compile(r"^peak_bytes=(\d+)$", re.M)


def cli_with_peak(args, **kwargs) -> tuple[subprocess.CompletedProcess, int]:
    """``warpscatter ARGS`` (the console script's entry) in a child that reports its peak memory when it exits:
    (the finished process, with the report taken out of its stderr; the peak in bytes)."""
    code = ("import atexit, sys\n"
            f"atexit.register(lambda: sys.stderr.write('\\npeak_bytes=%d\\n' % ({PEAK_BYTES})))\n"
            f"sys.argv = ['warpscatter', *{[str(a) for a in args]!r}]\n"
            "from warpscatter.cli.entry import run\nrun()\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, **kwargs)
    found = _REPORT.findall(done.stderr)
    done.stderr = _REPORT.sub("", done.stderr).rstrip("\n") + "\n"
    return done, int(found[-1]) if found else 0
