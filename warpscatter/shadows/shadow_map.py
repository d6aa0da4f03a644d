"""Light-space shadow maps: fitting, rendering, hard and PCF lookups. A :class:`ShadowMap` stores per texel the
LINEAR light-space depth of the nearest caster (+inf empty; j from the top; outside: lit), orthographic for
directional lights, perspective for spots; with translucent casters also the opaque depth and transmittance
(:class:`TranslucentShadowDepths`). Contact PCF at the map's silhouette: docs/design/shadows-scene.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import warp as wp

from ..runtime.device import default_device, module_options
from ..scene.camera import look_at_basis, orthographic_matrix, perspective_matrix, view_matrix
from ..scene.lights import DirectionalLight

module_options()

SHADOW_ORTHOGRAPHIC = 0
SHADOW_PERSPECTIVE = 1
#: Fraction of the depth bias kept by :func:`shadow_pcf_contact`: the receiver-plane test leaves only float noise.
CONTACT_BIAS_FRACTION = wp.constant(0.05)
#: Texels beyond the PCF box searched for an empty texel (the map's silhouette) by :func:`shadow_pcf_surface`.
CONTACT_RING = wp.constant(1)


@wp.struct
class ShadowMapParams:
    """A shadow map's transform as kernels see it."""

    view_proj: wp.mat44  # world -> clip
    view: wp.mat44  # world -> light view (looks down -Z)
    width: int
    height: int
    texel_world: float  # texel size at unit depth (perspective) or everywhere (orthographic)
    perspective: int


@dataclass
class ShadowMap:
    """Linear depth (H, W) float32 of the nearest caster (+inf empty), its float64 4x4 transforms and, with
    translucent casters, ``opaque_depth`` and ``transmittance`` (H, W)."""

    depth: np.ndarray
    view: np.ndarray
    projection: np.ndarray
    perspective: bool
    texel_world: float
    opaque_depth: np.ndarray | None = None
    transmittance: np.ndarray | None = None
    #: (name, device) -> the array uploaded once per frame for every kernel that reads it (the maps are not changed
    #: after they are built)
    _uploads: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def translucent(self) -> bool:
        return self.transmittance is not None

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

    def _upload(self, name: str, device) -> wp.array:
        key = (name, default_device(device))
        if key not in self._uploads:
            self._uploads[key] = wp.array(getattr(self, name), dtype=wp.float32, device=key[1])
        return self._uploads[key]

    def device_depth(self, device=None) -> wp.array:
        """:attr:`depth` on ``device``, uploaded on first use."""
        return self._upload("depth", device)

    def device_layers(self, depth: wp.array | None = None, device=None) -> TranslucentShadowDepths:
        """The :class:`TranslucentShadowDepths` kernels read (1x1 placeholders without translucent casters)."""
        device = default_device(device)
        t = TranslucentShadowDepths()
        t.depth = depth if depth is not None else self.device_depth(device)
        if self.translucent:
            t.opaque = self._upload("opaque_depth", device)
            t.transmittance = self._upload("transmittance", device)
        else:
            t.opaque = t.transmittance = wp.ones((1, 1), dtype=wp.float32, device=device)
        return t


