"""Bench suite ``scaleout``: an animation's frames through each executor (:mod:`..runs.jobs`).

The bundled ``colonnade_sunset`` animation (60 frames at 640x360, fourier; ``--quick``: 6 frames at 160x90), output
sets written to a temporary folder, by each of :data:`EXECUTOR_CASES` (Dask when installed). Per executor: frames/s
over the run, the median render time of a frame as its worker measured it, and the overhead per task against the
plain loop, (wall time x workers - the sum of the tasks' own times) / frames: a worker slot's time on anything but
rendering (scheduling, pickling, idling at the end). Starting the executor and a first warm-up frame per worker
(spawning processes, importing Warp, loading kernels) are timed apart (``startup_s``).
"""

from __future__ import annotations

import statistics
import tempfile
import time

from ..config import load_config
from ..runs.jobs import make_executor, run_tasks, task_for
from ..runtime.stages import ProgressFn
from .report import BenchReport
from .scenes import bundled_config

#: (executor, workers) in the order the suite runs them.
EXECUTOR_CASES = (("inline", 1), ("local", 1), ("local", 2), ("dask", 2))


def suite_scaleout(report: BenchReport, repeats: int, warmup: int, quick: bool, progress: ProgressFn | None):
    size = (["camera.width=160", "camera.height=90", "animation.frames=6"] if quick else [])
    config = load_config(bundled_config("colonnade_sunset"), size)
    frames = config.animation.frame_numbers
    report.meta.update(scene="colonnade_sunset", frames=len(frames),
                       size=f"{config.camera.width}x{config.camera.height}", method=config.method)
    baseline_fps = None
    for k, (kind, workers) in enumerate(EXECUTOR_CASES):
        if kind == "dask":
            try:
                import distributed  # noqa: F401
            except ImportError:
                report.meta["dask"] = "not installed (pip install 'warpscatter[distributed]')"
                continue
        if progress:
            progress(f"{kind} x{workers}", k / len(EXECUTOR_CASES))
        with tempfile.TemporaryDirectory(prefix="warpscatter-scaleout-") as tmp:
            tasks = [task_for(config.at_frame(f), f"frame {f}", tmp) for f in frames]
            t0 = time.perf_counter()
            with make_executor(kind, workers) as executor:
                warm = [task_for(config.at_frame(frames[0]), f"warm-up {w}", f"{tmp}/warm") for w in range(workers)]
                run_tasks(warm, executor, skip_finished=False)
                startup = time.perf_counter() - t0
                t1 = time.perf_counter()
                results = run_tasks(tasks, executor, skip_finished=False)
                wall = time.perf_counter() - t1
                described = executor.describe()
        failed = [r.error for r in results if not r.ok]
        if failed:
            raise RuntimeError(f"scaleout: {kind} x{workers}: {len(failed)} frame(s) failed: {failed[0]}")
        own = [r.seconds for r in results]
        fps = len(frames) / wall
        baseline_fps = baseline_fps or fps
        report.add(name=f"{kind} x{workers}", params={"executor": kind, "workers": workers},
                   median_ms=1e3 * wall / len(frames), speedup=fps / baseline_fps,
                   extra={"frames_per_s": round(fps, 3), "wall_s": round(wall, 2),
                          "frame_render_ms": round(1e3 * statistics.median(own), 1),
                          "overhead_per_task_ms": round(1e3 * (wall * workers - sum(own)) / len(frames), 1),
                          "startup_s": round(startup, 2), "executor": described})
    if progress:
        progress("scaleout", 1.0)


__all__ = ["EXECUTOR_CASES", "suite_scaleout"]
