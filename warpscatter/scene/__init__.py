"""Scenes: the triangle soup, materials, camera, light and medium one render works on.

:func:`build_scene` turns a validated :class:`warpscatter.config.Config` into a :class:`Scene`:
mesh files loaded with trimesh and procedural generators (:mod:`.procedural`), each with its
transform (CONVENTIONS: scale, then rotation X→Y→Z, then translation) and material, concatenated
into one vertex/triangle array with a per-triangle material index.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import warp as wp

from .camera import Camera
from .lights import DirectionalLight, SpotLight
from .medium import Medium


@dataclass
class Scene:
    """Everything a render needs, in world space (scene units).

    Attributes:
        vertices: (N, 3) float32 world-space positions.
        triangles: (T, 3) int32 vertex indices.
        tri_material: (T,) int32 index into ``albedo``/``opacity``.
        albedo: (K, 3) float32 Lambert albedo per material.
        opacity: (K,) float32 opacity per material (1 = opaque).
        camera, light, medium: see their modules.
        receiver_only: (K,) bool per material, or None (all cast): materials that receive shadows but cast none
            (config ``scene.meshes.N.receiver_only``). They are left out of every shadow map, moment map, rectified
            map, exact-visibility BVH and CSM; see :meth:`casters`.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    tri_material: np.ndarray
    albedo: np.ndarray
    opacity: np.ndarray
    camera: Camera
    light: DirectionalLight | SpotLight
    medium: Medium
    receiver_only: np.ndarray | None = None

    @property
    def triangle_count(self) -> int:
        return int(self.triangles.shape[0])

    def caster_mask(self) -> np.ndarray:
        """(T,) bool: the triangles that cast shadows (their material is not ``receiver_only``)."""
        if self.receiver_only is None:
            return np.ones(self.triangle_count, bool)
        return ~np.asarray(self.receiver_only, bool)[self.tri_material]

    def casters(self) -> "Scene":
        """This scene's shadow casters: ``self`` when every material casts, else a copy holding only the casting
        triangles, compacted to the vertices they use (materials, camera, light and medium unchanged). With no
        caster at all the copy keeps every vertex (so :meth:`bounds` stays the scene's) and has no triangle.

        Everything that computes light visibility works on it; only the camera's view (G-buffer) sees receivers.
        """
        keep = self.caster_mask()
        if keep.all():
            return self
        verts, tris = compact_mesh(self.vertices, self.triangles[keep])
        if not len(tris):
            verts = self.vertices
        return replace(self, vertices=verts, triangles=tris, tri_material=self.tri_material[keep], receiver_only=None)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds (min, max) of all vertices, float64."""
        v = self.vertices.astype(np.float64)
        return v.min(axis=0), v.max(axis=0)


def compact_mesh(vertices, triangles) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, triangles) reduced to the vertices the triangles use, in first-index order (float32, int32)."""
    used, inverse = np.unique(np.asarray(triangles).ravel(), return_inverse=True)
    return (np.ascontiguousarray(np.asarray(vertices)[used], np.float32),
            np.ascontiguousarray(inverse.reshape(-1, 3), np.int32))


