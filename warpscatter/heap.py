"""Keep large freed buffers in the process heap, so that repeated frames reuse pages already mapped.

A 1920x1080 frame allocates tens of MB of textures per stage. glibc serves blocks above its mmap threshold (at most
32 MB) with fresh ``mmap`` pages and unmaps them on free, so every frame pays the kernel's page faults and zeroing
again (at 1080p on two cores: epipolar's line textures, ~80 MB, are written in ~45 ms into fresh pages and in ~17 ms
into mapped ones). :func:`keep_freed_memory` raises the mmap and trim thresholds, so freed blocks stay in the heap
and the next frame reuses them. It is process-wide: the CLI applies it to its own process
(``WARPSCATTER_KEEP_FREED_MEMORY=0`` turns it off); a program calling warpscatter's API decides for itself. The cost
is that the process's resident memory stays at its peak instead of shrinking between frames.
"""

from __future__ import annotations

import ctypes
import logging
import os
import sys

log = logging.getLogger("warpscatter")

#: glibc's ``mallopt`` parameters (malloc.h).
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
#: Blocks up to this size stay in the heap after they are freed (1 GiB covers every buffer of an 8K frame).
KEEP_LIMIT_BYTES = 1 << 30

_applied = False


def keep_freed_memory(limit_bytes: int = KEEP_LIMIT_BYTES) -> bool:
    """Keep freed blocks up to ``limit_bytes`` in this process's heap (glibc's ``mallopt``: mmap threshold and trim
    threshold both ``limit_bytes``).

    Returns:
        True when applied (now, or by an earlier call, whose limit stays), False where the C library has no
        ``mallopt`` or refuses the limit (macOS, Windows, musl): there it does nothing.
    """
    global _applied
    if _applied:
        return True
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    limit = int(min(max(limit_bytes, 0), 2**31 - 1))
    _applied = bool(mallopt(M_MMAP_THRESHOLD, limit)) and bool(mallopt(M_TRIM_THRESHOLD, limit))
    if _applied:
        log.debug("freed blocks up to %d MB stay in the heap (mallopt)", limit >> 20)
    return _applied


def keep_freed_memory_unless_disabled() -> bool:
    """:func:`keep_freed_memory` unless the environment sets ``WARPSCATTER_KEEP_FREED_MEMORY=0`` (what the CLI and
    its worker processes do at start). Returns False when the environment turns it off (an earlier call stays in
    force: glibc's thresholds are process state)."""
    if os.environ.get("WARPSCATTER_KEEP_FREED_MEMORY", "1").strip() == "0":
        return False
    return keep_freed_memory()


__all__ = ["KEEP_LIMIT_BYTES", "keep_freed_memory", "keep_freed_memory_unless_disabled"]
