"""Fault injection on coherent-shadow-map files (issue #52): zip bombs and arrays whose declared sizes do not fit the
file, malformed ``.npy`` headers, params JSON that is deeply nested, infinite or beyond float32, negative depths.
Each is refused as a :class:`~warpscatter.csm.files.CSMFileError` (exit code 2) naming the file, before memory is
spent on it. The files are written by hand (a zip bomb cannot be made with ``np.savez_compressed``: its input would
not fit in memory).
"""

from __future__ import annotations

import io
import json
import struct
import subprocess
import sys
import textwrap
import tracemalloc
import zlib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from click.testing import CliRunner
from peak_memory import PEAK_BYTES

from warpscatter.cli.main import main
from warpscatter.csm.files import CSMFileError, load_csm
from warpscatter.csm.occluders import check_csm_for_scene
from warpscatter.errors import InputFileError
from warpscatter.scene.meshes import geometry_digest

ROOT = Path(__file__).resolve().parents[1]
GATE = ROOT / "configs" / "csm_gate.yaml"
SMALL = ["camera.width=48", "camera.height=27", "camera.supersample=1", "render.lighting.samples=4",
         "render.lighting.passes=1", "render.lighting.csm.maps=[16,8]", "render.lighting.csm.resolution=32"]
M32 = 0xFFFFFFFF

# ---- writing zip files by hand ---------------------------------------------------------------------------------------


def _npy(array) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.asarray(array), allow_pickle=False)
    return buf.getvalue()


def _npy_header(shape, descr: str = "<f4") -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False, "shape": shape})
    return buf.getvalue()


def _raw_header(text: str, version: int = 1) -> bytes:
    """A .npy magic and header of any text (no validation)."""
    body = text.encode("latin1") + b"\n"
    return b"\x93NUMPY" + bytes([version, 0]) + struct.pack("<H" if version == 1 else "<I", len(body)) + body


def _crc32_zeros(crc: int, n: int) -> int:
    """``zlib.crc32(bytes(n), crc)`` without making the n bytes: zero bytes act linearly on the CRC register, so
    the register map of a MiB of zeros is raised to the power n / 2^20 by squaring (32 x 32 bits over GF(2))."""
    chunk = 1 << 20
    q, r = divmod(n, chunk)

    def apply(cols, x):
        y, i = 0, 0
        while x:
            if x & 1:
                y ^= cols[i]
            x >>= 1
            i += 1
        return y

    cols = [zlib.crc32(bytes(chunk), (1 << i) ^ M32) ^ M32 for i in range(32)]
    reg = crc ^ M32
    while q:
        if q & 1:
            reg = apply(cols, reg)
        cols = [apply(cols, c) for c in cols]
        q >>= 1
    return zlib.crc32(bytes(r), reg ^ M32)


def _deflated_zeros(prefix: bytes, n: int, fill: int = 0) -> tuple[bytes, int, int]:
    """Raw deflate stream, CRC and size of ``prefix`` + n bytes ``fill``, made incrementally: after a full flush
    the compressor starts afresh, so every MiB of ``fill`` compresses to the same bytes, repeated."""
    chunk = 1 << 20
    co = zlib.compressobj(9, zlib.DEFLATED, -15)
    parts = [co.compress(prefix) + co.flush(zlib.Z_FULL_FLUSH)]
    block = bytes([fill]) * chunk
    q, r = divmod(n, chunk)
    if q:
        one = co.compress(block) + co.flush(zlib.Z_FULL_FLUSH)
        parts.append(one * q)
    parts.append(co.compress(block[:r]) + co.flush())
    crc = zlib.crc32(prefix)
    crc = _crc32_zeros(crc, n) if fill == 0 else zlib.crc32(bytes([fill]) * n, crc)
    return b"".join(parts), crc, len(prefix) + n


def _stored(data: bytes) -> tuple[int, bytes, int, int]:
    return 0, data, zlib.crc32(data), len(data)


def _deflated(data: bytes) -> tuple[int, bytes, int, int]:
    co = zlib.compressobj(6, zlib.DEFLATED, -15)
    return 8, co.compress(data) + co.flush(), zlib.crc32(data), len(data)


