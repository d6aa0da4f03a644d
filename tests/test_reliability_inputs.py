"""Bad input files and documents are refused up front, as user errors (issue 17, items 4-6): YAML alias bombs and keys
that cannot be config keys, files declaring huge sizes (CSM .npz, meshes), garbage meshes, and meshes, light textures
and environment maps holding NaN, infinite or negative values: exit code 2 naming the key and the file, nothing
written."""

import io
import json
import struct
import subprocess
import sys
import textwrap
import tracemalloc
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from data_files import raw_exr

from warpscatter.cli.main import main
from warpscatter.config import MAX_YAML_NODES, load_config, parse_override
from warpscatter.errors import ConfigError, InputFileError
from warpscatter.scene import meshes
from warpscatter.scene.meshes import MeshLoadError, load_mesh

ROOT = Path(__file__).resolve().parents[1]

# ---- YAML: alias bombs ----------------------------------------------------------------------------------------------


def laughs(indent: str = "", levels: int = 9) -> str:
    """The "billion laughs" document as YAML mappings: level k is a list of ten aliases of level k - 1 (10^9 nodes
    once expanded, a few hundred bytes as text)."""
    lines = [f"{indent}lol0: &lol0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    lines += [f"{indent}lol{k}: &lol{k} [{', '.join([f'*lol{k - 1}'] * 10)}]" for k in range(1, levels + 1)]
    return "\n".join(lines) + "\n"


BASE = {
    "scene": {"meshes": [{"procedural": "ground_plane", "params": {"size": 10}}]},
    "camera": {"position": [0, 1, 5], "look_at": [0, 0, 0], "width": 16, "height": 9},
    "light": {"type": "directional", "direction": [0, -1, 0]},
    "medium": {"sigma_t": 0.1},
    "render": {"scattering": {"steps": 4}},
    "output": {"dir": "out", "name": "shot"},
}


def bomb_configs(folder: Path) -> dict:
    """Config files with the bomb at the top level, inside ``camera`` and inside a generator's ``params``; the
    fourth case carries it in a ``--set`` value."""
    base = yaml.safe_dump(BASE, sort_keys=False)
    camera = base.replace("camera:\n", "camera:\n" + laughs("  "), 1)
    params = base.replace("    params:\n", "    params:\n" + laughs("      "), 1)
    files = {"top": base + laughs(), "camera": camera, "params": params, "set": base}
    out = {}
    for name, text in files.items():
        (folder / f"{name}.yaml").write_text(text)
        out[name] = str(folder / f"{name}.yaml")
    flow = "{" + ", ".join(laughs().splitlines()) + "}"
    return {"files": out, "set": f"camera.lol={flow}"}


_CHILD = textwrap.dedent("""
    import json, resource, sys, time
    resource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, 3 * 2**30))  # a regression must not take the machine down
    from warpscatter.config import load_config
    from warpscatter.errors import ConfigError
    cases = json.loads(sys.argv[1])
    out = {}
    for name, path in cases["files"].items():
        sets = [cases["set"]] if name == "set" else []
        t = time.perf_counter()
        try:
            load_config(path, sets)
            out[name] = ["loaded", time.perf_counter() - t]
        except ConfigError as exc:
            out[name] = ["ConfigError", time.perf_counter() - t, str(exc)]
        except BaseException as exc:
            out[name] = [type(exc).__name__, time.perf_counter() - t, str(exc)[:300]]
        print(json.dumps({name: out[name]}), flush=True)
""")


def test_alias_bombs_are_refused_quickly(tmp_path):
    # In a child process (memory capped, time-limited): before the fix the top-level bomb hung and the nested ones
    # ended in MemoryError after 30-40 s.
    cases = bomb_configs(tmp_path)
    try:
        proc = subprocess.run([sys.executable, "-c", _CHILD, json.dumps(cases)], capture_output=True, text=True,
                              timeout=60, cwd=tmp_path)
        lines = proc.stdout.splitlines()
    except subprocess.TimeoutExpired as exc:
        lines = (exc.stdout or b"").decode().splitlines() if isinstance(exc.stdout, bytes) else []
    results = {k: v for line in lines for k, v in json.loads(line).items()}
    assert sorted(results) == ["camera", "params", "set", "top"], f"child results: {results}"
    for name, (outcome, seconds, *message) in results.items():
        assert outcome == "ConfigError", (name, outcome, message)
        assert seconds < 1.0, (name, seconds)
        text = message[0]
        assert f"more than {MAX_YAML_NODES} nodes" in text, (name, text)
        if name == "set":
            assert text.startswith(f"{cases['files']['set']}:") and "--set camera.lol=" in text
        else:
            assert text.startswith(f"{cases['files'][name]}:") and "line " in text  # the file and the line


def test_aliases_that_share_data_still_work(tmp_path):
    # Aliases are for sharing: a material used by two meshes, within the node budget.
    config = dict(BASE)
    text = yaml.safe_dump(config, sort_keys=False).replace(
        "  - procedural: ground_plane\n    params:\n      size: 10\n",
        "  - procedural: ground_plane\n    params:\n      size: 10\n    material: &stone {albedo: [0.5, 0.4, 0.3]}\n"
        "  - procedural: colonnade\n    material: *stone\n", 1)
    path = tmp_path / "shared.yaml"
    path.write_text(text)
    cfg = load_config(path)
    assert [m.material.albedo for m in cfg.scene.meshes] == [(0.5, 0.4, 0.3)] * 2


def test_recursive_aliases_are_refused(tmp_path):
    path = tmp_path / "loop.yaml"
    path.write_text(yaml.safe_dump(BASE, sort_keys=False) + "loop: &me [1, *me]\n")
    with pytest.raises(ConfigError, match=r"line \d+.*alias \*me is inside the node it refers to") as info:
        load_config(path)
    assert str(path) in str(info.value)


# ---- YAML: keys that cannot be config keys --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("where", "key_path"),
    [("top", r"\[key\]"), ("camera", r"camera\.\[key\]"), ("params", r"scene\.meshes\.0\.params\.\[key\]")],
)
@pytest.mark.parametrize("key", ["[1, 2]", "{a: 1}"])
def test_collection_keys_name_their_key_path(tmp_path, where, key_path, key):
    base = yaml.safe_dump(BASE, sort_keys=False)
    text = {"top": f"{{{key}: 3}}\n",
            "camera": base.replace("camera:\n", f"camera:\n  ? {key}\n  : 3\n", 1),
            "params": base.replace("    params:\n", f"    params:\n      ? {key}\n      : 3\n", 1)}[where]
    path = tmp_path / "keys.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:  # before: TypeError: unhashable type
        load_config(path)
    message = str(info.value)
    assert message.startswith(f"{path}:")
    kind = "list" if key.startswith("[") else "mapping"
    assert __import__("re").search(key_path + rf": a key must be a name, not a {kind} \(line \d+\)", message), message


