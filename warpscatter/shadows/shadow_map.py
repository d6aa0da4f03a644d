"""Light-space shadow maps: fitting, rendering, hard and PCF lookups.

A :class:`ShadowMap` stores, per texel, the LINEAR light-space depth of the nearest caster: the
distance along the light's axis from the light's view origin (directional: an orthographic view
placed behind every caster; spot: the light position). Empty texels hold +inf.

* Directional lights get an orthographic map fitted to the camera's view frustum (its footprint in
  light space, intersected with the scene's bounds) and to the scene's casters: the depth range
  spans every caster, and the rasterizer's depth clamping keeps casters outside it in the map.
* Spot lights get a perspective map with the cone's square frustum (fov = 2 * cone half-angle).

Texel (i, j) has j from the TOP (NDC y = +1), as every image in warpscatter. A lookup outside the
map's xy footprint is lit (no caster was rasterized there).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from ..scene.camera import look_at_basis, orthographic_matrix, perspective_matrix, view_matrix
from ..scene.lights import DirectionalLight
from ..wpinit import default_device, module_options

module_options()

SHADOW_ORTHOGRAPHIC = 0
SHADOW_PERSPECTIVE = 1


@wp.struct
class ShadowMapParams:
    """A shadow map's transform as kernels see it."""

    view_proj: wp.mat44  # world -> clip
    view: wp.mat44  # world -> light view (looks down -Z)
    width: int
    height: int
    texel_world: float  # world size of one texel at unit depth (perspective) or everywhere (orthographic)
    perspective: int  # SHADOW_ORTHOGRAPHIC or SHADOW_PERSPECTIVE


@dataclass
class ShadowMap:
    """A rendered shadow map: linear depth (H, W) float32 (+inf empty) and its transforms (float64 4x4)."""

    depth: np.ndarray
    view: np.ndarray
    projection: np.ndarray
    perspective: bool
    texel_world: float

    @property
    def view_projection(self) -> np.ndarray:
        return self.projection @ self.view

    @property
    def shape(self) -> tuple[int, int]:
        return self.depth.shape

    def params(self) -> ShadowMapParams:
        p = ShadowMapParams()
        p.view_proj = wp.mat44(*self.view_projection.astype(np.float32).ravel())
        p.view = wp.mat44(*self.view.astype(np.float32).ravel())
        p.height, p.width = (int(s) for s in self.depth.shape)
        p.texel_world = float(self.texel_world)
        p.perspective = SHADOW_PERSPECTIVE if self.perspective else SHADOW_ORTHOGRAPHIC
        return p

    def device_depth(self, device=None) -> wp.array:
        return wp.array(self.depth, dtype=wp.float32, device=default_device(device))


