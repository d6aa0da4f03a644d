"""Animated configs: keyframed tracks over config keys, a frame range and rate; the config of each frame (an example
``animation`` section: docs/guide/runs.md).

Each track animates one config key (a dotted path, as ``--set`` takes it) with keyframes ``frame: value``. Numbers and
lists interpolate per component (directions are normalised on validation); integer keys round to integers; strings
and booleans hold the last key's value. Outside the keys a track holds its end value. Each frame's config is
validated like a loaded one. No Warp import.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal, Union

from pydantic import BeforeValidator, Field, field_validator, model_validator

from ..schema import MAX_FRAME, MAX_FRAMES, Int, SettingsModel, is_number

#: Interpolation between keyframes: ``linear``, or ``smooth`` (smoothstep: zero velocity at the keys).
INTERPOLATIONS = ("linear", "smooth")
#: Preview formats of a rendered sequence (``auto``: mp4 with imageio-ffmpeg, else gif with imageio, else none).
PREVIEWS = ("auto", "mp4", "gif", "none")
#: Frame numbers are written with this many digits at least (``NAME.0001.exr``).
FRAME_DIGITS = 4


class Track(SettingsModel):
    """One animated key: its keyframes (frame -> value) and interpolation (None: the animation's default)."""

    keys: dict[Annotated[int, Field(ge=-MAX_FRAME, le=MAX_FRAME)], Any] = Field(
        description=f"keyframes, frame number (within [-{MAX_FRAME}, {MAX_FRAME}]) -> value (at least one)")
    interpolation: Literal[INTERPOLATIONS] | None = Field(  # type: ignore[valid-type]
        None, description="linear or smooth; default: animation.interpolation")

    @field_validator("keys")
    @classmethod
    def _same_shape(cls, v: dict[int, Any]) -> dict[int, Any]:
        if not v:
            raise ValueError("needs at least one keyframe")
        shapes = {_shape(x) for x in v.values()}
        if len(shapes) > 1:
            raise ValueError(f"keyframe values must all have the same type and length, got {sorted(map(str, shapes))}")
        return dict(sorted(v.items()))


def _shape(value: Any) -> str:
    if is_number(value):
        return "number"
    if isinstance(value, (list, tuple)) and value and all(is_number(x) for x in value):
        return f"list of {len(value)} numbers"
    return type(value).__name__


def _track(v: Any) -> Any:
    """A track given as its keys alone (``{1: a, 60: b}``) is the same as ``{keys: {1: a, 60: b}}``."""
    if isinstance(v, dict) and "keys" not in v:
        return {"keys": v}
    return v


_Frame = Annotated[Int, Field(ge=0, le=MAX_FRAME)]


def _check_frames(v: Any) -> Any:
    """``frames``: a count N in [1, MAX_FRAMES] or [start, end], each in [0, MAX_FRAME] (one message for either)."""
    whole = isinstance(v, int) and not isinstance(v, bool)
    if whole:
        if not 1 <= v <= MAX_FRAMES:
            raise ValueError(f"must lie in [1, {MAX_FRAMES}], got {v}")
    elif isinstance(v, (list, tuple)) and len(v) == 2 and all(isinstance(x, int) and not isinstance(x, bool)
                                                              for x in v):
        if not all(0 <= x <= MAX_FRAME for x in v):
            raise ValueError(f"each frame number must lie in [0, {MAX_FRAME}], got {list(v)}")
    else:
        raise ValueError(f"expected a frame count N or [start, end], got {v!r}")
    return v


_check_frames.type_text = f"int 1–{MAX_FRAMES} \\| [start, end], each 0–{MAX_FRAME}"


class AnimationSettings(SettingsModel):
    """``animation``: frame range, rate, tracks and the preview of a rendered sequence."""

    frames: Annotated[Annotated[int, Field(ge=1, le=MAX_FRAMES)] | tuple[_Frame, _Frame],
                      BeforeValidator(_check_frames)] = Field(
        description=f"frame count N (frames 1..N), or [start, end] inclusive (0 <= start <= end <= {MAX_FRAME}, at "
                    f"most {MAX_FRAMES} frames)")
    fps: Annotated[float, Field(ge=0.01, le=1000.0, description="frames per second (the preview's rate)")] = 24.0
    interpolation: Literal[INTERPOLATIONS] = Field(  # type: ignore[valid-type]
        "smooth", description="default interpolation of the tracks: linear, or smooth (ease in and out at every key)")
    tracks: dict[str, Union[Track, dict[Annotated[int, Field(ge=-MAX_FRAME, le=MAX_FRAME)], Any]]] = Field(
        default_factory=dict, description="animated config keys (dotted paths) -> keyframes")
    preview: Literal[PREVIEWS] = Field(  # type: ignore[valid-type]
        "auto", description="a preview of the frames: mp4 (imageio-ffmpeg), gif (imageio), none, or auto (the "
                            "first available)")

    @field_validator("tracks", mode="before")
    @classmethod
    def _shorthand(cls, v: Any) -> Any:
        return {k: _track(t) for k, t in v.items()} if isinstance(v, dict) else v

    @field_validator("tracks")
    @classmethod
    def _plain_keys(cls, v: dict[str, Track]) -> dict[str, Track]:
        for key in v:
            if not key or key.startswith("animation") or any(not p for p in key.split(".")):
                raise ValueError(f"{key!r}: not a config key to animate (a dotted path such as light.direction)")
        return v

    @model_validator(mode="after")
    def _range(self) -> AnimationSettings:
        start, end = self.frame_range
        if start < 0 or end < start:
            raise ValueError(f"frames: need 0 <= start <= end, got [{start}, {end}]")
        if end - start + 1 > MAX_FRAMES:
            raise ValueError(f"frames: at most {MAX_FRAMES} frames, got [{start}, {end}] ({end - start + 1})")
        return self

    @property
    def frame_range(self) -> tuple[int, int]:
        """(first, last) frame numbers, inclusive."""
        return (1, self.frames) if isinstance(self.frames, int) else (int(self.frames[0]), int(self.frames[1]))

    @property
    def frame_numbers(self) -> list[int]:
        """Every frame number, in order."""
        first, last = self.frame_range
        return list(range(first, last + 1))

    def values_at(self, frame: float, integer_keys: frozenset[str] = frozenset()) -> dict[str, Any]:
        """Every track's value at ``frame``: dotted key -> value (:func:`warpscatter.config.apply_overrides`)."""
        return {key: track_value(track, frame, track.interpolation or self.interpolation, key in integer_keys)
                for key, track in self.tracks.items()}


def _ease(t: float, interpolation: str) -> float:
    return t * t * (3.0 - 2.0 * t) if interpolation == "smooth" else t


def track_value(track: Track, frame: float, interpolation: str = "linear", integer: bool = False) -> Any:
    """A track's value at ``frame``, interpolated between the keys around it; with ``integer`` rounded."""
    frames = list(track.keys)
    values = list(track.keys.values())
    if frame <= frames[0]:
        return values[0]
    if frame >= frames[-1]:
        return values[-1]
    k = max(i for i, f in enumerate(frames) if f <= frame)
    a, b = values[k], values[k + 1]
    if _shape(a) == _shape(b) and (is_number(a) or isinstance(a, (list, tuple))) and _shape(a) != "list":
        t = _ease((frame - frames[k]) / (frames[k + 1] - frames[k]), interpolation)

        def mix(x, y):
            v = x + (y - x) * t
            return int(round(v)) if integer else float(v)

        return mix(a, b) if is_number(a) else [mix(x, y) for x, y in zip(a, b, strict=True)]
    return a


def frame_name(name: str, frame: int) -> str:
    """The output stem of one frame: ``NAME.0001`` (at least :data:`FRAME_DIGITS` digits)."""
    return f"{name}.{frame:0{FRAME_DIGITS}d}"


__all__ = ["FRAME_DIGITS", "INTERPOLATIONS", "PREVIEWS", "AnimationSettings", "Track", "frame_name", "track_value"]
