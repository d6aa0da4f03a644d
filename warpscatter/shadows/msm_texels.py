"""Texel operations of 4-moment shadow maps (Peters et al. 2017, Sec. 2.4 and Appendix D.2): the storage format,
texture look-ups, the separable Gaussian filter and the mip chain.

Used by :mod:`.msm` (which re-exports every public name here) on the texels of a
:class:`~warpscatter.shadows.msm.MomentShadowMap`: (C, H, W) ``wp.vec4`` arrays, one moment vector per texel and
channel, in the stored domain of the map's 4-moment storage mode (:mod:`.moments`: Theta_4*(b) in emulated 16-bit
unorm channels, or canonical float32 moments).

* Storage (Sec. 2.4): :func:`round_texel` writes a texel-space value to the storage format (16-bit rounding or
  nothing), as a GPU does on every write to a 16-bit unorm render target.
* Look-ups: :func:`fetch_texel` (clamp-to-edge), :func:`sample_bilinear4` (hardware bilinear filtering),
  :func:`sample_mip_bilinear4` and :func:`sample_trilinear4` in a packed mip chain (:func:`mip_level_offset`).
* ``filter`` (:func:`gaussian_filter_texels`, D.2): two-pass separable Gaussian, :func:`gaussian_weights` taps,
  each pass clamping at the map border and rounding to the storage format again.
* ``msm_mipmap`` (:func:`build_mip_levels`, D.2 "generate a full mipmap hierarchy"): 2x2 box averages level by
  level. Averages of moment vectors are moment vectors of the merged distributions, and Theta_4* is affine, so the
  64-bit map is averaged in its stored domain (as a GPU mips a 16-bit unorm texture) and rounded to 16 bits again
  per level; odd sizes drop the last row/column (floor), as GPU mip chains do.

Texel (i, j) has j from the TOP, as every image here.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..parallel import launch_rows
from ..wpinit import default_device, module_options
from . import filterable

module_options()

_MIN_ROWS = 8  # fewest rows per chunk of a split CPU launch


# ---------------------------------------------------------------------------------------------------------------------
# Storage format and look-ups
# ---------------------------------------------------------------------------------------------------------------------


@wp.func
def round_texel(t: wp.vec4, storage: int) -> wp.vec4:
    """Write a texel-space value to the storage format (:func:`.filterable.round_texel`: 16-bit unorm rounding for
    64-bit moment maps, float16 for 32-bit VSM and 64-bit EVSM, unchanged for float32 channels)."""
    # Peters 2017, Sec. 2.4
    return filterable.round_texel(t, storage)


@wp.func
def fetch_texel(texels: wp.array3d(dtype=wp.vec4), c: int, i: int, j: int) -> wp.vec4:
    """Texel (i, j) of channel c with clamp-to-edge addressing."""
    ii = wp.clamp(i, 0, texels.shape[2] - 1)
    jj = wp.clamp(j, 0, texels.shape[1] - 1)
    return texels[c, jj, ii]


@wp.func
def bilinear_footprint(u: float, v: float, width: int, height: int):
    """The 2x2 texels of a bilinear sample at texture coordinates (u, v) in [0, 1] (v down) of a width x height
    texture with clamp-to-edge addressing: columns and rows (i0, i1, j0, j1) as ``wp.vec4i`` and the weights
    (a_x, a_y) of texels i1 and j1 as ``wp.vec2``."""
    fx = u * float(width) - 0.5
    fy = v * float(height) - 0.5
    x0 = wp.floor(fx)
    y0 = wp.floor(fy)
    i0 = int(x0)
    j0 = int(y0)
    texels = wp.vec4i(wp.clamp(i0, 0, width - 1), wp.clamp(i0 + 1, 0, width - 1), wp.clamp(j0, 0, height - 1),
                      wp.clamp(j0 + 1, 0, height - 1))
    return texels, wp.vec2(fx - x0, fy - y0)


@wp.func
def bilinear_blend(t00: wp.vec4, t10: wp.vec4, t01: wp.vec4, t11: wp.vec4, a: wp.vec2) -> wp.vec4:
    """Bilinear interpolation of texels (i0, j0), (i1, j0), (i0, j1), (i1, j1) with the weights a of
    :func:`bilinear_footprint`."""
    top = (1.0 - a[0]) * t00 + a[0] * t10
    bottom = (1.0 - a[0]) * t01 + a[0] * t11
    return (1.0 - a[1]) * top + a[1] * bottom


@wp.func
def sample_bilinear4(texels: wp.array3d(dtype=wp.vec4), c: int, u: float, v: float) -> wp.vec4:
    """Bilinear sample of channel c at texture coordinates (u, v) in [0, 1] (v down), clamp-to-edge."""
    f, a = bilinear_footprint(u, v, texels.shape[2], texels.shape[1])
    return bilinear_blend(texels[c, f[2], f[0]], texels[c, f[2], f[1]], texels[c, f[3], f[0]], texels[c, f[3], f[1]],
                          a)


@wp.func
def mip_level_offset(width: int, height: int, level: int) -> int:
    """First texel of mip ``level`` in a packed chain (levels 0, 1, ... of sizes max(1, w >> l) x max(1, h >> l))."""
    off = int(0)
    for k in range(level):
        off += wp.max(width >> k, 1) * wp.max(height >> k, 1)
    return off


@wp.func
def sample_mip_bilinear4(mips: wp.array2d(dtype=wp.vec4), c: int, width: int, height: int, level: int, u: float,
                         v: float) -> wp.vec4:
    """Bilinear sample of channel c of mip ``level`` at texture coordinates (u, v) (v down), clamp-to-edge."""
    w = wp.max(width >> level, 1)
    h = wp.max(height >> level, 1)
    off = mip_level_offset(width, height, level)
    f, a = bilinear_footprint(u, v, w, h)
    row0 = off + f[2] * w
    row1 = off + f[3] * w
    return bilinear_blend(mips[c, row0 + f[0]], mips[c, row0 + f[1]], mips[c, row1 + f[0]], mips[c, row1 + f[1]], a)


@wp.func
def sample_trilinear4(mips: wp.array2d(dtype=wp.vec4), c: int, width: int, height: int, levels: int, u: float,
                      v: float, lod: float) -> wp.vec4:
    """Trilinear sample: bilinear in mip levels floor(lod) and floor(lod) + 1, blended by the fraction of ``lod``
    (clamped to [0, levels - 1])."""
    t = wp.clamp(lod, 0.0, float(levels - 1))
    l0 = int(wp.floor(t))
    a = t - float(l0)
    s0 = sample_mip_bilinear4(mips, c, width, height, l0, u, v)
    if a <= 0.0 or l0 + 1 >= levels:
        return s0
    return (1.0 - a) * s0 + a * sample_mip_bilinear4(mips, c, width, height, l0 + 1, u, v)


# ---------------------------------------------------------------------------------------------------------------------
# Kernels (the last input of each is the row offset used by parallel.launch_rows)
# ---------------------------------------------------------------------------------------------------------------------


@wp.kernel
def _gauss_kernel(src: wp.array3d(dtype=wp.vec4), weights: wp.array(dtype=wp.float32), radius: int,
                  step: wp.vec2i, storage: int, dst: wp.array3d(dtype=wp.vec4), offset: int):
    # one pass of the separable Gaussian along ``step``: (1, 0) along rows, (0, 1) along columns
    j, i = wp.tid()
    j += offset
    for c in range(src.shape[0]):
        acc = wp.vec4(0.0, 0.0, 0.0, 0.0)
        for k in range(-radius, radius + 1):
            acc += weights[k + radius] * fetch_texel(src, c, i + k * step[0], j + k * step[1])
        dst[c, j, i] = round_texel(acc, storage)


@wp.kernel
def _mip_copy_kernel(texels: wp.array3d(dtype=wp.vec4), mips: wp.array2d(dtype=wp.vec4), offset: int):
    j, i = wp.tid()
    j += offset
    w = texels.shape[2]
    for c in range(texels.shape[0]):
        mips[c, j * w + i] = texels[c, j, i]


@wp.kernel
def _mip_downsample_kernel(mips: wp.array2d(dtype=wp.vec4), width: int, height: int, level: int, storage: int,
                           offset: int):
    # D.2 mipmap generation: level l texel (i, j) = mean of texels (2i..2i+1, 2j..2j+1) of level l - 1
    j, i = wp.tid()
    j += offset
    sw = wp.max(width >> (level - 1), 1)
    sh = wp.max(height >> (level - 1), 1)
    src = mip_level_offset(width, height, level - 1)
    dst = mip_level_offset(width, height, level)
    dw = wp.max(width >> level, 1)
    i0 = wp.min(2 * i, sw - 1)
    i1 = wp.min(2 * i + 1, sw - 1)
    j0 = wp.min(2 * j, sh - 1)
    j1 = wp.min(2 * j + 1, sh - 1)
    for c in range(mips.shape[0]):
        acc = mips[c, src + j0 * sw + i0] + mips[c, src + j0 * sw + i1] + mips[c, src + j1 * sw + i0]
        acc += mips[c, src + j1 * sw + i1]
        mips[c, dst + j * dw + i] = round_texel(0.25 * acc, storage)


# ---------------------------------------------------------------------------------------------------------------------
# Host functions
# ---------------------------------------------------------------------------------------------------------------------


def _check_int(x, name: str, lo: int, hi: int | None = None) -> int:
    if isinstance(x, bool) or not isinstance(x, (int, np.integer)) or x < lo or (hi is not None and x > hi):
        bound = f">= {lo}" if hi is None else f"in [{lo}, {hi}]"
        raise ValueError(f"{name}: expected an integer {bound}, got {x!r}")
    return int(x)


def gaussian_weights(filter_px: int) -> np.ndarray:
    """Normalised taps of the separable Gaussian: 2 (filter_px // 2) + 1 taps, sigma = filter_px / 4 texels.

    The kernel spans +-2 sigma; filter_px = 1 is the identity, 5 the paper's 5-tap filter (D.2).
    """
    filter_px = _check_int(filter_px, "filter_px", 1)
    r = filter_px // 2
    k = np.arange(-r, r + 1, dtype=np.float64)
    w = np.exp(-0.5 * (k / (filter_px / 4.0)) ** 2)
    return (w / w.sum()).astype(np.float32)


def gaussian_filter_texels(texels: wp.array, weights: np.ndarray, storage: int, device=None) -> wp.array:
    """Two-pass separable blur of (C, H, W) texels with the taps ``weights`` (:func:`gaussian_weights`), rows first;
    each pass clamps at the border and rounds to the format of ``storage``. Returns new texels."""
    # Peters 2017, D.2
    device = default_device(device)
    radius = len(weights) // 2
    wts = wp.array(weights, dtype=wp.float32, device=device)
    tmp = wp.empty_like(texels)
    out = wp.empty_like(texels)
    h, w = int(texels.shape[1]), int(texels.shape[2])
    for src, step, dst in ((texels, wp.vec2i(1, 0), tmp), (tmp, wp.vec2i(0, 1), out)):
        launch_rows(_gauss_kernel, (h, w), [src, wts, radius, step, storage, dst], device=device, min_chunk=_MIN_ROWS)
    return out


def mip_level_count(width: int, height: int) -> int:
    """Levels of a full mip chain of a width x height map (down to 1 x 1)."""
    return int(max(int(width), int(height))).bit_length()


def build_mip_levels(texels: wp.array, storage: int, device=None) -> tuple[wp.array, int]:
    """Full mip chain of (C, H, W) texels by 2x2 box averages, rounded to the format of ``storage`` per level (D.2).

    Returns:
        (mips, levels): the (C, N) ``wp.vec4`` chain, levels 0 (a copy of ``texels``), 1, ... packed one after
        another (:func:`mip_level_offset`), and the number of levels (:func:`mip_level_count`).
    """
    device = default_device(device)
    h, w = int(texels.shape[1]), int(texels.shape[2])
    levels = mip_level_count(w, h)
    total = sum(max(w >> k, 1) * max(h >> k, 1) for k in range(levels))
    mips = wp.empty((int(texels.shape[0]), total), dtype=wp.vec4, device=device)
    launch_rows(_mip_copy_kernel, (h, w), [texels, mips], device=device, min_chunk=_MIN_ROWS)
    for level in range(1, levels):
        # one launch per level; rows of a level are independent (launch_rows chunks own their output rows)
        launch_rows(_mip_downsample_kernel, (max(h >> level, 1), max(w >> level, 1)), [mips, w, h, level, storage],
                    device=device, min_chunk=_MIN_ROWS)
    return mips, levels
