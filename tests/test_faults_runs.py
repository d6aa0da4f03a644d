"""Fault injection on runs of many renders (issue #52, items 3 and 4): local workers die with a killed parent, a
stopped Dask worker cannot hang a run, SIGTERM during start-up exits 130, and resume re-renders a truncated frame."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner
from data_files import ANIMATED

from warpscatter.cli.main import main
from warpscatter.config import load_config
from warpscatter.runs.animation import render_animation
from warpscatter.runs.jobs import DaskExecutor, RenderTask, TaskResult, finished, run_tasks, task_for, task_timeout


@pytest.fixture
def animated(tmp_path):
    path = tmp_path / "sun.yaml"
    path.write_text(yaml.safe_dump(ANIMATED))
    return path


# ---- processes -----------------------------------------------------------------------------------------------------


def _children(pid: int) -> list[int]:
    found = []
    for task in Path(f"/proc/{pid}/task").glob("*/children"):
        try:
            found += [int(x) for x in task.read_text().split()]
        except OSError:
            pass
    return found


def _descendants(pid: int) -> list[int]:
    seen, todo = [], _children(pid)
    while todo:
        p = todo.pop()
        seen.append(p)
        todo += _children(p)
    return seen


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except (OSError, IndexError):
        return False


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_killed_local_run_leaves_no_process_behind(animated, tmp_path):
    data = yaml.safe_load(animated.read_text())
    data["animation"]["frames"] = 40
    data["camera"].update(width=160, height=90)
    animated.write_text(yaml.safe_dump(data))
    cmd = [sys.executable, "-m", "warpscatter", "render", str(animated), "-o", str(tmp_path / "out"), "--executor",
           "local", "--workers", "2", "-q"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.time() + 120
        while len(_descendants(proc.pid)) < 3 and proc.poll() is None and time.time() < deadline:
            time.sleep(0.05)  # two workers and multiprocessing's resource tracker
        kids = _descendants(proc.pid)
        assert len(kids) >= 3 and proc.poll() is None, kids
        os.kill(proc.pid, signal.SIGKILL)  # the parent only
        proc.wait()
        deadline = time.time() + 5
        while any(_alive(k) for k in kids) and time.time() < deadline:
            time.sleep(0.05)
        assert not [k for k in kids if _alive(k)]
    finally:
        for k in _descendants(proc.pid) + (kids if "kids" in locals() else []):
            if _alive(k):
                os.kill(k, signal.SIGKILL)
        if proc.poll() is None:
            proc.kill()


# ---- SIGTERM during start-up ---------------------------------------------------------------------------------------


def test_sigterm_while_importing_the_cli_exits_130():
    """The console script's entry (cli/entry.py) gets a SIGTERM while it imports the click application."""
    code = ("import builtins, os, signal, sys\nfrom warpscatter.cli import entry\n"
            "sys.argv = ['warpscatter', 'validate', '--help']\nreal = builtins.__import__\n"
            "def traced(name, *args, **kwargs):\n"
            "    if name == 'click':\n        os.kill(os.getpid(), signal.SIGTERM)\n"
            "    return real(name, *args, **kwargs)\n"
            "builtins.__import__ = traced\nentry.run()\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 130 and "interrupted" in done.stderr and "Traceback" not in done.stderr


def test_an_interrupt_before_the_render_exits_130_not_aborted(animated, tmp_path, monkeypatch):
    import warpscatter.cli.render as render_cli

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt  # SIGTERM (raised as KeyboardInterrupt by the CLI) while loading Warp

    monkeypatch.setattr(render_cli, "setup", interrupted)
    result = CliRunner().invoke(main, ["render", str(animated), "-o", str(tmp_path / "out")])
    assert result.exit_code == 130, result.output
    assert "Aborted!" not in result.output and "error: interrupted" in result.stderr
    assert not (tmp_path / "out").exists()


# ---- resume --------------------------------------------------------------------------------------------------------


def _truncate(path: Path, keep: float = 0.5) -> None:
    data = path.read_bytes()
    path.write_bytes(data[:int(len(data) * keep)])


def test_resume_renders_a_truncated_frame_again(animated, tmp_path):
    config = load_config(animated)
    out = tmp_path / "out"
    assert len(render_animation(config, out, frames=[1, 2]).rendered) == 2
    _truncate(out / "sun.0001.exr")
    stamp = (out / "sun.0002.exr").stat().st_mtime_ns
    again = render_animation(config, out, frames=[1, 2])
    assert [r.skipped for r in again.frames] == [False, True]
    assert (out / "sun.0002.exr").stat().st_mtime_ns == stamp
    from warpscatter.io.images import read_image

    assert read_image(out / "sun.0001.exr").shape[:2] == (14, 24)


def test_resume_settles_a_half_renamed_set_before_judging_it(animated, tmp_path, monkeypatch):
    """A commit manifest a killed writer left is completed or rolled back (output_sets) before resume reads the
    sidecars: run_tasks cleans every output folder first."""
    from warpscatter.io import output_sets

    config = load_config(animated)
    render_animation(config, tmp_path, frames=[1])
    cleaned = []
    real = output_sets.remove_stale_temporaries
    monkeypatch.setattr(output_sets, "remove_stale_temporaries", lambda folder: cleaned.append(folder) or real(folder))
    again = render_animation(config, tmp_path, frames=[1])
    assert [r.skipped for r in again.frames] == [True]
    assert cleaned and Path(cleaned[0]) == tmp_path


@pytest.mark.parametrize("damage", ["truncated png", "truncated aov", "exr tail cut", "empty", "wrong size", "missing",
                                    "bad list"])
def test_finished_verifies_every_listed_file(animated, tmp_path, damage):
    config = load_config(animated)
    render_animation(config, tmp_path, frames=[1])
    task = task_for(config.at_frame(1), "sun.0001", tmp_path)
    assert finished(task)
    if damage == "truncated png":
        _truncate(tmp_path / "sun.0001.png")
    elif damage == "truncated aov":
        _truncate(tmp_path / "sun.0001.depth.exr", 0.8)
    elif damage == "exr tail cut":  # only its last scanlines missing
        _truncate(tmp_path / "sun.0001.exr", 0.97)
    elif damage == "empty":
        (tmp_path / "sun.0001.exr").write_bytes(b"")
    elif damage == "wrong size":  # another frame's image of another size in its place
        task.config = {**task.config, "camera": {**task.config["camera"], "width": 25}}
        sidecar = json.loads((tmp_path / "sun.0001.json").read_text())
        (tmp_path / "sun.0001.json").write_text(json.dumps({**sidecar, "config": task.config}))
    elif damage == "missing":
        (tmp_path / "sun.0001.depth.exr").unlink()
    else:
        sidecar = json.loads((tmp_path / "sun.0001.json").read_text())
        (tmp_path / "sun.0001.json").write_text(json.dumps({**sidecar, "files": [None]}))
    assert not finished(task)


# ---- Dask task timeouts ----------------------------------------------------------------------------------------------


def test_task_timeout_rule():
    assert task_timeout([]) is None  # nothing measured yet: the first task includes Warp's compile
    assert task_timeout([1.0, 2.0, 30.0]) == 60.0  # max(60 s, 10 x median 2 s)
    assert task_timeout([10.0, 12.0, 11.0]) == 110.0
    assert task_timeout([1.0], factor=3, minimum=0.5) == 3.0
    assert task_timeout([1.0], fixed=5) == 5 and task_timeout([1.0], fixed=0) is None


def test_a_bad_task_timeout_setting_is_refused(animated, monkeypatch):
    pytest.importorskip("distributed")
    monkeypatch.setenv("WARPSCATTER_TASK_TIMEOUT", "soon")
    result = CliRunner().invoke(main, ["render", str(animated), "--executor", "dask", "--frames", "1"])
    assert result.exit_code == 2 and "WARPSCATTER_TASK_TIMEOUT" in result.stderr


class _Future:
    def __init__(self, task: RenderTask, worker: str, ready_at: float | None):
        self.task, self.worker, self.ready_at, self.key = task, worker, ready_at, f"k-{task.label}-{time.time_ns()}"
        self.cancelled = False

    def done(self) -> bool:
        return self.ready_at is not None and time.monotonic() >= self.ready_at

    def result(self) -> TaskResult:
        return TaskResult(label=self.task.label, ok=True, seconds=0.01, worker=self.worker)


class _FakeDask(DaskExecutor):
    """DaskExecutor's scheduling over a fake cluster: worker ``stuck`` never finishes a task (SIGSTOP), the others
    finish each in 10 ms."""

    poll_s = 0.02

    def __init__(self, workers=("stuck", "ok"), **timeouts):
        self.workers, self.address, self.cluster, self.client = len(workers), "fake", None, None
        self.fixed_timeout = timeouts.pop("timeout", None)
        self.timeout_factor, self.timeout_min = timeouts.pop("factor", 10.0), timeouts.pop("minimum", 0.3)
        self.retries = timeouts.pop("retries", 1)
        self.names, self.futures, self.cancelled, self.placed = list(workers), [], [], {}

    def _slots(self):
        return dict.fromkeys(self.names, 1)

    def _submit(self, task, avoid):  # as Dask's scheduler: to the allowed worker with the fewest running tasks
        allowed = [w for w in self.names if w not in avoid]
        busy = {w: sum(1 for f in self.futures if f.worker == w and not f.done() and not f.cancelled) for w in allowed}
        worker = min(allowed, key=lambda w: busy[w])
        self.placed.setdefault(task.label, []).append(worker)
        future = _Future(task, worker, None if worker == "stuck" else time.monotonic() + 0.01)
        self.futures.append(future)
        return future

    def _wait(self, futures, timeout):
        end = time.monotonic() + timeout
        while time.monotonic() < end and not any(f.done() for f in futures):
            time.sleep(0.002)
        return [f for f in futures if f.done()]

    def _where(self, future):
        return future.worker

    def _cancel(self, future):
        future.cancelled = True
        self.cancelled.append(future.task.label)

    def close(self):
        pass


def _tasks(n: int) -> list[RenderTask]:
    return [RenderTask(label=f"t{i}", config={}, config_dir=".") for i in range(n)]


def test_a_task_on_a_stopped_worker_is_retried_elsewhere_and_the_run_finishes():
    executor = _FakeDask()
    t0 = time.monotonic()
    results = run_tasks(_tasks(6), executor, skip_finished=False)
    assert time.monotonic() - t0 < 5
    assert all(r.ok for r in results) and {r.worker for r in results} == {"ok"}
    assert executor.cancelled == ["t0"] and executor.placed["t0"] == ["stuck", "ok"]
    assert all(w == "ok" for label, ws in executor.placed.items() if label != "t0" for w in ws)


def test_a_task_that_times_out_everywhere_fails_clearly():
    executor = _FakeDask(workers=("stuck", "ok"), retries=0)
    results = run_tasks(_tasks(3), executor, skip_finished=False)
    assert [r.ok for r in results] == [False, True, True]
    assert "timed out after" in results[0].error and "10 x the median task time" in results[0].error
    only_stuck = _FakeDask(workers=("stuck",), timeout=0.2)
    results = run_tasks(_tasks(2), only_stuck, skip_finished=False)
    assert not any(r.ok for r in results)
    assert "timed out" in results[0].error and "no worker left" in results[1].error


@pytest.mark.slow
def test_a_stopped_dask_worker_does_not_hang_the_run(animated, tmp_path):
    pytest.importorskip("distributed")
    config = load_config(animated)
    tasks = [task_for(config.at_frame(f), f"f{k}", tmp_path / str(k)) for k, f in enumerate([1, 2, 3, 1])]
    t0 = time.monotonic()
    victim = None
    try:
        with DaskExecutor(2, timeout_min=3.0) as executor:
            pids = executor.client.run(os.getpid)
            victim = pids[sorted(pids)[0]]
            os.kill(victim, signal.SIGSTOP)  # stays stopped while the run goes on and the cluster closes
            results = run_tasks(tasks, executor, skip_finished=False)
    finally:
        if victim is not None and _alive(victim):
            os.kill(victim, signal.SIGKILL)
    assert all(r.ok for r in results), [r.error for r in results]
    assert {r.worker.rsplit(":", 1)[1] for r in results} == {str(p) for p in pids.values() if p != victim}
    assert time.monotonic() - t0 < 60
