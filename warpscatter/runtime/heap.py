"""Keep large freed buffers in the process heap, so that repeated frames reuse pages already mapped.

:func:`keep_freed_memory` raises glibc's mmap and trim thresholds (else every frame pays page faults and zeroing
again); :func:`keep_freed_warp_buffers` gives Warp's CPU device a :class:`CachingHostAllocator`, since a fragmented
heap no longer fits a frame's largest textures. Both are process-wide; the CLI applies them unless
``WARPSCATTER_KEEP_FREED_MEMORY=0``, and resident memory stays at its peak. Figures: docs/design/csm-core.md.
"""

from __future__ import annotations

import ctypes
import logging
import os
import sys
import threading
from collections import OrderedDict

log = logging.getLogger("warpscatter")

#: glibc's ``mallopt`` parameters (malloc.h).
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
#: Blocks up to this size stay in the heap after they are freed (1 GiB covers every buffer of an 8K frame).
KEEP_LIMIT_BYTES = 1 << 30
#: Freed Warp CPU blocks of at least this size are kept (the heap reuses smaller ones well).
CACHE_MIN_BYTES = 1 << 20
#: At most this many bytes of freed Warp CPU blocks are kept (a 1080p frame of one method needs 250-410 MB).
CACHE_LIMIT_BYTES = 2 << 30

_applied = False


def keep_freed_memory(limit_bytes: int = KEEP_LIMIT_BYTES) -> bool:
    """Keep freed blocks up to ``limit_bytes`` in this process's heap (glibc ``mallopt`` thresholds); True when
    applied (now or earlier, whose limit stays), False without ``mallopt`` (macOS, Windows, musl)."""
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


class CachingHostAllocator:
    """A Warp host allocator that keeps freed blocks of at least ``min_bytes`` for the next request of that size.

    The most recently freed block goes out first (its pages are likeliest resident); beyond ``limit_bytes`` the
    oldest are released. Thread-safe; reused memory is not cleared. ``hits`` / ``misses``: requests of at least
    ``min_bytes`` served from kept blocks / by ``base``.
    """

    def __init__(self, base, min_bytes: int = CACHE_MIN_BYTES, limit_bytes: int = CACHE_LIMIT_BYTES):
        self.base = base
        self.min_bytes = int(min_bytes)
        self.limit_bytes = int(limit_bytes)
        # what Warp's allocator protocol reads besides allocate / deallocate: the wrapped allocator's
        self.memory_kind = getattr(base, "memory_kind", None)
        self.deallocate_requires_context_guard = getattr(base, "deallocate_requires_context_guard", False)
        self._kept: OrderedDict[int, int] = OrderedDict()  # pointer -> size, oldest first
        self._by_size: dict[int, list[int]] = {}
        self._kept_bytes = 0
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    @property
    def kept_bytes(self) -> int:
        """Bytes of freed blocks held for reuse."""
        return self._kept_bytes

    def allocate(self, size_in_bytes: int):
        if size_in_bytes >= self.min_bytes:
            with self._lock:
                same = self._by_size.get(size_in_bytes)
                if same:
                    ptr = same.pop()
                    del self._kept[ptr]
                    self._kept_bytes -= size_in_bytes
                    self.hits += 1
                    return ptr
                self.misses += 1
        return self.base.allocate(size_in_bytes)

    def deallocate(self, ptr, size_in_bytes: int) -> None:
        if size_in_bytes < self.min_bytes or size_in_bytes > self.limit_bytes:
            self.base.deallocate(ptr, size_in_bytes)
            return
        with self._lock:
            self._kept[ptr] = size_in_bytes
            self._by_size.setdefault(size_in_bytes, []).append(ptr)
            self._kept_bytes += size_in_bytes
            released = self._evict(self.limit_bytes)
        for old, size in released:
            self.base.deallocate(old, size)

    def _evict(self, limit: int) -> list[tuple[int, int]]:
        """Take the oldest kept blocks out until at most ``limit`` bytes are kept (the lock held); returns them."""
        released = []
        while self._kept_bytes > limit and self._kept:
            old, size = self._kept.popitem(last=False)
            self._by_size[size].remove(old)
            self._kept_bytes -= size
            released.append((old, size))
        return released

    def release(self) -> None:
        """Return every kept block to the wrapped allocator."""
        with self._lock:
            released = self._evict(0)
        for ptr, size in released:
            self.base.deallocate(ptr, size)


def default_cache_limit() -> int:
    """:data:`CACHE_LIMIT_BYTES`, or an eighth of the machine's physical memory where that is less."""
    try:
        memory = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, OSError, ValueError):  # pragma: no cover - no sysconf (Windows)
        return CACHE_LIMIT_BYTES
    return int(min(CACHE_LIMIT_BYTES, max(memory, 0) // 8))


def keep_freed_warp_buffers(device="cpu", limit_bytes: int | None = None) -> CachingHostAllocator | None:
    """Give Warp's CPU device a :class:`CachingHostAllocator` keeping at most ``limit_bytes`` (None:
    :func:`default_cache_limit`) as its ``default_allocator`` (Warp offers custom allocators publicly for CUDA only).
    Returns it (an earlier call's, whose limit stays), or None where nothing was installed."""
    import warp as wp

    if limit_bytes is None:
        limit_bytes = default_cache_limit()

    wp.init()
    dev = wp.get_device(device)
    current = getattr(dev, "default_allocator", None)
    if not dev.is_cpu or current is None or not hasattr(current, "allocate") or not hasattr(current, "deallocate"):
        return None
    if isinstance(current, CachingHostAllocator):
        return current
    dev.default_allocator = CachingHostAllocator(current, limit_bytes=limit_bytes)
    log.debug("freed Warp CPU blocks of %d MB and more are kept for reuse (up to %d MB)", CACHE_MIN_BYTES >> 20,
              limit_bytes >> 20)
    return dev.default_allocator


def restore_warp_allocator(device="cpu") -> bool:
    """Undo :func:`keep_freed_warp_buffers`; returns whether one was installed."""
    import warp as wp

    dev = wp.get_device(device)
    current = getattr(dev, "default_allocator", None)
    if not isinstance(current, CachingHostAllocator):
        return False
    current.release()
    current.limit_bytes = 0  # blocks freed later go straight back
    dev.default_allocator = current.base
    return True


def keep_freed_memory_unless_disabled() -> bool:
    """Both keepers unless ``WARPSCATTER_KEEP_FREED_MEMORY=0``; the allocator is installed once Warp starts (so
    ``--help`` starts no Warp). Returns False when the environment turns it off."""
    if os.environ.get("WARPSCATTER_KEEP_FREED_MEMORY", "1").strip() == "0":
        return False
    from . import device as wpinit

    applied = keep_freed_memory()
    wpinit.after_init(keep_freed_warp_buffers)  # now if Warp is up, else right after wpinit.init()
    return applied


__all__ = ["CACHE_LIMIT_BYTES", "CACHE_MIN_BYTES", "CachingHostAllocator", "KEEP_LIMIT_BYTES", "default_cache_limit",
           "keep_freed_memory", "keep_freed_memory_unless_disabled", "keep_freed_warp_buffers",
           "restore_warp_allocator"]
