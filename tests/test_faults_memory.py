"""Issue 52 item 1, the render's own size: ``--frames`` ranges checked arithmetically (never materialised) and a
render's estimated peak memory compared with the memory available before any work (warpscatter/pipeline/memory.py):
exit 2 naming the option or keys, no traceback, nothing written, little memory used."""

import contextlib
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import pytest
from click.testing import CliRunner
from peak_memory import PEAK_BYTES, cli_with_peak

from warpscatter.cli.main import main
from warpscatter.config import load_config
from warpscatter.errors import ConfigError
from warpscatter.pipeline import memory
from warpscatter.runs.animation import parse_frames
from warpscatter.schema import MAX_FRAMES

ROOT = Path(__file__).resolve().parents[1]
#: A bound on the data segment of the CLI subprocesses: the code before the fixes tried to take gigabytes (a list of
#: 10^9 frames, a 16384^2 render) and fails there quickly instead of taking the machine's memory.
DATA_LIMIT = 3 << 30


def _cli(*args: str, env: dict | None = None, timeout: float = 60) -> tuple[subprocess.CompletedProcess, float, int]:
    """``warpscatter ARGS`` in a subprocess with a bounded data segment: (result, wall s, its peak RSS in bytes)."""

    def limit():
        resource.setrlimit(resource.RLIMIT_DATA, (DATA_LIMIT, DATA_LIMIT))

    start = time.perf_counter()
    result, peak = cli_with_peak(args, timeout=timeout, preexec_fn=limit, env={**os.environ, **(env or {})}, cwd=ROOT)
    return result, time.perf_counter() - start, peak


# ---- frame ranges ---------------------------------------------------------------------------------------------------


