"""The ``rectify`` pass: the light's view in rectified coordinates for this camera and light (:mod:`..rectify`):
``projective`` (Klehm 2014 Sec. 4.2: the scene rasterized per light-frustum region with depth clamping), ``nonlinear``
(Peters 2017 Sec. 5.1.1, App. A: the shadow map resampled in spherical light coordinates by point taps, supersampled,
or filtered during resampling, :func:`resample_filtered`), or ``auto``: projective unless an epipole lies in or near
the image (:func:`~..rectify.params.build_rectification`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import warp as wp

from ...runtime.stages import StageTimer
from ...shadows import translucency
from ..rectify.bounds import NonlinearRectification
from ..rectify.nonlinear import (
    radial_samples_for,
    resample_footprint_texels,
    resample_moment_shadow_map,
    resample_shadow_map,
)
from ..rectify.params import build_rectification
from ..rectify.projective import ProjectiveRectification, rasterize_rectified
from ..rectify.taps import SparseRectifiedDepth
from ..settings import MAX_RESAMPLE_FILTER_PX, PrefilteredSettings


@dataclass
class Rectified:
    """The ``rectify`` pass's result."""

    rect: ProjectiveRectification | NonlinearRectification  # the rectification
    choice: object  # why it was chosen (:func:`~..rectify.params.build_rectification`)
    depth: object  # the rectified depth map (a (rows, cols) wp.array or a SparseRectifiedDepth)
    info: dict = field(default_factory=dict)  # resample_filter, resample_samples, resample_filter_px

    @property
    def nonlinear(self) -> bool:
        """Whether the rectification is the non-linear one (columns: equal steps along each view ray)."""
        return isinstance(self.rect, NonlinearRectification)


def rectify_map(frame, p: PrefilteredSettings, size: tuple[int, int], stage: StageTimer, device) -> Rectified:
    """Choose the rectification of ``frame`` and rectify its light's view (stage ``rectify``; ``resample_msm`` too
    when filtering during resampling). ``size``: (cols, rows) of the rectified map."""
    scene, shadow_map = frame.scene, frame.shadow_map
    cols, rows = size
    samples = 0
    with stage("rectify"):
        rect, choice = build_rectification(scene, p, rows, cols)
        nonlinear = isinstance(rect, NonlinearRectification)
        filtered_resampling = nonlinear and p.resample_filter == "moments"
        depth = None
        if not nonlinear:
            casters = scene.casters()
            depth = rasterize_rectified(rect, casters.vertices, casters.triangles,
                                        opacity=translucency.triangle_opacity(casters), device=device)
        elif not filtered_resampling:
            if p.resample_filter == "supersample":
                samples = radial_samples_for(rect, shadow_map.texel_world)
            depth = resample_shadow_map(
                rect, shadow_map.device_depth(device), shadow_map.view_projection, depth="linear",
                world_to_view=shadow_map.view, radial_samples=samples, device=device,
                translucency=_translucent_layer(shadow_map, device))
    info = {"resample_filter": p.resample_filter if nonlinear else "none"}
    if nonlinear and p.resample_filter == "supersample":
        info["resample_samples"] = samples
    if filtered_resampling:
        depth, info["resample_filter_px"] = resample_filtered(scene, rect, shadow_map, p, stage, device)
    return Rectified(rect, choice, depth, info)


def _translucent_layer(shadow_map, device):
    """(opaque depth, transmittance) of a translucent shadow map on ``device``, or None."""
    if not shadow_map.translucent:
        return None
    layers = shadow_map.device_layers(device=device)
    return layers.opaque, layers.transmittance


def resample_filtered(scene, rect: NonlinearRectification, shadow_map, settings: PrefilteredSettings,
                      stage: StageTimer, device) -> tuple:
    """Filtering during resampling (Peters 2017 Sec. 5.2): stage ``resample_msm`` makes the light view's 128-bit
    4-moment map (2x2 supersampled) and Gaussian-filters it (``resample_filter_px``, default the radial rectified
    texel footprint); stage ``rectify`` resamples it with Algorithm 2. Returns (:class:`~..SparseRectifiedDepth`, the
    Gaussian width in shadow-map texels)."""
    from ...shadows import msm as msm_maps

    filter_px = settings.resample_filter_px
    if filter_px is None:
        filter_px = int(np.clip(round(resample_footprint_texels(rect, shadow_map.texel_world)), 1,
                                MAX_RESAMPLE_FILTER_PX))
    with stage("resample_msm"):
        moments = msm_maps.filter_moment_shadow_map(
            msm_maps.generate_moment_shadow_map(scene, shadow_map, supersampling=2, bits=128, device=device),
            filter_px, device=device)
    with stage("rectify"):
        depth = shadow_map.depth.numpy() if isinstance(shadow_map.depth, wp.array) else np.asarray(shadow_map.depth)
        finite = depth[np.isfinite(depth)]
        farthest = float(finite.max()) if finite.size else None  # the map's farthest caster (linear light depth)
        return (resample_moment_shadow_map(rect, moments, farthest_caster=farthest, device=device),
                int(filter_px))


def map_depth(rectified) -> np.ndarray:
    """(rows, cols) float32 rectified depth of a map (its first depth when it holds two)."""
    depth = rectified.z1 if isinstance(rectified, SparseRectifiedDepth) else rectified
    return depth.numpy()


__all__ = ["Rectified", "map_depth", "rectify_map", "resample_filtered"]