@pytest.mark.parametrize("key", ["1", "null", "true", "1.5"])
def test_top_level_keys_must_be_section_names(tmp_path, key):
    path = tmp_path / "keys.yaml"
    text = yaml.safe_dump(BASE, sort_keys=False)
    path.write_text(text + f"{key}: x\n")
    line = len(text.splitlines()) + 1
    with pytest.raises(ConfigError, match=rf"{key}: a top-level key must be a section name \(a string\), got {key} "
                                          rf"\(line {line}\)"):  # before: "1: Keys should be strings"
        load_config(path)


def test_overrides_go_through_the_same_loader(tmp_path):
    path = tmp_path / "ok.yaml"
    path.write_text(yaml.safe_dump(BASE, sort_keys=False))
    with pytest.raises(ConfigError, match=r"--set camera=\{\[1, 2\]: 3\}: camera\.\[key\]: a key must be a name"):
        load_config(path, ["camera={[1, 2]: 3}"])
    with pytest.raises(ValueError, match="duplicate key"):
        parse_override("camera={a: 1, a: 2}")
    assert parse_override("animation.keys.camera.fov_y={1: 30, 24: 60}")[1] == {1: 30, 24: 60}  # keyframes


def test_cli_reports_a_bad_key_as_a_config_error(tmp_path):
    path = tmp_path / "keys.yaml"
    path.write_text(yaml.safe_dump(BASE, sort_keys=False).replace("camera:\n", "camera:\n  ? [1, 2]\n  : 3\n", 1))
    result = CliRunner().invoke(main, ["render", str(path), "-q"])
    assert result.exit_code == 2, result.output
    assert "camera.[key]: a key must be a name, not a list" in result.stderr


# ---- CSM files declaring huge arrays --------------------------------------------------------------------------------


def _npy(array: np.ndarray | None = None, *, descr: str = "<f4", shape=None, data: bytes = b"") -> bytes:
    """A .npy file: ``array``, or a header declaring ``shape`` of ``descr`` followed by ``data``."""
    buf = io.BytesIO()
    if array is not None:
        np.lib.format.write_array(buf, np.asarray(array), allow_pickle=False)
    else:
        np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False, "shape": shape})
        buf.write(data)
    return buf.getvalue()


