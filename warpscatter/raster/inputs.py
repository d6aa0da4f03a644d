"""Checks and conversions of the host inputs shared by the rasterizer and the ray caster: 4x4 matrices, image sizes,
vertex and triangle arrays (numpy or ``wp.array``), each raising ValueError naming the argument."""

from __future__ import annotations

import numpy as np
import warp as wp

from .funcs import MAX_RESOLUTION


def check_matrix(m, name: str = "view_proj") -> np.ndarray:
    """Return ``m`` as a float64 (4, 4) array; ValueError naming ``name`` when malformed or non-finite."""
    try:
        a = np.asarray(m, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a 4x4 numeric matrix") from exc
    if a.shape != (4, 4):
        raise ValueError(f"{name} must have shape (4, 4), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains non-finite entries")
    return a


def check_size(width, height) -> tuple[int, int]:
    """Validate an image size in pixels (1 .. MAX_RESOLUTION); ValueError naming the argument."""
    out = []
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise ValueError(f"{name} must be an integer, got {v!r}")
        if not 1 <= int(v) <= MAX_RESOLUTION:
            raise ValueError(f"{name} must lie in [1, {MAX_RESOLUTION}], got {v}")
        out.append(int(v))
    return out[0], out[1]


def as_points(vertices, device: str) -> wp.array:
    """(N, 3) numpy vertices (finite, else ValueError) or a ``wp.array(dtype=wp.vec3)`` (taken as is: the rasterizer
    skips triangles with non-finite clip coordinates) -> contiguous vec3 array on ``device``."""
    if isinstance(vertices, wp.array):
        if vertices.dtype != wp.vec3 or vertices.ndim != 1:
            raise ValueError("vertices as a wp.array must be 1-D with dtype wp.vec3")
        if str(vertices.device) != str(wp.get_device(device)) or not vertices.is_contiguous:
            vertices = wp.clone(vertices, device=device)
        return vertices
    try:
        v = np.asarray(vertices, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError("vertices must be a numeric (N, 3) array") from exc
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must have shape (N, 3), got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError("vertices contain non-finite coordinates")
    return wp.array(np.ascontiguousarray(v, dtype=np.float32), dtype=wp.vec3, device=device)


def as_triangles(triangles, num_points: int, device: str) -> wp.array:
    """(T, 3) integer indices (numpy or wp.array) -> int32 ``wp.array2d`` on ``device``, range-checked."""
    if isinstance(triangles, wp.array):
        t = triangles.numpy()
    else:
        t = np.asarray(triangles)
    if t.size == 0:
        t = t.reshape(0, 3)
    if t.ndim == 1 and t.size % 3 == 0:
        t = t.reshape(-1, 3)
    if t.ndim != 2 or t.shape[1] != 3:
        raise ValueError(f"triangles must have shape (T, 3), got {t.shape}")
    if not np.issubdtype(t.dtype, np.integer):
        raise ValueError(f"triangles must hold integer vertex indices, got dtype {t.dtype}")
    if t.size and (t.min() < 0 or t.max() >= num_points):
        raise ValueError(f"triangles index vertices out of range [0, {num_points}) (min {t.min()}, max {t.max()})")
    if t.shape[0] >= 2**31:
        raise ValueError("triangles: at most 2^31 - 1 triangles are supported")
    return wp.array(np.ascontiguousarray(t, dtype=np.int32), dtype=wp.int32, device=device)


def is_affine(view_proj: np.ndarray) -> bool:
    """True when clip w is a positive constant (orthographic-style matrix: last row (0, 0, 0, c > 0))."""
    m = np.asarray(view_proj, dtype=np.float64)
    return bool(np.all(m[3, :3] == 0.0) and m[3, 3] > 0.0)
