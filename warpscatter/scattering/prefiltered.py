"""Prefiltered single scattering on a rectified shadow map: the ``fourier`` (Klehm 2014), ``moments4`` and
``moments6`` (Peters 2017 Sec. 5) render methods. They share the rectification, the transmittance-weighted
per-row prefix sums, the per-pixel look-up and the epipole fallback; only the per-texel visibility
representation differs: M Fourier coefficients (Klehm Eq. 8) or 4 / 6 moments of the signed rectified depth
with Algorithm 1 and adaptive overestimation at evaluation (Peters Sec. 5.3-5.4).

Stages (names as they appear in timings):

1. ``rectify``   — the rectification for this camera and light, chosen per frame (``rectification``):
   * ``projective`` (Klehm 2014 Sec. 4.2): one 4x4 matrix per light-frustum region, the scene is
     rasterized STRAIGHT into the rectified map with depth clamping (:mod:`.rectify_projective`);
   * ``nonlinear`` (Peters 2017 Sec. 5.1.1, App. A): bounds in spherical light coordinates and
     resampling of the light's shadow map into them (:mod:`.rectify`);
   * ``auto``: projective unless the light's epipole (or anti-epipole) lies in the image or within
     ``epipole_margin`` half image heights of its border — Klehm's criterion for (close to) degenerate
     cases, :func:`~.rectify_projective.choose_rectification`; the reason is logged on the ``warpscatter``
     logger and returned in the info dict;
   then ``caster_culling`` (by default for the moment methods; not in the papers): every texel whose
   blocker shadows none of the pixels' look-ups is emptied (depth 1), :func:`cull_unseen_casters`. No hard
   visibility changes (up to a depth tolerance against discretisation acne), but the depths of surfaces
   that only receive — a ground plane under the rays that end on it — leave the representation, where they
   sat just behind the rays' fragment depths: the worst case of moment bounds;
2. ``prefilter`` — Fourier basis of the rectified depth fused into per-row prefix sums, plain
   (Klehm Listing 1) or transmittance-weighted with the per-slice reference ray (Listing 2/3); the
   projective map's columns are uneven, so its weights are per texel (Eq. 12: exact column lengths, or
   the paper's constant growth factor d with ``projective_weights: cross_ratio``); rows may be split
   into ``splits`` regions filtered independently (Sec. 3.3);
3. ``evaluate``  — per pixel: the G-buffer hit -> rectified (u, v, z_r) (one @wp.func dispatching on the
   rectification kind) -> bilinear fetch of the filtered-basis vector (one look-up per split region in
   front of the hit plus the hit's own) -> dot with a(z_r) + 0.5, clamped -> times
   sigma_s f E (1 - e^{-sigma_t s}) / sigma_t (Klehm Listing 4); the cost per pixel is constant whatever the scene;
4. ``epipole``   — when the light (or its flip) projects into the view, the non-linear rectification's
   slices all meet there and precision is low: light bleeds into a ring around the epipole (Klehm 2014
   Sec. 5, Fig. 8). The pixels whose view ray lies within ``epipole_angle_deg`` of the light direction (or its
   flip) — at least Klehm's block of ``epipole_block`` pixels — are ray-marched with shadow-map visibility
   instead, blended linearly in the angle with the prefiltered result over a band of ``EPIPOLE_BLEND`` times
   that radius. An angle rather than a pixel count keeps the region the same at every resolution; the stats
   report the fraction of pixels marched (``epipole_raymarched_fraction``).

Directional lights only (both rectifications are built for parallel light rays).

Parameters (:class:`PrefilteredSettings`; config ``render.scattering.prefiltered`` for the shared ones,
``render.scattering.fourier`` and ``render.scattering.moments`` for the representation):

==================  =========  =============  ==========================================================
name                type       default        meaning
==================  =========  =============  ==========================================================
basis               str        fourier        ``fourier``, ``moments4`` or ``moments6`` (the render method)
coefficients        int        32             M Fourier coefficients (even, 4..128)
moment_storage_bits int        64             moments4: 64 (Theta4*, 16-bit) or 128; moments6: 64 (10-bit), 96, 192
overestimation      str|float  adaptive       moments: beta between lower (0) and upper (1) visibility bounds
weighting           str        transmittance  ``transmittance`` (Sec. 3.2) or ``average`` (Eq. 2)
reference_ray       str        pixels         per-slice reference ray: pixels (median pixel ray), optimal,
                                              bisectrix, mean
bits                int        0              0 float32 storage, 8 emulates RGBA8 (App. A)
guard_band          float      0.1            relative stretch of the depth bounds
epipole_block       int        32             least ray-marched region around an epipole in view (pixels)
epipole_angle_deg   float      8              ray-marched disc around an epipole in view (degrees; 0 and block 0: off)
epipole_steps       int        64             ray-march steps inside that region
rectification       str        auto           ``auto``, ``projective`` or ``nonlinear``
epipole_margin      float      1.0            ``auto`` threshold, half image heights outside the image
regions             int        8              light-frustum regions of the projective map (Sec. 4.2)
projective_weights  str        exact          ``exact`` column lengths or ``cross_ratio`` (Eq. 12's d)
splits              int        1              prefilter regions per row (Sec. 3.3; 1 = off)
resample_filter     str        none           non-linear resampling: ``none`` (nearest depth) or ``moments``
                                              (Peters 2017 Sec. 5.2: filtered 4-moment map + Algorithm 2)
resample_filter_px  int|None   None           Gaussian width (shadow-map texels) of that map; None: the radial
                                              rectified texel footprint (:func:`~.rectify.resample_footprint_texels`)
caster_culling      str|bool   auto           empty the texels whose blocker shadows no pixel (stage
                                              ``caster_culling``, :func:`cull_unseen_casters`; warpscatter's);
                                              auto: moments4/moments6 only
caster_culling_bias float      1/64           its depth tolerance (fraction of the rectified depth range)
==================  =========  =============  ==========================================================
"""

