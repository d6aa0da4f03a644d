"""Camera G-buffer: per pixel the hit distance along its CONVENTIONS ray, the surface normal and material.

Two sources, one format: ``raster`` (the rasterized visible triangle, then the exact ray-plane distance) and
``raycast`` (one BVH ray per pixel, the reference). The rasterizer runs with ``exact_edges=True`` (issue #13), so it
covers exactly the pixels whose ray hits a triangle. The raster G-buffer is fused with the scan: each band of rows is
converted from packed keys as soon as it is final, bitwise :func:`store_hit` per pixel.

``distance`` is the ``s`` of the scattering integral: the hit distance, or far / dot(direction, forward) where
nothing is hit; ``normal`` the unit geometric normal facing the camera (0 where no hit); ``material`` the index or -1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from ..runtime.device import default_device, module_options
from ..runtime.parallel import launch_rows, thread_count
from ..scene import MeshArrays
from ..scene.camera import (
    CameraParams,
    factors_ray_direction,
    far_plane_distance,
    pixel_ray_direction,
    pixel_ray_factors,
)
from .rasterizer import (
    TRIANGLES_PER_CPU_THREAD,
    empty_array,
    key_ndc_depth,
    key_triangle,
    ndc_to_view_depth,
    rasterize_keys,
)

module_options()


@wp.struct
class GBufferArrays:
    """A camera G-buffer as kernels see it (:meth:`GBuffer.arrays`; fields as in :class:`GBuffer`)."""

    distance: wp.array2d(dtype=wp.float32)
    normal: wp.array2d(dtype=wp.vec3)
    material: wp.array2d(dtype=wp.int32)


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
    """(distance, camera-facing unit normal, material) of the ray origin + t d hitting triangle ``tri``: the exact
    ray-plane distance; grazing rays (|n . d| < 1e-4) keep ``t_fallback``. ``tri < 0`` (no hit) gives the far-plane
    distance, a zero normal and material -1."""
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
def triangle_planes_kernel(mesh: MeshArrays, origin: wp.vec3, planes: wp.array(dtype=wp.vec4), batch: int, offset: int):
    """Per triangle (unit normal n, dot(n, v0 - origin)) before n is turned to the camera; (0, 0, 0, 0) for
    degenerate triangles (they take the full :func:`hit_record`)."""
    first = (wp.tid() + offset) * batch
    for tri in range(first, wp.min(first + batch, planes.shape[0])):
        v0 = mesh.vertices[mesh.triangles[tri, 0]]
        v1 = mesh.vertices[mesh.triangles[tri, 1]]
        v2 = mesh.vertices[mesh.triangles[tri, 2]]
        n = wp.cross(v1 - v0, v2 - v0)
        ln = wp.length(n)
        plane = wp.vec4(0.0, 0.0, 0.0, 0.0)
        if ln > 0.0:
            n = n / ln
            plane = wp.vec4(n[0], n[1], n[2], wp.dot(n, v0 - origin))
        planes[tri] = plane


@wp.kernel
def column_factors_kernel(cam: CameraParams, xn: wp.array(dtype=float)):
    """``xn[i]``: the :func:`pixel_ray_factors` x factor of pixel column i."""
    i = wp.tid()
    xn[i] = pixel_ray_factors(cam, float(i) + 0.5, 0.5)[0]


@wp.kernel
def gbuffer_from_keys_kernel(
    cam: CameraParams,
    keys: wp.array2d(dtype=wp.int64),
    p22: float,  # projection entries for the grazing-ray fallback (see raster.ndc_to_view_depth)
    p23: float,
    mesh: MeshArrays,
    planes: wp.array(dtype=wp.vec4),
    xn: wp.array(dtype=float),
    out: GBufferArrays,
    offset: int,
):
    """Row ``tid + offset`` of the G-buffer from the packed keys: bitwise :func:`store_hit`, with precomputed
    triangle planes and pixel-ray factors."""
    j = wp.tid() + offset
    yn = pixel_ray_factors(cam, 0.5, float(j) + 0.5)[1]
    zero = wp.vec3(0.0, 0.0, 0.0)
    for i in range(keys.shape[1]):
        key = keys[j, i]
        tri = key_triangle(key)
        d = factors_ray_direction(cam, xn[i], yn)
        t_far = far_plane_distance(cam, d)
        if tri < 0:
            out.distance[j, i] = t_far
            out.normal[j, i] = zero
            out.material[j, i] = -1
            continue
        pl = planes[tri]
        n = wp.vec3(pl[0], pl[1], pl[2])
        if n == zero:
            t_raster = ndc_to_view_depth(key_ndc_depth(key), p22, p23, -1.0, 0.0) / wp.dot(d, cam.forward)
            store_hit(out, j, i, cam.position, d, t_far, tri, t_raster, mesh)
            continue
        c = pl[3]
        if wp.dot(n, d) > 0.0:
            n = -n
            c = -c
        denom = wp.dot(n, d)
        t = float(0.0)
        if denom < -1.0e-4:
            t = c / denom
        else:
            t = ndc_to_view_depth(key_ndc_depth(key), p22, p23, -1.0, 0.0) / wp.dot(d, cam.forward)
        out.distance[j, i] = wp.clamp(t, 0.0, t_far)
        out.normal[j, i] = n
        out.material[j, i] = mesh.tri_material[tri]


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
    return GBuffer(empty_array((h, w), wp.float32, device), empty_array((h, w), wp.vec3, device),
                   empty_array((h, w), wp.int32, device))


def gbuffer_raster(scene, geometry, device=None, threads: int | None = None) -> GBuffer:
    """G-buffer from the rasterized camera view, written band by band as the rasterizer resolves it.
    Args:
        scene: the :class:`~warpscatter.scene.Scene`.
        geometry: :class:`~warpscatter.scene.DeviceGeometry` (vertices, triangles, materials on device).
        threads: CPU worker threads (default :func:`..runtime.parallel.thread_count`).
    """

    device = default_device(device)
    threads = threads or thread_count()
    cam = scene.camera
    proj = cam.projection()
    mesh = geometry.arrays()
    n = mesh.triangles.shape[0]
    batch = TRIANGLES_PER_CPU_THREAD if wp.get_device(device).is_cpu else 1
    params = cam.params()
    planes = wp.empty(n, dtype=wp.vec4, device=device)
    launch_rows(triangle_planes_kernel, (n + batch - 1) // batch, [mesh, params.position, planes, batch],
                device=device, threads=threads, min_chunk=64)
    xn = wp.empty(cam.width, dtype=float, device=device)
    wp.launch(column_factors_kernel, dim=cam.width, inputs=[params, xn], device=device)
    out = _alloc(cam.height, cam.width, device)
    arrays = out.arrays()
    p22, p23 = float(proj[2, 2]), float(proj[2, 3])

    def rows(keys, r0, r1):
        wp.launch(gbuffer_from_keys_kernel, dim=r1 - r0,
                  inputs=[params, keys, p22, p23, mesh, planes, xn, arrays, r0], device=device)

    rasterize_keys(scene.vertices, scene.triangles, proj @ cam.view(), cam.width, cam.height, on_rows=rows,
                   exact_edges=True, device=device, threads=threads)
    return out


def gbuffer_raycast(scene, geometry, device=None) -> GBuffer:
    """Exact G-buffer by BVH ray casting (one ray per pixel centre)."""
    device = default_device(device)
    cam = scene.camera
    out = _alloc(cam.height, cam.width, device)
    launch_rows(gbuffer_raycast_kernel, (cam.height, cam.width),
                [cam.params(), geometry.mesh.id, geometry.arrays(), out.arrays()], device=device)
    return out
