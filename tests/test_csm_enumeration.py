"""Enumerations of the CSM map grid: bijections, coherence (neighbour steps), the classic Hilbert curve."""

import numpy as np
import pytest

from warpscatter.csm.enumeration import (
    ENUMERATIONS,
    enumerate_grid,
    hilbert_order,
    scanline_order,
    sequence_index,
    zigzag_order,
)

SIZES = [(1, 1), (1, 7), (7, 1), (2, 2), (4, 4), (8, 8), (16, 16), (6, 4), (5, 4), (4, 5), (13, 7), (32, 16), (3, 9)]


def classic_hilbert_d2xy(n: int, d: int) -> tuple[int, int]:
    """The textbook Hilbert curve of an n x n grid (n a power of two): index d -> (x, y)."""
    x = y = 0
    s = 1
    t = d
    while s < n:
        rx = 1 & (t // 2)
        ry = 1 & (t ^ rx)
        if ry == 0:
            if rx == 1:
                x, y = s - 1 - x, s - 1 - y
            x, y = y, x
        x += s * rx
        y += s * ry
        t //= 4
        s *= 2
    return x, y


@pytest.mark.parametrize("method", ENUMERATIONS)
@pytest.mark.parametrize("n1,n2", SIZES)
def test_enumeration_is_a_bijection(method, n1, n2):
    order = enumerate_grid(n1, n2, method)
    assert order.shape == (n1 * n2, 2)
    index = sequence_index(order, n1, n2)  # raises unless every cell is visited exactly once
    assert np.array_equal(index[order[:, 1], order[:, 0]], np.arange(n1 * n2))


def test_scanline_runs_along_the_first_axis():
    order = scanline_order(5, 3)
    assert order[:6].tolist() == [[0, 0], [1, 0], [2, 0], [3, 0], [4, 0], [0, 1]]
    assert np.array_equal(sequence_index(order, 5, 3), np.arange(15).reshape(3, 5))


@pytest.mark.parametrize("n1,n2", SIZES)
def test_zigzag_steps_between_neighbours(n1, n2):
    steps = np.abs(np.diff(zigzag_order(n1, n2), axis=0)).sum(axis=1)
    assert np.all(steps == 1)


@pytest.mark.parametrize("n1,n2", SIZES)
def test_hilbert_steps_between_neighbours(n1, n2):
    order = hilbert_order(n1, n2)
    assert order[0].tolist() == [0, 0]
    d = np.abs(np.diff(order, axis=0))
    # 4-neighbour steps, except at most one diagonal step when one side is odd and the other even
    diagonal = np.all(d == 1, axis=1)
    assert np.all((d.sum(axis=1) == 1) | diagonal)
    if (n1 % 2) == (n2 % 2):
        assert not diagonal.any()
    else:
        assert diagonal.sum() <= 1


@pytest.mark.parametrize("n", [2, 4, 8, 32])
def test_hilbert_equals_the_classic_curve_on_power_of_two_squares(n):
    order = hilbert_order(n, n)
    classic = np.array([classic_hilbert_d2xy(n, d) for d in range(n * n)])
    # Same curve up to the diagonal mirror (which axis the first step takes).
    assert np.array_equal(order, classic) or np.array_equal(order, classic[:, ::-1])


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="method"):
        enumerate_grid(4, 4, "spiral")
    with pytest.raises(ValueError, match="n1"):
        enumerate_grid(0, 4)
    with pytest.raises(ValueError, match="n2"):
        enumerate_grid(4, 2.5)
    with pytest.raises(ValueError, match="bijection"):
        sequence_index(np.zeros((4, 2), dtype=np.int64), 2, 2)