def _csm_npz(path: Path, seg_depth: bytes, compress: int = zipfile.ZIP_STORED) -> Path:
    params = {"kind": "latlong", "n1": 2, "n2": 1, "resolution": 1, "center": [0, 0, 0], "radius": 1.0,
              "enumeration": "scanline", "depth_layers": "z1z2", "far": "infinite", "num_segments": 1}
    with zipfile.ZipFile(path, "w", compression=compress) as zf:
        zf.writestr("format_version.npy", _npy(np.array(1, np.int64)))
        zf.writestr("params.npy", _npy(np.array(json.dumps(params))))
        zf.writestr("map_index.npy", _npy(np.array([[0, 1]], np.int32)))
        zf.writestr("seg_start.npy", _npy(np.array([0, 1], np.int32)))
        zf.writestr("seg_depth.npy", seg_depth)
        zf.writestr("seg_end.npy", _npy(np.array([1], np.int32)))
    return path


def test_csm_declaring_a_huge_array_is_refused_before_allocating(tmp_path):
    from warpscatter.csm.files import CSMFileError, load_csm

    path = _csm_npz(tmp_path / "huge.npz", _npy(shape=(1_500_000_000,), data=b"\0" * 16))  # 5.6 GiB declared
    tracemalloc.start()
    try:
        with pytest.raises(CSMFileError) as info:
            load_csm(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 64 * 2**20, f"{peak / 2**30:.2f} GiB allocated"  # before: the declared 5.6 GiB
    message = str(info.value)
    assert str(path) in message and "seg_depth" in message and "(1500000000,)" in message
    assert isinstance(info.value, InputFileError) and info.value.exit_code == 2


def test_csm_beyond_the_size_limit_is_refused(tmp_path, monkeypatch):
    from warpscatter.csm import files

    path = _csm_npz(tmp_path / "big.npz", _npy(np.zeros(1000, np.float32)), compress=zipfile.ZIP_DEFLATED)
    monkeypatch.setattr(files, "MAX_CSM_BYTES", 2000)
    with pytest.raises(files.CSMFileError, match=r"big\.npz: the arrays hold more than 2000 bytes .*seg_depth"):
        files.load_csm(path)


def test_csm_zip_entry_declaring_more_than_the_file_is_refused(tmp_path):
    from warpscatter.csm.files import CSMFileError, load_csm

    path = _csm_npz(tmp_path / "lying.npz", _npy(np.zeros(4, np.float32)))
    raw = bytearray(path.read_bytes())
    # the central directory's uncompressed size of seg_depth.npy, made 2^31 (the local header is not used for it)
    at = raw.rindex(b"seg_depth.npy") - 46
    assert raw[at:at + 4] == b"PK\x01\x02"
    struct.pack_into("<I", raw, at + 24, 2**31)
    path.write_bytes(bytes(raw))
    with pytest.raises(CSMFileError, match=r"lying\.npz: array 'seg_depth': its zip entry declares 2147483648 bytes"):
        load_csm(path)


# ---- mesh files ----------------------------------------------------------------------------------------------------

GARBAGE = bytes(range(256)) * 40


@pytest.mark.parametrize("ext", ["obj", "off", "gltf", "stl", "ply", "glb"])
def test_garbage_mesh_files_fail_naming_the_file(tmp_path, ext):
    path = tmp_path / f"garbage.{ext}"
    path.write_bytes(GARBAGE)
    with pytest.raises(MeshLoadError) as info:
        load_mesh(path)
    message = str(info.value)
    assert "charset_normalizer" not in message and "ModuleNotFoundError" not in message  # before: both
    assert repr(str(path)) in message
    if ext in ("obj", "off", "gltf"):
        assert f"cannot be parsed as {ext.upper()} (binary data" in message
    assert isinstance(info.value, InputFileError) and info.value.exit_code == 2


def test_text_mesh_files_that_are_not_utf8_load(tmp_path):
    obj = tmp_path / "latin1.obj"
    obj.write_bytes("# caf\xe9 cr\xe8me\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".encode("latin-1"))
    assert load_mesh(obj).num_triangles == 1
    # a binary STL whose free-text header is not UTF-8 (before: charset_normalizer)
    stl = tmp_path / "header.stl"
    triangle = np.array([[0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0]], np.float32).tobytes() + b"\0\0"
    stl.write_bytes("COLOR=\xff\xfe caf\xe9".encode("latin-1").ljust(80, b"\xff") + struct.pack("<I", 1) + triangle)
    assert load_mesh(stl).num_triangles == 1


def test_mesh_files_beyond_the_size_limit_are_refused(tmp_path, monkeypatch):
    path = tmp_path / "big.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n" * 10)
    monkeypatch.setattr(meshes, "MAX_MESH_FILE_BYTES", 100)
    with pytest.raises(MeshLoadError, match=r"big\.obj': the file has 320 bytes, more than the 100 a mesh file may "
                                            r"have \(warpscatter\.scene\.meshes\.MAX_MESH_FILE_BYTES\)"):
        load_mesh(path)


