"""Split CPU launches give the same result as one launch, for any thread count."""

import numpy as np
import pytest
import warp as wp

from warpscatter.runtime import parallel


@wp.kernel
def _rows_kernel(out: wp.array2d(dtype=wp.float32), offset: int):
    j, i = wp.tid()
    j += offset
    out[j, i] = float(j * 1000 + i)


@wp.kernel
def _flat_kernel(out: wp.array(dtype=wp.int32), offset: int):
    i = wp.tid() + offset
    out[i] = i * 3


@pytest.mark.parametrize("threads", [1, 2, 3, 7])
def test_launch_rows_covers_every_row_once(threads):
    out = wp.full((37, 5), -1.0, dtype=wp.float32, device="cpu")
    parallel.launch_rows(_rows_kernel, out.shape, [out], threads=threads)
    j, i = np.mgrid[0:37, 0:5]
    np.testing.assert_array_equal(out.numpy(), j * 1000 + i)


def test_launch_rows_1d_and_empty():
    out = wp.zeros(101, dtype=wp.int32, device="cpu")
    parallel.launch_rows(_flat_kernel, 101, [out], threads=4)
    np.testing.assert_array_equal(out.numpy(), np.arange(101) * 3)
    parallel.launch_rows(_flat_kernel, 0, [out], threads=4)  # no work, no error


def test_chunks_partition():
    for n in (0, 1, 5, 100):
        for parts in (1, 3, 8):
            c = parallel.chunks(n, parts)
            covered = [k for a, b in c for k in range(a, b)]
            assert covered == list(range(n))


def test_thread_count_env(monkeypatch):
    monkeypatch.setenv("WARPSCATTER_THREADS", "3")
    assert parallel.thread_count() == 3
    monkeypatch.delenv("WARPSCATTER_THREADS")
    assert parallel.thread_count() >= 1


def test_launch_rows_reports_progress():
    seen = []
    out = wp.zeros((200, 3), dtype=wp.float32, device="cpu")
    parallel.launch_rows(_rows_kernel, out.shape, [out], threads=2, progress=seen.append)
    assert len(seen) >= 32 and seen == sorted(seen) and seen[-1] == 1.0  # one call per chunk, in order
    j, i = np.mgrid[0:200, 0:3]
    np.testing.assert_array_equal(out.numpy(), j * 1000 + i)
    seen.clear()
    parallel.launch_rows(_rows_kernel, out.shape, [out], threads=1, progress=seen.append)
    assert seen[-1] == 1.0
