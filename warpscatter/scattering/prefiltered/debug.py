"""The prefiltered methods' debug outputs (``frame.aovs``, returned in ``info["debug_images"]``)."""

from __future__ import annotations

import numpy as np

from ..sparse_evaluation import SparseEvaluation
from .epipole_regions import epipole_weights
from .rectify import map_depth
from .row_mips import RowMips, pixel_mip_levels


def add_debug_images(info: dict, frame, coords, regions, rectified, map_before_culling,
                     mips: RowMips | None = None, sparse: SparseEvaluation | None = None) -> None:
    """The debug outputs a frame asked for, into ``info["debug_images"]``: ``rectified`` the (H, W, 3) look-up
    coordinates, ``epipole_mask`` the ray-marched epipole regions' weight, ``rectified_map`` the (rows, cols, 2) map
    the prefilter read and 1 where caster culling emptied a texel (``map_before_culling``: its depths before),
    ``mip_level`` the row mip level of each pixel's look-up (``mips``; None: level 0 everywhere),
    ``evaluated_pixels`` 1 where the look-up ran and 0 where the pixel was interpolated (``sparse``). ``coords``:
    every pixel's look-up coordinates (a wp.array; the ``rectified`` and ``mip_level`` outputs make them)."""
    debug = {}
    if "evaluated_pixels" in frame.aovs and sparse is not None:
        debug["evaluated_pixels"] = sparse.mask()
    if "mip_level" in frame.aovs:
        debug["mip_level"] = (pixel_mip_levels(mips, coords) if mips is not None else
                              np.zeros(coords.shape, np.float32))
    if "rectified" in frame.aovs:
        debug["rectified"] = coords.numpy()
    if "epipole_mask" in frame.aovs:
        debug["epipole_mask"] = epipole_weights(frame.scene.camera, regions)
    if map_before_culling is not None:
        depth = map_depth(rectified)
        debug["rectified_map"] = np.stack([depth, (depth != map_before_culling).astype(np.float32)], axis=-1)
    if debug:
        info["debug_images"] = debug


__all__ = ["add_debug_images"]
