"""Row mip-maps of the prefiltered textures (Peters 2017 App. D.5: the prefix-sum texture "should have mipmaps";
Klehm 2014 Sec. 5: filtering "blends neighboring epipolar slices").

Near an epipole (or a spot light) the rows converge and a pixel spans several, so shafts and a light texture's detail
alias. Level L + 1 averages row pairs (2k, 2k + 1) of level L in the texture's own storage (codes re-rounded per
level); only rows are mipped (the columns already hold prefix sums). A pixel reads level log2(row footprint) +
:data:`MIP_LEVEL_BIAS` (:func:`pixel_mip_level`), blending the two levels' reconstructed visibilities. The levels are
stacked along the rows of one texture, level 0 first (:func:`level_window`), as is the per-row data of the look-ups
(reference optical steps, depth bounds, a spot's prefix sums); levels halve the rows while their count is even.
Why this layout and blend: docs/design/prefiltered.md.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import warp as wp

from ...runtime.device import default_device, module_options
from ...runtime.parallel import launch_rows
from ..settings import MAX_MIP_LEVELS
from .textures import (
    FOURIER_UNORM_LEVELS,
    FilteredBasis,
    FilteredBasisArrays,
    FilteredMomentArrays,
    FilteredMoments,
    basis_value,
    moment_texel,
    signed_unorm_code,
    store_moment_texel,
)

module_options()


#: Added to a pixel's level (a GPU sampler's LOD bias): the trilinear blend blurs about half a level more than the
#: pixel's own box (docs/benchmarks.md, "Row mip level bias").
MIP_LEVEL_BIAS = wp.constant(-0.5)


@wp.struct
class RowMips:
    """The row mip chain a look-up reads (:meth:`RowMipChain.params`): level 0's rows, the levels (1: level 0 only)
    and whether the rows wrap around."""

    rows: int
    levels: int
    wrap: int


@wp.func
def level_window(mips: RowMips, level: int) -> wp.vec3i:
    """(first row, rows, wrap) of mip ``level`` in the stacked texture (:func:`~.filtered_lookups.window_footprint`)."""
    first = int(0)
    n = mips.rows
    for _ in range(level):
        first += n
        n = n // 2
    return wp.vec3i(first, n, mips.wrap)


@wp.func
def row_distance(a: float, b: float, wrap: int) -> float:
    """|b - a| in the row coordinate v in [0, 1], the short way round when the rows wrap."""
    d = b - a
    if wrap != 0:
        d = d - wp.round(d)
    return wp.abs(d)


@wp.func
def axis_row_step(coords: wp.array2d(dtype=wp.vec3), j: int, i: int, dj: int, di: int, wrap: int) -> float:
    """The smaller row-coordinate step from pixel (j, i) to its two neighbours along one axis (a depth edge's jump on
    one side is not the footprint); 0 without neighbours."""
    v = coords[j, i][1]
    step = float(1.0e30)
    if j - dj >= 0 and i - di >= 0:
        step = row_distance(coords[j - dj, i - di][1], v, wrap)
    if j + dj < coords.shape[0] and i + di < coords.shape[1]:
        step = wp.min(step, row_distance(v, coords[j + dj, i + di][1], wrap))
    if step >= 1.0e30:
        return 0.0
    return step


@wp.func
def pixel_mip_level(mips: RowMips, coords: wp.array2d(dtype=wp.vec3), j: int, i: int) -> wp.vec2:
    """(level, blend) of pixel (j, i)'s look-up: lambda = log2 of the level-0 rows its footprint spans (the larger
    image axis step, :func:`axis_row_step`) + MIP_LEVEL_BIAS, clamped to the chain; level = floor(lambda), blend =
    the share of level + 1."""
    if mips.levels <= 1:
        return wp.vec2(0.0, 0.0)
    rows_spanned = float(mips.rows) * wp.max(axis_row_step(coords, j, i, 0, 1, mips.wrap),
                                             axis_row_step(coords, j, i, 1, 0, mips.wrap))
    lam = wp.log2(wp.max(rows_spanned, 1.0e-30)) + MIP_LEVEL_BIAS
    if lam <= 0.0:
        return wp.vec2(0.0, 0.0)
    lam = wp.min(lam, float(mips.levels - 1))
    level = wp.floor(lam)
    return wp.vec2(level, lam - level)


@wp.kernel
def mip_level_kernel(mips: RowMips, coords: wp.array2d(dtype=wp.vec3), out: wp.array2d(dtype=wp.float32),
                     offset: int):
    j, i = wp.tid()
    j += offset
    lv = pixel_mip_level(mips, coords, j, i)
    out[j, i] = lv[0] + lv[1]


def pixel_mip_levels(mips: RowMips, coords: wp.array) -> np.ndarray:
    """(H, W) float32 level + share of the next of each pixel's look-up (the ``mip_level`` debug output)."""
    out = wp.empty(coords.shape, dtype=wp.float32, device=coords.device)
    launch_rows(mip_level_kernel, coords.shape, [mips, coords, out], device=coords.device)
    return out.numpy()


