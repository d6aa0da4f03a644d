"""Many renders (the frames of an animation, the cases of a sweep) through a pluggable executor (:func:`make_executor`;
the executors: docs/guide/runs.md).

A :class:`RenderTask` is plain data, so it travels to another process or machine; :func:`run_task` never raises (a
failure is a :class:`TaskResult` with its error). Tasks whose finished outputs exist with the same config are skipped
(:func:`finished`), so a killed run resumes.
"""

from __future__ import annotations

import json
import os
import time
import traceback
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..runtime.heap import keep_freed_memory_unless_disabled

#: Executor names of :func:`make_executor`.
EXECUTORS = ("inline", "local", "dask")


@dataclass
class RenderTask:
    """One render as plain data.

    Attributes:
        label: the task's name in reports (a frame's output name, a sweep case's label).
        config: the resolved config, ``Config.model_dump(mode="json")`` (absolute paths).
        config_dir: the folder relative paths were resolved against.
        source: the config file, if any (for ``{config}`` in names and the sidecar).
        out_dir: write the output set here; None writes nothing.
        return_images: images to send back (e.g. ``("color",)`` for a sweep's error); none by default.
        threads: threads of the split CPU launches in the worker (None: the worker's default).
        device: the Warp device to render on (None: the worker's default).
        worker_process: True in a worker process this run started: Warp kept quiet and freed buffers kept, as the CLI.
    """

    label: str
    config: dict
    config_dir: str
    source: str | None = None
    out_dir: str | None = None
    return_images: tuple[str, ...] = ()
    threads: int | None = None
    device: str | None = None
    worker_process: bool = False


@dataclass
class TaskResult:
    """What one task gave: ``ok`` with files, timings (s per stage), stats and the images asked for, or the error
    (``error``: the exception's type and message; ``details``: its traceback). ``skipped``: already done."""

    label: str
    ok: bool
    files: list[str] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    seconds: float = 0.0
    error: str | None = None
    details: str | None = None
    images: dict[str, Any] = field(default_factory=dict)
    skipped: bool = False
    worker: str = ""


def task_for(config, label: str, out_dir: str | Path | None = None, return_images: Iterable[str] = (),
             threads: int | None = None, device: str | None = None) -> RenderTask:
    """The :class:`RenderTask` of a validated config (``output.dir`` set to ``out_dir`` when given); ``threads``
    defaults to ``WARPSCATTER_THREADS``."""
    if threads is None and os.environ.get("WARPSCATTER_THREADS"):
        threads = int(os.environ["WARPSCATTER_THREADS"])
    if out_dir is not None:
        config = config.model_copy()
        config.output = config.output.model_copy(update={"dir": Path(out_dir).resolve()})
    return RenderTask(label=label, config=config.model_dump(mode="json"), config_dir=str(config.config_dir),
                      source=str(config.source) if config.source else None,
                      out_dir=str(Path(out_dir).resolve()) if out_dir is not None else None,
                      return_images=tuple(return_images), threads=threads,
                      device=None if device is None else str(device))


def finished(task: RenderTask) -> bool:
    """True when the task's complete sidecar holds the same resolved config and every file it lists exists."""
    if task.out_dir is None:
        return False
    from ..config import validated_config

    try:
        name = validated_config(task.config, task.config_dir, Path(task.source) if task.source else None).output_name
        sidecar = json.loads((Path(task.out_dir) / f"{name}.json").read_text(encoding="utf-8"))
    except Exception:
        return False
    files = sidecar.get("files") or []
    return sidecar.get("complete") is True and sidecar.get("config") == task.config and bool(files) and \
        all((Path(task.out_dir) / f).is_file() for f in files)


def run_task(task: RenderTask) -> TaskResult:
    """Render one task (in whatever process runs it); never raises: an error comes back in the result."""
    t0 = time.perf_counter()
    worker = f"{os.uname().nodename}:{os.getpid()}"
    if task.threads is not None:
        os.environ["WARPSCATTER_THREADS"] = str(task.threads)
    if task.worker_process:
        _quiet_worker()
        keep_freed_memory_unless_disabled()  # as the CLI's own process (warpscatter.runtime.heap)
    try:
        from ..config import validated_config
        from ..pipeline import render

        config = validated_config(task.config, task.config_dir, Path(task.source) if task.source else None)
        out = render(config, out_dir=task.out_dir, write=task.out_dir is not None, device=task.device)
        return TaskResult(label=task.label, ok=True, files=[str(f) for f in out.files], timings=dict(out.timings),
                          stats=out.stats, seconds=time.perf_counter() - t0, worker=worker,
                          images={k: out.images[k] for k in task.return_images if k in out.images})
    except Exception as exc:
        return TaskResult(label=task.label, ok=False, error=f"{type(exc).__name__}: {exc}",
                          details=traceback.format_exc(), seconds=time.perf_counter() - t0, worker=worker)


def _quiet_worker() -> None:
    """A worker process is ours: Warp's start-up and module-load messages stay out of the run's output."""
    import warp as wp

    from ..runtime.device import init

    if wp.config.log_level < wp.LOG_WARNING:
        wp.config.log_level = wp.LOG_WARNING
    init(quiet_native=True)


