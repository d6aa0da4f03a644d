"""The click application (warpscatter.cli.main) with fake pipeline/bench modules: no Warp compile."""

import io
import json
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from warpscatter import __version__
from warpscatter.cli.main import ProgressDisplay, main, timing_table
from warpscatter.io.images import write_outputs

CONFIG = {
    "scene": {"meshes": [{"path": "meshes/box.obj"}]},
    "camera": {"position": [0, 1, 5], "look_at": [0, 1, 0], "width": 4, "height": 3},
    "light": {"type": "directional", "direction": [0, -1, 0]},
    "output": {"dir": "out", "name": "shot", "aovs": ["color", "depth"]},
}


@pytest.fixture
def config_file(tmp_path):
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "box.obj").write_text("")
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(CONFIG))
    return path


@pytest.fixture
def fake_pipeline(monkeypatch):
    """Replace warpscatter.pipeline by a module whose render() writes tiny images with the real writer."""
    calls = []
    module = types.ModuleType("warpscatter.pipeline")

    def render(config, out_dir=None, progress=None, device=None):
        calls.append({"config": config, "out_dir": out_dir, "device": device})
        for stage in ("scene", "raymarch", "write"):
            progress(stage, 0.0)
            progress(stage, 0.5)
            progress(stage, 1.0)
        if config.output.name == "explode":
            raise RuntimeError("kernel exploded")
        h, w = config.camera.height, config.camera.width
        images = {"color": np.full((h, w, 3), 0.25, np.float32), "depth": np.ones((h, w), np.float32)}
        out = Path(out_dir) if out_dir is not None else config.output.dir
        files = write_outputs(out, config.output.name, images, config.output.aovs, config.output.exposure)
        timings = {"scene": 0.0125, "raymarch": 1.5, "write": 0.0004}
        return types.SimpleNamespace(files=files, timings=timings,
                                     stats={"steps": config.render.scattering.march_steps})

    module.render = render
    monkeypatch.setitem(sys.modules, "warpscatter.pipeline", module)
    return calls


@pytest.fixture
def fake_bench(monkeypatch, tmp_path):
    calls = []
    module = types.ModuleType("warpscatter.bench")
    module.SUITES = {"raster": types.SimpleNamespace(description="depth maps"),
                     "reference": types.SimpleNamespace(description="the ray marcher")}

    def run(suite="reference", *, repeats=5, warmup=1, out_dir=None, quick=False, progress=None):
        calls.append({"suite": suite, "repeats": repeats, "warmup": warmup, "out_dir": out_dir, "quick": quick})
        progress(suite, 1.0)
        return types.SimpleNamespace(table=lambda: f"TABLE {suite} x{repeats}", files=[Path("bench-x.json")])

    module.run = run
    monkeypatch.setitem(sys.modules, "warpscatter.bench", module)
    return calls


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


# ---- render ----------------------------------------------------------------------------------------


def test_render_writes_outputs_and_reports(config_file, tmp_path, fake_pipeline):
    result = invoke("render", config_file, "-o", tmp_path / "o")
    assert result.exit_code == 0, result.output
    out = (tmp_path / "o").resolve()
    assert sorted(p.name for p in out.iterdir()) == ["shot.depth.exr", "shot.exr", "shot.png"]
    assert fake_pipeline[0]["out_dir"] == out and fake_pipeline[0]["config"].output.dir == out
    assert "raymarch" in result.stdout and "1.500 s" in result.stdout and "total" in result.stdout
    assert result.stdout.splitlines()[0] == "shot: raymarch, 4 x 3 on cpu (1 statistic: -v)"
    assert "steps: 128" not in result.stdout  # the statistics: -v
    assert str(out / "shot.exr") in result.stdout
    # stderr is not a terminal here: a line when the render starts, then one every few seconds
    assert [line.split("] ")[1] for line in result.stderr.splitlines()] == ["scene"]
    verbose = invoke("render", config_file, "-o", tmp_path / "o", "-v")
    assert verbose.exit_code == 0, verbose.output
    assert "stats:\n  steps: 128" in verbose.stdout and "(1 statistic" not in verbose.stdout
    assert [line.split("] ")[1] for line in verbose.stderr.splitlines()] == ["scene", "raymarch", "write"]


