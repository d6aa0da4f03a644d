"""Pinhole camera following CONVENTIONS.md (``docs/conventions.md``), and the 4x4 matrices shared by every
rasterizing stage.

Pixel (i, j): column i from the left, row j from the TOP; its ray runs from ``position`` through the pixel centre
and ends on the far plane if it hits nothing. Matrices are OpenGL-style (view space right-handed looking down -Z,
NDC [-1, 1]^3, z = -1 at near); NDC y = +1 is image row 0, so pixel (i, j) rasterizes exactly at its ray's centre.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from ..runtime.device import module_options

module_options()


def normalize(v) -> np.ndarray:
    """Return ``v`` / |v| as float64 (raises ValueError on a zero vector)."""
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v)
    if not np.isfinite(n) or n == 0.0:
        raise ValueError(f"cannot normalise zero or non-finite vector {v.tolist()}")
    return v / n


def look_at_basis(position, look_at, up) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orthonormal (right, up', forward) of a camera; raises ValueError when ``up`` is parallel to the view."""
    forward = normalize(np.asarray(look_at, float) - np.asarray(position, float))
    r = np.cross(forward, np.asarray(up, float))
    if np.linalg.norm(r) < 1e-9:
        raise ValueError("camera.up is parallel to the viewing direction")
    right = r / np.linalg.norm(r)
    up2 = np.cross(right, forward)
    return right, up2, forward


def view_matrix(position, right, up, forward) -> np.ndarray:
    """World -> view (right-handed, camera looks down -Z) as a float64 4x4."""
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = right, up, -np.asarray(forward)
    m[:3, 3] = -m[:3, :3] @ np.asarray(position, float)
    return m


