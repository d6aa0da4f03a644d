"""Translucent casters in depth maps (Peters et al. 2017 Sec. 3.2's transmittance model, for maps of depths): per
texel the two-depth distribution Z = (1 - T) delta_{z_n} + T delta_{z_o}, z_n the nearest caster, z_o the nearest
OPAQUE one (+inf: none), T the transmittance prod (1 - alpha_k) in front of z_o. Fragments are found by depth peeling.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..raster.rasterizer import coverage_count, rasterize
from ..scene import CASTER_ALPHA_TEST

#: Alpha test of Peters 2017 Sec. 3.3: fragments with a lower opacity are discarded.
ALPHA_TEST = wp.constant(CASTER_ALPHA_TEST)
#: Opacities at or above this are opaque (rendered into the opaque depth pass).
OPAQUE_ALPHA = 1.0
#: Memory budget of the depth-peeled translucent layers: a view is peeled in row bands this size.
TRANSLUCENT_BAND_BYTES = 256 * 2**20
#: Bytes per peeled sample and layer.
PEEL_BYTES = 24
#: Most translucent layers peeled per texel by default (beyond them the farthest are dropped).
DEFAULT_MAX_LAYERS = 16


def triangle_opacity(scene) -> np.ndarray:
    """(T,) float64 opacity of each triangle of ``scene`` (its material's)."""
    return np.asarray(scene.opacity, np.float64)[np.asarray(scene.tri_material, np.int64)]


def has_translucent(opacity: np.ndarray) -> bool:
    """True when some triangle opacity lies in [ALPHA_TEST, OPAQUE_ALPHA): a translucent caster."""
    a = np.asarray(opacity, np.float64)
    return bool(np.any((a < OPAQUE_ALPHA) & (a >= float(ALPHA_TEST))))


def row_band_matrix(height: int, y0: int, y1: int) -> np.ndarray:
    """Clip-space crop mapping sample rows [y0, y1) of a ``height``-row image onto a full (y1 - y0)-row image."""
    a = height / float(y1 - y0)
    m = np.eye(4)
    m[1, 1], m[1, 3] = a, 1.0 - a * (1.0 - 2.0 * y0 / height)
    return m


def peel_row_bands(vertices, triangles, view_proj, width: int, height: int, *, max_layers: int,
                   row_multiple: int = 1, clamp_depth: bool = False, clip_near: bool | None = None, device=None):
    """Depth-peel a mesh in row bands of at most :data:`TRANSLUCENT_BAND_BYTES`, heights multiples of
    ``row_multiple``, each band as many layers as its deepest pixel has fragments (at most ``max_layers``).

    Yields:
        (y0, y1, k, result): rows [y0, y1), layer count k and their RasterResult, nearest first (None if k = 0).
    """
    counts = coverage_count(vertices, triangles, view_proj, width, height, clamp_depth=clamp_depth,
                            clip_near=clip_near, device=device)
    layers = min(int(counts.max(initial=0)), max_layers)
    m = int(row_multiple)
    band = m * max(1, min(height // m, TRANSLUCENT_BAND_BYTES // (PEEL_BYTES * max(layers, 1) * width * m)))
    for y0 in range(0, height, band):
        y1 = min(height, y0 + band)
        k = min(int(counts[y0:y1].max(initial=0)), max_layers)
        if k == 0:
            yield y0, y1, 0, None
            continue
        crop = view_proj if (y0, y1) == (0, height) else row_band_matrix(height, y0, y1) @ view_proj
        yield y0, y1, k, rasterize(vertices, triangles, crop, width, y1 - y0, layers=k, clamp_depth=clamp_depth,
                                   clip_near=clip_near, device=device)


def translucent_depths(vertices, triangles, opacity, view_proj, width: int, height: int, *,
                       max_layers: int = DEFAULT_MAX_LAYERS, clamp_depth: bool = False, clip_near: bool | None = None,
                       device=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The two-depth distribution (module doc) of every pixel of a view: (nearest, opaque, transmittance), (height,
    width) float32, NDC depths +inf where empty.

    Args:
        vertices, triangles: the casters (as :func:`~..raster.rasterizer.rasterize` takes them).
        opacity: (T,) opacity per triangle (:func:`triangle_opacity`).
        view_proj, width, height, clamp_depth, clip_near: as :func:`~..raster.rasterizer.rasterize`.
        max_layers: most translucent fragments per pixel (:func:`peel_row_bands`).
        device: Warp device.
    """
    tris = np.asarray(triangles)
    a = np.asarray(opacity, np.float64)
    if a.shape != (len(tris),):
        raise ValueError(f"opacity: expected one value per triangle ({len(tris)}), got shape {a.shape}")
    opaque = a >= OPAQUE_ALPHA
    translucent = ~opaque & (a >= float(ALPHA_TEST))
    kw = {"clamp_depth": clamp_depth, "clip_near": clip_near, "device": device}
    if np.any(opaque):
        opaque_ndc = rasterize(vertices, tris[opaque], view_proj, width, height, **kw).ndc_depth[0].copy()
    else:
        opaque_ndc = np.full((height, width), np.inf, np.float32)
    nearest = opaque_ndc.copy()
    transmittance = np.ones((height, width), np.float32)
    if not np.any(translucent):
        return nearest, opaque_ndc, transmittance
    passed = (1.0 - a[translucent]).astype(np.float32)
    for y0, y1, k, r in peel_row_bands(vertices, tris[translucent], view_proj, width, height, max_layers=max_layers,
                                       **kw):
        if k == 0:
            continue
        ids = r.tri_id
        front = (ids >= 0) & (r.ndc_depth < opaque_ndc[None, y0:y1])
        transmittance[y0:y1] = np.prod(np.where(front, passed[np.maximum(ids, 0)], np.float32(1.0)), axis=0)
        nearest[y0:y1] = np.where(front[0], r.ndc_depth[0], nearest[y0:y1])
    return nearest, opaque_ndc, transmittance


__all__ = [
    "ALPHA_TEST",
    "DEFAULT_MAX_LAYERS",
    "OPAQUE_ALPHA",
    "PEEL_BYTES",
    "TRANSLUCENT_BAND_BYTES",
    "has_translucent",
    "peel_row_bands",
    "row_band_matrix",
    "translucent_depths",
    "triangle_opacity",
]
