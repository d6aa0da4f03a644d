"""Peters 2017's spherical coordinates of a non-linear rectification, as kernels see them (Sec. 5.1.1).

Every camera view ray lies in ONE row, runs along the columns from the camera outward and has ONE depth. In light
view space (origin at the camera, z = the direction the light TRAVELS, CONVENTIONS.md; ``to_light``'s rows):

* r = sqrt(x^2 + y^2), the light ray's distance from the camera -> COLUMN, u = r / r_max;
* phi = atan2(y, x), the azimuth (epipolar slice) -> ROW, v in [0, 1];
* theta = atan2(r, z), the inclination from the camera -> DEPTH = (theta_hi - theta) / (theta_hi - theta_lo).

A view ray keeps phi and theta and has r = t sin(theta): a constant world step per column, (r_max / cols) /
sin(theta) (Klehm 2014 Sec. 3.2). A local light (:mod:`.local`) makes the column the angle at the light. Texel (row j,
column i) is centred at ((i + 0.5) / cols, (j + 0.5) / rows); the bounds come from :mod:`.bounds`.
"""

from __future__ import annotations

import warp as wp

from ...runtime.device import module_options
from ...runtime.fastmath import fast_atan2

module_options()


@wp.struct
class NonlinearRectParams:
    """A non-linear rectification as kernels see it (:class:`~.bounds.NonlinearRectification`)."""

    origin: wp.vec3  # camera position (world), origin of light view space
    to_light: wp.mat33  # world -> light view rotation; rows = light-view x, y, z (z = light travel dir)
    r_max: float  # distance from the light axis through the camera covered by u = 1 (world units)
    phi_mid: float  # azimuth of v = 0.5 (radians)
    phi_span: float  # azimuth range covered by v in [0, 1] (radians; 2 pi for the full circle)
    theta_hi: float  # guarded upper inclination bound = rectified depth 0 (radians)
    theta_len: float  # guarded inclination range = rectified depth 1 - depth 0 (radians)
    rows: int  # epipolar slices
    cols: int  # texels along a view ray
    full_circle: int  # 1 when phi covers the full circle (rows wrap around)
    light_distance: float  # local light: camera-light distance D (world units); 0 for a directional light
    psi_lo: float  # local light: the angle at the light of u = 0 (radians); r_max is then the angle span of u in [0, 1]


@wp.func
def world_to_rectified(rect: NonlinearRectParams, x: wp.vec3) -> wp.vec3:
    """Rectified (u, v, depth) of world point x (Peters 2017 Sec. 5.1.1): u = r / r_max (column),
    v = normalised azimuth (row), depth = normalised flipped inclination (pi - theta)."""
    q = rect.to_light * (x - rect.origin)
    r = wp.sqrt(q[0] * q[0] + q[1] * q[1])
    d = fast_atan2(q[1], q[0]) - rect.phi_mid
    d = d - 2.0 * wp.pi * wp.floor((d + wp.pi) / (2.0 * wp.pi))  # wrap into [-pi, pi)
    theta = fast_atan2(r, q[2])
    u = r / rect.r_max
    if rect.light_distance > 0.0:  # local light: the angle at the light from the baseline (.local)
        u = (fast_atan2(r, q[2] + rect.light_distance) - rect.psi_lo) / rect.r_max
    return wp.vec3(u, 0.5 + d / rect.phi_span, (rect.theta_hi - theta) / rect.theta_len)


@wp.func
def rectified_to_world(rect: NonlinearRectParams, c: wp.vec3) -> wp.vec3:
    """World point of rectified (u, v, depth); defined for inclinations strictly inside (0, pi)."""
    r = c[0] * rect.r_max
    phi = rect.phi_mid + (c[1] - 0.5) * rect.phi_span
    theta = rect.theta_hi - c[2] * rect.theta_len
    q = wp.vec3(r * wp.cos(phi), r * wp.sin(phi), r * wp.cos(theta) / wp.max(wp.sin(theta), 1.0e-12))
    return rect.origin + wp.transpose(rect.to_light) * q


@wp.func
def rectified_ray_depth(rect: NonlinearRectParams, direction: wp.vec3) -> float:
    """Constant rectified depth of the camera view ray with (unit or not) world direction ``direction``."""
    q = rect.to_light * direction
    theta = fast_atan2(wp.sqrt(q[0] * q[0] + q[1] * q[1]), q[2])
    return (rect.theta_hi - theta) / rect.theta_len


@wp.func
def light_ray_point(rect: NonlinearRectParams, u: float, v: float) -> wp.vec3:
    """World point of the light ray through rectified (u, v) closest to the camera (light-view z = 0)."""
    r = u * rect.r_max
    phi = rect.phi_mid + (v - 0.5) * rect.phi_span
    return rect.origin + wp.transpose(rect.to_light) * wp.vec3(r * wp.cos(phi), r * wp.sin(phi), 0.0)


@wp.func
def texel_light_ray(rect: NonlinearRectParams, i: int, j: int):
    """Column coordinate u of texel (column i, row j)'s centre and the point of its light ray closest to the camera
    (:func:`light_ray_point`)."""
    u = (float(i) + 0.5) / float(rect.cols)
    v = (float(j) + 0.5) / float(rect.rows)
    return u, light_ray_point(rect, u, v)


@wp.func
def rectified_blocker_depth(rect: NonlinearRectParams, u: float, z_b: float) -> float:
    """Rectified depth of a blocker at light-view distance z_b (along the light, from the light ray's point
    closest to the camera) on the light ray of column coordinate u, clamped to [0, 1] (Klehm 2014 Sec. 4.1:
    blockers in front of the frustum -> 0, behind it -> 1; both cast the same shadows into the frustum)."""
    theta_b = fast_atan2(u * rect.r_max, z_b)
    return wp.clamp((rect.theta_hi - theta_b) / rect.theta_len, 0.0, 1.0)
