"""BVH ray casting with ``wp.Mesh``: @wp.func building blocks (``ray_hit``, ``ray_hit_distance``, ``occluded``) and
the host references :func:`raycast_depth` (the rasterizer's reference, same format and pixel centres) and
:func:`raycast_camera` (hit distance along each camera ray)."""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np
import warp as wp

from ..runtime import parallel
from ..runtime.device import default_device, module_options
from ..scene.camera import Camera, CameraParams, far_plane_distance, pixel_ray_direction
from .funcs import pixel_center_ndc
from .inputs import as_points, as_triangles, check_matrix, check_size
from .rasterizer import RasterResult

module_options()




@wp.func
def ray_hit(mesh_id: wp.uint64, origin: wp.vec3, direction: wp.vec3, t_max: float) -> tuple[float, int]:
    """Closest hit of a ray with a mesh: (t, face), t in [0, t_max] in multiples of |direction|; (+inf, -1) for none.
    Both sides are hit; offset the origin of secondary rays."""
    q = wp.mesh_query_ray(mesh_id, origin, direction, t_max)
    if q.result:
        return q.t, q.face
    return wp.inf, -1


@wp.func
def ray_hit_distance(mesh_id: wp.uint64, origin: wp.vec3, direction: wp.vec3, t_max: float) -> float:
    """Distance t (multiples of |direction|) of the closest hit in [0, t_max]; +inf when there is none."""
    t, face = ray_hit(mesh_id, origin, direction, t_max)
    return t


@wp.func
def occluded(mesh_id: wp.uint64, origin: wp.vec3, direction: wp.vec3, t_max: float) -> bool:
    """True when any triangle lies on the ray within [0, t_max] (shadow rays; any-hit traversal)."""
    return wp.mesh_query_ray_anyhit(mesh_id, origin, direction, t_max)


@wp.func
def unproject_ndc(inv_view_proj: wp.mat44d, x: wp.float64, y: wp.float64, z: wp.float64) -> tuple[wp.vec3d, wp.float64]:
    """World point of NDC (x, y, z) and the homogeneous w of the unprojection (1 / clip w of the point)."""
    p = inv_view_proj * wp.vec4d(x, y, z, wp.float64(1.0))
    return wp.vec3d(p[0], p[1], p[2]) / p[3], p[3]




@wp.kernel
def raycast_depth_kernel(
    mesh_id: wp.uint64,
    inv_view_proj: wp.mat44d,
    width: int,
    height: int,
    ndc_depth: wp.array3d(dtype=wp.float32),
    tri_id: wp.array3d(dtype=wp.int32),
    offset: int,
):
    """One ray per pixel centre from the near plane (z_ndc = -1) to the far plane (z_ndc = +1)."""
    j, i = wp.tid()
    j += offset
    c = pixel_center_ndc(i, j, width, height)
    x = wp.float64(c[0])
    y = wp.float64(c[1])
    p_near, h_near = unproject_ndc(inv_view_proj, x, y, wp.float64(-1.0))
    p_far, h_far = unproject_ndc(inv_view_proj, x, y, wp.float64(1.0))
    origin = wp.vec3(p_near)
    direction = wp.vec3(p_far - p_near)
    t, face = ray_hit(mesh_id, origin, direction, 1.0)
    if face < 0:
        ndc_depth[0, j, i] = wp.inf
        tri_id[0, j, i] = -1
        return
    # Clip coordinates are affine along the world segment: clip(t) = (1-t) c_near + t c_far with
    # c_near = (x, y, -1, 1) / h_near and c_far = (x, y, 1, 1) / h_far.
    s = wp.float64(t)
    one = wp.float64(1.0)
    zc = -(one - s) / h_near + s / h_far
    wc = (one - s) / h_near + s / h_far
    ndc_depth[0, j, i] = float(wp.clamp(zc / wc, wp.float64(-1.0), wp.float64(1.0)))
    tri_id[0, j, i] = face


@wp.kernel
def raycast_camera_kernel(
    mesh_id: wp.uint64,
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    tri_id: wp.array2d(dtype=wp.int32),
    offset: int,
):
    """CONVENTIONS camera rays: hit distance along the unit ray within the far plane (+inf: none)."""
    j, i = wp.tid()
    j += offset
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    t, face = ray_hit(mesh_id, cam.position, d, far_plane_distance(cam, d))
    distance[j, i] = t
    tri_id[j, i] = face


@wp.kernel
def shadow_rays_kernel(
    mesh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    directions: wp.array(dtype=wp.vec3),
    eps: float,
    out: wp.array(dtype=wp.float32),
    offset: int,
):
    """Visibility of ray i: 1 when nothing lies on the unit ray from ``points[i] + eps d`` along d, else 0."""
    i = wp.tid() + offset
    d = wp.normalize(directions[i])
    out[i] = 1.0
    if occluded(mesh, points[i] + d * eps, d, 1.0e30):
        out[i] = 0.0




def build_mesh(vertices, triangles, device: str | None = None) -> wp.Mesh:
    """BVH mesh (a ``wp.Mesh``, holding references to its point and index arrays) for ray queries.

    Args:
        vertices: (N, 3) world positions (numpy, converted to float32) or ``wp.array(dtype=wp.vec3)``.
        triangles: (T, 3) integer vertex indices.
        device: Warp device.

    Raises:
        ValueError: wrong shapes, non-finite vertices, out-of-range indices, or no triangles.
    """
    device = default_device(device)
    points = as_points(vertices, device)
    tris = as_triangles(triangles, points.shape[0], device)
    if tris.shape[0] == 0:
        raise ValueError("triangles: a mesh needs at least one triangle")
    return wp.Mesh(points=points, indices=tris.flatten())


