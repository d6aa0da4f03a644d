"""Settings of the single-scattering methods: the keys, defaults, ranges and meanings of ``render.scattering``
(Warp-free; the only place they are written).

:class:`ScatteringSettings` holds what every method (:mod:`warpscatter.methods`) shares and one section per technique:
``prefiltered`` (``fourier``, ``moments4``, ``moments6``), ``fourier``, ``moments``, ``epipolar``. Example:
``ScatteringSettings(method="epipolar", steps=64, visibility="shadow_map", epipolar={"lines": 512})``.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal, Optional, Union

from pydantic import Field, field_validator, model_validator

from .. import methods
from ..schema import MAX_IMAGE_SIDE, MAX_STEPS, Bool, Float, Int, Seed, SettingsModel
from ..shadows.settings import ShadowMapSettings

# ---- limits and defaults (the technique modules import them; measurements: docs/design/scattering.md) ----

#: Visibility of the marching methods (``raymarch``, ``epipolar``).
VISIBILITY_MODES = ("exact", "shadow_map")
#: Step patterns of the marching methods (:mod:`~warpscatter.scattering.marching`).
JITTERS = ("per_pixel", "fixed")
#: The prefiltered methods' visibility representations.
PREFILTERED_BASES = ("fourier", "moments4", "moments6")
MIN_COEFFICIENTS = 4
#: fourier's Fourier coefficients M (even) by default; a 1024^2 float32 texture is 192 MB at 48.
FOURIER_COEFFICIENTS = 48
MAX_COEFFICIENTS = 128
#: Bits per texel of the prefiltered moment maps, per moment count (Peters 2017 Sec. 5.4.3, Table 1).
MOMENT_STORAGE_BITS = {4: (64, 128), 6: (64, 96, 192)}
#: Default angular radius (degrees) of the ray-marched disc around an epipole in view (Klehm 2014 Fig. 8).
EPIPOLE_ANGLE_DEG = 8.0
MAX_EPIPOLE_ANGLE_DEG = 60.0
#: ``rectification: auto`` (:func:`~.rectify.choose_rectification`) picks projective when every epipole in front of
#: the camera lies at least this far outside the image, in half image heights on the image plane.
EPIPOLE_MARGIN = 1.0
#: Most light-frustum regions of the projective rectification (Klehm 2014 Sec. 4.2).
MAX_REGIONS = 16
#: Most split regions of a row (Klehm 2014 Sec. 3.3 uses up to 4).
MAX_SPLITS = 16
#: Resampling filters of the non-linear rectification (Peters 2017 Sec. 5.2; :func:`~.rectify.resample_shadow_map`)
#: and the widest Gaussian (texels).
RESAMPLE_FILTERS = ("none", "supersample", "moments")
MAX_RESAMPLE_FILTER_PX = 64
#: Default tolerance of caster culling against acne (a fraction of the rectified depth range).
CASTER_CULLING_BIAS = 1.0 / 64.0
MAX_CASTER_CULLING_BIAS = 0.25
#: Default bits per texel of the moment maps: 64-bit Theta4*, 96-bit Theta6* (Peters 2017 Sec. 5.4.3; 60 bits leak).
DEFAULT_MOMENT_BITS = {4: 64, 6: 96}
#: Ray-march steps of the prefiltered methods' epipole region by default (strata of equal transmittance weight).
EPIPOLE_STEPS = 64
#: Grid stride of the marched epipole region (the evaluate_stride rule: :mod:`~.sparse_evaluation`).
EPIPOLE_STRIDE = 2
#: Per-ray transmittance segments of the prefiltered look-ups by default (:mod:`.prefiltered.ray_weights`).
SEGMENTS = 3
#: The moment methods' most adaptive per-ray segments with the light behind the camera (with SEGMENT_DEPTH).
BEHIND_SEGMENTS = 6
#: fourier's most adaptive per-ray segments (with FOURIER_SEGMENT_DEPTH): up to 7 is two passes over the coefficients.
FOURIER_SEGMENTS = 7
#: Optical-depth mismatch per segment of fourier's adaptive per-ray segments (ray_weights.segment_count).
FOURIER_SEGMENT_DEPTH = 0.08
#: Optical-depth mismatch per segment of the moment methods' adaptive segments with the light behind the camera.
SEGMENT_DEPTH = 0.15
#: Per-ray segments of the moment methods in a coloured medium (:func:`~.prefiltered.weights_extinction`).
COLOURED_SEGMENTS = 5
#: Per-ray segments under a spot light (:mod:`.prefiltered.spot_lookups`).
SPOT_SEGMENTS = 6
MAX_SEGMENTS = 8
#: The moment methods' overestimation weight beta by default (a fixed beta beat Peters' adaptive rule) ...
OVERESTIMATION = 0.25
#: ... rising to this for rays looking the way light travels (Peters 2017 Sec. 5.3.1): beta = OVERESTIMATION +
#: (OVERESTIMATION_ALONG_LIGHT - OVERESTIMATION) clamp((omega_l . omega_p - c) / (1 - c), 0, 1) ...
OVERESTIMATION_ALONG_LIGHT = 0.45
#: ... with c = this (``moments.overestimation_rise_cos``).
OVERESTIMATION_RISE_COS = -0.5
#: moments4's overestimation weight under a spot light by default (moments6 keeps OVERESTIMATION there).
SPOT_OVERESTIMATION_MOMENTS4 = 0.1
#: View rays within this angle (degrees) of the direction into a directional light take a smaller beta, 0 looking
#: straight into it (``moments.epipole_taper_deg``; Peters 2017 Sec. 5.3.1, Fig. 14).
EPIPOLE_TAPER_DEG = 2.0
#: Texels a prefiltered look-up ends before its ray's end point (the surface a ray ends on is its own blocker) ...
END_OFFSET = 1.0
#: ... and for rays ending lit (prefiltered.lit_ray_ends) under a directional light ahead of the camera.
END_OFFSET_LIT = 0.25
MAX_END_OFFSET = 8.0
#: Most shadow-map samples (PCF, one per texel) of the stretch a look-up leaves out before a ray that ends in shadow
#: under a directional light ahead of the camera.
END_SAMPLES = 4
MAX_END_SAMPLES = 64
#: The look-up runs on every EVALUATE_STRIDE-th pixel in x and y and where the grid cell cannot interpolate
#: (:mod:`~warpscatter.scattering.sparse_evaluation`, with the two tolerances below); 1: every pixel.
EVALUATE_STRIDE = 2
MAX_EVALUATE_STRIDE = 8
EVALUATE_TOLERANCE = 0.02
EVALUATE_DEPTH_TOLERANCE = 0.04
#: Grid levels filled coarse to fine (:mod:`~warpscatter.scattering.sparse_evaluation`); ``auto``: 2 under a
#: directional light on images of EVALUATE_LEVELS_AUTO_ROWS rows or more, else 1.
EVALUATE_LEVELS = "auto"
EVALUATE_LEVELS_AUTO_ROWS = 1080
MAX_EVALUATE_LEVELS = 4
#: END_SAMPLES skips rays within this many degrees of the light's direction (one texel decides them) ...
END_SAMPLES_MIN_DEG = 2.0
#: ... and rays whose left-out stretch carries less than this share of their transmittance weight.
END_STRETCH_MIN_WEIGHT = 0.01
#: moments4's depth warp c by default, (e^(c z) - 1) / (e^c - 1): it spreads the far depths apart against leaks.
MOMENTS4_DEPTH_WARP = 3.0
#: Map columns from which moments4 uses all of MOMENTS4_DEPTH_WARP (in proportion on coarser maps).
MOMENTS4_WARP_COLUMNS = 1024
#: Largest |c| of the exponential depth warp (prefiltered.depth_warp, filtered_textures.warped_depth).
MAX_DEPTH_WARP = 16.0
#: Most row mip levels of a prefiltered texture (prefiltered.mip_levels, row_mips).
MAX_MIP_LEVELS = 8
#: Border pixels per epipolar line by default (``epipolar.lines: null``): the line count follows the image size.
LINE_SPACING_PX = 4
#: Initial ray-marching samples per epipolar line by default (Engelhardt 2010 Sec. 4.1; its teaser uses 32).
EPIPOLAR_INITIAL_SAMPLES = 32
#: Ray-march steps per ray of the raymarch method by default (the bench's shadow-map marcher at its defaults).
RAYMARCH_STEPS = 128
#: Ray-march steps per marched sample of epipolar by default (its samples are a few per cent of the pixels) ...
EPIPOLAR_STEPS = 512
#: ... of which a sample takes this many per shadow-map texel its ray crosses (:func:`~.marching.texel_steps`), at
#: least EPIPOLAR_LEAST_STEPS; 0 gives every sample ``steps``.
EPIPOLAR_STEPS_PER_TEXEL = 4.0
EPIPOLAR_LEAST_STEPS = 32
#: Taps per line of epipolar's bilateral upsampling by default (Engelhardt 2010 Sec. 4.3 uses 3-5; one, the line
#: texture's depth-weighted linear interpolation, is as accurate here at half the cost).
EPIPOLAR_TAPS = 1
#: Grid stride of epipolar's upsampling under a directional light (the :mod:`~.sparse_evaluation` rule;
#: warpscatter's); spot and point lights keep every pixel, their shafts being a few pixels wide.
EPIPOLAR_UPSAMPLE_STRIDE = 2
#: Step pattern (``jitter``) of the raymarch method by default: per_pixel, unbiased pixel by pixel ...
RAYMARCH_JITTER = "per_pixel"
#: ... and of the few rays other methods march (Engelhardt 2010 Sec. 5.3's fixed step): its error varies smoothly
#: between the neighbouring pixels they are interpolated with, where per-ray noise shows as streaks and grain.
SAMPLE_JITTER = "fixed"
#: Radial basis functions of the epipolar bilateral filter (Engelhardt 2010 Sec. 4.3).
EPIPOLAR_KERNELS = ("gaussian", "shepard", "threshold")
#: Largest ``prefiltered.epipole_margin`` (half image heights): far beyond it ``auto`` always picks non-linear.
MAX_EPIPOLE_MARGIN = 1000.0
#: Most texels per epipolar line (twice the largest image side: more than any image diagonal).
MAX_SAMPLES_PER_LINE = 2 * MAX_IMAGE_SIDE
#: Bounds of the epipolar filter's relative depth thresholds and of its distance fall-off.
MIN_RELATIVE_DEPTH = 1.0e-6
MAX_RELATIVE_DEPTH = 1000.0
MAX_DISTANCE_FALLOFF = 1000.0
#: Largest ``epipolar.max_epipole_distance`` (image diagonals).
MAX_EPIPOLE_DISTANCE = 1.0e6


class PrefilteredSettings(SettingsModel):
    """What the prefiltered methods (``fourier``, ``moments4``, ``moments6``) share: rectification, weights and the
    epipole fallback (Klehm et al. 2014; Peters et al. 2017 Sec. 5)."""

    weighting: Literal["transmittance", "average"] = Field(
        "transmittance", description="transmittance-weighted prefix sums (Klehm 2014 Listing 2, Eq. 12) or the plain "
                                     "average visibility (Eq. 2)")
    reference_ray: Literal["auto", "pixels", "least", "optimal", "bisectrix", "mean"] = Field(
        "auto", description="per-slice reference ray of the weights: the slice's median pixel ray, its least optical "
                            "step (the ray closest to the light-perpendicular), Klehm's optimum k_ref = sqrt(k_min "
                            "k_max), the bisectrix, or Peters' mean inclination; auto: least with per-ray segments, "
                            "else pixels")
    segments: Optional[Annotated[Int, Field(ge=1, le=MAX_SEGMENTS)]] = Field(
        None, description="per-ray transmittance: each view ray is cut into this many segments of equal own weight and "
                          "reads the texture once per cut (warpscatter's, not in the papers: the reference ray's "
                          "weights alone are the largest error near the epipole and in thick media); 1: the "
                          "reference weights (Klehm 2014); with segment_depth the most a ray takes; null: with "
                          "transmittance weighting, splits 1 and the non-linear rectification " + str(FOURIER_SEGMENTS)
                          + " for fourier and, with the light behind the camera, " + str(BEHIND_SEGMENTS)
                          + " for the moment methods (adaptive), "
                          + str(SEGMENTS) + " for the moment methods with the light ahead (" + str(COLOURED_SEGMENTS)
                          + " in a coloured medium), else 1; " + str(SPOT_SEGMENTS) + " under a spot light")
    segment_depth: Optional[Annotated[Float, Field(ge=0.0, le=10.0)]] = Field(
        None, description="adaptive per-ray segments: a ray takes one segment per this much optical depth by which "
                          "its decay exceeds its row reference's, at most `segments` (a ray decaying like the "
                          "reference needs one); 0: every ray takes `segments`; null: " + str(FOURIER_SEGMENT_DEPTH)
                          + " for fourier (with segments up to " + str(FOURIER_SEGMENTS) + "), " + str(SEGMENT_DEPTH)
                          + " for the moment methods with the light behind the camera (it travels the way the camera "
                          "looks; up to " + str(BEHIND_SEGMENTS) + "), else 0; spot lights cut their own way")
    end_offset: Optional[Annotated[Float, Field(ge=0.0, le=MAX_END_OFFSET)]] = Field(
        None, description="texels the look-up ends before the ray's end point (texels of a map reaching the view: with "
                          "map_radius casters, as many more as the columns are finer): the surface a ray ends on is "
                          "its own blocker and lights or shadows the ray's last texel by chance; null: "
                          + f"{END_OFFSET:g}" + ", and " + f"{END_OFFSET_LIT:g}" + " for the rays that end lit "
                          "(on a surface the shadow map sees, or on none) under a directional light ahead of the "
                          "camera: a lit surface shadows its own ray only through the texel's filtering")
    end_samples: Annotated[Int, Field(ge=0, le=MAX_END_SAMPLES, description=(
        "most shadow-map samples of the stretch a look-up leaves out before a ray that ends in shadow (its "
        "end_offset texels, where the surface is its own blocker) under a directional light ahead of the camera, one "
        "per shadow-map texel of its length (not within " + f"{END_SAMPLES_MIN_DEG:g}" + " degrees of the light, nor "
        "where the stretch carries under " + f"{100 * END_STRETCH_MIN_WEIGHT:g}" + " % of the ray's weight); 0: that "
        "stretch takes the look-up's visibility"))] = END_SAMPLES
    depth_warp: Optional[Annotated[Float, Field(ge=-MAX_DEPTH_WARP, le=MAX_DEPTH_WARP)]] = Field(
        None, description="exponential warp c of the depths the representations store and look up, (e^(c z) - 1) / "
                          "(e^c - 1) (Klehm 2014 Sec. 5: against light bleeding); 0: none; < 0 stretches the depths "
                          "towards the light, > 0 away from it; null: " + f"{MOMENTS4_DEPTH_WARP:g}" + " for "
                          "moments4 on maps of " + str(MOMENTS4_WARP_COLUMNS) + " columns or more (in proportion on "
                          "coarser ones), 0 for fourier and moments6")
    mip_levels: Annotated[Int, Field(ge=1, le=MAX_MIP_LEVELS, description=(
        "row mip levels of the prefiltered texture (Peters 2017 D.5: mip-mapped prefix sums), level 0 included: a "
        "pixel spanning several epipolar slices (around an epipole or a spot light in view) reads the level as wide "
        "as it, blended between two levels; 1: level 0 only. Doubles the texture's memory; whole rows only (splits "
        "1)"))] = 1
    depth_bounds: Bool = Field(True, description="per-row prefix bounds of the rectified depths (8 bytes per texel): a "
                                                 "view ray whose texels all lie behind its end is lit, all in front "
                                                 "shadowed, exactly, without the basis' ringing or leaking "
                                                 "(warpscatter's, after Chen et al. 2011's 1D min-max maps)")
    guard_band: Annotated[Float, Field(ge=0.0, le=1.0, description="relative stretch of the depth bounds")] = 0.1
    map_radius: Literal["view", "casters"] = Field(
        "view", description="non-linear rectification: the map's columns reach as far from the camera's light axis as "
                            "the view frustum (Peters 2017 App. A), or as the farthest caster (a view ray's texels "
                            "beyond count as lit; finer columns where the shadows are: docs/methods/prefiltered.md)")
    epipole_fallback: Union[Literal["auto"], Bool] = Field(
        "auto", description="ray-march the pixels around an epipole in view (Klehm 2014 Sec. 5, Fig. 8; the region "
                            "is epipole_angle_deg / epipole_block); auto: for fourier under a directional light only "
                            "(Peters 2017 Sec. 6: the moment methods need no separate branch; measured, the disc "
                            "moves their error by -0.2 to +0.4 % and costs 50-70 ms at 1080p; under a spot the "
                            "marched disc near the light was noisier than the map: fourier 1.49 % without, 2.82 % "
                            "with it at 128 steps)")
    epipole_block: Annotated[Int, Field(ge=0, le=MAX_IMAGE_SIDE, description="the least ray-marched region around "
                                                                             "an epipole in view: "
                                                          "Klehm's block side in pixels (its half side as an angle at "
                                                          "the image centre is the least radius)")] = 32
    epipole_angle_deg: Annotated[Float, Field(ge=0.0, le=MAX_EPIPOLE_ANGLE_DEG, description=(
        "pixels whose view ray lies within this angle (degrees) of the light direction or its flip are ray-marched "
        "(2x2 shadow-map look-ups, weights ramping over 0.75 texel, `epipole_steps` strata of equal transmittance "
        "weight, `jitter`), blended with the prefiltered result over a further 25 % of the angle (Klehm 2014 Sec. 5, "
        "Fig. 8); this and epipole_block 0: off"))] = EPIPOLE_ANGLE_DEG
    epipole_steps: Annotated[Int, Field(ge=1, le=MAX_STEPS, description="ray-march steps of the epipole region "
                                                                         "(strata of equal "
                                                          "transmittance weight)")] = EPIPOLE_STEPS
    epipole_stride: Annotated[Int, Field(ge=1, le=MAX_EVALUATE_STRIDE, description=(
        "the epipole region is marched on every n-th pixel in x and y and on the pixels between them whose grid cell "
        "does not agree (evaluate_stride's rule, with evaluate_tolerance; warpscatter's); 1: every pixel"))] = (
        EPIPOLE_STRIDE)
    rectification: Literal["auto", "projective", "nonlinear"] = Field(
        "auto", description="auto: Peters' non-linear map, unless the look-ups take Klehm's single reference ray "
                            "(segments 1, average weighting or splits > 1) and every epipole lies epipole_margin half "
                            "image heights outside the view (then Klehm's projective map, Sec. 4.2, which cannot "
                            "weight each ray by its own transmittance); or one of them always")
    epipole_margin: Annotated[Float, Field(ge=0.0, le=MAX_EPIPOLE_MARGIN, description="auto, with Klehm's single "
                                                                                       "reference ray: the projective "
                                                               "map needs every epipole this many half image heights "
                                                               "outside the image")] = EPIPOLE_MARGIN
    regions: Annotated[Int, Field(ge=1, le=MAX_REGIONS, description="light-frustum regions of the projective map along "
                                                                    "x (Klehm 2014 Sec. 4.2; 1 = one matrix)")] = 8
    projective_weights: Literal["exact", "cross_ratio"] = Field(
        "exact", description="per-texel weights of the projective map: exact column lengths, or Eq. 12's constant "
                             "growth factor d")
    splits: Annotated[Int, Field(ge=1, le=MAX_SPLITS, description="row regions prefiltered independently (Klehm 2014 "
                                                                  "Sec. 3.3; fourier only; 1 = off)")] = 1
    resample_filter: Literal[RESAMPLE_FILTERS] = Field(  # type: ignore[valid-type]
        "supersample", description="non-linear rectification: none resamples the nearest shadow-map depth at each "
                                   "texel's centre; supersample reads 2x2 bilinear taps "
                                   "at one point per shadow-map texel the rectified texel spans radially "
                                   "(up to 4) and keeps two depths (warpscatter's: one nearest depth aliases into "
                                   "radial streaks); moments filters during resampling (Peters 2017 Sec. 5.2: a "
                                   "filtered 4-moment map and Algorithm 2)")
    resample_filter_px: Optional[Annotated[Int, Field(ge=1, le=MAX_RESAMPLE_FILTER_PX)]] = Field(
        None, description="width of that filter's Gaussian (shadow-map texels); null: the radial footprint of a "
                          "rectified texel")
    caster_culling: Union[Literal["auto"], Bool] = Field(
        "auto", description="empty every rectified texel whose blocker shadows no pixel's look-up (warpscatter's, not "
                            "in the papers); auto: on for moments4/moments6, off for fourier")
    caster_culling_bias: Annotated[Float, Field(ge=0.0, le=MAX_CASTER_CULLING_BIAS, description=(
        "caster culling's depth tolerance, a fraction of the rectified depth range"))] = CASTER_CULLING_BIAS
    evaluate_stride: Annotated[Int, Field(ge=1, le=MAX_EVALUATE_STRIDE, description=(
        "the look-up runs on every n-th pixel in x and y and on the pixels between them whose grid cell does not "
        "agree (a corner on another surface or left to the marcher, or the corners' radiance spread over "
        "evaluate_tolerance); the others interpolate the cell bilinearly (warpscatter's, not in the papers: most of "
        "the methods' time is the per-pixel look-up); 1: every pixel"))] = EVALUATE_STRIDE
    evaluate_tolerance: Annotated[Float, Field(ge=0.0, le=1.0, description=(
        "evaluate_stride: the largest spread of a grid cell's corner radiance (largest channel), relative to the "
        "largest corner, that is interpolated; 0: only cells of equal corners"))] = EVALUATE_TOLERANCE
    evaluate_levels: Union[Literal["auto"], Annotated[Int, Field(ge=1, le=MAX_EVALUATE_LEVELS)]] = Field(
        EVALUATE_LEVELS, description=(
            "evaluate_stride: grids filled coarse to fine; the look-up runs on every "
            "evaluate_stride * 2^(levels - 1)-th pixel first, and each finer grid's new nodes interpolate the coarser "
            "grid's cell by the same test (half the tolerance per coarser level) or are evaluated (warpscatter's); "
            f"1: one grid; auto: 2 under a directional light on images of {EVALUATE_LEVELS_AUTO_ROWS} rows or more, "
            "else 1"))

    def evaluate_levels_for(self, height: int, spot: bool = False) -> int:
        """Grid levels of a look-up on an image of ``height`` rows (``evaluate_levels``; auto:
        :data:`EVALUATE_LEVELS_AUTO_ROWS`, one level under a spot light, ``spot``)."""
        if self.evaluate_levels == "auto":
            return 2 if height >= EVALUATE_LEVELS_AUTO_ROWS and not spot else 1
        return int(self.evaluate_levels)

    @model_validator(mode="after")
    def _segments_need_whole_rows(self) -> PrefilteredSettings:
        if self.segments is not None and self.segments > 1 and self.splits > 1:
            raise ValueError(f"segments: {self.segments} per-ray segments read whole-row prefix sums; with splits: "
                             f"{self.splits} set segments: 1 (or leave it out)")
        if self.mip_levels > 1 and self.splits > 1:
            raise ValueError(f"mip_levels: {self.mip_levels} row mips average whole rows; with splits: {self.splits} "
                             f"set mip_levels: 1 (or leave it out)")
        return self

    def segments_for(self, nonlinear: bool, coloured: bool = False, method: str = "moments6",
                     light_behind: bool = False) -> int:
        """Per-ray segments a look-up uses, at most with adaptive segments (``segments``; null: :data:`FOURIER_SEGMENTS`
        for fourier, :data:`BEHIND_SEGMENTS` for the moment methods with the light behind the camera in a grey medium,
        else :data:`SEGMENTS` or, coloured, :data:`COLOURED_SEGMENTS`); 1 without :attr:`weights_per_ray`."""
        if not (nonlinear and self.weights_per_ray):
            return 1
        if self.segments is not None:
            return self.segments
        adaptive = self._adaptive_default(method, light_behind, coloured)
        if adaptive is not None:
            return adaptive[0]
        return COLOURED_SEGMENTS if coloured else SEGMENTS

    @property
    def weights_per_ray(self) -> bool:
        """Whether look-ups on the non-linear map weight each view ray by its own transmittance (per-ray segments):
        transmittance weighting, splits 1 and ``segments`` not 1 (the projective map's uneven columns cannot)."""
        return self.weighting == "transmittance" and self.splits == 1 and self.segments != 1

    def end_offsets_for(self, light_behind: bool, directional: bool = True) -> tuple[float, float]:
        """Texels a look-up ends before its ray's end point, (rays ending in shadow, rays ending lit): ``end_offset``
        for both; null: :data:`END_OFFSET`, and :data:`END_OFFSET_LIT` for rays ending lit under a directional light
        ahead of the camera."""
        if self.end_offset is not None:
            return float(self.end_offset), float(self.end_offset)
        return END_OFFSET, (END_OFFSET_LIT if directional and not light_behind else END_OFFSET)

    def segment_depth_for(self, method: str, light_behind: bool = False, coloured: bool = False) -> float:
        """The adaptive segments' optical depth per segment (``segment_depth``; null: :data:`FOURIER_SEGMENT_DEPTH`
        for fourier, :data:`SEGMENT_DEPTH` for the moment methods with the light behind the camera in a grey medium;
        else 0, fixed counts)."""
        if self.segment_depth is not None:
            return float(self.segment_depth)
        adaptive = self._adaptive_default(method, light_behind, coloured)
        return adaptive[1] if adaptive is not None else 0.0

    @staticmethod
    def _adaptive_default(method: str, light_behind: bool, coloured: bool) -> tuple[int, float] | None:
        """(most segments, optical depth per segment) of a method's default adaptive segments (fourier always, the
        moment methods with the light behind the camera in a grey medium); None: fixed segments."""
        if method == "fourier":
            return FOURIER_SEGMENTS, FOURIER_SEGMENT_DEPTH
        if light_behind and not coloured:
            return BEHIND_SEGMENTS, SEGMENT_DEPTH
        return None

    def depth_warp_for(self, method: str, columns: int) -> float:
        """The depth warp c the representations of a map with ``columns`` texels per row use (``depth_warp``; null:
        for moments4 :data:`MOMENTS4_DEPTH_WARP`, scaled down in proportion below :data:`MOMENTS4_WARP_COLUMNS`
        columns, 0 otherwise)."""
        if self.depth_warp is not None:
            return float(self.depth_warp)
        if method != "moments4":
            return 0.0
        return MOMENTS4_DEPTH_WARP * min(1.0, columns / MOMENTS4_WARP_COLUMNS)

    def reference_for(self, segments: int) -> str:
        """``reference_ray``; auto: ``least`` with per-ray segments (their weights are then convex), else ``pixels``."""
        if self.reference_ray != "auto":
            return self.reference_ray
        return "least" if segments > 1 else "pixels"


class FourierSettings(SettingsModel):
    """The ``fourier`` method's representation (Klehm et al. 2014): M coefficients, float32 or 8-bit storage."""

    coefficients: Annotated[Int, Field(ge=MIN_COEFFICIENTS, le=MAX_COEFFICIENTS, description=(
        "M Fourier coefficients (even: cos/sin pairs); a float32 texture takes 4 M bytes per texel"))] = (
        FOURIER_COEFFICIENTS)
    storage_bits: Literal[0, 8] = Field(0, description="0: float32 filtered bases; 8: the paper's 8-bit normalised "
                                                       "storage (App. A) in uint8 textures, a quarter of the bytes")

    @field_validator("coefficients")
    @classmethod
    def _even(cls, v: int) -> int:
        if v % 2:
            raise ValueError(f"must be even (cos/sin pairs), got {v}")
        return v


class MomentsSettings(SettingsModel):
    """The ``moments4`` / ``moments6`` methods' representation (Peters et al. 2017 Sec. 5.3-5.4)."""

    storage_bits: Optional[Literal[64, 96, 128, 192]] = Field(
        None, description="bits per texel: 64 or 128 for four moments; 64 (60 used), 96 or 192 for six (Theta* in "
                          "16- or 10-bit fixed point packed in uint16 / uint64 textures, or float32); null: 64 for "
                          "four, 96 for six moments")
    overestimation: Optional[Union[Literal["adaptive"], Annotated[Float, Field(ge=0.0, le=1.0)]]] = Field(
        None, description="beta between the lower (0) and upper (1) visibility bounds: a fixed number, or adaptive "
                          "(beta = (1 + omega_l . omega_p) / 2, Peters 2017 Sec. 5.3.1); null: "
                          f"{OVERESTIMATION:g} for view rays looking towards a directional light, rising from "
                          "omega_l . omega_p = overestimation_rise_cos to "
                          f"{OVERESTIMATION_ALONG_LIGHT:g} for rays looking the way it travels; under a spot light, "
                          f"whose direction varies along a ray, {OVERESTIMATION:g} for moments6 and "
                          f"{SPOT_OVERESTIMATION_MOMENTS4:g} for moments4")

    epipole_taper_deg: Annotated[Float, Field(ge=0.0, le=90.0)] = Field(
        EPIPOLE_TAPER_DEG, description="view rays within this angle (degrees) of the direction into a directional "
                                       "light weigh beta by (1 - cos psi) / (1 - cos angle), psi their angle to it: "
                                       "0 looking straight into the light, the lower bound (Peters 2017 Sec. 5.3.1, "
                                       "Fig. 14: no leaking at the epipole); 0: off")

    overestimation_rise_cos: Annotated[Float, Field(ge=-1.0, lt=1.0)] = Field(
        OVERESTIMATION_RISE_COS, description="with the default overestimation (null) under a directional light: the "
                                             "omega_l . omega_p (cosine between the way the light travels and the view "
                                             "ray) from which beta rises linearly to its value looking along the "
                                             f"light; 0: rays across the light keep {OVERESTIMATION:g}")

    def epipole_taper(self) -> float:
        """1 - cos of ``epipole_taper_deg`` (0: off), the form the look-up compares 1 + omega_l . omega_p with."""
        return 1.0 - math.cos(math.radians(self.epipole_taper_deg))

    def beta_range(self) -> tuple[float, float]:
        """(b0, b1) of beta = b0 + (b1 - b0) clamp((omega_l . omega_p - c) / (1 - c), 0, 1), c =
        ``overestimation_rise_cos``; a fixed ``overestimation`` gives b0 = b1; adaptive (-1, -1)."""
        if self.overestimation == "adaptive":
            return -1.0, -1.0
        if self.overestimation is None:
            return OVERESTIMATION, OVERESTIMATION_ALONG_LIGHT
        return float(self.overestimation), float(self.overestimation)

    def spot_beta(self, num_moments: int) -> float:
        """Beta of every view ray under a spot light: a fixed ``overestimation``, else
        :data:`SPOT_OVERESTIMATION_MOMENTS4` for four moments and :data:`OVERESTIMATION` for six; -1 for adaptive."""
        if self.overestimation == "adaptive":
            return -1.0
        if self.overestimation is None:
            return SPOT_OVERESTIMATION_MOMENTS4 if num_moments == 4 else OVERESTIMATION
        return float(self.overestimation)


class EpipolarSettings(SettingsModel):
    """The ``epipolar`` method (Engelhardt & Dachsbacher 2010)."""

    lines: Optional[Annotated[Int, Field(ge=8, le=16384)]] = Field(
        None, description="epipolar lines (equidistant border points); null: one per " + str(LINE_SPACING_PX) +
                          " border pixels (1504 at 1920x1080, 496 at 640x360, 248 at 320x180)")
    initial_samples: Annotated[Int, Field(ge=2, le=1024, description="initial ray-marching samples per line "
                                                                     "(Sec. 4.1; 32 as in the paper's teaser)")] = \
        EPIPOLAR_INITIAL_SAMPLES
    samples_per_line: Optional[Annotated[Int, Field(ge=2, le=MAX_SAMPLES_PER_LINE)]] = Field(
        None, description="texels per line (the most samples); null: the image diagonal in pixels")
    depth_threshold: Annotated[Float, Field(ge=MIN_RELATIVE_DEPTH, le=MAX_RELATIVE_DEPTH, description=(
        "relative camera-depth jump that is a discontinuity"))] = 0.05
    steps_per_texel: Annotated[Float, Field(ge=0.0, le=MAX_STEPS, description=(
        "steps per shadow-map texel its ray crosses for each ray-marched sample (shadow-map visibility), between "
        + str(EPIPOLAR_LEAST_STEPS) + " and `steps`; 0: every sample takes `steps`"))] = \
        EPIPOLAR_STEPS_PER_TEXEL
    kernel: Literal[EPIPOLAR_KERNELS] = Field(  # type: ignore[valid-type]
        "gaussian", description="bilateral weight: gaussian exp(-x^2), shepard 1/(1+x^2), threshold (depth only: "
                                "x <= 1; distance weight 1)")
    taps: Annotated[Int, Field(ge=1, le=5, description=(
        "taps per line of the bilateral filter: 1 reads each line's texture linearly at the pixel's projection with "
        "depth weights; 3-5 are the paper's filter, taps a multiple of the lines' distance apart (Sec. 4.3); not "
        "2"))] = \
        EPIPOLAR_TAPS
    distance_falloff: Annotated[Float, Field(ge=0.0, le=MAX_DISTANCE_FALLOFF, description=(
        "a of the distance weight, x^2 = a (offset / delta)^2"))] = 0.5
    depth_sigma: Annotated[Float, Field(ge=MIN_RELATIVE_DEPTH, le=MAX_RELATIVE_DEPTH, description=(
        "relative depth difference at which the depth x = 1"))] = 0.1
    min_weight: Annotated[Float, Field(gt=0.0, le=1.0, description="taps whose depth weight is below this are "
                                                                   "invalid")] = 0.05
    outer_lines: Annotated[Int, Field(ge=0, le=64, description="outer lines tried per side when a side has no valid "
                                                               "tap")] = 2
    upsample_stride: Union[Literal["auto"], Annotated[Int, Field(ge=1, le=MAX_EVALUATE_STRIDE)]] = Field(
        "auto", description="the bilateral upsampling runs on every n-th pixel in x and y and on the pixels between "
                            "them whose grid cell does not agree (prefiltered.evaluate_stride's rule and default "
                            "tolerances); the others interpolate the cell bilinearly (warpscatter's, not in the "
                            "paper); 1: every pixel, as the paper; auto: " + str(EPIPOLAR_UPSAMPLE_STRIDE) + " under "
                            "a directional light, 1 under spot and point lights")
    prefilter_light_texture: Bool = Field(False, description="box-downsample a spot texture to the line spacing "
                                                             "(Sec. 6)")
    fallback_stride: Annotated[Int, Field(ge=1, le=256, description="grid spacing (pixels) of the screen-space "
                                                                    "subsampling (the degenerate case, or sampling: "
                                                                    "screen)")] = 4
    sampling: Literal["epipolar", "screen"] = Field(
        "epipolar", description="epipolar lines (the method), or plain screen-space subsampling every fallback_stride "
                                "pixels with the same ray marching and bilateral upsampling: the naive baseline of "
                                "Engelhardt 2010 Fig. 9 (bench papers compares them at equal time)")
    max_epipole_distance: Annotated[Float, Field(gt=0.0, le=MAX_EPIPOLE_DISTANCE, description=(
        "epipoles farther than this many image diagonals count as at infinity"))] = 1000.0

    def upsample_stride_for(self, spot: bool) -> int:
        """The upsampling's grid stride (``upsample_stride``; auto: :data:`EPIPOLAR_UPSAMPLE_STRIDE` under a
        directional light, 1 under a spot light or a point light's faces)."""
        if self.upsample_stride == "auto":
            return 1 if spot else EPIPOLAR_UPSAMPLE_STRIDE
        return int(self.upsample_stride)

    def lines_for(self, width: int, height: int) -> int:
        """Epipolar lines for a width x height image: ``lines``, or one per :data:`LINE_SPACING_PX` pixels of the
        image border (a multiple of 8, at least 64)."""
        if self.lines is not None:
            return int(self.lines)
        return max(64, 8 * round(2 * (width + height) / LINE_SPACING_PX / 8))

    @field_validator("taps")
    @classmethod
    def _taps(cls, v: int) -> int:
        if v == 2:  # two taps +-delta/2 have no centre tap: at a line's ends the pair drops and nothing is left
            raise ValueError("must be 1 (the line texture read at the pixel's projection) or 3-5 (the paper's "
                             "filter), got 2")
        return v

    @model_validator(mode="after")
    def _samples(self) -> EpipolarSettings:
        if self.samples_per_line is not None and self.samples_per_line < self.initial_samples:
            raise ValueError(f"samples_per_line ({self.samples_per_line}) must be >= initial_samples "
                             f"({self.initial_samples})")
        return self


class ScatteringSettings(SettingsModel):
    """Single scattering (``render.scattering``): the method, what every method shares, one section per technique."""

    method: Literal[tuple(methods.SCATTERING)] = Field(  # type: ignore[valid-type]
        "raymarch", description="the single-scattering method (see the method table)")
    visibility: Literal[VISIBILITY_MODES] = Field(  # type: ignore[valid-type]
        "exact", description="raymarch, epipolar: exact (ray-cast shadow rays, the reference) or shadow_map")
    steps: Optional[Annotated[Int, Field(ge=1, le=MAX_STEPS)]] = Field(
        None, description="ray-march steps per ray (raymarch) or per ray-marched sample (epipolar); null: "
                          + str(RAYMARCH_STEPS) + " for raymarch, " + str(EPIPOLAR_STEPS) + " for epipolar (its "
                          "samples are a few per cent of the pixels); the prefiltered methods' epipole region has "
                          "prefiltered.epipole_steps")
    seed: Seed = Field(0, description="jitter seed (same seed, same image)")
    jitter: Optional[Literal[JITTERS]] = Field(  # type: ignore[valid-type]
        None, description="raymarch, epipolar (and the prefiltered methods' epipole disc) step pattern: per_pixel "
                          "(stratified jitter per ray) or fixed (one offset per frame, the paper's fixed step); null: "
                          f"{RAYMARCH_JITTER} for raymarch, {SAMPLE_JITTER} for the others' few marched rays")
    shadow_map: ShadowMapSettings = Field(default_factory=dict, description="the light's shadow map")
    prefiltered: PrefilteredSettings = Field(default_factory=dict, description="fourier, moments4, moments6")
    fourier: FourierSettings = Field(default_factory=dict, description="fourier")
    moments: MomentsSettings = Field(default_factory=dict, description="moments4, moments6")
    epipolar: EpipolarSettings = Field(default_factory=dict, description="epipolar")

    @property
    def march_steps(self) -> int:
        """Ray-march steps per ray (raymarch) or per ray-marched sample (epipolar): ``steps``, else
        :data:`RAYMARCH_STEPS` or :data:`EPIPOLAR_STEPS`."""
        if self.steps is not None:
            return int(self.steps)
        return EPIPOLAR_STEPS if self.method == "epipolar" else RAYMARCH_STEPS

    @property
    def march_jitter(self) -> str:
        """Step pattern of the marched rays: ``jitter``, else :data:`RAYMARCH_JITTER` (raymarch) or
        :data:`SAMPLE_JITTER` (epipolar's samples, the prefiltered methods' epipole disc)."""
        if self.jitter is not None:
            return self.jitter
        return RAYMARCH_JITTER if self.method == "raymarch" else SAMPLE_JITTER

    @model_validator(mode="after")
    def _moment_storage(self) -> ScatteringSettings:
        bits = self.moments.storage_bits
        allowed = {"moments4": MOMENT_STORAGE_BITS[4], "moments6": MOMENT_STORAGE_BITS[6]}.get(self.method)
        if allowed and bits is not None and bits not in allowed:
            raise ValueError(f"moments.storage_bits {bits} is not a {self.method} mode (choose from "
                             f"{', '.join(map(str, allowed))})")
        if allowed and self.prefiltered.splits != 1:
            raise ValueError("prefiltered.splits > 1 is implemented for the fourier method only")
        return self

    @property
    def num_moments(self) -> int:
        """4 or 6 for the moment methods (0 otherwise)."""
        return {"moments4": 4, "moments6": 6}.get(self.method, 0)

    @property
    def moment_storage_bits(self) -> int:
        """Bits per texel of the moment maps (``moments.storage_bits``; null: :data:`DEFAULT_MOMENT_BITS`)."""
        if self.moments.storage_bits is not None:
            return int(self.moments.storage_bits)
        return DEFAULT_MOMENT_BITS[6 if self.method == "moments6" else 4]

    @property
    def filtered_bits_per_texel(self) -> int:
        """Bits per texel of the prefiltered map the evaluation reads."""
        if self.method == "fourier":
            return self.fourier.coefficients * (8 if self.fourier.storage_bits == 8 else 32)
        return self.moment_storage_bits

    @property
    def marches_epipole(self) -> bool:
        """Whether the prefiltered methods ray-march the region around an epipole in view:
        ``prefiltered.epipole_fallback``, with ``auto`` = fourier only."""
        if self.prefiltered.epipole_fallback == "auto":
            return self.method == "fourier"
        return bool(self.prefiltered.epipole_fallback)

    @property
    def culls_casters(self) -> bool:
        """Whether caster culling runs: ``prefiltered.caster_culling``, with ``auto`` = the moment methods only."""
        if self.prefiltered.caster_culling == "auto":
            return self.method != "fourier"
        return bool(self.prefiltered.caster_culling)


__all__ = [
    "EVALUATE_DEPTH_TOLERANCE",
    "EVALUATE_LEVELS",
    "EVALUATE_LEVELS_AUTO_ROWS",
    "EVALUATE_STRIDE",
    "EVALUATE_TOLERANCE",
    "CASTER_CULLING_BIAS",
    "COLOURED_SEGMENTS",
    "SPOT_SEGMENTS",
    "FOURIER_SEGMENTS",
    "SEGMENT_DEPTH",
    "OVERESTIMATION",
    "OVERESTIMATION_ALONG_LIGHT",
    "OVERESTIMATION_RISE_COS",
    "SPOT_OVERESTIMATION_MOMENTS4",
    "EPIPOLAR_KERNELS",
    "EPIPOLAR_TAPS",
    "EPIPOLAR_UPSAMPLE_STRIDE",
    "EPIPOLAR_STEPS_PER_TEXEL",
    "EPIPOLAR_LEAST_STEPS",
    "END_SAMPLES",
    "END_SAMPLES_MIN_DEG",
    "END_STRETCH_MIN_WEIGHT",
    "EPIPOLE_ANGLE_DEG",
    "EPIPOLE_STRIDE",
    "EPIPOLE_MARGIN",
    "JITTERS",
    "MAX_COEFFICIENTS",
    "MAX_DISTANCE_FALLOFF",
    "MAX_EPIPOLE_DISTANCE",
    "MAX_EPIPOLE_MARGIN",
    "MAX_RELATIVE_DEPTH",
    "MAX_SAMPLES_PER_LINE",
    "MIN_RELATIVE_DEPTH",
    "MAX_REGIONS",
    "MAX_RESAMPLE_FILTER_PX",
    "MAX_SPLITS",
    "MIN_COEFFICIENTS",
    "MOMENT_STORAGE_BITS",
    "PREFILTERED_BASES",
    "RESAMPLE_FILTERS",
    "VISIBILITY_MODES",
    "EpipolarSettings",
    "FourierSettings",
    "MomentsSettings",
    "PrefilteredSettings",
    "ScatteringSettings",
]
