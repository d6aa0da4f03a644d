"""Image files through OpenImageIO: linear EXR, sRGB PNG previews, reading, and the render output set.

Conventions (CONVENTIONS.md, "Images"): arrays are ``(H, W)`` or ``(H, W, C)`` float32, row 0 is the
TOP row of the file. EXR files hold linear values exactly (32-bit float, lossless ZIP compression).
PNG previews are exposure-scaled, clamped to [0, 1] and sRGB-encoded to 8 bits; reading an 8/16-bit
file decodes sRGB back to linear.

Every write is atomic: the image goes to a hidden temporary file in the target folder (the real
extension kept last so OpenImageIO picks the format), then :func:`os.replace` moves it into place.
:func:`write_outputs` extends this to a whole set of render outputs: all files are written to
temporaries first and renamed only when every one succeeded, so a failure leaves no output file.
Non-finite pixels are refused: the renderer must never produce NaN or Inf.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from . import __version__

__all__ = [
    "AOV_CHANNELS",
    "ImageWriteError",
    "read_image",
    "srgb_decode",
    "srgb_encode",
    "write_exr",
    "write_outputs",
    "write_png",
]

#: Channel count of each render output (``color`` is also written as the PNG preview).
AOV_CHANNELS = {"color": 3, "scattering": 3, "surface": 3, "depth": 1}

_CHANNEL_NAMES = {1: ("Y",), 2: ("Y", "A"), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}
_INTEGER_BASETYPES = {oiio.UINT8, oiio.INT8, oiio.UINT16, oiio.INT16, oiio.UINT32, oiio.INT32}


class ImageWriteError(OSError):
    """An image file could not be written; the message names the file and OpenImageIO's error."""


