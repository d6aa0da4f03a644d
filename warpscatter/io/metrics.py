"""Image error metrics against a reference (numpy only): what the bench, sweeps and tests report."""

from __future__ import annotations

import numpy as np


def errors(image: np.ndarray, reference: np.ndarray) -> dict:
    """Relative L1 (sum |a - b| / sum |b|; NaN for an all-zero reference) and RMSE of ``image`` against
    ``reference`` (same shape), over all pixels and channels, in float64."""
    a = np.asarray(image, np.float64)
    b = np.asarray(reference, np.float64)
    denom = np.abs(b).sum()
    return {"rel_l1": float(np.abs(a - b).sum() / denom) if denom > 0 else float("nan"),
            "rmse": float(np.sqrt(np.mean((a - b) ** 2)))}


__all__ = ["errors"]
