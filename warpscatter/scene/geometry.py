"""A scene's triangles on a Warp device: the arrays kernels read and the BVHs (``wp.Mesh``) of exact visibility."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from ..runtime.device import default_device, module_options

if TYPE_CHECKING:
    from . import Scene

module_options()


@wp.struct
class MeshArrays:
    """A scene's triangles as kernels see them (:meth:`DeviceGeometry.arrays`)."""

    vertices: wp.array(dtype=wp.vec3)
    triangles: wp.array2d(dtype=wp.int32)
    tri_material: wp.array(dtype=wp.int32)


class DeviceGeometry:
    """A scene's triangles on a Warp device (``vertices``, ``triangles``, ``tri_material``), with BVHs on first use."""

    def __init__(self, scene: Scene, device=None):
        self.device = default_device(device)
        self.vertices = wp.array(scene.vertices, dtype=wp.vec3, device=self.device)
        self.triangles = wp.array(scene.triangles, dtype=wp.int32, device=self.device)
        self.tri_material = wp.array(scene.tri_material, dtype=wp.int32, device=self.device)
        self._indices = wp.array(scene.triangles.ravel(), dtype=wp.int32, device=self.device)
        self._host = (scene.vertices, scene.triangles)  # the BVH cache's key
        self._mesh = None
        casters = scene.casters()
        self._casters = None if casters is scene else casters  # None: every triangle casts
        self._shadow_mesh = None
        self._caster_transmittance = (1.0 - np.asarray(casters.opacity, np.float32)[casters.tri_material]).astype(
            np.float32) if len(casters.triangles) else np.zeros(0, np.float32)
        self._caster_transmittance_array = None

    def arrays(self) -> MeshArrays:
        """The triangles as kernels see them."""
        m = MeshArrays()
        m.vertices, m.triangles, m.tri_material = self.vertices, self.triangles, self.tri_material
        return m

    @property
    def mesh(self) -> wp.Mesh:
        """The BVH (``wp.Mesh``) over the triangles, built or reused (:func:`..raster.raycast.cached_bvh`)."""
        if self._mesh is None:
            from ..raster.raycast import cached_bvh

            self._mesh = cached_bvh(*self._host, device=self.device)
        return self._mesh

    @property
    def shadow_mesh(self) -> wp.Mesh:
        """The BVH of the shadow casters (:meth:`Scene.casters`) for exact visibility, built once; ValueError when
        every material is ``receiver_only`` (nothing casts)."""
        if self._casters is None:
            return self.mesh
        if self._shadow_mesh is None:
            if self._casters.triangle_count == 0:
                raise ValueError("scene: every mesh is receiver_only, so nothing casts a shadow")
            from ..raster.raycast import cached_bvh

            self._shadow_mesh = cached_bvh(self._casters.vertices, self._casters.triangles, device=self.device)
        return self._shadow_mesh


    @property
    def translucent_casters(self) -> bool:
        """True when some shadow caster has opacity < 1 (exact visibility then multiplies their transmittances)."""
        return bool(np.any(self._caster_transmittance > 0.0))

    @property
    def caster_transmittance(self) -> wp.array:
        """(T,) float32 1 - opacity of each triangle of :attr:`shadow_mesh` (its ``face`` order); built once."""
        if self._caster_transmittance_array is None:
            t = self._caster_transmittance if len(self._caster_transmittance) else np.zeros(1, np.float32)
            self._caster_transmittance_array = wp.array(t, dtype=wp.float32, device=self.device)
        return self._caster_transmittance_array


__all__ = ["DeviceGeometry", "MeshArrays"]