def _box_corners(lo, hi) -> np.ndarray:
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def fit_directional(camera, direction, scene_bounds, resolution, depth_bounds=None) -> tuple[np.ndarray, np.ndarray,
                                                                                               float]:
    """Fit an orthographic light view to the camera frustum and the scene's casters.

    Args:
        camera: the :class:`~warpscatter.scene.camera.Camera`.
        direction: unit travel direction of the light.
        scene_bounds: (min, max) world bounds of the casters.
        resolution: (width, height) of the map in texels.
        depth_bounds: (min, max) world bounds the far plane reaches too (the receivers); None: ``scene_bounds``.

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

    # the frustum from its apex: view rays start at the camera (t = 0), not at the near plane (design notes)
    frustum = to_light(camera.frustum_corners(near=0.0))
    scene_l = to_light(scene_pts)
    fx0, fy0 = frustum[:, 0].min(), frustum[:, 1].min()
    fx1, fy1 = frustum[:, 0].max(), frustum[:, 1].max()
    sx0, sy0 = scene_l[:, 0].min(), scene_l[:, 1].min()
    sx1, sy1 = scene_l[:, 0].max(), scene_l[:, 1].max()
    x0, x1 = max(fx0, sx0), min(fx1, sx1)
    y0, y1 = max(fy0, sy0), min(fy1, sy1)
    if not (x1 > x0 and y1 > y0):
        x0, x1, y0, y1 = sx0, sx1, sy0, sy1
    pad = 1e-3 * radius
    if x1 - x0 < pad:
        x0, x1 = 0.5 * (x0 + x1) - pad, 0.5 * (x0 + x1) + pad
    if y1 - y0 < pad:
        y0, y1 = 0.5 * (y0 + y1) - pad, 0.5 * (y0 + y1) + pad
    w, h = resolution
    mx, my = (x1 - x0) / w, (y1 - y0) / h
    x0, x1, y0, y1 = x0 - mx, x1 + mx, y0 - my, y1 + my
    # view looks down -Z, depth = -z
    d = -scene_l[:, 2]
    d_far = d.max() if depth_bounds is None else max(d.max(), float(-to_light(_box_corners(*depth_bounds))[:, 2].min()))
    near, far = max(d.min() - 1e-3 * radius, 1e-4), d_far + 1e-3 * radius
    proj = orthographic_matrix(x0, x1, y0, y1, near, far)
    return view, proj, float(max((x1 - x0) / w, (y1 - y0) / h))


def render_shadow_map(scene, resolution, device=None, max_translucent_layers: int | None = None) -> ShadowMap:
    """Rasterize the scene's casters into the light's shadow map, fitted to them.

    Args:
        scene: a :class:`~warpscatter.scene.Scene`; ``receiver_only`` materials are left out.
        resolution: int or (width, height) in texels.
        device: Warp device.
        max_translucent_layers: most translucent fragments per texel (:data:`~.translucency.DEFAULT_MAX_LAYERS`).
    """
    from ..raster.rasterizer import linearize_depth, rasterize_linear_depth
    from . import translucency

    w, h = (resolution, resolution) if np.isscalar(resolution) else tuple(resolution)
    every_bound = scene.bounds()
    scene = scene.casters()
    light = scene.light
    bounds = scene.bounds()
    if isinstance(light, DirectionalLight):
        view, proj, texel = fit_directional(scene.camera, light.direction, bounds, (w, h), depth_bounds=every_bound)
        perspective = False
    else:
        lo, hi = every_bound
        reach = np.linalg.norm(np.maximum(np.abs(hi - light.position), np.abs(lo - light.position))) + 1.0
        near = max(1e-3, 1e-4 * reach)
        view = view_matrix(light.position, *light.basis())
        proj = perspective_matrix(2.0 * light.cone_deg, 1.0, near, reach)
        texel = 2.0 * np.tan(np.radians(light.cone_deg)) / w
        perspective = True
    opacity = translucency.triangle_opacity(scene)
    if scene.triangle_count == 0:
        depth = np.full((h, w), np.inf, np.float32)
    elif translucency.has_translucent(opacity):
        layers = translucency.DEFAULT_MAX_LAYERS if max_translucent_layers is None else int(max_translucent_layers)
        nearest, opaque, passed = translucency.translucent_depths(
            scene.vertices, scene.triangles, opacity, proj @ view, w, h, max_layers=layers,
            clamp_depth=not perspective, device=device)

        return ShadowMap(depth=linearize_depth(nearest, proj).astype(np.float32), view=view, projection=proj,
                         perspective=perspective, texel_world=texel,
                         opaque_depth=linearize_depth(opaque, proj).astype(np.float32), transmittance=passed)
    else:
        depth = rasterize_linear_depth(scene.vertices, scene.triangles, proj @ view, proj, w, h,
                                       clamp_depth=not perspective, device=device)
    return ShadowMap(depth=depth, view=view, projection=proj, perspective=perspective, texel_world=texel)


@wp.func
def shadow_coords(sm: ShadowMapParams, x: wp.vec3) -> wp.vec3:
    """(u, v, depth) of world point x: texture coords in [0,1] (v down) and linear light-space depth."""
    c = sm.view_proj * wp.vec4(x[0], x[1], x[2], 1.0)
    pv = sm.view * wp.vec4(x[0], x[1], x[2], 1.0)
    w = c[3]
    if w <= 0.0:
        return wp.vec3(-1.0, -1.0, -pv[2])
    return wp.vec3(0.5 * c[0] / w + 0.5, 0.5 - 0.5 * c[1] / w, -pv[2])


@wp.struct
class TranslucentShadowDepths:
    """A shadow map with translucent casters as the look-ups read it (:meth:`ShadowMap.device_layers`)."""

    depth: wp.array2d(dtype=wp.float32)  # nearest caster
    opaque: wp.array2d(dtype=wp.float32)  # nearest opaque caster
    transmittance: wp.array2d(dtype=wp.float32)  # of the translucent casters in front of it


@wp.func
def map_width(depth_map: wp.array2d(dtype=wp.float32)) -> int:
    """Texel columns of a shadow map's depths (plain array or :class:`TranslucentShadowDepths`)."""
    return depth_map.shape[1]


