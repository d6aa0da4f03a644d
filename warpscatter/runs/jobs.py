"""Many renders (the frames of an animation, the cases of a sweep) through a pluggable executor (:func:`make_executor`;
the executors: docs/guide/runs.md).

A :class:`RenderTask` is plain data, so it travels to another process or machine; :func:`run_task` never raises (a
failure is a :class:`TaskResult` with its error). Tasks whose finished outputs exist with the same config are skipped
(:func:`finished`, which also decodes every image the sidecar lists: a truncated file is rendered again), so a killed
run resumes.

Local workers die with the process that started them (:func:`_die_with_parent`); a Dask task that runs longer than
:meth:`DaskExecutor.timeout` (``max(TASK_TIMEOUT_MIN_S, TASK_TIMEOUT_FACTOR x`` the median frame time so far), or
``WARPSCATTER_TASK_TIMEOUT`` seconds) is retried on another worker, then failed, so a stopped worker cannot hang a run.
"""

from __future__ import annotations

import json
import os
import signal
import statistics
import sys
import threading
import time
import traceback
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..runtime.heap import keep_freed_memory_unless_disabled

#: Executor names of :func:`make_executor`.
EXECUTORS = ("inline", "local", "dask")

#: Seconds between a local worker's checks that the process that started it is alive (where Linux's
#: ``PR_SET_PDEATHSIG`` does not end it at once).
PARENT_POLL_S = 0.5
#: Seconds an interrupted run (Ctrl-C, SIGTERM) lets its local workers clean up the frame they render before they are
#: killed.
ABORT_GRACE_S = 10.0
#: A Dask task running longer than max(TASK_TIMEOUT_MIN_S, TASK_TIMEOUT_FACTOR x the median task time so far) is
#: retried on another worker (TASK_RETRIES times), then failed; ``WARPSCATTER_TASK_TIMEOUT`` (seconds; 0: none)
#: replaces the rule. No timeout applies before the first task has finished (its time includes Warp's compile).
TASK_TIMEOUT_FACTOR = 10.0
TASK_TIMEOUT_MIN_S = 60.0
TASK_RETRIES = 1


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
    """True when the task's complete sidecar holds the same resolved config and every file it lists exists and is
    whole (:func:`_intact`: every image decodes, at the camera's size): a frame cut short by a kill renders again."""
    if task.out_dir is None:
        return False
    from ..config import validated_config

    try:
        name = validated_config(task.config, task.config_dir, Path(task.source) if task.source else None).output_name
        sidecar = json.loads((Path(task.out_dir) / f"{name}.json").read_text(encoding="utf-8"))
    except Exception:
        return False
    files = sidecar.get("files") or []
    if not (isinstance(sidecar, dict) and sidecar.get("complete") is True and sidecar.get("config") == task.config
            and isinstance(files, list) and files):
        return False
    camera = task.config.get("camera") or {}
    size = (camera.get("height"), camera.get("width"))
    return all(isinstance(f, str) and _intact(Path(task.out_dir) / f, size) for f in files)


#: Image files :func:`_intact` decodes (the others need only exist and be non-empty).
_IMAGE_SUFFIXES = (".exr", ".png", ".tif", ".tiff", ".jpg", ".jpeg", ".hdr")


def _intact(path: Path, size: tuple) -> bool:
    """A listed output file exists, is not empty and, if an image, opens at ``size`` (H, W) (unless an AOV of its own
    size) and decodes: a scanline EXR its first and last scanline (its chunks are written in order, so a truncated
    file lacks the last one; ~1 ms for 1920 x 1080, where decoding it all takes ~0.3 s), any other image every pixel
    (a truncated PNG fails)."""
    from ..io.images import OWN_SIZE_AOVS

    try:
        if not path.is_file() or path.stat().st_size == 0:
            return False
        if path.suffix.lower() not in _IMAGE_SUFFIXES:
            return True
        import OpenImageIO as oiio

        inp = oiio.ImageInput.open(str(path))
        if inp is None:
            oiio.geterror()
            return False
        try:
            spec = inp.spec()
            if path.suffix.lower() == ".exr" and spec.tile_width == 0:
                rows = [inp.read_scanlines(y, y + 1, spec.z, 0, spec.nchannels, "float")
                        for y in (spec.y, spec.y + spec.height - 1)]
                pixels = None if any(r is None for r in rows) else rows
            else:
                pixels = inp.read_image(format="float")
            if pixels is None:
                inp.geterror()
        finally:
            inp.close()
        if pixels is None:
            return False
        own_size = any(f".{aov}." in path.name for aov in OWN_SIZE_AOVS)
        return own_size or None in size or (spec.height, spec.width) == tuple(size)
    except Exception:
        return False