def _box_corners(lo, hi) -> np.ndarray:
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def fit_directional(camera, direction, scene_bounds, resolution) -> tuple[np.ndarray, np.ndarray, float]:
    """Fit an orthographic light view to the camera frustum and the scene's casters.

    Args:
        camera: the :class:`~warpscatter.scene.camera.Camera`.
        direction: unit travel direction of the light.
        scene_bounds: (min, max) world bounds of all geometry.
        resolution: (width, height) of the map in texels.

    Returns:
        (view, projection, texel_world): float64 4x4 matrices and the world size of a texel (max of x, y).
    """
    direction = np.asarray(direction, float)
    up = np.array([0.0, 1.0, 0.0]) if abs(direction[1]) < 0.99 else np.array([1.0, 0.0, 0.0])
    lo, hi = (np.asarray(b, float) for b in scene_bounds)
    scene_pts = _box_corners(lo, hi)
    centre = 0.5 * (lo + hi)
    radius = 0.5 * np.linalg.norm(hi - lo) + 1e-3
    eye = centre - direction * (radius + 1.0)
    right, up2, fwd = look_at_basis(eye, eye + direction, up)
    view = view_matrix(eye, right, up2, fwd)

    def to_light(p):
        return (view[:3, :3] @ p.T).T + view[:3, 3]

    frustum = to_light(camera.frustum_corners())
    scene_l = to_light(scene_pts)
    # xy footprint: frustum box intersected with the scene box (outside the scene nothing casts)
    fx0, fy0 = frustum[:, 0].min(), frustum[:, 1].min()
    fx1, fy1 = frustum[:, 0].max(), frustum[:, 1].max()
    sx0, sy0 = scene_l[:, 0].min(), scene_l[:, 1].min()
    sx1, sy1 = scene_l[:, 0].max(), scene_l[:, 1].max()
    x0, x1 = max(fx0, sx0), min(fx1, sx1)
    y0, y1 = max(fy0, sy0), min(fy1, sy1)
    if not (x1 > x0 and y1 > y0):  # frustum sees no geometry: any valid box will do
        x0, x1, y0, y1 = sx0, sx1, sy0, sy1
    # a flat scene seen edge-on by the light has no extent along one axis: give the box a minimal size
    pad = 1e-3 * radius
    if x1 - x0 < pad:
        x0, x1 = 0.5 * (x0 + x1) - pad, 0.5 * (x0 + x1) + pad
    if y1 - y0 < pad:
        y0, y1 = 0.5 * (y0 + y1) - pad, 0.5 * (y0 + y1) + pad
    w, h = resolution
    # one texel of margin so lookups at the footprint's edge still find the border texels
    mx, my = (x1 - x0) / w, (y1 - y0) / h
    x0, x1, y0, y1 = x0 - mx, x1 + mx, y0 - my, y1 + my
    # depth range (view looks down -Z, depth = -z): every caster, slightly padded
    d = -scene_l[:, 2]
    near, far = max(d.min() - 1e-3 * radius, 1e-4), d.max() + 1e-3 * radius
    proj = orthographic_matrix(x0, x1, y0, y1, near, far)
    return view, proj, float(max((x1 - x0) / w, (y1 - y0) / h))


def render_shadow_map(scene, resolution, device=None) -> ShadowMap:
    """Rasterize the scene's casters into the light's shadow map, fitted to them.

    Args:
        scene: a :class:`~warpscatter.scene.Scene`; its ``receiver_only`` materials are left out
            (:meth:`~warpscatter.scene.Scene.casters`).
        resolution: int or (width, height) in texels.
        device: Warp device.
    """
    from ..raster import rasterize_linear_depth

    w, h = (resolution, resolution) if np.isscalar(resolution) else tuple(resolution)
    scene = scene.casters()
    light = scene.light
    bounds = scene.bounds()
    if isinstance(light, DirectionalLight):
        view, proj, texel = fit_directional(scene.camera, light.direction, bounds, (w, h))
        perspective = False
    else:
        lo, hi = bounds
        reach = np.linalg.norm(np.maximum(np.abs(hi - light.position), np.abs(lo - light.position))) + 1.0
        near = max(1e-3, 1e-4 * reach)
        view = view_matrix(light.position, *light.basis())
        proj = perspective_matrix(2.0 * light.cone_deg, 1.0, near, reach)
        texel = 2.0 * np.tan(np.radians(light.cone_deg)) / w
        perspective = True
    if scene.triangle_count == 0:  # nothing casts: every texel is empty
        depth = np.full((h, w), np.inf, np.float32)
    else:
        # linear depth resolved band by band with the scan (bitwise linearize_depth of the NDC depth, as float32)
        depth = rasterize_linear_depth(scene.vertices, scene.triangles, proj @ view, proj, w, h,
                                       clamp_depth=not perspective, device=device)
    return ShadowMap(depth=depth, view=view, projection=proj, perspective=perspective, texel_world=texel)


# ---- kernel-side lookups ---------------------------------------------------------------------------


@wp.func
def shadow_coords(sm: ShadowMapParams, x: wp.vec3) -> wp.vec3:
    """(u, v, depth) of world point x: texture coords in [0,1] (v down) and linear light-space depth."""
    c = sm.view_proj * wp.vec4(x[0], x[1], x[2], 1.0)
    pv = sm.view * wp.vec4(x[0], x[1], x[2], 1.0)
    w = c[3]
    if w <= 0.0:
        return wp.vec3(-1.0, -1.0, -pv[2])
    return wp.vec3(0.5 * c[0] / w + 0.5, 0.5 - 0.5 * c[1] / w, -pv[2])