def test_render_prints_the_results_warnings_unless_quiet(config_file, tmp_path, monkeypatch):
    module = types.ModuleType("warpscatter.pipeline")
    dark = "the light reaches no pixel: light.direction is the direction the light travels"
    module.render = lambda config, **kwargs: types.SimpleNamespace(files=[], timings={"scene": 0.1}, stats={},
                                                                   warnings=[dark, "second"])
    monkeypatch.setitem(sys.modules, "warpscatter.pipeline", module)
    for flags in ((), ("-v",)):
        result = invoke("render", config_file, "-o", tmp_path / "o", *flags)
        assert result.exit_code == 0, result.output
        assert result.stderr.splitlines()[-2:] == [f"warning: {dark}", "warning: second"]
        assert "warning" not in result.stdout
    result = invoke("render", config_file, "-o", tmp_path / "o", "-q")
    assert result.exit_code == 0 and result.stderr == "" and result.stdout == ""


def test_render_default_output_dir_is_relative_to_config(config_file, tmp_path, fake_pipeline, monkeypatch):
    monkeypatch.chdir(tmp_path / "meshes")
    result = invoke("render", config_file)
    assert result.exit_code == 0, result.output
    assert fake_pipeline[0]["out_dir"] is None
    assert (tmp_path / "out" / "shot.exr").is_file()


def test_render_output_dir_relative_to_cwd(config_file, tmp_path, fake_pipeline, monkeypatch):
    monkeypatch.chdir(tmp_path / "meshes")
    assert invoke("render", config_file, "-o", "here").exit_code == 0
    assert (tmp_path / "meshes" / "here" / "shot.exr").is_file()


def test_render_set_and_method_apply(config_file, tmp_path, fake_pipeline):
    result = invoke(
        "render",
        config_file,
        "-o",
        tmp_path / "o",
        "--set",
        "camera.fov_y=40",
        "--set",
        "camera.width=6",
        "--set",
        "render.scattering.steps=7",
        "--method",
        "raymarch",
    )
    assert result.exit_code == 0, result.output
    cfg = fake_pipeline[0]["config"]
    assert cfg.camera.fov_y == 40 and cfg.camera.width == 6 and cfg.render.scattering.steps == 7
    assert cfg.render.scattering.method == "raymarch"
    assert "steps: 7" in invoke("render", config_file, "-o", tmp_path / "o", "--set", "render.scattering.steps=7",
                                "-v").stdout


def test_render_method_override_names_the_outputs(config_file, tmp_path, fake_pipeline):
    result = invoke("render", config_file, "-o", tmp_path / "o", "--method", "fourier", "--seed", "5")
    assert result.exit_code == 0, result.output
    cfg = fake_pipeline[0]["config"]
    assert cfg.render.scattering.method == "fourier" and cfg.render.scattering.seed == 5
    assert cfg.output_name == "shot_fourier"  # never the file names of the config's own method
    assert invoke("render", config_file, "-o", tmp_path / "p", "--method", "fourier", "--name",
                  "{config}-{method}").exit_code == 0
    assert fake_pipeline[1]["config"].output_name == "scene-fourier"
    assert invoke("render", config_file, "-o", tmp_path / "p", "--method", "fourier", "--name", "x").exit_code == 0
    assert fake_pipeline[2]["config"].output_name == "x"  # a name given is taken as it is
    assert invoke("render", config_file, "-o", tmp_path / "q", "--method", "csm").exit_code == 2  # needs its light


def test_render_several_configs(config_file, tmp_path, fake_pipeline):
    other = tmp_path / "other.yaml"
    other.write_text(yaml.safe_dump({**CONFIG, "output": {**CONFIG["output"], "name": "{config}"}}))
    result = invoke("render", config_file, other, "-o", tmp_path / "o")
    assert result.exit_code == 0, result.output
    assert [c["config"].output_name for c in fake_pipeline] == ["shot", "other"]
    assert "[1/2] scene" in result.stderr and "[2/2] scene" in result.stderr
    clash = invoke("render", config_file, config_file, "-o", tmp_path / "c")
    assert clash.exit_code == 2 and "would both write" in clash.stderr and len(fake_pipeline) == 2


def test_render_device_and_threads(config_file, tmp_path, fake_pipeline, monkeypatch):
    monkeypatch.delenv("WARPSCATTER_THREADS", raising=False)
    monkeypatch.delenv("WARPSCATTER_DEVICE", raising=False)
    bad = invoke("render", config_file, "-o", tmp_path / "o", "--device", "cuda:9")
    assert bad.exit_code == 2 and "--device cuda:9: not a device of this machine (available: cpu" in bad.stderr
    assert not fake_pipeline
    assert invoke("render", config_file, "-o", tmp_path / "o", "--device", "cpu", "--threads", "1").exit_code == 0
    import os

    assert fake_pipeline[0]["device"] == "cpu" and os.environ["WARPSCATTER_THREADS"] == "1"


