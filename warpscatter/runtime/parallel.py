"""Splitting CPU launches across cores.

Warp runs a CPU launch on one core; :func:`launch_rows` cuts it along its outer dimension into chunks run from a
thread pool (Warp releases the GIL). Kernels take the chunk's start as their LAST input, ``offset``, and index
``wp.tid() + offset``. CPU atomics are not atomic across launches, so each chunk owns its outputs. CUDA gets one
whole launch. Threads: ``WARPSCATTER_THREADS`` or the usable cores.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import warp as wp

from .device import default_device

_pool: ThreadPoolExecutor | None = None
_pool_size = 0


def thread_count() -> int:
    """Number of worker threads used for split CPU launches (>= 1)."""
    env = os.environ.get("WARPSCATTER_THREADS")
    if env:
        return max(1, int(env))
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


def _executor(n: int) -> ThreadPoolExecutor:
    global _pool, _pool_size
    if _pool is None or _pool_size != n:
        if _pool is not None:
            _pool.shutdown(wait=True)
        _pool = ThreadPoolExecutor(max_workers=n, thread_name_prefix="warpscatter")
        _pool_size = n
    return _pool


def chunks(n: int, parts: int, min_chunk: int = 1) -> list[tuple[int, int]]:
    """Split ``range(n)`` into at most ``parts`` contiguous ``(start, stop)`` pieces of >= min_chunk."""
    parts = max(1, min(parts, n // max(1, min_chunk) or 1))
    bounds = [round(k * n / parts) for k in range(parts + 1)]
    return [(bounds[k], bounds[k + 1]) for k in range(parts) if bounds[k + 1] > bounds[k]]


def run_parallel(fn, pieces: list, threads: int | None = None, progress=None) -> list:
    """Call ``fn(piece)`` for every piece on the thread pool; return the results in order. ``progress(fraction)``,
    if given, is called from the calling thread as pieces complete."""
    n = threads or thread_count()
    results = map(fn, pieces) if n <= 1 or len(pieces) <= 1 else _executor(n).map(fn, pieces)
    out = []
    for r in results:
        out.append(r)
        if progress is not None:
            progress(len(out) / len(pieces))
    return out


def launch_rows(kernel, dim, inputs: list, device: str | None = None, threads: int | None = None,
                min_chunk: int = 1, progress=None) -> None:
    """Launch ``kernel`` over ``dim`` split along its first dimension across CPU threads.

    Args:
        kernel: a ``@wp.kernel`` whose last input is the ``offset`` of the chunk along dim[0].
        dim: launch dimension (int or tuple); dim[0] is split.
        inputs: kernel inputs WITHOUT the trailing offset.
        device, threads: Warp device (CUDA gets one whole launch) and worker count (default :func:`thread_count`).
        min_chunk: smallest chunk along dim[0] worth a separate launch.
        progress: optional ``progress(fraction)`` called as chunks complete (then at least 32 chunks).
    """
    device = default_device(device)
    dims = (dim,) if isinstance(dim, int) else tuple(dim)
    n0 = dims[0]
    if n0 == 0 or any(d == 0 for d in dims):
        return
    nthreads = threads or thread_count()
    if not wp.get_device(device).is_cpu or (progress is None and (nthreads <= 1 or n0 < 2 * min_chunk)):
        wp.launch(kernel, dim=dims, inputs=[*inputs, 0], device=device)
        if progress is not None:
            progress(1.0)
        return
    wp.load_module(kernel.module, device=device)
    # A few more chunks than threads evens out unequal row costs.
    pieces = chunks(n0, max(nthreads * 4, 32 if progress is not None else 1), min_chunk)

    def _one(piece):
        start, stop = piece
        wp.launch(kernel, dim=(stop - start, *dims[1:]), inputs=[*inputs, start], device=device)

    run_parallel(_one, pieces, nthreads, progress)
