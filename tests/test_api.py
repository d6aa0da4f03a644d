"""The Python API (warpscatter.render / load_config), device resolution, and what a render's files say about it:
the sidecar JSON, the EXR headers (OpenEXR camera matrices, depth as Z), the output name template, layered EXRs."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

import warpscatter
from warpscatter.errors import ConfigError

ROOT = Path(__file__).resolve().parent.parent
QUICKSTART = ROOT / "configs" / "quickstart.yaml"
SMALL = {"camera.width": 24, "camera.height": 14, "render.scattering.method": "raymarch",
         "render.scattering.steps": 8, "render.scattering.shadow_map.resolution": 64}

SCENE = {
    "scene": {"meshes": [{"procedural": "ground_plane", "params": {"size": 20}, "receiver_only": True},
                         {"procedural": "fence", "transform": {"translate": [0, 0, 2]}}]},
    "camera": {"position": [0, 2, -8], "look_at": [0, 1, 2], "width": 20, "height": 12},
    "light": {"type": "directional", "direction": [0.3, -0.5, 1.0]},
    "medium": {"sigma_t": 0.1},
    "render": {"scattering": {"steps": 8, "shadow_map": {"resolution": 64}}},
}


def _header(path: Path) -> tuple[tuple[str, ...], dict]:
    inp = oiio.ImageInput.open(str(path))
    try:
        spec = inp.spec()
        return tuple(spec.channelnames), {a.name: a.value for a in spec.extra_attribs}
    finally:
        inp.close()


def test_render_a_dict_returns_images_and_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = warpscatter.render(SCENE)
    assert result.images["color"].shape == (12, 20, 3) and result.images["depth"].shape == (12, 20)
    assert result.files == [] and not list(tmp_path.iterdir())
    assert result.config.output_name == "render" and result.device == "cpu"
    assert {"scene", "compile", "scattering"} <= set(result.timings) and result.stats["method"] == "raymarch"
    assert np.all(np.isfinite(result.images["color"])) and result.images["scattering"].max() > 0


def test_render_a_path_with_overrides_in_a_scoped_device(tmp_path):
    import warp as wp

    with wp.ScopedDevice("cpu"):
        result = warpscatter.render(QUICKSTART, {**SMALL, "render.scattering.method": "fourier"}, out_dir=tmp_path)
    assert result.device == "cpu" and result.stats["method"] == "fourier"
    assert result.images["color"].shape == (14, 24, 3)
    assert sorted(p.name for p in result.files) == sorted(
        f"quickstart.{s}" for s in ("exr", "png", "scattering.exr", "surface.exr", "depth.exr", "json"))
    strings = warpscatter.render(QUICKSTART, [f"{k}={v}" for k, v in SMALL.items()])
    assert strings.images["color"].shape == (14, 24, 3)


def test_device_follows_warp(monkeypatch):
    import warp as wp

    from warpscatter.runtime.device import default_device

    monkeypatch.delenv("WARPSCATTER_DEVICE", raising=False)
    with wp.ScopedDevice("cpu"):
        assert default_device() == "cpu"
    monkeypatch.setattr(wp, "get_device", lambda *a: "cuda:7")  # what a scoped GPU device would return
    assert default_device() == "cuda:7" and default_device("cpu") == "cpu"
    monkeypatch.setenv("WARPSCATTER_DEVICE", "cpu")
    assert default_device() == "cpu"


def test_import_leaves_warps_settings_alone():
    code = ("import warp as wp; before = (wp.config.log_level, wp.config.kernel_cache_dir); "
            "import warpscatter, warpscatter.api, warpscatter.pipeline, warpscatter.scattering.prefiltered; "
            "assert (wp.config.log_level, wp.config.kernel_cache_dir) == before, (wp.config.log_level, before)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={k: v for k, v in __import__("os").environ.items() if k != "WARPSCATTER_KERNEL_CACHE"})
    assert out.returncode == 0, out.stderr


def test_every_path_into_a_render_validates(tmp_path):
    config = warpscatter.load_config(QUICKSTART, SMALL)
    with pytest.raises(ConfigError, match=r"medium.sigma_t: must be >= 0"):
        config.model_copy(update={"medium": {"sigma_t": -5}})
    config.medium.sigma_t = -5.0  # pydantic does not check assignments: the render does, before any work
    with pytest.raises(ConfigError, match=r"medium.sigma_t"):
        warpscatter.render(config, out_dir=tmp_path)
    assert not list(tmp_path.iterdir())
    with pytest.raises(ConfigError, match=r"camera.width"):
        warpscatter.render(SCENE, {"camera.width": 0})
    with pytest.raises(ConfigError, match=r"--set nonsense"):
        warpscatter.load_config(SCENE, ["nonsense"])
    with pytest.raises(TypeError, match="expected a file path, a dict or a Config"):
        warpscatter.load_config(42)


def test_load_config_keeps_the_source_and_copies_dicts():
    data = json.loads(json.dumps(SCENE))
    config = warpscatter.load_config(data, {"camera.fov_y": 30})
    assert config.camera.fov_y == 30 and data["camera"].get("fov_y") is None  # the caller's dict is untouched
    again = warpscatter.load_config(warpscatter.load_config(QUICKSTART), {"camera.width": 32})
    assert again.source == QUICKSTART and again.camera.width == 32 and again.output_name == "quickstart"


def test_output_name_template():
    config = warpscatter.load_config(QUICKSTART, {"output.name": "{config}_{method}_x",
                                                  "render.scattering.method": "raymarch"})
    assert config.output_name == "quickstart_raymarch_x"
    with pytest.raises(ConfigError, match=r"output.name: .*unknown template field\(s\) \{scene\}"):
        warpscatter.load_config(QUICKSTART, {"output.name": "{scene}"})
    with pytest.raises(ConfigError, match=r"output.name: .*not a valid template"):
        warpscatter.load_config(QUICKSTART, {"output.name": "a{b"})
    assert warpscatter.load_config(QUICKSTART, {"output.name": "a{{b}}"}).output_name == "a{b}"


def test_sidecar_and_exr_headers_describe_the_render(tmp_path):
    result = warpscatter.render(QUICKSTART, {**SMALL, "render.scattering.seed": 7}, out_dir=tmp_path)
    side = json.loads((tmp_path / "quickstart.json").read_text())
    assert side["method"] == "raymarch" and side["seed"] == 7 and side["device"] == "cpu"
    assert side["config"]["camera"]["width"] == 24 and side["config_file"] == str(QUICKSTART)
    assert side["versions"]["warpscatter"] == warpscatter.__version__ and side["versions"]["warp-lang"]
    assert side["machine"]["cpu"] and side["created"].endswith("Z") and "write" not in side["timings_s"]
    assert set(side["timings_s"]) == set(result.timings) - {"write"}
    assert side["stats"]["steps"] == 8 and side["files"] == [p.name for p in result.files]

    channels, attrs = _header(tmp_path / "quickstart.depth.exr")
    assert channels == ("Z",) and attrs["warpscatter:aov"] == "depth"
    channels, attrs = _header(tmp_path / "quickstart.exr")
    assert channels == ("R", "G", "B") and attrs["warpscatter:method"] == "raymarch"
    assert "sigma_t" in attrs["warpscatter:config"]

    # OpenEXR's matrices (row vectors): a pixel's hit point lands on its centre in NDC and at its view depth.
    cam = result.config.camera
    to_ndc = np.array(attrs["worldToNDC"], np.float64).reshape(4, 4)
    to_cam = np.array(attrs["worldToCamera"], np.float64).reshape(4, 4)
    from warpscatter.scene.camera import Camera

    camera = Camera(cam.position, cam.look_at, cam.up, cam.fov_y, cam.width, cam.height, cam.near, cam.far)
    dirs = camera.ray_directions()
    points = camera.position + dirs * result.images["depth"][..., None]
    homogeneous = np.concatenate([points, np.ones((*points.shape[:2], 1))], axis=2)
    ndc = homogeneous @ to_ndc
    j, i = np.mgrid[0:cam.height, 0:cam.width]
    np.testing.assert_allclose(ndc[..., 0] / ndc[..., 3], (i + 0.5) / cam.width, atol=2e-5)
    np.testing.assert_allclose(ndc[..., 1] / ndc[..., 3], (j + 0.5) / cam.height, atol=2e-5)
    view = homogeneous @ to_cam
    np.testing.assert_allclose(view[..., 2], result.images["depth"] * (dirs @ camera.forward), rtol=1e-5)


def test_layered_exr(tmp_path):
    result = warpscatter.render(QUICKSTART, {**SMALL, "output.layered": True}, out_dir=tmp_path)
    assert sorted(p.name for p in result.files) == ["quickstart.exr", "quickstart.json", "quickstart.png"]
    channels, attrs = _header(tmp_path / "quickstart.exr")
    assert sorted(channels) == sorted(("R", "G", "B", "scattering.R", "scattering.G", "scattering.B", "surface.R",
                                       "surface.G", "surface.B", "depth.Z"))  # OpenEXR orders them by name
    assert attrs["warpscatter:layers"] == "color,scattering,surface,depth"
    pixels = warpscatter.io.images.read_image(tmp_path / "quickstart.exr")
    channel = {name: pixels[..., k] for k, name in enumerate(channels)}
    np.testing.assert_array_equal(channel["depth.Z"], result.images["depth"])
    np.testing.assert_array_equal(np.stack([channel[f"scattering.{c}"] for c in "RGB"], axis=2),
                                  result.images["scattering"])
    np.testing.assert_array_equal(np.stack([channel[c] for c in "RGB"], axis=2), result.images["color"])


def test_the_sidecar_records_the_folder_written_to(tmp_path):
    warpscatter.render(QUICKSTART, SMALL, out_dir=tmp_path / "here")
    side = json.loads((tmp_path / "here" / "quickstart.json").read_text())
    assert side["config"]["output"]["dir"] == str((tmp_path / "here").resolve()) and side["complete"] is True
