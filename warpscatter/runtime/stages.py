"""Named, timed stages with progress: the one stage context of every render, method and bench case.

A :class:`StageTimer` times named stages (those of the timing tables and logs) and forwards progress as
``progress(stage, fraction)``; a stage run twice accumulates, and leaving one synchronises Warp::

    with timer("scattering") as stage:
        launch_rows(kernel, dim, inputs, progress=stage.report)

An :class:`EtaEstimator` turns the same reports into the time left (the CLI's progress display).
"""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Iterable, Mapping
from typing import Callable, NamedTuple

import warp as wp

#: ``progress(stage, fraction)``: the stage name and the fraction of it done, in [0, 1].
ProgressFn = Callable[[str, float], None]
#: ``report(fraction)``: progress inside one stage.
ReportFn = Callable[[float], None]


class Stage:
    """One running stage of a :class:`StageTimer` (a context manager)."""

    def __init__(self, timer: StageTimer, name: str):
        self.timer = timer
        self.name = name
        self.t0 = 0.0

    def __enter__(self) -> Stage:
        self.report(0.0)
        self.t0 = time.perf_counter()
        return self

    def report(self, fraction: float) -> None:
        """Progress inside the stage (0..1)."""
        if self.timer.progress is not None:
            self.timer.progress(self.name, fraction)

    def __exit__(self, *exc) -> bool:
        wp.synchronize()
        self.timer.add(self.name, time.perf_counter() - self.t0)
        if exc[0] is None:
            self.report(1.0)
        return False


class StageTimer:
    """Times named stages into ``timings`` (name -> seconds, in the order they first ran) and reports their
    progress to ``progress(stage, fraction)`` (:data:`ProgressFn`, or None)."""

    def __init__(self, progress: ProgressFn | None = None):
        self.timings: OrderedDict[str, float] = OrderedDict()
        self.progress = progress

    def __call__(self, name: str) -> Stage:
        """A context manager timing stage ``name``."""
        return Stage(self, name)

    def add(self, name: str, seconds: float) -> None:
        """Add ``seconds`` to stage ``name`` (for work timed outside a ``with`` block, e.g. one progressive pass)."""
        self.timings[name] = self.timings.get(name, 0.0) + seconds


class Estimate(NamedTuple):
    """What :meth:`EtaEstimator.estimate` returns: ``seconds`` left (None when nothing tells it yet), ``complete``
    when they include the stages still to come (else the running stage's rest only)."""

    seconds: float | None
    complete: bool


class EtaEstimator:
    """The time left of a run of named stages, from each stage's own measured rate.

    The running stage's rest is its remaining fraction over its rate since its first report above zero; stages to
    come are known only from ``expected`` (stage -> seconds of an earlier run, in order, e.g. a render's
    ``timings_s``), scaled by how the finished stages compared with theirs, drawn towards 1 by a prior of
    :attr:`PRIOR_SHARE` (``unscaled`` stages keep their time). The caller passes ``now``: no clock is read.
    """

    #: Weight of the earlier run's own pace in :meth:`scale`, as a share of its (scaled) stages' total time.
    PRIOR_SHARE = 0.25

    def __init__(self, expected: Mapping[str, float] | None = None, unscaled: Iterable[str] = ("compile",)):
        self.expected = OrderedDict((str(k), float(v)) for k, v in dict(expected or {}).items()
                                    if isinstance(v, (int, float)) and v >= 0)
        self.unscaled = frozenset(unscaled)
        self.stage: str | None = None
        self.fraction = 0.0
        self.stage_start = 0.0  # when the running stage began
        self.first: tuple[float, float] | None = None  # (time, fraction) of its first report above zero
        self.last: tuple[float, float] | None = None  # (time, fraction) of its latest report above zero
        self.finished: OrderedDict[str, float] = OrderedDict()  # stage -> seconds, stages left behind

    def update(self, stage: str, fraction: float, now: float) -> None:
        """A progress report: ``stage`` is ``fraction`` (0..1) done at time ``now``."""
        if stage != self.stage:
            if self.stage is not None:
                self.finished[self.stage] = self.finished.get(self.stage, 0.0) + (now - self.stage_start)
            self.stage, self.stage_start, self.first, self.last = stage, now, None, None
        self.fraction = min(max(fraction, 0.0), 1.0)
        if self.fraction > 0.0:
            self.last = (now, self.fraction)
            if self.first is None:
                self.first = self.last

    def scale(self) -> float:
        """Finished stages' time over their expected times, drawn towards 1 (1 when nothing has finished)."""
        done = [(t, self.expected[k]) for k, t in self.finished.items()
                if k in self.expected and k not in self.unscaled]
        spent, planned = sum(t for t, _ in done), sum(e for _, e in done)
        prior = self.PRIOR_SHARE * sum(v for k, v in self.expected.items() if k not in self.unscaled)
        return (spent + prior) / (planned + prior) if planned + prior > 0 else 1.0

    def _expected(self, stage: str) -> float:
        return self.expected[stage] * (1.0 if stage in self.unscaled else self.scale())

    def stage_left(self, now: float) -> float | None:
        """Seconds left of the running stage, or None when unknown."""
        if self.stage is None:
            return None
        if self.fraction >= 1.0:
            return 0.0
        if self.last is not None:
            (t0, f0), (t1, f1) = self.first, self.last
            if f1 > f0 and t1 > t0:
                rate = (f1 - f0) / (t1 - t0)
            elif t1 > self.stage_start:
                rate = f1 / (t1 - self.stage_start)
            else:
                return None
            return max((1.0 - f1) / rate - (now - t1), 0.0)
        if self.stage in self.expected:
            return max(self._expected(self.stage) - (now - self.stage_start), 0.0)
        return None

    def later_stages(self) -> list[str]:
        """The stages still to come, as far as ``expected`` tells (after the running stage in its order)."""
        names = list(self.expected)
        if self.stage in self.expected:
            return names[names.index(self.stage) + 1:]
        return [k for k in names if k not in self.finished]

    def estimate(self, now: float) -> Estimate:
        """The time left at ``now``: the running stage's rest plus, when ``expected`` is known, the later stages."""
        left = self.stage_left(now)
        if left is None:
            return Estimate(None, bool(self.expected))
        if not self.expected:
            return Estimate(left, False)
        return Estimate(left + sum(self._expected(k) for k in self.later_stages()), True)


__all__ = ["Estimate", "EtaEstimator", "ProgressFn", "ReportFn", "Stage", "StageTimer"]
