"""What both pipelines share: compiling the Warp modules a render launches, and the check of its images."""

from __future__ import annotations

import importlib

import numpy as np
import warp as wp

from ..errors import NonFiniteImageError
from ..runtime.device import default_device


def compile_kernels(modules, device=None) -> None:
    """Compile (or load from Warp's kernel cache) Warp ``modules`` (names such as ``"warpscatter.raster.rasterizer"``
    or module objects, e.g. a method's :attr:`~warpscatter.methods.Method.modules`) before any launch, which threads
    would otherwise compile at once."""
    device = default_device(device)
    for m in dict.fromkeys(modules):
        wp.load_module(importlib.import_module(m) if isinstance(m, str) else m, device=device)


def check_finite(images: dict) -> None:
    """Raise :class:`~warpscatter.errors.NonFiniteImageError` naming the first image with NaN or infinite pixels
    (every numerically hard case has a documented fallback, so this is a bug)."""
    for name, img in images.items():
        if not np.all(np.isfinite(img)):
            raise NonFiniteImageError(f"{name} image has non-finite pixels (a bug: please report it)")


__all__ = ["check_finite", "compile_kernels"]
