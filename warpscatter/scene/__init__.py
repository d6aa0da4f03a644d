"""Scenes: the triangle soup, materials, camera, light and medium one render works on.

:func:`build_scene` turns a validated :class:`warpscatter.config.Config` into a :class:`Scene`:
mesh files loaded with trimesh and procedural generators (:mod:`.procedural`), each with its
transform (CONVENTIONS: scale, then rotation X→Y→Z, then translation) and material, concatenated
into one vertex/triangle array with a per-triangle material index. The config sections it reads are the Warp-free
models of :mod:`.mesh_configs` (meshes, transforms, materials) and :mod:`.light_configs` (each light type's model,
which builds its light).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

#: Materials below this opacity cast no shadow (the alpha test of Peters 2017 Sec. 3.3; every visibility method).
CASTER_ALPHA_TEST = 0.01

if TYPE_CHECKING:
    from .camera import Camera
    from .lights import Light
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
        brdfs: per material the BRDF of the lighting methods as
            :meth:`~warpscatter.csm.brdf.MaterialTable.from_specs` reads it, or None (Lambert with ``albedo``).
    """

    vertices: np.ndarray
    triangles: np.ndarray
    tri_material: np.ndarray
    albedo: np.ndarray
    opacity: np.ndarray
    camera: Camera
    light: Light
    medium: Medium
    receiver_only: np.ndarray | None = None
    brdfs: list[dict] | None = None

    @property
    def triangle_count(self) -> int:
        return int(self.triangles.shape[0])

    def caster_mask(self) -> np.ndarray:
        """(T,) bool: the triangles that cast shadows: their material is not ``receiver_only`` and passes the alpha
        test (opacity >= :data:`CASTER_ALPHA_TEST`, Peters 2017 Sec. 3.3)."""
        keep = np.asarray(self.opacity, np.float64)[self.tri_material] >= CASTER_ALPHA_TEST
        if self.receiver_only is None:
            return keep
        return keep & ~np.asarray(self.receiver_only, bool)[self.tri_material]

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

    def brdf_specs(self) -> list[dict]:
        """Per material the BRDF as :meth:`~warpscatter.csm.brdf.MaterialTable.from_specs` reads it (Lambert with
        ``albedo`` where the scene gives none)."""
        if self.brdfs is not None:
            return self.brdfs
        return [{"albedo": tuple(float(c) for c in a)} for a in self.albedo]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds (min, max) of all vertices, float64."""
        # column by column: the same values as v.min(axis=0) without numpy's slow axis-0 reduction of an (N, 3)
        # array (114k vertices of configs/terrain.yaml: 0.3 ms instead of 6.5 ms)
        v = np.asarray(self.vertices)
        return (np.array([v[:, k].min() for k in range(3)], np.float64),
                np.array([v[:, k].max() for k in range(3)], np.float64))


def compact_mesh(vertices, triangles) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, triangles) reduced to the vertices the triangles use, in first-index order (float32, int32)."""
    used, inverse = np.unique(np.asarray(triangles).ravel(), return_inverse=True)
    return (np.ascontiguousarray(np.asarray(vertices)[used], np.float32),
            np.ascontiguousarray(inverse.reshape(-1, 3), np.int32))


def camera_from_config(c) -> Camera:
    """The :class:`~.camera.Camera` of a validated ``camera`` section."""
    from .camera import Camera

    return Camera(position=c.position, look_at=c.look_at, up=c.up, fov_y=c.fov_y, width=c.width,
                  height=c.height, near=c.near, far=c.far)


def light_from_config(c) -> Light:
    """The host light of a validated ``light`` section: its model builds it
    (:meth:`~warpscatter.scene.light_configs.LightSettings.build`).

    Raises:
        InputFileError: a texture or environment map that cannot be read or holds values that are not radiance
            (NaN, infinite, negative), at key ``light.texture`` / ``light.map``
            (:func:`~warpscatter.imageio.read_radiance_image`).
        ConfigError: an environment map that is not a valid radiance map once scaled; an area light's texture that
            is black (where it should emit).
    """
    return c.build()


def medium_from_config(c) -> Medium:
    """The :class:`~.medium.Medium` of a validated ``medium`` section."""
    from .medium import Medium

    g = getattr(c.phase, "g", 0.0)
    return Medium(sigma_t=c.sigma_t, albedo=c.albedo, phase=c.phase.type, g=g)