# ---- sRGB transfer function ------------------------------------------------------------------------


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Linear light -> sRGB-encoded values (IEC 61966-2-1), both in [0, 1]; input is clamped to [0, 1].

    Args:
        linear: array of linear values (any shape).

    Returns:
        float32 array of the same shape.
    """
    x = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)  # float64 so that 1 maps to exactly 1
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055).astype(np.float32)


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """sRGB-encoded values -> linear light (inverse of :func:`srgb_encode`); input is clamped to [0, 1]."""
    x = np.clip(np.asarray(encoded, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, np.power((x + 0.055) / 1.055, 2.4)).astype(np.float32)


# ---- checks ----------------------------------------------------------------------------------------


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


# ---- writing ---------------------------------------------------------------------------------------


def _temp_name(path: Path) -> Path:
    """Hidden temporary sibling of ``path`` that keeps the real extension last (``.name.tmp-PID-XXXX.exr``)."""
    return path.with_name(f".{path.stem}.tmp-{os.getpid()}-{secrets.token_hex(3)}{path.suffix}")


def _write_oiio(path: Path, pixels: np.ndarray, pixel_type: str, compression: str | None = None) -> None:
    """Write an (H, W, C) array to ``path`` with OpenImageIO (format from the extension)."""
    h, w, c = pixels.shape
    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise ImageWriteError(oiio.geterror() or f"no writer for {path.suffix!r} files")
    spec = oiio.ImageSpec(w, h, c, pixel_type)
    spec.channelnames = _CHANNEL_NAMES[c]
    if c in (2, 4):
        spec.alpha_channel = c - 1
    spec.attribute("Software", f"warpscatter {__version__}")
    if compression:
        spec.attribute("compression", compression)
    if not out.open(str(path), spec):
        raise ImageWriteError(out.geterror() or oiio.geterror() or "open failed")
    ok = False
    try:
        ok = out.write_image(pixels)
    finally:
        closed = out.close()
    if not (ok and closed):
        raise ImageWriteError(out.geterror() or oiio.geterror() or "write failed")


def _remove_quietly(path: Path) -> None:
    try:
        path.unlink()
    except OSError:
        pass


def _exr_writer(pixels: np.ndarray) -> Callable[[Path], None]:
    return lambda p: _write_oiio(p, pixels, "float", "zip")


def _png_writer(pixels: np.ndarray, exposure: float) -> Callable[[Path], None]:
    encoded = pixels.copy()
    colour = slice(0, 3) if pixels.shape[2] >= 3 else slice(0, 1)
    encoded[:, :, colour] = srgb_encode(pixels[:, :, colour] * np.float32(exposure))
    encoded = np.clip(encoded, 0.0, 1.0)  # alpha (if any) stays linear
    quantized = np.rint(encoded * 255.0).astype(np.uint8)
    return lambda p: _write_oiio(p, quantized, "uint8")


def _write_all(jobs: list[tuple[Path, Callable[[Path], None]]]) -> list[Path]:
    """Write every job to a temporary file, then rename all; on any failure leave none of the targets."""
    temps: list[Path] = []
    done: list[Path] = []
    current = jobs[0][0]
    try:
        for final, writer in jobs:
            current = final
            tmp = _temp_name(final)
            temps.append(tmp)
            writer(tmp)
        for (final, _), tmp in zip(jobs, temps, strict=True):
            current = final
            os.replace(tmp, final)
            done.append(final)
    except BaseException as exc:
        for p in temps + done:
            _remove_quietly(p)
        if not isinstance(exc, Exception):
            raise
        raise ImageWriteError(f"cannot write {current}: {exc}") from exc
    return done


def write_exr(path: str | Path, image: np.ndarray) -> Path:
    """Write a linear float image to an OpenEXR file, atomically (32-bit float, lossless).

    Args:
        path: target file (``.exr``); its folder must exist.
        image: (H, W) gray, or (H, W, C) with C in 1..4 (RGB/RGBA), row 0 = top; converted to float32.

    Returns:
        The written path.

    Raises:
        ValueError: bad shape or non-finite values.
        ImageWriteError: the file could not be written (no partial file is left behind).
    """
    path = Path(path)
    pixels = _as_image(str(path), image)
    return _write_all([(path, _exr_writer(pixels))])[0]


def write_png(path: str | Path, linear_rgb: np.ndarray, exposure: float = 1.0) -> Path:
    """Write an 8-bit sRGB preview of a linear image, atomically.

    Each colour value v becomes round(255 * srgb_encode(clamp(v * exposure, 0, 1))); an alpha
    channel, if present, is clamped and stored linearly.

    Args:
        path: target file (``.png``, or any 8-bit format OpenImageIO writes, e.g. ``.jpg``).
        linear_rgb: (H, W) gray or (H, W, C) with C in 1..4, linear light, row 0 = top.
        exposure: scale applied before clamping (> 0).

    Returns:
        The written path.

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
) -> list[Path]:
    """Write a render's output set (CONVENTIONS.md "Config and output contract"), all or nothing.

    Files, in this order: ``NAME.exr`` (linear RGB) and ``NAME.png`` (preview) always, then
    ``NAME.scattering.exr``, ``NAME.surface.exr`` (linear RGB) and ``NAME.depth.exr`` (one channel)
    for the AOVs requested.

    Args:
        out_dir: output folder (created if missing).
        name: file stem.
        images: arrays by AOV name; ``color`` is required, and every requested AOV must be present.
            All must share (H, W); depth may be (H, W) or (H, W, 1).
        aovs: requested AOV names out of ``color``, ``scattering``, ``surface``, ``depth``.
        exposure: PNG preview exposure (> 0).

    Returns:
        The written paths.

    Raises:
        ValueError: unknown/missing AOV, mismatched shapes, non-finite pixels, bad exposure or name.
        ImageWriteError: a file could not be written; then none of the output files exists.
    """
    if not name or "/" in name or "\\" in name or name in (".", ".."):
        raise ValueError(f"name: must be a plain file stem, got {name!r}")
    if not (np.isfinite(exposure) and exposure > 0):
        raise ValueError(f"exposure: must be > 0, got {exposure}")
    requested = list(dict.fromkeys(["color", *aovs]))
    unknown = [a for a in requested if a not in AOV_CHANNELS]
    if unknown:
        raise ValueError(f"aovs: unknown {unknown} (choose from {list(AOV_CHANNELS)})")
    missing = [a for a in requested if a not in images]
    if missing:
        raise ValueError(f"images: no image given for requested aov(s) {missing}")

    checked = {a: _as_image(a, images[a], (AOV_CHANNELS[a],)) for a in AOV_CHANNELS if a in requested}
    sizes = {a: img.shape[:2] for a, img in checked.items()}
    if len(set(sizes.values())) > 1:
        raise ValueError(f"images: sizes differ {sizes}")

    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ImageWriteError(f"cannot create output folder {out_dir}: {exc}") from exc

    jobs = [
        (out_dir / f"{name}.exr", _exr_writer(checked["color"])),
        (out_dir / f"{name}.png", _png_writer(checked["color"], exposure)),
    ]
    for aov in ("scattering", "surface", "depth"):
        if aov in checked:
            jobs.append((out_dir / f"{name}.{aov}.exr", _exr_writer(checked[aov])))
    return _write_all(jobs)


# ---- reading ---------------------------------------------------------------------------------------


def read_image(path: str | Path) -> np.ndarray:
    """Read an image as linear float32 (H, W, C), row 0 = top.

    Integer-valued files (PNG, JPEG, 8/16-bit TIFF) are taken as sRGB-encoded and decoded to linear,
    unless the file declares a linear or raw colour space; alpha stays as stored. Float files (EXR,
    float TIFF/HDR) are returned as stored.

    Raises:
        OSError: the file cannot be opened or read (message names the file and OpenImageIO's error).
    """
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
