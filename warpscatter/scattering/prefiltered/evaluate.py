"""The ``evaluate`` pass of a directional light (Klehm 2014 Listing 4, Peters 2017 D.5): per pixel, the G-buffer hit
-> rectified (u, v, z_r) -> its row mip level -> the filtered look-up (:mod:`.lookups`) -> times sigma_s f E
(1 - e^{-sigma_t s}) / sigma_t, on the pixels :mod:`..sparse_evaluation` asks for. :class:`Evaluation` builds the
kernel's arguments once per frame and picks its compiled :class:`EvaluateVariant` (each field a ``wp.static`` branch;
the choices that change little code stay at run time, so that the variants stay few).

With a directional light ahead of the camera each ray's end is tested lit or in shadow (:func:`.lookups.ray_ends_lit`):
a lit end reads ``lit_shift`` further; a shadowed end whose whole look-up lies in its end surface's zone is left to the
marcher (``end_zone``); other shadowed ends, more than :data:`~..settings.END_SAMPLES_MIN_DEG` from the light and with
at least :data:`~..settings.END_STRETCH_MIN_WEIGHT` of the weight in the left-out stretch, sample that stretch in the
shadow map (``end_samples``, :func:`~..marching.stretch_visibility`).
"""

import functools
from dataclasses import dataclass

import numpy as np
import warp as wp

from ...runtime.device import MODULE_OPTIONS, default_device
from ...runtime.parallel import launch_rows
from ...scene.camera import CameraParams, pixel_ray_direction
from ...scene.lights import LightParams, faces_away_from_light, light_params
from ...scene.medium import MediumParams, coloured_scattering, phase_eval, transmittance_integral
from ..marching import Visibility, end_surface_at, stretch_visibility, visibility_params
from ..rectify.bounds import NonlinearRectification
from ..rectify.caster_culling import end_faces_away
from ..rectify.params import RectificationParams, rectification_params, rectified_coords, wrap_rows
from ..settings import END_SAMPLES_MIN_DEG, EVALUATE_DEPTH_TOLERANCE, ScatteringSettings
from ..sparse_evaluation import PIXELS_ALL, PIXELS_GRID, PixelSet, evaluate_sparse, grid_size, pixel_set, set_pixel
from .epipole_regions import MarchedCones, marched_cones, wholly_marched
from .filtered_lookups import RAY_END_IN_SHADOW, RAY_END_LIT, RAY_END_UNKNOWN, DepthBounds
from .lookups import STRETCH_MIN_WEIGHT, left_out_start, mipped_visibility, ray_ends_lit, with_left_out_stretch
from .ray_weights import ChannelRayWeights, RayWeights, looked_up_share, ray_weights
from .row_mips import RowMips, pixel_mip_level
from .textures import FilteredBasis, FilteredBasisArrays, FilteredMomentArrays

#: The Warp module of the fixed per-pixel kernels (the method registry preloads it; the variants compile apart).
KERNELS = __name__
wp.set_module_options(MODULE_OPTIONS, module=KERNELS)


@wp.struct
class PixelEnds:
    """Where each pixel's view ray ends, and what is known of the end before the look-up."""

    distance: wp.array2d(dtype=wp.float32)  # G-buffer camera distance of the hit (world units)
    normal: wp.array2d(dtype=wp.vec3)  # G-buffer camera-facing normal (the end surface's bias guard)
    coords: wp.array2d(dtype=wp.vec3)  # rectified (u, v, z_r) of each end (pixel_coords), or unset (shape 0) ...
    rect: RectificationParams  # ... and the rectification computes them at the pixels evaluated


@wp.struct
class MapLookUp:
    """The prefiltered map and how a ray reads it."""

    weights: RayWeights  # how a ray weights its texels (reference ray or per-ray segments)
    channel_weights: ChannelRayWeights  # each channel's own: coloured variants
    bounds: DepthBounds  # per-row prefix depth bounds: wholly lit / shadowed rays skip the reconstruction
    mips: RowMips  # the texture's row mip levels and whether its rows wrap around (wrap_rows)
    beta: wp.vec4  # the moments' overestimation weight and its taper (lookups.representation_visibility)


