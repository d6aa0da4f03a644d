"""Scene inputs that broke the exit-2 contract or memory (issue 52, items 1 and 4): YAML nested hundreds of levels
deep, light textures and environment maps holding 3e38 (or too large to decode), mesh vertices at 1e30 and
truncated meshes. Each is refused up front as a user error: exit code 2, the key and the file named, nothing
written."""

import json
import struct
import subprocess
import sys
import textwrap
import time
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from data_files import raw_exr
from peak_memory import PEAK_BYTES

from warpscatter.cli.main import main
from warpscatter.config import load_config, parse_override
from warpscatter.config.files import MAX_YAML_DEPTH, read_config_data
from warpscatter.errors import ConfigError, InputFileError
from warpscatter.scene import light_configs
from warpscatter.scene.environment_map import MAX_TEXEL_RADIANCE, EnvironmentMap
from warpscatter.scene.lights import AreaLight, SpotLight
from warpscatter.scene.meshes import MAX_MESH_COORD, MeshLoadError, TriangleMesh, apply_transform, load_mesh

BASE = {
    "scene": {"meshes": [{"procedural": "ground_plane", "params": {"size": 10}}]},
    "camera": {"position": [0, 1, 5], "look_at": [0, 0, 0], "width": 16, "height": 9},
    "light": {"type": "directional", "direction": [0, -1, 0]},
    "medium": {"sigma_t": 0.1},
    "render": {"scattering": {"steps": 4}},
    "output": {"dir": "out", "name": "shot"},
}
SPOT = {"type": "spot", "position": [0, 3, 0], "direction": [0, -1, 0], "cone_deg": 30, "intensity": [1, 1, 1]}
ENVIRONMENT = {"light": {"type": "environment", "map": "sky.exr"}, "medium": {"sigma_t": 0.0},
               "render": {"lighting": {"method": "raytrace", "samples": 1, "passes": 1}}}


def _config(tmp_path: Path, **sections) -> Path:
    config = json.loads(json.dumps(BASE))
    config.update(sections)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def _render(tmp_path: Path, *args, **sections):
    return CliRunner().invoke(main, ["render", str(_config(tmp_path, **sections)), "-q", *args])


def _outputs(tmp_path: Path) -> list[str]:
    out = tmp_path / "out"
    return sorted(p.name for p in out.iterdir()) if out.exists() else []



def _chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)


def zero_png(width: int, height: int, rows_per_block: int = 100) -> bytes:
    """A valid 8-bit RGB PNG of zeros, built fast: one deflated block of ``rows_per_block`` rows (ended by a full
    flush, so it refers to nothing before it) repeated; 20000 x 20000 is 1.1 MB that decodes to 1.2 GB of bytes."""
    assert height % rows_per_block == 0
    c = zlib.compressobj(9, zlib.DEFLATED, -15)
    block = c.compress(b"\0" * ((1 + 3 * width) * rows_per_block)) + c.flush(zlib.Z_FULL_FLUSH)
    n = (1 + 3 * width) * height  # the adler32 of n zero bytes: a = 1, b = n
    stream = b"\x78\xda" + block * (height // rows_per_block) + b"\x03\x00" + struct.pack(">I", ((n % 65521) << 16) | 1)
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + _chunk(b"IDAT", stream) + _chunk(b"IEND", b""))


# ---- YAML nested hundreds of levels deep ---------------------------------------------------------------------------


def _deep_flow(depth: int) -> str:
    return "[" * depth + "]" * depth


def _deep_block(depth: int) -> str:
    return "".join("  " * i + f"k{i}:\n" for i in range(1, depth)) + "  " * depth + "x: 1\n"


@pytest.mark.parametrize("form", ["flow", "block"])
def test_deeply_nested_yaml_is_a_config_error(tmp_path, form):
    text = f"camera: {_deep_flow(600)}\n" if form == "flow" else "camera:\n" + _deep_block(600)
    path = tmp_path / "deep.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:  # before: RecursionError
        read_config_data(path)
    assert info.value.source == path and f"more than {MAX_YAML_DEPTH} levels deep" in str(info.value)
    result = CliRunner().invoke(main, ["validate", str(path)])
    assert result.exit_code == 2, result.output
    assert "levels deep" in result.stderr and "Traceback" not in result.output


def test_deeply_nested_override_is_a_config_error(tmp_path):
    path = _config(tmp_path)
    with pytest.raises(ConfigError, match="levels deep"):  # before: RecursionError
        load_config(path, [f"camera.width={_deep_flow(600)}"])
    assert parse_override(f"a={_deep_flow(MAX_YAML_DEPTH)}")[1] is not None  # at the bound: read


# ---- light textures and environment maps: values -------------------------------------------------------------------