def run_task(task: RenderTask) -> TaskResult:
    """Render one task (in whatever process runs it); never raises: an error comes back in the result."""
    t0 = time.perf_counter()
    worker = f"{os.uname().nodename}:{os.getpid()}"
    if task.threads is not None:
        os.environ["WARPSCATTER_THREADS"] = str(task.threads)
    if task.worker_process:
        _quiet_worker()
        keep_freed_memory_unless_disabled()  # as the CLI's own process (warpscatter.runtime.heap)
    _busy.set()
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
    finally:
        _busy.clear()


#: Set while :func:`run_task` renders (a local worker's SIGINT handler reads it).
_busy = threading.Event()


def _die_with_parent(parent: int, pdeathsig: bool) -> None:
    """Initializer of a local worker process: it ends when ``parent`` (the process that started it) dies, even by
    SIGKILL, so no worker (hundreds of MB each) outlives its run.

    On Linux ``PR_SET_PDEATHSIG`` asks the kernel for a SIGKILL when the parent goes (only when ``pdeathsig``: the
    workers were started from the parent's main thread, since the kernel's "parent" is the thread that started them);
    everywhere a daemon thread checks every :data:`PARENT_POLL_S` seconds that the parent is still this process's
    parent. SIGINT (Ctrl-C, or the parent's abort) interrupts the frame being rendered, so that it removes its
    temporaries, and ends an idle worker quietly."""
    if pdeathsig and sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL), 0, 0, 0)  # 1: PR_SET_PDEATHSIG
        except Exception:  # pragma: no cover - no prctl: the watchdog below remains
            pass
    if os.getppid() != parent:  # the parent died before the line above
        os._exit(1)

    def interrupt(signum, frame):
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # once: a second SIGINT must not cut the clean-up short
        if _busy.is_set():
            raise KeyboardInterrupt
        raise SystemExit(0)

    signal.signal(signal.SIGINT, interrupt)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # SIGTERM ends a worker, whatever the main script installed

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="warpscatter-parent-watch", daemon=True).start()


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

    def abort(self) -> None:
        """Stop at once (an error or an interrupt in the caller): by default as :meth:`close`."""
        self.close()

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, exc_type, *exc) -> bool:
        if exc_type is None:
            self.close()
        else:
            self.abort()
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
    """A pool of local worker processes (``spawn``: no Warp state is forked), started by the first :meth:`run`; they
    end with this process (:func:`_die_with_parent`)."""

    name = "local"

    def __init__(self, workers: int = 2):
        super().__init__(workers)
        self._pool: ProcessPoolExecutor | None = None

    @property
    def pool(self) -> ProcessPoolExecutor:
        """The process pool; its workers start on the first submit, from the thread that submits."""
        if self._pool is None:
            import multiprocessing

            main = threading.current_thread() is threading.main_thread()
            self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=multiprocessing.get_context("spawn"),
                                             initializer=_die_with_parent, initargs=(os.getpid(), main))
        return self._pool

    def run(self, tasks: list[RenderTask]) -> Iterator[TaskResult]:
        threads = _worker_threads(self.workers)
        pool = self.pool
        futures = {pool.submit(run_task, _for_worker(t, threads)): t for t in tasks}
        for future in as_completed(futures):
            task = futures[future]
            try:
                yield future.result()
            except Exception as exc:  # the worker process died (killed, out of memory)
                yield TaskResult(label=task.label, ok=False, error=f"worker failed: {type(exc).__name__}: {exc}")

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)

    def abort(self) -> None:
        """Cancel the queued tasks, interrupt the running ones (SIGINT: each removes its temporaries) and end the
        workers; one still running after :data:`ABORT_GRACE_S` seconds is killed."""
        if self._pool is None:
            return
        processes = list((getattr(self._pool, "_processes", None) or {}).values())
        self._pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            try:
                os.kill(process.pid, signal.SIGINT)
            except (OSError, TypeError):
                pass
        deadline = time.monotonic() + ABORT_GRACE_S
        for process in processes:
            process.join(max(0.0, deadline - time.monotonic()))
            if process.is_alive():
                process.kill()
                process.join(5.0)
        self._pool.shutdown(wait=True)


