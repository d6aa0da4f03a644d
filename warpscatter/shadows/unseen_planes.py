"""Planar casters whose shadows fall where the camera sees nothing (warpscatter's, not in the papers): such a plane
(a ground under everything seen) only costs shadow-map resolution, so :func:`without_unseen_planes` marks it
``receiver_only`` in the scene the light's maps are built from (``render.scattering.shadow_map.skip_unseen_planes``).
The test is conservative; exact visibility keeps every plane. Rationale and figures: docs/design/shadows-scene.md.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import warp as wp

from ..runtime.device import module_options
from ..runtime.parallel import launch_rows
from ..scene.camera import CameraParams, pixel_ray_factors
from ..scene.lights import DirectionalLight

module_options()

#: Largest distance of a material's vertices from their best-fit plane, relative to the material's extent, for the
#: material to count as planar.
PLANE_TOLERANCE = 1e-5
#: Triangles of a material tested first: a curved mesh is told from a plane without reading all of it.
PLANE_PROBE_TRIANGLES = 64
#: Relative distance behind a plane still counted as on it (float32 rounding of its own pixels' distances).
SIDE_TOLERANCE = 1e-4


def caster_planes(scene) -> list[tuple[int, np.ndarray, float, np.ndarray, np.ndarray]]:
    """(material k, unit normal n, offset d, box min, box max) of every planar casting material n . x + d = 0."""
    mask = scene.caster_mask()
    vertices = np.asarray(scene.vertices)
    planes = []
    for k in range(len(scene.albedo)):
        tris = np.flatnonzero(mask & (scene.tri_material == k))
        if not len(tris):
            continue
        plane = triangles_plane(vertices, scene.triangles[tris[:PLANE_PROBE_TRIANGLES]])
        if plane is not None and len(tris) > PLANE_PROBE_TRIANGLES:
            plane = triangles_plane(vertices, scene.triangles[tris])
        if plane is not None:
            planes.append((int(k), *plane))
    return planes


def triangles_plane(vertices: np.ndarray, tris: np.ndarray):
    """(unit normal n, offset d, box min, box max) of the plane holding triangles ``tris``; None if not coplanar."""
    v = np.asarray(vertices[tris], np.float64)
    normals = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    areas = np.linalg.norm(normals, axis=1)
    if not len(areas) or areas.max() <= 0.0:
        return None
    n = normals[np.argmax(areas)] / areas.max()  # coplanar corners all lie in the largest triangle's plane
    corners = v.reshape(-1, 3)
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    offsets = corners @ n
    if offsets.max() - offsets.min() > PLANE_TOLERANCE * float((hi - lo).max()):
        return None
    return n, -float(offsets.mean()), lo, hi


def lit_side(light, n: np.ndarray, d: float, scale: float) -> float:
    """+1 or -1: the side of plane (n, d) the light comes from; 0 where the plane holds the light."""
    if isinstance(light, DirectionalLight):
        s = -float(n @ light.direction)
        return 0.0 if abs(s) < 1e-6 else float(np.sign(s))
    s = float(n @ np.asarray(light.position, np.float64)) + d
    return 0.0 if abs(s) < SIDE_TOLERANCE * scale else float(np.sign(s))


@wp.func
def along_light_to_plane(x: wp.vec3, n: wp.vec3, d: float, directional: int, light: wp.vec3) -> wp.vec3:
    """Where the light ray through x meets plane n . p + d = 0 (``light``: travel direction or light position)."""
    if directional != 0:
        return x - light * ((wp.dot(n, x) + d) / wp.dot(n, light))
    t = -(wp.dot(n, light) + d) / wp.dot(n, x - light)
    return light + t * (x - light)


@wp.func
def segment_meets_box(a: wp.vec3, b: wp.vec3, lo: wp.vec3, hi: wp.vec3) -> bool:
    """True if the segment a -> b meets the axis-aligned box [lo, hi] (slab test)."""
    t0 = float(0.0)
    t1 = float(1.0)
    for k in range(3):
        dk = b[k] - a[k]
        if dk == 0.0:
            if a[k] < lo[k] or a[k] > hi[k]:
                return False
        else:
            ta = (lo[k] - a[k]) / dk
            tb = (hi[k] - a[k]) / dk
            t0 = wp.max(t0, wp.min(ta, tb))
            t1 = wp.min(t1, wp.max(ta, tb))
    return t0 <= t1


@wp.kernel
def plane_shadow_seen_kernel(cam: CameraParams, distance: wp.array2d(dtype=wp.float32), n: wp.vec3, d: float,
                             camera_side: float, tol: float, directional: int, light: wp.vec3, box_lo: wp.vec3,
                             box_hi: wp.vec3, seen: wp.array(dtype=wp.int32), offset: int):
    """seen[row] = 1 where a view ray ends behind plane (n, d) (n towards the light) and its stretch behind the
    plane, carried along the light onto it, meets the material's box. One thread per row."""
    j = wp.tid() + offset
    a = wp.dot(n, cam.right)
    b = wp.dot(n, cam.up)
    c = wp.dot(n, cam.forward)
    yn = pixel_ray_factors(cam, 0.5, float(j) + 0.5)[1]
    x_lo = pixel_ray_factors(cam, 0.5, 0.5)[0]
    if wp.min(x_lo * a, -x_lo * a) + yn * b + c >= 0.0:  # n . (xn right + yn up + forward) is linear in xn
        return
    for i in range(cam.width):
        xn = pixel_ray_factors(cam, float(i) + 0.5, 0.5)[0]
        inv_length = 1.0 / wp.sqrt(xn * xn + yn * yn + 1.0)
        rate = (xn * a + yn * b + c) * inv_length  # the lit-side distance gained per unit along the ray
        s = distance[j, i]
        if camera_side + s * rate < -tol:
            # the stretch behind the plane, carried along the light, is the segment cross -> end'
            direction = (xn * cam.right + yn * cam.up + cam.forward) * inv_length
            cross = cam.position + (camera_side / -rate) * direction
            end = along_light_to_plane(cam.position + s * direction, n, d, directional, light)
            if segment_meets_box(cross, end, box_lo, box_hi):
                seen[j] = 1
                return


