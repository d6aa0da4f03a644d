"""Reading CSM files (the ``.npz`` of :func:`~.compress.save_csm`), bounded: :func:`load_csm` checks every zip
entry's sizes and inflation ratio and every ``.npy`` header before it inflates any array data, then the params JSON,
the segment lists, the depths and the enumeration table, so that a corrupt or hostile file is refused as a
:class:`CSMFileError` naming it, within a small multiple of the memory the arrays it describes need.
"""

from __future__ import annotations

import io
import json
import os
import zipfile
import zlib
from dataclasses import dataclass
from struct import error as struct_error

import numpy as np

from ..errors import InputFileError
from .compress import FORMAT_VERSION, KIND_CUBE, KINDS, CoherentShadowMap, SegmentLists
from .depthmaps import DEPTH_LAYERS, FAR_MODES
from .enumeration import ENUMERATIONS, enumerate_grid, sequence_index

#: The most array data in bytes :func:`load_csm` reads, checked before anything is allocated.
MAX_CSM_BYTES = 4 * 2**30
#: A compressed ``.npz`` entry may inflate to at most this many times its compressed size plus
#: :data:`INFLATE_SLACK_BYTES`, checked from the zip directory before it is inflated (a zip bomb of deflated zeros
#: inflates ~1000 times; :func:`~.compress.save_csm` stores its arrays uncompressed, ``np.savez_compressed`` of a
#: CSM inflates 2-12 times).
MAX_INFLATE_RATIO = 64
INFLATE_SLACK_BYTES = 2**20
#: The most bytes the ``params`` JSON string may declare (a CSM's is about 1.3 KB).
MAX_PARAMS_BYTES = 2**20
#: Largest |centre coordinate|, radius, near plane and |light sample coordinate| of a CSM: (2 R)^2 stays finite in
#: float32 (the kernels' precision).
MAX_CSM_EXTENT = 1.0e18
#: Most cells n1 x n2 (the largest grid a config builds, 1024^2) and largest face size M of a CSM file: checking the
#: enumeration takes ~40 bytes a cell.
MAX_CSM_CELLS = 2**20
MAX_CSM_RESOLUTION = 8192


class CSMFileError(InputFileError):
    """A CSM file cannot be read or is inconsistent (an InputFileError: a user error, CLI exit code 2)."""


_ARRAYS = ("format_version", "params", "map_index", "seg_start", "seg_depth", "seg_end")


def _fail(path: str, reason: str) -> CSMFileError:
    return CSMFileError(f"{path}: {reason}", path=path)


def _clip(text: str, limit: int = 200) -> str:
    """``text`` cut to ``limit`` characters: messages quote what a file holds, bounded."""
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _short(value, limit: int = 80) -> str:
    """repr of ``value``, cut to ``limit`` characters."""
    return _clip(repr(value), limit)


@dataclass
class _Entry:
    """One ``NAME.npy`` entry of a CSM ``.npz``: its zip entry and what its ``.npy`` header declares."""

    name: str
    info: zipfile.ZipInfo
    shape: tuple
    fortran: bool
    dtype: np.dtype
    header_bytes: int

    @property
    def count(self) -> int:
        return int(np.prod(self.shape, dtype=object))

    @property
    def nbytes(self) -> int:
        return self.count * self.dtype.itemsize


_NPY_READ_CHUNK = 2**20
#: Longest .npy header read (numpy refuses those over 10000 characters, but only after reading them whole).
_NPY_MAX_HEADER = 2**16