@wp.func
def map_width(depth_map: TranslucentShadowDepths) -> int:  # noqa: F811
    return depth_map.depth.shape[1]


@wp.func
def map_height(depth_map: wp.array2d(dtype=wp.float32)) -> int:
    """Texel rows of a shadow map's depths."""
    return depth_map.shape[0]


@wp.func
def map_height(depth_map: TranslucentShadowDepths) -> int:  # noqa: F811
    return depth_map.depth.shape[0]


@wp.func
def texel_depth(depth_map: wp.array2d(dtype=wp.float32), j: int, i: int) -> float:
    """Linear depth of the nearest caster in texel (i, j) (+inf: empty)."""
    return depth_map[j, i]


@wp.func
def texel_depth(depth_map: TranslucentShadowDepths, j: int, i: int) -> float:  # noqa: F811
    return depth_map.depth[j, i]


@wp.func
def texel_blocked(depth_map: wp.array2d(dtype=wp.float32), j: int, i: int, d: float, bias: float) -> float:
    """Light reaching depth d behind the nearest caster of texel (i, j): 0 for a plain map."""
    return 0.0


@wp.func
def texel_blocked(depth_map: TranslucentShadowDepths, j: int, i: int, d: float, bias: float) -> float:  # noqa: F811
    if d <= depth_map.opaque[j, i] + bias:
        return depth_map.transmittance[j, i]
    return 0.0


@wp.func
def shadow_texel_lit(depth_map: Any, i: int, j: int, d: float, bias: float) -> float:
    """1 if depth d is not behind texel (i, j)'s caster or (i, j) is outside; else 0 or the transmittance."""
    if i < 0 or j < 0 or i >= map_width(depth_map) or j >= map_height(depth_map):
        return 1.0
    if d <= texel_depth(depth_map, j, i) + bias:
        return 1.0
    return texel_blocked(depth_map, j, i, d, bias)


@wp.func
def nearest_texel(sm: ShadowMapParams, c: wp.vec3):
    """(i, j) of the texel holding c = (u, v, depth) of :func:`shadow_coords`, or (-1, -1) outside."""
    if c[0] < 0.0 or c[0] >= 1.0 or c[1] < 0.0 or c[1] >= 1.0:
        return -1, -1
    return int(c[0] * float(sm.width)), int(c[1] * float(sm.height))


@wp.func
def shadow_visibility_at(sm: ShadowMapParams, depth_map: Any, c: wp.vec3, bias: float) -> float:
    """Hard visibility (nearest texel) at c = (u, v, depth); 1 = lit. ``bias`` in world units."""
    i, j = nearest_texel(sm, c)
    if i < 0:
        return 1.0
    return shadow_texel_lit(depth_map, i, j, c[2], bias)