def test_schema_prints_the_json_schema(tmp_path):
    result = invoke("schema")
    assert result.exit_code == 0
    schema = json.loads(result.stdout)
    camera = schema["$defs"]["CameraConfig"]["properties"]
    assert "vertical field of view" in camera["fov_y"]["description"].lower()
    assert invoke("schema", "-o", tmp_path / "s.json", "-q").exit_code == 0
    assert json.loads((tmp_path / "s.json").read_text()) == schema


def test_bench_default_suite_is_the_one_help_names():
    import inspect

    from warpscatter.bench import run
    from warpscatter.cli.main import DEFAULT_SUITE

    assert inspect.signature(run).parameters["suite"].default == DEFAULT_SUITE
    assert f"the {DEFAULT_SUITE} suite" in invoke("bench", "--help").stdout


def test_render_quiet_prints_only_files(config_file, tmp_path, fake_pipeline):
    result = invoke("render", config_file, "-o", tmp_path / "o", "--quiet")
    assert result.exit_code == 0
    assert result.stderr == ""
    assert result.stdout.split() == [
        str((tmp_path / "o" / n).resolve()) for n in ("shot.exr", "shot.png", "shot.depth.exr")
    ]


@pytest.mark.parametrize(
    ("edit", "extra_args", "key"),
    [
        ({"camera": {**CONFIG["camera"], "colour": 1}}, [], "camera.colour: unknown key"),
        ({"camera": {**CONFIG["camera"], "width": "wide"}}, [], "camera.width: expected an integer"),
        ({"medium": {"sigma_t": -1}}, [], "medium.sigma_t: must be >= 0"),
        ({"scene": {"meshes": [{"path": "meshes/missing.obj"}]}}, [], "scene.meshes.0.path: file not found"),
        ({"camera": {**CONFIG["camera"], "near": 10, "far": 1}}, [], "camera: near (10.0) must be < far (1.0)"),
        ({}, ["--set", "camera.fov_y"], "--set camera.fov_y: expected KEY=VALUE"),
        ({}, ["--set", "scene.meshes.0.material.opacity=2"], "scene.meshes.0.material.opacity: must be <= 1"),
        ({}, ["--method", "moonlight"], "render.scattering.method: must be one of 'raymarch', 'fourier', "
                                        "'moments4', 'moments6' or 'epipolar' (got 'moonlight')"),
    ],
)
def test_render_rejects_bad_config_and_writes_nothing(config_file, tmp_path, fake_pipeline, edit, extra_args, key):
    config_file.write_text(yaml.safe_dump({**CONFIG, **edit}))
    result = invoke("render", config_file, "-o", tmp_path / "o", *extra_args)
    assert result.exit_code == 2
    assert result.stderr.startswith(f"error: {config_file}:\n")
    assert key in result.stderr
    assert fake_pipeline == []
    assert not (tmp_path / "o").exists()
    assert result.stdout == ""


def test_render_missing_config_file(tmp_path, fake_pipeline):
    result = invoke("render", tmp_path / "nope.yaml")
    assert result.exit_code == 2 and "config file not found" in result.stderr


def test_render_output_dir_is_a_file(config_file, tmp_path, fake_pipeline):
    (tmp_path / "f").write_text("")
    result = invoke("render", config_file, "-o", tmp_path / "f")
    assert result.exit_code == 2 and "not a directory" in result.stderr and fake_pipeline == []


def test_render_pipeline_failure_exit_1(config_file, tmp_path, fake_pipeline):
    result = invoke("render", config_file, "-o", tmp_path / "o", "--set", "output.name=explode")
    assert result.exit_code == 1
    assert "error: RuntimeError: kernel exploded" in result.stderr
    assert "Traceback" not in result.stderr
    debug = invoke("render", config_file, "-o", tmp_path / "o", "--set", "output.name=explode", "--debug")
    assert debug.exit_code == 1 and "Traceback" in debug.stderr and "kernel exploded" in debug.stderr
    assert "Traceback" in invoke("--debug", "render", config_file, "--set", "output.name=explode").stderr


# ---- validate --------------------------------------------------------------------------------------


def test_validate_summary(config_file):
    result = invoke("validate", config_file, "--set", "camera.fov_y=30")
    assert result.exit_code == 0, result.output
    assert result.stdout.startswith(f"ok: {config_file}")
    assert "1 mesh(es)" in result.stdout and "4x3, fov_y 30 deg" in result.stdout
    assert "directional, direction [0, -1, 0]" in result.stdout and "method:  raymarch" in result.stdout


@pytest.mark.parametrize("method, text", [("moments4", "64 bits per texel, 1024^2 maps, depth warp 3)"),
                                          ("moments6", "96 bits per texel, 1024^2 maps)")])