#: BVHs built by :func:`cached_bvh`, by (geometry digest, device); the least recently used leave first.
_BVHS: OrderedDict = OrderedDict()
#: How many BVHs :func:`cached_bvh` keeps (each holds its points, indices and tree on the device).
BVH_CACHE_SIZE = 4
_BVHS_LOCK = threading.RLock()


def cached_bvh(vertices, triangles, device: str | None = None) -> wp.Mesh:
    """:func:`build_mesh` of host geometry, reused while the same geometry (by digest) comes back on the same device;
    nothing refits a BVH, so a shared one never changes."""
    from ..scene.meshes import geometry_digest

    device = default_device(device)
    key = (geometry_digest(vertices, triangles), str(device))
    with _BVHS_LOCK:  # one build per key, also when several threads render the same scene
        mesh = _BVHS.pop(key, None)
        if mesh is None:
            mesh = build_mesh(vertices, triangles, device=device)
        _BVHS[key] = mesh
        while len(_BVHS) > BVH_CACHE_SIZE:
            _BVHS.popitem(last=False)
    return mesh


def clear_bvh_cache() -> None:
    """Drop the BVHs :func:`cached_bvh` keeps (their device memory is freed when no render holds them)."""
    with _BVHS_LOCK:
        _BVHS.clear()


def _check_mesh(mesh) -> wp.Mesh:
    if not isinstance(mesh, wp.Mesh):
        raise ValueError(f"mesh must be a wp.Mesh (see build_mesh), got {type(mesh).__name__}")
    return mesh


def raycast_depth(
    mesh: wp.Mesh, view_proj, width: int, height: int, device: str | None = None, threads: int | None = None
) -> RasterResult:
    """Ray-cast NDC depth and triangle ids per pixel centre, in the format of ``rasterize`` (one layer): rays from
    the near to the far plane of ``view_proj``, unprojected, so perspective and orthographic alike.

    Args:
        mesh: ``wp.Mesh`` from :func:`build_mesh`.
        view_proj: 4x4 world -> clip matrix (must be invertible).
        width, height: image size in pixels (row 0 at the top).
        device: Warp device; the mesh's device when None.
        threads: CPU worker threads.

    Returns:
        :class:`.rasterizer.RasterResult` with shapes (1, height, width); ``keys`` is None.

    Raises:
        ValueError: bad mesh, matrix (non-finite or singular) or size.
    """
    mesh = _check_mesh(mesh)
    device = default_device(device or str(mesh.device))
    m = check_matrix(view_proj, "view_proj")
    width, height = check_size(width, height)
    if abs(np.linalg.det(m)) < 1e-300 or not np.all(np.isfinite(inv := np.linalg.inv(m))):
        raise ValueError("view_proj must be invertible")
    ndc_depth = wp.empty((1, height, width), dtype=wp.float32, device=device)
    tri_id = wp.empty((1, height, width), dtype=wp.int32, device=device)
    parallel.launch_rows(
        raycast_depth_kernel, (height, width), [mesh.id, wp.mat44d(*inv.ravel()), width, height, ndc_depth, tri_id],
        device, threads=threads, min_chunk=8,
    )
    return RasterResult.from_device(ndc_depth, tri_id, None, m)


def raycast_camera(
    mesh: wp.Mesh, camera: Camera, device: str | None = None, threads: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Hit distance along every camera ray from the camera position to the far plane, and the hit triangle.

    Args:
        mesh: ``wp.Mesh`` from :func:`build_mesh`.
        camera: the camera (its width x height pixels).
        device: Warp device; the mesh's device when None.
        threads: CPU worker threads.

    Returns:
        ``(distance, tri_id)``: (height, width) float32 scene units (+inf where no surface lies within the far plane)
        and int32 triangle index (-1 there); row 0 at the top.
    """
    mesh = _check_mesh(mesh)
    if not isinstance(camera, Camera):
        raise ValueError(f"camera must be a Camera, got {type(camera).__name__}")
    device = default_device(device or str(mesh.device))
    h, w = int(camera.height), int(camera.width)
    distance = wp.empty((h, w), dtype=wp.float32, device=device)
    tri_id = wp.empty((h, w), dtype=wp.int32, device=device)
    parallel.launch_rows(
        raycast_camera_kernel,
        (h, w),
        [mesh.id, camera.params(), distance, tri_id],
        device,
        threads=threads,
        min_chunk=8,
    )
    return distance.numpy(), tri_id.numpy()


def shadow_ray_visibility(mesh: wp.Mesh, points, directions, *, eps: float = 0.0, device: str | None = None,
                          threads: int | None = None) -> wp.array:
    """Visibility (1 lit, 0 blocked) of rays from ``points`` (offset by ``eps``) towards ``directions``: the BVH
    reference of batched queries. (K, 3) inputs; returns a (K,) float32 ``wp.array``."""
    device = default_device(device)
    mesh = _check_mesh(mesh)
    pts = points if isinstance(points, wp.array) else wp.array(np.asarray(points, np.float32), dtype=wp.vec3,
                                                              device=device)
    dirs = directions if isinstance(directions, wp.array) else wp.array(np.asarray(directions, np.float32),
                                                                       dtype=wp.vec3, device=device)
    if pts.shape != dirs.shape:
        raise ValueError(f"points and directions must have the same length, got {pts.shape} and {dirs.shape}")
    out = wp.empty(pts.shape[0], dtype=wp.float32, device=device)
    parallel.launch_rows(shadow_rays_kernel, pts.shape[0], [mesh.id, pts, dirs, float(eps), out], device,
                         threads=threads, min_chunk=1024)
    return out