from __future__ import annotations

from contextlib import nullcontext
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..parallel import launch_rows
from ..scene.camera import CameraParams, pixel_ray_direction
from ..scene.lights import DirectionalLight, LightParams, light_params, light_texture_array
from ..scene.medium import phase_eval, transmittance_integral
from ..shadows import moments as mm
from ..shadows.shadow_map import ShadowMapParams
from ..wpinit import default_device, module_options
from . import rectify, rectify_projective
from .prefilter import (
    MAX_SPLITS,
    MOMENT_STORAGE,
    FilteredBasis,
    moments_visibility,
    prefilter_moments,
    prefilter_weighted,
    prefiltered_visibility_split,
    texel_footprint,
)
from .raymarch import JITTER_PER_PIXEL, VISIBILITY_SHADOW_MAP, MediumParams, march_ray, medium_params, visibility_inputs
from .rectify import NonlinearRectification, NonlinearRectParams, reference_ray, resample_shadow_map
from .rectify_projective import (
    EPIPOLE_MARGIN,
    MAX_REGIONS,
    ProjectiveRectification,
    ProjectiveRectParams,
    choose_rectification,
    column_lengths,
    cross_ratio_factors,
    rasterize_rectified,
    reference_rays,
)

module_options()

RECT_NONLINEAR = 0
RECT_PROJECTIVE = 1

#: Default angular radius (degrees) of the ray-marched disc around an epipole in view (Klehm 2014 Fig. 8).
EPIPOLE_ANGLE_DEG = 8.0
#: Width of the blend band beyond the ray-marched disc, relative to its radius.
EPIPOLE_BLEND = 0.25
#: Default tolerance of caster culling, as a fraction of the rectified depth range: a texel is kept only for
#: readers at least this much deeper than its blocker. Between neighbouring rows (slices) and at a ray's last
#: prefix column, the surface a ray ends on can lie a little in FRONT of the ray in the map although it is behind
#: it in the scene (discretisation acne); 1/64 covers that on the bench scenes (0, 1/128 and 1/32 measured).
CASTER_CULLING_BIAS = 1.0 / 64.0


#: The visibility representations of prefiltered single scattering (render methods).
BASES = ("fourier", "moments4", "moments6")
#: Resampling filters of the non-linear rectification (Peters 2017 Sec. 5.2).
RESAMPLE_FILTERS = ("none", "moments")
#: Widest Gaussian of filtering during resampling (shadow-map texels).
MAX_RESAMPLE_FILTER_PX = 64


