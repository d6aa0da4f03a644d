"""Projective rectification of a directional light's shadow map (Klehm 2014 Sec. 4.2, Fig. 4, Eq. 12).

ONE 4x4 matrix per region replaces the light's view-projection, so the scene is rasterized straight into the map:
light view space at the camera (z = the direction the light TRAVELS, CONVENTIONS.md), rotated about z so that the
bisectrix of the projected frustum corners is +x, then a perspective projection ALONG x with the camera as centre. A
view ray lies in one row (slope y/x) at one depth (slope z/x): u = f (x - n) / ((f - n) x), v = (s_hi - y/x) /
(s_hi - s_lo) (row 0 at NDC y = +1), depth = normalised, guard-banded z/x, clamped when rasterizing (casters before
the frustum land at 0). Columns grow like x^2 (:func:`column_lengths`); ``regions`` R > 1 cuts the frustum along x
into geometric regions of cols/R columns each. An epipole in the image degenerates it (:func:`choose_rectification`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ...raster import rasterizer as raster
from ...runtime.device import default_device, module_options
from ...scene.camera import normalize
from ..prefiltered.prefix_sums import split_columns
from ..settings import EPIPOLE_MARGIN, MAX_REGIONS
from .bounds import perpendicular_basis, unit_light_direction, widest_pair
from .taps import SparseRectifiedDepth

module_options()

logger = logging.getLogger("warpscatter")


@wp.struct
class ProjectiveRectParams:
    """A projective rectification as kernels see it (see :class:`ProjectiveRectification`)."""

    origin: wp.vec3  # camera position (world), the centre of projection
    to_light: wp.mat33  # world -> rectifying light view; rows = bisectrix x, y, light travel direction z
    near: float  # n: smallest light-view x of the frustum corners (world units, > 0)
    log_ratio: float  # log(f / n)
    regions: int  # light-frustum regions along x (1 = one projection)
    s_hi: float  # slope y/x of row coordinate v = 0
    s_span: float  # slope range covered by v in [0, 1]
    zeta_lo: float  # guarded slope z/x of rectified depth 0
    zeta_span: float  # guarded slope range covered by depth in [0, 1]
    rows: int  # epipolar slices
    cols: int  # texels along a view ray (all regions)


@wp.func
def region_near_far(rect: ProjectiveRectParams, k: int):
    """Light-view x range [n_k, f_k] of light-frustum region k: n (f/n)^(k/R) .. n (f/n)^((k+1)/R) (Klehm Sec. 4.2)."""
    s = float(rect.regions)
    return rect.near * wp.exp(rect.log_ratio * float(k) / s), rect.near * wp.exp(rect.log_ratio * float(k + 1) / s)


@wp.func
def world_to_rectified(rect: ProjectiveRectParams, x: wp.vec3) -> wp.vec3:
    """Rectified (u, v, depth) of world point x (Klehm 2014 Sec. 4.2): u = projective depth of the light-view x
    (per light-frustum region), v = normalised slope y/x (row), depth = normalised slope z/x."""
    q = rect.to_light * (x - rect.origin)
    qx = wp.max(q[0], 1.0e-6 * rect.near)  # points behind the centre of projection go to column 0
    k = int(0)
    if rect.regions > 1:
        k = int(wp.floor(float(rect.regions) * wp.log(qx / rect.near) / rect.log_ratio))
        k = wp.clamp(k, 0, rect.regions - 1)
    n, f = region_near_far(rect, k)
    c0, nc = split_columns(rect.regions, rect.cols, k)
    u_local = f * (qx - n) / ((f - n) * qx)
    u = (float(c0) + u_local * float(nc)) / float(rect.cols)
    v = (rect.s_hi - q[1] / qx) / rect.s_span
    return wp.vec3(u, v, (q[2] / qx - rect.zeta_lo) / rect.zeta_span)


@wp.func
def rectified_to_world(rect: ProjectiveRectParams, c: wp.vec3) -> wp.vec3:
    """World point of rectified (u, v, depth) (inverse of :func:`world_to_rectified` for u in [0, 1])."""
    col = c[0] * float(rect.cols)
    k = int(0)
    for r in range(1, rect.regions):
        c_r, nc_r = split_columns(rect.regions, rect.cols, r)
        if col >= float(c_r):
            k = r
    n, f = region_near_far(rect, k)
    c0, nc = split_columns(rect.regions, rect.cols, k)
    u_local = (col - float(c0)) / float(nc)
    qx = f * n / (f - u_local * (f - n))
    q = qx * wp.vec3(1.0, rect.s_hi - c[1] * rect.s_span, rect.zeta_lo + c[2] * rect.zeta_span)
    return rect.origin + wp.transpose(rect.to_light) * q


@wp.func
def rectified_ray_depth(rect: ProjectiveRectParams, direction: wp.vec3) -> float:
    """Constant rectified depth of the camera view ray with world direction ``direction`` (x component > 0)."""
    q = rect.to_light * direction
    return (q[2] / q[0] - rect.zeta_lo) / rect.zeta_span


# ---- host side: construction ----------------------------------------------------------------------


def projection_matrix(near: float, far: float, s_lo: float, s_hi: float, zeta_lo: float, zeta_hi: float) -> np.ndarray:
    """Perspective projection ALONG x (Klehm 2014 Sec. 4.2): light view (x, y, z) -> clip (X, Y, Z, W = x), mapping
    x in [n, f], y/x in [s_lo, s_hi] and z/x in [zeta_lo, zeta_hi] to [-1, 1]."""
    m = np.zeros((4, 4))
    m[0, 0] = (far + near) / (far - near)
    m[0, 3] = -2.0 * far * near / (far - near)
    m[1, 0] = -(s_hi + s_lo) / (s_hi - s_lo)
    m[1, 1] = 2.0 / (s_hi - s_lo)
    m[2, 0] = -(zeta_hi + zeta_lo) / (zeta_hi - zeta_lo)
    m[2, 2] = 2.0 / (zeta_hi - zeta_lo)
    m[3, 0] = 1.0
    return m


@dataclass(frozen=True)
class ProjectiveRectification:
    """Projective rectification of a directional light for one camera (Klehm 2014 Sec. 4.2).

    Attributes:
        position: camera position (world), the centre of projection.
        to_light: (3, 3) world -> rectifying light view, rows = x (bisectrix), y, z (light travel direction).
        corners: (8, 3) frustum corners in that light view (near plane first, as ``Camera.frustum_corners``).
        near, far: smallest / largest light-view x of the corners (world units, 0 < near < far).
        s_lo, s_hi: slope y/x range of the corners (rows; s_lo = -s_hi by the bisectrix).
        zeta_min, zeta_max: tight slope z/x range of the corners (rectified depth before the guard band).
        guard_band: relative stretch of the depth slope interval (half on each side).
        half_angle: half the angle of the widest pair of projected corners (radians, < pi/2).
        rows, cols: rectified map size (epipolar slices x texels along a view ray).
        regions: light-frustum regions along x, each with its own projection (Klehm 2014 Sec. 4.2; 1 = one).
    """

    position: np.ndarray
    to_light: np.ndarray
    corners: np.ndarray
    near: float
    far: float
    s_lo: float
    s_hi: float
    zeta_min: float
    zeta_max: float
    guard_band: float
    half_angle: float
    rows: int
    cols: int
    regions: int

    @classmethod
    def from_camera(cls, camera, light_direction, guard_band: float = 0.1, rows: int = 1024, cols: int = 1024,
                    regions: int = 1) -> "ProjectiveRectification":
        """The rectifying light frustum around ``camera`` for a directional light travelling along
        ``light_direction`` (Klehm 2014 Sec. 4.2, Fig. 4); sizes and ``guard_band`` as the attributes (cols >= 3 per
        region). ValueError on bad inputs or an (anti-)epipole in the image, where the construction is impossible."""
        if not (np.isfinite(guard_band) and guard_band >= 0.0):
            raise ValueError(f"guard_band must be finite and >= 0, got {guard_band}")
        if int(regions) != regions or not 1 <= regions <= MAX_REGIONS:
            raise ValueError(f"regions must be an integer in [1, {MAX_REGIONS}], got {regions}")
        for name, val, low in (("rows", rows, 2), ("cols", cols, 3 * int(regions))):
            if int(val) != val or val < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {val}")
        ez = unit_light_direction(light_direction)
        position = np.asarray(camera.position, float)
        # ---- step 1-2: any light view from the camera; widest pair of projected corners -> bisectrix ----
        ex0, ey0 = perpendicular_basis(ez)
        far_dirs = camera.frustum_corners()[4:] - position
        xy = np.stack([far_dirs @ ex0, far_dirs @ ey0], axis=-1)
        lengths = np.linalg.norm(xy, axis=1)
        if np.any(lengths <= 1e-12 * np.linalg.norm(far_dirs, axis=1)):
            raise ValueError("projective rectification impossible: a frustum corner ray is parallel to the light")
        a, b, angle = widest_pair(xy)
        if angle >= math.pi - 1e-9:
            raise ValueError("projective rectification impossible: the view frustum surrounds the light direction "
                             "(its epipole or anti-epipole is in the image); use the non-linear rectification")
        bis = xy[a] / lengths[a] + xy[b] / lengths[b]
        bis /= np.linalg.norm(bis)
        # ---- step 3: rotate the light view about z so the bisectrix is +x ----
        ex = bis[0] * ex0 + bis[1] * ey0
        to_light = np.stack([ex, np.cross(ez, ex), ez])
        q = (camera.frustum_corners() - position) @ to_light.T
        # ---- step 4: light frustum along x around the camera frustum ----
        near, far = float(q[:, 0].min()), float(q[:, 0].max())
        if not near > 0.0:
            raise ValueError("projective rectification impossible: the view frustum reaches behind the camera as "
                             "seen along the light (epipole in the image); use the non-linear rectification")
        slope_y, slope_z = q[:, 1] / q[:, 0], q[:, 2] / q[:, 0]
        s_lo, s_hi = float(slope_y.min()), float(slope_y.max())
        if s_hi - s_lo <= 1e-12 * max(1.0, abs(s_hi)):
            s_lo, s_hi = s_lo - 1e-9, s_hi + 1e-9
        zmin, zmax = float(slope_z.min()), float(slope_z.max())
        if zmax - zmin <= 1e-12 * max(1.0, abs(zmax)):
            zmin, zmax = zmin - 1e-9, zmax + 1e-9
        return cls(position=position, to_light=to_light, corners=q, near=near, far=far, s_lo=s_lo, s_hi=s_hi,
                   zeta_min=zmin, zeta_max=zmax, guard_band=float(guard_band), half_angle=0.5 * angle,
                   rows=int(rows), cols=int(cols), regions=int(regions))

    @property
    def light_direction(self) -> np.ndarray:
        """Unit direction the light travels (light-view z axis)."""
        return self.to_light[2]

    @property
    def zeta_lo(self) -> float:
        """Guarded slope z/x of rectified depth 0."""
        return self.zeta_min - 0.5 * self.guard_band * (self.zeta_max - self.zeta_min)

    @property
    def zeta_hi(self) -> float:
        """Guarded slope z/x of rectified depth 1."""
        return self.zeta_max + 0.5 * self.guard_band * (self.zeta_max - self.zeta_min)

    def region_columns(self) -> np.ndarray:
        """(regions + 1,) first column of every region, then ``cols``."""
        return (np.arange(self.regions + 1) * self.cols) // self.regions

    def region_bounds(self) -> np.ndarray:
        """(regions + 1,) light-view x at the region boundaries, n (f/n)^(k/S) (geometric, Klehm 2014 Sec. 4.2)."""
        b = self.near * (self.far / self.near) ** (np.arange(self.regions + 1) / self.regions)
        b[0], b[-1] = self.near, self.far
        return b

    def world_to_view(self) -> np.ndarray:
        """(4, 4) world -> rectifying light view (rotation about the camera position)."""
        m = np.eye(4)
        m[:3, :3] = self.to_light
        m[:3, 3] = -self.to_light @ self.position
        return m

    def world_to_clip(self, region: int = 0) -> np.ndarray:
        """(4, 4) world -> clip matrix of region ``region`` (the whole frustum when regions = 1)."""
        if not 0 <= region < self.regions:
            raise ValueError(f"region must lie in [0, {self.regions}), got {region}")
        b = self.region_bounds()
        return projection_matrix(b[region], b[region + 1], self.s_lo, self.s_hi, self.zeta_lo,
                                 self.zeta_hi) @ self.world_to_view()

    def params(self) -> ProjectiveRectParams:
        """Kernel-side parameters (:class:`ProjectiveRectParams`)."""
        p = ProjectiveRectParams()
        p.origin = wp.vec3(*self.position)
        p.to_light = wp.mat33(*self.to_light.ravel())
        p.near = float(self.near)
        p.log_ratio = float(math.log(self.far / self.near))
        p.regions = int(self.regions)
        p.s_hi = float(self.s_hi)
        p.s_span = float(self.s_hi - self.s_lo)
        p.zeta_lo = float(self.zeta_lo)
        p.zeta_span = float(self.zeta_hi - self.zeta_lo)
        p.rows = int(self.rows)
        p.cols = int(self.cols)
        return p

    def column_to_x(self, column) -> np.ndarray:
        """Light-view x at continuous global column coordinates (0 = left edge of column 0, cols = far)."""
        c = np.asarray(column, dtype=np.float64)
        starts = self.region_columns()
        b = self.region_bounds()
        k = np.clip(np.searchsorted(starts, c, side="right") - 1, 0, self.regions - 1)
        n, f = b[k], b[k + 1]
        u_local = (c - starts[k]) / (starts[k + 1] - starts[k])
        return f * n / (f - u_local * (f - n))

    def x_to_column(self, x) -> np.ndarray:
        """Continuous global column coordinate of light-view x > 0 (inverse of :meth:`column_to_x`)."""
        x = np.maximum(np.asarray(x, dtype=np.float64), 1e-6 * self.near)
        starts = self.region_columns()
        b = self.region_bounds()
        if self.regions > 1:
            k = np.floor(self.regions * np.log(x / self.near) / math.log(self.far / self.near)).astype(np.int64)
            k = np.clip(k, 0, self.regions - 1)
        else:
            k = np.zeros(x.shape, np.int64)
        n, f = b[k], b[k + 1]
        return starts[k] + f * (x - n) / ((f - n) * x) * (starts[k + 1] - starts[k])

    def world_to_rectified(self, points) -> np.ndarray:
        """Rectified (u, v, depth) of world points, shape (..., 3) -> (..., 3) float64 (see the module doc)."""
        p = np.asarray(points, dtype=np.float64)
        if p.shape[-1] != 3:
            raise ValueError(f"points must have shape (..., 3), got {p.shape}")
        q = (p - self.position) @ self.to_light.T
        qx = np.maximum(q[..., 0], 1e-6 * self.near)
        u = self.x_to_column(qx) / self.cols
        v = (self.s_hi - q[..., 1] / qx) / (self.s_hi - self.s_lo)
        depth = (q[..., 2] / qx - self.zeta_lo) / (self.zeta_hi - self.zeta_lo)
        return np.stack([u, v, depth], axis=-1)

    def rectified_to_world(self, coords) -> np.ndarray:
        """World points of rectified (u, v, depth), shape (..., 3) (u in [0, 1])."""
        c = np.asarray(coords, dtype=np.float64)
        if c.shape[-1] != 3:
            raise ValueError(f"coords must have shape (..., 3), got {c.shape}")
        qx = self.column_to_x(c[..., 0] * self.cols)
        sy = self.s_hi - c[..., 1] * (self.s_hi - self.s_lo)
        sz = self.zeta_lo + c[..., 2] * (self.zeta_hi - self.zeta_lo)
        q = np.stack([qx, qx * sy, qx * sz], axis=-1)
        return self.position + q @ self.to_light

    def row_slopes(self) -> np.ndarray:
        """Slope y/x of every row centre, shape (rows,)."""
        return self.s_hi - (np.arange(self.rows) + 0.5) / self.rows * (self.s_hi - self.s_lo)

    def slice_depth_slope_range(self, slope) -> tuple[np.ndarray, np.ndarray]:
        """Unguarded range (lo, hi) of the depth slope z/x of the frustum's view rays in the slice(s) y/x = ``slope``
        (any shape); slices that miss the frustum's cone of directions get the global bounds."""
        s = np.asarray(slope, dtype=np.float64)
        quad = self.corners[4:][[0, 1, 3, 2]]  # far-plane corners in cyclic order
        lo = np.full(s.shape, np.inf)
        hi = np.full(s.shape, -np.inf)
        for a in range(4):
            qa, qb = quad[a], quad[(a + 1) % 4]
            da = qa[1] - s * qa[0]
            db = qb[1] - s * qb[0]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.where(da != db, da / (da - db), 0.0)
            ok = (t >= -1e-12) & (t <= 1.0 + 1e-12)
            t = np.clip(t, 0.0, 1.0)
            p = qa + t[..., None] * (qb - qa)
            zeta = p[..., 2] / p[..., 0]
            lo = np.where(ok, np.minimum(lo, zeta), lo)
            hi = np.where(ok, np.maximum(hi, zeta), hi)
        empty = ~(lo <= hi)
        return np.where(empty, self.zeta_min, lo), np.where(empty, self.zeta_max, hi)


