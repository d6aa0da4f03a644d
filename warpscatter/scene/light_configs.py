"""The ``light`` section: one settings model per light type, each beside the host light it builds.

Every model parses and checks its keys (pydantic, Warp-free), says what it is in one line
(:meth:`LightSettings.describe`) and builds its host light (:meth:`LightSettings.build`, which imports Warp);
:data:`LightConfig` is the union of :data:`LIGHT_CONFIGS` on ``type``.

Adding a light type: its model here (keys, checks, ``describe``, ``build``) and in :data:`LIGHT_CONFIGS`, its host
class in :mod:`.lights`, its type in the light lists of :mod:`warpscatter.methods`, and its estimator.
"""

from __future__ import annotations

import math
import typing
from abc import abstractmethod
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, Optional, Union

from pydantic import Field, ValidationInfo, field_validator, model_validator

from ..errors import ConfigError
from ..schema import (
    MAX_EMISSION,
    MIN_CONE_DEG,
    MIN_LENGTH,
    RGB,
    Bool,
    Direction,
    Float,
    NonZeroVec3,
    PathStr,
    SettingsModel,
    Vec3,
    existing_file,
    length,
    resolve_path,
)

#: The RGB of a light given neither its emission nor its power.
_WHITE = (1.0, 1.0, 1.0)


def format_value(v: Any) -> str:
    """A config value as the summaries print it: floats with 6 significant digits, lists as ``[a, b, c]``."""
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(format_value(x) for x in v) + "]"
    return str(v)


#: The most pixels a light texture or environment map may have: 2^25, an 8192 x 4096 lat-long map. Reading one and
#: building its sampling tables peaks near 90 (environment map) to 110 (area light) bytes a pixel, measured (float32
#: pixels decoded, float64 luminance, weights and CDFs), some 4 GB at this bound before the device copies (~30 bytes a
#: pixel); the header is checked before any pixel is decoded.
MAX_LIGHT_IMAGE_PIXELS = 2**25
#: The longest side (pixels) of a light texture or environment map.
MAX_LIGHT_IMAGE_SIDE = 16384
#: The most channels such an image may have (each is decoded as float32 before the colour channels are kept).
MAX_LIGHT_IMAGE_CHANNELS = 16
#: The largest value a light texture or environment map file may hold: the bound of every emission value of a config
#: (:data:`~warpscatter.schema.MAX_EMISSION`), so that a texel times its light's intensity, radiance or scale stays at
#: most 1e12, far inside float32's 3.4e38 through the renderers' products.
MAX_LIGHT_IMAGE_VALUE = MAX_EMISSION


def check_light_image_size(path: str | Path) -> None:
    """Refuse a light texture or environment map too large to read, from its header alone (nothing is decoded):
    more than :data:`MAX_LIGHT_IMAGE_PIXELS` pixels, a side over :data:`MAX_LIGHT_IMAGE_SIDE`, more than
    :data:`MAX_LIGHT_IMAGE_CHANNELS` channels, or a 3-D (volume) image. A file OpenImageIO cannot open passes (the
    read reports it).

    Raises:
        ValueError: naming the file, its size and the limit.
    """
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()  # clear it: the read reports why
        return
    try:
        spec = inp.spec()
        w, h, d, c = int(spec.width), int(spec.height), max(int(spec.depth), 1), int(spec.nchannels)
    finally:
        inp.close()
    if d > 1:
        raise ValueError(f"{path}: a 3-D image ({w} x {h} x {d} pixels); a light image must be 2-D")
    if w > MAX_LIGHT_IMAGE_SIDE or h > MAX_LIGHT_IMAGE_SIDE or w * h > MAX_LIGHT_IMAGE_PIXELS:
        raise ValueError(f"{path}: the image is {w} x {h} pixels ({w * h:,}), more than a light texture or "
                         f"environment map may have (at most {MAX_LIGHT_IMAGE_PIXELS:,} pixels and "
                         f"{MAX_LIGHT_IMAGE_SIDE} a side, e.g. 8192 x 4096: its tables take ~110 bytes a pixel)")
    if c > MAX_LIGHT_IMAGE_CHANNELS:
        raise ValueError(f"{path}: the image has {c} channels, more than the {MAX_LIGHT_IMAGE_CHANNELS} a light "
                         "image may have")