@dataclass(frozen=True)
class PrefilteredSettings:
    """Parameters of the prefiltered methods ``fourier``, ``moments4`` and ``moments6`` (see the module doc's table).

    Attributes:
        basis: ``"fourier"`` (Klehm 2014), ``"moments4"`` or ``"moments6"`` (Peters 2017 Sec. 5.3-5.4).
        coefficients: M, number of Fourier coefficients (even, 4..128).
        moment_storage_bits: bits per texel of the moment maps: 64 or 128 (4 moments), 64 (60 used), 96 or 192
            (6 moments); None: 64.
        overestimation: the weight beta between the sharp lower (0) and upper (1) visibility bounds of the
            moment methods: ``"adaptive"`` (beta = (1 + omega_l . omega_p) / 2, Peters 2017 Sec. 5.3.1) or a number.
        weighting: ``"transmittance"`` (Klehm Sec. 3.2, Listing 2) or ``"average"`` (Listing 1, Eq. 2).
        reference_ray: per-slice reference ray for the weights: ``"optimal"`` (k_ref = sqrt(k_min k_max)
            where defined, else bisectrix), ``"bisectrix"``, ``"mean"`` or ``"pixels"`` (median of the slice's
            pixel rays).
        bits: 0 stores float32 filtered bases; 8 emulates the paper's 8-bit normalised storage (App. A).
        guard_band: relative stretch of the depth bounds (Peters 2017 uses 0.1).
        epipole_block: a minimum size of the ray-marched region around an epipole in view, as the side in pixels
            of Klehm's block (its half side, as an angle at the image centre, is the least region radius).
        epipole_angle_deg: angular radius of the ray-marched disc around an epipole in view (degrees; pixels whose
            view ray lies this close to the light direction or its flip). The larger of the two radii is used;
            both 0 disables the fallback. A band of ``EPIPOLE_BLEND`` times the radius beyond it blends both.
        epipole_steps: ray-march steps inside that block.
        rectification: ``"auto"``, ``"projective"`` (Klehm 2014 Sec. 4.2) or ``"nonlinear"`` (Peters 2017).
        epipole_margin: ``auto`` picks projective when every epipole in front of the camera lies at least this
            many half image heights outside the image (:func:`~.rectify_projective.choose_rectification`).
        regions: light-frustum regions of the projective rectification along x (Klehm 2014 Sec. 4.2, 1 = one
            matrix); counters its x^2 texel growth.
        projective_weights: per-texel weights of the projective map: ``"exact"`` column lengths or
            ``"cross_ratio"``, Klehm 2014 Eq. 12's constant growth factor d from the first three texel centres.
        splits: regions per row filtered independently (Klehm 2014 Sec. 3.3; 1 = off); exact up to rounding.
        resample_filter: ``"none"`` resamples the nearest shadow-map depth; ``"moments"`` filters during resampling
            (Peters 2017 Sec. 5.2): a 128-bit 4-moment map of the light view (2x2 supersampled, Gaussian filtered),
            a bilinear moment sample per rectified texel, two depths by Algorithm 2 and their weighted basis mix.
            Non-linear rectification only (the projective map is rasterized, not resampled).
        resample_filter_px: width in shadow-map texels of that Gaussian (1: bilinear only); None matches the
            radial footprint of a rectified texel, r_max / cols in texels (:func:`~.rectify.resample_footprint_texels`).
        caster_culling: True: empty (depth 1) every rectified texel whose blocker shadows no pixel's view ray
            (:func:`cull_unseen_casters`; a warpscatter addition); False: the papers' maps; ``"auto"``: True for the
            moment methods, False for ``fourier`` (:attr:`culls_casters`).
        caster_culling_bias: its depth tolerance, a fraction of the rectified depth range in [0, 0.25].
    """

    basis: str = "fourier"
    coefficients: int = 32
    moment_storage_bits: int | None = None
    overestimation: str | float = "adaptive"
    weighting: str = "transmittance"
    reference_ray: str = "pixels"
    bits: int = 0
    guard_band: float = 0.1
    epipole_block: int = 32
    epipole_angle_deg: float = EPIPOLE_ANGLE_DEG
    epipole_steps: int = 64
    rectification: str = "auto"
    epipole_margin: float = EPIPOLE_MARGIN
    regions: int = 8
    projective_weights: str = "exact"
    splits: int = 1
    resample_filter: str = "none"
    resample_filter_px: int | None = None
    caster_culling: str | bool = "auto"
    caster_culling_bias: float = CASTER_CULLING_BIAS

    def validate(self) -> "PrefilteredSettings":
        """Raise ValueError naming the first bad field; return self."""
        if self.resample_filter not in RESAMPLE_FILTERS:
            raise ValueError(f"resample_filter must be one of {', '.join(RESAMPLE_FILTERS)}, "
                             f"got {self.resample_filter!r}")
        if self.resample_filter_px is not None and (isinstance(self.resample_filter_px, bool) or
                                                    int(self.resample_filter_px) != self.resample_filter_px or
                                                    not 1 <= self.resample_filter_px <= MAX_RESAMPLE_FILTER_PX):
            raise ValueError(f"resample_filter_px must be null or an integer in [1, {MAX_RESAMPLE_FILTER_PX}], "
                             f"got {self.resample_filter_px}")
        if self.basis not in BASES:
            raise ValueError(f"basis must be one of {', '.join(BASES)}, got {self.basis!r}")
        if self.caster_culling not in ("auto", True, False):
            raise ValueError(f"caster_culling must be auto, true or false, got {self.caster_culling!r}")
        if not (np.isfinite(self.caster_culling_bias) and 0.0 <= self.caster_culling_bias <= 0.25):
            raise ValueError(f"caster_culling_bias must lie in [0, 0.25], got {self.caster_culling_bias}")
        if self.basis != "fourier":
            m = self.num_moments
            if self.moment_storage_bits is not None and self.moment_storage_bits not in MOMENT_STORAGE[m]:
                raise ValueError(f"moment_storage_bits for {m} moments must be one of {sorted(MOMENT_STORAGE[m])}, "
                                 f"got {self.moment_storage_bits}")
            if self.splits != 1:
                raise ValueError("splits > 1 is implemented for the fourier basis only")
            if self.overestimation != "adaptive" and not (isinstance(self.overestimation, (int, float))
                                                          and 0.0 <= self.overestimation <= 1.0):
                raise ValueError("overestimation must be 'adaptive' or a number in [0, 1], "
                                 f"got {self.overestimation!r}")
        if self.weighting not in ("transmittance", "average"):
            raise ValueError(f"weighting must be 'transmittance' or 'average', got {self.weighting!r}")
        if self.reference_ray not in ("optimal", "bisectrix", "mean", "pixels"):
            raise ValueError("reference_ray must be 'optimal', 'bisectrix', 'mean' or 'pixels', "
                             f"got {self.reference_ray!r}")
        if self.rectification not in ("auto", "projective", "nonlinear"):
            raise ValueError(f"rectification must be 'auto', 'projective' or 'nonlinear', got {self.rectification!r}")
        if self.projective_weights not in ("exact", "cross_ratio"):
            raise ValueError(f"projective_weights must be 'exact' or 'cross_ratio', got {self.projective_weights!r}")
        if isinstance(self.regions, bool) or int(self.regions) != self.regions or not 1 <= self.regions <= MAX_REGIONS:
            raise ValueError(f"regions must be an integer in [1, {MAX_REGIONS}], got {self.regions}")
        if isinstance(self.splits, bool) or int(self.splits) != self.splits or not 1 <= self.splits <= MAX_SPLITS:
            raise ValueError(f"splits must be an integer in [1, {MAX_SPLITS}], got {self.splits}")
        if not (np.isfinite(self.epipole_angle_deg) and 0.0 <= self.epipole_angle_deg <= 60.0):
            raise ValueError(f"epipole_angle_deg must lie in [0, 60], got {self.epipole_angle_deg}")
        if not (np.isfinite(self.epipole_margin) and self.epipole_margin >= 0.0):
            raise ValueError(f"epipole_margin must be finite and >= 0, got {self.epipole_margin}")
        return self

    @property
    def culls_casters(self) -> bool:
        """Whether caster culling runs: ``caster_culling``, with ``auto`` = the moment methods only (it lowers their
        error a lot where rays end on lit surfaces and moves fourier's slightly either way; README, Methods)."""
        if self.caster_culling == "auto":
            return self.basis != "fourier"
        return bool(self.caster_culling)

    @property
    def num_moments(self) -> int:
        """4 or 6 for the moment bases (0 for fourier)."""
        return {"moments4": 4, "moments6": 6}.get(self.basis, 0)

    @property
    def storage_bits(self) -> int:
        """Bits per texel of the filtered map the evaluation reads."""
        if self.basis == "fourier":
            return self.coefficients * (8 if self.bits == 8 else 32)
        return 64 if self.moment_storage_bits is None else int(self.moment_storage_bits)


