"""Settings of ``render.scattering.shadow_map`` (:class:`ShadowMapSettings`) and ``render.shadows``
(:class:`ShadowsSettings`, Peters et al. 2017 Sec. 2-4): keys, defaults, ranges and meanings (Warp-free).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal, Optional, Union

from pydantic import Field, field_validator, model_validator

from ..schema import MAX_COORD, MAX_IMAGE_SIDE, MIN_LENGTH, Bool, Float, Int, SettingsModel

#: Surface shadow methods (``render.shadows.method``).
SHADOW_METHODS = ("pcf", "msm", "msm_soft", "pcss", "msm2015", "vsm", "evsm", "none")
#: Bits per texel of each filterable method (a Warp-free copy of :data:`.filterable.BITS_OF_METHOD`).
FILTERABLE_BITS = {"msm": (64, 128), "msm2015": (64, 128), "vsm": (32, 64), "evsm": (64, 128)}
#: Largest EVSM exponent per storage: exp(2c) must fit float16 (64 bits) or float32 (128 bits).
EVSM_MAX_EXPONENT = {64: 5.545, 128: 44.3}
#: Moment-map look-ups of ``msm`` (``render.shadows.sampling``).
SHADOW_SAMPLING = ("bilinear", "mipmap")
#: Smallest shadow-map side (texels).
MIN_SHADOW_MAP_SIDE = 16
#: Widest PCF box / MSM Gaussian (texels).
MAX_FILTER_PX = 64
#: Most depth samples per texel and axis of a moment shadow map.
MAX_SUPERSAMPLING = 8
#: Most translucent layers peeled into a moment shadow map.
MAX_TRANSLUCENT_LAYERS = 64
#: Soft shadows: the reference region side n (n_t = n^2 texels of the summed-area table; Peters 2017 D.4 uses 28).
REFERENCE_KERNEL_PX = 28
#: Soft shadows: smallest and largest region side (texels).
MIN_KERNEL_PX = 4
MAX_KERNEL_PX = 256
#: Largest shadow-map depth bias (texel sizes).
MAX_BIAS_TEXELS = 1000.0
#: Soft shadows, directional light: smallest angular size (degrees; the sun's is 0.53).
MIN_LIGHT_ANGLE_DEG = 1.0e-3

_MapSide = Annotated[int, Field(ge=MIN_SHADOW_MAP_SIDE, le=MAX_IMAGE_SIDE)]
_EVSMExponent = Annotated[Float, Field(gt=0.0, le=max(EVSM_MAX_EXPONENT.values()))]


class ShadowMapSettings(SettingsModel):
    """The light's shadow map: ``resolution`` texels and a depth ``bias`` in texel sizes (a point is lit when its
    light-space depth is at most the stored caster depth plus ``bias`` times the world size of one texel)."""

    resolution: Union[_MapSide, tuple[_MapSide, _MapSide]] = Field(
        1024, description=f"side of the light's shadow map in texels, or [width, height] (each "
                          f"{MIN_SHADOW_MAP_SIDE} to {MAX_IMAGE_SIDE}); for the prefiltered methods also the rectified "
                          f"map (columns x rows)")
    bias: Annotated[Float, Field(ge=0.0, le=MAX_BIAS_TEXELS, description="depth bias in texel sizes (world units = "
                                                                         "bias x texel size)")] = 1.0
    skip_unseen_planes: Bool = Field(True, description=(
        "leave planar casters that shadow nothing the camera sees (the camera and every view ray's end on the side "
        "the light comes from: a ground plane under everything seen) out of the light's maps, so that a "
        "directional map fits the casters that matter; the exact-visibility BVH keeps them (warpscatter's)"))

    @field_validator("resolution", mode="before")
    @classmethod
    def _check_resolution(cls, v: Any) -> Any:
        sides = v if isinstance(v, (list, tuple)) else [v]
        if len(sides) not in (1, 2) or not all(isinstance(s, int) and not isinstance(s, bool) for s in sides):
            raise ValueError(f"expected an integer or [width, height], got {v!r}")
        if not all(MIN_SHADOW_MAP_SIDE <= s <= MAX_IMAGE_SIDE for s in sides):
            raise ValueError(f"each side must lie in [{MIN_SHADOW_MAP_SIDE}, {MAX_IMAGE_SIDE}], got {v!r}")
        return tuple(sides) if isinstance(v, (list, tuple)) else v

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in texels."""
        r = self.resolution
        return (r, r) if isinstance(r, int) else tuple(r)