def _read_entry_header(path: str, zf: zipfile.ZipFile, info: zipfile.ZipInfo, file_size: int) -> _Entry:
    """The zip entry's sizes and its ``.npy`` header, checked without inflating more than the header: the entry
    must fit in the file and inflate at most :data:`MAX_INFLATE_RATIO` times, and the header's shape x itemsize
    must be the entry's data size."""
    name = info.filename[:-4]
    if info.compress_size > file_size or (info.compress_type == zipfile.ZIP_STORED
                                          and info.file_size != info.compress_size):
        raise _fail(path, f"array {name!r}: its zip entry declares {info.file_size} bytes, more than the "
                          f"file holds ({file_size} bytes)")
    if info.file_size > MAX_INFLATE_RATIO * info.compress_size + INFLATE_SLACK_BYTES:
        raise _fail(path, f"array {name!r}: its zip entry inflates {info.compress_size} compressed bytes to "
                          f"{info.file_size}, more than {MAX_INFLATE_RATIO} times (a zip bomb?; "
                          f"warpscatter.csm.files.MAX_INFLATE_RATIO)")
    with zf.open(info) as f:
        try:
            version = np.lib.format.read_magic(f)
            if version not in ((1, 0), (2, 0), (3, 0)):
                raise ValueError(f"unsupported .npy format version {version}")
            size = f.read(2 if version == (1, 0) else 4)
            length = int.from_bytes(size, "little")
            if len(size) not in (2, 4) or length > _NPY_MAX_HEADER:
                raise ValueError(f"a header of {length} bytes (at most {_NPY_MAX_HEADER})")
            header = f.read(length)  # bounded here: numpy reads the whole declared length before its own check
            read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                           else np.lib.format.read_array_header_2_0)
            shape, fortran, dtype = read_header(io.BytesIO(size + header))
            shape = tuple(int(d) for d in shape)
        except Exception as exc:  # noqa: BLE001  (numpy's header parser raises many kinds; each is a bad header)
            raise _fail(path, f"array {name!r} has no valid .npy header ({_clip(str(exc))})") from None
        header_bytes = f.tell()
    entry = _Entry(name, info, shape, bool(fortran), dtype, header_bytes)
    if dtype.hasobject:
        raise _fail(path, f"array {name!r} holds Python objects (dtype {dtype}), not numbers")
    if any(d < 0 for d in shape):
        raise _fail(path, f"array {name!r} declares a negative dimension (shape {_short(shape)})")
    if entry.nbytes != info.file_size - header_bytes:
        raise _fail(path, f"array {name!r} declares shape {_short(shape)} of {dtype} ({entry.nbytes} bytes) but "
                          f"its entry holds {info.file_size - header_bytes} bytes of data")
    return entry


def _read_headers(path: str, zf: zipfile.ZipFile) -> dict[str, _Entry]:
    """The headers of the arrays a CSM may hold (other entries are never read), their sum checked against
    :data:`MAX_CSM_BYTES`; CSMFileError for missing or repeated arrays."""
    file_size = os.path.getsize(path)
    wanted = _ARRAYS + ("light_samples",)
    infos: dict[str, zipfile.ZipInfo] = {}
    for info in zf.infolist():
        name = info.filename[:-4] if info.filename.endswith(".npy") else None
        if name in wanted:
            if name in infos:
                raise _fail(path, f"the file holds array {name!r} twice")
            infos[name] = info
    missing = [k for k in _ARRAYS if k not in infos]
    if missing:
        raise _fail(path, f"missing arrays {missing}")
    entries, total = {}, 0
    for name, info in infos.items():
        entry = entries[name] = _read_entry_header(path, zf, info, file_size)
        total += entry.nbytes
        if total > MAX_CSM_BYTES:
            raise _fail(path, f"the arrays hold more than {MAX_CSM_BYTES} bytes (array {name!r}: shape "
                              f"{_short(entry.shape)} of {entry.dtype}), the limit of a CSM file "
                              f"(warpscatter.csm.files.MAX_CSM_BYTES)")
    return entries


def _read_data(zf: zipfile.ZipFile, entry: _Entry) -> np.ndarray:
    """The array of a checked entry: allocated once at its declared (checked) size, filled chunk by chunk; the zip
    CRC is verified at the end."""
    out = np.empty(entry.count, dtype=entry.dtype)
    with zf.open(entry.info) as f:
        f.read(entry.header_bytes)
        if entry.nbytes:
            view, pos = out.view(np.uint8), 0
            while pos < entry.nbytes:
                chunk = f.read(min(_NPY_READ_CHUNK, entry.nbytes - pos))
                if not chunk:
                    raise EOFError(f"array {entry.name!r} ends after {pos} of {entry.nbytes} bytes")
                view[pos: pos + len(chunk)] = np.frombuffer(chunk, dtype=np.uint8)
                pos += len(chunk)
        if f.read(1):
            raise ValueError(f"array {entry.name!r} holds more data than its header declares")
    if entry.fortran:
        return out.reshape(entry.shape[::-1]).T
    return out.reshape(entry.shape)


def _read_params(path: str, zf: zipfile.ZipFile, entries: dict[str, _Entry]) -> dict:
    """The format version, checked, and the params JSON object (at most :data:`MAX_PARAMS_BYTES`)."""
    e = entries["format_version"]
    if e.count != 1 or e.dtype.kind not in "iu":
        raise _fail(path, f"format_version is not an integer (shape {_short(e.shape)} of {e.dtype})")
    version = int(_read_data(zf, e).reshape(()))
    if version != FORMAT_VERSION:
        raise _fail(path, f"format version {version} is not supported (this build reads version {FORMAT_VERSION})")
    e = entries["params"]
    if e.count != 1 or e.dtype.kind not in "US" or e.nbytes > MAX_PARAMS_BYTES:
        raise _fail(path, f"params is not one JSON string of at most {MAX_PARAMS_BYTES} bytes (shape "
                          f"{_short(e.shape)} of {e.dtype})")
    text = _read_data(zf, e).reshape(())[()]
    try:
        params = json.loads(text.decode("utf-8") if isinstance(text, bytes) else str(text))
    except RecursionError:
        raise _fail(path, "params is not valid JSON (nested too deeply)") from None
    except (TypeError, ValueError) as exc:
        raise _fail(path, f"params is not valid JSON ({_clip(str(exc), 120)})") from None
    return params