def read_light_image(path: str | Path, key: str) -> Any:
    """The radiance image (H, W, 3) float32 of a light's ``texture`` or ``map`` file, refused before decoding when
    too large (:func:`check_light_image_size`) and after when a value is not finite, negative or above
    :data:`MAX_LIGHT_IMAGE_VALUE`.

    Raises:
        InputFileError: at ``key``, naming the file and the reason.
    """
    import numpy as np

    from ..errors import InputFileError
    from ..io.images import read_radiance_image

    try:
        check_light_image_size(path)
    except ValueError as exc:
        raise InputFileError(str(exc), path=path, key=key) from None
    image = read_radiance_image(path, key=key)
    over = image > MAX_LIGHT_IMAGE_VALUE
    if over.any():
        r, c, ch = np.unravel_index(int(np.argmax(image)), image.shape)
        largest = float(image[r, c, ch])
        raise InputFileError(
            f"{path}: {int(over.sum())} value(s) above {MAX_LIGHT_IMAGE_VALUE:g}, the largest {largest:g} at row {r}, "
            f"column {c}, channel {ch}; a light image's values must be finite, >= 0 and at most "
            f"{MAX_LIGHT_IMAGE_VALUE:g} (warpscatter.schema.MAX_EMISSION: scale the light's intensity, radiance or "
            "scale instead)", path=path, key=key)
    return image


def _light_image_file(v: Path | None, info: ValidationInfo) -> Path | None:
    """A ``texture`` or ``map`` key's file: existing, and not too large by its header
    (:func:`check_light_image_size`)."""
    if v is None:
        return None
    p = existing_file(resolve_path(v, info))
    check_light_image_size(p)
    return p


def _texture(path: Path | None) -> Any:
    """The image of a light's ``texture`` key, or None (:func:`read_light_image`)."""
    if path is None:
        return None
    return read_light_image(path, key="light.texture")


class LightSettings(SettingsModel):
    """Base of the light models: what every light type can say and build."""

    #: Keys of the section that another key replaces when an override sets it (see :meth:`keys_replaced_by`).
    ALTERNATIVE_KEYS: ClassVar[tuple[tuple[str, ...], ...]] = ()

    @abstractmethod
    def describe(self) -> str:
        """One line: the light type and its settings (``warpscatter validate``)."""

    @abstractmethod
    def build(self) -> Any:
        """The host light of :mod:`warpscatter.scene.lights` (textures and maps read from their files).

        Raises:
            InputFileError: a texture or map that cannot be read or holds values that are not radiance.
            ConfigError: an image the light cannot use.
        """

    @classmethod
    def keys_replaced_by(cls, key: str) -> tuple[str, ...]:
        """The keys an override of ``key`` removes from the section: the other ways of giving the same thing
        (:data:`ALTERNATIVE_KEYS`), so that ``--set light.azimuth_deg=40`` on a light given by its direction does not
        fail with two orientations."""
        if not any(key in keys for keys in cls.ALTERNATIVE_KEYS):
            return ()
        return tuple(k for keys in cls.ALTERNATIVE_KEYS if key not in keys for k in keys)


#: The ways a directional light's orientation may be given; exactly one per light (see DirectionalLightConfig).
SUN_FORMS = ("direction", "toward_sun", "azimuth_deg + elevation_deg")


