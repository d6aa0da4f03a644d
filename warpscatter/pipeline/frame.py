"""What the classic pipeline hands a scattering method: one frame's scene, G-buffer, BVH and shadow map."""

from __future__ import annotations

from dataclasses import dataclass

import warp as wp

from ..runtime.device import default_device


@dataclass
class Frame:
    """The inputs of a scattering method's ``render(frame, settings, stage)`` (:mod:`warpscatter.methods`).

    Attributes:
        scene: the :class:`~warpscatter.scene.Scene`.
        gbuffer: the camera :class:`~..raster.gbuffer.GBuffer` (hit distance s per pixel).
        geometry: the scene's :class:`~warpscatter.scene.DeviceGeometry` (casters' BVH); None without shadow rays.
        shadow_map: the light's :class:`~warpscatter.shadows.shadow_map.ShadowMap`, or None.
        aovs: the requested outputs (``output.aovs``): a method makes the debug ones it lists
            (:attr:`~warpscatter.methods.Method.debug_aovs`) and returns them in ``info["debug_images"]``.
    """

    scene: object
    gbuffer: object
    geometry: object | None = None
    shadow_map: object | None = None
    device: str | wp.context.Device | None = None
    aovs: tuple[str, ...] = ()

    def __post_init__(self):
        self.device = default_device(self.device)


__all__ = ["Frame"]