# ---- one evaluation for both rectifications ----------------------------------------------------------------


@wp.struct
class RectificationParams:
    """Either rectification as kernels see it; ``kind`` selects RECT_NONLINEAR or RECT_PROJECTIVE."""

    kind: int
    nonlinear: NonlinearRectParams
    projective: ProjectiveRectParams


@wp.func
def rectified_coords(rect: RectificationParams, x: wp.vec3) -> wp.vec3:
    """Rectified (u, v, depth) of world point x: u along the view ray from the camera, v = row, depth in [0, 1]
    growing along the light (the common convention of :mod:`.rectify` and :mod:`.rectify_projective`)."""
    if rect.kind == RECT_PROJECTIVE:
        return rectify_projective.world_to_rectified(rect.projective, x)
    return rectify.world_to_rectified(rect.nonlinear, x)


def wrap_rows(rect) -> bool:
    """True when the rectified rows wrap around (non-linear rectification over the full azimuth circle)."""
    return isinstance(rect, NonlinearRectification) and bool(rect.full_circle)


def rectification_params(rect) -> RectificationParams:
    """Kernel-side :class:`RectificationParams` of a NonlinearRectification or ProjectiveRectification."""
    p = RectificationParams()
    if isinstance(rect, ProjectiveRectification):
        p.kind = RECT_PROJECTIVE
        p.projective = rect.params()
        p.nonlinear = NonlinearRectParams()
    elif isinstance(rect, NonlinearRectification):
        p.kind = RECT_NONLINEAR
        p.nonlinear = rect.params()
        p.projective = ProjectiveRectParams()
    else:
        raise ValueError(f"rect must be a NonlinearRectification or ProjectiveRectification, got {type(rect).__name__}")
    return p


BASIS_FOURIER = 0
BASIS_MOMENTS = 1


@wp.kernel
def pixel_coords_kernel(
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    rect: RectificationParams,
    out: wp.array2d(dtype=wp.vec3),
    offset: int,
):
    # the rectified (u, v, z_r) of every pixel's view-ray end (its G-buffer hit): what caster culling and the
    # evaluation look up
    j, i = wp.tid()
    j += offset
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    out[j, i] = rectified_coords(rect, cam.position + d * distance[j, i])


@wp.kernel
def evaluate_prefiltered_kernel(
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    coords: wp.array2d(dtype=wp.vec3),  # pixel_coords_kernel's output
    wrap: int,  # 1: the rows wrap around (wrap_rows)
    basis: int,  # BASIS_FOURIER or BASIS_MOMENTS
    filtered: wp.array3d(dtype=wp.float32),  # filtered Fourier basis or stored moments, (rows, cols, M)
    weight_sums: wp.array2d(dtype=wp.float32),  # Fourier split regions (see prefiltered_visibility_split)
    region_weights: wp.array2d(dtype=wp.float32),
    splits: int,
    moment_storage: int,  # moments.STORAGE*_ of the moment map
    beta: float,  # moment overestimation weight in [0, 1], or < 0: adaptive (Peters 2017 Sec. 5.3.1)
    light: LightParams,
    med: MediumParams,
    out: wp.array2d(dtype=wp.vec3),
    offset: int,
):
    # Klehm 2014 Listing 4 / Peters 2017 D.5: one filtered look-up and one reconstruction per pixel
    j, i = wp.tid()
    j += offset
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    s = distance[j, i]
    c = coords[j, i]
    f = float(0.0)
    if basis == BASIS_FOURIER:
        f = prefiltered_visibility_split(filtered, weight_sums, region_weights, splits, c[0], c[1], c[2], wrap)
    else:
        b = beta
        if b < 0.0:
            b = mm.adaptive_overestimation_weight(light.direction, d)
        f = moments_visibility(filtered, c[0], c[1], c[2], wrap, moment_storage, b)
    phase = phase_eval(med.phase_id, med.g, wp.dot(light.direction, -d))
    out[j, i] = light.radiance * (med.sigma_s * phase * f * transmittance_integral(med.sigma_t, 0.0, s))


def pixel_coords(rect, camera, distance: wp.array, device=None) -> wp.array:
    """(H, W) vec3 Warp array: the rectified (u, v, z_r) of every pixel's view-ray end (distance: G-buffer)."""
    device = default_device(device)
    out = wp.empty((camera.height, camera.width), dtype=wp.vec3, device=device)
    launch_rows(pixel_coords_kernel, (camera.height, camera.width),
                [camera.params(), distance, rectification_params(rect), out], device=device)
    return out


# ---- caster culling: texels whose blocker shadows no pixel ------------------------------------------------
#
# A pixel's look-up reads rows j0, j1 and the prefix columns up to i1 (texel_footprint), and a texel there shadows
# it only when the texel's blocker depth is below the pixel's z_r. A texel that no pixel reads with a larger z_r
# is lit for every pixel, whatever depth it holds: emptying it (depth 1) changes no hard-visibility result but
# takes its depth out of the filtered representation. Typical: a ground plane's own depths just behind the
# fragment depth of the rays that end on it, where Fourier series ring and moment bounds are loosest.

#: Depth bins per row of the caster-culling table (pixels are binned by z_r; a texel keeps its blocker when any
#: pixel in its bin or above reads it, so the binning only ever keeps more).
CULL_DEPTH_BINS = 1024


