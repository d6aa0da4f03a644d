"""Texel operations of 4-moment shadow maps (Peters et al. 2017, Sec. 2.4 and Appendix D.2): storage rounding,
texture look-ups, the separable Gaussian filter and the mip chain, on (C, H, W) ``wp.vec4`` texels in the map's stored
domain. Re-exported by :mod:`.msm`. Texel (i, j) has j from the top.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..runtime.device import default_device, module_options
from ..runtime.parallel import launch_rows
from . import filterable

module_options()

_MIN_ROWS = 8  # fewest rows per chunk of a split CPU launch




@wp.func
def round_texel(t: wp.vec4, storage: int) -> wp.vec4:
    """Write a texel-space value to the storage format (Sec. 2.4; :func:`.filterable.round_texel`)."""
    return filterable.round_texel(t, storage)


@wp.func
def fetch_texel(texels: wp.array3d(dtype=wp.vec4), c: int, i: int, j: int) -> wp.vec4:
    """Texel (i, j) of channel c with clamp-to-edge addressing."""
    ii = wp.clamp(i, 0, texels.shape[2] - 1)
    jj = wp.clamp(j, 0, texels.shape[1] - 1)
    return texels[c, jj, ii]


@wp.func
def bilinear_footprint(u: float, v: float, width: int, height: int):
    """Texels (i0, i1, j0, j1) and weights (a_x, a_y) of i1, j1 of a clamp-to-edge bilinear sample at (u, v)."""
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
    """Bilinear interpolation of four texels with the weights of :func:`bilinear_footprint`."""
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
    """Trilinear sample: bilinear in levels floor(lod) and floor(lod) + 1, blended by the fraction of ``lod``."""
    t = wp.clamp(lod, 0.0, float(levels - 1))
    l0 = int(wp.floor(t))
    a = t - float(l0)
    s0 = sample_mip_bilinear4(mips, c, width, height, l0, u, v)
    if a <= 0.0 or l0 + 1 >= levels:
        return s0
    return (1.0 - a) * s0 + a * sample_mip_bilinear4(mips, c, width, height, l0 + 1, u, v)




@wp.kernel
def _gauss_kernel(src: wp.array3d(dtype=wp.vec4), weights: wp.array(dtype=wp.float32), radius: int,
                  step: wp.vec2i, storage: int, dst: wp.array3d(dtype=wp.vec4), offset: int):
    # one pass along ``step``: (1, 0) rows, (0, 1) columns
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




def _check_int(x, name: str, lo: int, hi: int | None = None) -> int:
    if isinstance(x, bool) or not isinstance(x, (int, np.integer)) or x < lo or (hi is not None and x > hi):
        bound = f">= {lo}" if hi is None else f"in [{lo}, {hi}]"
        raise ValueError(f"{name}: expected an integer {bound}, got {x!r}")
    return int(x)


def gaussian_weights(filter_px: int) -> np.ndarray:
    """Normalised Gaussian taps: 2 (filter_px // 2) + 1, sigma = filter_px / 4 texels (5: the paper's, D.2)."""
    filter_px = _check_int(filter_px, "filter_px", 1)
    r = filter_px // 2
    k = np.arange(-r, r + 1, dtype=np.float64)
    w = np.exp(-0.5 * (k / (filter_px / 4.0)) ** 2)
    return (w / w.sum()).astype(np.float32)


def gaussian_filter_texels(texels: wp.array, weights: np.ndarray, storage: int, device=None) -> wp.array:
    """Two-pass separable blur of (C, H, W) texels (D.2), each pass clamping and rounding."""
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
    """Full mip chain of (C, H, W) texels by 2x2 box averages, rounded per level (D.2): (mips (C, N) packed
    (:func:`mip_level_offset`), levels)."""
    device = default_device(device)
    h, w = int(texels.shape[1]), int(texels.shape[2])
    levels = mip_level_count(w, h)
    total = sum(max(w >> k, 1) * max(h >> k, 1) for k in range(levels))
    mips = wp.empty((int(texels.shape[0]), total), dtype=wp.vec4, device=device)
    launch_rows(_mip_copy_kernel, (h, w), [texels, mips], device=device, min_chunk=_MIN_ROWS)
    for level in range(1, levels):
        launch_rows(_mip_downsample_kernel, (max(h >> level, 1), max(w >> level, 1)), [mips, w, h, level, storage],
                    device=device, min_chunk=_MIN_ROWS)
    return mips, levels
