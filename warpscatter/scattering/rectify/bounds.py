"""Bounds of a non-linear rectification for one camera and a directional light (Peters 2017 App. A).

The far-plane corners q_j in light view space (:mod:`.spherical`) bound the map, the near plane ignored (r_min = 0):
r_max = max_j |q_j,xy|; phi from the pair of corners enclosing the largest angle, or the full circle when the
(flipped) light direction lies inside the view frustum; theta from the corners, the critical points on the far-plane
edges and 0 / pi for the (flipped) light direction inside; the theta interval is widened by the guard band against
light leaking. Host float64, once per frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ...scene.camera import normalize
from .spherical import NonlinearRectParams

TWO_PI = 2.0 * math.pi
_INSIDE_TOL = 1e-9  # relative tolerance of the inclusive "direction inside the frustum" test


def _light_basis(light_direction) -> np.ndarray:
    """Rotation whose rows are light-view x, y, z; z = the light travel direction (right-handed)."""
    ez = unit_light_direction(light_direction)
    ex, ey = perpendicular_basis(ez)
    return np.stack([ex, ey, ez])


def unit_light_direction(light_direction) -> np.ndarray:
    """The unit direction the light travels; ValueError for a zero or non-finite vector."""
    try:
        return normalize(light_direction)
    except ValueError as exc:
        raise ValueError(f"light_direction must be a finite non-zero 3-vector: {exc}") from None


def perpendicular_basis(ez: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit x, y axes completing unit ``ez`` to a right-handed basis (x from the world axis least parallel to ez)."""
    helper = np.eye(3)[int(np.argmin(np.abs(ez)))]
    ex = helper - helper.dot(ez) * ez
    ex /= np.linalg.norm(ex)
    return ex, np.cross(ez, ex)


def direction_in_frustum(camera, direction) -> bool:
    """True when the (infinite) view frustum of ``camera`` contains the ray from its position along ``direction``."""
    right, up, fwd = camera.basis
    d = np.asarray(direction, float)
    cz = d @ fwd
    if cz <= 0.0:
        return False
    t = math.tan(math.radians(camera.fov_y) / 2.0)
    tol = 1.0 + _INSIDE_TOL
    return abs(d @ right) <= cz * t * camera.aspect * tol and abs(d @ up) <= cz * t * tol


def inclination(q: np.ndarray) -> np.ndarray:
    """theta = arccos(z / |q|) of light-view points, computed as atan2(r, z)."""
    return np.arctan2(np.hypot(q[..., 0], q[..., 1]), q[..., 2])


def _edge_critical_inclinations(quad: np.ndarray) -> list[float]:
    """Inclinations at the critical points on the far-plane edges (Peters 2017 App. A)."""
    out = []
    for a in range(4):
        qj, qk = quad[a], quad[(a + 1) % 4]
        b = qk - qj
        den = b[2] * qj.dot(b) - qj[2] * b.dot(b)
        if abs(den) <= 1e-300:
            continue
        t = (qj[2] * qj.dot(b) - b[2] * qj.dot(qj)) / den
        if 0.0 <= t <= 1.0:
            out.append(float(inclination(qj + t * b)))
    return out


def widest_pair(xy: np.ndarray) -> tuple[int, int, float]:
    """Indices of the two 2D vectors enclosing the largest angle, and that angle (radians)."""
    best, pair = -1.0, (0, 1)
    for a in range(len(xy)):
        for b in range(a + 1, len(xy)):
            cross = xy[a, 0] * xy[b, 1] - xy[a, 1] * xy[b, 0]
            ang = math.atan2(abs(cross), float(xy[a] @ xy[b]))
            if ang > best:
                best, pair = ang, (a, b)
    return pair[0], pair[1], best


