"""Image files through OpenImageIO: linear EXR, sRGB PNG previews, reading, and the render output set.

Conventions (CONVENTIONS.md, "Images"): arrays are ``(H, W)`` or ``(H, W, C)`` float32, row 0 is the top row.
EXRs hold linear float32 exactly; PNG previews are exposure-scaled, clamped and sRGB-encoded to 8 bits. Every write
is atomic (temporary file, fsync, :func:`os.replace`), a whole output set all or nothing; non-finite pixels are
refused. The temporaries, the lock per output name, the commit manifest and the clean-up are :mod:`.output_sets`'s
(its :class:`ImageWriteError`, :func:`remove_stale_temporaries`, :func:`temp_name`, :func:`write_file_atomic` and
:data:`AOV_CHANNELS` import from here too).
"""

from __future__ import annotations

import functools
import json
import os
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from .. import __version__
from ..errors import InputFileError
from .output_sets import (
    AOV_CHANNELS,
    ImageWriteError,
    _write_all,
    check_output_target,
    remove_stale_temporaries,
    temp_name,
    write_file_atomic,
)

__all__ = [
    "AOV_CHANNELS",
    "AOV_CHANNEL_NAMES",
    "OWN_SIZE_AOVS",
    "DEFAULT_EXR_COMPRESSION",
    "EXR_COMPRESSIONS",
    "ImageWriteError",
    "json_ready",
    "read_image",
    "read_radiance_image",
    "remove_stale_temporaries",
    "temp_name",
    "write_file_atomic",
    "srgb_decode",
    "srgb_encode",
    "write_exr",
    "write_outputs",
    "write_png",
]


#: Outputs with their own size (a texture, not the image): exempt from the same-size check.
OWN_SIZE_AOVS = ("rectified_map",)

#: The lossless EXR compressions (OpenImageIO names) of ``output.compression``. Timings: docs/design/csm-core.md.
EXR_COMPRESSIONS = ("none", "rle", "zips", "zip", "piz")
#: The least CPU per render.
DEFAULT_EXR_COMPRESSION = "none"

#: PNG (zlib) settings of the previews: fast over small (docs/design/csm-core.md).
_PNG_ATTRIBUTES = {"png:compressionLevel": 1, "png:filter": 0x10}