# ---- building the chain -------------------------------------------------------------------------------


@wp.func
def store_basis_value(basis: wp.array3d(dtype=wp.float32), j: int, i: int, k: int, x: float):
    """Write value x of basis k at texel (j, i) of a float32 texture."""
    basis[j, i, k] = x


@wp.func
def store_basis_value(basis: wp.array3d(dtype=wp.uint8), j: int, i: int, k: int, x: float):  # noqa: F811
    """Write value x of basis k at texel (j, i) of an RGBA8 texture: its code (:func:`store_basis`)."""
    basis[j, i, k] = wp.uint8(signed_unorm_code(x, FOURIER_UNORM_LEVELS))


@wp.func
def average_basis_rows(basis: Any, code_values: wp.array(dtype=wp.float32), a: int, dst: int):
    """Row dst := the mean of rows a and a + 1, every texel and basis, in the array's storage."""
    for i in range(basis.shape[1]):
        for m in range(basis.shape[2]):
            store_basis_value(basis, dst, i, m, 0.5 * (basis_value(basis, code_values, a, i, m)
                                                        + basis_value(basis, code_values, a + 1, i, m)))


@wp.kernel
def basis_level_kernel(tex: FilteredBasisArrays, src_first: int, dst_first: int, offset: int):
    # row k of the new level := mean of rows 2k, 2k + 1 of the one before; a thread per row (per texel costs more)
    k = wp.tid() + offset
    if tex.code_bits == 0:
        average_basis_rows(tex.basis, tex.tables.code_values, src_first + 2 * k, dst_first + k)
    else:
        average_basis_rows(tex.codes, tex.tables.code_values, src_first + 2 * k, dst_first + k)


@wp.kernel
def moments_level_kernel(tex: FilteredMomentArrays, src_first: int, dst_first: int, cols: int, offset: int):
    # as basis_level_kernel (the stored moments are affine in the canonical ones: their mean is the mean texel's)
    k = wp.tid() + offset
    a = src_first + 2 * k
    for i in range(cols):
        store_moment_texel(tex, dst_first + k, i, 0.5 * (moment_texel(tex, a, i) + moment_texel(tex, a + 1, i)))


@wp.kernel
def bounds_level_kernel(bounds: wp.array2d(dtype=wp.vec2), src_first: int, dst_first: int, offset: int):
    # a merged row's prefix depth bounds: the least and greatest of its pair's
    k = wp.tid() + offset
    for i in range(bounds.shape[1]):
        a = bounds[src_first + 2 * k, i]
        b = bounds[src_first + 2 * k + 1, i]
        bounds[dst_first + k, i] = wp.vec2(wp.min(a[0], b[0]), wp.max(a[1], b[1]))