def _entry_source(entry):
    """(cache key of the untransformed mesh, a function building it) of a ``scene.meshes`` entry: the file (path,
    size, times) and its loader, or the generator with its exact parameters (key None: not cacheable)."""
    from .meshes import file_key, load_mesh
    from .procedural import GENERATORS, generator_key

    if entry.path is not None:
        return file_key(entry.path), lambda: load_mesh(entry.path)
    return generator_key(entry.procedural, entry.params), lambda: GENERATORS[entry.procedural](**(entry.params or {}))


def load_entry_mesh(entry):
    """Load one ``scene.meshes`` entry (file or generator) with its transform applied.

    Meshes are cached in process (:func:`.meshes.cached_mesh`), keyed by the file (path, size, times) or the
    generator and its exact parameters, and the transform matrix: repeated renders load and generate each mesh
    once. The returned mesh's arrays are read-only (shared with the cache).
    """
    from .meshes import apply_transform, cached_mesh, transform_matrix

    t = entry.transform
    matrix = transform_matrix(t.translate, t.rotate_deg, t.scale)
    source, make = _entry_source(entry)
    return cached_mesh(None if source is None else (source, matrix.tobytes()),
                       lambda: apply_transform(make(), matrix))


def object_meshes(cfg) -> list:
    """The casting meshes of a config as rigid objects (Ritschel 2007 Sec. 4.6): for each ``scene.meshes`` entry
    that casts (not ``receiver_only``, opacity >= :data:`CASTER_ALPHA_TEST`), ``(mesh, matrix)``: its
    :class:`~.meshes.TriangleMesh` in OBJECT space (as loaded or generated, no transform; cached like
    :func:`load_entry_mesh`) and its 4x4 object -> world matrix."""
    from .meshes import cached_mesh, transform_matrix

    out = []
    for entry in cfg.scene.meshes:
        if entry.receiver_only or entry.material.opacity < CASTER_ALPHA_TEST:
            continue
        t = entry.transform
        source, make = _entry_source(entry)
        mesh = cached_mesh(None if source is None else (source, "object space"), make)
        out.append((mesh, transform_matrix(t.translate, t.rotate_deg, t.scale)))
    return out


def build_scene(cfg) -> Scene:
    """Build a :class:`Scene` from a validated config (meshes loaded and transformed, see :func:`load_entry_mesh`).

    The scene's arrays are new (writable) arrays: changing them does not touch the mesh cache.

    Raises:
        InputFileError: a mesh file that cannot be used (:class:`.meshes.MeshLoadError`), at its key
            (``scene.meshes.N.path``), or a light texture or environment map (:func:`light_from_config`).
        ConfigError: a generator that refuses its parameters, at ``scene.meshes.N.params``.
    """
    from ..errors import ConfigError, InputFileError

    verts, tris, mats, albedo, opacity = [], [], [], [], []
    base = 0
    for k, entry in enumerate(cfg.scene.meshes):
        try:
            mesh = load_entry_mesh(entry)  # float32 and int32 already
        except InputFileError as exc:  # a mesh file that cannot be used: name the entry's key
            exc.at(f"scene.meshes.{k}.path" if entry.path is not None else f"scene.meshes.{k}")
            raise
        except ValueError as exc:  # a generator refusing its parameters (pillars=100000): a config error
            if entry.path is not None:
                raise
            raise ConfigError(f"scene.meshes.{k}.params: {exc}", getattr(cfg, "source", None)) from None
        verts.append(mesh.vertices)
        tris.append(mesh.triangles + base)
        mats.append(np.full(len(mesh.triangles), k, dtype=np.int32))
        albedo.append(entry.material.albedo)
        opacity.append(entry.material.opacity)
        base += len(mesh.vertices)
    return Scene(
        vertices=np.concatenate(verts),
        triangles=np.concatenate(tris),
        tri_material=np.concatenate(mats),
        albedo=np.asarray(albedo, dtype=np.float32).reshape(-1, 3),
        opacity=np.asarray(opacity, dtype=np.float32),
        receiver_only=(np.array([m.receiver_only for m in cfg.scene.meshes], bool)
                       if any(m.receiver_only for m in cfg.scene.meshes) else None),
        brdfs=[m.material.brdf_spec() for m in cfg.scene.meshes],
        camera=camera_from_config(cfg.camera),
        light=light_from_config(cfg.light),
        medium=medium_from_config(cfg.medium),
    )


#: Names served from the Warp-side module :mod:`.geometry` (loaded on first access: building and validating
#: scenes needs no Warp).
_GEOMETRY = ("DeviceGeometry", "MeshArrays")


def __getattr__(name: str):
    if name in _GEOMETRY:
        return getattr(importlib.import_module(f"{__name__}.geometry"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
