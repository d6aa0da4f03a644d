"""Config loading, validation, error messages and ``--set`` overrides (warpscatter.config)."""

from pathlib import Path

import pytest
import yaml

from warpscatter import config as cfgmod
from warpscatter.config import Config, ConfigError, load_config, parse_override

BASE = {
    "scene": {"meshes": [{"path": "meshes/box.obj"}]},
    "camera": {"position": [0, 1, 5], "look_at": [0, 1, 0]},
    "light": {"type": "directional", "direction": [0, -2, 0]},
}


def _merge(base: dict, patch: dict) -> dict:
    out = dict(base)
    for k, v in patch.items():
        out[k] = _merge(base[k], v) if isinstance(v, dict) and isinstance(base.get(k), dict) else v
    return out


def write(tmp_path: Path, patch: dict | None = None, text: str | None = None, name: str = "scene.yaml") -> Path:
    """Write a config (BASE merged with ``patch``, or raw ``text``) next to an (empty) mesh file."""
    (tmp_path / "meshes").mkdir(exist_ok=True)
    (tmp_path / "meshes" / "box.obj").write_text("")
    path = tmp_path / name
    path.write_text(text if text is not None else yaml.safe_dump(_merge(BASE, patch or {})))
    return path


def problems(tmp_path, patch=None, text=None, overrides=()) -> str:
    with pytest.raises(ConfigError) as info:
        load_config(write(tmp_path, patch, text), overrides)
    return str(info.value)


# ---- defaults and resolution ---------------------------------------------------------------------


def test_minimal_config_fills_defaults(tmp_path):
    c = load_config(write(tmp_path))
    assert (c.camera.width, c.camera.height, c.camera.fov_y, c.camera.near, c.camera.far) == (320, 180, 45, 0.1, 100)
    assert c.camera.up == (0.0, 1.0, 0.0)
    assert c.light.direction == (0.0, -1.0, 0.0)  # normalised on load
    assert c.light.irradiance == (1.0, 1.0, 1.0)
    assert (c.medium.sigma_t, c.medium.albedo, c.medium.phase.type) == (0.1, 1.0, "isotropic")
    assert c.render.scattering.method == "raymarch" and c.render.scattering.steps is None
    assert c.render.scattering.march_steps == 128
    assert c.render.scattering.visibility == "exact" and c.render.scattering.shadow_map.size == (1024, 1024)
    assert c.render.shadows.method == "pcf" and c.render.surfaces.enabled is True
    assert c.output.aovs == ["color", "scattering", "surface", "depth"] and c.output.name == "{config}"
    assert c.output_name == "scene"  # the file's stem


def test_relative_paths_resolve_against_config_folder(tmp_path, monkeypatch):
    sub = tmp_path / "cfg"
    sub.mkdir()
    (tmp_path / "assets").mkdir()
    (tmp_path / "assets" / "gate.obj").write_text("")
    path = write(sub, {"scene": {"meshes": [{"path": "meshes/box.obj"}, {"path": "../assets/gate.obj"}]}})
    monkeypatch.chdir(tmp_path / "assets")  # the cwd must not matter
    c = load_config(path)
    assert c.scene.meshes[0].path == (sub / "meshes" / "box.obj").resolve()
    assert c.scene.meshes[1].path == (tmp_path / "assets" / "gate.obj").resolve()
    assert c.output.dir == (sub / "out").resolve() and c.output.dir.is_absolute()
    assert c.config_dir == sub.resolve()
    assert c.source == path.resolve()


def test_absolute_mesh_path_is_kept(tmp_path):
    other = tmp_path / "elsewhere.ply"
    other.write_text("")
    c = load_config(write(tmp_path, {"scene": {"meshes": [{"path": str(other)}]}}))
    assert c.scene.meshes[0].path == other


