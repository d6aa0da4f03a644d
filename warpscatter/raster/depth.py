"""Rasterized depth on the host: :class:`RasterResult` and numpy mirrors of :mod:`.funcs` (pixel-centre NDC grids,
unprojection to world positions, linearization to view-space distance)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .inputs import check_matrix

if TYPE_CHECKING:
    import warp as wp


@dataclass
class RasterResult:
    """Depth layers of a rasterization (or of :func:`.raycast.raycast_depth`).

    Attributes:
        ndc_depth: (layers, height, width) float32 NDC depth in [-1, 1]; +inf where no surface.
        tri_id: (layers, height, width) int32 triangle index; -1 where no surface.
        keys: (layers, height, width) int64 packed keys (:func:`depth_key`) on the device; None for ray-cast results.
        device_ndc_depth, device_tri_id: ``ndc_depth``, ``tri_id`` as ``wp.array`` on the device (CPU: shared memory).
        view_proj: the float64 4x4 world -> clip matrix used.
    """

    ndc_depth: np.ndarray
    tri_id: np.ndarray
    keys: wp.array | None
    device_ndc_depth: wp.array
    device_tri_id: wp.array
    view_proj: np.ndarray

    @property
    def layers(self) -> int:
        return int(self.ndc_depth.shape[0])

    @property
    def height(self) -> int:
        return int(self.ndc_depth.shape[1])

    @property
    def width(self) -> int:
        return int(self.ndc_depth.shape[2])

    @classmethod
    def from_device(cls, ndc_depth: wp.array, tri_id: wp.array, keys: wp.array | None, view_proj) -> RasterResult:
        """Result holding the device arrays ``ndc_depth`` and ``tri_id`` and their host copies."""
        return cls(
            ndc_depth=ndc_depth.numpy(), tri_id=tri_id.numpy(), keys=keys, device_ndc_depth=ndc_depth,
            device_tri_id=tri_id, view_proj=view_proj,
        )


def pixel_center_ndc_grid(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """NDC x (width,) and y (height,) of pixel centres, row 0 at the top (float64, host mirror of
    :func:`pixel_center_ndc`)."""
    x = 2.0 * (np.arange(width) + 0.5) / width - 1.0
    y = 1.0 - 2.0 * (np.arange(height) + 0.5) / height
    return x, y


def unproject(ndc_depth, view_proj) -> np.ndarray:
    """(..., H, W, 3) float64 world positions of the pixel centres at NDC depths ``ndc_depth`` (..., H, W) (e.g.
    ``RasterResult.ndc_depth``) rendered with the 4x4 world -> clip ``view_proj``; +inf where a depth is not finite.
    """
    m = check_matrix(view_proj, "view_proj")
    z = np.asarray(ndc_depth, dtype=np.float64)
    if z.ndim < 2:
        raise ValueError(f"ndc_depth must have at least 2 dimensions (H, W), got shape {z.shape}")
    h, w = z.shape[-2:]
    xs, ys = pixel_center_ndc_grid(w, h)
    finite = np.isfinite(z)
    zz = np.where(finite, z, 0.0)
    ndc = np.stack(np.broadcast_arrays(xs[None, :], ys[:, None], zz, np.ones_like(zz)), axis=-1)
    p = ndc @ np.linalg.inv(m).T
    with np.errstate(divide="ignore", invalid="ignore"):
        world = p[..., :3] / p[..., 3:4]
    world[~finite | ~np.all(np.isfinite(world), axis=-1)] = np.inf
    return world


def linearize_depth(ndc_depth, projection) -> np.ndarray:
    """View-space distance (positive in front; float64, scene units, the shape of ``ndc_depth``) from NDC depth for an
    OpenGL-style perspective or orthographic 4x4 ``projection``; non-finite depths (empty texels) map to +inf. Host
    mirror of :func:`ndc_to_view_depth`.

    Raises:
        ValueError: malformed projection, or rows 2/3 of it depending on view-space x or y.
    """
    p = check_matrix(projection, "projection")
    if np.any(p[2:, :2] != 0.0):
        raise ValueError("projection: rows 2 and 3 must not depend on view-space x or y")
    z = np.asarray(ndc_depth, dtype=np.float64)
    finite = np.isfinite(z)
    zz = np.where(finite, z, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = -(p[2, 3] - p[3, 3] * zz) / (p[3, 2] * zz - p[2, 2])
    return np.where(finite & np.isfinite(d), d, np.inf)