def plane_shadow_seen(scene, distance: wp.array, n: np.ndarray, d: float, box_lo: np.ndarray, box_hi: np.ndarray,
                      tol: float) -> bool:
    """True if plane (n, d), ``n`` towards the light, may shadow a point of some view ray."""
    cam = scene.camera
    camera_side = float(n @ cam.position) + d
    if camera_side < -tol:
        return True
    device = distance.device
    light = scene.light
    directional = isinstance(light, DirectionalLight)
    seen = wp.zeros(cam.height, dtype=wp.int32, device=device)
    pad = tol * np.abs(n)  # across the plane only: the segments lie in it
    launch_rows(plane_shadow_seen_kernel, cam.height,
                [cam.params(), distance, wp.vec3(*n), float(d), camera_side, float(tol), int(directional),
                 wp.vec3(*(light.direction if directional else light.position)), wp.vec3(*(box_lo - pad)),
                 wp.vec3(*(box_hi + pad)), seen], device=device)
    return bool(seen.numpy().any())


def without_unseen_planes(scene, distance: wp.array) -> tuple[object, list[int]]:
    """``scene`` with every planar caster that shadows nothing the camera sees marked ``receiver_only``, and the
    materials so marked.

    Args:
        scene: a :class:`~warpscatter.scene.Scene` with a directional, spot or point light.
        distance: the (H, W) float32 G-buffer distances (scene units, CONVENTIONS' ``s``) as a Warp array.
    """
    planes = caster_planes(scene)
    if not planes:
        return scene, []
    lo, hi = scene.bounds()
    scale = float(np.linalg.norm(hi - lo)) + 1e-6
    tol = None
    unseen = []
    for k, n, d, box_lo, box_hi in planes:
        side = lit_side(scene.light, n, d, scale)
        if side == 0.0:
            continue
        if tol is None:
            tol = SIDE_TOLERANCE * (float(distance.numpy().max()) + scale)
        if not plane_shadow_seen(scene, distance, side * n, side * d, box_lo, box_hi, tol):
            unseen.append(k)
    if not unseen:
        return scene, []
    receiver_only = (np.zeros(len(scene.albedo), bool) if scene.receiver_only is None
                     else np.array(scene.receiver_only, bool))
    receiver_only[unseen] = True
    return replace(scene, receiver_only=receiver_only), unseen


__all__ = ["PLANE_PROBE_TRIANGLES", "PLANE_TOLERANCE", "SIDE_TOLERANCE", "caster_planes", "lit_side",
           "plane_shadow_seen", "plane_shadow_seen_kernel", "triangles_plane", "without_unseen_planes"]