def test_config_dir_not_in_dump_and_dump_reloads(tmp_path):
    c = load_config(write(tmp_path, {"medium": {"phase": {"type": "henyey_greenstein", "g": 0.4}}}))
    text = c.model_dump_yaml()
    data = yaml.safe_load(text)
    assert "config_dir" not in data and "source" not in data
    assert data["scene"]["meshes"][0]["path"] == str(tmp_path / "meshes" / "box.obj")
    again = Config.from_dict(data, config_dir="/nonexistent-dir")  # absolute paths need no config dir
    assert again.model_dump() == c.model_dump()


def test_from_dict_uses_given_config_dir(tmp_path):
    write(tmp_path)
    c = Config.from_dict(BASE, config_dir=tmp_path)
    assert c.scene.meshes[0].path == tmp_path / "meshes" / "box.obj"
    assert c.config_dir == tmp_path.resolve()
    with pytest.raises(ConfigError, match="scene.meshes.0.path: file not found"):
        Config.from_dict(BASE, config_dir=tmp_path / "missing")


def test_yaml_exponent_without_dot_is_a_float(tmp_path):
    c = load_config(write(tmp_path, text=write(tmp_path).read_text() + "medium: {sigma_t: 1e-3}\n"))
    assert c.medium.sigma_t == pytest.approx(1e-3)


def test_camera_and_medium_from_config(tmp_path):
    from warpscatter.scene import camera_from_config, medium_from_config

    c = load_config(write(tmp_path, {"camera": {"width": 8, "height": 4}}))
    cam = camera_from_config(c.camera)
    assert cam.ray_directions().shape == (4, 8, 3)
    assert medium_from_config(c.medium).sigma_s == pytest.approx(0.1)


def test_config_validation_does_not_import_warp():
    import subprocess
    import sys

    code = ("import sys, warpscatter.config as c; c.load_config('configs/quickstart.yaml'); "
            "sys.exit(1 if 'warp' in sys.modules else 0)")
    root = Path(__file__).resolve().parent.parent
    assert subprocess.run([sys.executable, "-c", code], cwd=root).returncode == 0


# ---- error messages ------------------------------------------------------------------------------


def test_unknown_key_names_the_key_path(tmp_path):
    msg = problems(tmp_path, {"scene": {"meshes": [{"path": "meshes/box.obj", "colour": [1, 0, 0]}]}})
    assert "scene.meshes.0.colour: unknown key" in msg


def test_unknown_key_suggests_close_name(tmp_path):
    msg = problems(tmp_path, {"camera": {"position": [0, 1, 5], "look_at": [0, 1, 0], "fovy": 30}})
    assert "camera.fovy: unknown key (did you mean 'fov_y'?)" in msg


def test_unknown_top_level_section(tmp_path):
    assert "lights: unknown key" in problems(tmp_path, {"lights": {}})


def test_wrong_types(tmp_path):
    msg = problems(tmp_path, {"camera": {"position": [0, 1, 5], "look_at": [0, 1, 0], "width": "abc", "height": 9.5}})
    assert "camera.width: expected an integer, got 'abc'" in msg
    assert "camera.height: expected an integer, got 9.5" in msg
    msg = problems(tmp_path, {"render": {"surfaces": {"enabled": 1}}, "medium": {"sigma_t": "dense"}})
    assert "render.surfaces.enabled: expected true or false" in msg
    assert "medium.sigma_t: expected a number" in msg


def test_negative_sigma_t(tmp_path):
    assert "medium.sigma_t: must be >= 0" in problems(tmp_path, {"medium": {"sigma_t": -0.5}})