@wp.struct
class EndStretch:
    """The shadow map's answers at a ray's end: lit or in shadow, and the stretch a look-up leaves out."""

    vis: Visibility  # the light's shadow map
    samples: int  # most samples of a left-out end stretch (0: it takes the look-up's visibility)
    cos_max: float  # cos END_SAMPLES_MIN_DEG: rays looking closer into the light keep the look-up's
    lit_shift: float  # u by which the look-up of a ray ending lit ends later (end_offsets_for: their difference)


@wp.struct
class LookUpOutputs:
    """What the look-up writes."""

    radiance: wp.array2d(dtype=wp.vec3)  # in-scattered radiance per pixel
    end_zone: wp.array2d(dtype=wp.int32)  # 1 where the look-up is left to the marcher, else 0
    end_zone_any: wp.array(dtype=wp.int32)  # [0] set to 1 when any pixel is (a plain store: no race to lose)


@dataclass(frozen=True)
class EvaluateVariant:
    """What one compiled look-up kernel is specialised for (each field a ``wp.static`` branch)."""

    texels: type  # FilteredBasisArrays (Fourier) or FilteredMomentArrays (moments)
    coloured: bool  # a coloured medium: one look-up per channel, each with its own ray weights
    lit_end_test: bool  # each ray's end is tested lit or in shadow (a directional light ahead of the camera)


@functools.cache
def evaluate_prefiltered_kernel(variant: EvaluateVariant) -> wp.Kernel:
    """The look-up kernel of a :class:`EvaluateVariant` (compiled in a module of its own on first launch)."""
    Texels = variant.texels  # noqa: N806 (a type)
    coloured, lit_end_test = variant.coloured, variant.lit_end_test

    def evaluate_prefiltered(cam: CameraParams, ends: PixelEnds, texels: Texels, look: MapLookUp, light: LightParams,
                             med: MediumParams, stretch: EndStretch, result: LookUpOutputs, marched: MarchedCones,
                             pixels: PixelSet, offset: int):
        a, b = wp.tid()
        j, i, listed = set_pixel(pixels, cam.height, cam.width, a + offset, b)
        if not listed:
            return
        d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
        if wholly_marched(marched, d, i, j):  # the epipole disc's march replaces whatever is here
            result.radiance[j, i] = wp.vec3(0.0, 0.0, 0.0)
            result.end_zone[j, i] = 0
            return
        s = ends.distance[j, i]
        phase = phase_eval(med.phase_id, med.g, wp.dot(light.direction, -d))
        lv = pixel_mip_level(look.mips, ends.coords, j, i)
        x_end = cam.position + d * s  # the ray's end point
        c = wp.vec3()
        if ends.coords.shape[0] != 0:
            c = ends.coords[j, i]
        else:
            c = rectified_coords(ends.rect, x_end)
        in_end_zone = int(0)
        ray_end = int(RAY_END_UNKNOWN)  # what the depth bounds may assume of the ray's end (row_bounds)
        if wp.static(lit_end_test):
            away = int(faces_away_from_light(light, x_end, ends.normal[j, i]))  # as caster_culling.end_faces_away
            if ray_ends_lit(x_end, ends.normal[j, i], away, light, stretch.vis):
                c = wp.vec3(c[0] + stretch.lit_shift, c[1], c[2])
                ray_end = RAY_END_LIT
            else:
                ray_end = RAY_END_IN_SHADOW
            if ray_end == RAY_END_IN_SHADOW and c[0] * float(look.weights.cols) <= look.weights.end_offset:
                in_end_zone = 1  # the whole look-up lies within the end surface's own zone: the marcher takes it
                result.end_zone_any[0] = 1
        result.end_zone[j, i] = in_end_zone
        if in_end_zone != 0:
            result.radiance[j, i] = wp.vec3(0.0, 0.0, 0.0)
            return
        march_end = False  # the end stretch's visibility sampled from the shadow map (module doc)
        v_end = float(0.0)
        share = float(1.0)
        if wp.static(lit_end_test):
            march_end = (stretch.samples > 0 and ray_end == RAY_END_IN_SHADOW and c[0] <= 1.0
                         and look.weights.end_offset > 0.0 and -wp.dot(light.direction, d) < stretch.cos_max)
            if march_end:  # ... when the stretch carries enough of the ray's weight to matter
                share = looked_up_share(look.weights, c[0], c[2])
                march_end = share < 1.0 - STRETCH_MIN_WEIGHT
            if march_end:
                end = end_surface_at(stretch.vis, light, x_end, ends.normal[j, i])
                v_end = stretch_visibility(stretch.vis, end, cam.position, d, left_out_start(look.weights, c[0], s),
                                           s, med.sigma_t, stretch.samples)
        if wp.static(not coloured):
            f = mipped_visibility(texels, look.weights, look.bounds, look.mips, lv, c, look.beta, light.direction, d,
                                  ray_end)
            if march_end:
                f = with_left_out_stretch(f, share, v_end)
            result.radiance[j, i] = light.radiance * (med.sigma_s * phase * f
                                                      * transmittance_integral(med.sigma_t, 0.0, s))
        else:  # one look-up per channel, each with the channel's own ray weights
            cw = look.channel_weights
            f_rgb = wp.vec3(
                mipped_visibility(texels, cw.r, look.bounds, look.mips, lv, c, look.beta, light.direction, d,
                                  ray_end),
                mipped_visibility(texels, cw.g, look.bounds, look.mips, lv, c, look.beta, light.direction, d,
                                  ray_end),
                mipped_visibility(texels, cw.b, look.bounds, look.mips, lv, c, look.beta, light.direction, d,
                                  ray_end))
            if march_end:
                f_rgb = wp.vec3(with_left_out_stretch(f_rgb[0], looked_up_share(cw.r, c[0], c[2]), v_end),
                                with_left_out_stretch(f_rgb[1], looked_up_share(cw.g, c[0], c[2]), v_end),
                                with_left_out_stretch(f_rgb[2], looked_up_share(cw.b, c[0], c[2]), v_end))
            result.radiance[j, i] = wp.cw_mul(coloured_scattering(med, light.radiance, 0.0, s), f_rgb) * phase

    return wp.kernel(evaluate_prefiltered, module="unique", module_options=dict(MODULE_OPTIONS))