class DaskExecutor(Executor):
    """Dask distributed: the scheduler at ``address``, or a ``LocalCluster`` of ``workers`` processes.

    At most one task per worker thread is in flight, so a task's age is its run time. A task older than
    :meth:`timeout` (a stopped or hung worker) is cancelled and submitted again to the other workers (``retries``
    times; its worker gets no more tasks in this run), then reported failed: the run always finishes.

    Args:
        timeout_factor, timeout_min: the timeout's rule (:data:`TASK_TIMEOUT_FACTOR`, :data:`TASK_TIMEOUT_MIN_S`).
        timeout: a fixed timeout in seconds instead (0: none; default ``WARPSCATTER_TASK_TIMEOUT``, else the rule).
        retries: submissions of a timed-out task to other workers before it fails (:data:`TASK_RETRIES`).
    """

    name = "dask"
    #: Seconds between checks of the tasks' ages.
    poll_s = 1.0

    def __init__(self, workers: int = 2, address: str | None = None, *, timeout: float | None = None,
                 timeout_factor: float = TASK_TIMEOUT_FACTOR, timeout_min: float = TASK_TIMEOUT_MIN_S,
                 retries: int = TASK_RETRIES):
        super().__init__(workers)
        self.fixed_timeout = _env_timeout() if timeout is None else float(timeout)
        self.timeout_factor, self.timeout_min, self.retries = float(timeout_factor), float(timeout_min), int(retries)
        self.address = address
        self.cluster = None
        self.client = None
        self._connect(address)

    def _connect(self, address: str | None) -> None:
        try:
            from distributed import Client, LocalCluster
        except ImportError as exc:
            raise ImportError("--executor dask needs Dask distributed: pip install 'warpscatter[distributed]'") from exc
        try:
            if address:
                self.client = Client(address, timeout="30s")
                self.workers = max(1, len(self.client.scheduler_info().get("workers", {})))
            else:
                self.cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                            dashboard_address=None, silence_logs=40)
                self.client = Client(self.cluster)
        except BaseException:  # an interrupt or a failure while starting: leave no cluster behind
            self.close()
            raise

    def describe(self) -> str:
        where = self.address or "a LocalCluster"
        return f"dask at {where} ({self.workers} worker{'s' if self.workers != 1 else ''})"

    def timeout(self, seconds: list[float]) -> float | None:
        """The timeout of a task given the run times of the tasks finished so far (None: no timeout)."""
        return task_timeout(seconds, self.timeout_factor, self.timeout_min, self.fixed_timeout)

    # ---- what the scheduling below asks of Dask (a test replaces these) ----

    def _slots(self) -> dict[str, int]:
        """Worker address -> threads."""
        workers = self.client.scheduler_info().get("workers", {})
        return {address: int(info.get("nthreads") or 1) for address, info in workers.items()}

    def _submit(self, task: RenderTask, avoid: set[str]):
        slots = [w for w in self._slots() if w not in avoid]
        return self.client.submit(run_task, task, pure=False, key=f"warpscatter-{task.label}-{os.getpid()}-"
                                  f"{time.time_ns()}", workers=slots if avoid else None, allow_other_workers=False)

    def _wait(self, futures: list, timeout: float) -> list:
        from distributed import wait

        try:
            wait(futures, timeout=timeout, return_when="FIRST_COMPLETED")
        except TimeoutError:
            pass
        return [f for f in futures if f.done()]

    def _where(self, future) -> str | None:
        try:
            return next((w for w, keys in self.client.processing().items() if future.key in keys), None)
        except Exception:
            return None

    def _cancel(self, future) -> None:
        try:
            future.cancel()
        except Exception:
            pass

    def run(self, tasks: list[RenderTask]) -> Iterator[TaskResult]:
        # a remote cluster's workers are not ours: their threads and Warp settings stay as they are
        ready = [t if self.address else _for_worker(t, _worker_threads(self.workers)) for t in tasks]
        queue = deque((t, 0) for t in ready)
        running: dict = {}  # future -> (task, submitted at, tries)
        seconds: list[float] = []
        avoid: set[str] = set()  # workers that held a timed-out task
        while queue or running:
            slots = sum(n for w, n in self._slots().items() if w not in avoid)
            if slots < 1 and queue and not running:
                why = ("no worker left: every worker timed out (stopped or hung); see WARPSCATTER_TASK_TIMEOUT"
                       if avoid else "the Dask cluster has no workers")
                for task, _ in queue:
                    yield TaskResult(label=task.label, ok=False, error=why)
                return
            while queue and len(running) < slots:
                task, tries = queue.popleft()
                running[self._submit(task, avoid)] = (task, time.monotonic(), tries)
            for future in self._wait(list(running), self.poll_s):
                task, _, _ = running.pop(future)
                try:
                    result = future.result()
                except Exception as exc:  # the worker died or the result could not travel
                    result = TaskResult(label=task.label, ok=False, error=f"worker failed: {type(exc).__name__}: {exc}")
                if result.ok:
                    seconds.append(result.seconds)
                yield result
            limit = self.timeout(seconds)
            now = time.monotonic()
            for future, (task, since, tries) in list(running.items()):
                if limit is None or now - since <= limit:
                    continue
                where = self._where(future)
                if where:
                    avoid.add(where)
                self._cancel(future)
                del running[future]
                if tries < self.retries and any(w not in avoid for w in self._slots()):
                    queue.appendleft((task, tries + 1))
                else:
                    yield TaskResult(label=task.label, ok=False, worker=where or "",
                                     error=f"timed out after {now - since:.0f} s (limit {limit:.0f} s: "
                                           f"{_timeout_rule(self, seconds)}) on {where or 'an unknown worker'}, "
                                           f"{tries + 1} tr{'ies' if tries else 'y'}")

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def task_timeout(seconds: list[float], factor: float = TASK_TIMEOUT_FACTOR, minimum: float = TASK_TIMEOUT_MIN_S,
                 fixed: float | None = None) -> float | None:
    """A task's timeout: ``fixed`` when given (0 or less: none), else ``max(minimum, factor x`` the median of
    ``seconds``, the run times of the tasks finished so far), None before the first has finished."""
    if fixed is not None:
        return fixed if fixed > 0 else None
    if not seconds:
        return None
    return max(minimum, factor * statistics.median(seconds))


def _timeout_rule(executor: DaskExecutor, seconds: list[float]) -> str:
    if executor.fixed_timeout is not None:
        return "WARPSCATTER_TASK_TIMEOUT"
    return (f"max({executor.timeout_min:g} s, {executor.timeout_factor:g} x the median task time "
            f"{statistics.median(seconds):.1f} s)")


def _env_timeout() -> float | None:
    """``WARPSCATTER_TASK_TIMEOUT`` in seconds, or None when unset."""
    text = os.environ.get("WARPSCATTER_TASK_TIMEOUT", "").strip()
    if not text:
        return None
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"WARPSCATTER_TASK_TIMEOUT: expected seconds (0: no timeout), got {text!r}") from None


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
    if skip_finished:  # a set a killed run left half-renamed is completed or rolled back before it is judged
        from ..io.output_sets import remove_stale_temporaries

        for folder in sorted({Path(t.out_dir) for t in tasks if t.out_dir is not None and Path(t.out_dir).is_dir()}):
            remove_stale_temporaries(folder)
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
           "finished", "make_executor", "run_task", "run_tasks", "task_for", "task_timeout"]
