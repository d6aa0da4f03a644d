"""Reference view rays of a rectified map, one per row (Klehm 2014 Sec. 3.2), for both rectifications.

The prefilter weights a row's texels by the transmittance along ONE view ray of the row's epipolar slice; every other
ray crosses a column over a different world length. In a slice, omega_min is the frustum's view ray closest to the
light-perpendicular (largest k, k = cos of the angle to it), omega_max the farthest (smallest k).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .bounds import TWO_PI, inclination

if TYPE_CHECKING:
    from .bounds import NonlinearRectification
    from .projective import ProjectiveRectification

REFERENCE_METHODS = ("optimal", "bisectrix", "mean", "pixels", "least")


def check_reference_method(method: str, camera, caller: str) -> None:
    """Raise ValueError for an unknown reference-ray method, or ``"pixels"`` without a camera."""
    if method not in REFERENCE_METHODS:
        raise ValueError(f"method must be one of {', '.join(map(repr, REFERENCE_METHODS))}, got {method!r}")
    if method == "pixels" and camera is None:
        raise ValueError(f"{caller}(method='pixels') needs the camera")


def select_reference(method: str, shape, *, mean: Callable, bisectrix: np.ndarray, pixels: Callable,
                     least: np.ndarray, optimal: Callable) -> tuple[np.ndarray, np.ndarray]:
    """(the reference ray's parameter per row for ``method``, where the optimal one was used); ``mean``, ``pixels``
    and ``optimal`` are called only when chosen, ``optimal`` returning (parameter, mask where defined)."""
    if method == "optimal":
        return optimal()
    none = np.zeros(shape, bool)
    if method == "mean":
        return mean(), none
    if method == "bisectrix":
        return bisectrix, none
    if method == "pixels":
        return pixels(), none
    return least, none


def pixel_rays(camera, stride: int, to_light: np.ndarray) -> np.ndarray:
    """Directions of every ``stride``-th pixel ray of ``camera`` in a light view (rows of ``to_light``), (N, 3)."""
    if int(stride) != stride or stride < 1:
        raise ValueError(f"pixel_stride must be an integer >= 1, got {stride}")
    return camera.ray_directions(stride).reshape(-1, 3) @ to_light.T


def median_per_row(row: np.ndarray, key: np.ndarray, value: np.ndarray, rows: int, default: np.ndarray) -> np.ndarray:
    """Per row r in [0, rows), ``value`` of the sample with the median ``key`` among those with row == r
    (``default[r]`` where a row has none)."""
    order = np.lexsort((key, row))  # by row, then by key
    row_sorted = row[order]
    start = np.searchsorted(row_sorted, np.arange(rows), side="left")
    stop = np.searchsorted(row_sorted, np.arange(rows), side="right")
    has = stop > start
    mid = order[(start + stop - 1) // 2]
    return np.where(has, value[np.where(has, mid, 0)], default)


# ---- non-linear rectification: per-row inclinations -------------------------------------------------------


@dataclass(frozen=True)
class ReferenceRays:
    """Per-row reference view rays and their world step per rectified texel (Klehm 2014 Sec. 3.2).

    Attributes:
        phi: (rows,) azimuth of each row centre (radians).
        theta_lo, theta_hi: (rows,) inclination range of the frustum's rays in the slice (radians).
        theta_ref: (rows,) inclination of the reference ray (radians).
        k_ref: (rows,) k(omega_ref) = cos of its angle to the light-perpendicular = sin(theta_ref).
        delta_ref: (rows,) world distance per column along the reference ray, delta_perp / k_ref.
        direction: (rows, 3) unit world direction of the reference ray.
        optimal: (rows,) bool, True where k_ref = sqrt(k_min k_max) was used (else the bisectrix).
    """

    phi: np.ndarray
    theta_lo: np.ndarray
    theta_hi: np.ndarray
    theta_ref: np.ndarray
    k_ref: np.ndarray
    delta_ref: np.ndarray
    direction: np.ndarray
    optimal: np.ndarray

    def optical_steps(self, sigma_t: float) -> np.ndarray:
        """Per-row optical thickness of one texel along the reference ray, sigma_t * delta_ref (float32)."""
        if not (np.isfinite(sigma_t) and sigma_t >= 0.0):
            raise ValueError(f"sigma_t must be finite and >= 0, got {sigma_t}")
        return (sigma_t * self.delta_ref).astype(np.float32)


def reference_ray(rect: NonlinearRectification, method: str = "optimal", camera=None,
                  pixel_stride: int = 4) -> ReferenceRays:
    """Reference ray per epipolar slice of a non-linear rectification and its world step per texel (Klehm 2014
    Sec. 3.2): a ray of inclination theta crosses a column over Delta = Delta_perp / k, k = sin(theta).

    Args:
        rect: the rectification.
        method: ``"optimal"`` k_ref = sqrt(k(omega_min) k(omega_max)), minimising the worst ratio of Delta errors,
            where defined (omega_max is not the light axis), else the bisectrix of omega_min and omega_max;
            ``"bisectrix"`` everywhere (Klehm's); ``"mean"`` of the global theta bounds (Peters 2017 Sec. 5.1.1);
            ``"pixels"`` the median-k pixel ray in the slice (every ``pixel_stride``-th pixel; the bisectrix where
            none), then a running median over :data:`PIXEL_MEDIAN_SHARE` of the rows: weighting by the rays rendered
            beats Klehm's worst case over rays nearly along the light (warpscatter's); ``"least"`` omega_min, the
            least optical step, which the per-ray segment weights need (:mod:`.ray_weights`).
        camera: the :class:`~warpscatter.scene.camera.Camera`, required by ``"pixels"``.
        pixel_stride: pixel subsampling of ``"pixels"`` (>= 1).
    """
    check_reference_method(method, camera, "reference_ray")
    phi = rect.row_azimuths()
    lo, hi = rect.slice_inclination_range(phi)
    half_pi = 0.5 * math.pi
    theta_kmax = np.clip(half_pi, lo, hi)  # omega_min: closest to the light-perpendicular
    theta_kmin = np.where(np.abs(lo - half_pi) >= np.abs(hi - half_pi), lo, hi)  # omega_max: farthest
    k_big, k_small = np.sin(theta_kmax), np.sin(theta_kmin)
    bisectrix = 0.5 * (theta_kmax + theta_kmin)

    def optimal():
        defined = k_small > 1e-12  # undefined iff omega_max is the light axis (k = 0)
        k_opt = np.sqrt(np.clip(k_big * k_small, 0.0, 1.0))
        theta_opt = np.where(theta_kmin <= half_pi, np.arcsin(k_opt), math.pi - np.arcsin(k_opt))
        return np.where(defined, theta_opt, bisectrix), defined

    theta_ref, optimal = select_reference(
        method, phi.shape, mean=lambda: np.full(phi.shape, 0.5 * (rect.theta_min + rect.theta_max)),
        bisectrix=bisectrix, pixels=lambda: _pixel_median_inclination(rect, camera, pixel_stride, default=bisectrix),
        least=theta_kmax, optimal=optimal)
    k_ref = np.maximum(np.sin(theta_ref), 1e-6)
    st, ct = np.sin(theta_ref), np.cos(theta_ref)
    local = np.stack([st * np.cos(phi), st * np.sin(phi), ct], axis=-1)
    return ReferenceRays(phi=phi, theta_lo=lo, theta_hi=hi, theta_ref=theta_ref, k_ref=k_ref,
                         delta_ref=rect.delta_perp / k_ref, direction=local @ rect.to_light, optimal=optimal)


#: Share of the rows in the running median over the ``pixels`` reference rays (9 of 1024): near the epipole a slice
#: holds few sampled pixels, and one odd reference ray among its neighbours draws a line in the image.
PIXEL_MEDIAN_SHARE = 9.0 / 1024.0


def _pixel_median_inclination(rect: NonlinearRectification, camera, stride: int, default: np.ndarray) -> np.ndarray:
    """Per row, the inclination of the median-k pixel ray of ``camera`` in that slice (``default`` where none)."""
    q = pixel_rays(camera, stride, rect.to_light)
    theta = inclination(q)
    v = (np.mod(np.arctan2(q[:, 1], q[:, 0]) - rect.phi_mid + math.pi, TWO_PI) - math.pi) / rect.phi_span + 0.5
    row = np.clip((v * rect.rows).astype(np.int64), 0, rect.rows - 1)
    theta_ref = median_per_row(row, np.sin(theta), theta, rect.rows, default)
    half = int(round(0.5 * (PIXEL_MEDIAN_SHARE * rect.rows - 1.0)))
    if half < 1:
        return theta_ref
    padded = np.pad(theta_ref, half, mode="wrap" if rect.full_circle else "edge")
    window = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)
    return np.median(window, axis=1)


# ---- projective rectification: per-row depth slopes -------------------------------------------------------


@dataclass(frozen=True)
class ProjectiveReferenceRays:
    """Per-row reference view rays of a projective rectification (Klehm 2014 Sec. 3.2): a view ray along (1, s, zeta)
    in the light view crosses a column of light-view width dX over the world length dX sqrt(1 + s^2 + zeta^2).

    Attributes:
        slope: (rows,) y/x of the row centre.
        zeta_lo, zeta_hi: (rows,) depth-slope range of the frustum's rays in the slice.
        zeta_ref: (rows,) depth slope of the reference ray.
        k_ref: (rows,) k(omega_ref) = cosine of its angle to the light-perpendicular.
        length_scale: (rows,) world length per unit light-view x along the reference ray, sqrt(1 + s^2 + zeta^2).
        direction: (rows, 3) unit world direction of the reference ray.
        optimal: (rows,) bool, True where k_ref = sqrt(k_min k_max) was used (else the bisectrix).
    """

    slope: np.ndarray
    zeta_lo: np.ndarray
    zeta_hi: np.ndarray
    zeta_ref: np.ndarray
    k_ref: np.ndarray
    length_scale: np.ndarray
    direction: np.ndarray
    optimal: np.ndarray


def _pixel_median_slopes(rect: ProjectiveRectification, camera, stride: int, default: np.ndarray) -> np.ndarray:
    """Per row, the depth slope z/x of the median-k pixel ray of ``camera`` in that slice (``default`` where none)."""
    q = pixel_rays(camera, stride, rect.to_light)
    slope, zeta = q[:, 1] / q[:, 0], q[:, 2] / q[:, 0]
    row = np.clip(((rect.s_hi - slope) / (rect.s_hi - rect.s_lo) * rect.rows).astype(np.int64), 0, rect.rows - 1)
    k = np.sqrt(1.0 + slope**2) / np.sqrt(1.0 + slope**2 + zeta**2)
    return median_per_row(row, k, zeta, rect.rows, default)


def reference_rays(rect: ProjectiveRectification, method: str = "optimal", camera=None,
                   pixel_stride: int = 4) -> ProjectiveReferenceRays:
    """:func:`reference_ray` for a projective rectification (Klehm 2014 Sec. 3.2), the same ``method`` choices (the
    optimal one always defined; ``"mean"`` the middle of the depth-slope bounds) and arguments: omega_min has the
    smallest |z/x|, omega_max the largest, k = sqrt(1 + s^2) / sqrt(1 + s^2 + zeta^2)."""
    check_reference_method(method, camera, "reference_rays")
    s = rect.row_slopes()
    lo, hi = rect.slice_depth_slope_range(s)
    h2 = 1.0 + s * s
    zeta_near = np.clip(0.0, lo, hi)  # omega_min (largest k)
    zeta_far = np.where(np.abs(lo) >= np.abs(hi), lo, hi)  # omega_max (smallest k)
    n_near, n_far = np.sqrt(h2 + zeta_near**2), np.sqrt(h2 + zeta_far**2)
    bisectrix = (zeta_near / n_near + zeta_far / n_far) / (1.0 / n_near + 1.0 / n_far)

    def optimal():
        k_ref = np.sqrt(np.sqrt(h2) / n_near * np.sqrt(h2) / n_far)
        return np.sign(zeta_far) * np.sqrt(np.maximum(h2 / k_ref**2 - h2, 0.0)), np.ones(s.shape, bool)

    zeta_ref, optimal = select_reference(
        method, s.shape, mean=lambda: np.full(s.shape, 0.5 * (rect.zeta_min + rect.zeta_max)), bisectrix=bisectrix,
        pixels=lambda: _pixel_median_slopes(rect, camera, pixel_stride, default=bisectrix), least=zeta_near,
        optimal=optimal)
    scale = np.sqrt(h2 + zeta_ref**2)
    local = np.stack([np.ones_like(s), s, zeta_ref], axis=-1) / scale[:, None]
    return ProjectiveReferenceRays(slope=s, zeta_lo=lo, zeta_hi=hi, zeta_ref=zeta_ref, k_ref=np.sqrt(h2) / scale,
                                   length_scale=scale, direction=local @ rect.to_light, optimal=optimal)
