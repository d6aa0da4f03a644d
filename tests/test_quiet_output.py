"""What a user sees: warpscatter.render() writes nothing to stdout or stderr unless asked (Warp's banner and module
loads go to the ``warpscatter.warp`` logger; Warp's settings stay as they were), and a default CLI render prints
a short report."""

import logging
import subprocess
import sys
from pathlib import Path

import pytest
import warp as wp
from click.testing import CliRunner

import warpscatter
import warpscatter.pipeline
from warpscatter.cli.main import main
from warpscatter.runtime.device import warp_log, warp_messages

ROOT = Path(__file__).resolve().parent.parent
QUICKSTART = ROOT / "configs" / "quickstart.yaml"
SMALL = {"camera.width": 24, "camera.height": 14, "render.scattering.method": "raymarch",
         "render.scattering.steps": 8, "render.scattering.shadow_map.resolution": 64}


def _fresh_process(verbose: bool) -> subprocess.CompletedProcess:
    """Two renders in a new Python process (Warp not yet initialised, its modules not yet loaded)."""
    code = (f"import warpscatter\n"
            f"for _ in range(2):\n"
            f"    warpscatter.render({str(QUICKSTART)!r}, {SMALL!r}, verbose={verbose})\n")
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)


def test_render_in_a_fresh_process_prints_nothing():
    out = _fresh_process(verbose=False)
    assert out.returncode == 0, out.stderr
    assert out.stdout == "" and out.stderr == ""  # no banner, no module loads, no CUDA-driver warning


def test_render_verbose_shows_warps_messages():
    out = _fresh_process(verbose=True)
    assert out.returncode == 0, out.stderr
    assert f"Warp {wp.config.version} initialized" in out.stdout and "load on device 'cpu'" in out.stdout


def test_warm_render_prints_nothing_and_leaves_warps_settings(capfd, tmp_path):
    before = (wp.get_logger(), wp.config.log_level)
    warpscatter.render(QUICKSTART, SMALL)
    capfd.readouterr()
    warpscatter.render(QUICKSTART, SMALL, out_dir=tmp_path)
    assert capfd.readouterr() == ("", "")
    assert (wp.get_logger(), wp.config.log_level) == before
    warpscatter.render(QUICKSTART, SMALL, verbose=True)
    assert (wp.get_logger(), wp.config.log_level) == before


class _Recorder:
    """A user's own Warp logger."""

    def __init__(self):
        self.calls = []

    def debug(self, message):
        self.calls.append(("debug", message))

    def info(self, message):
        self.calls.append(("info", message))

    def warning(self, message, category=None, stacklevel=1):
        self.calls.append(("warning", message))

    def error(self, message):
        self.calls.append(("error", message))


class _Records(logging.Handler):
    def __init__(self):
        super().__init__()
        self.messages = []

    def emit(self, record):
        self.messages.append((record.levelno, record.getMessage()))


def test_warps_messages_go_to_the_logger_and_settings_come_back_after_an_error(monkeypatch, capfd):
    user = _Recorder()
    records = _Records()
    monkeypatch.setattr(wp.config, "log_level", wp.LOG_INFO)
    monkeypatch.setattr(warp_log, "propagate", False)  # the CLI tests leave a handler on "warpscatter"
    level = warp_log.level
    warp_log.setLevel(logging.INFO)
    warp_log.addHandler(records)

    def failing_render(config, **kwargs):
        with wp.ScopedTimer("inside the render"):  # Warp's info message, as its module loads are
            wp.get_logger().warning("a Warp warning")
        raise RuntimeError("kernel exploded")

    monkeypatch.setattr(warpscatter.pipeline, "render", failing_render)
    wp.set_logger(user)
    try:
        with pytest.raises(RuntimeError, match="kernel exploded"):
            warpscatter.render(QUICKSTART, SMALL)
        assert wp.get_logger() is user and wp.config.log_level == wp.LOG_INFO
    finally:
        wp.set_logger(None)
        warp_log.removeHandler(records)
        warp_log.setLevel(level)
    assert user.calls == [("warning", "a Warp warning")]  # warnings stay the user's; info goes to logging
    assert [level for level, _ in records.messages] == [logging.INFO]
    assert records.messages[0][1].startswith("inside the render took")
    assert capfd.readouterr() == ("", "")


def test_nested_quiet_blocks_restore_the_logger_once():
    before = wp.get_logger()
    with warp_messages():
        inner = wp.get_logger()
        assert inner is not before
        with warp_messages():
            assert wp.get_logger() is inner
        assert wp.get_logger() is inner
    assert wp.get_logger() is before


def test_default_cli_render_is_short_and_verbose_has_the_statistics(tmp_path, monkeypatch):
    monkeypatch.setattr(wp.config, "log_level", wp.config.log_level)  # the CLI sets Warp's log level: restore it
    args = ["render", str(QUICKSTART), "--method", "fourier", "--set", "camera.width=64", "--set",
            "camera.height=36", "-o", str(tmp_path)]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines() + result.stderr.splitlines()
    assert len(lines) <= 25, "\n".join(lines)
    assert ": fourier, 64 x 36 on cpu (" in lines[0] and " statistics: -v or quickstart" in lines[0]
    assert "coefficients" not in result.stdout and str(tmp_path / "quickstart") in result.stdout
    verbose = CliRunner().invoke(main, [*args, "-v"])
    assert verbose.exit_code == 0, verbose.output
    assert "stats:" in verbose.stdout and "  coefficients: " in verbose.stdout
    assert "other stages)" not in verbose.stdout and "\nprefilter " in verbose.stdout
