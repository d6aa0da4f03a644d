"""Named, timed stages with progress: the one stage context of every render, method and bench case.

A :class:`StageTimer` times named stages in order (their names appear in the CLI's timing table, in ``bench``
output and in logs) and forwards progress to one callback shape, ``progress(stage, fraction)``. Inside a stage,
``report(fraction)`` moves the fraction (the shape that :func:`warpscatter.parallel.launch_rows` and the CSM
builders accept as ``progress=``)::

    timer = StageTimer(progress=lambda stage, f: print(stage, f))
    with timer("scattering") as stage:
        launch_rows(kernel, dim, inputs, progress=stage.report)
    timer.timings  # {"scattering": seconds}

A stage that runs twice accumulates its time. Leaving a stage synchronises Warp, so the time includes the work
launched inside it.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from typing import Callable

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
    """Times named stages in order and reports their progress to an optional callback.

    Args:
        progress: ``progress(stage, fraction)`` (:data:`ProgressFn`), or None.

    Attributes:
        timings: stage name -> seconds, in the order the stages first ran.
    """

    def __init__(self, progress: ProgressFn | None = None):
        self.timings: OrderedDict[str, float] = OrderedDict()
        self.progress = progress

    def __call__(self, name: str) -> Stage:
        """A context manager timing stage ``name``."""
        return Stage(self, name)

    def add(self, name: str, seconds: float) -> None:
        """Add ``seconds`` to stage ``name`` (for work timed outside a ``with`` block, e.g. one progressive pass)."""
        self.timings[name] = self.timings.get(name, 0.0) + seconds


__all__ = ["ProgressFn", "ReportFn", "Stage", "StageTimer"]