def test_coloured_medium_keys(tmp_path):
    from warpscatter.scene import medium_from_config

    c = load_config(write(tmp_path, {"medium": {"sigma_t": [0.04, 0.08, 0.16], "albedo": [0.9, 0.7, 0.5]}}))
    m = medium_from_config(c.medium)
    assert c.medium.sigma_t == (0.04, 0.08, 0.16) and m.coloured
    assert m.sigma_s_rgb == pytest.approx((0.036, 0.056, 0.08)) and m.extinction == pytest.approx(0.28 / 3)
    grey = medium_from_config(load_config(write(tmp_path, {"medium": {"sigma_t": [0.1, 0.1, 0.1]}})).medium)
    assert not grey.coloured and grey.extinction == 0.1
    msg = problems(tmp_path, {"medium": {"sigma_t": [0.1, -0.2, 0.3], "albedo": [0.5, 1.5, 0.5]}})
    assert "medium.sigma_t: must be >= 0 (got [0.1, -0.2, 0.3])" in msg
    assert "medium.albedo: must be <= 1 (got [0.5, 1.5, 0.5])" in msg
    assert "medium.sigma_t: expected a number or a list of 3 numbers [r, g, b], got [1, 2]" in problems(
        tmp_path, {"medium": {"sigma_t": [1, 2]}})


def test_near_not_below_far(tmp_path):
    msg = problems(tmp_path, {"camera": {"near": 5, "far": 1.0}})
    assert "camera: near (5.0) must be < far (1.0)" in msg
    assert "camera: near (2.0) must be < far (2.0)" in problems(tmp_path, {"camera": {"near": 2, "far": 2}})


def test_degenerate_camera(tmp_path):
    assert "camera: position and look_at must differ" in problems(tmp_path, {"camera": {"look_at": [0, 1, 5]}})
    assert "parallel to the viewing direction look_at - position" in problems(tmp_path, {"camera": {"up": [0, 0, -3]}})
    assert "camera.up: must be non-zero" in problems(tmp_path, {"camera": {"up": [0, 0, 0]}})


def test_integer_bounds_are_printed_exactly(tmp_path):
    msg = problems(tmp_path, {"render": {"scattering": {"seed": 2**31}}})
    assert "render.scattering.seed: must be <= 2147483647 (got 2147483648)" in msg


@pytest.mark.parametrize("size", [(1, 1), (1, 9), (9, 1)])
def test_epipolar_needs_two_pixels_each_way_at_load_time(tmp_path, size):
    msg = problems(tmp_path, {"camera": {"width": size[0], "height": size[1]},
                              "render": {"scattering": {"method": "epipolar"}}})
    assert f"camera.width / camera.height: render.scattering.method 'epipolar' needs an image of at least 2x2 " \
           f"pixels (its lines run between two border points), got {size[0]}x{size[1]}" in msg
    epipolar = {"render": {"scattering": {"method": "epipolar"}}}
    load_config(write(tmp_path, {"camera": {"width": 2, "height": 2}, **epipolar}))
    load_config(write(tmp_path, {"camera": {"width": 1, "height": 1}}))  # the other methods render a single pixel


@pytest.mark.parametrize(
    ("patch", "expected"),
    [
        ({"fov_y": 180}, "camera.fov_y: must be <= 170"),
        ({"fov_y": 0}, "camera.fov_y: must be >= 0.01"),
        ({"width": 0}, "camera.width: must be >= 1"),
        ({"height": -4}, "camera.height: must be >= 1"),
        ({"near": 0}, "camera.near: must be > 0"),
        ({"position": [0, 1]}, "camera.position: expected a list of 3 numbers"),
        ({"position": [0, ".nan", 1]}, "camera.position: expected a list of 3 numbers"),
        ({"look_at": "origin"}, "camera.look_at: expected a list of 3 numbers"),
    ],
)
def test_camera_ranges(tmp_path, patch, expected):
    assert expected in problems(tmp_path, {"camera": patch})


def test_non_finite_vector(tmp_path):
    text = write(tmp_path).read_text().replace("- -2", "- .inf")
    assert "light.direction: must be finite" in problems(tmp_path, text=text)


