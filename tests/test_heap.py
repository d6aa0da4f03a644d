"""warpscatter.runtime.heap: freed frame-sized buffers stay in the heap, so the next frame's allocation does not fault
in fresh pages."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import threading

import pytest
import warp as wp

from warpscatter.runtime.heap import (
    CACHE_LIMIT_BYTES,
    CachingHostAllocator,
    default_cache_limit,
    keep_freed_memory,
    keep_freed_memory_unless_disabled,
    keep_freed_warp_buffers,
    restore_warp_allocator,
)

_FAULTS = textwrap.dedent("""
    import resource, sys
    import numpy as np
    from warpscatter.runtime.heap import keep_freed_memory
    if sys.argv[1] == "keep":
        assert keep_freed_memory()
    np.ones(64 << 18, dtype=np.float32)  # 64 MB: above glibc's mmap threshold
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(3):
        np.ones(64 << 18, dtype=np.float32)  # allocated, written, freed: one frame's texture
    print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
""")


def _page_faults(mode: str) -> int:
    out = subprocess.run([sys.executable, "-c", _FAULTS, mode], capture_output=True, text=True, check=True)
    return int(out.stdout.split()[-1])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_freed_buffers_are_reused_without_page_faults():
    plain, kept = _page_faults("plain"), _page_faults("keep")
    # 3 x 64 MB of fresh pages: at least one fault per 2 MiB (transparent huge pages), ~49k with 4 KiB pages;
    # kept: the same pages each time
    assert plain >= 96  # measured 1632 (huge pages on)
    assert kept <= plain // 10  # measured 0


def test_keep_freed_memory_is_idempotent():
    first = keep_freed_memory()
    assert keep_freed_memory() == first
    assert first == sys.platform.startswith("linux")


def test_the_environment_can_turn_it_off(monkeypatch):
    monkeypatch.setenv("WARPSCATTER_KEEP_FREED_MEMORY", "0")
    assert keep_freed_memory_unless_disabled() is False


class _CountingAllocator:
    """A stand-in for Warp's host allocator: hands out fresh integer 'pointers' and records what comes back."""

    memory_kind = None

    def __init__(self):
        self.next = 1000
        self.live: dict[int, int] = {}
        self.allocations = 0

    def allocate(self, size):
        self.next += 1
        self.allocations += 1
        self.live[self.next] = size
        return self.next

    def deallocate(self, ptr, size):
        assert self.live.pop(ptr) == size  # every block comes back once, with its own size


MB = 1 << 20


def test_caching_allocator_reuses_freed_blocks_of_the_same_size():
    base = _CountingAllocator()
    cache = CachingHostAllocator(base, min_bytes=MB, limit_bytes=64 * MB)
    a = cache.allocate(8 * MB)
    cache.deallocate(a, 8 * MB)
    assert cache.kept_bytes == 8 * MB and a in base.live  # kept, not returned
    assert cache.allocate(8 * MB) == a  # the same block again
    assert cache.allocate(4 * MB) != a  # another size: a fresh block
    assert (cache.hits, cache.misses, base.allocations) == (1, 2, 2)
    # below min_bytes nothing is kept
    small = cache.allocate(MB - 1)
    cache.deallocate(small, MB - 1)
    assert small not in base.live and cache.kept_bytes == 0


def test_caching_allocator_keeps_at_most_its_limit_releasing_the_oldest():
    base = _CountingAllocator()
    cache = CachingHostAllocator(base, min_bytes=MB, limit_bytes=20 * MB)
    blocks = [cache.allocate(8 * MB) for _ in range(3)]
    for b in blocks:
        cache.deallocate(b, 8 * MB)
    assert cache.kept_bytes == 16 * MB  # 24 MB freed, 20 MB kept at most: the oldest went back
    assert blocks[0] not in base.live and blocks[1] in base.live and blocks[2] in base.live
    assert cache.allocate(8 * MB) == blocks[2]  # the most recently freed first
    big = cache.allocate(32 * MB)  # larger than the limit: never kept
    cache.deallocate(big, 32 * MB)
    assert big not in base.live
    cache.release()
    assert cache.kept_bytes == 0 and set(base.live) == {blocks[2]}