def perspective_matrix(fov_y_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    """OpenGL perspective projection (NDC z in [-1, 1], -1 at ``near``)."""
    f = 1.0 / np.tan(np.radians(fov_y_deg) / 2.0)
    m = np.zeros((4, 4))
    m[0, 0], m[1, 1] = f / aspect, f
    m[2, 2] = (far + near) / (near - far)
    m[2, 3] = 2.0 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


def orthographic_matrix(left: float, right: float, bottom: float, top: float, near: float, far: float) -> np.ndarray:
    """OpenGL orthographic projection of the view-space box [l,r]x[b,t]x[-far,-near]."""
    m = np.eye(4)
    m[0, 0], m[1, 1], m[2, 2] = 2.0 / (right - left), 2.0 / (top - bottom), -2.0 / (far - near)
    m[0, 3] = -(right + left) / (right - left)
    m[1, 3] = -(top + bottom) / (top - bottom)
    m[2, 3] = -(far + near) / (far - near)
    return m


@dataclass(frozen=True)
class Camera:
    """Pinhole camera. Lengths in scene units, ``fov_y`` in degrees, image size in pixels."""

    position: np.ndarray
    look_at: np.ndarray
    up: np.ndarray
    fov_y: float
    width: int
    height: int
    near: float
    far: float

    def __post_init__(self):
        for name in ("position", "look_at", "up"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=np.float64))
        if not (self.width > 0 and self.height > 0):
            raise ValueError("camera width and height must be positive")
        if not (0.0 < self.near < self.far):
            raise ValueError("camera needs 0 < near < far")
        if not (0.0 < self.fov_y < 180.0):
            raise ValueError("camera fov_y must lie in (0, 180) degrees")
        look_at_basis(self.position, self.look_at, self.up)  # validates

    @property
    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up', forward), orthonormal, float64."""
        return look_at_basis(self.position, self.look_at, self.up)

    @property
    def forward(self) -> np.ndarray:
        return self.basis[2]

    @property
    def aspect(self) -> float:
        return self.width / self.height

    def view(self) -> np.ndarray:
        """World -> view matrix (float64 4x4)."""
        return view_matrix(self.position, *self.basis)

    def projection(self) -> np.ndarray:
        """Perspective projection (float64 4x4)."""
        return perspective_matrix(self.fov_y, self.aspect, self.near, self.far)

    def view_projection(self) -> np.ndarray:
        """World -> clip matrix; pixel (i, j) rasterizes at the centre of its CONVENTIONS ray."""
        return self.projection() @ self.view()

    def exr_matrices(self) -> dict[str, np.ndarray]:
        """OpenEXR's ``worldToCamera`` and ``worldToNDC`` (float64 4x4, transposed: p maps as [p, 1] @ M); camera space
        left-handed with +z forward, NDC (0, 0) at the top-left corner, z in [0, 1] from near to far."""
        right, up, forward = self.basis
        to_camera = np.eye(4)
        to_camera[0, :3], to_camera[1, :3], to_camera[2, :3] = right, up, forward
        to_camera[:3, 3] = -to_camera[:3, :3] @ self.position
        t = np.tan(np.radians(self.fov_y) / 2.0)
        n, f = self.near, self.far
        projection = np.array([  # x, y: 0.5 +- 0.5 x / (z t a); z: (z - n) f / ((f - n) z); w = z
            [0.5 / (t * self.aspect), 0.0, 0.5, 0.0],
            [0.0, -0.5 / t, 0.5, 0.0],
            [0.0, 0.0, f / (f - n), -n * f / (f - n)],
            [0.0, 0.0, 1.0, 0.0],
        ])
        return {"worldToCamera": to_camera.T.copy(), "worldToNDC": (projection @ to_camera).T.copy()}

    def ray_directions(self, stride: int = 1) -> np.ndarray:
        """Unit ray directions (height, width, 3) float64, row 0 = top; ``stride`` s: ``[s//2::s, s//2::s]``."""
        t = np.tan(np.radians(self.fov_y) / 2.0)
        i = np.arange(stride // 2, self.width, stride) + 0.5
        j = np.arange(stride // 2, self.height, stride) + 0.5
        x = (2.0 * i / self.width - 1.0) * t * self.aspect
        y = (1.0 - 2.0 * j / self.height) * t
        right, up, fwd = self.basis
        d = x[None, :, None] * right + y[:, None, None] * up + fwd
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def far_distance(self, directions: np.ndarray) -> np.ndarray:
        """Distance along each unit ray to the far plane: far / dot(direction, forward)."""
        return self.far / (directions @ self.forward)

    def frustum_corners(self, near: float | None = None, far: float | None = None) -> np.ndarray:
        """World-space corners of the view frustum between ``near`` and ``far``, shape (8, 3)."""
        near = self.near if near is None else near
        far = self.far if far is None else far
        right, up, fwd = self.basis
        t = np.tan(np.radians(self.fov_y) / 2.0)
        out = []
        for d in (near, far):
            for sy in (-1, 1):
                for sx in (-1, 1):
                    out.append(self.position + d * (fwd + sx * t * self.aspect * right + sy * t * up))
        return np.array(out)

    def params(self) -> "CameraParams":
        """Kernel-side parameters (:class:`CameraParams`)."""
        right, up, fwd = self.basis
        p = CameraParams()
        p.position = wp.vec3(*self.position)
        p.right = wp.vec3(*right)
        p.up = wp.vec3(*up)
        p.forward = wp.vec3(*fwd)
        p.tan_half_fov = float(np.tan(np.radians(self.fov_y) / 2.0))
        p.aspect = float(self.aspect)
        p.width = int(self.width)
        p.height = int(self.height)
        p.near = float(self.near)
        p.far = float(self.far)
        return p


@wp.struct
class CameraParams:
    """Camera as kernels see it (world space, unit basis vectors)."""

    position: wp.vec3
    right: wp.vec3
    up: wp.vec3  # up' = cross(right, forward)
    forward: wp.vec3
    tan_half_fov: float  # tan(fov_y / 2)
    aspect: float  # width / height
    width: int
    height: int
    near: float
    far: float


@wp.func
def pixel_ray_factors(cam: CameraParams, x: float, y: float) -> wp.vec2:
    """Factors (xn, yn) of ``cam.right`` and ``cam.up`` for image point (x, y) (xn depends on x only, yn on y)."""
    xn = (2.0 * x / float(cam.width) - 1.0) * cam.tan_half_fov * cam.aspect
    yn = (1.0 - 2.0 * y / float(cam.height)) * cam.tan_half_fov
    return wp.vec2(xn, yn)


@wp.func
def factors_ray_direction(cam: CameraParams, xn: float, yn: float) -> wp.vec3:
    """The unit direction of :func:`pixel_ray_factors` (xn, yn): normalize(xn right + yn up + forward)."""
    return wp.normalize(xn * cam.right + yn * cam.up + cam.forward)


@wp.func
def pixel_ray_direction(cam: CameraParams, x: float, y: float) -> wp.vec3:
    """Unit direction through image point (x, y) in pixels (pixel (i, j) centre = (i+0.5, j+0.5), y down)."""
    f = pixel_ray_factors(cam, x, y)
    return factors_ray_direction(cam, f[0], f[1])


@wp.func
def far_plane_distance(cam: CameraParams, direction: wp.vec3) -> float:
    """Distance along a unit ray from the camera to the far plane."""
    return cam.far / wp.dot(direction, cam.forward)