@pytest.mark.parametrize("value", [3e38, 1e7])
def test_light_texture_too_bright_is_a_user_error(tmp_path, value):
    pixels = np.ones((4, 6, 3), np.float32)
    pixels[1, 2, 0] = value
    texture = raw_exr(tmp_path / "cookie.exr", pixels)
    result = _render(tmp_path, light={**SPOT, "texture": "cookie.exr"})
    assert result.exit_code == 2, result.output  # before: 1 ("a bug: please report it") or rendered
    assert f"light.texture: {texture}: 1 value(s) above 1e+06" in result.stderr, result.stderr
    assert "row 1, column 2, channel 0" in result.stderr
    assert _outputs(tmp_path) == []


def test_environment_map_too_bright_is_a_user_error(tmp_path):
    pixels = np.ones((8, 16, 3), np.float32)
    pixels[2, 3, 1] = 3e38
    sky = raw_exr(tmp_path / "sky.exr", pixels)
    result = _render(tmp_path, **ENVIRONMENT)
    assert result.exit_code == 2, result.output  # before: rendered from an overflowing map
    assert f"light.map: {sky}: 1 value(s) above 1e+06" in result.stderr, result.stderr
    assert _outputs(tmp_path) == []


def test_host_lights_refuse_texels_that_overflow_float32():
    huge = np.full((2, 2, 3), 3e38, np.float32)
    with pytest.raises(ValueError, match="at most 1e\\+12"):
        SpotLight([0, 0, 0], [0, 0, 1], 30.0, [1, 1, 1], texture=huge)  # before: accepted
    with pytest.raises(ValueError, match="above 1e\\+12"):
        EnvironmentMap(huge)
    with pytest.raises(ValueError, match="at most 1e\\+12"):
        AreaLight([0, 0, 0], [1, 0, 0], [0, 0, 1], [1, 1, 1], texture=huge)
    dark = np.zeros((4, 4, 3), np.float32)
    dark[0, 0] = 1e-30
    with pytest.raises(ValueError, match="so dark"):  # P / (pi A) / mean = 5e30: inf in float32
        AreaLight.from_power([0, 0, 0], [1, 0, 0], [0, 0, 1], [1, 1, 1], texture=dark)
    EnvironmentMap(np.full((2, 4, 3), MAX_TEXEL_RADIANCE, np.float32))  # at the bound: fine


def test_area_light_emitting_nothing_has_uniform_sampling_tables():
    texture = np.random.default_rng(1).random((4, 5, 3)).astype(np.float32)
    light = AreaLight([0, 0, 0], [1, 0, 0], [0, 0, 1], [0, 0, 0], texture=texture)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # before: RuntimeWarning: invalid value encountered in divide
        marginal, conditional, texel_pdf = light.sampling_tables()
    assert np.allclose(marginal, np.linspace(0, 1, 5)) and np.all(np.isfinite(conditional))
    assert np.allclose(texel_pdf, 1.0)


# ---- light textures and environment maps: size, from the header ---------------------------------------------------


def test_light_image_too_large_is_refused_from_its_header(tmp_path, monkeypatch):
    (tmp_path / "cookie.png").write_bytes(zero_png(300, 200))
    monkeypatch.setattr(light_configs, "MAX_LIGHT_IMAGE_PIXELS", 300 * 200 - 1)
    problem = "the image is 300 x 200 pixels (60,000), more than a light texture or environment map may have"
    with pytest.raises(ConfigError, match="light.texture: .*" + problem.replace("(", "\\(").replace(")", "\\)")):
        load_config(_config(tmp_path, light={**SPOT, "texture": "cookie.png"}))
    with pytest.raises(InputFileError, match="light.map: ") as info:
        light_configs.read_light_image(tmp_path / "cookie.png", key="light.map")
    assert info.value.path == tmp_path / "cookie.png"
    monkeypatch.setattr(light_configs, "MAX_LIGHT_IMAGE_PIXELS", 300 * 200)
    assert light_configs.read_light_image(tmp_path / "cookie.png", key="light.map").shape == (200, 300, 3)


_CHILD = textwrap.dedent("""
    import resource, sys
    resource.setrlimit(resource.RLIMIT_AS, (6 * 2**30, 6 * 2**30))  # a regression fails here, not the machine
    from warpscatter.cli.main import main
    try:
        main(sys.argv[1:])
    finally:
        print("max_rss=" + str(PEAK_BYTES), file=sys.stderr)
""").replace("PEAK_BYTES", PEAK_BYTES)


@pytest.mark.slow
@pytest.mark.parametrize("light", ["spot", "environment"])
def test_huge_png_light_image_exits_2_quickly_in_little_memory(tmp_path, light):
    """Issue 52's done-when: a 1.1 MB PNG of 20000 x 20000 zeros (23 GB once decoded and tabled) exits 2 within
    10 s using less than 1 GB."""
    name, key = ("cookie.png", "light.texture") if light == "spot" else ("sky.png", "light.map")
    (tmp_path / name).write_bytes(zero_png(20000, 20000))
    if light == "spot":
        config = _config(tmp_path, light={**SPOT, "texture": name})
    else:
        config = _config(tmp_path, **{**ENVIRONMENT, "light": {"type": "environment", "map": name}})
    t = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", _CHILD, "render", str(config), "-q"], capture_output=True, text=True,
                          timeout=120)
    wall = time.perf_counter() - t
    assert proc.returncode == 2, proc.stderr[-2000:]  # before: killed by the kernel (23 GB), or out of memory here
    assert "20000 x 20000 pixels" in proc.stderr and key in proc.stderr, proc.stderr
    rss = int(proc.stderr.rsplit("max_rss=", 1)[1])
    assert wall < 10.0 and rss < 2**30, (wall, rss)
    assert _outputs(tmp_path) == []


