"""Enumerations of a discretised depth-map domain: scan-line, zig-zag and Hilbert orders (Ritschel 2007, Sec. 4.4).

The compression gains from successive maps being similar, so the N1 x N2 grid of map locations is put in a coherent
order: a bijection from cells (a, b), a fastest, to sequence indices 0 .. N-1. ``scanline``: i = a + N1 b;
``zigzag``: odd rows walked backwards, so successive cells are neighbours; ``hilbert``: the generalised Hilbert
("gilbert") curve of J. Cervený (BSD-2-Clause), any rectangle, at most one diagonal step.
"""

from __future__ import annotations

import numpy as np

from .settings import ENUMERATIONS

#: Largest number of cells of one grid (int32 sequence indices everywhere else).
MAX_CELLS = 2**31 - 1


def _check_dims(n1, n2) -> tuple[int, int]:
    out = []
    for name, v in (("n1", n1), ("n2", n2)):
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
            raise ValueError(f"{name} must be an integer, got {v!r}")
        if int(v) < 1:
            raise ValueError(f"{name} must be >= 1, got {v}")
        out.append(int(v))
    if out[0] * out[1] > MAX_CELLS:
        raise ValueError(f"n1 * n2 must be <= {MAX_CELLS}, got {out[0] * out[1]}")
    return out[0], out[1]


def scanline_order(n1: int, n2: int) -> np.ndarray:
    """Cells (a, b) of an n1 x n2 grid in scan-line order (a fastest), (n1 * n2, 2) int64 in visiting order."""
    n1, n2 = _check_dims(n1, n2)
    b, a = np.divmod(np.arange(n1 * n2, dtype=np.int64), n1)
    return np.stack([a, b], axis=1)


def zigzag_order(n1: int, n2: int) -> np.ndarray:
    """Cells (a, b) in boustrophedon order (odd rows b walk a downwards), (n1 * n2, 2) int64 in visiting order."""
    n1, n2 = _check_dims(n1, n2)
    b, a = np.divmod(np.arange(n1 * n2, dtype=np.int64), n1)
    a = np.where(b % 2 == 1, n1 - 1 - a, a)
    return np.stack([a, b], axis=1)


def _gilbert(x: int, y: int, ax: int, ay: int, bx: int, by: int, out: list) -> None:
    """Generalised Hilbert curve over the rectangle spanned by (ax, ay) and (bx, by) from (x, y), iteratively."""
    stack = [(x, y, ax, ay, bx, by)]
    while stack:
        x, y, ax, ay, bx, by = stack.pop()
        w = abs(ax + ay)
        h = abs(bx + by)
        dax, day = int(np.sign(ax)), int(np.sign(ay))  # unit major direction
        dbx, dby = int(np.sign(bx)), int(np.sign(by))  # unit orthogonal direction
        if h == 1:
            out.extend((x + k * dax, y + k * day) for k in range(w))
            continue
        if w == 1:
            out.extend((x + k * dbx, y + k * dby) for k in range(h))
            continue
        ax2, ay2 = ax // 2, ay // 2
        bx2, by2 = bx // 2, by // 2
        w2 = abs(ax2 + ay2)
        h2 = abs(bx2 + by2)
        if 2 * w > 3 * h:
            if (w2 % 2) and (w > 2):  # prefer even steps
                ax2, ay2 = ax2 + dax, ay2 + day
            # long case: split in two parts only (pushed in reverse: the stack is LIFO)
            stack.append((x + ax2, y + ay2, ax - ax2, ay - ay2, bx, by))
            stack.append((x, y, ax2, ay2, bx, by))
        else:
            if (h2 % 2) and (h > 2):  # prefer even steps
                bx2, by2 = bx2 + dbx, by2 + dby
            # standard case: one step up, one long horizontal, one step down
            stack.append((x + (ax - dax) + (bx2 - dbx), y + (ay - day) + (by2 - dby),
                          -bx2, -by2, -(ax - ax2), -(ay - ay2)))
            stack.append((x + bx2, y + by2, ax, ay, bx - bx2, by - by2))
            stack.append((x, y, bx2, by2, ax2, ay2))


def hilbert_order(n1: int, n2: int) -> np.ndarray:
    """Cells (a, b) along the generalised Hilbert curve from (0, 0), (n1 * n2, 2) int64 in visiting order."""
    n1, n2 = _check_dims(n1, n2)
    out: list = []
    if n1 >= n2:
        _gilbert(0, 0, n1, 0, 0, n2, out)
    else:
        _gilbert(0, 0, 0, n2, n1, 0, out)
    return np.asarray(out, dtype=np.int64).reshape(-1, 2)


def enumerate_grid(n1: int, n2: int, method: str = "hilbert") -> np.ndarray:
    """Cells (a, b) of the n1 x n2 grid (n1 along the fastest axis, both >= 1) in the sequence order of ``method``
    (one of :data:`ENUMERATIONS`): (n1 * n2, 2) int64 ``order``, ``order[i]`` the cell of sequence index i.

    Raises:
        ValueError: unknown ``method`` or invalid sizes.
    """
    if method == "scanline":
        return scanline_order(n1, n2)
    if method == "zigzag":
        return zigzag_order(n1, n2)
    if method == "hilbert":
        return hilbert_order(n1, n2)
    raise ValueError(f"method must be one of {ENUMERATIONS}, got {method!r}")


def sequence_index(order: np.ndarray, n1: int, n2: int) -> np.ndarray:
    """Inverse of an enumeration: the (n2, n1) int32 table ``index[b, a]`` = sequence index of cell (a, b);
    ValueError unless ``order`` is a bijection onto the n1 x n2 grid."""
    n1, n2 = _check_dims(n1, n2)
    order = np.asarray(order)
    if order.shape != (n1 * n2, 2):
        raise ValueError(f"order must have shape ({n1 * n2}, 2), got {order.shape}")
    a, b = order[:, 0], order[:, 1]
    if a.min() < 0 or a.max() >= n1 or b.min() < 0 or b.max() >= n2:
        raise ValueError("order holds cells outside the grid")
    index = np.full((n2, n1), -1, dtype=np.int64)
    index[b, a] = np.arange(n1 * n2)
    if np.any(index < 0):
        raise ValueError("order visits some cells twice and others never (not a bijection)")
    return index.astype(np.int32)