def test_caching_allocator_is_thread_safe():
    base = _CountingAllocator()
    cache = CachingHostAllocator(base, min_bytes=MB, limit_bytes=1 << 40)

    def churn():
        for k in range(2000):
            size = (1 + k % 3) * MB
            cache.deallocate(cache.allocate(size), size)

    threads = [threading.Thread(target=churn) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    # every kept block is live in the base exactly once and accounted for; no block was handed out twice
    assert cache.kept_bytes == sum(base.live.values())
    assert cache.hits + cache.misses == 4 * 2000 and base.allocations == cache.misses <= 4 * 3


def test_the_default_limit_is_at_most_an_eighth_of_the_memory():
    limit = default_cache_limit()
    assert 0 < limit <= CACHE_LIMIT_BYTES
    if sys.platform.startswith("linux"):
        memory = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        assert limit == min(CACHE_LIMIT_BYTES, memory // 8)


def test_warp_arrays_reuse_freed_blocks_through_the_cpu_device():
    n = (16 * MB) // 4
    cache = keep_freed_warp_buffers("cpu")
    try:
        assert cache is not None and keep_freed_warp_buffers("cpu") is cache  # idempotent
        assert cache.limit_bytes == default_cache_limit()
        a = wp.empty(n, dtype=wp.float32, device="cpu")
        ptr = a.ptr
        del a
        b = wp.zeros(n, dtype=wp.float32, device="cpu")  # the same block, cleared by wp.zeros
        assert b.ptr == ptr and not b.numpy().any()
        b.fill_(3.0)
        del b
        c = wp.empty(n, dtype=wp.float32, device="cpu")
        assert c.ptr == ptr  # not cleared by wp.empty, as a fresh block is not either
    finally:
        assert restore_warp_allocator("cpu")
    assert not isinstance(wp.get_device("cpu").get_allocator(), CachingHostAllocator)
    del c  # allocated through the cache, freed after the restore: passed on to Warp's allocator
    assert cache.kept_bytes == 0
    assert not restore_warp_allocator("cpu")


_WARP_FAULTS = textwrap.dedent("""
    import resource, sys
    import warp as wp
    from warpscatter.runtime.heap import keep_freed_memory_unless_disabled
    from warpscatter.runtime.device import init
    keep_freed_memory_unless_disabled()  # as the CLI: before Warp starts (installed by init)
    init()
    n = (128 << 20) // 4  # 128 MB: a 1080p fourier frame's filtered basis

    def frame():
        big = wp.empty(n, dtype=wp.float32, device="cpu")
        big.fill_(1.0)  # written: its pages are mapped
        small = [wp.empty((3 << 20) // 4, dtype=wp.float32, device="cpu") for _ in range(8)]
        del big  # the big block is freed while smaller ones live on (what splits the heap's hole)
        return small

    kept = frame()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(3):
        kept = frame()
    print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
""")


def test_the_cli_setting_starts_no_warp_and_installs_the_allocator_with_it():
    script = textwrap.dedent("""
        import warp as wp
        from warpscatter import wpinit
        from warpscatter.runtime.heap import CachingHostAllocator, keep_freed_memory_unless_disabled
        keep_freed_memory_unless_disabled()
        assert not wpinit.initialised()
        wpinit.init()
        print(isinstance(wp.get_device("cpu").get_allocator(), CachingHostAllocator))
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert out.stdout.split()[-1] == "True"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="page-fault counts (getrusage)")
def test_the_cli_setting_keeps_warp_frames_from_faulting_in_fresh_pages():
    def faults(keep: str) -> int:
        env = {"WARPSCATTER_KEEP_FREED_MEMORY": keep}
        out = subprocess.run([sys.executable, "-c", _WARP_FAULTS], capture_output=True, text=True, check=True,
                             env={**os.environ, **env})
        return int(out.stdout.split()[-1])

    plain, kept = faults("0"), faults("1")
    # 3 frames x 128 MB of fresh pages: ~98k faults with 4 KiB pages, >= 192 with 2 MiB ones
    assert plain >= 192  # measured 98332
    assert kept <= plain // 10  # measured 8; glibc's thresholds alone (keep_freed_memory): 35836