# ---- host side: rasterization straight into the rectified map ---------------------------------------------


def rasterize_rectified(rect: ProjectiveRectification, vertices, triangles, *, opacity=None, device=None,
                        threads: int | None = None):
    """Rasterize a mesh (``vertices`` (N, 3), ``triangles`` (T, 3)) straight into the rectified blocker-depth map
    (Klehm 2014 Sec. 4.2): one pass per region, depth clamped, no near-plane clipping; (rows, cols) float32 depth in
    [0, 1], 1 where empty. With an ``opacity`` per triangle, a :class:`~.taps.SparseRectifiedDepth` by depth peeling
    (z_1 the nearest caster, z_2 the opaque one, w_2 = T). ``threads``: the rasterizer's CPU workers."""
    from ...shadows import translucency

    device = default_device(device)
    points = raster.as_points(vertices, device)  # uploaded once for all regions
    translucent = opacity is not None and translucency.has_translucent(opacity)
    maps = [np.ones((rect.rows, rect.cols), np.float32) for _ in range(3 if translucent else 1)]
    starts = rect.region_columns()

    def rectified(z):
        return np.where(np.isfinite(z), 0.5 * z + 0.5, 1.0)

    for k in range(rect.regions):
        width = int(starts[k + 1] - starts[k])
        cols = slice(starts[k], starts[k + 1])
        if translucent:
            nearest, opaque, passed = translucency.translucent_depths(
                points, triangles, opacity, rect.world_to_clip(k), width, rect.rows, clamp_depth=True,
                clip_near=False, device=device)
            maps[0][:, cols], maps[1][:, cols], maps[2][:, cols] = rectified(nearest), rectified(opaque), passed
            continue
        r = raster.rasterize(points, triangles, rect.world_to_clip(k), width, rect.rows, clamp_depth=True,
                             clip_near=False, device=device, threads=threads)
        maps[0][:, cols] = rectified(r.ndc_depth[0])
    z1, *rest = (wp.array(a, dtype=wp.float32, device=device) for a in maps)
    if not translucent:
        return z1
    return SparseRectifiedDepth(z1=z1, z2=rest[0], w2=rest[1])


