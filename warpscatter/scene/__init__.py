"""Scenes: the triangle soup, materials, camera, light and medium one render works on.

:func:`build_scene` turns a validated config into a :class:`Scene`: meshes loaded or generated, transformed
(CONVENTIONS), concatenated with a per-triangle material index. The config sections it reads are the Warp-free models
of :mod:`.mesh_configs` and :mod:`.light_configs`.
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
        vertices: (N, 3) float32; triangles: (T, 3) int32; tri_material: (T,) int32 material index.
        albedo: (K, 3) float32 Lambert albedo; opacity: (K,) float32 (1 = opaque).
        receiver_only: (K,) bool, or None: materials left out of every visibility structure (:meth:`casters`).
        brdfs: per material the BRDF spec of the lighting methods, or None (Lambert with ``albedo``).
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
        """(T,) bool: triangles not ``receiver_only`` with opacity >= :data:`CASTER_ALPHA_TEST`."""
        keep = np.asarray(self.opacity, np.float64)[self.tri_material] >= CASTER_ALPHA_TEST
        if self.receiver_only is None:
            return keep
        return keep & ~np.asarray(self.receiver_only, bool)[self.tri_material]

    def casters(self) -> "Scene":
        """The scene of the shadow casters only, compacted (``self`` when all cast; without casters every vertex is
        kept for :meth:`bounds`). Every light-visibility computation works on it."""
        keep = self.caster_mask()
        if keep.all():
            return self
        verts, tris = compact_mesh(self.vertices, self.triangles[keep])
        if not len(tris):
            verts = self.vertices
        return replace(self, vertices=verts, triangles=tris, tri_material=self.tri_material[keep], receiver_only=None)

    def brdf_specs(self) -> list[dict]:
        """Per material the BRDF spec (Lambert with ``albedo`` where the scene gives none)."""
        if self.brdfs is not None:
            return self.brdfs
        return [{"albedo": tuple(float(c) for c in a)} for a in self.albedo]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds (min, max) of all vertices, float64."""
        # column by column: numpy's axis-0 reduction of an (N, 3) array is slow
        v = np.asarray(self.vertices)
        return (np.array([v[:, k].min() for k in range(3)], np.float64),
                np.array([v[:, k].max() for k in range(3)], np.float64))


def compact_mesh(vertices, triangles) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, triangles) reduced to the vertices the triangles use, in first-index order (float32, int32)."""
    used, inverse = np.unique(np.asarray(triangles).ravel(), return_inverse=True)
    return (np.ascontiguousarray(np.asarray(vertices)[used], np.float32),
            np.ascontiguousarray(inverse.reshape(-1, 3), np.int32))


def camera_from_config(c) -> Camera:
    from .camera import Camera

    return Camera(position=c.position, look_at=c.look_at, up=c.up, fov_y=c.fov_y, width=c.width,
                  height=c.height, near=c.near, far=c.far)


def light_from_config(c) -> Light:
    """The host light of a validated ``light`` section (:meth:`~warpscatter.scene.light_configs.LightSettings.build`).

    Raises:
        InputFileError: an unreadable or invalid texture or environment map (``light.texture`` / ``light.map``).
        ConfigError: an environment map invalid once scaled; a black area-light texture.
    """
    return c.build()


def medium_from_config(c) -> Medium:
    from .medium import Medium

    g = getattr(c.phase, "g", 0.0)
    return Medium(sigma_t=c.sigma_t, albedo=c.albedo, phase=c.phase.type, g=g)


def _entry_source(entry):
    """(cache key, builder) of a ``scene.meshes`` entry's untransformed mesh (key None: not cacheable)."""
    from .meshes import file_key, load_mesh
    from .procedural import GENERATORS, generator_key

    if entry.path is not None:
        return file_key(entry.path), lambda: load_mesh(entry.path)
    return generator_key(entry.procedural, entry.params), lambda: GENERATORS[entry.procedural](**(entry.params or {}))


def load_entry_mesh(entry):
    """Load one ``scene.meshes`` entry with its transform applied, cached in process (read-only arrays)."""
    from .meshes import apply_transform, cached_mesh, transform_matrix

    t = entry.transform
    matrix = transform_matrix(t.translate, t.rotate_deg, t.scale)
    source, make = _entry_source(entry)
    return cached_mesh(None if source is None else (source, matrix.tobytes()),
                       lambda: apply_transform(make(), matrix))


def object_meshes(cfg) -> list:
    """``(mesh in object space, 4x4 object -> world matrix)`` of each casting ``scene.meshes`` entry: the rigid
    objects of Ritschel 2007 Sec. 4.6."""
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

    Raises:
        InputFileError: an unusable mesh file (at ``scene.meshes.N.path``) or light image.
        ConfigError: a generator that refuses its parameters, at ``scene.meshes.N.params``.
    """
    from ..errors import ConfigError, InputFileError

    verts, tris, mats, albedo, opacity = [], [], [], [], []
    base = 0
    for k, entry in enumerate(cfg.scene.meshes):
        try:
            mesh = load_entry_mesh(entry)
        except InputFileError as exc:
            exc.at(f"scene.meshes.{k}.path" if entry.path is not None else f"scene.meshes.{k}")
            raise
        except ValueError as exc:  # a generator refusing its parameters
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


#: Names served lazily from the Warp-side :mod:`.geometry`, so building scenes needs no Warp.
_GEOMETRY = ("DeviceGeometry", "MeshArrays")


def __getattr__(name: str):
    if name in _GEOMETRY:
        return getattr(importlib.import_module(f"{__name__}.geometry"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