def sun_direction(azimuth_deg: float, elevation_deg: float) -> tuple[float, float, float]:
    """Unit vector from the scene TOWARD the sun: ``elevation_deg`` above the horizon (the XZ plane), ``azimuth_deg``
    about +Y, 0 toward +Z and 90 toward +X."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return (math.sin(az) * math.cos(el), math.sin(el), math.cos(az) * math.cos(el))


class DirectionalLightConfig(LightSettings):
    """Directional light (a sun) with RGB ``irradiance``, oriented by exactly one of: ``direction`` (the way the
    light TRAVELS, CONVENTIONS.md), ``toward_sun`` (from the scene toward the sun, i.e. -direction), or
    ``azimuth_deg`` with ``elevation_deg`` (the sun's position in the sky). Every form becomes ``direction`` on load
    (unit), which is what the resolved config and the renderers hold."""

    ALTERNATIVE_KEYS: ClassVar = (("direction",), ("toward_sun",), ("azimuth_deg", "elevation_deg"))

    type: Literal["directional"] = Field(description="directional")
    direction: Optional[Direction] = Field(None, description="direction the light TRAVELS, from the sun into the "
                                           "scene (normalised on load); or give toward_sun, or azimuth_deg and "
                                           "elevation_deg")
    toward_sun: Optional[Direction] = Field(None, description="direction from the scene toward the sun (= -direction;"
                                            " replaced by direction on load)")
    azimuth_deg: Optional[Annotated[Float, Field(ge=-360.0, le=360.0)]] = Field(
        None, description="the sun's azimuth (degrees) about +Y: 0 toward +Z, 90 toward +X; with elevation_deg "
                          "(replaced by direction on load)")
    elevation_deg: Optional[Annotated[Float, Field(ge=-90.0, le=90.0)]] = Field(
        None, description="the sun's elevation above the horizon (the XZ plane, degrees); negative: below it, "
                          "lighting from underneath")
    irradiance: RGB = Field((1.0, 1.0, 1.0), description="RGB irradiance on a plane facing the light")

    @model_validator(mode="after")
    def _one_orientation(self) -> DirectionalLightConfig:
        given = [name for name, set_ in (("direction", self.direction is not None),
                                         ("toward_sun", self.toward_sun is not None),
                                         ("azimuth_deg + elevation_deg",
                                          self.azimuth_deg is not None or self.elevation_deg is not None)) if set_]
        if len(given) != 1:
            raise ValueError(f"give exactly one of {', '.join(SUN_FORMS)} (got "
                             f"{' and '.join(given) if given else 'none'})")
        if given[0] == "azimuth_deg + elevation_deg":
            if self.azimuth_deg is None or self.elevation_deg is None:
                missing = "azimuth_deg" if self.azimuth_deg is None else "elevation_deg"
                raise ValueError(f"{missing} is missing: the sun's position needs azimuth_deg and elevation_deg")
            self.direction = tuple(0.0 - c for c in sun_direction(self.azimuth_deg, self.elevation_deg))
        elif given[0] == "toward_sun":
            self.direction = tuple(0.0 - c for c in self.toward_sun)
        self.toward_sun = self.azimuth_deg = self.elevation_deg = None
        return self

    def describe(self) -> str:
        return f"directional, direction {format_value(self.direction)}, irradiance {format_value(self.irradiance)}"

    def build(self) -> Any:
        from .lights import DirectionalLight

        return DirectionalLight(direction=self.direction, irradiance=self.irradiance)


class SpotLightConfig(LightSettings):
    """Spot light at ``position`` with axis ``direction`` (unit), cone HALF-angle ``cone_deg``, intensity W/sr.

    ``texture`` (optional image file) modulates the emitted radiance over the cone.
    """

    type: Literal["spot"] = Field(description="spot")
    position: Vec3 = Field(description="light position (scene units)")
    direction: Direction = Field(description="cone axis (normalised on load)")
    cone_deg: Annotated[Float, Field(ge=MIN_CONE_DEG, le=89.0, description="cone HALF-angle (degrees)")] = 30.0
    intensity: RGB = Field((1.0, 1.0, 1.0), description="RGB intensity (W/sr); irradiance falls off as 1/d^2")
    texture: PathStr | None = Field(None, description="an image modulating the light over the cone's square")

    @field_validator("texture")
    @classmethod
    def _check_texture(cls, v: Path | None, info: ValidationInfo) -> Path | None:
        return _light_image_file(v, info)

    def describe(self) -> str:
        return (f"spot at {format_value(self.position)}, direction {format_value(self.direction)}, "
                f"cone {self.cone_deg:g} deg, intensity {format_value(self.intensity)}"
                + (f", texture {self.texture}" if self.texture else ""))

    def build(self) -> Any:
        from .lights import SpotLight

        return SpotLight(position=self.position, direction=self.direction, cone_deg=self.cone_deg,
                         intensity=self.intensity, texture=_texture(self.texture))


class PointLightConfig(LightSettings):
    """Point light at ``position`` shining ``intensity`` W/sr in every direction (rendered as six 90-degree spots,
    one per cube face, each with its own shadow map)."""

    type: Literal["point"] = Field(description="point")
    position: Vec3 = Field(description="light position (scene units)")
    intensity: RGB = Field((1.0, 1.0, 1.0), description="RGB intensity (W/sr); irradiance falls off as 1/d^2")

    def describe(self) -> str:
        return (f"point at {format_value(self.position)}, intensity {format_value(self.intensity)} (six cube-face "
                "spots)")

    def build(self) -> Any:
        from .lights import PointLight

        return PointLight(position=self.position, intensity=self.intensity)


class EnvironmentLightConfig(LightSettings):
    """Distant lat-long environment map (``map``: an image file, row 0 = zenith, see assets/README.md) whose texels
    are radiance, times ``scale``; lighting methods only."""

    type: Literal["environment"] = Field(description="environment")
    map: PathStr = Field(description="a lat-long radiance image (row 0 = zenith)")
    scale: Annotated[Float, Field(ge=0.0, le=MAX_EMISSION, description="factor on the map's radiance")] = 1.0

    @field_validator("map")
    @classmethod
    def _check_map(cls, v: Path, info: ValidationInfo) -> Path:
        return _light_image_file(v, info)

    def describe(self) -> str:
        return f"environment map {self.map}, scale {self.scale:g}"

    def build(self) -> Any:
        import numpy as np

        from .environment_map import EnvironmentMap
        from .lights import EnvironmentLight

        image = read_light_image(self.map, key="light.map")
        try:
            return EnvironmentLight(EnvironmentMap(image * np.float32(self.scale)))
        except ValueError as exc:
            raise ConfigError(f"light.map: {self.map}: {exc}") from None


class AreaLightConfig(LightSettings):
    """Parallelogram light ``position`` + s ``u`` + t ``v`` (s, t in [0, 1]) emitting constant ``radiance`` (or its
    ``power`` in W) from the side u x v points to, or both sides (``two_sided``); lighting methods only."""

    type: Literal["area"] = Field(description="area")
    position: Vec3 = Field(description="the corner y(0, 0) of the parallelogram (scene units)")
    u: NonZeroVec3 = Field(description="first edge vector")
    v: NonZeroVec3 = Field(description="second edge vector (not parallel to u); the light emits towards u x v")
    radiance: Optional[RGB] = Field(None, description="RGB radiance L_e (null and no power: [1, 1, 1])")
    power: Optional[RGB] = Field(None, description="RGB power (W) instead of the radiance (the radiance it gives, P / "
                                                   f"(pi A), must be <= {MAX_EMISSION:g} too)")
    two_sided: Bool = Field(False, description="emit from both sides")
    texture: PathStr | None = Field(None, description="an image modulating the radiance over the parallelogram "
                                                      "(row 0 = the edge at v, columns along u; with power: "
                                                      "divided by its mean)")

    @field_validator("texture")
    @classmethod
    def _check_texture(cls, v: Path | None, info: ValidationInfo) -> Path | None:
        return _light_image_file(v, info)

    @model_validator(mode="after")
    def _check(self) -> AreaLightConfig:
        cross = (self.u[1] * self.v[2] - self.u[2] * self.v[1], self.u[2] * self.v[0] - self.u[0] * self.v[2],
                 self.u[0] * self.v[1] - self.u[1] * self.v[0])
        nu, nv, area = length(self.u), length(self.v), length(cross)
        # the second test is the scene's (warpscatter.scene.lights.AreaLight): a sliver counts as no area either
        if area <= 1e-9 * nu * nv or area <= 1e-12 * max(nu, nv) ** 2:
            raise ValueError(f"u {list(self.u)} and v {list(self.v)} are parallel (the light has no area)")
        if self.radiance is not None and self.power is not None:
            raise ValueError("give radiance or power, not both")
        if self.power is not None:
            radiance = max(self.power) / ((2.0 if self.two_sided else 1.0) * math.pi * area)
            if radiance > MAX_EMISSION:
                raise ValueError(f"power: gives the radiance P / ({'2 ' if self.two_sided else ''}pi A) = "
                                 f"{radiance:g}, more than {MAX_EMISSION:g} (a larger light or less power)")
        return self

    def describe(self) -> str:
        emit = f"power {format_value(self.power)}" if self.power is not None else \
            f"radiance {format_value(self.radiance or _WHITE)}"
        return (f"area at {format_value(self.position)}, edges {format_value(self.u)} x {format_value(self.v)}, "
                f"{emit}" + (", two-sided" if self.two_sided else "")
                + (f", texture {self.texture}" if self.texture else ""))

    def build(self) -> Any:
        from .lights import AreaLight

        texture = _texture(self.texture)
        try:
            if self.power is not None:
                return AreaLight.from_power(self.position, self.u, self.v, self.power, self.two_sided, texture)
            return AreaLight(self.position, self.u, self.v, self.radiance if self.radiance is not None else _WHITE,
                             self.two_sided, texture)
        except ValueError as exc:
            raise ConfigError(f"light.texture: {self.texture}: {exc}") from None


class LinearLightConfig(LightSettings):
    """Segment light from ``start`` to ``end``, isotropic, ``intensity`` RGB per unit length (W sr^-1 unit^-1);
    lighting methods only."""

    type: Literal["linear"] = Field(description="linear")
    start: Vec3 = Field(description="segment start (scene units)")
    end: Vec3 = Field(description=f"segment end (at least {MIN_LENGTH:g} from start)")
    intensity: RGB = Field((1.0, 1.0, 1.0), description="RGB intensity per unit length (W sr^-1 unit^-1)")

    @model_validator(mode="after")
    def _check(self) -> LinearLightConfig:
        if self.start == self.end:
            raise ValueError(f"start and end must differ (both {list(self.start)})")
        d = length([b - a for a, b in zip(self.start, self.end, strict=True)])
        if d < MIN_LENGTH:
            raise ValueError(f"start and end must be at least {MIN_LENGTH:g} apart (they are {d:g})")
        return self

    def describe(self) -> str:
        return (f"linear {format_value(self.start)} -> {format_value(self.end)}, intensity "
                f"{format_value(self.intensity)} per unit length")

    def build(self) -> Any:
        from .lights import LinearLight

        return LinearLight(self.start, self.end, self.intensity)


class VolumeLightConfig(LightSettings):
    """Parallelepiped light ``position`` + s ``u`` + t ``v`` + r ``w`` (s, t, r in [0, 1]), an isotropic emitter of
    ``intensity`` RGB per unit volume (W sr^-1 unit^-3) or of ``power`` W (Ritschel 2007's volumetric lights);
    lighting methods only, its visibility semi-local or ray-cast."""

    type: Literal["volume"] = Field(description="volume")
    position: Vec3 = Field(description="the corner y(0, 0, 0) (scene units)")
    u: NonZeroVec3 = Field(description="first edge vector")
    v: NonZeroVec3 = Field(description="second edge vector")
    w: NonZeroVec3 = Field(description="third edge vector (u, v, w not coplanar)")
    intensity: Optional[RGB] = Field(None, description="RGB intensity per unit volume (null and no power: [1, 1, 1])")
    power: Optional[RGB] = Field(None, description="RGB power (W) instead: intensity = P / (4 pi V), at most "
                                                   f"{MAX_EMISSION:g}")

    @model_validator(mode="after")
    def _check(self) -> VolumeLightConfig:
        u, v, w = self.u, self.v, self.w
        vol = abs(u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
                  + u[2] * (v[0] * w[1] - v[1] * w[0]))
        if vol <= 1e-9 * length(u) * length(v) * length(w):
            raise ValueError(f"u {list(u)}, v {list(v)} and w {list(w)} are coplanar (the light has no volume)")
        if self.intensity is not None and self.power is not None:
            raise ValueError("give intensity or power, not both")
        if self.power is not None and max(self.power) / (4.0 * math.pi * vol) > MAX_EMISSION:
            raise ValueError(f"power: gives the intensity P / (4 pi V) = {max(self.power) / (4.0 * math.pi * vol):g}, "
                             f"more than {MAX_EMISSION:g}")
        return self

    def describe(self) -> str:
        emit = (f"power {format_value(self.power)}" if self.power is not None else
                f"intensity {format_value(self.intensity or _WHITE)} per unit volume")
        return (f"volume at {format_value(self.position)}, edges {format_value(self.u)} x {format_value(self.v)} x "
                f"{format_value(self.w)}, {emit}")

    def build(self) -> Any:
        from .lights import VolumeLight

        if self.power is not None:
            return VolumeLight.from_power(self.position, self.u, self.v, self.w, self.power)
        return VolumeLight(self.position, self.u, self.v, self.w,
                           self.intensity if self.intensity is not None else _WHITE)


#: Every light type's model, in the order the docs list them.
LIGHT_CONFIGS: tuple[type[LightSettings], ...] = (
    DirectionalLightConfig, SpotLightConfig, PointLightConfig, EnvironmentLightConfig, AreaLightConfig,
    LinearLightConfig, VolumeLightConfig)
#: ``light.type`` -> its model.
LIGHT_TYPES: dict[str, type[LightSettings]] = {typing.get_args(m.model_fields["type"].annotation)[0]: m
                                               for m in LIGHT_CONFIGS}

#: The ``light`` section: one of :data:`LIGHT_CONFIGS`, chosen by ``type``.
LightConfig = Annotated[Union[LIGHT_CONFIGS], Field(discriminator="type")]  # type: ignore[valid-type]

__all__ = [
    "LIGHT_CONFIGS",
    "LIGHT_TYPES",
    "MAX_LIGHT_IMAGE_CHANNELS",
    "MAX_LIGHT_IMAGE_PIXELS",
    "MAX_LIGHT_IMAGE_SIDE",
    "MAX_LIGHT_IMAGE_VALUE",
    "SUN_FORMS",
    "AreaLightConfig",
    "DirectionalLightConfig",
    "EnvironmentLightConfig",
    "LightConfig",
    "LightSettings",
    "LinearLightConfig",
    "PointLightConfig",
    "SpotLightConfig",
    "VolumeLightConfig",
    "check_light_image_size",
    "format_value",
    "read_light_image",
    "sun_direction",
]
