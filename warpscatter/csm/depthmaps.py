"""Depth-map sets of coherent shadow maps: orthographic maps around an object's bounding sphere (Ritschel 2007).

Distant lights (Sec. 4.1): the lat-long mapping D discretised into N1 x N2 cells (a, b) centred at

    phi = 2 pi (a + 0.5) / N1,  theta = pi (b + 0.5) / N2,
    dir = (sin theta cos phi, cos theta, sin theta sin phi)                    (+Y up, theta from +Y),

``dir`` pointing towards the light. Cell (a, b)'s map is an orthographic camera at c + R dir looking at the
bounding sphere's centre c, with frame

    right = (sin phi, 0, -cos phi),  up = (-cos theta cos phi, sin theta, -cos theta sin phi)   (right x up = dir):

NDC x = <p - c, right> / R, y = <p - c, up> / R, LINEAR depth q_z = R - <p - c, dir> in [0, 2R]. Texel centres as
in :mod:`..raster.rasterizer`. The frame varies smoothly, so neighbouring maps are coherent.

Per texel z_lo = z1 and z_hi = z2 (``"z1z2"``, any mesh) or z3 (``"z1z3"``, closed two-manifolds) bound the stored
depth (Sec. 3.1, Fig. 3), peeled by the exact rasterizer (bitwise as ``rasterize(..., clamp_depth=True)``). A
missing upper surface takes ``far``: ``"sphere"``, the paper's spherical far plane R + sqrt(R^2 - r^2) (receivers
behind the object stay shadowed), or ``"infinite"`` (longer segments; receivers behind may be wrongly lit). Empty
texels hold +inf twice. Fixed local lights (Sec. 3.3, 4.2): :class:`CubeMapSet`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import warp as wp

from ..raster import rasterizer as raster
from ..runtime import parallel
from ..runtime.device import default_device, module_options
from ..scene.environment_map import latlong_param  # noqa: F401  (public here as well: the maps' inverse mapping)
from ..scene.lights import light_grid_params, parallelogram_light_samples, segment_light_samples  # noqa: F401
from .enumeration import ENUMERATIONS, enumerate_grid, sequence_index
from .settings import FAR_MODES

module_options()

#: Accepted ``depth_layers`` values and the number of peeled layers each needs.
DEPTH_LAYERS = {"z1z2": 2, "z1z3": 3}
#: Relative padding of the bounding-sphere radius (keeps every vertex strictly inside the maps).
RADIUS_PADDING = 1e-5

#: Codes of the ``far`` modes as the resolve kernel sees them.
FAR_CODES = {"sphere": 0, "infinite": 1}
FAR_SPHERE = wp.constant(FAR_CODES["sphere"])
_EMPTY_KEY = wp.constant(wp.int64(raster.EMPTY_KEY))
_TWO_PI = 2.0 * np.pi




@wp.func
def latlong_direction(u: float, v: float) -> wp.vec3:
    """Lat-long mapping D (Sec. 4.1): (u, v) in [0, 1]^2 -> unit direction, phi = 2 pi u, theta = pi v from +Y."""
    phi = 2.0 * wp.pi * u
    theta = wp.pi * v
    st = wp.sin(theta)
    return wp.vec3(st * wp.cos(phi), wp.cos(theta), st * wp.sin(phi))


@wp.func
def ortho_snap(view_proj: wp.mat44d, q: wp.vec3, size: int) -> wp.vec3d:
    """Snapped screen position of a vertex, exactly as the rasterizer's vertex pass computes it."""
    c = view_proj * wp.vec4d(wp.float64(q[0]), wp.float64(q[1]), wp.float64(q[2]), wp.float64(1.0))
    v = wp.vec4(float(c[0]), float(c[1]), float(c[2]), float(c[3]))
    return raster.snap_to_screen(v, size, size)


@wp.func
def key_depth01(key: wp.int64) -> float:
    """depth01 = 0.5 z_ndc + 0.5 held in a packed z-buffer key (+inf for the empty key)."""
    if key == _EMPTY_KEY:
        return wp.inf
    return wp.cast(wp.uint32(key >> wp.int64(32)), wp.float32)