def every_evaluate_kernel() -> list[wp.Kernel]:
    """The look-up kernel of every :class:`EvaluateVariant` (what the CUDA compile check builds)."""
    return [evaluate_prefiltered_kernel(EvaluateVariant(texels, coloured, lit_end_test))
            for texels in (FilteredBasisArrays, FilteredMomentArrays) for coloured in (False, True)
            for lit_end_test in (False, True)]


@wp.kernel(module=KERNELS)
def pixel_coords_kernel(cam: CameraParams, distance: wp.array2d(dtype=wp.float32), rect: RectificationParams,
                        out: wp.array2d(dtype=wp.vec3), pixels: PixelSet, offset: int):
    # the rectified (u, v, z_r) of every listed pixel's view-ray end (its G-buffer hit)
    a, b = wp.tid()
    j, i, listed = set_pixel(pixels, cam.height, cam.width, a + offset, b)
    if not listed:
        return
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    out[j, i] = rectified_coords(rect, cam.position + d * distance[j, i])


@wp.kernel(module=KERNELS)
def lit_ray_ends_kernel(cam: CameraParams, distance: wp.array2d(dtype=wp.float32), normal: wp.array2d(dtype=wp.vec3),
                        faces_away: wp.array2d(dtype=wp.int32), light: LightParams, vis: Visibility,
                        out: wp.array2d(dtype=wp.int32), offset: int):
    j, i = wp.tid()
    j += offset
    x = cam.position + pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5) * distance[j, i]
    out[j, i] = ray_ends_lit(x, normal[j, i], faces_away[j, i], light, vis)


@wp.kernel(module=KERNELS)
def pixel_phase_kernel(cam: CameraParams, light: LightParams, med: MediumParams, out: wp.array2d(dtype=wp.float32),
                       pixels: PixelSet, offset: int):
    # each view ray's phase function (one angle under a directional light), which evaluate_sparse divides out (> 0)
    a, b = wp.tid()
    j, i, listed = set_pixel(pixels, cam.height, cam.width, a + offset, b)
    if not listed:
        return
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    out[j, i] = wp.max(phase_eval(med.phase_id, med.g, wp.dot(light.direction, -d)), 1.0e-30)


