"""Animated configs (tracks, frames), rendering sequences through the executors (inline, local processes, a real
Dask LocalCluster), resuming, previews, and parameter sweeps."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from data_files import ANIMATED as BASE_ANIMATED

from warpscatter.cli.main import main
from warpscatter.config import load_config
from warpscatter.config.animation import AnimationSettings, Track, frame_name, track_value
from warpscatter.errors import ConfigError
from warpscatter.io.images import read_image
from warpscatter.runs.animation import parse_frames, render_animation
from warpscatter.runs.jobs import InlineExecutor, LocalExecutor, RenderTask, make_executor, run_tasks, task_for

ROOT = Path(__file__).resolve().parent.parent

#: the shared animated config with a GIF preview and a second, linearly interpolated track
ANIMATED = {**BASE_ANIMATED, "animation": {
    "frames": 3, "preview": "gif",
    "tracks": {"light.direction": {1: [0.6, -0.4, 1.0], 3: [-0.6, -0.4, 1.0]},
               "camera.fov_y": {"keys": {1: 50, 3: 40}, "interpolation": "linear"}}}}


@pytest.fixture
def animated(tmp_path):
    path = tmp_path / "sun.yaml"
    path.write_text(yaml.safe_dump(ANIMATED))
    return path


# ---- tracks ------------------------------------------------------------------------------------------------------


def test_track_interpolation():
    lin = Track(keys={1: 0.0, 11: 10.0, 21: 0.0})
    assert [track_value(lin, f) for f in (0, 1, 6, 11, 16, 21, 30)] == [0.0, 0.0, 5.0, 10.0, 5.0, 0.0, 0.0]
    smooth = [track_value(lin, f, "smooth") for f in (1, 3.5, 6, 8.5, 11)]
    assert smooth[0] == 0.0 and smooth[2] == 5.0 and smooth[4] == 10.0
    assert smooth[1] == pytest.approx(10 * 0.15625) and smooth[3] == pytest.approx(10 * 0.84375)  # 3t^2 - 2t^3
    vec = Track(keys={0: [0, 0, 1], 4: [4, 9, 1]})
    assert track_value(vec, 1) == [1.0, 2.25, 1.0]  # whole-number keyframes of a float key stay floats
    assert track_value(vec, 1, integer=True) == [1, 2, 1]  # an integer key rounds
    assert track_value(Track(keys={1: "fourier", 5: "moments6"}), 4) == "fourier"  # held until the next key
    with pytest.raises(ValueError, match="same type and length"):
        Track(keys={1: [0, 1, 2], 2: 3})


def test_animation_settings_and_frame_configs(animated):
    config = load_config(animated)
    assert config.animation.frame_numbers == [1, 2, 3]
    assert AnimationSettings(frames=[5, 8]).frame_numbers == [5, 6, 7, 8]
    frames = [config.at_frame(f) for f in (1, 2, 3)]
    assert [f.output_name for f in frames] == ["sun.0001", "sun.0002", "sun.0003"] == [frame_name("sun", k)
                                                                                      for k in (1, 2, 3)]
    assert [f.camera.fov_y for f in frames] == [50, 45, 40]
    assert frames[1].light.direction == pytest.approx((0.0, -0.4 / np.hypot(0.4, 1.0), 1.0 / np.hypot(0.4, 1.0)))
    assert frames[0].animation is None
    # whole-number positions move evenly (not rounded), an integer key (the image width) rounds
    data = {**ANIMATED, "animation": {"frames": 5, "interpolation": "linear", "tracks": {
        "camera.position": {1: [0, 2, -14], 5: [0, 2, -8]}, "camera.width": {1: 24, 5: 31}}}}
    path = animated.with_name("even.yaml")
    path.write_text(yaml.safe_dump(data))
    even = load_config(path)
    assert [even.at_frame(f).camera.position[2] for f in range(1, 6)] == [-14.0, -12.5, -11.0, -9.5, -8.0]
    assert [even.at_frame(f).camera.width for f in range(1, 6)] == [24, 26, 28, 29, 31]


@pytest.mark.parametrize("tracks, message", [
    ({"camera.fov_y": {1: 500}}, r"animation.tracks.camera.fov_y \(frame 1\): camera.fov_y: must be <"),
    ({"camera.bogus": {1: 1}}, r"animation.tracks.camera.bogus \(frame 1\): camera.bogus: unknown key"),
    ({"camera.width": {1: 10, 2: [1, 2]}}, r"same type and length"),
    ({"camera.width": {}}, r"at least one keyframe"),
])
def test_bad_tracks_are_rejected_with_their_key(tmp_path, tracks, message):
    path = tmp_path / "a.yaml"
    path.write_text(yaml.safe_dump({**ANIMATED, "animation": {"frames": 2, "tracks": tracks}}))
    with pytest.raises(ConfigError, match=message):
        load_config(path)


def test_parse_frames():
    assert parse_frames(None, 1, 5) == [1, 2, 3, 4, 5]
    assert parse_frames("2:4", 1, 5) == [2, 3, 4] and parse_frames("1:5:2", 1, 5) == [1, 3, 5]
    assert parse_frames("5,1", 1, 5) == [5, 1]
    for bad in ("0:3", "a:b", "1:5:0", "9"):
        with pytest.raises(ValueError, match="--frames"):
            parse_frames(bad, 1, 5)


# ---- sequences ---------------------------------------------------------------------------------------------------


def test_render_animation_resumes_and_writes_a_preview(animated, tmp_path):
    config = load_config(animated)
    out = tmp_path / "out"
    first = render_animation(config, out, frames=[1, 2])
    assert len(first.rendered) == 2 and first.preview is None and "not every frame" in first.notes[0]
    stamp = (out / "sun.0001.exr").stat().st_mtime_ns
    second = render_animation(config, out)  # frames 1 and 2 are done: only 3 renders, then the preview
    assert [r.skipped for r in second.frames] == [True, True, False] and second.preview == out / "sun.gif"
    assert (out / "sun.0001.exr").stat().st_mtime_ns == stamp
    import imageio.v2 as iio

    assert np.asarray(iio.mimread(out / "sun.gif")).shape[:3] == (3, 14, 24)
    sidecar = json.loads((out / "sun.0003.json").read_text())
    assert sidecar["config"]["camera"]["fov_y"] == 40 and sidecar["name"] == "sun.0003"
    changed = config.model_copy(update={"medium": {"sigma_t": 0.2, "albedo": 0.9}})  # another config: re-rendered
    assert len(render_animation(changed, out, preview="none").rendered) == 3


def test_frames_are_bit_identical_on_every_executor(animated, tmp_path):
    distributed = pytest.importorskip("distributed")  # noqa: F841  (the test extra installs it)
    config = load_config(animated)
    runs = {}
    for kind in ("inline", "local", "dask"):
        with make_executor(kind, workers=2) as executor:
            result = render_animation(config, tmp_path / kind, executor=executor, preview="none")
        assert not result.failed, [r.error for r in result.failed]
        if kind != "inline":
            assert len({r.worker for r in result.rendered}) >= 1 and result.rendered[0].worker.split(":")[1] != str(
                os.getpid())  # rendered in worker processes
        runs[kind] = [read_image(tmp_path / kind / f"sun.000{f}.exr") for f in (1, 2, 3)]
    for kind in ("local", "dask"):
        for a, b in zip(runs["inline"], runs[kind], strict=True):
            np.testing.assert_array_equal(a, b)
    assert not np.array_equal(runs["inline"][0], runs["inline"][2])  # the sun moved


def test_a_failed_task_does_not_stop_the_others(tmp_path):
    config = load_config(ROOT / "configs" / "quickstart.yaml", ["camera.width=16", "camera.height=9",
                                                                 "render.scattering.steps=4"])
    good = task_for(config, "good", tmp_path / "good")
    broken = RenderTask(**{**good.__dict__, "label": "broken", "out_dir": str(tmp_path / "broken")})
    broken.config = {**broken.config, "camera": {**broken.config["camera"], "width": -1}}
    for executor in (InlineExecutor(), LocalExecutor(2)):
        with executor:
            results = run_tasks([broken, good], executor, skip_finished=False)
        assert [r.label for r in results] == ["broken", "good"]
        assert not results[0].ok and "camera.width" in results[0].error and results[1].ok


def test_executor_choices():
    with pytest.raises(ValueError, match="executor: must be one of inline, local, dask"):
        make_executor("ray")
    with pytest.raises(ValueError, match="--address is for the dask executor"):
        make_executor("local", address="tcp://127.0.0.1:8786")


def test_killed_run_resumes_without_rerendering(animated, tmp_path):
    out = tmp_path / "out"
    data = yaml.safe_load(animated.read_text())
    data["animation"]["frames"] = 6
    data["camera"].update(width=96, height=54)
    animated.write_text(yaml.safe_dump(data))
    cmd = [sys.executable, "-m", "warpscatter", "render", str(animated), "-o", str(out), "--executor", "inline",
           "--preview", "none", "-q"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while not (out / "sun.0002.json").exists() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done = sorted(p.name for p in out.glob("sun.*.json"))
    assert done and len(done) < 6, done
    stamps = {p: (out / p).stat().st_mtime_ns for p in done}
    result = CliRunner().invoke(main, ["render", str(animated), "-o", str(out), "--executor", "inline",
                                       "--preview", "none"])
    assert result.exit_code == 0, result.output
    assert f"{6 - len(done)} frame(s) rendered, {len(done)} already done, 0 failed" in result.output
    assert all((out / p).stat().st_mtime_ns == t for p, t in stamps.items())
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporaries left by the kill survive
    # they are a valid sequence: every frame has its full output set
    assert sorted(p.name for p in out.glob("sun.*.exr")) == sorted(
        [f"sun.000{f}.exr" for f in range(1, 7)] + [f"sun.000{f}.depth.exr" for f in range(1, 7)])


def test_cli_renders_an_animation_with_local_workers(animated, tmp_path):
    result = CliRunner().invoke(main, ["render", str(animated), "-o", str(tmp_path / "o"), "--workers", "2",
                                       "--frames", "1:3"])
    assert result.exit_code == 0, result.output
    assert "3 frame(s) rendered, 0 already done, 0 failed" in result.output and "local (2 workers)" in result.output
    assert (tmp_path / "o" / "sun.gif").is_file()
    bad = CliRunner().invoke(main, ["render", str(animated), "--frames", "2:9"])
    assert bad.exit_code == 2 and "the animation has frames 1..3" in bad.stderr
    wrong = CliRunner().invoke(main, ["render", str(animated), "--address", "tcp://127.0.0.1:1"])
    assert wrong.exit_code == 2 and "--address is for the dask executor" in wrong.stderr


# ---- sweeps ------------------------------------------------------------------------------------------------------


def test_sweep_writes_a_table_and_a_chart(tmp_path):
    sweep = {
        "configs": [str(ROOT / "configs" / "quickstart.yaml"), str(ROOT / "configs" / "gate.yaml")],
        "set": {"camera.width": 32, "camera.height": 18, "render.scattering.shadow_map.resolution": 128},
        "grid": {"render.scattering.method": ["fourier", "moments6"], "render.scattering.steps": [8, 16]},
        "reference": {"render.scattering.method": "raymarch", "render.scattering.visibility": "exact",
                      "render.scattering.steps": 64},
    }
    path = tmp_path / "sweep.yaml"
    path.write_text(yaml.safe_dump(sweep))
    result = CliRunner().invoke(main, ["sweep", str(path), "-o", str(tmp_path / "out"), "--executor", "inline"])
    assert result.exit_code == 0, result.output
    rows = json.loads((tmp_path / "out" / "sweep.json").read_text())["rows"]
    assert len(rows) == 8 and {r["method"] for r in rows} == {"fourier", "moments6"}
    assert rows[0]["case"] == "quickstart/method=fourier,steps=8"
    assert all(0 < r["rel_l1"] < 1 and r["technique_s"] > 0 for r in rows)
    import csv

    with open(tmp_path / "out" / "sweep.csv") as f:
        table = list(csv.DictReader(f))
    assert len(table) == 8 and {"case", "method", "technique_s", "rel_l1", "rmse"} <= set(table[0])
    pytest.importorskip("matplotlib")
    assert (tmp_path / "out" / "sweep-error-time.png").is_file()


def test_sweep_rejects_bad_cases_before_any_render(tmp_path):
    path = tmp_path / "sweep.yaml"
    path.write_text(yaml.safe_dump({"configs": [str(ROOT / "configs" / "quickstart.yaml")],
                                    "grid": {"render.scattering.method": ["fourier", "nonsense"]}}))
    result = CliRunner().invoke(main, ["sweep", str(path), "-o", str(tmp_path / "out")])
    assert result.exit_code == 2 and "quickstart/method=nonsense: render.scattering.method" in result.stderr
    assert not (tmp_path / "out").exists()


def test_a_csm_of_unmoved_occluders_is_built_once_per_process():
    from warpscatter.csm.occluders import prepare_csm, scene_occluders
    from warpscatter.scene import build_scene

    config = load_config(ROOT / "configs" / "csm_gate.yaml", ["render.lighting.csm.maps=[8, 4]",
                                                              "render.lighting.csm.resolution=32"])
    scene = build_scene(config)
    vertices, triangles = scene_occluders(scene)
    first = prepare_csm(scene.light, config.render.lighting.csm, vertices, triangles)
    assert prepare_csm(scene.light, config.render.lighting.csm, vertices, triangles) is first  # a frame later
    moved = prepare_csm(scene.light, config.render.lighting.csm, vertices + np.float32(0.5), triangles)
    assert moved is not first and moved.geometry != first.geometry
    other = config.render.lighting.csm.model_copy(update={"resolution": 16})
    assert prepare_csm(scene.light, other, vertices, triangles).resolution == 16


# ---- regressions found in review -----------------------------------------------------------------------------------


def test_a_progressive_frame_counts_as_done_only_when_complete(animated, tmp_path, monkeypatch):
    from warpscatter.runs.jobs import finished

    task = task_for(load_config(animated).at_frame(1), "sun.0001", tmp_path)
    render_animation(load_config(animated), tmp_path, frames=[1], preview="none")
    assert finished(task)
    sidecar = tmp_path / "sun.0001.json"
    data = json.loads(sidecar.read_text())
    sidecar.write_text(json.dumps({**data, "complete": False}))  # an intermediate pass of a killed csm render
    assert not finished(task)


def test_a_failed_preview_is_a_note_and_leaves_no_temporary(tmp_path):
    data = {**ANIMATED, "animation": {"frames": 2, "preview": "gif", "tracks": {"camera.width": {1: 24, 2: 32}}}}
    path = tmp_path / "grow.yaml"
    path.write_text(yaml.safe_dump(data))
    result = render_animation(load_config(path), tmp_path / "out")
    assert len(result.rendered) == 2 and result.preview is None
    assert "no gif preview" in result.notes[0]
    assert not [p for p in (tmp_path / "out").iterdir() if p.name.startswith(".")]


def test_tasks_carry_the_callers_threads_and_device(animated, monkeypatch):
    monkeypatch.setenv("WARPSCATTER_THREADS", "1")
    task = task_for(load_config(animated).at_frame(1), "f", None, device="cpu")
    assert task.threads == 1 and task.device == "cpu"


def test_sweep_cases_that_change_the_scene_get_their_own_reference(tmp_path):
    sweep = {"configs": [str(ROOT / "configs" / "quickstart.yaml")],
             "set": {"camera.height": 12, "render.scattering.shadow_map.resolution": 64},
             "grid": {"camera.width": [20, 24], "render.scattering.method": ["fourier"]},
             "reference": {"render.scattering.method": "raymarch", "render.scattering.steps": 16}}
    path = tmp_path / "sweep.yaml"
    path.write_text(yaml.safe_dump(sweep))
    from warpscatter.runs.sweep import load_sweep, run_sweep, sweep_cases

    cases, references = sweep_cases(load_sweep(path))
    assert sorted(references) == ["quickstart reference (width=20)", "quickstart reference (width=24)"]
    assert [c.reference for c in cases] == sorted(references)
    rows = run_sweep(load_sweep(path), tmp_path / "out").rows
    assert all(0 < r["rel_l1"] < 1 and "error" not in r for r in rows)  # each against a reference of its size


def test_render_refuses_an_animated_config(animated):
    import warpscatter

    with pytest.raises(ConfigError, match="animation: the config is a sequence"):
        warpscatter.render(animated)


def test_static_geometry_keeps_its_bvh_across_frames(animated):
    from warpscatter.scene import DeviceGeometry, build_scene

    config = load_config(animated)  # the sun and the field of view move, the geometry stands still
    first, last = (DeviceGeometry(build_scene(config.at_frame(f))) for f in (1, 3))
    assert first.mesh is last.mesh and first.shadow_mesh is last.shadow_mesh
    moved = config.model_copy(update={"scene": {"meshes": [
        *config.model_dump()["scene"]["meshes"][:1],
        {**config.model_dump()["scene"]["meshes"][1], "transform": {"translate": [0.5, 0, 3]}}]}})
    assert DeviceGeometry(build_scene(moved.at_frame(1))).mesh is not first.mesh  # other geometry: its own BVH


def test_an_optional_integer_key_interpolates_to_integers(tmp_path):
    # render.scattering.epipolar.lines defaults to null: the models, not the base value, say it is an integer
    data = {**ANIMATED, "render": {"scattering": {"method": "epipolar", "visibility": "shadow_map", "steps": 8}},
            "animation": {"frames": 10, "tracks": {"render.scattering.epipolar.lines": {1: 64, 10: 128}}}}
    path = tmp_path / "lines.yaml"
    path.write_text(yaml.safe_dump(data))
    config = load_config(path)
    lines = [config.at_frame(f).render.scattering.epipolar.lines for f in range(1, 11)]
    assert lines[0] == 64 and lines[-1] == 128 and all(isinstance(n, int) for n in lines)