@wp.func
def sphere_exit_depth(x: int, y: int, size: int, radius: float) -> float:
    """Linear depth where the ray of texel (x, y) leaves the bounding sphere (the spherical far plane)."""
    nx = 2.0 * (float(x) + 0.5) / float(size) - 1.0
    ny = 1.0 - 2.0 * (float(y) + 0.5) / float(size)
    return radius * (1.0 + wp.sqrt(wp.max(1.0 - nx * nx - ny * ny, 0.0)))




@wp.kernel
def peel_maps_kernel(
    points: wp.array(dtype=wp.vec3),
    triangles: wp.array2d(dtype=wp.int32),
    view_proj: wp.array(dtype=wp.mat44d),
    params: raster.RasterParams,
    prev_keys: wp.array3d(dtype=wp.int64),
    keys: wp.array3d(dtype=wp.int64),
    counts: wp.array2d(dtype=wp.int32),
    batch: int,
    offset: int,
):
    """One depth-peeling pass: thread (m, k) scans triangles [k batch, (k + 1) batch) into map m + offset (no
    clipping: every vertex lies inside the maps)."""
    m, k = wp.tid()
    m = m + offset
    vp = view_proj[m]
    size = params.width
    first = k * batch
    for t in range(first, wp.min(first + batch, triangles.shape[0])):
        s0 = ortho_snap(vp, points[triangles[t, 0]], size)
        s1 = ortho_snap(vp, points[triangles[t, 1]], size)
        s2 = ortho_snap(vp, points[triangles[t, 2]], size)
        raster.rasterize_screen_triangle(s0, s1, s2, t, params, prev_keys[m], keys[m], counts)


@wp.kernel
def resolve_depths_kernel(
    keys: wp.array4d(dtype=wp.int64),
    hi_layer: int,
    far_mode: int,
    radius: float,
    z_lo: wp.array2d(dtype=wp.float32),
    z_hi: wp.array2d(dtype=wp.float32),
    offset: int,
):
    """Peeled keys (layers, maps, M, M) -> linear depths z_lo = z1 and z_hi = z_{hi_layer + 1}, (maps, M * M)."""
    m = wp.tid() + offset
    size = keys.shape[3]
    scale = 2.0 * radius
    for y in range(size):
        for x in range(size):
            t = y * size + x
            d1 = key_depth01(keys[0, m, y, x])
            lo = wp.inf
            hi = wp.inf
            if d1 < wp.inf:
                lo = d1 * scale
                dh = key_depth01(keys[hi_layer, m, y, x])
                if dh < wp.inf:
                    hi = dh * scale
                elif far_mode == FAR_SPHERE:
                    hi = wp.max(sphere_exit_depth(x, y, size, radius), lo)
            z_lo[m, t] = lo
            z_hi[m, t] = hi




def latlong_frames(n1: int, n2: int) -> np.ndarray:
    """Image frames of the N1 x N2 lat-long maps: (n2 * n1, 3, 3) float64, entry b * n1 + a the rows (right, up,
    dir) of cell (a, b)."""
    a = np.arange(n1, dtype=np.float64)
    b = np.arange(n2, dtype=np.float64)
    phi = _TWO_PI * (a + 0.5) / n1
    theta = np.pi * (b + 0.5) / n2
    ph, th = np.meshgrid(phi, theta)  # (n2, n1)
    sp, cp, st, ct = np.sin(ph), np.cos(ph), np.sin(th), np.cos(th)
    direction = np.stack([st * cp, ct, st * sp], axis=-1)
    right = np.stack([sp, np.zeros_like(sp), -cp], axis=-1)
    up = np.stack([-ct * cp, st, -ct * sp], axis=-1)
    return np.stack([right, up, direction], axis=-2).reshape(n1 * n2, 3, 3)