@wp.func
def shadow_texel_lit(depth_map: wp.array2d(dtype=wp.float32), i: int, j: int, d: float, bias: float) -> float:
    """1 if depth d is not behind the caster stored in texel (i, j) (out-of-map texels are lit)."""
    if i < 0 or j < 0 or i >= depth_map.shape[1] or j >= depth_map.shape[0]:
        return 1.0
    if d <= depth_map[j, i] + bias:
        return 1.0
    return 0.0


@wp.func
def shadow_visibility_at(sm: ShadowMapParams, depth_map: wp.array2d(dtype=wp.float32), c: wp.vec3,
                         bias: float) -> float:
    """Hard shadow-map visibility at map coordinates c = (u, v, depth) of :func:`shadow_coords` (nearest texel;
    outside the map: lit); 1 = lit. ``bias`` in world units."""
    if c[0] < 0.0 or c[0] >= 1.0 or c[1] < 0.0 or c[1] >= 1.0:
        return 1.0
    i = int(c[0] * float(sm.width))
    j = int(c[1] * float(sm.height))
    return shadow_texel_lit(depth_map, i, j, c[2], bias)


@wp.func
def shadow_visibility(sm: ShadowMapParams, depth_map: wp.array2d(dtype=wp.float32), x: wp.vec3, bias: float) -> float:
    """Hard shadow-map visibility of world point x (nearest texel); 1 = lit. ``bias`` in world units."""
    return shadow_visibility_at(sm, depth_map, shadow_coords(sm, x), bias)


@wp.func
def orthographic_ray_coords(sm: ShadowMapParams, origin: wp.vec3, d: wp.vec3):
    """:func:`shadow_coords` along the ray origin + t d of an ORTHOGRAPHIC map (``perspective`` 0), where they
    are affine in t: returns (c0, dc) with coords(t) = c0 + t dc (equal to :func:`shadow_coords` up to float
    rounding)."""
    c = sm.view_proj * wp.vec4(origin[0], origin[1], origin[2], 1.0)
    cd = sm.view_proj * wp.vec4(d[0], d[1], d[2], 0.0)
    pv = sm.view * wp.vec4(origin[0], origin[1], origin[2], 1.0)
    pd = sm.view * wp.vec4(d[0], d[1], d[2], 0.0)
    return wp.vec3(0.5 * c[0] + 0.5, 0.5 - 0.5 * c[1], -pv[2]), wp.vec3(0.5 * cd[0], -0.5 * cd[1], -pd[2])


@wp.func
def shadow_pcf(sm: ShadowMapParams, depth_map: wp.array2d(dtype=wp.float32), x: wp.vec3, bias: float,
               filter_px: int) -> float:
    """Percentage-closer filtering over a filter_px x filter_px texel box, bilinearly weighted; 1 = lit."""
    c = shadow_coords(sm, x)
    fx = c[0] * float(sm.width) - 0.5
    fy = c[1] * float(sm.height) - 0.5
    i0 = int(wp.floor(fx))
    j0 = int(wp.floor(fy))
    ax = fx - float(i0)
    ay = fy - float(j0)
    r = filter_px / 2
    lo = -r
    hi = filter_px - r  # filter_px + 1 texel columns, bilinear weights at the two ends
    total = float(0.0)
    wsum = float(0.0)
    for dj in range(lo, hi + 1):
        wy = 1.0
        if dj == lo:
            wy = 1.0 - ay
        elif dj == hi:
            wy = ay
        for di in range(lo, hi + 1):
            wx = 1.0
            if di == lo:
                wx = 1.0 - ax
            elif di == hi:
                wx = ax
            wgt = wx * wy
            total += wgt * shadow_texel_lit(depth_map, i0 + di, j0 + dj, c[2], bias)
            wsum += wgt
    return total / wp.max(wsum, 1.0e-12)