def test_validate_summary_names_the_depth_warp_in_use(config_file, method, text):
    result = invoke("validate", config_file, "--set", f"render.scattering.method={method}")
    assert result.exit_code == 0, result.output
    assert text in result.stdout


@pytest.mark.parametrize("light, text", [
    ("{type: point, position: [0, 2, 3], intensity: [5, 5, 5]}", "point at [0, 2, 3], intensity [5, 5, 5]"),
    ("{type: spot, position: [0, 2, 3], direction: [0, -1, 0], cone_deg: 20}", "spot at [0, 2, 3]"),
])
def test_validate_summary_names_every_classic_light(config_file, light, text):
    result = invoke("validate", config_file, "--set", f"light={light}")
    assert result.exit_code == 0, result.output
    assert f"light:   {text}" in result.stdout


def test_validate_dump_is_resolved_yaml(config_file, tmp_path):
    result = invoke("validate", config_file, "--dump")
    assert result.exit_code == 0
    data = yaml.safe_load(result.stdout)
    assert data["scene"]["meshes"][0]["path"] == str(tmp_path / "meshes" / "box.obj")
    assert data["output"]["dir"] == str(tmp_path / "out") and data["camera"]["far"] == 100.0


def test_validate_reports_every_problem(config_file):
    result = invoke("validate", config_file, "--set", "medium.sigma_t=-1", "--set", "light.direction=[0,0,0]")
    assert result.exit_code == 2
    assert "medium.sigma_t: must be >= 0" in result.stderr and "light.direction: must be non-zero" in result.stderr


def test_version():
    result = invoke("--version")
    assert result.exit_code == 0 and result.stdout.strip() == f"warpscatter {__version__}"


# ---- bench -----------------------------------------------------------------------------------------


def test_bench_list(fake_bench):
    result = invoke("bench", "--list")
    assert result.exit_code == 0
    assert result.stdout.splitlines() == ["raster     depth maps", "reference  the ray marcher"]
    assert fake_bench == []


def test_bench_runs_suite(fake_bench, tmp_path):
    result = invoke("bench", "raster", "--repeats", 3, "--warmup", 0, "-o", tmp_path / "b", "--quick")
    assert result.exit_code == 0, result.output
    assert fake_bench == [
        {"suite": "raster", "repeats": 3, "warmup": 0, "out_dir": (tmp_path / "b").resolve(), "quick": True}
    ]
    assert "TABLE raster x3" in result.stdout and "bench-x.json" in result.stdout


def test_bench_default_suite_from_run_signature(fake_bench):
    assert invoke("bench").exit_code == 0
    assert fake_bench[0]["suite"] == "reference" and fake_bench[0]["out_dir"] is None
    assert invoke("bench", "all").exit_code == 0 and fake_bench[1]["suite"] == "all"


def test_bench_unknown_suite(fake_bench):
    result = invoke("bench", "warp9")
    assert result.exit_code == 2
    assert "unknown suite 'warp9' (choose from: raster, reference, all, compare)" in result.stderr
    assert fake_bench == []
    assert invoke("bench", "raster", "--repeats", 0).exit_code == 2  # click range check


# ---- helpers ---------------------------------------------------------------------------------------


class _Tty(io.StringIO):
    def isatty(self):
        return True


def test_progress_on_a_terminal_draws_a_bar_and_clears_it():
    stream = _Tty()
    show = ProgressDisplay(stream=stream, prefix="[1/2] ")
    show("raymarch", 0.0)
    show("raymarch", 0.5)
    show("shading", 0.0)  # a new stage: the previous bar is removed
    show.close()
    text = stream.getvalue()
    assert "\n" not in text  # one line redrawn in place
    assert "[1/2] raymarch" in text and "[1/2] shading" in text and "0.0% |" in text
    assert text.endswith("\r")  # the last bar is cleared