@wp.func
def shadow_visibility(sm: ShadowMapParams, depth_map: wp.array2d(dtype=wp.float32), x: wp.vec3, bias: float) -> float:
    """Hard shadow-map visibility of world point x (nearest texel); 1 = lit. ``bias`` in world units."""
    return shadow_visibility_at(sm, depth_map, shadow_coords(sm, x), bias)


@wp.func
def orthographic_ray_coords(sm: ShadowMapParams, origin: wp.vec3, d: wp.vec3):
    """(c0, dc) with :func:`shadow_coords` (origin + t d) = c0 + t dc on an orthographic map."""
    c = sm.view_proj * wp.vec4(origin[0], origin[1], origin[2], 1.0)
    cd = sm.view_proj * wp.vec4(d[0], d[1], d[2], 0.0)
    pv = sm.view * wp.vec4(origin[0], origin[1], origin[2], 1.0)
    pd = sm.view * wp.vec4(d[0], d[1], d[2], 0.0)
    return wp.vec3(0.5 * c[0] + 0.5, 0.5 - 0.5 * c[1], -pv[2]), wp.vec3(0.5 * cd[0], -0.5 * cd[1], -pd[2])


#: Ramp width (texels) of :func:`narrowed_offset`: narrower than bilinear (1) keeps silhouettes sharp (design notes).
PCF_RAMP_TEXELS = wp.constant(0.75)


@wp.func
def narrowed_offset(frac: float, ramp: float) -> float:
    """Weight of the second of two texels at ``frac`` (0-1) past the first's centre, ramping over ``ramp`` texels
    around their border (``ramp`` 1: bilinear)."""
    return wp.clamp((frac - 0.5) / ramp + 0.5, 0.0, 1.0)


@wp.func
def texel_corner(sm: ShadowMapParams, c: wp.vec3):
    """Bilinear frame of c = (u, v, depth): top-left texel (i0, j0) of the 2 x 2 around c and c's offset past it."""
    fx = c[0] * float(sm.width) - 0.5
    fy = c[1] * float(sm.height) - 0.5
    i0 = int(wp.floor(fx))
    j0 = int(wp.floor(fy))
    return i0, j0, fx - float(i0), fy - float(j0)


@wp.func
def narrowed_pcf_at(sm: ShadowMapParams, depth_map: Any, c: wp.vec3, bias: float, ramp: float) -> float:
    """2 x 2 PCF at c = (u, v, depth) with :func:`narrowed_offset` weights; 1 = lit."""
    i0, j0, fx, fy = texel_corner(sm, c)
    ax = narrowed_offset(fx, ramp)
    ay = narrowed_offset(fy, ramp)
    top = (1.0 - ax) * shadow_texel_lit(depth_map, i0, j0, c[2], bias) + ax * shadow_texel_lit(depth_map, i0 + 1, j0,
                                                                                              c[2], bias)
    bottom = ((1.0 - ax) * shadow_texel_lit(depth_map, i0, j0 + 1, c[2], bias)
              + ax * shadow_texel_lit(depth_map, i0 + 1, j0 + 1, c[2], bias))
    return (1.0 - ay) * top + ay * bottom


@wp.func
def box_tap_weight(d: int, lo: int, hi: int, frac: float) -> float:
    """Weight of tap d in [lo, hi] of a PCF box centred ``frac`` past tap 0: 1 inside, 1 - frac / frac at the ends."""
    if d == lo:
        return 1.0 - frac
    if d == hi:
        return frac
    return 1.0


@wp.func
def shadow_pcf(sm: ShadowMapParams, depth_map: Any, x: wp.vec3, bias: float, filter_px: int) -> float:
    """Percentage-closer filtering over a filter_px x filter_px texel box, bilinearly weighted; 1 = lit."""
    return shadow_pcf_at(sm, depth_map, shadow_coords(sm, x), bias, filter_px)