def _write_zip(path: Path, members: list[tuple[str, tuple[int, bytes, int, int]]]) -> Path:
    """A zip of (name, (method, stream, crc, size)) members, sizes under 4 GiB (no zip64)."""
    out, central = io.BytesIO(), []
    for name, (method, stream, crc, size) in members:
        raw = name.encode()
        offset = out.tell()
        out.write(struct.pack("<IHHHHHIIIHH", 0x04034B50, 20, 0, method, 0, 33, crc, len(stream), size, len(raw), 0))
        out.write(raw + stream)
        central.append(struct.pack("<IHHHHHHIIIHHHHHII", 0x02014B50, 20, 20, 0, method, 0, 33, crc, len(stream), size,
                                   len(raw), 0, 0, 0, 0, 0, offset) + raw)
    start = out.tell()
    out.write(b"".join(central))
    out.write(struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, len(central), len(central), out.tell() - start, start, 0))
    path.write_bytes(out.getvalue())
    return path


# ---- a small valid CSM and its variants ------------------------------------------------------------------------------

PARAMS = {"kind": "latlong", "n1": 2, "n2": 2, "resolution": 1, "center": [0.0, 0.0, 0.0], "radius": 1.0,
          "enumeration": "scanline", "depth_layers": "z1z2", "far": "infinite", "num_segments": 2}


def _members(params: dict | str | None = None, **arrays) -> dict[str, tuple]:
    """The entries of a 2 x 2 lat-long CSM of one texel (two segments), ``arrays`` (name: entry tuple or array)
    replacing its arrays; ``params`` a dict merged into the valid one or raw JSON text."""
    text = params if isinstance(params, str) else json.dumps({**PARAMS, **(params or {})})
    out = {
        "format_version.npy": _stored(_npy(np.array(1, np.int64))),
        "params.npy": _stored(_npy(np.array(text))),
        "map_index.npy": _stored(_npy(np.asfortranarray(np.array([[0, 1], [2, 3]], np.int32)))),
        "seg_start.npy": _stored(_npy(np.array([0, 2], np.int32))),
        "seg_depth.npy": _stored(_npy(np.array([0.5, np.inf], np.float32))),
        "seg_end.npy": _stored(_npy(np.array([1, 3], np.int32))),
    }
    for key, value in arrays.items():
        out[f"{key}.npy"] = value if isinstance(value, tuple) else _stored(_npy(value))
    return out


def _csm(path: Path, params=None, extra: dict | None = None, **arrays) -> Path:
    return _write_zip(path, list({**_members(params, **arrays), **(extra or {})}.items()))


def _refused(path: Path, *fragments: str) -> str:
    with pytest.raises(CSMFileError) as info:
        load_csm(path)
    message = str(info.value)
    assert isinstance(info.value, InputFileError) and info.value.exit_code == 2
    assert str(path) in message and len(message) < 600, message
    for fragment in fragments:
        assert fragment in message, message
    return message


def test_the_hand_written_csm_loads(tmp_path):
    csm = load_csm(_csm(tmp_path / "ok.npz"))
    assert (csm.n1, csm.n2, csm.num_segments) == (2, 2, 2)
    assert np.array_equal(csm.map_index, [[0, 1], [2, 3]])  # written in Fortran order, read back right
    assert csm.lists.seg_depth.dtype == np.float32 and csm.lists.seg_end.tolist() == [1, 3]


# ---- zip bombs: refused from the directory and headers, before inflating ---------------------------------------------