@contextlib.contextmanager
def _bounded_data(extra: int = 512 << 20):
    """This process's data segment bounded to what it holds now plus ``extra`` (Linux): code that materialises a huge
    range raises MemoryError here instead of taking the machine's memory."""
    try:
        status = Path("/proc/self/status").read_text(encoding="ascii")
        held = int(next(line.split()[1] for line in status.splitlines() if line.startswith("VmData:"))) * 1024
    except (OSError, StopIteration, ValueError):
        yield
        return
    soft, hard = resource.getrlimit(resource.RLIMIT_DATA)
    resource.setrlimit(resource.RLIMIT_DATA, (held + extra, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_DATA, (soft, hard))


@pytest.mark.parametrize("text", ["1:1000000000", "1:99999999999999999999", "0:60", "5:3", "-99999999999:1", "61"])
def test_frame_ranges_outside_the_animation_are_refused_arithmetically(text):
    start = time.perf_counter()
    with _bounded_data(), pytest.raises(ValueError, match=r"--frames .*the animation has frames 1\.\.60"):
        parse_frames(text, 1, 60)
    assert time.perf_counter() - start < 0.5


def test_frame_ranges_inside_the_animation_still_parse():
    assert parse_frames("2:8:3", 1, 60) == [2, 5, 8]
    assert parse_frames("1:60:99999999999999999999999", 1, 60) == [1]
    assert parse_frames("3,1", 1, 60) == [3, 1]
    assert parse_frames(None, 1, 3) == [1, 2, 3]
    with pytest.raises(ValueError, match="expected A:B"):
        parse_frames("1:x", 1, 60)


def test_too_many_frame_numbers_are_refused():
    with pytest.raises(ValueError, match=f"at most {MAX_FRAMES} frame numbers"):
        parse_frames(",".join(["1"] * (MAX_FRAMES + 1)), 1, 60)


def test_cli_refuses_a_billion_frames_fast_with_little_memory(tmp_path):
    result, seconds, rss = _cli("render", "configs/colonnade_sunset.yaml", "-o", str(tmp_path), "--frames",
                                "1:1000000000")
    assert result.returncode == 2, result.stderr
    assert "--frames 1:1000000000: the animation has frames 1..60" in result.stderr
    assert "Traceback" not in result.stderr and not list(tmp_path.iterdir())
    assert seconds < 20 and rss < 1 << 30, (seconds, rss)



def test_a_sweep_grid_is_counted_not_built(tmp_path):
    """Three 199-value grid keys are 7.9 million cases: refused from their count, in well under a second of work."""
    import yaml

    sweep = tmp_path / "s.yaml"
    keys = ("camera.width", "camera.height", "render.scattering.shadow_map.resolution")
    grid = {k: list(range(1, 200)) for k in keys}
    sweep.write_text(yaml.safe_dump({"configs": [str(ROOT / "configs" / "quickstart.yaml")], "grid": grid}))
    result, seconds, rss = _cli("sweep", str(sweep), "-o", str(tmp_path / "out"))
    assert result.returncode == 2, result.stderr
    assert "grid: 7.88e+06 cases (configs x cases x grid points); at most 10000" in result.stderr
    assert not (tmp_path / "out").exists() and rss < 1 << 30, rss

# ---- the memory estimate and budget ---------------------------------------------------------------------------------


def _config(name: str = "quickstart.yaml", **overrides):
    return load_config(ROOT / "configs" / name, overrides)


def test_budget_variable_parses_bytes_and_suffixes(monkeypatch):
    assert memory.parse_bytes("1048576") == 1 << 20
    assert memory.parse_bytes("8G") == 8 << 30
    assert memory.parse_bytes("1.5gib") == 3 << 29
    assert memory.parse_bytes("512M") == 512 << 20
    for bad in ("", "lots", "-1G", "8X", "0"):
        with pytest.raises(ConfigError, match="WARPSCATTER_MEMORY_LIMIT: expected bytes"):
            memory.parse_bytes(bad)
    monkeypatch.setenv(memory.MEMORY_LIMIT_ENV, "2G")
    assert memory.memory_budget() == (2 << 30, memory.MEMORY_LIMIT_ENV)


@pytest.mark.parametrize("name, overrides", [
    ("quickstart.yaml", {}),
    ("canopy_moments.yaml", {}),
    ("colonnade.yaml", {"render.scattering.method": "epipolar"}),
    ("quickstart.yaml", {"render.scattering.method": "raymarch"}),
    ("csm_area.yaml", {}),
])
def test_estimate_grows_with_the_image_and_the_maps(name, overrides):
    small = memory.estimate_peak_bytes(_config(name, **overrides, **{"camera.width": 320, "camera.height": 180}))
    large = memory.estimate_peak_bytes(_config(name, **overrides, **{"camera.width": 1280, "camera.height": 720}))
    assert memory.BASE_BYTES < small < large < 2 << 30
    assert large - small >= 1280 * 720 * 100  # at least 100 bytes per added pixel (measured 129 to 247)


def test_estimate_counts_the_rectified_maps():
    lo = memory.estimate_terms(_config(**{"render.scattering.shadow_map.resolution": 512}))
    hi = memory.estimate_terms(_config(**{"render.scattering.shadow_map.resolution": 2048}))
    assert hi["rectified maps"] == 16 * lo["rectified maps"] and hi["frame"] == lo["frame"]


def test_a_16384_square_render_is_refused_under_a_budget(monkeypatch):
    monkeypatch.setenv(memory.MEMORY_LIMIT_ENV, "16G")
    config = _config(**{"camera.width": 16384, "camera.height": 16384, "camera.supersample": 1})
    with pytest.raises(ConfigError) as err:
        memory.check_memory(config)
    text = str(err.value)
    assert "camera.width/height: a 16384 x 16384 render needs an estimated" in text
    assert "more than the 16.0 GiB available (WARPSCATTER_MEMORY_LIMIT)" in text
    assert memory.check_memory(_config()) == memory.estimate_peak_bytes(_config())  # the bundled size fits


def test_maps_heavier_than_the_frame_are_named(monkeypatch):
    monkeypatch.setenv(memory.MEMORY_LIMIT_ENV, "1G")
    with pytest.raises(ConfigError, match="camera.width/height, render.scattering.shadow_map.resolution: a 320 x 180"):
        memory.check_memory(_config(**{"camera.width": 320, "camera.height": 180, "camera.supersample": 1,
                                       "render.scattering.shadow_map.resolution": 8192}))


@pytest.mark.skipif(not Path("/proc/meminfo").exists(), reason="MemAvailable is read from /proc/meminfo")
def test_a_render_beyond_any_machine_is_refused_on_the_machines_own_memory(monkeypatch):
    monkeypatch.delenv(memory.MEMORY_LIMIT_ENV, raising=False)
    config = _config(**{"camera.width": 16384, "camera.height": 16384, "camera.supersample": 1,
                        "render.scattering.shadow_map.resolution": 16384, "render.scattering.fourier.coefficients": 128,
                        "render.shadows.method": "msm", "render.shadows.supersampling": 8,
                        "render.shadows.coloured": True, "render.scattering.prefiltered.mip_levels": 2})
    assert memory.estimate_peak_bytes(config) > 1 << 40  # > 1 TiB
    with pytest.raises(ConfigError, match=r"GiB available \((MemAvailable|the cgroup's memory.max) \+ this process\)"):
        memory.check_memory(config)


def test_cli_render_refuses_before_any_work(tmp_path):
    result, seconds, rss = _cli("render", "configs/quickstart.yaml", "-o", str(tmp_path), "--set", "camera.width=16384",
                                "--set", "camera.height=16384", "--set", "camera.supersample=1",
                                env={memory.MEMORY_LIMIT_ENV: "16G"})
    assert result.returncode == 2, result.stderr
    assert "camera.width/height: a 16384 x 16384 render needs an estimated" in result.stderr
    assert "Traceback" not in result.stderr and not list(tmp_path.iterdir())
    assert seconds < 20 and rss < 1 << 30, (seconds, rss)


def test_cli_render_checks_every_frame_of_an_animation(tmp_path):
    result, _, _ = _cli("render", "configs/colonnade_sunset.yaml", "-o", str(tmp_path), "--frames", "1:2",
                        env={memory.MEMORY_LIMIT_ENV: "100M"})
    assert result.returncode == 2, result.stderr
    assert "more than the 0.1 GiB available (WARPSCATTER_MEMORY_LIMIT)" in result.stderr
    assert not list(tmp_path.iterdir())


def test_python_api_render_refuses_before_any_work(monkeypatch, tmp_path):
    from warpscatter.pipeline import render

    monkeypatch.setenv(memory.MEMORY_LIMIT_ENV, "100M")
    with pytest.raises(ConfigError, match="camera.width/height"):
        render(_config(**{"camera.width": 64, "camera.height": 32}), out_dir=tmp_path)
    assert not list(tmp_path.iterdir())


def test_validate_reports_the_estimate_and_refuses_what_does_not_fit(monkeypatch):
    runner = CliRunner()
    monkeypatch.setenv(memory.MEMORY_LIMIT_ENV, "64G")
    ok = runner.invoke(main, ["validate", str(ROOT / "configs" / "quickstart.yaml")])
    assert ok.exit_code == 0 and "memory:  estimated peak" in ok.output and "of 64.0 GiB available" in ok.output
    monkeypatch.setenv(memory.MEMORY_LIMIT_ENV, "16G")
    big = runner.invoke(main, ["validate", str(ROOT / "configs" / "quickstart.yaml"), "--set", "camera.width=16384",
                               "--set", "camera.height=16384", "--set", "camera.supersample=1"])
    assert big.exit_code == 2 and "needs an estimated" in big.output
    monkeypatch.setenv(memory.MEMORY_LIMIT_ENV, "lots")
    bad = runner.invoke(main, ["validate", str(ROOT / "configs" / "quickstart.yaml")])
    assert bad.exit_code == 2 and "WARPSCATTER_MEMORY_LIMIT: expected bytes" in bad.output


@pytest.mark.slow
def test_the_estimate_bounds_a_measured_render(tmp_path):
    """A real render's peak RSS lies under the estimate and within 1.5x of it (the calibration's promise)."""
    sets = {"camera.width": 320, "camera.height": 180, "camera.supersample": 1,
            "render.scattering.shadow_map.resolution": 512}
    code = ("import resource, sys; from warpscatter import load_config, render; "
            f"render(load_config('configs/quickstart.yaml', {sets!r}), out_dir={str(tmp_path)!r}); "
            f"print({PEAK_BYTES})")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr
    peak = int(out.stdout.split()[-1])
    estimate = memory.estimate_peak_bytes(_config(**sets))
    assert peak <= estimate <= 1.5 * peak, (peak, estimate)
