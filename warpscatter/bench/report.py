"""Measuring and reporting bench cases: median timing, image errors, the report table, JSON and chart."""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import warp as wp

from ..wpinit import default_device


def measure(fn: Callable[[], object], repeats: int, warmup: int) -> dict:
    """Run ``fn`` warmup times untimed, then ``repeats`` times; return median/min/all times (seconds)."""
    for _ in range(warmup):
        fn()
        wp.synchronize()
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        fn()
        wp.synchronize()
        times.append(time.perf_counter() - t0)
    return {"median_s": statistics.median(times), "min_s": min(times), "times_s": times}


def errors(image: np.ndarray, reference: np.ndarray) -> dict:
    """Relative L1 and RMSE of ``image`` against ``reference`` (same shape)."""
    a = np.asarray(image, np.float64)
    b = np.asarray(reference, np.float64)
    denom = np.abs(b).sum()
    return {"rel_l1": float(np.abs(a - b).sum() / denom) if denom > 0 else float("nan"),
            "rmse": float(np.sqrt(np.mean((a - b) ** 2)))}


@contextmanager
def thread_limit(n: int | None):
    """Temporarily set WARPSCATTER_THREADS (None: leave as is)."""
    old = os.environ.get("WARPSCATTER_THREADS")
    if n is not None:
        os.environ["WARPSCATTER_THREADS"] = str(n)
    try:
        yield
    finally:
        if n is not None:
            if old is None:
                os.environ.pop("WARPSCATTER_THREADS", None)
            else:
                os.environ["WARPSCATTER_THREADS"] = old


@dataclass
class BenchReport:
    """Rows of one suite run plus the machine description."""

    suite: str
    rows: list[dict] = field(default_factory=list)
    meta: dict = field(default_factory=dict)
    files: list[Path] = field(default_factory=list)
    #: ``chart(report, path) -> path or None``: a suite's own chart instead of the default bar chart of medians.
    chart: Callable[[BenchReport, Path], Path | None] | None = None

    def add(self, **row) -> dict:
        self.rows.append(row)
        return row

    def table(self) -> str:
        """Fixed-width text table: one line per row, stage medians in ms."""
        cols = ["name", "params", "median_ms", "stages_ms", "speedup", "rel_l1", "rmse", "extra"]
        lines = []
        for r in self.rows:
            stages = r.get("stages_ms") or {}
            lines.append([
                r.get("name", ""),
                " ".join(f"{k}={v}" for k, v in (r.get("params") or {}).items()),
                f"{r['median_ms']:.1f}" if r.get("median_ms") is not None else "",
                " ".join(f"{k}={v:.1f}" for k, v in stages.items()),
                f"{r['speedup']:.2f}x" if r.get("speedup") is not None else "",
                f"{r['rel_l1']:.4f}" if r.get("rel_l1") is not None else "",
                f"{r['rmse']:.3g}" if r.get("rmse") is not None else "",
                " ".join(f"{k}={v}" for k, v in (r.get("extra") or {}).items()),
            ])
        widths = [max(len(c), *(len(x[i]) for x in lines)) if lines else len(c) for i, c in enumerate(cols)]
        out = [f"suite {self.suite}: " + ", ".join(f"{k}={v}" for k, v in self.meta.items()
                                                   if k != "suite" and not isinstance(v, (dict, list)))]
        out.append("  ".join(c.ljust(w) for c, w in zip(cols, widths, strict=True)))
        out.append("  ".join("-" * w for w in widths))
        out += ["  ".join(x.ljust(w) for x, w in zip(line, widths, strict=True)) for line in lines]
        return "\n".join(out)

    def write(self, out_dir: Path) -> list[Path]:
        """Write JSON (and a PNG chart when matplotlib is available) into ``out_dir``."""
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        path = out_dir / f"bench-{self.suite}.json"
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps({"suite": self.suite, "meta": self.meta, "rows": self.rows}, indent=2))
        os.replace(tmp, path)
        self.files = [path]
        chart = (self.chart or BenchReport._chart)(self, out_dir / f"bench-{self.suite}.png")
        if chart is not None:
            self.files.append(chart)
        return self.files

    def _chart(self, path: Path) -> Path | None:
        plt = pyplot()
        if plt is None:
            return None
        rows = [r for r in self.rows if r.get("median_ms") is not None]
        if not rows:
            return None
        labels = [f"{r['name']}\n" + " ".join(f"{k}={v}" for k, v in (r.get("params") or {}).items()) for r in rows]
        fig, ax = plt.subplots(figsize=(max(6, 1.2 * len(rows)), 4))
        ax.bar(range(len(rows)), [r["median_ms"] for r in rows], color="#4477aa")
        ax.set_xticks(range(len(rows)), labels, fontsize=7)
        ax.set_ylabel("median time (ms)")
        ax.set_yscale("log")
        ax.set_title(f"warpscatter bench {self.suite} ({self.meta.get('threads')} threads)")
        return save_figure(fig, path)


def pyplot():
    """matplotlib.pyplot on the file-only Agg backend, or None when matplotlib (the ``plot`` extra) is missing."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    return plt


def save_figure(fig, path: Path) -> Path:
    """Save a chart atomically (a temporary file renamed into place) at 110 dpi and close it; returns ``path``."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    tmp = path.with_name(".tmp-" + path.name)
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)
    return path


def machine_meta() -> dict:
    from ..parallel import thread_count

    return {"warp": wp.__version__, "python": platform.python_version(), "cpu": platform.processor() or
            platform.machine(), "threads": thread_count(), "device": default_device()}


__all__ = ["BenchReport", "errors", "machine_meta", "measure", "pyplot", "save_figure", "thread_limit"]