def _param_int(path: str, params: dict, key: str, lo: int, hi: int) -> int:
    v = params[key]
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise _fail(path, f"params {key} = {_short(v)} is not an integer in [{lo}, {hi}]")
    return v


def _param_float(path: str, params: dict, key: str) -> float:
    v = params[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise _fail(path, f"params {key} = {_short(v)} is not a number")
    return float(v) if isinstance(v, float) or abs(v) < 2**1000 else float(np.sign(v)) * np.inf


def _load_params(path: str, params) -> dict:
    """The CSM's parameters from its params JSON, every field typed and bounded."""
    if not isinstance(params, dict) or params.get("kind") not in KINDS:
        kind = params.get("kind") if isinstance(params, dict) else params
        raise _fail(path, f"unknown CSM kind {_short(kind)}")
    cube = params["kind"] == KIND_CUBE
    try:
        center = params["center"]
        if not (isinstance(center, list) and len(center) == 3):
            raise _fail(path, f"params center = {_short(center)} is not 3 numbers")
        out = {
            "kind": params["kind"], "near": _param_float(path, params, "near") if cube else None,
            "n1": _param_int(path, params, "n1", 1, MAX_CSM_CELLS),
            "n2": _param_int(path, params, "n2", 1, MAX_CSM_CELLS),
            "resolution": _param_int(path, params, "resolution", 1, MAX_CSM_RESOLUTION),
            "center": np.array([_param_float(path, {"center": c}, "center") for c in center], dtype=np.float64),
            "radius": _param_float(path, params, "radius"),
            "num_segments": _param_int(path, params, "num_segments", 1, 2**31 - 1),
        }
        for key in ("enumeration", "depth_layers", "far"):
            out[key] = params[key]
        geometry = params.get("geometry")
    except KeyError as exc:
        raise _fail(path, f"params lack or mistype a field ({exc})") from None
    if geometry is not None and not isinstance(geometry, str):
        raise _fail(path, f"params geometry = {_short(geometry)} is not a digest string")
    out["geometry"] = geometry
    cells, texels = out["n1"] * out["n2"], out["resolution"] ** 2
    num_maps = cells * (6 if cube else 1)
    if cells > MAX_CSM_CELLS:
        raise _fail(path, f"params hold {out['n1']} x {out['n2']} cells, more than {MAX_CSM_CELLS} "
                          f"(warpscatter.csm.files.MAX_CSM_CELLS)")
    if not texels <= out["num_segments"] <= num_maps * texels:
        raise _fail(path, f"params hold impossible sizes ({out['num_segments']} segments for {num_maps} maps of "
                          f"{texels} texels: between 1 and {num_maps} a texel)")
    if out["near"] is not None and not (np.isfinite(out["near"]) and out["near"] > 0):
        raise _fail(path, "params hold a near plane that is not > 0")
    if not (np.all(np.isfinite(out["center"])) and np.isfinite(out["radius"]) and out["radius"] > 0):
        raise _fail(path, "params hold a non-finite centre or a radius <= 0")
    extents = (*np.abs(out["center"]), out["radius"], out["near"] or 0.0)
    if max(extents) > MAX_CSM_EXTENT:
        raise _fail(path, f"params hold a centre, radius or near plane beyond {MAX_CSM_EXTENT:g} (centre "
                          f"{out['center'].tolist()}, radius {out['radius']:g}; warpscatter.csm.files."
                          f"MAX_CSM_EXTENT)")
    for key, allowed in (("enumeration", ENUMERATIONS), ("depth_layers", tuple(DEPTH_LAYERS)), ("far", FAR_MODES)):
        if not isinstance(out[key], str) or out[key] not in allowed:
            raise _fail(path, f"params {key} = {_short(out[key])} is not one of {allowed}")
    return out


def load_csm(path: str | os.PathLike) -> CoherentShadowMap:
    """Read a CSM written by :func:`~.compress.save_csm`, checking it completely. Every array's zip entry and
    ``.npy`` header are checked against the file, :data:`MAX_INFLATE_RATIO`, :data:`MAX_CSM_BYTES` and the shapes the
    params imply before any array data is inflated, so memory stays within a small multiple of the arrays the params
    describe.

    Raises:
        CSMFileError: missing or unreadable file, sizes beyond the file, the inflation ratio or
            :data:`MAX_CSM_BYTES`, wrong version, params out of bounds, arrays, dtypes or sizes, inconsistent
            segment lists or enumeration tables, negative depths.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise _fail(path, "no such file")
    try:
        with zipfile.ZipFile(path) as zf:
            entries = _read_headers(path, zf)
            p = _load_params(path, _read_params(path, zf, entries))
            n1, n2, m = p["n1"], p["n2"], p["resolution"]
            cube = p["kind"] == KIND_CUBE
            n, texels, s = n1 * n2 * (6 if cube else 1), m * m, p["num_segments"]
            expect = {"map_index": ((n2, n1), np.integer), "seg_start": ((texels + 1,), np.integer),
                      "seg_depth": ((s,), np.floating), "seg_end": ((s,), np.integer)}
            if cube:
                if "light_samples" not in entries:
                    raise _fail(path, "missing arrays ['light_samples'] of a cube CSM")
                expect["light_samples"] = ((n1 * n2, 3), np.floating)
            for key, (shape, kind) in expect.items():
                e = entries[key]
                if e.shape != shape or not np.issubdtype(e.dtype, kind) or e.dtype.itemsize > 8:
                    raise _fail(path, f"{key} has shape {_short(e.shape)} and dtype {e.dtype}, expected {shape} of "
                                      f"{kind.__name__}")
            arrays = {k: _read_data(zf, entries[k]) for k in expect}
    except CSMFileError:
        raise
    except (OSError, ValueError, EOFError, KeyError, NotImplementedError, RuntimeError, OverflowError,
            struct_error, zipfile.BadZipFile, zlib.error) as exc:
        raise _fail(path, f"not a readable .npz file ({_clip(str(exc))})") from exc
    # ranges first, then int32 (no copy for the int32 arrays save_csm writes): few temporaries on large files
    start, end = arrays["seg_start"], arrays["seg_end"]
    if start.min() < 0 or start.max() > s:
        raise _fail(path, "seg_start does not partition the segments (its entries lie outside 0 .. num_segments)")
    if end.min() < 0 or end.max() > n - 1:
        raise _fail(path, f"segment ends are not strictly ascending within a texel (they lie outside 0 .. {n - 1})")
    start, end = start.astype(np.int32, copy=False), end.astype(np.int32, copy=False)
    if start[0] != 0 or start[-1] != s or np.any(np.diff(start) < 1):
        raise _fail(path, "seg_start does not partition the segments (every texel needs >= 1 segment)")
    if np.any(end[start[1:] - 1] != n - 1):
        raise _fail(path, f"a texel's last segment does not end at map {n - 1}")
    not_first = np.ones(s, dtype=bool)  # segments that are not their texel's first
    not_first[start[:-1]] = False
    bad_step = np.diff(end) <= 0
    bad_step &= not_first[1:]
    if bad_step.any():
        raise _fail(path, "segment ends are not strictly ascending within a texel")
    del not_first, bad_step
    depth = arrays["seg_depth"]
    if np.isnan(depth).any() or (depth < 0).any():
        raise _fail(path, "seg_depth contains NaN, -inf or negative depths (depths are distances >= 0; +inf, no "
                          "blocker, is the only non-finite depth)")
    with np.errstate(over="ignore"):
        depth32 = depth.astype(np.float32, copy=False)
    if depth.dtype.itemsize > 4 and np.any(np.isfinite(depth) & np.isinf(depth32)):
        raise _fail(path, "seg_depth holds finite depths beyond float32's range")
    if cube and not np.all(np.abs(arrays["light_samples"]) <= MAX_CSM_EXTENT):
        raise _fail(path, f"light_samples contain non-finite positions or coordinates beyond {MAX_CSM_EXTENT:g}")
    try:
        order = enumerate_grid(n1, n2, p["enumeration"])
        index = sequence_index(order, n1, n2)
    except ValueError as exc:
        raise _fail(path, str(exc)) from exc
    if not np.array_equal(index, arrays["map_index"]):
        raise _fail(path, f"map_index does not match the {p['enumeration']} enumeration of {n1} x {n2}")
    lists = SegmentLists(seg_start=start, seg_depth=depth32, seg_end=end, num_maps=n)
    return CoherentShadowMap(
        n1=n1, n2=n2, resolution=m, center=p["center"], radius=p["radius"], enumeration=p["enumeration"],
        depth_layers=p["depth_layers"], far=p["far"], map_index=index, lists=lists, kind=p["kind"],
        light_samples=arrays["light_samples"].astype(np.float64) if cube else None, near=p["near"],
        geometry=p["geometry"],
    )
