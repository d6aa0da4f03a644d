"""Planar casters whose shadows fall where the camera sees nothing (warpscatter's, not in the papers).

A plane lit from one side shadows only points on its other side, and of those only the ones whose light ray crosses
the plane inside the material's extent. When the camera lies on the lit side and every view ray (from the camera to
its G-buffer distance: the stretch the scattering integral covers, and the surface point the shading shadows) either
stays on that side or passes it beyond the material's bounding box (seen along the light: the view rays past the
edge of a finite ground, down to the far plane), the plane darkens nothing in the image: a ground plane under
everything seen. Left in the light's maps it only costs: a directional map is fitted to the casters, so an 80 m
ground spreads 1024 texels over 80 m where the colonnade's pillars alone get 4x finer ones
(``configs/colonnade_fourier.yaml`` at 1280x720: fourier's rel. L1 against the exact marcher 2.67 -> 1.79 %, the
grey fringe beside the sun gone), and its own depth sits just behind every ground pixel in the map's filters.

The test is conservative: a plane is kept whenever a view ray's stretch behind it may reach the material's
axis-aligned box along the light, and a plane edge-on to the light (or through a spot's position) is kept.

:func:`without_unseen_planes` marks such materials ``receiver_only`` (:class:`~warpscatter.scene.Scene`) in the
scene the light's maps are built from (``render.scattering.shadow_map.skip_unseen_planes``). The exact-visibility
BVH keeps them: they block no visible point's light, so the reference is the same either way.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import warp as wp

from ..parallel import launch_rows
from ..scene.camera import CameraParams, pixel_ray_factors
from ..scene.lights import DirectionalLight
from ..wpinit import module_options

module_options()

#: Largest distance of a material's vertices from their best-fit plane, relative to the material's extent, for the
#: material to count as planar.
PLANE_TOLERANCE = 1e-5
#: Triangles of a material tested first: a curved mesh is told from a plane without reading all of it.
PLANE_PROBE_TRIANGLES = 64
#: View points this far behind a plane (relative to the longest view ray plus the scene's size) still count as on
#: it: the plane's own pixels, whose G-buffer distance carries float32 rounding.
SIDE_TOLERANCE = 1e-4


def caster_planes(scene) -> list[tuple[int, np.ndarray, float, np.ndarray, np.ndarray]]:
    """(material k, unit normal n, offset d, box min, box max) of every casting material whose triangles all lie in
    one plane n . x + d = 0, with the axis-aligned box of its vertices (scene units;
    :meth:`~warpscatter.scene.Scene.caster_mask`)."""
    mask = scene.caster_mask()
    vertices = np.asarray(scene.vertices)
    planes = []
    for k in range(len(scene.albedo)):
        tris = np.flatnonzero(mask & (scene.tri_material == k))
        if not len(tris):
            continue
        plane = triangles_plane(vertices, scene.triangles[tris[:PLANE_PROBE_TRIANGLES]])  # curved meshes fail here
        if plane is not None and len(tris) > PLANE_PROBE_TRIANGLES:
            plane = triangles_plane(vertices, scene.triangles[tris])
        if plane is not None:
            planes.append((int(k), *plane))
    return planes


def triangles_plane(vertices: np.ndarray, tris: np.ndarray):
    """(unit normal n, offset d, box min, box max) of the plane n . x + d = 0 holding every corner of triangles
    ``tris`` (within :data:`PLANE_TOLERANCE` of their extent), with the corners' box; None if they are not coplanar
    or have no area."""
    v = np.asarray(vertices[tris], np.float64)  # (T, 3 corners, 3)
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
    """+1 or -1: the side of plane (n, d) the light comes from (a directional light's -direction; a spot or point
    light's position); 0 where the plane holds the light (edge-on to a directional light, or through the light's
    position): it casts no shadow region to test."""
    if isinstance(light, DirectionalLight):
        s = -float(n @ light.direction)
        return 0.0 if abs(s) < 1e-6 else float(np.sign(s))
    s = float(n @ np.asarray(light.position, np.float64)) + d
    return 0.0 if abs(s) < SIDE_TOLERANCE * scale else float(np.sign(s))


@wp.func
def along_light_to_plane(x: wp.vec3, n: wp.vec3, d: float, directional: int, light: wp.vec3) -> wp.vec3:
    """Where the light ray through x meets plane n . p + d = 0: along a directional light's travel direction
    ``light``, or on the line from a spot or point light's position ``light`` (x on the side away from it)."""
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
    """seen[row] = 1 where a pixel's view ray ends behind the plane (n, d), whose normal n points to the light's
    side, and the stretch behind it, carried along the light onto the plane, meets the material's box. One thread
    per row; a row whose rays all run away from the plane's far side is skipped whole."""
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
            # the ray crosses the plane at `cross` (past the material's edge, or the G-buffer would have stopped it
            # there) and ends behind it; along the light that stretch lands on the segment cross -> end'
            direction = (xn * cam.right + yn * cam.up + cam.forward) * inv_length
            cross = cam.position + (camera_side / -rate) * direction
            end = along_light_to_plane(cam.position + s * direction, n, d, directional, light)
            if segment_meets_box(cross, end, box_lo, box_hi):
                seen[j] = 1
                return


def plane_shadow_seen(scene, distance: wp.array, n: np.ndarray, d: float, box_lo: np.ndarray, box_hi: np.ndarray,
                      tol: float) -> bool:
    """True if plane (n, d), with ``n`` turned to the light's side, may shadow a point of some view ray (module doc):
    the camera lies behind it, or :func:`plane_shadow_seen_kernel` finds a ray."""
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
    """``scene`` with every planar caster that shadows nothing the camera sees marked ``receiver_only`` (module
    doc), and the materials (= ``scene.meshes`` entries) so marked.

    Args:
        scene: a :class:`~warpscatter.scene.Scene` with a directional, spot or point light.
        distance: the (H, W) float32 G-buffer distances (scene units along each pixel's unit ray, CONVENTIONS'
            ``s``), a Warp array on the device the test runs on.
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
        if tol is None:  # float32 rounding of the G-buffer's distances, of the plane's own pixels above all
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