def test_light_errors_have_no_union_tag_noise(tmp_path):
    msg = problems(tmp_path, {"light": {"type": "directional", "direction": [0, 0, 0], "irradiance": [1, -1, 1]}})
    assert "light.direction: must be non-zero" in msg
    assert "light.irradiance: every component must be >= 0" in msg
    assert "directional" not in msg  # pydantic's union tag is not part of the user's key path
    msg = problems(tmp_path, {"light": {"type": "sun", "direction": [0, -1, 0]}})
    assert ("light.type: unknown type 'sun' (choose from 'directional', 'spot', 'point', 'environment', 'area', "
            "'linear', 'volume')" in msg)
    msg = problems(tmp_path, {"light": {"type": "point", "direction": [0, -1, 0]}})
    assert "light.position: required key missing" in msg and "light.direction: unknown key" in msg
    text = write(tmp_path).read_text().replace("type: directional", "kind: directional")
    assert "light.type: required key missing" in problems(tmp_path, text=text)


def test_spot_light(tmp_path):
    (tmp_path / "tex").mkdir()
    (tmp_path / "tex" / "gobo.png").write_text("")
    spot = {"type": "spot", "position": [0, 5, 0], "direction": [0, -3, 0], "cone_deg": 30, "texture": "tex/gobo.png"}
    c = load_config(write(tmp_path, {"light": spot}))
    assert c.light.type == "spot" and c.light.direction == (0.0, -1.0, 0.0)
    assert c.light.texture == tmp_path / "tex" / "gobo.png"
    msg = problems(tmp_path, {"light": {**spot, "cone_deg": 90, "texture": "tex/missing.png"}})
    assert "light.cone_deg: must be <= 89" in msg
    assert f"light.texture: file not found: {tmp_path / 'tex' / 'missing.png'}" in msg
    assert "light.position: required key missing" in problems(
        tmp_path, {"light": {"type": "spot", "direction": [1, 0, 0]}}
    )


def test_missing_mesh_file_names_index_and_absolute_path(tmp_path):
    msg = problems(tmp_path, {"scene": {"meshes": [{"path": "meshes/box.obj"}, {"path": "foo.obj"}]}})
    assert f"scene.meshes.1.path: file not found: {tmp_path / 'foo.obj'}" in msg


def test_mesh_format_and_directory(tmp_path):
    (tmp_path / "m.xyz").write_text("")
    assert "unsupported mesh format '.xyz'" in problems(tmp_path, {"scene": {"meshes": [{"path": "m.xyz"}]}})
    assert "scene.meshes.0.path: not a file" in problems(tmp_path, {"scene": {"meshes": [{"path": "meshes"}]}})


def test_meshes_required_and_non_empty(tmp_path):
    assert "scene.meshes: needs at least 1 item" in problems(tmp_path, {"scene": {"meshes": []}})
    assert "scene: required key missing" in problems(tmp_path, text="camera: {position: [0,0,1], look_at: [0,0,0]}\n")


def test_mesh_entry_needs_exactly_one_source(tmp_path):
    msg = problems(tmp_path, {"scene": {"meshes": [{"material": {"opacity": 0.5}}]}})
    assert "scene.meshes.0: give exactly one of 'path' or 'procedural' (got neither)" in msg
    msg = problems(tmp_path, {"scene": {"meshes": [{"path": "meshes/box.obj", "params": {"n": 3}}]}})
    assert "scene.meshes.0.params: only used with 'procedural'" in msg


def test_path_entry_with_empty_params_is_valid(tmp_path):
    c = load_config(write(tmp_path, {"scene": {"meshes": [{"path": "meshes/box.obj", "params": {}}]}}))
    assert c.scene.meshes[0].params == {}