def _azimuth_bounds(xy: np.ndarray) -> tuple[float, float]:
    """(phi_min in [0, 2 pi), span) of the cone spanned by 2D vectors xy: the pair enclosing the largest angle."""
    a, b, best = widest_pair(xy)
    if xy[a, 0] * xy[b, 1] - xy[a, 1] * xy[b, 0] < 0.0:
        a, b = b, a  # counter-clockwise from a to b
    return math.atan2(xy[a, 1], xy[a, 0]) % TWO_PI, best


@dataclass(frozen=True)
class NonlinearRectification:
    """Non-linear rectification of a directional light for one camera (Peters 2017 Sec. 5.1.1, App. A).

    Attributes:
        position: camera position (world), the origin of light view space.
        to_light: (3, 3) world -> light-view rotation, rows = x, y, z axes; z = light travel direction.
        far_corners: (4, 3) far-plane corners in light view space, in cyclic order.
        r_max: largest distance of the frustum from the light axis through the camera (world units).
        phi_min, phi_span: azimuth range [phi_min, phi_min + phi_span] mapped to v in [0, 1] (radians).
        full_circle: True when phi covers the full circle (light or flipped light direction inside the view).
        light_in_view / flipped_light_in_view: the light direction / its flip lies inside the view frustum.
        theta_min, theta_max: tight inclination bounds of the frustum (radians).
        guard_band: relative stretch of the theta interval (0.1 = 10 %, half on each side).
        rows, cols: resolution of the rectified map (epipolar slices x texels along a view ray).
        view_radius: r_max of the view frustum alone (before a ``radius`` cap).
    """

    position: np.ndarray
    to_light: np.ndarray
    far_corners: np.ndarray
    r_max: float
    phi_min: float
    phi_span: float
    full_circle: bool
    light_in_view: bool
    flipped_light_in_view: bool
    theta_min: float
    theta_max: float
    guard_band: float
    rows: int
    cols: int
    view_radius: float = 0.0
    light_distance: float = 0.0
    psi_lo: float = 0.0

    @property
    def local(self) -> bool:
        """True for a local (spot) light's rectification (:mod:`.local`): columns are angles at the light."""
        return self.light_distance > 0.0

    @property
    def column_scale(self) -> float:
        """View radius / r_max: how many times finer the columns are than those of a map reaching the view's far
        corners (1 unless ``radius`` capped it)."""
        return self.view_radius / self.r_max if self.view_radius > 0.0 else 1.0

    @classmethod
    def from_camera(cls, camera, light_direction, guard_band: float = 0.1, rows: int = 1024,
                    cols: int = 1024, radius: float | None = None) -> "NonlinearRectification":
        """Tight bounds of the rectified coordinates for ``camera`` and a directional light travelling along
        ``light_direction`` (Peters 2017 App. A); sizes and ``guard_band`` as the attributes (rows, cols >= 2).
        ``radius`` caps r_max (world units; :func:`caster_radius`): the look-ups count texels beyond it as lit."""
        if not (np.isfinite(guard_band) and guard_band >= 0.0):
            raise ValueError(f"guard_band must be finite and >= 0, got {guard_band}")
        for name, val in (("rows", rows), ("cols", cols)):
            if int(val) != val or val < 2:
                raise ValueError(f"{name} must be an integer >= 2, got {val}")
        to_light = _light_basis(light_direction)
        ez = to_light[2]
        position = np.asarray(camera.position, float)
        far = camera.frustum_corners()[4:][[0, 1, 3, 2]]  # cyclic order around the far plane
        quad = (far - position) @ to_light.T

        # ---- r: distance to the light axis through the camera (r_min = 0, near plane ignored) ----
        r_max = float(np.max(np.hypot(quad[:, 0], quad[:, 1])))
        r_max = max(r_max, 1e-12 * float(np.max(np.linalg.norm(quad, axis=1))))
        view_radius = r_max
        if radius is not None:
            if not (np.isfinite(radius) and radius > 0.0):
                raise ValueError(f"radius must be finite and > 0, got {radius}")
            r_max = min(r_max, float(radius))

        # ---- phi: full circle when the (flipped) light direction lies inside the frustum ----
        light_in = direction_in_frustum(camera, ez)
        flipped_in = direction_in_frustum(camera, -ez)
        if light_in or flipped_in:
            phi_min, phi_span = 0.0, TWO_PI
        else:
            phi_min, phi_span = _azimuth_bounds(quad[:, :2])
            phi_span = max(phi_span, 1e-9)

        # ---- theta: corners, edge critical points, and the interior when the axis is inside ----
        thetas = list(inclination(quad)) + _edge_critical_inclinations(quad)
        if light_in:
            thetas.append(0.0)
        if flipped_in:
            thetas.append(math.pi)
        return cls(position=position, to_light=to_light, far_corners=quad, r_max=r_max, phi_min=float(phi_min),
                   phi_span=float(phi_span), full_circle=bool(light_in or flipped_in), light_in_view=bool(light_in),
                   flipped_light_in_view=bool(flipped_in), theta_min=float(min(thetas)),
                   theta_max=float(max(thetas)), guard_band=float(guard_band), rows=int(rows), cols=int(cols),
                   view_radius=float(view_radius))

    @property
    def light_direction(self) -> np.ndarray:
        """Unit direction the light travels (light-view z axis)."""
        return self.to_light[2]

    @property
    def phi_mid(self) -> float:
        return self.phi_min + 0.5 * self.phi_span

    @property
    def theta_lo(self) -> float:
        """Guarded lower inclination bound (rectified depth 1)."""
        return self.theta_min - 0.5 * self.guard_band * (self.theta_max - self.theta_min)

    @property
    def theta_hi(self) -> float:
        """Guarded upper inclination bound (rectified depth 0)."""
        return self.theta_max + 0.5 * self.guard_band * (self.theta_max - self.theta_min)

    @property
    def theta_len(self) -> float:
        return max(self.theta_hi - self.theta_lo, 1e-9)

    @property
    def delta_perp(self) -> float:
        """World width of one column for a ray perpendicular to the light (Klehm 2014 Delta-perp)."""
        return self.r_max / self.cols

    def params(self) -> NonlinearRectParams:
        """Kernel-side parameters (:class:`NonlinearRectParams`)."""
        p = NonlinearRectParams()
        p.origin = wp.vec3(*self.position)
        p.to_light = wp.mat33(*self.to_light.ravel())
        p.r_max = float(self.r_max)
        p.phi_mid = float(self.phi_mid)
        p.phi_span = float(self.phi_span)
        p.theta_hi = float(self.theta_hi)
        p.theta_len = float(self.theta_len)
        p.rows = int(self.rows)
        p.cols = int(self.cols)
        p.full_circle = 1 if self.full_circle else 0
        p.light_distance = float(self.light_distance)
        p.psi_lo = float(self.psi_lo)
        return p

    def world_to_rectified(self, points) -> np.ndarray:
        """Rectified (u, v, depth) of world points, shape (..., 3) -> (..., 3) float64 (see the module doc)."""
        p = np.asarray(points, dtype=np.float64)
        if p.shape[-1] != 3:
            raise ValueError(f"points must have shape (..., 3), got {p.shape}")
        q = (p - self.position) @ self.to_light.T
        d = np.mod(np.arctan2(q[..., 1], q[..., 0]) - self.phi_mid + math.pi, TWO_PI) - math.pi
        u = np.hypot(q[..., 0], q[..., 1]) / self.r_max
        if self.local:
            u = (np.arctan2(np.hypot(q[..., 0], q[..., 1]), q[..., 2] + self.light_distance) - self.psi_lo) / self.r_max
        depth = (self.theta_hi - inclination(q)) / self.theta_len
        return np.stack([u, 0.5 + d / self.phi_span, depth], axis=-1)

    def rectified_to_world(self, coords) -> np.ndarray:
        """World points of rectified (u, v, depth), shape (..., 3); inclinations must lie inside (0, pi)."""
        c = np.asarray(coords, dtype=np.float64)
        if c.shape[-1] != 3:
            raise ValueError(f"coords must have shape (..., 3), got {c.shape}")
        phi = self.phi_mid + (c[..., 1] - 0.5) * self.phi_span
        theta = self.theta_hi - c[..., 2] * self.theta_len
        if self.local:  # the view ray theta meets the light ray psi at t = D sin(psi) / sin(theta - psi)
            psi = self.psi_lo + c[..., 0] * self.r_max
            t = self.light_distance * np.sin(psi) / np.maximum(np.sin(theta - psi), 1e-300)
            r = t * np.sin(theta)
        else:
            r = c[..., 0] * self.r_max
        z = r * np.cos(theta) / np.maximum(np.sin(theta), 1e-300)
        q = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
        return self.position + q @ self.to_light

    def row_azimuths(self) -> np.ndarray:
        """Azimuth phi (radians) of every row centre, shape (rows,)."""
        return self.phi_mid + ((np.arange(self.rows) + 0.5) / self.rows - 0.5) * self.phi_span

    def slice_inclination_range(self, phi) -> tuple[np.ndarray, np.ndarray]:
        """Unguarded inclination range (theta_lo, theta_hi) of the frustum's view rays in the slices at azimuths
        ``phi`` (any shape): where the slice's boundary rays cross the far-plane edges, or the light axis (0 / pi)
        when the (flipped) light lies inside the view; slices missing the frustum get the global bounds."""
        phi = np.asarray(phi, dtype=np.float64)
        e = np.stack([np.cos(phi), np.sin(phi)], axis=-1)
        lo = np.full(phi.shape, np.inf)
        hi = np.full(phi.shape, -np.inf)
        for a in range(4):
            qa, qb = self.far_corners[a], self.far_corners[(a + 1) % 4]
            da = qa[0] * e[..., 1] - qa[1] * e[..., 0]  # cross(qa_xy, e)
            dd = (qb[0] - qa[0]) * e[..., 1] - (qb[1] - qa[1]) * e[..., 0]
            with np.errstate(divide="ignore", invalid="ignore"):
                s = np.where(np.abs(dd) > 1e-300, -da / dd, np.nan)
            ok = (s >= -1e-9) & (s <= 1.0 + 1e-9)
            s = np.clip(np.nan_to_num(s), 0.0, 1.0)
            pts = qa + s[..., None] * (qb - qa)
            ok &= (pts[..., 0] * e[..., 0] + pts[..., 1] * e[..., 1]) >= 0.0  # same half-plane, not opposite
            th = inclination(pts)
            lo = np.where(ok, np.minimum(lo, th), lo)
            hi = np.where(ok, np.maximum(hi, th), hi)
        if self.light_in_view:
            lo = np.zeros_like(lo)
        if self.flipped_light_in_view:
            hi = np.full_like(hi, math.pi)
        empty = ~(lo <= hi)
        lo = np.where(empty, self.theta_min, lo)
        hi = np.where(empty, self.theta_max, hi)
        return lo, hi


def caster_radius(vertices, camera, light_direction, margin: float = 0.02) -> float | None:
    """Largest distance of a caster vertex from the light axis through the camera, widened by ``margin`` (relative):
    no light ray farther out is blocked, so a rectified map need not reach beyond it (``map_radius: casters``).
    None without vertices. World units."""
    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    if len(v) == 0:
        return None
    axis = np.asarray(light_direction, np.float64)
    axis = axis / np.linalg.norm(axis)
    p = v - np.asarray(camera.position, np.float64)
    r = np.sqrt(np.maximum(np.einsum("ij,ij->i", p, p) - (p @ axis) ** 2, 0.0))
    return float(r.max() * (1.0 + margin)) if r.max() > 0 else None