def pixel_coords(rect, camera, distance: wp.array, device=None, pixels: "PixelSet | None" = None,
                 dim: tuple[int, int] | None = None, out: wp.array | None = None) -> wp.array:
    """(H, W) vec3: the rectified (u, v, z_r) of every pixel's view-ray end, or only of ``pixels`` (a
    :class:`~..sparse_evaluation.PixelSet` launched over ``dim``) written into ``out``."""
    device = default_device(device)
    if out is None:
        out = wp.empty((camera.height, camera.width), dtype=wp.vec3, device=device)
    if pixels is None:
        pixels, dim = pixel_set(PIXELS_ALL, device=device), (camera.height, camera.width)
    launch_rows(pixel_coords_kernel, dim, [camera.params(), distance, rectification_params(rect), out, pixels],
                device=device)
    return out


def coords_of_every_pixel(settings: ScatteringSettings, aovs) -> bool:
    """Whether a render needs every pixel's rectified coordinates before its look-up (caster culling, row mips, the
    ``rectified`` and ``mip_level`` debug outputs); otherwise the look-up computes them where it runs."""
    return (settings.culls_casters or settings.prefiltered.mip_levels > 1
            or bool({"rectified", "mip_level"} & set(aovs)))


def lit_ray_ends(scene, gbuffer, shadow_map, bias_texels: float, faces_away: wp.array | None = None,
                 device=None) -> wp.array:
    """(H, W) int32: :func:`~.lookups.ray_ends_lit` of every pixel (shadow-map depth bias ``bias_texels``), the look-up
    kernel's test at every pixel; ``faces_away``: :func:`~..rectify.caster_culling.end_faces_away` if already made."""
    device = default_device(device)
    cam = scene.camera
    light = light_params(scene.light, device)
    if faces_away is None:
        faces_away = end_faces_away(cam, gbuffer, light, device)
    out = wp.empty((cam.height, cam.width), dtype=wp.int32, device=device)
    vis = visibility_params(scene, "shadow_map", shadow_map=shadow_map, shadow_bias_texels=bias_texels, device=device)
    launch_rows(lit_ray_ends_kernel, (cam.height, cam.width),
                [cam.params(), gbuffer.distance, gbuffer.normal, faces_away, light, vis, out], device=device)
    return out