@pytest.fixture(scope="module")
def bombs(tmp_path_factory):
    """Two 3.9 MB CSM files of deflated zeros that inflate to 4e9 bytes (under MAX_CSM_BYTES): ``issue``, the one
    of issue #52 (one array of 1e9 float32 zeros, params of a tiny CSM), and ``consistent``, whose params describe
    exactly the arrays it holds (256 x 256 maps of 128^2 texels, 5e8 segments)."""
    folder = tmp_path_factory.mktemp("bombs")
    issue = _csm(folder / "issue.npz", seg_depth=_deflate_member(_npy_header((1_000_000_000,)), 4_000_000_000))
    n, m, s = 256, 128, 500_000_000
    consistent = _csm(
        folder / "consistent.npz", {"n1": n, "n2": n, "resolution": m, "num_segments": s},
        map_index=_deflated(_npy(np.arange(n * n, dtype=np.int32).reshape(n, n))),
        seg_start=_deflated(_npy(np.arange(m * m + 1, dtype=np.int32) * (s // (m * m)))),
        seg_depth=_deflate_member(_npy_header((s,)), 4 * s),
        seg_end=_deflate_member(_npy_header((s,), "<i4"), 4 * s),
    )
    return {"issue": issue, "consistent": consistent}


def _deflate_member(header: bytes, n: int) -> tuple[int, bytes, int, int]:
    stream, crc, size = _deflated_zeros(header, n)
    return 8, stream, crc, size


_CHILD = textwrap.dedent(f"""
    import json, resource, sys, time
    resource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, 3 * 2**30))  # a failing build dies here, not the machine
    from warpscatter.csm.files import CSMFileError, load_csm
    t0 = time.perf_counter()
    try:
        load_csm(sys.argv[1])
        message = "accepted"
    except CSMFileError as exc:
        message = str(exc)
    seconds = time.perf_counter() - t0
    print(json.dumps({{"message": message, "seconds": seconds,
                      "max_rss": {PEAK_BYTES}}}))
""")


@pytest.mark.parametrize("which", ["issue", "consistent"])
def test_a_csm_zip_bomb_is_refused_in_seconds_and_little_memory(bombs, which):
    path = bombs[which]
    assert path.stat().st_size < 4.5e6
    run = subprocess.run([sys.executable, "-c", _CHILD, str(path)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]  # before: MemoryError at the 3 GiB limit (8.1 GB without it)
    result = json.loads(run.stdout.strip().splitlines()[-1])
    assert str(path) in result["message"] and "inflates" in result["message"], result
    assert result["max_rss"] < 2**30 and result["seconds"] < 10, result


def test_cli_render_with_the_bomb_exits_2_naming_the_key_and_file(bombs, tmp_path):
    args = ["render", str(GATE), "-q", "-o", str(tmp_path / "out")]
    for item in [*SMALL, f"render.lighting.csm.file={bombs['issue']}"]:
        args += ["--set", item]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2, result.output
    assert "render.lighting.csm.file" in result.output and str(bombs["issue"]) in result.output
    assert "inflates" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "out").exists()


def test_arrays_the_params_do_not_describe_are_refused_before_their_data_is_read(tmp_path):
    path = _csm(tmp_path / "long.npz", seg_depth=np.zeros(4_000_000, np.float32))  # 16 MB where params say 2
    tracemalloc.start()
    try:
        _refused(path, "seg_depth has shape (4000000,)", "expected (2,)")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2**20, f"{peak} bytes"  # before: the 16 MB were read


def test_a_npy_header_declaring_gigabytes_of_header_is_not_read(tmp_path):
    # a version-2 header may declare up to 4 GiB of header text; numpy reads it whole before its size check
    body = b"\x93NUMPY\x02\x00" + struct.pack("<I", 2**31) + b" " * (900_000)
    path = _csm(tmp_path / "header.npz", seg_depth=_deflated(body))
    tracemalloc.start()
    try:
        _refused(path, "array 'seg_depth' has no valid .npy header", "a header of 2147483648 bytes")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2**19, f"{peak} bytes"  # before: the 900 kB of header read (and decoded)


def test_entries_other_than_the_arrays_are_never_read(tmp_path):
    # np.load lists an entry named "seg_depth" (no .npy) as array seg_depth too, and reads it whole as bytes
    path = _csm(tmp_path / "extra.npz", extra={"seg_depth": _stored(bytes(16 * 2**20))})
    tracemalloc.start()
    try:
        csm = load_csm(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert csm.num_segments == 2 and peak < 2**20, f"{peak} bytes"


def test_an_array_stored_twice_is_refused(tmp_path):
    path = _write_zip(tmp_path / "twice.npz", [*_members().items(), ("seg_end.npy", _stored(_npy(np.zeros(2))))])
    _refused(path, "holds array 'seg_end' twice")


# ---- malformed .npy headers ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("header, reason", [
    (_raw_header("{'descr': '<f4', 'fortran_order': False, 'shape': " + "(" * 3000 + ")" * 3000 + ", }"),
     "has no valid .npy header"),
    (_raw_header("{'descr': '<f4', 'fortran_order': False, 'shape': (-2, -1), }") + bytes(8),
     "declares a negative dimension"),
    (_raw_header("{'descr': '<f4', 'fortran_order': False, 'shape': (1e400,), }"), "has no valid .npy header"),
    (_raw_header("{'descr': '<f4', 'fortran_order': False, 'shape': (2,), }", version=9), "format version (9, 0)"),
    (_raw_header("{'descr': '<f4', 'fortran_order': False, 'shape': (2,), 'x': __import__('os')}"),
     "has no valid .npy header"),
    (b"\x93NUM", "has no valid .npy header"),
    (_raw_header("{'descr': 'O', 'fortran_order': False, 'shape': (2,), }") + bytes(16), "Python objects"),
], ids=["nested", "negative", "inf", "version", "call", "truncated", "objects"])
@pytest.mark.parametrize("array", ["params", "seg_depth"])
def test_malformed_npy_headers_are_refused_naming_the_array(tmp_path, header, reason, array):
    path = _csm(tmp_path / "header.npz", extra={f"{array}.npy": _stored(header)})
    _refused(path, f"array {array!r}", reason)


# ---- params ----------------------------------------------------------------------------------------------------------


def _params_text(**fields) -> str:
    return json.dumps({**PARAMS, **fields})


@pytest.mark.parametrize("text, reason", [
    ("[" * 100_000 + "]" * 100_000, "params is not valid JSON (nested too deeply)"),
    (_params_text()[:-1] + ', "x": ' + "[" * 50_000 + "]" * 50_000 + "}", "nested too deeply"),
    (_params_text().replace('"n1": 2', '"n1": 1e400'), "params n1 = inf is not an integer in [1, 1048576]"),
    (_params_text(n1=2.5), "params n1 = 2.5 is not an integer"),
    (_params_text(n2=True), "params n2 = True is not an integer"),
    (_params_text(num_segments=10**30), "params num_segments = 1000000000000000000000000000000 is not an integer"),
    (_params_text(n1=1024, n2=2048), "params hold 1024 x 2048 cells, more than 1048576"),
    (_params_text(num_segments=5), "params hold impossible sizes (5 segments for 4 maps of 1 texels"),
    (_params_text(radius=1e308), "beyond 1e+18"),
    (_params_text(center=[1e300, 0.0, 0.0]), "beyond 1e+18"),
    (_params_text(radius=10**400), "non-finite centre or a radius <= 0"),
    (_params_text(center="origin"), "params center = 'origin' is not 3 numbers"),
    (_params_text(kind=["latlong"] * 10_000), "unknown CSM kind"),
    (_params_text(enumeration=["hilbert"]), "params enumeration = ['hilbert'] is not one of"),
    (_params_text(geometry=[1, 2]), "params geometry = [1, 2] is not a digest string"),
    ("\udcff", "params is not valid JSON"),
])
def test_bad_params_are_refused_naming_the_file_and_field(tmp_path, text, reason):
    _refused(_csm(tmp_path / "params.npz", text), reason)


def test_params_that_are_not_one_short_string_are_refused(tmp_path):
    path = _csm(tmp_path / "long.npz", extra={"params.npy": _stored(_npy(np.array("x" * 300_000)))})
    _refused(path, "params is not one JSON string of at most 1048576 bytes")


# ---- depths ----------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("depth, reason", [
    (np.array([-0.5, np.inf], np.float32), "negative depths"),
    (np.array([0.5, -np.inf], np.float32), "-inf"),
    (np.array([1e300, np.inf], np.float64), "beyond float32's range"),
])
def test_negative_or_unrepresentable_depths_are_refused(tmp_path, depth, reason):
    _refused(_csm(tmp_path / "depth.npz", seg_depth=depth), reason)