# ---- through the CLI: exit code 2, the key and the file named, nothing written --------------------------------------



def _render(tmp_path: Path, **changes):
    config = json.loads(json.dumps(BASE))
    for key, value in changes.items():
        section, _, rest = key.partition(".")
        if rest:
            config[section][rest] = value
        else:
            config[section] = value
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return CliRunner().invoke(main, ["render", str(path), "-q"])


def _outputs(tmp_path: Path) -> list[str]:
    out = tmp_path / "out"
    return sorted(p.name for p in out.iterdir()) if out.exists() else []


MESHES = {
    "empty.obj": (b"", "the file is empty"),
    "garbage.obj": (GARBAGE, "cannot be parsed as OBJ"),
    "nan.obj": (b"v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n", "object 0 is invalid (vertices must be finite"),
}


@pytest.mark.parametrize("name", list(MESHES))
def test_cli_bad_mesh_file_is_a_user_error(tmp_path, name):
    content, reason = MESHES[name]
    (tmp_path / name).write_bytes(content)
    ground = BASE["scene"]["meshes"][0]
    result = _render(tmp_path, scene={"meshes": [ground, {"path": name}]})
    assert result.exit_code == 2, result.output  # before: 1
    assert f"scene.meshes.1.path: mesh file {str(tmp_path / name)!r}: {reason}" in result.stderr, result.stderr
    assert _outputs(tmp_path) == []


SPOT = {"type": "spot", "position": [0, 3, 0], "direction": [0, -1, 0], "cone_deg": 30, "intensity": [1, 1, 1]}


@pytest.mark.parametrize(("value", "what"), [(-1.0, "negative"), (np.inf, "non-finite"), (np.nan, "non-finite")])
def test_cli_light_texture_that_is_not_radiance_is_a_user_error(tmp_path, value, what):
    pixels = np.ones((4, 6, 3), np.float32)
    pixels[1, 2, 0] = value
    texture = raw_exr(tmp_path / "cookie.exr", pixels)
    result = _render(tmp_path, light={**SPOT, "texture": "cookie.exr"})
    assert result.exit_code == 2, result.output  # before: 0 (negative radiance) or 1 ("a bug")
    assert f"light.texture: {texture}: 1 {what}" in result.stderr and "row 1, column 2, channel 0" in result.stderr
    assert _outputs(tmp_path) == []


def test_cli_unreadable_light_texture_is_a_user_error(tmp_path):
    (tmp_path / "cookie.exr").write_bytes(GARBAGE)
    result = _render(tmp_path, light={**SPOT, "texture": "cookie.exr"})
    assert result.exit_code == 2, result.output  # before: 1
    assert f"light.texture: cannot read {tmp_path / 'cookie.exr'}" in result.stderr, result.stderr
    assert _outputs(tmp_path) == []


@pytest.mark.parametrize(("value", "what"), [(np.nan, "non-finite"), (-0.5, "negative")])
def test_cli_environment_map_that_is_not_radiance_is_a_user_error(tmp_path, value, what):
    pixels = np.ones((8, 16, 3), np.float32)
    pixels[2, 3, 1] = value
    sky = raw_exr(tmp_path / "sky.exr", pixels)
    result = _render(tmp_path, light={"type": "environment", "map": "sky.exr"}, medium={"sigma_t": 0.0},
                     render={"lighting": {"method": "raytrace", "samples": 1, "passes": 1}})
    assert result.exit_code == 2, result.output
    assert f"light.map: {sky}: 1 {what}" in result.stderr, result.stderr  # before: no file named in the key
    assert _outputs(tmp_path) == []


def test_light_texture_grey_and_alpha_is_read_as_grey(tmp_path):
    from warpscatter.io.images import read_radiance_image

    pixels = np.stack([np.full((2, 3), 0.25, np.float32), np.full((2, 3), -7.0, np.float32)], axis=2)  # alpha < 0
    tex = read_radiance_image(raw_exr(tmp_path / "ga.exr", pixels), key="light.texture")
    assert tex.shape == (2, 3, 3) and np.all(tex == 0.25)