def test_progress_plain_lines_and_disabled():
    stream = io.StringIO()
    show = ProgressDisplay(stream=stream)
    for stage, f in [("scene", 0.0), ("scene", 1.0), ("raster", 0.3), ("raster", float("nan"))]:
        show(stage, f)
    assert [line.split("] ")[1] for line in stream.getvalue().splitlines()] == ["scene"]  # the next in 10 s
    stream = io.StringIO()
    show = ProgressDisplay(stream=stream, every_stage=True)  # -v: a line per stage
    for stage, f in [("scene", 0.0), ("scene", 1.0), ("raster", 0.3), ("raster", float("nan"))]:
        show(stage, f)
    assert [line.split("] ")[1] for line in stream.getvalue().splitlines()] == ["scene", "raster"]
    slow = io.StringIO()
    show = ProgressDisplay(stream=slow, interval=0.0)  # a long stage: a line with the percentage and the ETA
    show("scattering", 0.0)
    show("scattering", 0.25)
    assert slow.getvalue().splitlines()[1].split("] ")[1].startswith("scattering  25% (ETA ")
    quiet_stage = io.StringIO()
    show = ProgressDisplay(stream=quiet_stage, interval=0.05)  # a stage that reports nothing for a while
    show("compile", 0.0)
    import time

    time.sleep(0.3)
    show.close()
    lines = quiet_stage.getvalue().splitlines()
    assert lines[0].endswith("] compile") and any("compile still running" in line for line in lines[1:])
    quiet = io.StringIO()
    ProgressDisplay(enabled=False, stream=quiet)("scene", 0.5)
    assert quiet.getvalue() == ""


def test_timing_table():
    table = timing_table({"scene": 0.25, "raymarch": 0.75})
    lines = table.splitlines()
    assert lines[0].split() == ["stage", "time", "share"]
    assert lines[2].split() == ["scene", "250.0", "ms", "25.0%"]
    assert lines[3].split() == ["raymarch", "750.0", "ms", "75.0%"]
    assert lines[-1].split() == ["total", "1.000", "s", "100.0%"]
    assert timing_table({}) == "(no timings)"


# ---- precompute (coherent shadow maps) ---------------------------------------------------------------------


def test_precompute_writes_a_loadable_csm(tmp_path):
    from warpscatter.csm import load_csm

    root = Path(__file__).resolve().parent.parent
    out = tmp_path / "gate.npz"
    result = CliRunner().invoke(main, ["precompute", str(root / "assets" / "gate.obj"), "-o", str(out),
                                       "--maps", "8x4", "--resolution", "32", "--enumeration", "zigzag"])
    assert result.exit_code == 0, result.output
    assert "ratio" in result.output and out.is_file()
    csm = load_csm(out)
    assert csm.num_maps == 32 and csm.resolution == 32 and csm.enumeration == "zigzag"


@pytest.mark.parametrize("args, message", [
    (["--maps", "8by4"], "--maps"),
    (["--maps", "0x4"], "--maps"),
    (["-o", "x.csm"], "must end in .npz"),
])
def test_precompute_bad_arguments(tmp_path, args, message):
    root = Path(__file__).resolve().parent.parent
    base = ["precompute", str(root / "assets" / "gate.obj"), "-o", str(tmp_path / "a.npz")]
    result = CliRunner().invoke(main, [*base, *args])
    assert result.exit_code == 2 and message in result.output
    assert not list(tmp_path.iterdir())


def test_precompute_missing_source(tmp_path):
    result = CliRunner().invoke(main, ["precompute", str(tmp_path / "nope.obj"), "-o", str(tmp_path / "a.npz")])
    assert result.exit_code == 2 and "not found" in result.output


def test_python_dash_m_lists_every_command():
    import subprocess

    for module in ("warpscatter", "warpscatter.cli.main"):
        out = subprocess.run([sys.executable, "-m", module, "--help"], capture_output=True, text=True)
        assert out.returncode == 0, out.stderr
        for command in ("render", "validate", "bench", "precompute"):
            assert command in out.stdout, (module, command)


def test_method_applies_before_validation(config_file, tmp_path, fake_pipeline):
    # an AOV that only the overriding method makes: valid, as with --set render.scattering.method
    result = invoke("render", config_file, "-o", tmp_path / "o", "--method", "fourier", "--set",
                    "output.aovs=[color,rectified]")
    assert "is made by" not in result.stderr and len(fake_pipeline) == 1  # validated and handed to the pipeline
    cfg = fake_pipeline[0]["config"]
    assert cfg.render.scattering.method == "fourier" and "rectified" in cfg.output.aovs
    assert cfg.output_name == "shot_fourier"


def test_each_command_is_a_module_and_gallery_imports_first():
    import subprocess

    from warpscatter.cli.main import main as group

    assert {name: cmd.callback.__module__ for name, cmd in group.commands.items()} == {
        "bench": "warpscatter.cli.bench", "gallery": "warpscatter.cli.gallery",
        "precompute": "warpscatter.cli.precompute", "render": "warpscatter.cli.render",
        "schema": "warpscatter.cli.validate", "sweep": "warpscatter.cli.sweep", "validate": "warpscatter.cli.validate"}
    code = "import warpscatter.cli.gallery; from warpscatter.cli.main import main; print(sorted(main.commands))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and "'gallery'" in out.stdout, out.stderr