def test_procedural_generators(tmp_path, monkeypatch):
    procedural = pytest.importorskip("warpscatter.scene.procedural")

    def colonnade(pillars=8, radius=0.2):
        return None

    monkeypatch.setattr(procedural, "GENERATORS", {"colonnade": colonnade, "fence": lambda **kw: None})
    c = load_config(write(tmp_path, {"scene": {"meshes": [{"procedural": "colonnade", "params": {"pillars": 4}}]}}))
    assert c.scene.meshes[0].procedural == "colonnade" and c.scene.meshes[0].params == {"pillars": 4}
    msg = problems(tmp_path, {"scene": {"meshes": [{"path": "meshes/box.obj"}, {"procedural": "gate"}]}})
    assert "scene.meshes.1.procedural: unknown generator 'gate' (choose from colonnade, fence)" in msg
    msg = problems(tmp_path, {"scene": {"meshes": [{"procedural": "colonnade", "params": {"posts": 3}}]}})
    assert (
        "scene.meshes.0.params: unknown parameter(s) 'posts' for generator 'colonnade' (accepts: pillars, radius)"
        in msg
    )
    msg = problems(tmp_path, {"scene": {"meshes": [{"procedural": "colonnade", "params": {"pilars": 3}}]}})
    assert "'pilars' for generator 'colonnade' (did you mean 'pillars'?)" in msg
    c = load_config(write(tmp_path, {"scene": {"meshes": [{"procedural": "fence", "params": {"anything": 1}}]}}))
    assert c.scene.meshes[0].params == {"anything": 1}  # **kwargs generators check their own parameters
    msg = problems(tmp_path, {"scene": {"meshes": [{"path": "meshes/box.obj", "procedural": "fence"}]}})
    assert "scene.meshes.0: give exactly one of 'path' or 'procedural' (got both)" in msg


def test_real_generator_names_validate(tmp_path):
    procedural = pytest.importorskip("warpscatter.scene.procedural")
    if not procedural.GENERATORS:
        pytest.skip("no generators registered")
    name = next(iter(procedural.GENERATORS))
    c = load_config(write(tmp_path, {"scene": {"meshes": [{"procedural": name}]}}))
    assert c.scene.meshes[0].procedural == name


def test_transform_and_material(tmp_path):
    mesh = {"path": "meshes/box.obj", "transform": {"scale": [1, 2, 3], "rotate_deg": [0, 30, 0]}}
    c = load_config(write(tmp_path, {"scene": {"meshes": [mesh]}}))
    assert c.scene.meshes[0].transform.scale3 == (1.0, 2.0, 3.0)
    assert c.scene.meshes[0].transform.translate == (0.0, 0.0, 0.0)
    c = load_config(write(tmp_path, {"scene": {"meshes": [{"path": "meshes/box.obj", "transform": {"scale": 2}}]}}))
    assert c.scene.meshes[0].transform.scale3 == (2.0, 2.0, 2.0)
    bad = {
        "path": "meshes/box.obj",
        "transform": {"scale": [1, 0, 1]},
        "material": {"albedo": [1.2, 0, 0], "opacity": 0},
    }
    msg = problems(tmp_path, {"scene": {"meshes": [bad]}})
    assert "scene.meshes.0.transform.scale: must be > 0" in msg
    assert "scene.meshes.0.material.albedo: every component must lie in [0, 1]" in msg
    assert "scene.meshes.0.material.opacity: must be > 0" in msg
    assert "scale: must be > 0" in problems(tmp_path, {"scene": {"meshes": [{**bad, "transform": {"scale": -1}}]}})


def test_phase_function(tmp_path):
    c = load_config(write(tmp_path, {"medium": {"phase": {"type": "henyey_greenstein", "g": -0.3}}}))
    assert c.medium.phase.g == -0.3
    assert "medium.phase.g: must be <= 0.99" in problems(
        tmp_path, {"medium": {"phase": {"type": "henyey_greenstein", "g": 1}}}
    )
    msg = problems(tmp_path, {"medium": {"phase": {"type": "isotropic", "g": 0.5}}})
    assert "medium.phase: g (0.5) is only used by type henyey_greenstein" in msg
    assert "medium.phase.type: must be one of" in problems(tmp_path, {"medium": {"phase": {"type": "rayleigh"}}})
    assert "medium.albedo: must be <= 1" in problems(tmp_path, {"medium": {"albedo": 1.5}})