@wp.func
def shadow_pcf_at(sm: ShadowMapParams, depth_map: Any, c: wp.vec3, bias: float, filter_px: int) -> float:
    """:func:`shadow_pcf` at map coordinates c = (u, v, depth) of :func:`shadow_coords`."""
    i0, j0, ax, ay = texel_corner(sm, c)
    r = filter_px / 2
    lo = -r
    hi = filter_px - r
    total = float(0.0)
    wsum = float(0.0)
    for dj in range(lo, hi + 1):
        wy = box_tap_weight(dj, lo, hi, ay)
        for di in range(lo, hi + 1):
            wx = box_tap_weight(di, lo, hi, ax)
            wgt = wx * wy
            total += wgt * shadow_texel_lit(depth_map, i0 + di, j0 + dj, c[2], bias)
            wsum += wgt
    return total / wp.max(wsum, 1.0e-12)


@wp.func
def shadow_texel_coords(sm: ShadowMapParams, x: wp.vec3) -> wp.vec3:
    """(fx, fy, depth) of x: map coordinates in texels (centre of (i, j) at (i, j)) and linear depth."""
    c = shadow_coords(sm, x)
    return wp.vec3(c[0] * float(sm.width) - 0.5, c[1] * float(sm.height) - 0.5, c[2])


@wp.func
def receiver_plane_gradient(sm: ShadowMapParams, x: wp.vec3, n: wp.vec3, c: wp.vec3) -> wp.vec2:
    """Depth change per texel (map x, y) of the plane through x with normal n, at c; 0 if seen edge-on."""
    a = wp.vec3(1.0, 0.0, 0.0)
    if wp.abs(n[0]) > 0.9:
        a = wp.vec3(0.0, 1.0, 0.0)
    t1 = wp.normalize(wp.cross(n, a))
    t2 = wp.cross(n, t1)
    h = sm.texel_world
    if sm.perspective != 0:
        h = sm.texel_world * wp.max(c[2], 1.0e-6)
    e1 = shadow_texel_coords(sm, x + t1 * h) - c
    e2 = shadow_texel_coords(sm, x + t2 * h) - c
    det = e1[0] * e2[1] - e2[0] * e1[1]
    if not (wp.abs(det) > 1.0e-6):
        return wp.vec2(0.0, 0.0)
    return wp.vec2((e1[2] * e2[1] - e2[2] * e1[1]) / det, (e2[2] * e1[0] - e1[2] * e2[0]) / det)


@wp.func
def near_map_silhouette(depth_map: Any, i0: int, j0: int, lo: int, hi: int) -> bool:
    """True when a texel (i0 + di, j0 + dj), di, dj in [lo, hi], inside the map is empty (+inf)."""
    for dj in range(lo, hi + 1):
        j = j0 + dj
        if j >= 0 and j < map_height(depth_map):
            for di in range(lo, hi + 1):
                i = i0 + di
                if i >= 0 and i < map_width(depth_map):
                    if not wp.isfinite(texel_depth(depth_map, j, i)):
                        return True
    return False


@wp.func
def texel_on_outline(depth_map: Any, j: int, i: int) -> bool:
    """True when a 4-neighbour of texel (i, j) inside the map is empty."""
    w = map_width(depth_map)
    h = map_height(depth_map)
    if i > 0 and not wp.isfinite(texel_depth(depth_map, j, i - 1)):
        return True
    if i + 1 < w and not wp.isfinite(texel_depth(depth_map, j, i + 1)):
        return True
    if j > 0 and not wp.isfinite(texel_depth(depth_map, j - 1, i)):
        return True
    if j + 1 < h and not wp.isfinite(texel_depth(depth_map, j + 1, i)):
        return True
    return False