class ShadowsSettings(SettingsModel):
    """Surface shadows (``render.shadows``): the method and its parameters (Peters et al. 2017 Sec. 2-4)."""

    method: Literal[SHADOW_METHODS] = Field(  # type: ignore[valid-type]
        "pcf", description="pcf (percentage-closer filtering), msm (4-moment shadow maps, translucent occluders), "
                           "msm_soft (moment soft shadows), pcss (their brute-force reference), the filterable "
                           "baselines msm2015 (Peters and Klein 2015: depth in [0, 1], their quantization), vsm "
                           "(variance), evsm (exponential variance), or none")
    filter_px: Annotated[Int, Field(ge=1, le=MAX_FILTER_PX,
                                    description="PCF box / MSM Gaussian width (shadow-map texels)")] = 3
    storage: Literal[32, 64, 128] = Field(
        64, description="bits per texel of the filterable maps: msm and msm2015 64 (16-bit fixed point) or 128 "
                        "(float32); vsm 32 (2 x float16) or 64 (2 x float32); evsm 64 (4 x float16) or 128 (4 x "
                        "float32); msm_soft always uses 128")
    evsm_exponents: Optional[tuple[_EVSMExponent, _EVSMExponent]] = Field(
        None, description="evsm: exponents [c+, c-] (> 0; 64 bits: <= 5.545); null: Peters 2017 Fig. 4's, [5.54, "
                          "5.54] at 64 bits and [40, 5.54] at 128")
    supersampling: Annotated[Int, Field(ge=1, le=MAX_SUPERSAMPLING,
                                        description="depth samples per texel and axis of the moment map")] = 2
    coloured: Bool = Field(False, description="one moment map per RGB channel (tinted translucent occluders)")
    max_translucent_layers: Annotated[Int, Field(ge=1, le=MAX_TRANSLUCENT_LAYERS,
                                                 description="translucent layers peeled into the moment map")] = 16
    light_angle_deg: Annotated[Float, Field(ge=MIN_LIGHT_ANGLE_DEG, lt=180.0, description=(
        "soft methods, directional light: its angular size (full angle, degrees)"))] = 1.0
    light_size: Annotated[Float, Field(ge=MIN_LENGTH, le=MAX_COORD, description="soft methods, spot light: its size "
                                                                                "(scene units)")] = 0.5
    max_kernel_px: Annotated[Int, Field(ge=MIN_KERNEL_PX, le=MAX_KERNEL_PX,
                                        description="soft methods: widest region side (texels; n_t = side^2)")] = (
        REFERENCE_KERNEL_PX)
    sampling: Literal[SHADOW_SAMPLING] = Field(  # type: ignore[valid-type]
        "bilinear", description="msm look-ups: bilinear (level 0) or mipmap (trilinear in the moment map's mip chain "
                                "at the level of each pixel's footprint, Peters 2017 D.2)")

    @model_validator(mode="after")
    def _storage_fits_method(self) -> ShadowsSettings:
        offered = FILTERABLE_BITS.get(self.method)
        if offered is not None and self.storage not in offered:
            raise ValueError(f"storage: {self.method} stores {' or '.join(map(str, offered))} bits per texel, not "
                             f"{self.storage}")
        if self.evsm_exponents is not None:
            if self.method != "evsm":
                raise ValueError(f"evsm_exponents: used by method evsm only (method is {self.method!r})")
            limit = EVSM_MAX_EXPONENT[self.storage]
            if not all(0.0 < c <= limit for c in self.evsm_exponents):
                raise ValueError(f"evsm_exponents: each must lie in (0, {limit}] at {self.storage} bits (exp(2c) must "
                                 f"fit the channel), got {list(self.evsm_exponents)}")
        return self


__all__ = [
    "EVSM_MAX_EXPONENT",
    "FILTERABLE_BITS",
    "MAX_BIAS_TEXELS",
    "MAX_FILTER_PX",
    "MAX_KERNEL_PX",
    "MAX_SUPERSAMPLING",
    "MAX_TRANSLUCENT_LAYERS",
    "MIN_KERNEL_PX",
    "MIN_LIGHT_ANGLE_DEG",
    "MIN_SHADOW_MAP_SIDE",
    "REFERENCE_KERNEL_PX",
    "SHADOW_METHODS",
    "SHADOW_SAMPLING",
    "ShadowMapSettings",
    "ShadowsSettings",
]