def _worker_threads(workers: int) -> int:
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - non-Linux
        cores = os.cpu_count() or 1
    return max(1, cores // max(1, workers))


class Executor(ABC):
    """Runs tasks and yields their results as they complete (:meth:`run`); a context manager."""

    name = "executor"

    def __init__(self, workers: int = 1):
        self.workers = max(1, int(workers))

    @abstractmethod
    def run(self, tasks: list[RenderTask]) -> Iterator[TaskResult]:
        """Run ``tasks``; yield one :class:`TaskResult` per task as each completes (any order)."""

    def close(self) -> None:  # noqa: B027 (optional: an executor without workers has nothing to release)
        """Release the workers (nothing by default)."""

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc) -> bool:
        self.close()
        return False

    def describe(self) -> str:
        return f"{self.name} ({self.workers} worker{'s' if self.workers != 1 else ''})"


class InlineExecutor(Executor):
    """A plain loop in this process."""

    name = "inline"

    def run(self, tasks: list[RenderTask]) -> Iterator[TaskResult]:
        for task in tasks:
            yield run_task(task)


class LocalExecutor(Executor):
    """A pool of local worker processes (``spawn``: no Warp state is forked)."""

    name = "local"

    def __init__(self, workers: int = 2):
        super().__init__(workers)
        import multiprocessing

        self.pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=multiprocessing.get_context("spawn"))

    def run(self, tasks: list[RenderTask]) -> Iterator[TaskResult]:
        threads = _worker_threads(self.workers)
        futures = {self.pool.submit(run_task, _for_worker(t, threads)): t for t in tasks}
        for future in as_completed(futures):
            task = futures[future]
            try:
                yield future.result()
            except Exception as exc:  # the worker process died (killed, out of memory)
                yield TaskResult(label=task.label, ok=False, error=f"worker failed: {type(exc).__name__}: {exc}")

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)


class DaskExecutor(Executor):
    """Dask distributed: the scheduler at ``address``, or a ``LocalCluster`` of ``workers`` processes."""

    name = "dask"

    def __init__(self, workers: int = 2, address: str | None = None):
        super().__init__(workers)
        try:
            from distributed import Client, LocalCluster
        except ImportError as exc:
            raise ImportError("--executor dask needs Dask distributed: pip install 'warpscatter[distributed]'") from exc
        self.address = address
        self.cluster = None
        if address:
            self.client = Client(address, timeout="30s")
            self.workers = max(1, len(self.client.scheduler_info().get("workers", {})))
        else:
            self.cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                        dashboard_address=None, silence_logs=40)
            self.client = Client(self.cluster)

    def describe(self) -> str:
        where = self.address or "a LocalCluster"
        return f"dask at {where} ({self.workers} worker{'s' if self.workers != 1 else ''})"

    def run(self, tasks: list[RenderTask]) -> Iterator[TaskResult]:
        from distributed import as_completed as dask_completed

        # a remote cluster's workers are not ours: their threads and Warp settings stay as they are
        ready = [t if self.address else _for_worker(t, _worker_threads(self.workers)) for t in tasks]
        futures = self.client.map(run_task, ready, pure=False,
                                  key=[f"warpscatter-{t.label}-{os.getpid()}-{time.time_ns()}" for t in tasks])
        labels = {f.key: t.label for f, t in zip(futures, tasks, strict=True)}
        for future in dask_completed(futures):
            try:
                yield future.result()
            except Exception as exc:  # the worker died or the result could not travel
                yield TaskResult(label=labels[future.key], ok=False,
                                 error=f"worker failed: {type(exc).__name__}: {exc}")

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def _for_worker(task: RenderTask, threads: int | None) -> RenderTask:
    """The task as a worker process runs it: quiet Warp, and ``threads`` unless the task names its own."""
    return RenderTask(**{**task.__dict__, "worker_process": True,
                         "threads": task.threads if task.threads is not None else threads})


def make_executor(kind: str = "inline", workers: int | None = None, address: str | None = None) -> Executor:
    """An executor by name (:data:`EXECUTORS`).

    Args:
        kind: ``inline``, ``local`` or ``dask``.
        workers: worker processes (``local``: default 2; ``dask`` LocalCluster: default 2); ignored by ``inline``.
        address: ``dask`` only: a scheduler address; None starts a LocalCluster.

    Raises:
        ValueError: an unknown kind, or an address for another kind.
        ImportError: ``dask`` without Dask distributed installed.
    """
    if kind not in EXECUTORS:
        raise ValueError(f"executor: must be one of {', '.join(EXECUTORS)}, got {kind!r}")
    if address and kind != "dask":
        raise ValueError(f"--address is for the dask executor (the executor is {kind!r})")
    if kind == "inline":
        return InlineExecutor(1)
    if kind == "local":
        return LocalExecutor(workers or 2)
    return DaskExecutor(workers or 2, address)


def run_tasks(tasks: list[RenderTask], executor: Executor, *, skip_finished: bool = True,
              progress: Callable[[str, float], None] | None = None, stage: str = "renders") -> list[TaskResult]:
    """Run tasks through an executor (skipping finished ones when ``skip_finished``); results in the tasks' order."""
    results: dict[str, TaskResult] = {}
    todo = []
    for task in tasks:
        if skip_finished and finished(task):
            results[task.label] = TaskResult(label=task.label, ok=True, skipped=True)
        else:
            todo.append(task)
    if progress is not None:
        progress(stage, len(results) / max(1, len(tasks)))
    for result in executor.run(todo):
        results[result.label] = result
        if progress is not None:
            progress(stage, len(results) / max(1, len(tasks)))
    return [results[t.label] for t in tasks]


__all__ = ["EXECUTORS", "DaskExecutor", "Executor", "InlineExecutor", "LocalExecutor", "RenderTask", "TaskResult",
           "finished", "make_executor", "run_task", "run_tasks", "task_for"]