class Evaluation:
    """The ``evaluate`` pass of one frame under a directional light (module doc).

    Args:
        frame: the :class:`~warpscatter.pipeline.frame.Frame` (G-buffer, shadow map, scene).
        settings: the method's :class:`~..settings.ScatteringSettings`.
        rect: the frame's rectification (:mod:`.rectify`).
        filtered: the frame's :class:`~.prefilter.Prefiltered` map.
        coords: every pixel's rectified coordinates (:func:`pixel_coords`), or None: computed at the pixels evaluated.
        regions: the epipole regions ray-marched afterwards (:func:`~.epipole_regions.epipole_regions`).
    """

    def __init__(self, frame, settings: ScatteringSettings, rect, filtered, coords: wp.array | None, regions: list,
                 device):
        scene, gbuffer, cam = frame.scene, frame.gbuffer, frame.scene.camera
        p = settings.prefiltered
        self.device = device
        self.settings = settings
        self.frame = frame
        cols = settings.shadow_map.size[0]
        nonlinear = rect if isinstance(rect, NonlinearRectification) else None
        # (rays ending in shadow, lit), in texels of a map reaching the view (a fixed world distance along the rays);
        # a ray ending lit moves its end by the difference
        self.end_offsets = p.end_offsets_for(filtered.light_behind)
        column_scale = nonlinear.column_scale if nonlinear is not None else 1.0
        end_offset = self.end_offsets[0] * column_scale
        lit_end_test = not filtered.light_behind
        self.end_samples = p.end_samples if lit_end_test and nonlinear is not None else 0
        texels = FilteredBasisArrays if isinstance(filtered.texture, FilteredBasis) else FilteredMomentArrays
        self.variant = EvaluateVariant(texels, bool(scene.medium.coloured), lit_end_test)

        def weights_for(sigma_t: float) -> RayWeights:
            return ray_weights(filtered.segments, filtered.chain.optical_step, nonlinear, sigma_t, end_offset,
                               device=device, cols=cols, segment_depth=filtered.segment_depth)

        ends = PixelEnds()
        ends.distance, ends.normal = gbuffer.distance, gbuffer.normal
        ends.rect = rectification_params(rect)
        if coords is not None:
            ends.coords = coords
        look = MapLookUp()
        look.weights = weights_for(filtered.sigma_ref)
        if self.variant.coloured:
            look.channel_weights = ChannelRayWeights()
            if filtered.segments > 1:
                look.channel_weights.r, look.channel_weights.g, look.channel_weights.b = (
                    weights_for(sigma) for sigma in scene.medium.sigma_t_rgb)
            else:
                look.channel_weights.r = look.channel_weights.g = look.channel_weights.b = look.weights
        look.bounds = filtered.bounds
        look.mips = filtered.chain.params(wrap_rows(rect))
        m = settings.moments
        look.beta = wp.vec4(*m.beta_range(), m.epipole_taper(), m.overestimation_rise_cos)
        stretch = EndStretch()
        stretch.vis = visibility_params(scene, "shadow_map", shadow_map=frame.shadow_map,
                                        shadow_bias_texels=settings.shadow_map.bias, device=device)
        stretch.samples = self.end_samples
        stretch.cos_max = float(np.cos(np.radians(END_SAMPLES_MIN_DEG)))
        stretch.lit_shift = (self.end_offsets[0] - self.end_offsets[1]) * column_scale / cols
        result = LookUpOutputs()
        result.radiance = wp.empty((cam.height, cam.width), dtype=wp.vec3, device=device)
        result.end_zone = wp.zeros((cam.height, cam.width), dtype=wp.int32, device=device)
        result.end_zone_any = wp.zeros(1, dtype=wp.int32, device=device)
        self.result = result
        self.light = light_params(scene.light, device)
        self.medium = scene.medium.params()
        self.inputs = [cam.params(), ends, filtered.texture.arrays(), look, self.light, self.medium, stretch, result,
                       marched_cones(regions)]
        self.kernel = evaluate_prefiltered_kernel(self.variant)

    def look_up(self, pixels: PixelSet, dim: tuple[int, int]) -> None:
        """Run the look-up on a :class:`~..sparse_evaluation.PixelSet` launched over ``dim``."""
        launch_rows(self.kernel, dim, [*self.inputs, pixels], device=self.device)

    def run(self):
        """Evaluate the frame's pixels (:func:`~..sparse_evaluation.evaluate_sparse`).

        Returns:
            (radiance (H, W) vec3 wp.array, :class:`~..sparse_evaluation.SparseEvaluation`).
        """
        p, cam, device = self.settings.prefiltered, self.frame.scene.camera, self.device
        levels = p.evaluate_levels_for(cam.height)
        phase = None
        if p.evaluate_stride > 1 and levels > 1:
            # the coarser levels interpolate radiance / phase so that the sun's forward peak is not flattened over a
            # coarse cell (docs/benchmarks.md, "Sparse evaluation")
            phase = wp.empty((cam.height, cam.width), dtype=wp.float32, device=device)
            grid = (grid_size(cam.height, p.evaluate_stride), grid_size(cam.width, p.evaluate_stride))
            launch_rows(pixel_phase_kernel, grid, [cam.params(), self.light, self.medium, phase,
                                                   pixel_set(PIXELS_GRID, p.evaluate_stride, device=device)],
                        device=device)
        sparse = evaluate_sparse(self.look_up, self.frame.gbuffer.distance, self.result.radiance, p.evaluate_stride,
                                 p.evaluate_tolerance, EVALUATE_DEPTH_TOLERANCE, end_zone=self.result.end_zone,
                                 levels=levels, scale=phase, device=device)
        return self.result.radiance, sparse

    @property
    def end_zone_any(self) -> bool:
        """Whether any pixel was left to the marcher (rays looking into the light within their end zone; rare)."""
        return bool(self.result.end_zone_any.numpy()[0])


__all__ = [
    "EndStretch",
    "EvaluateVariant",
    "Evaluation",
    "LookUpOutputs",
    "MapLookUp",
    "PixelEnds",
    "coords_of_every_pixel",
    "evaluate_prefiltered_kernel",
    "lit_ray_ends",
    "lit_ray_ends_kernel",
    "pixel_coords",
    "pixel_coords_kernel",
    "pixel_phase_kernel",
]