def test_render_section(tmp_path):
    c = load_config(write(tmp_path, {"render": {"scattering": {"shadow_map": {"resolution": [512, 256]}}}}))
    assert c.render.scattering.shadow_map.size == (512, 256)
    msg = problems(
        tmp_path,
        {
            "render": {
                "scattering": {"method": "moonlight", "steps": 0, "visibility": "bvh", "shadow_map": {"resolution": 8}},
                "shadows": {"method": "esm", "filter_px": 0},
            }
        },
    )
    assert ("render.scattering.method: must be one of 'raymarch', 'fourier', 'moments4', 'moments6' or 'epipolar' "
            "(got 'moonlight')") in msg
    assert "render.scattering.steps: must be >= 1" in msg
    assert "render.scattering.visibility: must be one of 'exact' or 'shadow_map'" in msg
    assert "render.scattering.shadow_map.resolution: each side must lie in [16," in msg
    assert "render.shadows.method: must be one of 'pcf', 'msm', 'msm_soft', 'pcss', 'msm2015', 'vsm', 'evsm' or " \
           "'none'" in msg
    assert "render.shadows.filter_px: must be >= 1" in msg


def test_output_section(tmp_path):
    c = load_config(write(tmp_path, {"output": {"dir": "results/a", "aovs": ["depth", "color", "depth"]}}))
    assert c.output.dir == tmp_path / "results" / "a"
    assert c.output.aovs == ["depth", "color"]
    msg = problems(tmp_path, {"output": {"name": "a/b", "aovs": ["normals"], "exposure": 0}})
    assert "output.name: must be a plain file stem" in msg
    assert ("output.aovs.0: must be one of 'color', 'scattering', 'surface', 'depth', 'rectified', 'epipole_mask', "
            "'rectified_map', 'mip_level', 'evaluated_pixels' or 'epipolar_samples' (got 'normals')") in msg
    assert "output.exposure: must be > 0" in msg


def test_output_compression(tmp_path):
    assert load_config(write(tmp_path)).output.compression == "none"
    for choice in cfgmod.EXR_COMPRESSIONS:
        assert load_config(write(tmp_path, {"output": {"compression": choice}})).output.compression == choice
    assert load_config(write(tmp_path), ["output.compression=piz"]).output.compression == "piz"
    msg = problems(tmp_path, {"output": {"compression": "dwaa"}})  # lossy: not offered
    assert "output.compression: must be one of 'none', 'rle', 'zips', 'zip' or 'piz' (got 'dwaa')" in msg
    msg = problems(tmp_path, overrides=["output.compression=zip2"])
    assert "output.compression: must be one of 'none', 'rle', 'zips', 'zip' or 'piz' (got 'zip2') (from --set)" in msg


def test_output_compression_matches_the_image_writer():
    imageio = pytest.importorskip("warpscatter.io.images")
    assert cfgmod.EXR_COMPRESSIONS == imageio.EXR_COMPRESSIONS
    assert cfgmod.OutputConfig().compression == imageio.DEFAULT_EXR_COMPRESSION


def test_every_problem_reported_with_line_numbers(tmp_path):
    text = (
        "scene:\n"
        "  meshes:\n"
        "    - path: meshes/box.obj\n"
        "      colour: 1\n"
        "camera: {position: [0, 1, 5], look_at: [0, 1, 0], width: 0}\n"
        "light:\n"
        "  type: directional\n"
        "  direction: [0, 0, 0]\n"
        "medium: {sigma_t: -1}\n"
    )
    err = pytest.raises(ConfigError, load_config, write(tmp_path, text=text)).value
    assert err.problems == [
        "scene.meshes.0.colour: unknown key (line 4)",
        "camera.width: must be >= 1 (got 0) (line 5)",
        "light.direction: must be non-zero (line 8)",
        "medium.sigma_t: must be >= 0 (got -1) (line 9)",
    ]
    assert err.source == tmp_path / "scene.yaml"
    assert str(err).startswith(f"{tmp_path / 'scene.yaml'}:\n  scene.meshes.0.colour")