def ortho_view_proj(center, radius: float, frame: np.ndarray) -> np.ndarray:
    """World -> clip float64 matrix (4, 4) of an orthographic map of the sphere (``center``, ``radius`` R) with
    ``frame`` rows (right, up, dir), or (K, 4, 4) for (K, 3, 3) frames: NDC x, y = <p - c, right | up> / R,
    z = -<p - c, dir> / R; linear depth is (z_ndc + 1) R."""
    c = np.asarray(center, dtype=np.float64)
    f = np.asarray(frame, dtype=np.float64)
    rows = f * np.array([1.0, 1.0, -1.0])[:, None]  # (..., 3, 3): right, up, -dir
    m = np.zeros(f.shape[:-2] + (4, 4))
    m[..., :3, :3] = rows / radius
    m[..., :3, 3] = -(rows @ c) / radius
    m[..., 3, 3] = 1.0
    return m


def bounding_sphere(vertices) -> tuple[np.ndarray, float]:
    """Centre (bounding-box midpoint) and radius (largest vertex distance, padded) of a vertex set."""
    v = np.asarray(vertices, dtype=np.float64)
    c = 0.5 * (v.min(axis=0) + v.max(axis=0))
    r = float(np.sqrt(np.max(np.sum((v - c) ** 2, axis=1))))
    r = r * (1.0 + RADIUS_PADDING) + 1e-12 * max(1.0, float(np.abs(c).max()))
    return c, r


def _check_int(name: str, value, lo: int, hi: int) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if not lo <= int(value) <= hi:
        raise ValueError(f"{name} must lie in [{lo}, {hi}], got {value}")
    return int(value)


def _check_options(resolution, enumeration: str, depth_layers: str, far: str) -> int:
    resolution = _check_int("resolution", resolution, 1, 8192)
    if enumeration not in ENUMERATIONS:
        raise ValueError(f"enumeration must be one of {ENUMERATIONS}, got {enumeration!r}")
    if depth_layers not in DEPTH_LAYERS:
        raise ValueError(f"depth_layers must be one of {tuple(DEPTH_LAYERS)}, got {depth_layers!r}")
    if far not in FAR_MODES:
        raise ValueError(f"far must be one of {FAR_MODES}, got {far!r}")
    return resolution


def _set_fields(v: np.ndarray, t: np.ndarray, n1: int, n2: int, enumeration: str, depth_layers: str, far: str) -> dict:
    order = enumerate_grid(n1, n2, enumeration)
    return {
        "enumeration": enumeration, "depth_layers": depth_layers, "far": far, "order": order,
        "map_index": sequence_index(order, n1, n2), "vertices": v.astype(np.float32), "triangles": t.astype(np.int32),
    }