# ---- meshes: coordinates -------------------------------------------------------------------------------------------


def test_mesh_vertices_beyond_the_bound_are_a_user_error(tmp_path):
    (tmp_path / "far.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 1e30\nf 1 2 3\n")
    ground = BASE["scene"]["meshes"][0]
    result = _render(tmp_path, scene={"meshes": [ground, {"path": "far.obj"}]},
                     light={"type": "environment", "map": str(raw_exr(tmp_path / "sky.exr", np.ones((4, 8, 3))))},
                     medium={"sigma_t": 0.0}, render=ENVIRONMENT["render"])
    assert result.exit_code == 2, result.output  # before: 1 ("cannot normalise ...", "normals ...")
    assert f"scene.meshes.1.path: mesh file {str(tmp_path / 'far.obj')!r}" in result.stderr, result.stderr
    assert f"within +-{MAX_MESH_COORD:g}" in result.stderr and "vertex 2" in result.stderr
    assert _outputs(tmp_path) == []


def test_a_transform_placing_a_mesh_beyond_the_bound_is_a_user_error(tmp_path):
    result = _render(tmp_path, scene={"meshes": [{"procedural": "ground_plane", "params": {"size": 1e6},
                                                  "transform": {"scale": 1e3}}]})
    assert result.exit_code == 2, result.output  # before: rendered with a plane of 1e9 units
    assert "scene.meshes.0: the mesh placed by its transform" in result.stderr, result.stderr
    assert _outputs(tmp_path) == []


def test_mesh_coordinates_at_the_bound_are_accepted():
    tri = np.array([[0, 1, 2]])
    TriangleMesh(np.array([[0, 0, 0], [MAX_MESH_COORD, 0, 0], [0, 0, -MAX_MESH_COORD]]), tri)
    with pytest.raises(ValueError, match="within"):
        TriangleMesh(np.array([[0, 0, 0], [1e9, 0, 0], [0, 0, 1]]), tri)
    mesh = TriangleMesh(np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1]]), tri)
    with pytest.raises(InputFileError, match="placed by its transform"):
        apply_transform(mesh, np.diag([1e9, 1.0, 1.0, 1.0]))


# ---- meshes: truncated files ---------------------------------------------------------------------------------------


PLY_HEADER = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
              "element face {faces}\nproperty list uchar int vertex_indices\nend_header\n")
TRUNCATED = {
    "faces.ply": (PLY_HEADER.format(faces=5_000_000) + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
                  "truncated: its header declares 3 'vertex' and 5,000,000 'face' elements (5,000,003 lines of data) "
                  "but 4 line(s) of data follow"),
    "short.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2\n",
                  "line 5: a face with fewer than 3 vertices ('f 1 2')"),
    "faces.off": ("OFF\n3 2 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
                  "truncated: its header declares 3 vertices and 2 faces (5 lines of data) but 4 line(s)"),
    "short.off": ("OFF\n3 2 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n2 0 1\n", "face 1 ('2 0 1') has fewer than 3 vertices"),
}


@pytest.mark.parametrize("name", list(TRUNCATED))
def test_truncated_meshes_are_refused(tmp_path, name):
    text, reason = TRUNCATED[name]
    (tmp_path / name).write_text(text)
    with pytest.raises(MeshLoadError) as info:  # before: loaded with the faces present
        load_mesh(tmp_path / name)
    assert reason in str(info.value) and info.value.path == tmp_path / name


def test_complete_meshes_still_load(tmp_path):
    (tmp_path / "ok.ply").write_text(PLY_HEADER.format(faces=1) + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    (tmp_path / "ok.obj").write_text("# f 1 2\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3 4\nf 1/1 2/2 3/3\n")
    (tmp_path / "ok.off").write_text("OFF\n# a comment\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n")
    assert load_mesh(tmp_path / "ok.ply").num_triangles == 1
    assert load_mesh(tmp_path / "ok.obj").num_triangles == 3
    assert load_mesh(tmp_path / "ok.off").num_triangles == 2


def test_cli_truncated_mesh_is_a_user_error(tmp_path):
    text, reason = TRUNCATED["faces.ply"]
    (tmp_path / "faces.ply").write_text(text)
    result = _render(tmp_path, scene={"meshes": [BASE["scene"]["meshes"][0], {"path": "faces.ply"}]})
    assert result.exit_code == 2, result.output  # before: rendered the one face
    assert f"scene.meshes.1.path: mesh file {str(tmp_path / 'faces.ply')!r}: {reason}" in result.stderr
    assert _outputs(tmp_path) == []