# ---- file-level errors ---------------------------------------------------------------------------


def test_missing_config_file(tmp_path):
    with pytest.raises(ConfigError, match="config file not found") as info:
        load_config(tmp_path / "nope.yaml")
    assert info.value.source == tmp_path / "nope.yaml"


def test_yaml_syntax_error_names_line(tmp_path):
    msg = problems(tmp_path, text="scene:\n  meshes: [1, 2\ncamera: 3\n")
    assert msg.startswith(f"{tmp_path / 'scene.yaml'}:\n")
    assert "line 3, column 7: YAML error: while parsing a flow sequence" in msg


def test_duplicate_key_rejected(tmp_path):
    msg = problems(tmp_path, text=write(tmp_path).read_text() + "camera: {position: [1, 1, 1], look_at: [0, 0, 0]}\n")
    assert "duplicate key 'camera'" in msg and "line " in msg


def test_empty_section_means_defaults(tmp_path):
    c = load_config(write(tmp_path, text=write(tmp_path).read_text() + "medium:\nrender:\n  scattering:\n"))
    assert c.medium.sigma_t == 0.1 and c.render.scattering.march_steps == 128
    assert "scene: expected a mapping (key: value), got None (line 1)" in problems(tmp_path, text="scene:\n")


def test_empty_and_non_mapping_documents(tmp_path):
    assert "scene: required key missing" in problems(tmp_path, text="")
    assert "expected a mapping at the top level" in problems(tmp_path, text="- 1\n- 2\n")


# ---- overrides -----------------------------------------------------------------------------------


def test_parse_override_values():
    assert parse_override("camera.fov_y=40") == (("camera", "fov_y"), 40)
    assert parse_override("camera.position=[0,1,2]") == (("camera", "position"), [0, 1, 2])
    assert parse_override("render.scattering.method=raymarch") == (("render", "scattering", "method"), "raymarch")
    assert parse_override("scene.meshes.0.material.opacity=0.5") == (("scene", "meshes", 0, "material", "opacity"), 0.5)
    assert parse_override("medium.sigma_t=2e-2") == (("medium", "sigma_t"), 0.02)
    assert parse_override("output.name=a=b") == (("output", "name"), "a=b")  # only the first '=' splits
    assert parse_override("render.surfaces.enabled=false")[1] is False
    for bad in ("camera.fov_y", "=3", "camera..fov_y=3", "camera.position=[0,1"):
        with pytest.raises(ValueError):
            parse_override(bad)


def test_overrides_apply_in_order(tmp_path):
    c = load_config(
        write(tmp_path),
        [
            "camera.fov_y=40",
            "camera.position=[0,2,9]",
            "render.scattering.method=raymarch",
            "scene.meshes.0.material.opacity=0.5",
            "medium.phase={type: henyey_greenstein, g: 0.25}",
            "camera.fov_y=35",
        ],
    )
    assert c.camera.fov_y == 35 and c.camera.position == (0.0, 2.0, 9.0)
    assert c.scene.meshes[0].material.opacity == 0.5
    assert c.medium.phase.type == "henyey_greenstein" and c.medium.phase.g == 0.25


def test_override_creates_missing_sections_and_appends(tmp_path):
    (tmp_path / "two.obj").write_text("")
    c = load_config(write(tmp_path), ["render.scattering.steps=16", "scene.meshes.1.path=two.obj"])
    assert c.render.scattering.steps == 16
    assert [m.path.name for m in c.scene.meshes] == ["box.obj", "two.obj"]


