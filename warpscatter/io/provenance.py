"""What made an output: software versions, the machine, the source commit and the time, for sidecars and reports.
Every value is gathered without failing: what cannot be found is ``None``."""

from __future__ import annotations

import datetime
import functools
import os
import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path

from .. import __version__

#: Distributions whose versions an output records (import names differ: warp-lang is ``warp``).
DISTRIBUTIONS = ("warp-lang", "numpy", "OpenImageIO", "trimesh", "pydantic", "PyYAML", "click")


def versions() -> dict[str, str | None]:
    """Versions of Python, warpscatter and its main dependencies (``None`` where not installed)."""
    out: dict[str, str | None] = {"python": platform.python_version(), "warpscatter": __version__}
    out.update({name: package_version(name) for name in DISTRIBUTIONS})
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


def _git(root: Path, *args: str) -> str | None:
    """``git args`` in ``root`` (stdout stripped), None on any failure or after 2 s."""
    try:
        done = subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, timeout=2.0, check=False)
    except (OSError, subprocess.SubprocessError, ValueError):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


@functools.lru_cache(maxsize=1)
def source_commit() -> tuple[str | None, bool | None]:
    """(HEAD commit, whether tracked files differ from it) of the git checkout warpscatter is imported from, or
    (None, None) when it is not one (an installed wheel: a site-packages inside another repository never counts)."""
    root = Path(__file__).resolve().parents[2]
    top = _git(root, "rev-parse", "--show-toplevel")
    if top is None or Path(top).resolve() != root:
        return None, None
    status = _git(root, "status", "--porcelain", "--untracked-files=no")
    return _git(root, "rev-parse", "HEAD"), None if status is None else bool(status)


def package_version(dist: str, module: str | None = None) -> str | None:
    """The installed version of distribution ``dist`` (else ``module.__version__``), None when missing."""
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        pass
    try:
        return getattr(__import__(module or dist), "__version__", None)
    except ImportError:
        return None


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
    """Everything above: ``created``, ``command``, ``versions``, ``machine``, ``commit``, ``git_dirty``."""
    commit, dirty = source_commit()
    return {"created": timestamp(), "command": list(sys.argv), "versions": versions(), "machine": machine(),
            "commit": commit, "git_dirty": dirty}


__all__ = ["DISTRIBUTIONS", "cpu_model", "machine", "package_version", "provenance", "source_commit", "timestamp",
           "versions"]