def _check_mesh(vertices, triangles) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) finite float64 vertices and (T, 3) in-range integer triangles, or ValueError."""
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] == 0:
        raise ValueError(f"vertices must have shape (V, 3) with V >= 1, got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError("vertices contain non-finite coordinates")
    t = np.asarray(triangles)
    if t.ndim != 2 or t.shape[1] != 3 or t.shape[0] == 0 or not np.issubdtype(t.dtype, np.integer):
        raise ValueError(f"triangles must be a non-empty (T, 3) integer array, got shape {t.shape}")
    if t.min() < 0 or t.max() >= v.shape[0]:
        raise ValueError(f"triangles index vertices outside [0, {v.shape[0]})")
    return v, t


@dataclass
class LatLongMapSet:
    """The N1 x N2 orthographic depth maps of a mesh for distant (and semi-local) lights, in sequence order.

    Attributes:
        n1, n2: azimuth cells N1 (grid axis a, fastest in scan-line order), polar cells N2 (axis b, theta from +Y).
        resolution: map size M in texels (M x M).
        center, radius: (3,) float64 bounding-sphere centre and radius R (the maps' half extent and half depth range).
        enumeration, depth_layers, far: the options of :meth:`create`.
        order: (N, 2) int64 cells (a, b) by sequence index.
        map_index: (n2, n1) int32 sequence index of each cell.
        frames: (N, 3, 3) float64 rows (right, up, dir) per cell b * n1 + a.
    """

    n1: int
    n2: int
    resolution: int
    center: np.ndarray
    radius: float
    enumeration: str
    depth_layers: str
    far: str
    order: np.ndarray
    map_index: np.ndarray
    frames: np.ndarray
    vertices: np.ndarray = field(repr=False)
    triangles: np.ndarray = field(repr=False)
    _device: dict = field(default_factory=dict, repr=False)
    last_working_bytes: int = field(default=0, repr=False)

    @classmethod
    def create(
        cls,
        vertices,
        triangles,
        *,
        n1: int,
        n2: int,
        resolution: int,
        enumeration: str = "hilbert",
        depth_layers: str = "z1z2",
        far: str = "sphere",
        center=None,
        radius: float | None = None,
    ) -> LatLongMapSet:
        """Discretise the lat-long domain around a mesh.

        Args:
            vertices, triangles: (V, 3) object-space positions, (T, 3) integer vertex indices.
            n1, n2: azimuth and polar cells (>= 1).
            resolution: map size M (1 .. 8192).
            enumeration: sequence order of the maps (:mod:`warpscatter.csm.enumeration`).
            depth_layers, far: ``"z1z2"`` or ``"z1z3"``; ``"sphere"`` or ``"infinite"`` (module docstring).
            center, radius: bounding sphere (default: the bounding-box midpoint and the farthest vertex, padded).

        Raises:
            ValueError: bad sizes or option names, malformed mesh, or vertices outside the given sphere.
        """
        n1 = _check_int("n1", n1, 1, 2**15)
        n2 = _check_int("n2", n2, 1, 2**15)
        resolution = _check_options(resolution, enumeration, depth_layers, far)
        v, t = _check_mesh(vertices, triangles)
        c0, r0 = bounding_sphere(v)
        c = c0 if center is None else np.asarray(center, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(c)):
            raise ValueError("center must be 3 finite numbers")
        far_vertex = float(np.sqrt(np.max(np.sum((v - c) ** 2, axis=1))))
        if radius is None:
            r = r0 if center is None else far_vertex * (1.0 + RADIUS_PADDING) + 1e-12 * max(1.0, far_vertex)
        else:
            r = float(radius)
            if not np.isfinite(r) or r <= 0.0:
                raise ValueError(f"radius must be a finite number > 0, got {radius!r}")
            if far_vertex > r:
                raise ValueError(f"radius {r} does not enclose the mesh (farthest vertex at {far_vertex})")
        return cls(
            n1=n1, n2=n2, resolution=resolution, center=c, radius=r, frames=latlong_frames(n1, n2),
            **_set_fields(v, t, n1, n2, enumeration, depth_layers, far),
        )

    @property
    def num_maps(self) -> int:
        """N = n1 * n2."""
        return self.n1 * self.n2

    @property
    def num_texels(self) -> int:
        """M * M."""
        return self.resolution * self.resolution

    def view_proj(self, sequence: int) -> np.ndarray:
        """World -> clip matrix of the map with sequence index ``sequence`` (float64 4x4)."""
        a, b = self.order[sequence]
        return ortho_view_proj(self.center, self.radius, self.frames[b * self.n1 + a])

    def _geometry(self, device: str):
        if device not in self._device:
            self._device[device] = (
                wp.array(self.vertices, dtype=wp.vec3, device=device),
                wp.array(self.triangles, dtype=wp.int32, device=device),
            )
        return self._device[device]

    def render_device(self, start: int, stop: int, device: str | None = None, threads: int | None = None):
        """Linear depths (z_lo, z_hi) of the maps [start, stop) as ``wp.array2d(float32)`` (stop - start, M * M),
        texel y * M + x, +inf = empty. Sets :attr:`last_working_bytes` (the device arrays it allocated)."""
        device = default_device(device)
        n = self.num_maps
        if not (0 <= start < stop <= n):
            raise ValueError(f"[start, stop) must be a non-empty range within [0, {n}], got [{start}, {stop})")
        count = stop - start
        size = self.resolution
        layers = DEPTH_LAYERS[self.depth_layers]
        points, tris = self._geometry(device)
        cells = self.order[start:stop]
        mats = ortho_view_proj(self.center, self.radius, self.frames[cells[:, 1] * self.n1 + cells[:, 0]])
        view_proj = wp.array(mats, dtype=wp.mat44d, device=device)
        keys = wp.full((layers, count, size, size), raster.EMPTY_KEY, dtype=wp.int64, device=device)
        dummy = wp.zeros((1, 1), dtype=wp.int32, device=device)
        is_cpu = wp.get_device(device).is_cpu
        batch = raster.TRIANGLES_PER_CPU_THREAD if is_cpu else 1
        nb = (tris.shape[0] + batch - 1) // batch
        for layer in range(layers):
            p = raster.RasterParams()
            p.width = p.height = size
            p.guard_x = p.guard_y = 1.0
            p.clip_near, p.clamp_depth, p.cull_backfaces, p.count_mode = 0, 1, 0, 0
            p.peel = 1 if layer > 0 else 0
            prev = keys[layer - 1] if layer > 0 else keys[layer]
            parallel.launch_rows(peel_maps_kernel, (count, nb), [points, tris, view_proj, p, prev, keys[layer], dummy,
                                                                 batch], device, threads=threads)
        z_lo = wp.empty((count, size * size), dtype=wp.float32, device=device)
        z_hi = wp.empty((count, size * size), dtype=wp.float32, device=device)
        far_mode = FAR_CODES[self.far]
        parallel.launch_rows(resolve_depths_kernel, count, [keys, layers - 1, far_mode, float(self.radius), z_lo, z_hi],
                             device, threads=threads)
        self.last_working_bytes = sum(a.capacity for a in (view_proj, keys, z_lo, z_hi))
        return z_lo, z_hi

    def render(self, start: int, stop: int, device: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Depths of the maps [start, stop) as numpy: (z_lo, z_hi), each (stop - start, M, M) float32."""
        z_lo, z_hi = self.render_device(start, stop, device)
        shape = (stop - start, self.resolution, self.resolution)
        return z_lo.numpy().reshape(shape), z_hi.numpy().reshape(shape)




def cube_face_frames() -> np.ndarray:
    """Rows (right, up, forward) of the cube faces k = 0..5 along +X, -X, +Y, -Y, +Z, -Z; right x up = -forward."""
    out = np.zeros((6, 3, 3))
    for k in range(6):
        f = np.zeros(3)
        f[k // 2] = 1.0 if k % 2 == 0 else -1.0
        hint = np.array([0.0, 0.0, 1.0]) if k // 2 == 1 else np.array([0.0, 1.0, 0.0])
        right = np.cross(f, hint)
        right /= np.linalg.norm(right)
        out[k] = [right, np.cross(right, f), f]
    return out


@dataclass
class CubeMapSet:
    """Depth cube maps at the sample points of a fixed local light, concatenated face by face (Sec. 3.3).

    Map k N + i is face k of sample i, so each face's N maps are coherent (Fig. 5). A face is a 90-degree perspective
    view, LINEAR depth q_z = <p - o, forward>; ``far`` as for :class:`LatLongMapSet`; geometry nearer than ``near``
    is clipped.

    Attributes:
        n1, n2: light-sample grid; N = n1 n2 samples, 6N maps.
        samples: (N, 3) float64 sample positions, entry b n1 + a for grid cell (a, b).
        resolution, center, radius, near: face size M, the object's bounding sphere, the faces' near plane.
        enumeration, depth_layers, far, order, map_index: as for :class:`LatLongMapSet` (over the sample grid).
    """

    n1: int
    n2: int
    resolution: int
    samples: np.ndarray
    center: np.ndarray
    radius: float
    near: float
    enumeration: str
    depth_layers: str
    far: str
    order: np.ndarray
    map_index: np.ndarray
    vertices: np.ndarray = field(repr=False)
    triangles: np.ndarray = field(repr=False)

    @classmethod
    def create(
        cls,
        vertices,
        triangles,
        samples,
        *,
        resolution: int,
        enumeration: str = "hilbert",
        depth_layers: str = "z1z2",
        far: str = "sphere",
        near: float | None = None,
    ) -> CubeMapSet:
        """Set up the cube maps of a light given by its sample points.

        Args:
            vertices, triangles, enumeration, depth_layers, far: as for :meth:`LatLongMapSet.create`.
            samples: (n2, n1, 3) grid (or (n, 3) row) of light sample positions, e.g. from
                :func:`segment_light_samples` or :func:`parallelogram_light_samples`.
            resolution: face size M (1 .. 8192).
            near: near-plane distance (> 0; default 1e-3 R).

        Raises:
            ValueError: bad sizes, options, mesh or samples.
        """
        resolution = _check_options(resolution, enumeration, depth_layers, far)
        v, t = _check_mesh(vertices, triangles)
        center, radius = bounding_sphere(v)
        s = np.asarray(samples, dtype=np.float64)
        if s.ndim == 2:
            s = s[None]
        if s.ndim != 3 or s.shape[2] != 3 or s.shape[0] * s.shape[1] == 0:
            raise ValueError(f"samples must have shape (n2, n1, 3) or (n, 3), got {np.shape(samples)}")
        if not np.all(np.isfinite(s)):
            raise ValueError("samples contain non-finite coordinates")
        n2, n1 = s.shape[:2]
        near = 1e-3 * radius if near is None else float(near)
        if not np.isfinite(near) or near <= 0.0:
            raise ValueError(f"near must be a finite number > 0, got {near}")
        return cls(
            n1=n1, n2=n2, resolution=resolution, samples=s.reshape(-1, 3), center=center, radius=radius, near=near,
            **_set_fields(v, t, n1, n2, enumeration, depth_layers, far),
        )

    @property
    def num_samples(self) -> int:
        """N = n1 n2."""
        return self.n1 * self.n2

    @property
    def num_maps(self) -> int:
        """6 N."""
        return 6 * self.num_samples

    @property
    def num_texels(self) -> int:
        return self.resolution * self.resolution

    def face_matrices(self, sequence: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(view_proj, projection, sample position) of map ``sequence`` = face k N + sample i."""
        from ..scene.camera import perspective_matrix, view_matrix

        k, i = divmod(int(sequence), self.num_samples)
        a, b = self.order[i]
        o = self.samples[b * self.n1 + a]
        right, up, forward = cube_face_frames()[k]
        far = float(np.linalg.norm(o - self.center)) + 2.0 * self.radius
        proj = perspective_matrix(90.0, 1.0, self.near, max(far, 2.0 * self.near))
        return proj @ view_matrix(o, right, up, forward), proj, o

    def render(self, start: int, stop: int, device: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Linear depths (z_lo, z_hi) of the maps [start, stop), each (stop - start, M, M) float32."""
        if not (0 <= start < stop <= self.num_maps):
            raise ValueError(f"[start, stop) must be a non-empty range within [0, {self.num_maps}], got "
                             f"[{start}, {stop})")
        m = self.resolution
        layers = DEPTH_LAYERS[self.depth_layers]
        z_lo = np.empty((stop - start, m, m), np.float32)
        z_hi = np.empty((stop - start, m, m), np.float32)
        x = 2.0 * (np.arange(m) + 0.5) / m - 1.0
        y = 1.0 - 2.0 * (np.arange(m) + 0.5) / m
        for s in range(start, stop):
            vp, proj, o = self.face_matrices(s)
            r = raster.rasterize(self.vertices, self.triangles, vp, m, m, layers=layers, clamp_depth=True,
                                 device=device)
            depth = raster.linearize_depth(r.ndc_depth, proj).astype(np.float32)
            lo = depth[0]
            hi = depth[layers - 1].copy()
            if self.far == "sphere":
                right, up, forward = cube_face_frames()[s // self.num_samples]
                ray = x[None, :, None] * right + y[:, None, None] * up + forward  # unit component along forward
                oc = o - self.center
                qa = np.sum(ray * ray, axis=-1)
                qb = 2.0 * ray @ oc
                qc = oc @ oc - self.radius**2
                exit_t = (-qb + np.sqrt(np.maximum(qb * qb - 4.0 * qa * qc, 0.0))) / (2.0 * qa)
                fill = np.maximum(exit_t.astype(np.float32), lo)
                hi = np.where(np.isinf(hi) & np.isfinite(lo), fill, hi)
            z_lo[s - start] = lo
            z_hi[s - start] = np.where(np.isfinite(lo), hi, np.inf)
        return z_lo, z_hi