@wp.func
def cull_depth_bin(z: float) -> int:
    """Bin of rectified depth z in the caster-culling table."""
    return wp.clamp(int(wp.floor(z * float(CULL_DEPTH_BINS))), 0, CULL_DEPTH_BINS - 1)


@wp.kernel
def reader_table_kernel(coords: wp.array2d(dtype=wp.vec3), rows: int, cols: int, wrap: int,
                        table: wp.array2d(dtype=wp.int32)):
    # one launch (CPU atomics are exact within a launch): table[row, bin] = last prefix column a pixel of that depth
    # bin reads in that row (its look-up footprint, as the evaluation's)
    j, i = wp.tid()
    c = coords[j, i]
    j0, j1, ay, i0, i1, ax = texel_footprint(rows, cols, c[0], c[1], wrap)
    b = cull_depth_bin(c[2])
    wp.atomic_max(table, j0, b, i1)
    wp.atomic_max(table, j1, b, i1)


@wp.kernel
def reader_suffix_kernel(table: wp.array2d(dtype=wp.int32), offset: int):
    # table[row, b] = last column read by any pixel with a depth bin >= b
    j = wp.tid() + offset
    for k in range(CULL_DEPTH_BINS - 1):
        b = CULL_DEPTH_BINS - 2 - k
        table[j, b] = wp.max(table[j, b], table[j, b + 1])


@wp.func
def unread_blocker(table: wp.array2d(dtype=wp.int32), j: int, i: int, z: float, bias_bins: int) -> bool:
    """True when texel (j, i) holds a blocker (z < 1) that no pixel reads at least ``bias_bins`` bins deeper."""
    return z < 1.0 and table[j, wp.min(cull_depth_bin(z) + bias_bins, CULL_DEPTH_BINS - 1)] < i


@wp.kernel
def cull_casters_kernel(
    table: wp.array2d(dtype=wp.int32),
    depth: wp.array2d(dtype=wp.float32),
    depth2: wp.array2d(dtype=wp.float32),  # the second depth of a SparseRectifiedDepth (two_depths != 0)
    two_depths: int,
    bias_bins: int,
    culled: wp.array(dtype=wp.int32),  # per row: texels emptied (one row per thread: no race)
    offset: int,
):
    j, i = wp.tid()
    j += offset
    if unread_blocker(table, j, i, depth[j, i], bias_bins):
        depth[j, i] = 1.0
        culled[j] = culled[j] + 1
    if two_depths != 0 and unread_blocker(table, j, i, depth2[j, i], bias_bins):
        depth2[j, i] = 1.0


def cull_unseen_casters(rectified, rect, coords: wp.array, bias: float = 0.0, device=None) -> float:
    """Empty, in place, every texel of a rectified map whose blocker shadows no pixel's look-up.

    A texel is kept when some pixel's look-up (:func:`~.prefilter.texel_footprint`: its two rows, prefix columns up
    to i1) reads it with a depth z_r of at least the texel's depth + ``bias`` (pixels are binned by z_r into
    ``CULL_DEPTH_BINS`` bins, rounding towards keeping). With ``bias`` 0 no pixel's hard (step-function)
    visibility changes.

    Args:
        rectified: (rows, cols) float32 Warp array of rectified depth in [0, 1] (1: no blocker), or a
            :class:`~.rectify.SparseRectifiedDepth` (both depths are culled).
        rect: its NonlinearRectification or ProjectiveRectification.
        coords: (H, W) vec3 rectified coordinates of the pixels' view-ray ends (:func:`pixel_coords`).
        bias: tolerance in rectified depth (a fraction of the depth range), >= 0.

    Returns:
        The fraction of texels emptied (of the first depth).
    """
    device = default_device(device)
    if not (np.isfinite(bias) and bias >= 0.0):
        raise ValueError(f"caster culling bias must be finite and >= 0, got {bias}")
    bias_bins = int(np.floor(bias * CULL_DEPTH_BINS))  # floor: a partial bin still counts readers in it
    two = isinstance(rectified, rectify.SparseRectifiedDepth)
    depth = rectified.z1 if two else rectified
    rows, cols = int(depth.shape[0]), int(depth.shape[1])
    table = wp.full((rows, CULL_DEPTH_BINS), -1, dtype=wp.int32, device=device)
    wrap = int(wrap_rows(rect))
    wp.launch(reader_table_kernel, dim=coords.shape, inputs=[coords, rows, cols, wrap, table], device=device)
    launch_rows(reader_suffix_kernel, rows, [table], device=device)
    culled = wp.zeros(rows, dtype=wp.int32, device=device)
    launch_rows(cull_casters_kernel, (rows, cols),
                [table, depth, rectified.z2 if two else depth, int(two), int(bias_bins), culled], device=device)
    return float(culled.numpy().sum()) / float(rows * cols)


@wp.kernel
def epipole_region_kernel(
    cam: CameraParams,
    distance: wp.array2d(dtype=wp.float32),
    axis: wp.vec3,  # unit direction of the epipole from the camera (-L for the light, +L for its flip)
    cos_inner: float,  # cos of the fully ray-marched angular radius
    cos_outer: float,  # cos of the outer radius of the blend band (<= cos_inner)
    light: LightParams,
    light_tex: wp.array2d(dtype=wp.vec3),
    med: MediumParams,
    steps: int,
    seed: int,
    sm: ShadowMapParams,
    sm_depth: wp.array2d(dtype=wp.float32),
    sm_bias: float,
    x0: int,  # pixel rectangle origin (column, row) of the launch
    y0: int,
    out: wp.array2d(dtype=wp.vec3),
    offset: int,
):
    # Klehm 2014 Sec. 5, Fig. 8: ray-march where the epipolar slices converge; a linear blend in the angle over
    # the band between the inner and outer radius hides the seam to the prefiltered result
    j, i = wp.tid()
    j += offset + y0
    i += x0
    d = pixel_ray_direction(cam, float(i) + 0.5, float(j) + 0.5)
    c = wp.dot(d, axis)
    if c > cos_outer:
        marched = march_ray(cam, i, j, distance[j, i], light, light_tex, med, steps, seed, JITTER_PER_PIXEL,
                            VISIBILITY_SHADOW_MAP,
                            wp.uint64(0), 0.0, sm, sm_depth, sm_bias)
        w = float(1.0)
        if c < cos_inner:
            psi = wp.acos(wp.clamp(c, -1.0, 1.0))
            psi_in = wp.acos(cos_inner)
            psi_out = wp.acos(cos_outer)
            w = (psi_out - psi) / wp.max(psi_out - psi_in, 1.0e-12)
        out[j, i] = marched * w + out[j, i] * (1.0 - w)