def level_rows(rows: int, levels: int) -> list[int]:
    """Rows of each level of a chain of ``levels`` (level 0: ``rows``), halving while the count is even."""
    counts = [int(rows)]
    while len(counts) < levels and counts[-1] % 2 == 0 and counts[-1] >= 2:
        counts.append(counts[-1] // 2)
    return counts


def stacked_row_means(a: np.ndarray, levels: int, axis: int = 0) -> np.ndarray:
    """Per-row data of level 0 (rows along ``axis``) with each further level's row-pair means stacked after it, in
    float64 (level 0 alone: ``a`` as it is)."""
    counts = level_rows(np.shape(a)[axis], levels)
    if len(counts) == 1:
        return np.asarray(a)  # no float64 copy on the path without mips
    a = np.moveaxis(np.asarray(a, np.float64), axis, 0)
    out = [a]
    for _ in counts[1:]:
        out.append(0.5 * (out[-1][0::2] + out[-1][1::2]))
    return np.moveaxis(np.concatenate(out), 0, axis)


def _stacked(a: wp.array, rows_total: int) -> wp.array:
    """A copy of ``a`` with ``rows_total`` rows (its own first; the rest uninitialised)."""
    out = wp.empty((rows_total, *a.shape[1:]), dtype=a.dtype, device=a.device)
    wp.copy(out, a, count=a.size)
    return out


@dataclass
class RowMipChain:
    """A prefiltered texture (:class:`~.textures.FilteredBasis` or :class:`~.textures.FilteredMoments`) with its row
    mip levels stacked along the rows, level 0 (``rows``) first, ``levels`` in all; ``optical_step`` (float32) and
    ``bounds`` (vec2, or the (1, 1) disabled placeholder) stacked alike."""

    texture: FilteredBasis | FilteredMoments
    optical_step: np.ndarray
    bounds: wp.array
    rows: int
    levels: int

    def params(self, wrap: bool) -> RowMips:
        """The kernels' :class:`RowMips`."""
        m = RowMips()
        m.rows, m.levels, m.wrap = int(self.rows), int(self.levels), int(bool(wrap))
        return m

    @property
    def level_rows(self) -> list[int]:
        """Rows of each stored level."""
        return level_rows(self.rows, self.levels)


def row_mip_chain(texture, optical_step, bounds: wp.array, levels: int, device=None) -> RowMipChain:
    """The :class:`RowMipChain` of a texture (splits 1, else ValueError), its (rows,) reference optical steps (None:
    zeros) and depth bounds, with up to ``levels`` (1 .. MAX_MIP_LEVELS) levels; fewer once the row count is odd."""
    device = default_device(device)
    if not 1 <= int(levels) <= MAX_MIP_LEVELS:
        raise ValueError(f"mip levels must be in [1, {MAX_MIP_LEVELS}], got {levels}")
    basis = isinstance(texture, FilteredBasis)
    if basis and texture.splits > 1 and int(levels) > 1:
        raise ValueError("row mips need whole rows (splits 1): a split row's regions are filtered apart")
    texels = texture.basis if basis else texture.texels
    rows = int(texels.shape[0])
    tau = np.zeros(rows, np.float32) if optical_step is None else np.asarray(optical_step, np.float32)
    counts = level_rows(rows, int(levels))
    if len(counts) == 1:
        return RowMipChain(texture, tau, bounds, rows, 1)
    total = sum(counts)
    stacked = _stacked(texels, total)
    texture = replace(texture, basis=stacked) if basis else replace(texture, texels=stacked)
    arrays = texture.arrays()
    has_bounds = bounds.shape[0] == rows
    if has_bounds:
        bounds = _stacked(bounds, total)
    first = 0
    for n_src, n_dst in zip(counts[:-1], counts[1:], strict=True):
        dst = first + n_src
        if basis:
            launch_rows(basis_level_kernel, n_dst, [arrays, first, dst], device=device)
        else:
            launch_rows(moments_level_kernel, n_dst, [arrays, first, dst, int(texels.shape[1])], device=device)
        if has_bounds:
            launch_rows(bounds_level_kernel, n_dst, [bounds, first, dst], device=device)
        first = dst
    return RowMipChain(texture, stacked_row_means(tau, len(counts)).astype(np.float32), bounds, rows, len(counts))


__all__ = [
    "MIP_LEVEL_BIAS",
    "RowMipChain",
    "RowMips",
    "axis_row_step",
    "basis_level_kernel",
    "bounds_level_kernel",
    "level_rows",
    "level_window",
    "moments_level_kernel",
    "mip_level_kernel",
    "pixel_mip_level",
    "pixel_mip_levels",
    "row_distance",
    "row_mip_chain",
    "stacked_row_means",
]