def test_a_sphere_that_does_not_enclose_the_occluders_is_refused(tmp_path):
    v = np.array([[0, 0, 0], [4, 0, 0], [0, 4, 0]], np.float32)
    t = np.array([[0, 1, 2]], np.int32)
    light = SimpleNamespace(kind="environment")
    good = load_csm(_csm(tmp_path / "ok.npz", {"geometry": geometry_digest(v, t), "center": [2, 2, 0], "radius": 3}))
    check_csm_for_scene(good, light, v, t, where="ok.npz")
    small = load_csm(_csm(tmp_path / "small.npz", {"geometry": geometry_digest(v, t), "radius": 1.0}))
    with pytest.raises(CSMFileError, match=r"small\.npz: its bounding sphere .* does not enclose"):
        check_csm_for_scene(small, light, v, t, where="small.npz")


@pytest.mark.parametrize("params, arrays, reason", [
    ("[" * 100_000 + "]" * 100_000, {}, "nested too deeply"),
    (_params_text(radius=1e308), {}, "beyond 1e+18"),
    (None, {"seg_depth": np.array([-0.5, np.inf], np.float32)}, "negative depths"),
])
def test_cli_render_refuses_bad_csm_files_with_exit_2(tmp_path, params, arrays, reason):
    path = _csm(tmp_path / "bad.npz", params, **arrays)
    args = ["render", str(GATE), "-q", "-o", str(tmp_path / "out")]
    for item in [*SMALL, f"render.lighting.csm.file={path}"]:
        args += ["--set", item]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2, result.output
    assert f"render.lighting.csm.file: {path}" in result.output and reason in result.output, result.output
    assert "Traceback" not in result.output and not (tmp_path / "out").exists()