# ---- host side ------------------------------------------------------------------------------------------------


def epipole_pixels(camera, light_direction) -> list[tuple[float, float, str]]:
    """Image positions (x, y in pixels, y down) of the light's epipole and anti-epipole when they lie in front.

    The epipole is where rays towards the light (direction -L) meet the image; the anti-epipole is the
    vanishing point of the light's travel direction +L (anti-crepuscular rays converge there).
    """
    vp = camera.view_projection()
    out = []
    for sign, name in ((-1.0, "light"), (1.0, "anti-light")):
        c = vp @ np.append(sign * np.asarray(light_direction, float), 0.0)
        if c[3] <= 1e-9:
            continue
        x = (c[0] / c[3] * 0.5 + 0.5) * camera.width
        y = (0.5 - 0.5 * c[1] / c[3]) * camera.height
        out.append((float(x), float(y), name))
    return out


@dataclass(frozen=True)
class EpipoleRegion:
    """A ray-marched region around an epipole in view (Klehm 2014 Sec. 5, Fig. 8).

    Pixels whose view ray lies within ``inner_deg`` of ``axis`` are ray-marched; between ``inner_deg`` and
    ``outer_deg`` the marched and prefiltered results are blended linearly in the angle. ``rect`` (x0, y0, w, h)
    bounds those pixels in the image.
    """

    name: str  # "light" (axis -L) or "anti-light" (axis +L)
    axis: tuple[float, float, float]  # unit direction of the epipole from the camera (world)
    inner_deg: float
    outer_deg: float
    rect: tuple[int, int, int, int]


def _pixel_angle_deg(camera, block: int) -> float:
    """Angle (degrees) subtended by ``block / 2`` pixels at the image centre (a pixel size -> angle conversion)."""
    t = np.tan(np.radians(camera.fov_y) / 2.0)
    return float(np.degrees(np.arctan(t * block / camera.height)))


def _cone_rect(camera, axis: np.ndarray, angle_deg: float, stride: int = 4) -> tuple[int, int, int, int] | None:
    """Pixel rectangle (x0, y0, w, h) bounding the pixels whose view ray lies within ``angle_deg`` of ``axis``, or
    None when there are none. Found on every ``stride``-th pixel with the angle widened by ``stride`` pixels and
    the rectangle padded by ``stride``, so it is conservative for any cone wider than a few pixels."""
    d = camera.ray_directions(stride)
    margin = _pixel_angle_deg(camera, 2 * stride)
    rows, cols = np.nonzero(d @ axis > np.cos(np.radians(min(angle_deg + margin, 180.0))))
    if len(rows) == 0:
        return None
    x0 = max(int(cols.min()) * stride - stride, 0)
    y0 = max(int(rows.min()) * stride - stride, 0)
    x1 = min(int(cols.max()) * stride + 2 * stride, camera.width)
    y1 = min(int(rows.max()) * stride + 2 * stride, camera.height)
    return (x0, y0, x1 - x0, y1 - y0)


def epipole_regions(camera, light_direction, angle_deg: float, block: int = 0,
                    blend: float = EPIPOLE_BLEND) -> list[EpipoleRegion]:
    """The ray-marched regions around each epipole whose cone touches the image.

    Args:
        camera: the :class:`~warpscatter.scene.camera.Camera`.
        light_direction: unit direction the light travels.
        angle_deg: angular radius (degrees) of the fully ray-marched disc around the epipole direction.
        block: a minimum radius in pixels at the image centre, as ``block / 2`` (Klehm's block side; 0: none).
        blend: relative width of the blend band beyond the inner radius (outer = inner * (1 + blend)).

    Returns:
        One :class:`EpipoleRegion` per epipole ("light": towards the light, "anti-light": its flip) whose region
        meets the image; empty when both radii are 0.
    """
    inner = max(float(angle_deg), _pixel_angle_deg(camera, block) if block > 0 else 0.0)
    if inner <= 0.0:
        return []
    outer = min(inner * (1.0 + blend), 89.0)
    inner = min(inner, outer)
    regions = []
    for sign, name in ((-1.0, "light"), (1.0, "anti-light")):
        axis = sign * np.asarray(light_direction, float)
        axis = axis / np.linalg.norm(axis)
        rect = _cone_rect(camera, axis, outer)
        if rect is not None:
            regions.append(EpipoleRegion(name, tuple(float(a) for a in axis), inner, outer, rect))
    return regions


def epipole_pixel_fraction(camera, regions: list[EpipoleRegion], stride: int = 4) -> float:
    """Fraction of the image's pixels inside the regions' outer cones (ray-marched), estimated on every
    ``stride``-th pixel."""
    if not regions:
        return 0.0
    d = camera.ray_directions(stride)
    inside = np.zeros(d.shape[:2], bool)
    for r in regions:
        inside |= d @ np.asarray(r.axis) > np.cos(np.radians(r.outer_deg))
    return float(inside.mean())


