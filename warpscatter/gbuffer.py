"""Camera G-buffer: per pixel the hit distance along its CONVENTIONS ray, the surface normal and material.

Two sources with one output format:

* ``raster`` — the camera view rasterized by :mod:`warpscatter.raster` gives the visible triangle of
  each pixel centre; the hit distance is then the exact intersection of the pixel's ray with that
  triangle's plane (so rasterized and ray-cast G-buffers agree to float precision off silhouettes).
* ``raycast`` — one BVH ray per pixel (``wp.mesh_query_ray``), the exact reference.

``distance`` is the ``s`` of the scattering integral: the camera hit distance, or the far-plane
distance far / dot(direction, forward) where nothing is hit (hits beyond the far plane count as
misses, as the rasterizer clips them). ``normal`` is the unit geometric normal turned to face the
camera (zero where nothing is hit); ``material`` the material index or -1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from .parallel import launch_rows
from .scene.camera import CameraParams, far_plane_distance, pixel_ray_direction
from .wpinit import default_device, module_options

module_options()


@dataclass
class GBuffer:
    """Camera G-buffer (row 0 = top). Device arrays mirror the numpy views."""

    distance: wp.array  # (H, W) float32, scene units along the unit pixel ray
    normal: wp.array  # (H, W) vec3, unit, facing the camera; 0 where no hit
    material: wp.array  # (H, W) int32, -1 where no hit

    def numpy(self) -> dict[str, np.ndarray]:
        return {"distance": self.distance.numpy(), "normal": self.normal.numpy(), "material": self.material.numpy()}


@wp.func
def facing_normal(v0: wp.vec3, v1: wp.vec3, v2: wp.vec3, d: wp.vec3) -> wp.vec3:
    """Unit geometric normal of triangle (v0, v1, v2) turned against the ray direction d."""
    n = wp.cross(v1 - v0, v2 - v0)
    ln = wp.length(n)
    if ln <= 0.0:
        return -d
    n = n / ln
    if wp.dot(n, d) > 0.0:
        n = -n
    return n


@wp.kernel
def gbuffer_from_raster_kernel(
    cam: CameraParams,
    tri_id: wp.array2d(dtype=wp.int32),
    ndc_depth: wp.array2d(dtype=wp.float32),
    vertices: wp.array(dtype=wp.vec3),
    triangles: wp.array2d(dtype=wp.int32),
    tri_material: wp.array(dtype=wp.int32),
    distance: wp.array2d(dtype=wp.float32),
    normal: wp.array2d(dtype=wp.vec3),
    material: wp.array2d(dtype=wp.int32),
    offset: int,
):
    j, i = wp.tid()
    j += offset
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    t_far = far_plane_distance(cam, d)
    tri = tri_id[j, i]
    if tri < 0:
        distance[j, i] = t_far
        normal[j, i] = wp.vec3(0.0, 0.0, 0.0)
        material[j, i] = -1
        return
    v0 = vertices[triangles[tri, 0]]
    v1 = vertices[triangles[tri, 1]]
    v2 = vertices[triangles[tri, 2]]
    n = facing_normal(v0, v1, v2, d)
    denom = wp.dot(n, d)
    t = float(0.0)
    if denom < -1.0e-4:
        t = wp.dot(n, v0 - cam.position) / denom
    else:
        # grazing: fall back on the rasterized depth (perspective NDC z -> view depth -> ray distance)
        z = ndc_depth[j, i]
        view_depth = 2.0 * cam.near * cam.far / (cam.far + cam.near - z * (cam.far - cam.near))
        t = view_depth / wp.dot(d, cam.forward)
    distance[j, i] = wp.clamp(t, 0.0, t_far)
    normal[j, i] = n
    material[j, i] = tri_material[tri]


@wp.kernel
def gbuffer_raycast_kernel(
    cam: CameraParams,
    mesh: wp.uint64,
    vertices: wp.array(dtype=wp.vec3),
    triangles: wp.array2d(dtype=wp.int32),
    tri_material: wp.array(dtype=wp.int32),
    distance: wp.array2d(dtype=wp.float32),
    normal: wp.array2d(dtype=wp.vec3),
    material: wp.array2d(dtype=wp.int32),
    offset: int,
):
    j, i = wp.tid()
    j += offset
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    t_far = far_plane_distance(cam, d)
    q = wp.mesh_query_ray(mesh, cam.position, d, t_far)
    if q.result:
        tri = q.face
        v0 = vertices[triangles[tri, 0]]
        v1 = vertices[triangles[tri, 1]]
        v2 = vertices[triangles[tri, 2]]
        distance[j, i] = q.t
        normal[j, i] = facing_normal(v0, v1, v2, d)
        material[j, i] = tri_material[tri]
    else:
        distance[j, i] = t_far
        normal[j, i] = wp.vec3(0.0, 0.0, 0.0)
        material[j, i] = -1


def _alloc(h, w, device):
    return (wp.empty((h, w), dtype=wp.float32, device=device), wp.empty((h, w), dtype=wp.vec3, device=device),
            wp.empty((h, w), dtype=wp.int32, device=device))


def gbuffer_raster(scene, geometry, device=None) -> GBuffer:
    """G-buffer from the rasterized camera view (see module docstring).

    Args:
        scene: the :class:`~warpscatter.scene.Scene`.
        geometry: :class:`~warpscatter.scene.DeviceGeometry` (vertices, triangles, materials on device).
    """
    from .raster import rasterize

    device = default_device(device)
    cam = scene.camera
    r = rasterize(scene.vertices, scene.triangles, cam.view_projection(), cam.width, cam.height, device=device)
    tri = wp.array(r.tri_id[0], dtype=wp.int32, device=device)
    ndc = wp.array(r.ndc_depth[0], dtype=wp.float32, device=device)
    distance, normal, material = _alloc(cam.height, cam.width, device)
    launch_rows(gbuffer_from_raster_kernel, (cam.height, cam.width),
                [cam.params(), tri, ndc, geometry.vertices, geometry.triangles, geometry.tri_material,
                 distance, normal, material], device=device)
    return GBuffer(distance, normal, material)


def gbuffer_raycast(scene, geometry, device=None) -> GBuffer:
    """Exact G-buffer by BVH ray casting (one ray per pixel centre)."""
    device = default_device(device)
    cam = scene.camera
    distance, normal, material = _alloc(cam.height, cam.width, device)
    launch_rows(gbuffer_raycast_kernel, (cam.height, cam.width),
                [cam.params(), geometry.mesh.id, geometry.vertices, geometry.triangles, geometry.tri_material,
                 distance, normal, material], device=device)
    return GBuffer(distance, normal, material)