def test_override_errors(tmp_path):
    msg = problems(
        tmp_path,
        overrides=["camera.fov_y", "scene.meshes.5.path=x.obj", "light.direction.x=1"],
    )
    assert "--set camera.fov_y: expected KEY=VALUE" in msg
    assert "--set scene.meshes.5.path=x.obj: index 5 out of range (scene.meshes has 1 item(s))" in msg
    assert "--set light.direction.x=1: light.direction is a list: use an item index" in msg
    msg = problems(tmp_path, overrides=["camera.position=[0,1"])
    assert "--set camera.position=[0,1: value is not valid YAML" in msg


def test_override_validation_error_is_marked(tmp_path):
    msg = problems(tmp_path, overrides=["medium.sigma_t=-2", "camera.colour=1"])
    assert "medium.sigma_t: must be >= 0 (got -2) (from --set)" in msg
    assert "camera.colour: unknown key (from --set)" in msg


def test_override_into_scalar_rejected(tmp_path):
    msg = problems(tmp_path, overrides=["light.type.kind=spot"])
    assert "--set light.type.kind=spot: light.type is not a mapping" in msg


def test_aov_names_match_output_model():
    assert cfgmod.OutputConfig().aovs == list(cfgmod.STANDARD_AOVS)


# ---- the seams: light models, method rules, config files ----------------------------------------


def test_every_light_type_is_one_model_that_describes_and_builds_itself():
    import typing

    from warpscatter.scene.light_configs import LIGHT_CONFIGS, LIGHT_TYPES, LightSettings

    union = typing.get_args(typing.get_args(cfgmod.LightConfig)[0])
    assert set(union) == set(LIGHT_CONFIGS) == set(LIGHT_TYPES.values())
    for model in LIGHT_CONFIGS:  # no if-chain over light types elsewhere: each model has its own
        assert model.describe is not LightSettings.describe and model.build is not LightSettings.build, model
    assert "environment, area, linear or volume" in cfgmod.Config.model_fields["light"].description


def test_a_light_builds_its_scene_light_and_describes_itself(tmp_path):
    pytest.importorskip("warp")
    from warpscatter.scene import light_from_config

    write(tmp_path)
    light = {"type": "linear", "start": [0, 2, 0], "end": [1, 2, 0], "intensity": [2, 2, 2]}
    c = Config.from_dict({**BASE, "light": light, "render": {"lighting": {"method": "raytrace"}}}, tmp_path)
    built = light_from_config(c.light)
    assert built.kind == "linear" and built.length == pytest.approx(1.0)
    assert c.light.describe() == "linear [0, 2, 0] -> [1, 2, 0], intensity [2, 2, 2] per unit length"


def test_method_rules_are_their_registry_records(tmp_path):
    from warpscatter import methods

    write(tmp_path)
    spot = {"type": "spot", "position": [0, 1, 5], "direction": [0, -1, 0]}  # at the camera
    c = Config.from_dict({**BASE, "light": spot, "render": {"scattering": {"method": "raymarch"}}}, tmp_path)
    assert methods.SCATTERING["raymarch"].validate(c) == []  # no rules of its own
    c.render.scattering.method = "moments4"  # assigned in place: not validated again
    rules = methods.SCATTERING["moments4"].validate(c)
    assert [r.split(":")[0] for r in rules] == ["light.position"]
    with pytest.raises(ConfigError) as info:
        c.revalidated()
    assert info.value.problems == rules


def test_an_override_replaces_the_other_forms_of_the_same_key():
    data = {"light": {"type": "directional", "direction": [0, -1, 0]}}
    cfgmod.apply_overrides(data, ["light.azimuth_deg=30", "light.elevation_deg=40"])
    assert data["light"] == {"type": "directional", "azimuth_deg": 30, "elevation_deg": 40}
    data = {"light": {"type": ["not", "a", "name"], "direction": [0, -1, 0]}}
    cfgmod.apply_overrides(data, ["light.toward_sun=[0, 1, 0]"])  # an invalid type is validation's to report
    assert data["light"]["direction"] == [0, -1, 0]