def march_epipole_regions(scene, gbuffer, shadow_map, regions: list[EpipoleRegion], out: wp.array, *, steps: int,
                          seed: int, shadow_bias_texels: float, device=None) -> None:
    """Ray-march the pixels of ``regions`` into ``out`` (shadow-map visibility, the reference marcher's estimator),
    blending with the prefiltered values already in ``out`` over each region's blend band."""
    cam = scene.camera
    _, _, _, sm_params, sm_depth, bias = visibility_inputs(scene, "shadow_map", None, shadow_map, shadow_bias_texels,
                                                           device)
    light_tex = light_texture_array(scene.light, device)
    for r in regions:
        x0, y0, w, h = r.rect
        launch_rows(epipole_region_kernel, (h, w),
                    [cam.params(), gbuffer.distance, wp.vec3(*r.axis), float(np.cos(np.radians(r.inner_deg))),
                     float(np.cos(np.radians(r.outer_deg))), light_params(scene.light), light_tex,
                     medium_params(scene.medium), int(steps), int(seed), sm_params, sm_depth, float(bias), int(x0),
                     int(y0), out], device=device)


def row_weights(rect, settings: PrefilteredSettings, sigma_t: float,
                camera=None) -> tuple[np.ndarray, np.ndarray | None, dict]:
    """Per-row optical steps and per-column lengths of the prefilter weights (Klehm 2014 Sec. 3.2, Eq. 11-12).

    Non-linear rectification: uniform columns, tau_j = sigma_t Delta_ref of the row's reference ray. Projective:
    column lengths l_i = dX_i / dX_0 (exact, or Eq. 12's Delta d^i per region) and tau_j = sigma_t times the
    reference ray's world length of column 0 (dX_0 sqrt(1 + s^2 + zeta_ref^2)). ``camera`` is needed by the
    ``"pixels"`` reference ray.

    Returns:
        (optical_step (rows,) float32, column_length (cols,) float64 or None, info dict).
    """
    transmittance = settings.weighting == "transmittance"
    if isinstance(rect, NonlinearRectification):
        tau = reference_ray(rect, settings.reference_ray, camera).optical_steps(sigma_t) if transmittance else None
        return tau, None, {}
    lengths = column_lengths(rect, "exact" if settings.projective_weights == "exact" else "cross_ratio")
    info = {"projective_weights": settings.projective_weights}
    if settings.projective_weights == "cross_ratio":
        info["cross_ratio_d"] = [round(float(d), 6) for d in cross_ratio_factors(rect)[0]]
    tau = np.zeros(rect.rows, np.float32)
    if transmittance:
        scale = reference_rays(rect, settings.reference_ray, camera).length_scale
        tau = (sigma_t * lengths[0] * scale).astype(np.float32)
    return tau, lengths / lengths[0], info


def build_rectification(scene, settings: PrefilteredSettings, rows: int, cols: int):
    """Choose and build the rectification for ``scene``'s camera and directional light.

    Returns:
        (rect, choice): a :class:`~.rectify.NonlinearRectification` or
        :class:`~.rectify_projective.ProjectiveRectification`, and the
        :class:`~.rectify_projective.RectificationChoice` (kind and reason).
    """
    cam, light_dir = scene.camera, scene.light.direction
    choice = choose_rectification(cam, light_dir, settings.rectification, settings.epipole_margin)
    if choice.kind == "projective":
        try:
            rect = ProjectiveRectification.from_camera(cam, light_dir, guard_band=settings.guard_band, rows=rows,
                                                       cols=cols, regions=settings.regions)
            return rect, choice
        except ValueError as exc:  # numerically degenerate although the epipole is (barely) outside the image
            choice = rectify_projective.RectificationChoice(
                kind="nonlinear", reason=f"{choice.reason}; projective construction failed ({exc}): non-linear used",
                epipole_distance=choice.epipole_distance)
            rectify_projective.logger.warning("fourier rectification: %s", choice.reason)
    rect = NonlinearRectification.from_camera(cam, light_dir, guard_band=settings.guard_band, rows=rows, cols=cols)
    return rect, choice


def resample_filtered(scene, rect: NonlinearRectification, shadow_map, settings: PrefilteredSettings, stage,
                      device) -> tuple:
    """Filtering during resampling (Peters 2017 Sec. 5.2): stage ``resample_msm`` generates the light view's
    128-bit 4-moment map (2x2 supersampled, :func:`~warpscatter.shadows.msm.generate_moment_shadow_map`) and
    Gaussian-filters it (``resample_filter_px``, default the radial rectified texel footprint); stage ``rectify``
    resamples it with Algorithm 2 (:func:`~.rectify.resample_moment_shadow_map`).

    Returns:
        (:class:`~.rectify.SparseRectifiedDepth`, the Gaussian width used in shadow-map texels).
    """
    from ..shadows import msm as msm_maps

    filter_px = settings.resample_filter_px
    if filter_px is None:
        filter_px = int(np.clip(round(rectify.resample_footprint_texels(rect, shadow_map.texel_world)), 1,
                                MAX_RESAMPLE_FILTER_PX))
    with stage("resample_msm"):
        moments = msm_maps.filter_moment_shadow_map(
            msm_maps.generate_moment_shadow_map(scene, shadow_map, supersampling=2, bits=128, device=device),
            filter_px, device=device)
    with stage("rectify"):
        return rectify.resample_moment_shadow_map(rect, moments, device=device), int(filter_px)