def cross_ratio_factors(rect: ProjectiveRectification) -> tuple[np.ndarray, np.ndarray]:
    """(d, first_step), (regions,) each: Eq. 12's growth factor, the ratio of the distances between a region's first
    three texel centres (independent of row and depth), and its first step in light-view x (Klehm 2014 Sec. 4.2)."""
    starts = rect.region_columns()[:-1]
    c = starts[:, None] + np.array([0.5, 1.5, 2.5])[None, :]
    rows = np.full(c.shape, 0.5)
    world = rect.rectified_to_world(np.stack([c / rect.cols, rows, rows], axis=-1))
    d1 = np.linalg.norm(world[:, 1] - world[:, 0], axis=-1)
    d2 = np.linalg.norm(world[:, 2] - world[:, 1], axis=-1)
    dirs = (world[:, 0] - rect.position) @ rect.to_light.T
    per_x = np.linalg.norm(dirs, axis=-1) / dirs[:, 0]  # world length per unit light-view x at that depth
    return d2 / d1, d1 / per_x


def column_lengths(rect: ProjectiveRectification, model: str = "exact") -> np.ndarray:
    """(cols,) light-view x width of every column (times a row's ``length_scale``: world lengths). ``model``:
    ``"exact"`` X(i + 1) - X(i), or ``"cross_ratio"`` Klehm 2014 Eq. 12's Delta d^i per region, a constant growth
    factor (:func:`cross_ratio_factors`)."""
    if model == "exact":
        return np.diff(rect.column_to_x(np.arange(rect.cols + 1, dtype=np.float64)))
    if model != "cross_ratio":
        raise ValueError(f"model must be 'exact' or 'cross_ratio', got {model!r}")
    d, first = cross_ratio_factors(rect)
    starts = rect.region_columns()
    out = np.empty(rect.cols)
    for k in range(rect.regions):
        i = np.arange(starts[k + 1] - starts[k], dtype=np.float64)
        out[starts[k]:starts[k + 1]] = first[k] * d[k] ** i
    return out