_CHANNEL_NAMES = {1: ("Y",), 2: ("Y", "A"), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}
#: Channel names that differ from the default by channel count (depth is OpenEXR's ``Z``).
AOV_CHANNEL_NAMES = {"depth": ("Z",), "rectified": ("u", "v", "z"), "rectified_map": ("depth", "culled")}
_INTEGER_BASETYPES = {oiio.UINT8, oiio.INT8, oiio.UINT16, oiio.INT16, oiio.UINT32, oiio.INT32}


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Linear light -> sRGB-encoded values (IEC 61966-2-1), both in [0, 1]; input is clamped to [0, 1]."""
    x = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)  # float64 so that 1 maps to exactly 1
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055).astype(np.float32)


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """sRGB-encoded values -> linear light (inverse of :func:`srgb_encode`); input is clamped to [0, 1]."""
    x = np.clip(np.asarray(encoded, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, np.power((x + 0.055) / 1.055, 2.4)).astype(np.float32)


def _srgb8_reference(linear: np.ndarray) -> np.ndarray:
    """8-bit preview codes round(255 * srgb_encode(clamp(v, 0, 1))) of float32 values, computed directly."""
    encoded = np.clip(srgb_encode(linear), 0.0, 1.0)
    return np.rint(encoded * np.float32(255.0)).astype(np.uint8)


_ONE_BITS = 0x3F800000  # float32 1.0
_BUCKET_SHIFT = 16  # 2^16 consecutive float32 values per table entry: less than the gap between two codes


@functools.cache
def _srgb8_tables() -> tuple[np.ndarray, np.ndarray] | None:
    """Tables giving :func:`_srgb8_reference` of every float32 in [0, 1] from its bit pattern ``b``:
    ``code = base[b >> 16] + (b >= step[b >> 16])``; None should a bucket hold more than one code step."""
    starts = np.arange((_ONE_BITS >> _BUCKET_SHIFT) + 1, dtype=np.int64) << _BUCKET_SHIFT
    ends = np.minimum(starts + (1 << _BUCKET_SHIFT) - 1, _ONE_BITS)

    def code(bits: np.ndarray) -> np.ndarray:
        return _srgb8_reference(bits.astype(np.uint32).view(np.float32)).astype(np.int64)

    base = code(starts)
    rises = code(ends) - base
    if rises.min() < 0 or rises.max() > 1:
        return None
    (idx,) = np.nonzero(rises)
    lo, hi = starts[idx], ends[idx]  # code(lo) = base, code(hi) = base + 1
    while np.any(hi - lo > 1):
        mid = (lo + hi) // 2
        up = code(mid) > base[idx]
        hi, lo = np.where(up, mid, hi), np.where(up, lo, mid)
    step = np.full(len(starts), 0xFFFFFFFF, dtype=np.uint32)
    step[idx] = hi
    return base.astype(np.uint8), step


def _srgb8(linear: np.ndarray) -> np.ndarray:
    """:func:`_srgb8_reference` of a float32 array (bit-identical), by table look-up: about 5x faster."""
    tables = _srgb8_tables()
    if tables is None:
        return _srgb8_reference(linear)
    base, step = tables
    bits = np.clip(linear, np.float32(0.0), np.float32(1.0)).view(np.uint32)
    bits &= np.uint32(0x7FFFFFFF)  # -0.0 -> +0.0
    bucket = (bits >> _BUCKET_SHIFT).astype(np.intp)  # one index conversion for both look-ups
    codes = base.take(bucket)
    codes += bits >= step.take(bucket)
    return codes


def _as_image(name: str, image, channels: Iterable[int] = (1, 2, 3, 4)) -> np.ndarray:
    """Return ``image`` as a C-contiguous float32 (H, W, C) array, or raise ValueError naming ``name``."""
    a = np.asarray(image)
    if a.ndim == 2:
        a = a[:, :, None]
    channels = tuple(channels)
    if a.ndim != 3 or a.shape[2] not in channels or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"{name}: expected an (H, W) or (H, W, C) image with C in {channels}, got shape {a.shape}")
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise ValueError(f"{name}: expected a numeric image, got dtype {a.dtype}")
    with np.errstate(over="ignore", invalid="ignore"):  # out-of-range values become inf and are reported below
        a = np.ascontiguousarray(a, dtype=np.float32)
    bad = ~np.isfinite(a)
    if bad.any():
        r, c, _ = np.argwhere(bad)[0]
        raise ValueError(
            f"{name}: {int(bad.sum())} non-finite value(s) (NaN/Inf, after conversion to float32), "
            f"first at row {r}, column {c}; refusing to write"
        )
    return a


def _header_attribute(spec: oiio.ImageSpec, key: str, value) -> None:
    """Store one metadata value in a file header: a 4x4 matrix (row-vector convention, as Imath), a number, or text."""
    if isinstance(value, np.ndarray) and value.shape == (4, 4):
        spec.attribute(key, oiio.TypeDesc("matrix"), tuple(float(x) for x in value.reshape(-1)))
    elif isinstance(value, (bool, np.bool_)):
        spec.attribute(key, str(bool(value)).lower())
    elif isinstance(value, (int, np.integer)):
        spec.attribute(key, int(value))
    elif isinstance(value, (float, np.floating)):
        spec.attribute(key, float(value))
    else:
        spec.attribute(key, str(value))


def _write_oiio(path: Path, pixels: np.ndarray, pixel_type: str, compression: str | None = None,
                attributes: Mapping[str, object] | None = None, channel_names: tuple[str, ...] | None = None,
                metadata: Mapping[str, object] | None = None) -> None:
    """Write an (H, W, C) array with OpenImageIO; ``attributes`` are writer settings, ``metadata`` header values."""
    h, w, c = pixels.shape
    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise ImageWriteError(oiio.geterror() or f"no writer for {path.suffix!r} files")
    spec = oiio.ImageSpec(w, h, c, pixel_type)
    spec.channelnames = channel_names or _CHANNEL_NAMES[c]
    if channel_names is None and c in (2, 4):
        spec.alpha_channel = c - 1
    spec.attribute("Software", f"warpscatter {__version__}")
    if compression:
        spec.attribute("compression", compression)
    for key, value in (attributes or {}).items():
        spec.attribute(key, value)
    for key, value in (metadata or {}).items():
        _header_attribute(spec, key, value)
    if not out.open(str(path), spec):
        raise ImageWriteError(out.geterror() or oiio.geterror() or "open failed")
    ok = False
    try:
        ok = out.write_image(pixels)
    finally:
        closed = out.close()
    if not (ok and closed):
        raise ImageWriteError(out.geterror() or oiio.geterror() or "write failed")


def _check_compression(compression: str) -> str:
    if compression not in EXR_COMPRESSIONS:
        raise ValueError(f"compression: must be one of {', '.join(EXR_COMPRESSIONS)}, got {compression!r}")
    return compression


def _exr_writer(pixels: np.ndarray, compression: str, channel_names: tuple[str, ...] | None = None,
                metadata: Mapping[str, object] | None = None) -> Callable[[Path], None]:
    return lambda p: _write_oiio(p, pixels, "float", compression, channel_names=channel_names, metadata=metadata)


def _text_writer(text: str) -> Callable[[Path], None]:
    return lambda p: p.write_text(text, encoding="utf-8")


def json_ready(value):
    """Plain JSON data of sidecar values: numpy to numbers and lists, paths to strings, non-finite floats to null."""
    if isinstance(value, Mapping):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        return [json_ready(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_ready(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return str(value)


def _layer_channels(aov: str, channels: int) -> tuple[str, ...]:
    """Channel names of an output inside the layered EXR: ``R, G, B`` for the colour, ``LAYER.NAME`` otherwise."""
    names = AOV_CHANNEL_NAMES.get(aov, _CHANNEL_NAMES[channels])
    return names if aov == "color" else tuple(f"{aov}.{n}" for n in names)


def _png_pixels(pixels: np.ndarray, exposure: float) -> np.ndarray:
    """The 8-bit preview of a checked float32 (H, W, C) image: colour sRGB-encoded, alpha (if any) linear."""
    colour = 3 if pixels.shape[2] >= 3 else 1
    if pixels.shape[2] == colour:
        return _srgb8(pixels * np.float32(exposure))
    quantized = np.empty(pixels.shape, dtype=np.uint8)
    quantized[:, :, :colour] = _srgb8(pixels[:, :, :colour] * np.float32(exposure))
    alpha = np.clip(pixels[:, :, colour:], 0.0, 1.0)
    quantized[:, :, colour:] = np.rint(alpha * np.float32(255.0)).astype(np.uint8)
    return quantized


def _png_writer(pixels: np.ndarray, exposure: float) -> Callable[[Path], None]:
    return lambda p: _write_oiio(p, _png_pixels(pixels, exposure), "uint8", attributes=_PNG_ATTRIBUTES)


def write_exr(path: str | Path, image: np.ndarray, compression: str = DEFAULT_EXR_COMPRESSION) -> Path:
    """Write a linear float image to an OpenEXR file, atomically (32-bit float, lossless); returns the path.

    Args:
        path: target file (``warpscatter.exr``); its folder must exist.
        image: (H, W) gray, or (H, W, C) with C in 1..4 (RGB/RGBA), row 0 = top; converted to float32.
        compression: one of :data:`EXR_COMPRESSIONS`.

    Raises:
        ValueError: bad shape, non-finite values or an unknown compression.
        ImageWriteError: the file could not be written (no partial file is left behind).
    """
    path = Path(path)
    _check_compression(compression)
    pixels = _as_image(str(path), image)
    return _write_all([(path, _exr_writer(pixels, compression))])[0]


def write_png(path: str | Path, linear_rgb: np.ndarray, exposure: float = 1.0) -> Path:
    """Write an 8-bit sRGB preview round(255 * srgb_encode(clamp(v * exposure))) of a linear image, atomically;
    returns the path.

    Args:
        path: target file (``warpscatter.png``, or any 8-bit format OpenImageIO writes, e.g. ``warpscatter.jpg``).
        linear_rgb: (H, W) gray or (H, W, C) with C in 1..4, linear light, row 0 = top.
        exposure: scale applied before clamping (> 0).

    Raises:
        ValueError: bad shape, non-finite values, or exposure <= 0.
        ImageWriteError: the file could not be written.
    """
    path = Path(path)
    if not (np.isfinite(exposure) and exposure > 0):
        raise ValueError(f"exposure: must be > 0, got {exposure}")
    pixels = _as_image(str(path), linear_rgb)
    return _write_all([(path, _png_writer(pixels, exposure))])[0]


def write_outputs(
    out_dir: str | Path,
    name: str,
    images: Mapping[str, np.ndarray],
    aovs: Iterable[str] = ("color",),
    exposure: float = 1.0,
    compression: str = DEFAULT_EXR_COMPRESSION,
    *,
    metadata: Mapping[str, object] | None = None,
    sidecar: Mapping[str, object] | None = None,
    layered: bool = False,
) -> list[Path]:
    """Write a render's output set (CONVENTIONS.md "Config and output contract"), all or nothing; returns the paths.

    Files: ``NAME.exr`` and ``NAME.png`` always, one ``NAME.<aov>.exr`` per requested AOV, ``NAME.json`` when a sidecar
    is given; with ``layered``, image-sized AOVs are layers of ``NAME.exr``. On any failure the previous files return.

    Args:
        out_dir, name: output folder (created if missing) and file stem.
        images: arrays by AOV name; ``color`` is required, and every requested AOV must be present.
            All but :data:`OWN_SIZE_AOVS` must share (H, W); one-channel images may be (H, W) or (H, W, 1).
        aovs: requested AOV names out of :data:`AOV_CHANNELS` (each written as ``NAME.<aov>.exr``).
        exposure, compression: as :func:`write_png` and :func:`write_exr`.
        metadata: header attributes of every EXR (e.g. ``worldToCamera``: a 4x4 numpy matrix; text; numbers);
            each EXR also gets ``warpscatter:aov``, its output's name.
        sidecar: plain data written as ``NAME.json`` with the set (numpy values and paths converted).
        layered: one multi-layer ``NAME.exr`` instead of one file per AOV.

    Raises:
        ValueError: unknown/missing AOV, mismatched shapes, non-finite pixels, bad exposure, compression or name.
        OutputNameError: (a ValueError) a reserved or too long name (:func:`check_output_target`); nothing is
            written. :class:`OutputFolderError` (an ImageWriteError): a folder that cannot hold the files.
        ImageWriteError: a file could not be written or renamed in; the previous files are kept (or the message
            names the backups if the rollback failed). :class:`OutputBusyError`: another process kept writing the
            same name for longer than :data:`OUTPUT_LOCK_TIMEOUT_S`.
    """
    if not name or "/" in name or "\\" in name or name in (".", ".."):
        raise ValueError(f"name: must be a plain file stem, got {name!r}")
    if not (np.isfinite(exposure) and exposure > 0):
        raise ValueError(f"exposure: must be > 0, got {exposure}")
    _check_compression(compression)
    requested = list(dict.fromkeys(["color", *aovs]))
    unknown = [a for a in requested if a not in AOV_CHANNELS]
    if unknown:
        raise ValueError(f"aovs: unknown {unknown} (choose from {list(AOV_CHANNELS)})")
    missing = [a for a in requested if a not in images]
    if missing:
        raise ValueError(f"images: no image given for requested aov(s) {missing}")

    checked = {a: _as_image(a, images[a], (AOV_CHANNELS[a],)) for a in AOV_CHANNELS if a in requested}
    sizes = {a: img.shape[:2] for a, img in checked.items() if a not in OWN_SIZE_AOVS}
    if len(set(sizes.values())) > 1:
        raise ValueError(f"images: sizes differ {sizes}")

    out_dir = Path(out_dir)
    check_output_target(out_dir, name, requested)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ImageWriteError(f"cannot create output folder {out_dir}: {exc}") from exc
    remove_stale_temporaries(out_dir)

    def exr_meta(aov: str) -> dict:
        return {**(metadata or {}), "warpscatter:aov": aov}

    separate = [a for a in checked if a != "color" and (not layered or a in OWN_SIZE_AOVS)]
    if layered:
        layers = [a for a in checked if a not in separate]
        stacked = np.concatenate([checked[a] for a in layers], axis=2)
        channels = sum((_layer_channels(a, checked[a].shape[2]) for a in layers), ())
        color_job = _exr_writer(stacked, compression, channels, {**exr_meta("color"), "warpscatter:layers":
                                                                 ",".join(layers)})
    else:
        color_job = _exr_writer(checked["color"], compression, metadata=exr_meta("color"))
    jobs = [(out_dir / f"{name}.exr", color_job), (out_dir / f"{name}.png", _png_writer(checked["color"], exposure))]
    for aov in separate:
        jobs.append((out_dir / f"{name}.{aov}.exr",
                     _exr_writer(checked[aov], compression, AOV_CHANNEL_NAMES.get(aov), exr_meta(aov))))
    if sidecar is not None:
        text = json.dumps(json_ready(sidecar), indent=2) + "\n"
        jobs.append((out_dir / f"{name}.json", _text_writer(text)))
    return _write_all(jobs, name)


def read_image(path: str | Path) -> np.ndarray:
    """Read an image as linear float32 (H, W, C), row 0 = top; integer files are decoded from sRGB unless linear.
    OSError (naming the file and OpenImageIO's error) when it cannot be read."""
    path = Path(path)
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise OSError(f"cannot read {path}: {oiio.geterror()}")
    try:
        spec = inp.spec()
        pixels = inp.read_image(format="float")
        if pixels is None:
            raise OSError(f"cannot read {path}: {inp.geterror()}")
    finally:
        inp.close()
    pixels = np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)
    colourspace = (spec.get_string_attribute("oiio:ColorSpace") or "").lower()
    linear_file = colourspace.startswith("lin") or colourspace in ("raw", "data", "scene_linear")
    if spec.format.basetype in _INTEGER_BASETYPES and not linear_file:
        colour = [i for i in range(spec.nchannels) if i != spec.alpha_channel][:3]
        pixels[:, :, colour] = srgb_decode(pixels[:, :, colour])
    return np.ascontiguousarray(pixels)


def read_radiance_image(path: str | Path, key: str | None = None) -> np.ndarray:
    """Read radiance values (a light texture, an environment map) as linear float32 (H, W, 3), finite and >= 0;
    ``key``: the config key that named ``path`` (``light.texture``), put in front of the message.

    Raises:
        InputFileError: the file cannot be read, or holds non-finite or negative values (the message names the file,
            the count and the first texel).
    """
    path = Path(path)
    try:
        image = read_image(path)
    except OSError as exc:
        raise InputFileError(str(exc), path=path, key=key) from None
    colour = image[:, :, :1] if image.shape[2] <= 2 else image[:, :, :3]
    for bad, what in ((~np.isfinite(colour), "non-finite (NaN or infinite)"), (colour < 0.0, "negative")):
        if bad.any():
            r, c, ch = np.argwhere(bad)[0]
            raise InputFileError(
                f"{path}: {int(bad.sum())} {what} value(s), first at row {r}, column {c}, channel {ch} "
                f"({float(colour[r, c, ch])}); radiance must be finite and >= 0", path=path, key=key)
    return np.ascontiguousarray(np.repeat(colour, 3, axis=2) if colour.shape[2] == 1 else colour)