def render_prefiltered(scene, gbuffer, shadow_map, *, map_size: tuple[int, int],
                       settings: PrefilteredSettings = None, seed: int = 0, shadow_bias_texels: float = 1.0, timer=None,
                       device=None):
    """Prefiltered single scattering: the ``fourier``, ``moments4`` and ``moments6`` methods (see the module doc).

    Args:
        scene: the :class:`~warpscatter.scene.Scene` (directional light).
        gbuffer: the camera :class:`~warpscatter.gbuffer.GBuffer` (rasterized).
        shadow_map: the light's :class:`~warpscatter.shadows.shadow_map.ShadowMap` (orthographic); resampled
            by the non-linear rectification and ray-marched in the epipole blocks.
        map_size: (cols, rows) of the rectified map: texels along each view ray x epipolar slices.
        settings: :class:`PrefilteredSettings` (``basis`` selects the method).
        seed: jitter seed of the epipole block's ray marching.
        shadow_bias_texels: shadow-map bias of the epipole block's ray marching.
        timer: optional callable ``timer(stage_name)`` returning a context manager (e.g. a pipeline StageTimer).
        device: Warp device.

    Returns:
        (L_scat, info): (H, W) vec3 wp.array and a dict describing the rectification (kind and the reason it
        was chosen), the filtered textures and the epipole blocks.

    Raises:
        ValueError: for a non-directional light or bad settings.
    """
    device = default_device(device)
    settings = (settings or PrefilteredSettings()).validate()
    if not isinstance(scene.light, DirectionalLight):
        raise ValueError(f"the {settings.basis} method needs a directional light (render.scattering.method)")
    stage = timer or (lambda name: nullcontext())
    cam = scene.camera
    cols, rows = map_size
    with stage("rectify"):
        rect, choice = build_rectification(scene, settings, rows, cols)
        filtered_resampling = isinstance(rect, NonlinearRectification) and settings.resample_filter == "moments"
        if isinstance(rect, ProjectiveRectification):
            casters = scene.casters()
            rectified = rasterize_rectified(rect, casters.vertices, casters.triangles, device=device)
        elif not filtered_resampling:
            rectified = resample_shadow_map(rect, shadow_map.depth, shadow_map.view_projection, depth="linear",
                                            world_to_view=shadow_map.view, device=device)
    resample_info = {"resample_filter": settings.resample_filter if filtered_resampling else "none"}
    if filtered_resampling:
        rectified, resample_info["resample_filter_px"] = resample_filtered(scene, rect, shadow_map, settings,
                                                                           stage, device)
    with stage("pixel_coords"):
        coords = pixel_coords(rect, cam, gbuffer.distance, device=device)
    culled = None
    if settings.culls_casters:
        with stage("caster_culling"):
            culled = cull_unseen_casters(rectified, rect, coords, bias=settings.caster_culling_bias, device=device)
    with stage("prefilter"):
        tau, lengths, weight_info = row_weights(rect, settings, scene.medium.sigma_t, cam)
        if settings.basis == "fourier":
            fb: FilteredBasis = prefilter_weighted(rectified, settings.coefficients, tau, lengths,
                                                   splits=settings.splits, bits=settings.bits, device=device)
            basis, storage = BASIS_FOURIER, 0
        else:
            moments = prefilter_moments(rectified, settings.num_moments, tau, lengths,
                                        storage_bits=settings.storage_bits, device=device)
            fb = FilteredBasis(basis=moments, weight_sums=wp.zeros((1, 1), dtype=wp.float32, device=device),
                               region_weights=wp.zeros((1, 1), dtype=wp.float32, device=device), splits=1)
            basis, storage = BASIS_MOMENTS, MOMENT_STORAGE[settings.num_moments][settings.storage_bits]
    with stage("evaluate"):
        beta = -1.0 if settings.overestimation == "adaptive" else float(settings.overestimation)
        out = wp.empty((cam.height, cam.width), dtype=wp.vec3, device=device)
        launch_rows(evaluate_prefiltered_kernel, (cam.height, cam.width),
                    [cam.params(), gbuffer.distance, coords, int(wrap_rows(rect)), basis, fb.basis, fb.weight_sums,
                     fb.region_weights, fb.splits, storage, beta, light_params(scene.light),
                     medium_params(scene.medium), out], device=device)
    regions = epipole_regions(cam, scene.light.direction, settings.epipole_angle_deg, settings.epipole_block)
    if regions:
        with stage("epipole"):
            march_epipole_regions(scene, gbuffer, shadow_map, regions, out, steps=settings.epipole_steps, seed=seed,
                                  shadow_bias_texels=shadow_bias_texels, device=device)
    info = {
        "rectification": choice.kind,
        "rectification_reason": choice.reason,
        "epipole_distance": round(choice.epipole_distance, 4) if np.isfinite(choice.epipole_distance) else None,
        "rectified_map": [cols, rows],
        "basis": settings.basis,
        **({"coefficients": settings.coefficients, "splits": fb.splits} if settings.basis == "fourier" else
           {"overestimation": settings.overestimation}),
        "bits_per_texel": settings.storage_bits,
        **resample_info,
        "caster_culling": culled is not None,
        **({} if culled is None else {"culled_texel_fraction": round(culled, 4)}),
        "filtered_map_bytes": int(rows * cols * settings.storage_bits // 8),
        "epipole_blocks": [[*r.rect, r.name] for r in regions],
        "epipole_angle_deg": round(regions[0].inner_deg, 3) if regions else None,
        "epipole_raymarched_fraction": round(epipole_pixel_fraction(cam, regions), 4),
    }
    if isinstance(rect, ProjectiveRectification):
        info.update({"regions": rect.regions, "near_far": [round(rect.near, 6), round(rect.far, 6)], **weight_info})
    else:
        info["full_circle"] = rect.full_circle
    return out, info