# ---- host side: automatic choice ---------------------------------------------------------------------------


def epipole_distance(camera, light_direction) -> tuple[float, str]:
    """(distance, ``"light"``, ``"anti-light"`` or ``"none"``) of the nearer epipole in front of the camera from the
    image, in half image heights on the image plane (NDC y units; 0: inside, +inf: none in front)."""
    right, up, fwd = camera.basis
    t = math.tan(math.radians(camera.fov_y) / 2.0)
    a = camera.aspect
    best, name = math.inf, "none"
    for sign, label in ((-1.0, "light"), (1.0, "anti-light")):
        d = sign * normalize(light_direction)
        cz = float(d @ fwd)
        if cz <= 1e-12:
            continue
        ex, ey = float(d @ right) / (cz * t), float(d @ up) / (cz * t)  # image plane in NDC-y units
        dist = math.hypot(max(abs(ex) - a, 0.0), max(abs(ey) - 1.0, 0.0))
        if dist < best:
            best, name = dist, label
    return best, name


@dataclass(frozen=True)
class RectificationChoice:
    """Which rectification :func:`choose_rectification` picked, and why."""

    kind: str  # "projective" or "nonlinear"
    reason: str
    epipole_distance: float  # in half image heights (see :func:`epipole_distance`)


def choose_rectification(camera, light_direction, requested: str = "auto",
                         margin: float = EPIPOLE_MARGIN, weights_per_ray: bool = False) -> RectificationChoice:
    """Pick the projective or the non-linear rectification (Klehm 2014 Sec. 4.2), the reason logged.

    ``requested`` ``auto`` takes projective when every epipole in front of the camera lies at least ``margin`` half
    image heights outside the image (:func:`epipole_distance`; nearer, its slopes blow up), else non-linear; with
    ``weights_per_ray`` always non-linear (uneven columns cannot weight each ray). An impossible ``projective`` falls
    back with a warning.
    """
    if requested not in ("auto", "projective", "nonlinear"):
        raise ValueError(f"rectification must be 'auto', 'projective' or 'nonlinear', got {requested!r}")
    if not (np.isfinite(margin) and margin >= 0.0):
        raise ValueError(f"epipole margin must be finite and >= 0, got {margin}")
    dist, which = epipole_distance(camera, light_direction)
    where = "no epipole in front of the camera" if which == "none" else \
        f"{which} epipole {dist:.3g} half image heights outside the image" if dist > 0.0 else \
        f"{which} epipole inside the image"
    level = logging.INFO
    if requested == "nonlinear":
        kind, reason = "nonlinear", f"non-linear rectification requested ({where})"
    elif requested == "projective":
        if dist > 0.0:
            kind, reason = "projective", f"projective rectification requested ({where})"
        else:
            kind, reason = "nonlinear", f"projective rectification impossible ({where}): non-linear used instead"
            level = logging.WARNING
    elif dist < margin:
        kind, reason = "nonlinear", f"auto: non-linear ({where}, threshold {margin:g})"
    elif weights_per_ray:
        kind, reason = "nonlinear", f"auto: non-linear (per-ray weights need its even columns; {where})"
    else:
        kind, reason = "projective", f"auto: projective ({where}, threshold {margin:g})"
    logger.log(level, "fourier rectification: %s", reason)
    return RectificationChoice(kind=kind, reason=reason, epipole_distance=float(dist))