class DeviceGeometry:
    """A scene's triangles on a Warp device, with the ``wp.Mesh`` BVH built on first use.

    Attributes:
        vertices: wp.array(vec3) world positions.
        triangles: wp.array2d(int32) (T, 3) indices.
        tri_material: wp.array(int32) material per triangle.
    """

    def __init__(self, scene: "Scene", device=None):
        from ..wpinit import default_device

        self.device = default_device(device)
        self.vertices = wp.array(scene.vertices, dtype=wp.vec3, device=self.device)
        self.triangles = wp.array(scene.triangles, dtype=wp.int32, device=self.device)
        self.tri_material = wp.array(scene.tri_material, dtype=wp.int32, device=self.device)
        self._indices = wp.array(scene.triangles.ravel(), dtype=wp.int32, device=self.device)
        self._mesh = None
        casters = scene.casters()
        self._casters = None if casters is scene else casters  # None: every triangle casts
        self._shadow_mesh = None

    @property
    def mesh(self) -> wp.Mesh:
        """The BVH (``wp.Mesh``) over the triangles; built once, on first access."""
        if self._mesh is None:
            self._mesh = wp.Mesh(points=self.vertices, indices=self._indices)
        return self._mesh

    @property
    def shadow_mesh(self) -> wp.Mesh:
        """The BVH of the shadow casters (:meth:`Scene.casters`), for exact visibility; :attr:`mesh` when every
        material casts. Built once, on first access.

        Raises:
            ValueError: when every material is ``receiver_only`` (nothing casts).
        """
        if self._casters is None:
            return self.mesh
        if self._shadow_mesh is None:
            if self._casters.triangle_count == 0:
                raise ValueError("scene: every mesh is receiver_only, so nothing casts a shadow")
            from ..raycast import build_mesh

            self._shadow_mesh = build_mesh(self._casters.vertices, self._casters.triangles, device=self.device)
        return self._shadow_mesh


def camera_from_config(c) -> Camera:
    return Camera(position=c.position, look_at=c.look_at, up=c.up, fov_y=c.fov_y, width=c.width,
                  height=c.height, near=c.near, far=c.far)


def light_from_config(c) -> DirectionalLight | SpotLight:
    if c.type in ("environment", "area", "linear"):  # Monte-Carlo lights of render.lighting (warpscatter.csm)
        from ..csm.render import light_from_config as mc_light_from_config

        return mc_light_from_config(c)
    if c.type == "directional":
        return DirectionalLight(direction=c.direction, irradiance=c.irradiance)
    texture = None
    if c.texture is not None:
        from ..imageio import read_image

        texture = read_image(c.texture)[..., :3].astype(np.float32)
        if texture.shape[-1] == 1:
            texture = np.repeat(texture, 3, axis=-1)
    return SpotLight(position=c.position, direction=c.direction, cone_deg=c.cone_deg, intensity=c.intensity,
                     texture=texture)


def medium_from_config(c) -> Medium:
    g = getattr(c.phase, "g", 0.0)
    return Medium(sigma_t=c.sigma_t, albedo=c.albedo, phase=c.phase.type, g=g)


def load_entry_mesh(entry):
    """Load one ``scene.meshes`` entry (file or generator) with its transform applied."""
    from .meshes import apply_transform, load_mesh, transform_matrix
    from .procedural import GENERATORS

    if entry.path is not None:
        mesh = load_mesh(entry.path)
    else:
        mesh = GENERATORS[entry.procedural](**(entry.params or {}))
    t = entry.transform
    return apply_transform(mesh, transform_matrix(t.translate, t.rotate_deg, t.scale))


def build_scene(cfg) -> Scene:
    """Build a :class:`Scene` from a validated config (meshes loaded and transformed)."""
    verts, tris, mats, albedo, opacity = [], [], [], [], []
    base = 0
    for k, entry in enumerate(cfg.scene.meshes):
        mesh = load_entry_mesh(entry)
        verts.append(mesh.vertices.astype(np.float32))
        tris.append(mesh.triangles.astype(np.int32) + base)
        mats.append(np.full(len(mesh.triangles), k, dtype=np.int32))
        albedo.append(entry.material.albedo)
        opacity.append(entry.material.opacity)
        base += len(mesh.vertices)
    return Scene(
        vertices=np.ascontiguousarray(np.concatenate(verts), dtype=np.float32),
        triangles=np.ascontiguousarray(np.concatenate(tris), dtype=np.int32),
        tri_material=np.concatenate(mats),
        albedo=np.asarray(albedo, dtype=np.float32).reshape(-1, 3),
        opacity=np.asarray(opacity, dtype=np.float32),
        receiver_only=(np.array([m.receiver_only for m in cfg.scene.meshes], bool)
                       if any(m.receiver_only for m in cfg.scene.meshes) else None),
        camera=camera_from_config(cfg.camera),
        light=light_from_config(cfg.light),
        medium=medium_from_config(cfg.medium),
    )