@wp.func
def shadow_pcf_contact(sm: ShadowMapParams, depth_map: Any, x: wp.vec3, n: wp.vec3, bias: float,
                       filter_px: int) -> float:
    """PCF of caster point x (normal n) at a contact on the map's silhouette: the :func:`shadow_pcf` box without
    empty and out-of-map texels, each compared against the receiver's plane; outline texels count only when no other
    is left (their centres can lie just inside the occluder). ``bias`` in world units; 1 = lit."""
    c = shadow_texel_coords(sm, x)
    g = receiver_plane_gradient(sm, x, n, c)
    i0 = int(wp.floor(c[0]))
    j0 = int(wp.floor(c[1]))
    ax = c[0] - float(i0)
    ay = c[1] - float(j0)
    r = filter_px / 2
    lo = -r
    hi = filter_px - r
    total = float(0.0)
    wsum = float(0.0)
    outline_total = float(0.0)
    outline_wsum = float(0.0)
    for dj in range(lo, hi + 1):
        wy = box_tap_weight(dj, lo, hi, ay)
        j = j0 + dj
        for di in range(lo, hi + 1):
            wx = box_tap_weight(di, lo, hi, ax)
            i = i0 + di
            if i < 0 or j < 0 or i >= map_width(depth_map) or j >= map_height(depth_map):
                continue
            s = texel_depth(depth_map, j, i)
            if not wp.isfinite(s):
                continue
            lit = float(1.0)
            d = c[2] + g[0] * (float(i) - c[0]) + g[1] * (float(j) - c[1])
            if d > s + bias:
                lit = texel_blocked(depth_map, j, i, d, bias)
            wgt = wx * wy
            if texel_on_outline(depth_map, j, i):
                outline_total += wgt * lit
                outline_wsum += wgt
            else:
                total += wgt * lit
                wsum += wgt
    if wsum <= 1.0e-12:
        if outline_wsum <= 1.0e-12:
            return 1.0
        return outline_total / outline_wsum
    return total / wsum


#: Largest factor of the slope-scaled normal offset on perspective maps (:func:`shadow_pcf_surface`).
SLOPE_OFFSET_MAX = wp.constant(4.0)


@wp.func
def shadow_pcf_surface(sm: ShadowMapParams, depth_map: Any, x: wp.vec3, n: wp.vec3, normal_offset: float,
                       bias: float, filter_px: int, contact: int) -> float:
    """PCF visibility of surface point x with unit normal n facing the light; 1 = lit.

    :func:`shadow_pcf` of x moved ``normal_offset`` (world units; per unit depth on perspective maps, slope-scaled up
    to :data:`SLOPE_OFFSET_MAX`) along n with depth bias ``bias``; with ``contact`` (every receiver also casts) and an
    empty texel within :data:`CONTACT_RING` of the box, :func:`shadow_pcf_contact` instead."""
    offset = normal_offset
    depth_bias = bias
    if sm.perspective != 0:
        z = wp.max(shadow_coords(sm, x)[2], 0.0)
        offset = normal_offset * z
        depth_bias = bias * z
        # a texel spans 1 / cos(incidence) of the surface: slope-scale the offset against acne at grazing angles
        p = wp.transform_point(sm.view, x)
        nv = wp.transform_vector(sm.view, n)
        cos_in = -wp.dot(nv, p) / wp.max(wp.length(p), 1.0e-30)
        offset = offset * wp.clamp(1.0 / wp.max(cos_in, 1.0e-6), 1.0, SLOPE_OFFSET_MAX)
    if contact != 0:
        c = shadow_texel_coords(sm, x)
        if wp.isfinite(c[0]) and wp.isfinite(c[1]) and wp.abs(c[0]) < 1.0e6 and wp.abs(c[1]) < 1.0e6:
            r = filter_px / 2
            if near_map_silhouette(depth_map, int(wp.floor(c[0])), int(wp.floor(c[1])), -r - CONTACT_RING,
                                   filter_px - r + CONTACT_RING):
                return shadow_pcf_contact(sm, depth_map, x, n, depth_bias * CONTACT_BIAS_FRACTION, filter_px)
    return shadow_pcf(sm, depth_map, x + n * offset, depth_bias, filter_px)
