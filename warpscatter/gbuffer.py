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
from .raster import ndc_to_view_depth, rasterize
from .scene import MeshArrays
from .scene.camera import CameraParams, far_plane_distance, pixel_ray_direction
from .wpinit import default_device, module_options

module_options()


@wp.struct
class GBufferArrays:
    """A camera G-buffer as kernels see it (:meth:`GBuffer.arrays`)."""

    distance: wp.array2d(dtype=wp.float32)  # scene units along the unit pixel ray
    normal: wp.array2d(dtype=wp.vec3)  # unit, facing the camera; 0 where no hit
    material: wp.array2d(dtype=wp.int32)  # material index, -1 where no hit


@dataclass
class GBuffer:
    """Camera G-buffer (row 0 = top). Device arrays mirror the numpy views."""

    distance: wp.array  # (H, W) float32, scene units along the unit pixel ray
    normal: wp.array  # (H, W) vec3, unit, facing the camera; 0 where no hit
    material: wp.array  # (H, W) int32, -1 where no hit

    def numpy(self) -> dict[str, np.ndarray]:
        return {"distance": self.distance.numpy(), "normal": self.normal.numpy(), "material": self.material.numpy()}

    def arrays(self) -> GBufferArrays:
        """The G-buffer as kernels see it."""
        g = GBufferArrays()
        g.distance, g.normal, g.material = self.distance, self.normal, self.material
        return g


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


@wp.func
def hit_record(origin: wp.vec3, d: wp.vec3, t_far: float, tri: int, t_fallback: float, mesh: MeshArrays):
    """(distance, camera-facing unit normal, material) of the ray origin + t d hitting triangle ``tri``.

    The distance is the exact ray-plane intersection with the triangle; grazing rays (|n . d| < 1e-4)
    keep ``t_fallback``. ``tri < 0`` (no hit) gives the far-plane distance, a zero normal and material -1.
    """
    if tri < 0:
        return t_far, wp.vec3(0.0, 0.0, 0.0), -1
    v0 = mesh.vertices[mesh.triangles[tri, 0]]
    n = facing_normal(v0, mesh.vertices[mesh.triangles[tri, 1]], mesh.vertices[mesh.triangles[tri, 2]], d)
    denom = wp.dot(n, d)
    t = t_fallback
    if denom < -1.0e-4:
        t = wp.dot(n, v0 - origin) / denom
    return wp.clamp(t, 0.0, t_far), n, mesh.tri_material[tri]


@wp.func
def store_hit(out: GBufferArrays, j: int, i: int, origin: wp.vec3, d: wp.vec3, t_far: float, tri: int,
              t_fallback: float, mesh: MeshArrays):
    """Write pixel (i, j)'s :func:`hit_record` into the G-buffer."""
    t, n, m = hit_record(origin, d, t_far, tri, t_fallback, mesh)
    out.distance[j, i] = t
    out.normal[j, i] = n
    out.material[j, i] = m


@wp.kernel
def gbuffer_from_raster_kernel(
    cam: CameraParams,
    tri_id: wp.array2d(dtype=wp.int32),
    ndc_depth: wp.array2d(dtype=wp.float32),
    p22: float,  # projection entries for the grazing-ray fallback (see raster.ndc_to_view_depth)
    p23: float,
    mesh: MeshArrays,
    out: GBufferArrays,
    offset: int,
):
    j, i = wp.tid()
    j += offset
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    # rasterized depth -> view depth -> distance along the ray; only used for grazing rays
    t_raster = ndc_to_view_depth(ndc_depth[j, i], p22, p23, -1.0, 0.0) / wp.dot(d, cam.forward)
    store_hit(out, j, i, cam.position, d, far_plane_distance(cam, d), tri_id[j, i], t_raster, mesh)


@wp.kernel
def gbuffer_raycast_kernel(
    cam: CameraParams,
    bvh: wp.uint64,
    mesh: MeshArrays,
    out: GBufferArrays,
    offset: int,
):
    j, i = wp.tid()
    j += offset
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    t_far = far_plane_distance(cam, d)
    q = wp.mesh_query_ray(bvh, cam.position, d, t_far)
    tri = int(-1)
    if q.result:
        tri = q.face
    store_hit(out, j, i, cam.position, d, t_far, tri, q.t, mesh)


def _alloc(h, w, device) -> GBuffer:
    return GBuffer(wp.empty((h, w), dtype=wp.float32, device=device), wp.empty((h, w), dtype=wp.vec3, device=device),
                   wp.empty((h, w), dtype=wp.int32, device=device))


def gbuffer_raster(scene, geometry, device=None) -> GBuffer:
    """G-buffer from the rasterized camera view (see module docstring).

    Args:
        scene: the :class:`~warpscatter.scene.Scene`.
        geometry: :class:`~warpscatter.scene.DeviceGeometry` (vertices, triangles, materials on device).
    """

    device = default_device(device)
    cam = scene.camera
    proj = cam.projection()
    r = rasterize(scene.vertices, scene.triangles, proj @ cam.view(), cam.width, cam.height, device=device)
    out = _alloc(cam.height, cam.width, device)
    launch_rows(gbuffer_from_raster_kernel, (cam.height, cam.width),
                [cam.params(), r.device_tri_id[0], r.device_ndc_depth[0], float(proj[2, 2]), float(proj[2, 3]),
                 geometry.arrays(), out.arrays()], device=device)
    return out


def gbuffer_raycast(scene, geometry, device=None) -> GBuffer:
    """Exact G-buffer by BVH ray casting (one ray per pixel centre)."""
    device = default_device(device)
    cam = scene.camera
    out = _alloc(cam.height, cam.width, device)
    launch_rows(gbuffer_raycast_kernel, (cam.height, cam.width),
                [cam.params(), geometry.mesh.id, geometry.arrays(), out.arrays()], device=device)
    return out
