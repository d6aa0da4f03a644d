"""Settings of the single-scattering methods: the keys, defaults, ranges and meanings of ``render.scattering``
(Warp-free; the only place they are written).

:class:`ScatteringSettings` holds what every method shares (``method``, ``visibility``, ``steps``, ``seed``,
``jitter``, ``shadow_map``) and one section per technique: ``prefiltered`` (what ``fourier``, ``moments4`` and
``moments6`` share), ``fourier``, ``moments``, ``epipolar``. The methods themselves are listed in
:mod:`warpscatter.methods`; each reads the shared keys and its own sections.

Example (a validated settings object for the library's ``render`` functions)::

    settings = ScatteringSettings(method="epipolar", steps=64, visibility="shadow_map", epipolar={"lines": 512})
"""

from __future__ import annotations

import math
from typing import Annotated, Literal, Optional, Union

from pydantic import Field, field_validator, model_validator

from .. import methods
from ..schema import MAX_IMAGE_SIDE, MAX_STEPS, Bool, Float, Int, Seed, SettingsModel
from ..shadows.settings import ShadowMapSettings

# ---- limits and defaults (one home; the technique modules import them) ---------------------------

#: Visibility of the marching methods (``raymarch``, ``epipolar``).
VISIBILITY_MODES = ("exact", "shadow_map")
#: Step patterns of the marching methods (:mod:`~warpscatter.scattering.marching`).
JITTERS = ("per_pixel", "fixed")
#: The prefiltered methods' visibility representations.
PREFILTERED_BASES = ("fourier", "moments4", "moments6")
#: Fourier coefficients M (even).
MIN_COEFFICIENTS = 4
#: fourier's Fourier coefficients M by default, with FOURIER_SEGMENTS (the pair measured there); 32 before. Under the
#: textured spot (configs/spot.yaml, 960x540, rel. L1 against the exact marcher) 32 / 48 / 64: 0.79 / 0.65 / 0.60 %,
#: 1080p 1471 / 1622 / 1820 ms. A 1024^2 float32 texture is 192 MB at 48 (128 at 32, 256 at 64).
FOURIER_COEFFICIENTS = 48
MAX_COEFFICIENTS = 128
#: Bits per texel of the prefiltered moment maps, per moment count (Peters 2017 Sec. 5.4.3, Table 1).
MOMENT_STORAGE_BITS = {4: (64, 128), 6: (64, 96, 192)}
#: Default angular radius (degrees) of the ray-marched disc around an epipole in view (Klehm 2014 Fig. 8).
EPIPOLE_ANGLE_DEG = 8.0
MAX_EPIPOLE_ANGLE_DEG = 60.0
#: ``rectification: auto`` (:func:`~.rectify_projective.choose_rectification`) picks projective when every epipole
#: in front of the camera lies at least this far outside the image, in units of the image's half height on the
#: image plane (NDC y units; x scaled by the aspect ratio). Measured on the quickstart colonnade (160x90, 512^2
#: maps, 8 regions, relative L1 against the shadow-map marcher) while turning the light towards the view: with the
#: LIGHT epipole approaching, projective stays as good as non-linear down to 0.14 (0.060 vs 0.063; 0.015 vs 0.016
#: at 1.1); with the ANTI-light epipole approaching it falls behind (0.0080 vs 0.0074 at 1.8, 0.0110 vs 0.0094 at
#: 0.70, 0.0188 vs 0.0127 at 0.30), so 1.0 keeps projective within ~15 % of non-linear where it is chosen.
EPIPOLE_MARGIN = 1.0
#: Most light-frustum regions of the projective rectification (Klehm 2014 Sec. 4.2).
MAX_REGIONS = 16
#: Most split regions of a row (Klehm 2014 Sec. 3.3 uses up to 4).
MAX_SPLITS = 16
#: Resampling filters of the non-linear rectification (Peters 2017 Sec. 5.2) and the widest Gaussian (texels). The
#: default, supersample (:func:`~.rectify_nonlinear.resample_shadow_map`), measured at 640x360, 1024^2 maps, rel. L1
#: against the 512-step exact marcher (colonnade / canopy / window, fourier): none 3.83 / 1.22 / 9.69 %, supersample
#: 3.01 / 0.98 / 9.48 %, moments 3.19 / 0.92 / 9.55 %; moments6 on the colonnade 6.61 / 6.35 / 6.08 %. It removes
#: the radial streaks of the nearest depths as the moments filter does; cost at 1024^2 ~+55 ms CPU time in rectify
#: with 2 radial samples (the moments filter: 120-310 ms wall time in resample_msm alone, 2 shared cores).
RESAMPLE_FILTERS = ("none", "supersample", "moments")
MAX_RESAMPLE_FILTER_PX = 64
#: Default tolerance of caster culling, as a fraction of the rectified depth range: a texel is kept only for
#: readers at least this much deeper than its blocker. Between neighbouring rows (slices) and at a ray's last
#: prefix column, the surface a ray ends on can lie a little in FRONT of the ray in the map although it is behind
#: it in the scene (discretisation acne); 1/64 covers that on the bench scenes (0, 1/128 and 1/32 measured).
CASTER_CULLING_BIAS = 1.0 / 64.0
MAX_CASTER_CULLING_BIAS = 0.25
#: Default bits per texel of the moment maps. Six moments: Peters 2017 Sec. 5.4.3's 96-bit Theta6* (16-bit codes), not
#: the 60-bit one: its moment bias (4e-3) leaks light through walls (Peters Fig. 19). Measured at 640x360 with 3 ray
#: segments, rel. L1 against the exact marcher (colonnade / canopy / window): 64 bits 7.3 / 1.1 / 23 %, 96 bits
#: 6.8 / 1.0 / 15.7 %, 192 bits 6.8 / - / 13.9 %, evaluate time the same at 1080p. Four moments: 64 bits (Theta4* in
#: 16-bit codes); 128 bits measured no better (11.5 / 1.2 / 19.4 % against 11.5 / 1.2 / 20.3 %).
DEFAULT_MOMENT_BITS = {4: 64, 6: 96}
#: Ray-march steps of the prefiltered methods' epipole region by default. Its strata hold equal shares of the
#: transmittance weight, so few suffice for the error: 640x360 fourier rel. L1 against the exact marcher with
#: 128 / 64 / 32 steps colonnade 3.00 / 3.01 / 3.03 %, canopy 0.98 / 0.98 / 0.99 %; the epipole stage at 1080p costs
#: ~1.3 ms per step. But a ray near the sun crosses many map texels, and once the map is fitted to the casters
#: (``shadow_map.skip_unseen_planes``: 4x finer texels on the colonnade) 32 strata alias into streaks round the sun:
#: colonnade_sunset.yaml frame 40 at 640x360, the disc's high-pass energy against the exact render's 2.35x / 1.36x
#: in two boxes with 32 steps, 0.92 / 1.00x with 64 (0.86 / 0.93x with 96).
EPIPOLE_STEPS = 64
#: The epipole region is marched on a grid of every EPIPOLE_STRIDE-th pixel and at the pixels its cells cannot
#: interpolate (the evaluate_stride rule, with evaluate_tolerance: :mod:`~warpscatter.scattering.sparse_evaluation`);
#: the sky around the sun is smooth but for the shafts meeting there. 1920x1080 fourier, 1 -> 2: the march ran at
#: 0.32 / 0.37 / 0.25 of the region's pixels on the colonnade / canopy / window room, its kernel on the colonnade 38-51
#: -> 14 ms; rel. L1 against the exact reference on pixels off the 2-pixel grid (every 4th from 1) 2.54954 ->
#: 2.54950 %, 0.61790 -> 0.61799 %, 1.50406 -> 1.50406 % (a tighter tolerance is no closer: the march's own noise).
EPIPOLE_STRIDE = 2
#: Per-ray transmittance segments of the prefiltered look-ups by default (:mod:`.ray_weights`). Measured at 640x360,
#: 1024^2 maps, rel. L1 against the exact marcher (colonnade / canopy / window): fourier 1 segment 8.5 / 2.5 / 40 %,
#: 3 segments 4.0 / 1.2 / 9.8 %, 4 segments 3.9 / 1.2 / - %; moments6 9.0 / 2.4 / 31 % -> 7.3 / 1.1 / 23 %. Cost at
#: 1920x1080: the fourier evaluate stage ~2.2x (182 -> ~400 ms), moments6 ~2x; the least reference ray needs no
#: pass over the pixels (prefilter 143 -> 100 ms, 71 -> 30 ms).
SEGMENTS = 3
#: fourier's per-ray segments by default: adaptive (SEGMENT_DEPTH), at most this many. Measured at 480x270, 1024^2
#: maps, rel. L1 against the exact marcher on colonnade / canopy / window / quickstart / terrain / gate, each with its
#: own sun and with the sun behind the camera (12 cases): 3 fixed segments mean 2.69 % (the dark window room 17.6 %),
#: 6 fixed 1.33 % (4.2 %), 8 fixed 1.33 % (4.1 %); adaptive at 0.15: up to 4 1.91 %, up to 6 1.36 % (4.2 %; window
#: 2.94 -> 1.87 %, colonnade with the sun behind 0.47 -> 0.29 %, canopy 0.24 -> 0.10 %, quickstart 0.43 -> 0.18 %),
#: up to 8 1.33 %; up to 6 at 0.25 1.45 %. evaluate at 960x540 (gate / terrain / colonnade): 3 fixed 123 / 129 /
#: 97 ms, adaptive up to 6 178 / 178 / 94 ms, up to 8 197 / 207 / 103 ms (a look-up reads four columns per pass over
#: the coefficients: up to 6 segments is two passes, 8 three); 6 fixed ~1.7x the 3 fixed. The moment methods keep 3
#: fixed with the light ahead of the camera: with 6-8 (fixed or adaptive) their own-light colonnade and window get
#: worse (moments6 4.86 -> 5.31 %, 5.47 -> 7.38 %); with the light behind it they take these adaptive segments
#: (BEHIND_SEGMENTS, SEGMENT_DEPTH). fourier itself now takes more, finer segments (FOURIER_SEGMENTS).
BEHIND_SEGMENTS = 6
#: fourier's per-ray segments by default: adaptive (FOURIER_SEGMENT_DEPTH), at most this many. With 48 coefficients
#: (FOURIER_COEFFICIENTS) the two together: 1920x1080, 1024^2 maps, bench pareto's exact reference, colonnade /
#: canopy / window room, up to 6 at 0.15 and 32 coefficients (before) 1.43 / 0.346 / 1.50 %, up to 7 at 0.05 and 48
#: 1.34 / 0.253 / 0.976 %, at 0.08 1.34 / 0.253 / 0.986 % (the same look-ups fewer times), up to 8 at 0.05 1.34 /
#: 0.252 / 0.944 % but a third pass over the coefficients (a look-up reads four columns per pass: up to 7 segments is
#: two); either alone does little on the window room (up to 8 at 0.05 and 32: 1.27 %, 48 at up to 6: 1.42 %): its
#: rays look through the panes into the sun, where the shaft's edge must be both sharp in depth and cut finely.
FOURIER_SEGMENTS = 7
#: Optical-depth mismatch per segment of fourier's adaptive per-ray segments by default (ray_weights.segment_count);
#: see FOURIER_SEGMENTS (0.15 before, with up to 6).
FOURIER_SEGMENT_DEPTH = 0.08
#: Optical-depth mismatch per segment of the moment methods' adaptive per-ray segments with the light behind the
#: camera (it travels the way the camera looks; up to BEHIND_SEGMENTS; PrefilteredSettings.segments_for); fourier
#: took these until it took FOURIER_SEGMENTS. Measured at 960x540, 1024^2 maps, rel. L1
#: against the exact reference, the bench's seven scenes with the sun turned behind the camera, moments4 / moments6,
#: 3 fixed -> adaptive (beta 0.25): colonnade 0.94 -> 0.83 / 0.69 -> 0.59 %, canopy 0.226 -> 0.088 / 0.212 ->
#: 0.073 %, terrain 0.062 -> 0.031 / 0.061 -> 0.031 %, the dark window room 23.9 -> 10.7 / 19.5 -> 5.9 %, gate 0.163
#: -> 0.172 / 0.125 -> 0.118 %, quickstart 0.72 -> 0.84 / 0.47 -> 0.54 % (the last two recovered by the
#: overestimation along the light, OVERESTIMATION_ALONG_LIGHT).
SEGMENT_DEPTH = 0.15
#: Per-ray segments of the moment methods in a coloured medium, where each channel weights its rays with its own
#: extinction against prefix sums weighted with the least one (:func:`~.prefiltered.weights_extinction`): with
#: channel extinctions 4x apart, 3 segments left
#: the densest channel at 3.1 / 3.3 % rel. L1 (fourier / moments6) where its grey render errs 1.1 / 1.1 %; 5 segments
#: 1.2 / 1.3 % (tests/test_coloured_media.py's scene).
COLOURED_SEGMENTS = 5
#: Per-ray segments under a spot light (:mod:`.prefiltered_spot`; it always weights each ray by its own in-scattering).
#: The fence under the textured spot at 320x180, 1024^2 maps, rel. L1 fourier / moments4 / moments6 (with the filter
#: factor per panel, prefiltered_spot.filter_factors): 2 segments 1.06 / 2.09 / 1.22 %, 3: 1.04 / 2.11 / 1.27 %,
#: 4: 0.98 / 2.05 / 1.23 %, 6: 0.92 / 2.02 / 1.15 %, 8: 0.91 / 1.99 / 1.16 %; 4 and 6 cost the same at 1080p
#: (evaluate ~1.6-1.9 s with a coloured texture's three maps, run to run spread ~15 %).
SPOT_SEGMENTS = 6
MAX_SEGMENTS = 8
#: The moment methods' overestimation weight beta by default. With the depth bounds answering wholly lit and wholly
#: shadowed rays exactly, beta only weighs the rays that cross shadow edges, and a fixed 0.25 beat Peters' adaptive
#: rule on every case of bench fidelity (960x540, rel. L1, moments6 adaptive / 0.15 / 0.25 / 0.35 / 0.5: colonnade
#: 6.36 / 5.38 / 4.47 / 3.86 / 4.30 %, window room 8.63 / 6.44 / 6.11 / 8.20 / 13.9 %, quickstart 3.93 / 3.22 /
#: 2.90 / 3.07 / 4.12 %, dark room 82 / 28 / 36 / 44 / 56 %; moments4 adaptive / 0.25 / 0.4: colonnade 11.3 / 8.2 /
#: 6.7 %, window room 10.8 / 9.9 / 16.5 %, quickstart 8.7 / 5.6 / 5.6 %; canopy, terrain, gates within 0.1 %).
OVERESTIMATION = 0.25
#: ... and looking along the light (the sun behind the camera): the default beta rises from OVERESTIMATION for view
#: rays looking towards or across the light to this for rays looking the way light travels, beta = OVERESTIMATION +
#: (OVERESTIMATION_ALONG_LIGHT - OVERESTIMATION) max(0, omega_l . omega_p) -- Peters 2017 Sec. 5.3.1's observation
#: (the upper bound fits rays looking away from the light, the lower bound rays looking into it) on a narrower range
#: than his (1 + omega_l . omega_p) / 2. Rays looking towards the light keep 0.25, so every light-ahead render is
#: unchanged. Swept with the sun behind the camera (960x540, seven bench scenes, adaptive segments; beta 0.25 / 0.35 /
#: 0.4 / 0.45 held constant): moments4 quickstart 0.84 / 0.59 / 0.48 / 0.40 %, gate 0.172 / 0.138 / 0.132 / 0.135 %,
#: the dark window room 10.7 / 14.5 / 16.3 / 18.2 %; moments6 quickstart 0.54 / 0.41 / 0.36 / 0.31 %, window 5.9 /
#: 7.7 / 8.6 / 9.5 %; colonnade, canopy, terrain and the gates improve or hold to 0.45.
OVERESTIMATION_ALONG_LIGHT = 0.45
#: ... starting from omega_l . omega_p = this (``moments.overestimation_rise_cos``): beta = OVERESTIMATION +
#: (OVERESTIMATION_ALONG_LIGHT - OVERESTIMATION) clamp((omega_l . omega_p - c) / (1 - c), 0, 1). With c = 0 (the rule
#: above) rays across the light kept 0.25, and the sun beside the view (bench fidelity's third light) wanted more:
#: swept on the bench's 21 directional cases (960x540, 1024^2, rel. L1 against the exact reference, moments4 / moments6,
#: c = 0 / -0.5 / -0.75 / -1), the sun beside: colonnade 2.74 / 2.23 / 2.05 / 1.92 % and 2.23 / 1.98 / 1.90 / 1.83 %,
#: quickstart 0.575 / 0.470 / 0.426 / 0.396 % and 0.451 / 0.387 / 0.359 / 0.338 %, gate 0.216 / 0.194 / 0.187 / 0.181 %
#: and 0.161 / 0.149 / 0.145 / 0.143 %, window room 5.79 / 6.00 / 6.41 / 6.80 % and 6.36 / 5.28 / 4.94 / 4.73 %; the
#: dark window room (sun behind) 9.73 / 10.05 / 10.14 / 10.21 % and 4.82 / 4.96 / 5.00 / 5.03 %; the sun ahead: window
#: room moments4 7.50 / 7.50 / 7.51 / 7.95 %. Geometric mean of the 42 ratios 0.968 / 0.958 / 0.952, the worst 1.035 /
#: 1.107 / 1.174: -0.5 gains most of it for the least loss (3 cells worse, by up to 3.5 %).
OVERESTIMATION_RISE_COS = -0.5
#: moments4's overestimation weight under a spot light by default (moments6 keeps OVERESTIMATION there). Measured at
#: 960x540 against the exact reference (rel. L1 %, beta 0 / 0.05 / 0.1 / 0.25): colonnade_spot (the textured spot
#: outside the view) 2.04 / 2.28 / 2.58 / 3.69, spot_fence (the stained-glass spot in view) 2.06 / 1.92 / 1.84 / 1.71;
#: and at 640x360 the fence seen from above with the spot out of view 0.76 / 0.74 / 0.75 / 0.83 and from its other
#: side looking into the spot 0.99 / 0.99 / 1.01 / 1.15. moments6 on the same four, beta 0.05 / 0.1 / 0.25: 1.99 /
#: 2.06 / 2.38, 1.46 / 1.39 / 1.24, 0.58 / 0.57 / 0.55, 0.91 / 0.92 / 0.98: no clear winner, and the bundled
#: spot_moments.yaml (the fence, moments6) would lose 12 %, so it keeps 0.25.
SPOT_OVERESTIMATION_MOMENTS4 = 0.1
#: View rays within this angle (degrees) of the direction into a directional light take a smaller overestimation
#: weight, falling to 0 looking straight into it (``moments.epipole_taper_deg``): Peters 2017 Sec. 5.3.1 (Fig. 14)
#: finds the leaking strongest at the epipole and the lower bound right there; his (1 + omega_l . omega_p) / 2 over
#: the whole sphere lost elsewhere (OVERESTIMATION), so the taper is kept to a narrow cone. Measured at 960x540
#: against the exact reference, the sun-ahead bench cases, 0 / 2 / 3 / 4 degrees, moments4: colonnade 6.619 / 6.598 /
#: 6.559 / 6.556 %, gate 2.481 / 2.480 / 2.482 / 2.487 %, 60 %-opaque gate 1.981 / 1.980 / 1.981 / 1.986 %, terrain
#: 2.086 / 2.086 / 2.084 / 2.073 %; moments6: colonnade 4.742 / 4.727 / 4.701 / 4.683 %, gate 2.326 / 2.324 / 2.325 /
#: 2.326 %; the other cases have no pixel in the cone. 2: no case worse.
EPIPOLE_TAPER_DEG = 2.0
#: Texels a prefiltered look-up ends before its ray's end point by default: every ray's with the light behind the
#: camera (it travels the way the camera looks) and under a spot light, else those ending in shadow (END_OFFSET_LIT
#: for the rays ending lit). Measured with 3 segments (as above): fourier 0 texels
#: 3.6 / 1.2 / 16.2 %, 0.5: 3.7 / 1.2 / 12.7 %, 1: 4.0 / 1.2 / 9.8 % (the closed room's surfaces are their own
#: blockers: half a texel of each lit ray-end lights the dark room). With the sun behind the camera it is still the
#: best (960x540, 1024^2, rel. L1 against the exact reference, 1 / 0.5 / 0.25): fourier's dark window room 3.1 / 6.0 /
#: 8.7 %, quickstart 0.175 / 0.186 / 0.198 %, gate 0.112 / 0.121 / 0.129 %; moments4 / moments6 dark room 16.0 / 27.1 %,
#: 8.4 / 15.0 % at 1 / 0.5. Under a spot it hardly matters (fence, colonnade: within 0.01 % from 1 to 0.25).
END_OFFSET = 1.0
#: ... and for the rays that end lit (on no surface, or on a surface facing the light that the shadow map sees:
#: prefiltered.lit_ray_ends) under a directional light ahead of the camera (omega_l . camera forward <= 0). A lit
#: surface's own depth lies behind the ray's last samples and shadows them only through the texel's filtering, so a
#: quarter texel keeps its acne out; a shadowed end keeps a whole texel: 0.25 for every ray brought back the window
#: room's crease dots (5 -> 29 pixels of the dark room brighter than 2 % of the shafts at 320x180; 13 with 0.5, 13
#: with 0.25 for every surface merely facing the light, 5 with this rule). Measured at 960x540, 1024^2, rel. L1
#: against the exact reference, end_offset 1 for every ray -> this rule, fourier / moments4 / moments6: window room
#: 1.71 -> 1.53 %, 7.92 -> 7.57 %, 5.31 -> 4.91 %; colonnade 2.85 -> 2.77 %, 6.79 -> 6.74 %, 4.91 -> 4.86 %;
#: quickstart 1.80 -> 1.74 %, 3.87 -> 3.81 %, 3.01 -> 2.93 %; terrain 1.24 -> 1.21 %, 2.12 -> 2.09 %, 1.56 -> 1.52 %;
#: canopy and the gates within 0.02 % (better but for fourier's 60 %-opaque gate, 1.960 -> 1.962 %). 0.25 for every
#: ray would give more on the colonnade (2.41 / 6.43 / 4.64 %), with the dots; 0.125 or 0 for the lit ends moves the
#: errors by under 0.04 % (colonnade 2.75 / 6.73 / 4.85 % at 0.125, 2.74 / 6.73 / 4.84 % at 0). With the light
#: behind the camera 0.25 for the lit ends was worse for fourier (colonnade 0.287 -> 0.311 %, canopy 0.096 ->
#: 0.123 %), so there every ray keeps END_OFFSET.
END_OFFSET_LIT = 0.25
MAX_END_OFFSET = 8.0
#: Most shadow-map samples of the stretch a prefiltered look-up leaves out before a ray that ends in shadow under a
#: directional light ahead of the camera (its END_OFFSET texels; one PCF sample per shadow-map texel of its
#: length, at most this many). Before, that stretch took the look-up's own visibility: near the sun a texel of the
#: rectified map is a long stretch of ray (1 / sin of its angle to the light), in the end surface's shadow where the
#: look-up saw the lit air before it (colonnade_sunset's last frame, fourier 640x360 against the exact marcher: 4.94 ->
#: 4.02 %; a bright wedge on the pillar beside the sun). Measured at 960x540, 1024^2, rel. L1 against the exact
#: reference, 0 -> 4 samples (with the two rules below), fourier / moments4 / moments6: colonnade 2.744 -> 2.591 % /
#: 6.598 -> 6.337 % / 4.727 -> 4.735 %; canopy 0.679 -> 0.642 % / 0.757 -> 0.662 % / 0.685 -> 0.630 %; terrain 1.171 ->
#: 1.151 % / 2.086 -> 2.071 % / 1.520 -> 1.507 %; gate 2.305 -> 2.272 % / 2.480 -> 2.371 % / 2.324 -> 2.260 %; 60
#: %-opaque gate 1.922 -> 1.916 % / 1.980 -> 1.897 % / 1.866 -> 1.829 %; window room within 0.004 %; quickstart 1.720 ->
#: 1.768 % / 3.795 -> 3.826 % / 2.917 -> 2.972 % (higher: its look-up is too dark beside the central shafts and the
#: too-bright stretch made up for it; with exact visibility for the stretch it is as high). 16 samples, or hard samples:
#: within 0.015 % of these (hard ones streak along the rows). The evaluate stage (1080p, 2 threads, hard samples,
#: medians of 4 alternating rounds on a noisy machine): colonnade fourier 590 -> 726 ms, canopy moments6 580 -> 666 ms,
#: window room moments6 351 -> 372 ms.
END_SAMPLES = 4
MAX_END_SAMPLES = 64
#: The look-up runs on every EVALUATE_STRIDE-th pixel in x and y, and on the pixels between them that their grid cell
#: cannot interpolate (:mod:`~warpscatter.scattering.sparse_evaluation`: a corner off the pixel's surface by more than
#: EVALUATE_DEPTH_TOLERANCE of its distance, left to the marcher, or the corners' radiance spread over
#: EVALUATE_TOLERANCE of the largest). Measured at 960x540 (a coarser grid against the image than at 1080p), 1024^2,
#: rel. L1 against the exact reference, every pixel -> stride 2 with tolerance 0.02, fourier / moments6 / moments4:
#: colonnade 2.586 -> 2.585 % / 4.742 -> 4.741 % / 6.339 -> 6.338 % (sun behind 0.270 -> 0.271 % / 0.429 -> 0.430 % /
#: 0.602 -> 0.603 %); canopy 0.641 -> 0.641 % / 0.627 -> 0.627 % / 0.658 -> 0.658 % (0.0785 -> 0.0794 % / 0.0686 ->
#: 0.0694 % / 0.0807 -> 0.0815 %); window room 1.523 -> 1.517 % / 4.881 -> 4.879 % / 7.512 -> 7.510 % (1.974 ->
#: 1.939 % / 4.941 -> 4.835 % / 9.931 -> 9.746 %); quickstart 1.766 -> 1.763 % (0.166 -> 0.166 %); terrain 1.150 ->
#: 1.148 % (0.0359 -> 0.0381 % / 0.0279 -> 0.0298 % / 0.0285 -> 0.0303 %); gate 2.272 -> 2.270 % (0.101 -> 0.102 %);
#: 60 %-opaque gate 1.916 -> 1.915 %; colonnade spot 1.775 -> 1.776 %; spot fence 0.907 -> 0.915 % / 1.238 -> 1.247 %
#: / 1.841 -> 1.850 % (its shafts are a few pixels wide). Tolerance 0.05: the spot fence 0.951 %, the terrain behind
#: 0.0388 %, the rest within 0.01 % of these; 0.01: spot fence 0.908 %. At 1920x1080 (1024^2, 2 threads, medians of
#: 3 alternating rounds) the look-up ran at 28-35 % of the pixels, fourier's technique time colonnade / canopy /
#: window room 971 / 935 / 846 -> 652 / 626 / 612 ms, moments6's 976 / 854 / 631 -> 674 / 547 / 542 ms (evaluate
#: stage 628 / 585 / 409 -> 376 / 305 / 270 and 732 / 533 / 347 -> 352 / 233 / 232 ms); tolerance 0.05 evaluates
#: 27-29 % of the pixels (fourier's evaluate stage 50-80 ms less). 1: every pixel (the papers' evaluation).
EVALUATE_STRIDE = 2
MAX_EVALUATE_STRIDE = 8
EVALUATE_TOLERANCE = 0.02
EVALUATE_DEPTH_TOLERANCE = 0.04
#: The grid is filled coarse to fine over this many levels (:mod:`~warpscatter.scattering.sparse_evaluation`): the
#: look-up runs on every EVALUATE_STRIDE * 2^(levels - 1)-th pixel first, and each finer grid's new nodes are
#: interpolated in the coarser grid's cells by the same test (with half the radiance tolerance per coarser level) or
#: evaluated. ``auto``: 2 levels under a directional light on images of EVALUATE_LEVELS_AUTO_ROWS rows or more, else 1:
#: a 4-pixel grid at 1080 rows spans the view's angles as the 2-pixel grid, measured at 960x540, does there. Measured at
#: 1920x1080 against the exact reference (1024^2, rel. L1), one level as before -> two levels (with the phase divided
#: out of the coarse cells: prefiltered.render), fourier / moments6 / moments4: colonnade 2.5562 -> 2.5546 % / 4.7562 ->
#: 4.7554 % / 6.3525 -> 6.3515 %; canopy 0.6206 -> 0.6201 % / 0.6070 -> 0.6069 % / 0.6388 -> 0.6386 %; window room
#: 1.5010 -> 1.4983 % / 4.8344 -> 4.8324 % / 7.4075 -> 7.4058 %; fourier's look-up ran at 0.23 / 0.17 / 0.16 of the
#: pixels instead of 0.34 / 0.29 / 0.32, the evaluate stage (2 threads, fastest of 7) colonnade fourier 175 -> 157 ms,
#: moments6 178 -> 161 ms, window room 122 -> 106 / 113 -> 101 ms. The same coarse tolerance as the fine one: canopy
#: moments6 0.6071 %. At 960x540 two levels evaluate 0.28-0.45 instead of 0.35-0.52 of the pixels but raise the window
#: room's moments6 error 4.814 -> 4.820 % and the canopy's moments4 0.6387 -> 0.6389 %: there the coarse grid misses
#: shafts a few pixels wide. Under a spot light (no phase factor to interpolate apart: its 1/d^2 peak lies along each
#: ray) two levels raise the spot fence's error at 1920x1080 (fourier 0.9073 -> 0.9098 %, moments6 1.2645 -> 1.2672 %):
#: auto keeps one there.
EVALUATE_LEVELS = "auto"
EVALUATE_LEVELS_AUTO_ROWS = 1080
MAX_EVALUATE_LEVELS = 4
#: ... but for the rays within this many degrees of the light's direction, whose stretch runs along nearly one light
#: ray, where one shadow-map texel at a caster's silhouette decides it: there the look-up's visibility stays (the
#: colonnade's 320x180 rays within 2 degrees of its sun, rel. abs. error sum against the exact marcher, moments4 /
#: moments6: 3.19 / 3.38 with the look-up's, 3.70 / 4.00 sampled).
END_SAMPLES_MIN_DEG = 2.0
#: ... and for the rays whose left-out stretch carries less than this share of their transmittance weight (it moves
#: the pixel by less than that share of its value): most rays of a closed room end in shadow, and sampling all of them
#: cost the window room's 1080p evaluate stage a third more time for 0.02-0.17 % of rel. L1 (moments6 4.91 -> 4.75 %
#: with every ray, 4.91 % with this rule; the colonnade and the canopy keep their gains).
END_STRETCH_MIN_WEIGHT = 0.01
#: moments4's depth warp c by default (prefiltered.depth_warp; fourier and moments6: none). Four moments leak light
#: where a ray's depths sit close behind its blockers' in the map; the warp (e^(c z) - 1) / (e^c - 1) with c > 0 spreads
#: the far depths apart and the leak shrinks. Measured at 480x270, 1024^2 maps, rel. L1 against the exact marcher, c = 0
#: / 2 / 3 / 4 (sun ahead): colonnade 9.27 / 7.14 / 6.71 / 6.50 %, window room 8.91 / 7.96 / 8.14 / 8.70 %,
#: quickstart 5.86 / 3.82 / 3.86 / 4.09 %, canopy 1.03 / 0.83 / 0.82 / 0.82 %, terrain 2.49 / 2.02 / 2.15 / 2.41 %,
#: gate 3.77 / 2.95 / 2.87 / 2.85 %; the textured spot on the fence 2.01 / 1.58 / 1.58 / 1.67 %, on the colonnade
#: 5.03 / 4.03 / 3.72 / 3.58 %; with the sun behind the camera within 0.01 % (colonnade, canopy, quickstart, terrain,
#: gate) except the dark window room 23.1 / 27.6 / 26.7 %; c = -2 doubled every error. moments6 gains nothing (c = 1:
#: window room 5.47 -> 4.95 %, colonnade 4.86 -> 4.89 %; c = 2: spot fence 1.20 -> 1.38 %), fourier loses.
MOMENTS4_DEPTH_WARP = 3.0
#: Map columns from which moments4 uses all of MOMENTS4_DEPTH_WARP; coarser maps use c in proportion. The warp also
#: magnifies the depth spread inside a texel at the far end (by up to c e^c / (e^c - 1), 3.2 at c = 3), which grows
#: as the texels do: with c = 3 at 512 / 256 columns the window room went 9.32 -> 10.13 % / 12.89 -> 15.78 % and the
#: colonnade with the sun behind 1.45 -> 1.85 % / 2.70 -> 3.31 %; with c = 1.5 / 0.75 8.58 / 12.18 % and 1.64 /
#: 2.83 %, and every sun-ahead case still gains (colonnade 15.6 -> 14.0 % / 18.8 -> 17.8 %, quickstart 6.89 ->
#: 4.97 % / 8.95 -> 7.73 %, gate 4.38 -> 3.68 % / 7.40 -> 7.15 %). At 2048 columns c = 3 gains as at 1024
#: (colonnade 8.80 -> 6.21 %, window room 9.89 -> 8.72 %, quickstart 5.79 -> 3.25 %, gate 3.22 -> 2.32 %).
MOMENTS4_WARP_COLUMNS = 1024
#: Largest |c| of the exponential depth warp (prefiltered.depth_warp, filtered_textures.warped_depth).
MAX_DEPTH_WARP = 16.0
#: Most row mip levels of a prefiltered texture (prefiltered.mip_levels, row_mips): a pixel spanning up to 2^(8-1)
#: rows (the epipole's neighbourhood) reads a level whose rows are as wide as it.
MAX_MIP_LEVELS = 8
#: Border pixels per epipolar line by default (``epipolar.lines: null``): the line count follows the image size (1024
#: lines at 320x180 meet nearly every border pixel and ray-march 58-67 % of the pixels). Measured with exact visibility,
#: rel. L1 against the 512-step exact marcher and the share of pixels ray-marched (colonnade / canopy / window):
#: 320x180: 1024 lines 1.88 / 1.04 / 1.88 % (58 / 67 / 21 % marched), 256 lines 1.94 / - / 2.63 % (15 / - / 5 %),
#: 168 lines 2.13 / 1.08 / 3.16 %; 640x360: 1024 lines 1.84 / 1.00 / 1.85 % (14 / 16 / 5 %), 512 lines 1.81 / 1.01 /
#: 2.03 % (7 / 8 / 3 %), 336 lines 1.85 / 1.01 / 2.20 %. At 1920x1080 the ray marching is a tenth of the epipolar
#: time (the upsampling is most of it), so 1504 lines cost little more than 1024.
LINE_SPACING_PX = 4
#: Initial ray-marching samples per epipolar line by default (Engelhardt 2010 Sec. 4.1; its teaser uses 32). Between
#: them the lines interpolate, so where in-scattering curves smoothly (the sky, a sun behind the camera) fewer leave
#: interpolation error. Measured at 480x270 with shadow-map visibility, rel. L1 against the exact marcher, 16 / 32 /
#: 64: terrain with the sun behind 0.124 / 0.064 / 0.046 %, colonnade behind 0.388 / 0.304 / 0.259 %, canopy behind
#: 0.142 / 0.102 / 0.087 %, quickstart behind 0.237 / 0.178 / 0.144 %, window room 2.19 / 1.91 / 1.82 %, colonnade
#: 2.76 / 2.74 / 2.75 %. At 1920x1080 (medians of 3) the raymarch stage took 25-33 / 37-38 / 60-98 ms and the
#: discontinuity search 11-21 / 9-15 / 9-16 ms of a ~350 ms frame: 32 costs about nothing, 64 a tenth of the frame.
EPIPOLAR_INITIAL_SAMPLES = 32
#: Ray-march steps per ray of the raymarch method by default (the bench's shadow-map marcher at its defaults).
RAYMARCH_STEPS = 128
#: Ray-march steps per ray-marched sample of epipolar by default. Its samples are a few per cent of the pixels and its
#: error was mostly their marching noise, so more steps buy more than they cost. Equal-error speed-ups over the
#: shadow-map marcher (960x540, 1024^2, rel. L1 against the exact reference; the marcher's curve 8-1024 steps, both
#: patterns; medians of 3), colonnade / canopy / window room, 128 / 256 / 512 steps: 2.5x / 4.8x / 8.8x (2.78 / 2.27
#: / 2.09 %), 5.2x / 5.3x / 6.3x (1.10 / 0.80 / 0.66 %), 4.2x / 5.7x / 6.0x (1.41 / 0.92 / 0.70 %); 1024: 2.04 / 0.61 /
#: 0.63 % in 1.3-1.6x the time of 512 (the 1024^2 map's own error is the floor). At 1920x1080 the colonnade's raymarch
#: stage takes 100 ms with 128 steps, 339 ms with 512, of a 673 / 935 ms frame.
EPIPOLAR_STEPS = 512
#: ... of which a ray-marched epipolar sample takes this many per shadow-map texel its ray crosses (shadow-map
#: visibility; :func:`~.marching.texel_steps`), at least EPIPOLAR_LEAST_STEPS. A hard look-up is constant
#: along a texel's stretch of ray but for one depth crossing, so the fixed pattern's error depends on the steps per
#: texel, not per ray: at 1920x1080 with a 1024^2 map the colonnade's marched rays cross 75 texels (median; mean 292),
#: the canopy's 172 (375), the window room's 530 (553), and 512 steps gave the short ones 7-70 per texel. Measured at
#: 960x540 against the exact reference (rel. L1, the 16 bench fidelity cases), 512 fixed -> 4 / 6 / 8 per texel:
#: colonnade 2.067 -> 2.067 / 2.069 / 2.064 %, canopy 0.646 -> 0.647 / 0.646 / 0.647 %, gate 2.393 -> 2.395 / 2.393 /
#: 2.394 %, 60 %-opaque gate 1.931 -> 1.932 / 1.931 / 1.931 %, terrain 0.767 -> 0.767 %, quickstart 1.380 -> 1.380 %,
#: the window room and every sun-behind case within 0.0003 % (3 per texel: colonnade 2.080 %). The raymarch stage at
#: 1080p (two alternating runs): colonnade 240 / 245 -> 135 / 167 ms, canopy 242 / 282 -> 157 / 195 ms, window room
#: 125 / 119 -> 117 / 115 ms. Under a spot (its perspective map, counted on the finer of map and texture) the rays
#: near the light cross many texels: colonnade spot 0.7292 -> 0.7294 % in 484 steps on average, spot fence 0.7299 ->
#: 0.7299 % in 474. 0 gives every sample ``steps``.
EPIPOLAR_STEPS_PER_TEXEL = 4.0
#: Fewest steps of a ray-marched epipolar sample under EPIPOLAR_STEPS_PER_TEXEL (rays along the light cross few texels
#: but their depth sweeps through a caster's within one; 32 and 64 measured the same).
EPIPOLAR_LEAST_STEPS = 32
#: Taps per line of epipolar's bilateral upsampling by default. Engelhardt 2010 Sec. 4.3 filters along each of the two
#: nearest lines with 3-5 taps a multiple of the lines' distance apart; here the line textures hold a texel per pixel of
#: line length or more (``samples_per_line``: the image diagonal) and the marched samples carry little noise
#: (:data:`EPIPOLAR_STEPS`), so one tap, the line texture's depth-weighted linear interpolation at the pixel's
#: projection, measured within 1 % of the paper's filter (lower or equal on 11 of 16 cases) at half its cost. 960x540,
#: 1024^2, rel. L1 against the exact reference, 3 taps / 1 tap: colonnade 2.065 / 2.067 %, sun behind 0.231 / 0.227 %;
#: canopy 0.646 / 0.646 %, behind 0.068 / 0.065 %; window room 0.648 / 0.647 %, behind 0.229 / 0.201 %; quickstart 1.372
#: / 1.380 %, behind 0.099 / 0.097 %; terrain 0.760 / 0.767 %, behind 0.049 / 0.047 %; gate 2.385 / 2.393 %, behind
#: 0.071 / 0.069 %; 60 %-opaque gate 1.924 / 1.931 %, behind 0.065 / 0.063 %; colonnade spot 0.729 / 0.729 %; spot fence
#: 0.735 / 0.730 %. With noisier samples the taps help a little (128 steps, both step patterns: 3 taps 0.3-1.6 % lower
#: on the sun-ahead cases and the window room behind, 0.7-2.3 % higher on the colonnade and canopy behind). The
#: upsampling kernel at 1920x1080 on two cores: colonnade 269 -> 129 ms, window room 330 -> 158 ms.
EPIPOLAR_TAPS = 1
#: epipolar's upsampling runs on every EPIPOLAR_UPSAMPLE_STRIDE-th pixel in x and y and on the pixels between them that
#: their grid cell cannot interpolate (the prefiltered look-up's rule and tolerances, EVALUATE_TOLERANCE and
#: EVALUATE_DEPTH_TOLERANCE: :mod:`~warpscatter.scattering.sparse_evaluation`); warpscatter's, not in the paper.
#: 1920x1080, 1024^2, against the 2048-step exact reference on every 3rd pixel (bench pareto's), 1 -> 2: colonnade /
#: canopy / window room 1.240 -> 1.230 %, 0.278 -> 0.272 %, 0.578 -> 0.565 % (the cells interpolate the samples'
#: noise away); the filter ran at 0.40 / 0.37 / 0.36 of the pixels (0.36-0.53 at 960x540, 0.73 at 480x270), its stage
#: (``interpolate``, medians of 5 alternating rounds on two cores) 106 -> 81, 108 -> 75, 92 -> 61 ms. Against stride 1
#: at 960x540 the images differ by 0.02-0.03 % rel. L1. bench fidelity (960x540), 1 -> 2 on its 21 directional
#: cases: geometric mean of the error ratios 0.992, every own-light and sun-beside case lower (0.3-2.3 %), four
#: sun-behind cases up to 1.2 % higher (absolute errors 0.04-0.05 %); under the two spot lights, whose shafts are a
#: few pixels wide, the fence rose 1.6 % and the textured spot 0.4 %: spot and point lights keep every pixel (auto).
EPIPOLAR_UPSAMPLE_STRIDE = 2
#: Step pattern (``jitter``) of the raymarch method by default: per_pixel, whose estimate is unbiased pixel by pixel
#: (the reference marcher converges to the integral at every pixel; its noise decorrelates between pixels).
RAYMARCH_JITTER = "per_pixel"
#: ... and of the marching other methods do on a few rays, epipolar's ray-marched samples and the prefiltered methods'
#: epipole disc: fixed, Engelhardt 2010 Sec. 5.3's fixed step. Their rays are interpolated between (epipolar) or sit
#: beside prefiltered pixels (the disc), where per-ray noise shows as streaks along the lines and grain in the disc,
#: while the fixed pattern's error moves smoothly between neighbouring rays. Measured at 960x540 against the exact
#: reference (rel. L1, per_pixel -> fixed): epipolar lower on all 16 bench fidelity cases (colonnade 2.09 -> 2.07 %,
#: window room 0.70 -> 0.65 %, the dark room 0.30 -> 0.23 %, gate 2.53 -> 2.39 %, spot fence 0.77 -> 0.74 %), and no
#: randf per step (1080p canopy raymarch stage 421 -> 325 ms); fourier's disc lower or equal on all 14 (colonnade
#: 2.77 -> 2.74 %, terrain 1.21 -> 1.17 %, 60 %-opaque gate 1.96 -> 1.92 %). Looked at 1:1 at 1920x1080: no bands.
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
        """Per-ray segments a look-up uses, at most with adaptive segments (``segments``; null:
        :data:`FOURIER_SEGMENTS` for fourier, :data:`BEHIND_SEGMENTS` for the moment methods with the light behind
        the camera (``light_behind``, grey media), else :data:`SEGMENTS`, :data:`COLOURED_SEGMENTS` in a coloured
        medium, where they apply). They need transmittance weighting, whole rows (splits 1) and the non-linear
        rectification's uniform columns."""
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
        """Whether look-ups on the non-linear map weight each view ray's texels by its own transmittance (per-ray
        segments): transmittance weighting over whole rows (splits 1) and ``segments`` not 1. The projective map
        cannot (its columns are uneven): ``rectification: auto`` then takes the non-linear map."""
        return self.weighting == "transmittance" and self.splits == 1 and self.segments != 1

    def end_offsets_for(self, light_behind: bool, directional: bool = True) -> tuple[float, float]:
        """Texels a look-up ends before its ray's end point: (rays ending in shadow, rays ending lit:
        :func:`~.prefiltered.lit_ray_ends`). ``end_offset`` for both; null: :data:`END_OFFSET`, and
        :data:`END_OFFSET_LIT` for the rays ending lit under a directional light ahead of the camera (not
        ``light_behind``)."""
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
        """(most segments, optical depth per segment) of a method's adaptive segments by default: fourier's always,
        the moment methods' with the light behind the camera in a grey medium (a coloured one keeps its fixed
        :data:`COLOURED_SEGMENTS`); None: fixed segments."""
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
        """The reference ray used: ``reference_ray``, or for auto the least optical step with per-ray segments (their
        weights are then convex) and the median pixel ray without."""
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
        """The overestimation weight a look-up uses as (beta towards the light, beta along it): beta = b0 + (b1 - b0)
        clamp((omega_l . omega_p - c) / (1 - c), 0, 1), c = ``overestimation_rise_cos``; a fixed ``overestimation``
        gives b0 = b1; adaptive (-1, -1)."""
        if self.overestimation == "adaptive":
            return -1.0, -1.0
        if self.overestimation is None:
            return OVERESTIMATION, OVERESTIMATION_ALONG_LIGHT
        return float(self.overestimation), float(self.overestimation)

    def spot_beta(self, num_moments: int) -> float:
        """The overestimation weight of every view ray under a spot light (whose direction varies along the ray): a
        fixed ``overestimation``, else :data:`SPOT_OVERESTIMATION_MOMENTS4` for four moments and
        :data:`OVERESTIMATION` for six; -1 for adaptive (which needs a directional light)."""
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

    # ---- derived values the prefiltered methods read ----

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
        """Whether caster culling runs: ``prefiltered.caster_culling``, with ``auto`` = the moment methods only (it
        lowers their error a lot where rays end on lit surfaces and moves fourier's slightly either way)."""
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
