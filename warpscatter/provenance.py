"""What made an output: software versions, the machine, the source commit and the time, for sidecars and reports.

Every value is gathered without failing: what cannot be found is ``None``.
"""

from __future__ import annotations

import datetime
import functools
import os
import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path

from . import __version__

#: Distributions whose versions an output records (import names differ: warp-lang is ``warp``).
DISTRIBUTIONS = ("warp-lang", "numpy", "OpenImageIO", "trimesh", "pydantic", "PyYAML", "click")


def versions() -> dict[str, str | None]:
    """Versions of Python, warpscatter and its main dependencies (``None`` where not installed)."""
    out: dict[str, str | None] = {"python": platform.python_version(), "warpscatter": __version__}
    for name in DISTRIBUTIONS:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


@functools.lru_cache(maxsize=1)
def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``; else ``platform.processor()``; else the machine type)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


@functools.lru_cache(maxsize=1)
def source_commit() -> str | None:
    """The git commit of warpscatter's source tree (with ``+dirty`` when it has changes), or None when it is not
    a git checkout (an installed wheel) or git is unavailable."""
    root = Path(__file__).resolve().parent.parent
    if not (root / ".git").exists():
        return None
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                              timeout=5, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=5, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return head + ("+dirty" if dirty else "") if head else None


def machine() -> dict[str, object]:
    """The machine: CPU model, usable cores, OS."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - non-Linux
        cores = os.cpu_count()
    return {"cpu": cpu_model(), "cores": cores, "os": platform.platform(), "host": platform.node()}


def timestamp() -> str:
    """Now, ISO 8601 in UTC with seconds (``2026-12-02T06:30:00Z``)."""
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def provenance() -> dict[str, object]:
    """Everything above in one mapping: ``created``, ``command``, ``versions``, ``machine``, ``commit``."""
    return {"created": timestamp(), "command": list(sys.argv), "versions": versions(), "machine": machine(),
            "commit": source_commit()}


__all__ = ["DISTRIBUTIONS", "cpu_model", "machine", "provenance", "source_commit", "timestamp", "versions"]
