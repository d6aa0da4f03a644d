"""Measuring and reporting bench cases: timings with their spread, image errors, the report table, JSON, CSV, charts.

Timings: :func:`measure` and :func:`stage_medians` record every repeat; :meth:`BenchReport.add` attaches the repeats
whose median equals a figure of the row as ``timing`` (:func:`spread`); rows not measured through them carry
``repeats_ms: null``.

``bench-<suite>.json``::

    {"format": "warpscatter-bench/2", "suite": ..., "meta": {...}, "rows": [row, ...]}

``meta``: :data:`RUN_KEYS` (:func:`machine_meta` and the run's settings) plus the suite's own figures. Each row:
``name``, ``params``, ``case`` (:func:`case_label`, the key :mod:`.compare` matches on), ``median_ms`` (the suite's
headline figure: for renders the sum of the stage medians), ``stages_ms`` (stage medians), ``speedup``, ``rel_l1``,
``rmse``, ``extra`` and ``timing``: ``{"total": S, "stages": {stage: S}}`` with S = :func:`spread` (``repeats_ms``:
every repeat's time, ``n``, ``median_ms``, ``min_ms``, ``max_ms``, ``q1_ms``, ``q3_ms``, ``iqr_ms``;
``total.repeats_ms`` of a render are the per-repeat sums of its stages).

``bench-<suite>.csv`` (:data:`CSV_COLUMNS`): long format, one line per (row, stage), the row's total first with
``stage = "total"``; load with ``pandas.read_csv`` and filter or pivot on ``stage``::

    df = pd.read_csv("bench-moments.csv"); totals = df[df.stage == "total"]
    stages = df[df.stage != "total"].pivot(index="case", columns="stage", values="median_ms")

``median_ms`` .. ``iqr_ms`` and ``n`` as in the JSON, ``repeats_ms`` the repeats joined by ``;``; ``speedup``,
``rel_l1``, ``rmse`` and ``extra`` (``key=value`` pairs) only on the total line; ``params`` as ``key=value`` pairs.

Charts (the ``plot`` extra): ``bench-<suite>.png``, ``bench-<suite>-error-time.png`` where rows have an error, and
``bench-<suite>-errors-<name>.png`` per kept image comparison (:attr:`BenchReport.comparisons`).
"""

from __future__ import annotations

import csv
import json
import math
import os
import platform
import re
import statistics
import textwrap
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import warp as wp

from ..io.images import json_ready
from ..io.metrics import errors
from ..io.provenance import cpu_model, machine, package_version, source_commit, timestamp
from ..runtime.device import default_device

#: The JSON layout's name and version (``format`` key).
FORMAT = "warpscatter-bench/2"
#: Longest line of :meth:`BenchReport.table` (characters).
TABLE_WIDTH = 160
#: Characters per line of a bar chart's label (longer ones wrap onto a second line, then are cut).
LABEL_WIDTH = 80
#: Columns of ``bench-<suite>.csv``.
CSV_COLUMNS = ("suite", "case", "name", "params", "stage", "median_ms", "min_ms", "q1_ms", "q3_ms", "max_ms",
               "iqr_ms", "n", "repeats_ms", "speedup", "rel_l1", "rmse", "extra", "commit", "timestamp")
#: The keys of ``meta`` that describe the machine and the run (the rest are the suite's own figures).
RUN_KEYS = ("suite", "cpu", "cpu_arch", "cores", "threads", "device", "os", "python", "warp", "numpy", "openimageio",
            "warpscatter", "commit", "git_dirty", "timestamp", "repeats", "warmup", "quick", "argv")

#: Repeats recorded by :func:`measure` / :func:`stage_medians` and not yet claimed by a row: (median ms, times ms).
_recorded: list[tuple[float, list[float]]] = []
_RECORD_LIMIT = 256


def _record(median_ms: float, times_ms: list[float]) -> None:
    _recorded.append((median_ms, times_ms))
    del _recorded[:-_RECORD_LIMIT]


def _claim(median_ms) -> list[float] | None:
    """The recorded repeats (ms) whose median is exactly ``median_ms`` (newest first), removed from the record."""
    if not isinstance(median_ms, (int, float)):
        return None
    for k in range(len(_recorded) - 1, -1, -1):
        if _recorded[k][0] == median_ms:
            return _recorded.pop(k)[1]
    return None


def measure(fn: Callable[[], object], repeats: int, warmup: int) -> dict:
    """Run ``fn`` warmup times untimed, then ``repeats`` times: median/min/all times (s), the repeats recorded for the
    next :meth:`BenchReport.add` whose ``median_ms`` is ``1e3 * median_s``."""
    for _ in range(warmup):
        fn()
        wp.synchronize()
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        fn()
        wp.synchronize()
        times.append(time.perf_counter() - t0)
    median_s = statistics.median(times)
    _record(1e3 * median_s, [1e3 * t for t in times])
    return {"median_s": median_s, "min_s": min(times), "times_s": times}


def stage_medians(runs: list[dict], names=None) -> dict:
    """Per-stage median (ms) over the stage timings (s) of several runs (``names``: those stages only; compile
    excluded). Every stage's repeats are recorded for :meth:`BenchReport.add` (as :func:`measure` does)."""
    out = {}
    for n in runs[0]:
        if n != "compile" and (names is None or n in names):
            out[n] = 1e3 * statistics.median(r[n] for r in runs)
            _record(out[n], [1e3 * r[n] for r in runs])
    return out


def spread(times_ms: list[float] | None, median_ms: float | None = None) -> dict:
    """Every repeat's time and their spread (ms): ``n``, median, min, max, quartiles (inclusive method) and the
    interquartile range ``iqr_ms = q3_ms - q1_ms``. Without repeats: ``median_ms`` alone, the rest None."""
    if not times_ms:
        return {"repeats_ms": None, "n": None, "median_ms": median_ms, "min_ms": None, "max_ms": None, "q1_ms": None,
                "q3_ms": None, "iqr_ms": None}
    times = [float(t) for t in times_ms]
    q1, _, q3 = statistics.quantiles(times, n=4, method="inclusive") if len(times) > 1 else (times[0],) * 3
    return {"repeats_ms": times, "n": len(times), "median_ms": statistics.median(times), "min_ms": min(times),
            "max_ms": max(times), "q1_ms": q1, "q3_ms": q3, "iqr_ms": q3 - q1}


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




def format_value(v) -> str:
    """A short text of a cell value: floats to 4 significant digits, lists joined by ``,``, dicts flattened."""
    if isinstance(v, bool) or v is None:
        return str(v)
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, dict):
        return " ".join(flatten(v))
    if isinstance(v, (list, tuple)):
        return ",".join(format_value(x) for x in v)
    return str(v)


def flatten(d: dict, prefix: str = "") -> list[str]:
    """``key=value`` texts of a (nested) dict, nested keys joined by ``.``."""
    out = []
    for k, v in d.items():
        if isinstance(v, dict):
            out += flatten(v, f"{prefix}{k}.")
        else:
            out.append(f"{prefix}{k}={format_value(v)}")
    return out


def shorten(text: str, width: int) -> str:
    """``text`` cut to ``width`` characters, the last one an ellipsis when cut."""
    return text if len(text) <= width else text[:max(0, width - 1)] + "…"


def params_text(row: dict) -> str:
    """The row's parameters as ``key=value`` pairs separated by spaces."""
    return " ".join(f"{k}={format_value(v)}" for k, v in (row.get("params") or {}).items())


def case_label(row: dict) -> str:
    """The row's case: its name and every parameter, ``name [k=v k=v]`` (the key bench JSONs are compared on)."""
    p = params_text(row)
    return f"{row.get('name', '')} [{p}]" if p else str(row.get("name", ""))


def short_labels(rows: list[dict]) -> list[str]:
    """Chart labels: each row's name plus the parameters that differ between rows of the same name (unique)."""
    by_name: dict[str, list[dict]] = {}
    for r in rows:
        by_name.setdefault(r.get("name", ""), []).append(r)
    labels = []
    for r in rows:
        group = by_name[r.get("name", "")]
        keys = [k for k in (r.get("params") or {})
                if len({format_value((g.get("params") or {}).get(k)) for g in group}) > 1]
        p = " ".join(f"{k}={format_value(r['params'][k])}" for k in keys)
        labels.append(f"{r.get('name', '')} ({p})" if p else str(r.get("name", "")))
    seen: dict[str, int] = {}
    for i, label in enumerate(labels):
        seen[label] = seen.get(label, 0) + 1
        if seen[label] > 1:
            labels[i] = f"{label} #{seen[label]}"
    return labels


def _number(v, fmt: str) -> str:
    return format(v, fmt) if isinstance(v, (int, float)) and not isinstance(v, bool) else ""


def format_ms(v) -> str:
    """A time (ms) in 3 significant digits, whole milliseconds from 1000 on (no exponent); "" for a non-number."""
    return _number(v, ".3g" if abs(v) < 1e3 else ".0f") if isinstance(v, (int, float)) else ""


def _wrap(text: str, indent: str = "  ") -> list[str]:
    return textwrap.wrap(text, TABLE_WIDTH, subsequent_indent=indent, break_long_words=True) or [""]




@dataclass
class BenchReport:
    """Rows of one suite run plus the machine description."""

    suite: str
    rows: list[dict] = field(default_factory=list)
    meta: dict = field(default_factory=dict)
    files: list[Path] = field(default_factory=list)
    #: ``chart(report, path) -> path or None``: a suite's own chart instead of the default bar chart of medians.
    chart: Callable[[BenchReport, Path], Path | None] | None = None
    #: name -> (reference, {method: image}) linear RGB (H, W, 3) images to compare, each written as
    #: ``bench-<suite>-errors-<name>.png`` (:func:`chart_error_images`).
    comparisons: dict[str, tuple[np.ndarray, dict[str, np.ndarray]]] = field(default_factory=dict)

    def add(self, **row) -> dict:
        """Add a row (``name``, ``params``, ``median_ms``, ``stages_ms``, ... in ms) with the recorded repeats of its
        figures as ``timing`` (unless given); returns the row, which the suite may still update."""
        if "timing" not in row:
            stages = {k: _claim(v) for k, v in (row.get("stages_ms") or {}).items()}
            total = _claim(row.get("median_ms"))
            counts = {len(t) for t in stages.values() if t}
            if (total is None and stages and all(stages.values()) and len(counts) == 1
                    and math.isclose(sum(row["stages_ms"].values()), row.get("median_ms") or 0.0, rel_tol=1e-9)):
                total = [sum(t[k] for t in stages.values()) for k in range(counts.pop())]
            row["timing"] = {"total": spread(total, row.get("median_ms")),
                             "stages": {k: spread(t, row["stages_ms"][k]) for k, t in stages.items()}}
        self.rows.append(row)
        return row


    def header(self) -> list[str]:
        """The table's header lines: run, machine, versions, then the suite's meta as ``key=value`` (long ones only
        counted)."""
        m = self.meta

        def items(*formats: str) -> list[str]:
            """Each ``format`` filled from the meta, those naming a missing key left out."""
            return [f.format(**m) for f in formats if all(m.get(k) is not None for k in re.findall(r"{(\w+)", f))]

        run = [f"{len(self.rows)} rows", *(["quick"] if m.get("quick") else []), *items("repeats {repeats}",
                                                                                     "warmup {warmup}")]
        machine = items("{threads} threads", "{cpu}", "{cores} cores", "{os}", "device {device}")
        software = items("warp {warp}", "numpy {numpy}", "OpenImageIO {openimageio}", "python {python}",
                         "warpscatter {warpscatter}", "commit {commit:.10}", "{timestamp}")
        if m.get("git_dirty") and m.get("commit"):
            software = [f"{x}+dirty" if x.startswith("commit ") else x for x in software]
        lines = [f"bench {self.suite}: " + ", ".join(run) + ("; " + ", ".join(machine) if machine else "")]
        if software:
            lines.append(", ".join(software))
        own = []
        for k, v in m.items():
            if k in RUN_KEYS:
                continue
            flat = flatten(v, f"{k}.") if isinstance(v, dict) else [f"{k}={format_value(v)}"]
            own += flat if len(flat) <= 16 else [f"{k}=({len(flat)} values: see the JSON)"]
        if own:
            lines.append(" ".join(own))
        return [w for line in lines for w in _wrap(line)]

    def table(self) -> str:
        """Fixed-width text table (:data:`TABLE_WIDTH`): the header, then per row its median, IQR, speed-up and
        errors, with its stage medians and extra figures indented below (cut with an ellipsis)."""
        cols = ["name", "params", "median_ms", "iqr_ms", "speedup", "rel_l1", "rmse"]
        cells = []
        for r in self.rows:
            total = (r.get("timing") or {}).get("total") or {}
            cells.append([str(r.get("name", "")), params_text(r), _number(r.get("median_ms"), ".1f"),
                          format_ms(total.get("iqr_ms")) if (total.get("n") or 0) > 1 else "",
                          f"{r['speedup']:.2f}x" if isinstance(r.get("speedup"), (int, float)) else "",
                          _number(r.get("rel_l1"), ".4f"), _number(r.get("rmse"), ".3g")])
        widths = [max([len(c)] + [len(x[i]) for x in cells]) for i, c in enumerate(cols)]
        fixed = sum(widths[2:]) + 2 * (len(cols) - 1)
        room = TABLE_WIDTH - fixed
        widths[0] = min(widths[0], max(24, room * 11 // 20))
        widths[1] = min(widths[1], room - widths[0])
        right = [False, False, True, True, True, True, True]

        def line(values):
            return "  ".join((shorten(v, w).rjust(w) if r else shorten(v, w).ljust(w))
                             for v, w, r in zip(values, widths, right, strict=True)).rstrip()

        out = self.header() + [line(cols), line(["-" * w for w in widths])]
        for r, c in zip(self.rows, cells, strict=True):
            out.append(line(c))
            detail = []
            if r.get("stages_ms"):
                detail.append("stages_ms " + " ".join(f"{k}={format_ms(v)}" for k, v in r["stages_ms"].items()))
            if r.get("extra"):
                detail.append(" ".join(flatten(r["extra"])))
            out += textwrap.wrap(" | ".join(detail), TABLE_WIDTH, initial_indent="    ", subsequent_indent="      ",
                                 max_lines=2, placeholder=" …")
        return "\n".join(out)


    def to_dict(self) -> dict:
        """The JSON document (module doc): format, suite, meta, rows with their case keys."""
        return {"format": FORMAT, "suite": self.suite, "meta": self.meta,
                "rows": [{**r, "case": case_label(r)} for r in self.rows]}

    def csv_lines(self) -> list[dict]:
        """The CSV lines (:data:`CSV_COLUMNS`): per row its total, then one per stage."""
        out = []
        for r in self.rows:
            timing = r.get("timing") or {}
            total = timing.get("total") or spread(None, r.get("median_ms"))
            common = {"suite": self.suite, "case": case_label(r), "name": r.get("name", ""), "params": params_text(r),
                      "commit": self.meta.get("commit") or "", "timestamp": self.meta.get("timestamp") or ""}
            stages = [("total", {**total, "median_ms": r.get("median_ms")})]
            stages += [(k, (timing.get("stages") or {}).get(k) or spread(None, v))
                       for k, v in (r.get("stages_ms") or {}).items()]
            for k, (stage, s) in enumerate(stages):
                line = {**common, "stage": stage,
                        **{c: s.get(c) for c in ("median_ms", "min_ms", "q1_ms", "q3_ms", "max_ms", "iqr_ms", "n")},
                        "repeats_ms": ";".join(f"{t:.6g}" for t in s.get("repeats_ms") or [])}
                if k == 0:
                    line.update({c: r.get(c) for c in ("speedup", "rel_l1", "rmse")},
                                extra=" ".join(flatten(r.get("extra") or {})))
                out.append({c: "" if line.get(c) is None else line[c] for c in CSV_COLUMNS})
        return out

    def write(self, out_dir: Path) -> list[Path]:
        """Write ``bench-<suite>.json``, ``bench-<suite>.csv`` and, when matplotlib is available, the charts into
        ``out_dir`` (each file written to a temporary name, then renamed); returns the paths written."""
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        stem = out_dir / f"bench-{self.suite}"
        json_path = _write_atomic(stem.with_suffix(".json"),
                                  lambda f: json.dump(json_ready(self.to_dict()), f, indent=2))
        csv_path = _write_atomic(stem.with_suffix(".csv"), self._write_csv, newline="")
        self.files = [json_path, csv_path]
        charts = [(self.chart or chart_bars)(self, stem.with_suffix(".png")),
                  chart_error_time(self, out_dir / f"bench-{self.suite}-error-time.png")]
        charts += [chart_error_images(self, name, reference, images, out_dir / f"bench-{self.suite}-errors-{name}.png")
                   for name, (reference, images) in self.comparisons.items()]
        self.files += [c for c in charts if c is not None]
        return self.files

    def _write_csv(self, f) -> None:
        writer = csv.DictWriter(f, fieldnames=CSV_COLUMNS)
        writer.writeheader()
        writer.writerows(self.csv_lines())


def _write_atomic(path: Path, write: Callable, newline: str | None = None) -> Path:
    """Write a text file through ``write(file object)``, atomically (:func:`..io.output_sets.write_file_atomic`)."""
    from ..io.output_sets import write_file_atomic

    def text(tmp: Path) -> None:
        with open(tmp, "w", encoding="utf-8", newline=newline) as f:
            write(f)

    return write_file_atomic(path, text)




def pyplot():
    """matplotlib.pyplot on the file-only Agg backend, or None when matplotlib (the ``plot`` extra) is missing."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    return plt


def save_figure(fig, path: Path, layout: bool = True) -> Path:
    """Save a chart atomically (a temporary file renamed into place) at 110 dpi and close it; returns ``path``.
    ``layout``: apply ``tight_layout`` first (False: the caller laid the figure out)."""
    import matplotlib.pyplot as plt

    from ..io.output_sets import write_file_atomic

    if layout:
        fig.tight_layout()
    try:
        return write_file_atomic(path, lambda tmp: fig.savefig(tmp, dpi=110))
    finally:
        plt.close(fig)


def chart_title(report: BenchReport, what: str) -> str:
    """A chart's two-line title: the suite and ``what``, then the machine and run."""
    m = report.meta
    run = [str(m["cpu"]) if m.get("cpu") else "", f"{m['threads']} threads" if m.get("threads") else "",
           f"{m['repeats']} repeats" if m.get("repeats") else "", str(m.get("timestamp") or "")]
    return (f"warpscatter {'' if report.suite == 'sweep' else 'bench '}{report.suite}"
            f"{' --quick' if m.get('quick') else ''}: {what}\n" + ", ".join(x for x in run if x))


def scenes(rows: list[dict]) -> list[str]:
    """The scene of each row: its ``scene`` parameter, else its name's prefix before ``": "``; a row with neither
    gets the rows' only scene when they name exactly one, else ``""``."""
    out = []
    for r in rows:
        scene = (r.get("params") or {}).get("scene")
        name = str(r.get("name", ""))
        out.append(str(scene) if scene is not None else name.split(": ", 1)[0] if ": " in name else "")
    named = set(out) - {""}
    return [s or (next(iter(named)) if len(named) == 1 else "") for s in out]


def hbar_chart(report: BenchReport, path: Path, rows: list[dict], values, what: str, xlabel: str,
               texts: list[str] | None = None, whiskers: tuple[list, list] | None = None, line: float | None = None):
    """Horizontal bars, one per row top-down, coloured by scene, log scale when the values span more than 30x.
    ``texts``: written at the bars' ends; ``whiskers``: (low, high) per row or None; ``line``: a reference line."""
    plt = pyplot()
    if plt is None or not rows:
        return None
    values = np.asarray(values, np.float64)
    row_scenes = scenes(rows)
    groups = list(dict.fromkeys(row_scenes))
    palette = plt.get_cmap("tab10")
    labels = [textwrap.fill(shorten(label, 2 * LABEL_WIDTH), LABEL_WIDTH) for label in short_labels(rows)]
    chars = max(len(line) for label in labels for line in label.splitlines())
    row_height = 0.26 if all("\n" not in label for label in labels) else 0.4
    fig, ax = plt.subplots(figsize=(7.5 + 0.065 * chars, 1.4 + row_height * len(rows)))
    y = np.arange(len(rows))
    ax.barh(y, values, color=[palette(groups.index(s) % 10) for s in row_scenes], height=0.7)
    right = values.copy()
    if whiskers is not None:
        at = [k for k, w in enumerate(whiskers[0]) if w is not None]
        lo = np.array([values[k] - whiskers[0][k] for k in at])
        hi = np.array([whiskers[1][k] - values[k] for k in at])
        if at:
            ax.errorbar(values[at], y[at], xerr=[np.maximum(lo, 0.0), np.maximum(hi, 0.0)], fmt="none",
                        ecolor="black", elinewidth=0.8, capsize=2)
            right[at] = np.maximum(right[at], values[at] + hi)
    ax.set_yticks(y, labels, fontsize=8)
    ax.set_ylim(len(rows) - 0.5, -0.5)
    log = values.max() / values.min() > 30.0
    if log:
        ax.set_xscale("log")
        log_ticks(ax.xaxis, values)
    texts = texts or [format_ms(v) for v in values]
    for k, (x, text) in enumerate(zip(right, texts, strict=True)):
        ax.text(x * 1.04 if log else x + 0.01 * right.max(), k, text, va="center", fontsize=7)
    ax.set_xlim(values.min() * 0.5 if log else 0.0, right.max() * (2.5 if log else 1.12))
    if line is not None:
        ax.axvline(line, color="0.3", linewidth=0.8, linestyle="--")
    ax.set_xlabel(xlabel)
    ax.grid(True, axis="x", which="both", alpha=0.3)
    ax.set_title(chart_title(report, what), fontsize=9)
    return save_figure(fig, path)


def chart_bars(report: BenchReport, path: Path) -> Path | None:
    """The default chart: each row's median time (ms) as a horizontal bar (:func:`hbar_chart`), whiskers from the
    fastest to the slowest repeat where a row has two or more."""
    rows = [r for r in report.rows if isinstance(r.get("median_ms"), (int, float)) and r["median_ms"] > 0]
    totals = [(r.get("timing") or {}).get("total") or {} for r in rows]
    known = [(t.get("n") or 0) > 1 for t in totals]
    whiskers = ([t["min_ms"] if ok else None for t, ok in zip(totals, known, strict=True)],
                [t["max_ms"] if ok else None for t, ok in zip(totals, known, strict=True)])
    return hbar_chart(report, path, rows, [r["median_ms"] for r in rows], "time per case",
                      "median time (ms); whiskers: fastest to slowest repeat", whiskers=whiskers)


_MARCHER = re.compile(r"raymarch|marcher")


def error_time_points(report: BenchReport) -> dict[str, list[tuple[str, float, float, str]]]:
    """The error/time chart's points by scene (scenes of 2+ points): (series, time ms, rel. L1, label); a marcher's
    step count labels its points."""
    rows = [r for r in report.rows if isinstance(r.get("rel_l1"), (int, float)) and r["rel_l1"] > 0
            and isinstance(r.get("median_ms"), (int, float)) and r["median_ms"] > 0]
    named = []
    for r, scene in zip(rows, scenes(rows), strict=True):
        name = str(r.get("name", ""))
        name = name[len(scene) + 2:] if scene and name.startswith(f"{scene}: ") else name
        marcher = _MARCHER.search(name)
        m = re.fullmatch(r"(.*\S) (\d+)", name) if marcher else None
        steps = (r.get("params") or {}).get("steps")
        label = m.group(2) if m else str(steps) if marcher and steps is not None else ""
        named.append((scene, name, m.group(1) if m else name, label, r))
    sizes: dict[tuple[str, str], int] = {}
    for scene, _, curve, _, _ in named:
        sizes[scene, curve] = sizes.get((scene, curve), 0) + 1
    out: dict[str, list[tuple[str, float, float, str]]] = {}
    for scene, name, curve, label, r in named:
        on_curve = bool(label) and sizes[scene, curve] > 1
        out.setdefault(scene or "all", []).append((curve if on_curve else name, r["median_ms"], r["rel_l1"],
                                                   label if on_curve else ""))
    return {s: pts for s, pts in out.items() if len(pts) > 1}


def log_ticks(axis, values) -> None:
    """Log-axis ticks as plain numbers at 1, 2, 5 x 10^k (denser or linear for narrow spans)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, MaxNLocator, NullFormatter

    span = max(values) / min(values)
    subs = (1.0, 1.5, 2.0, 3.0, 5.0, 7.0) if span < 10.0 else (1.0, 2.0, 5.0)
    axis.set_major_locator(MaxNLocator(nbins=6) if span < 3.0 else LogLocator(base=10.0, subs=subs))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


def chart_error_time(report: BenchReport, path: Path) -> Path | None:
    """Error against time per scene (log-log, one panel per scene), one colour and marker per method, a marcher's
    points joined in step order. None without matplotlib or a scene of two such rows."""
    plt = pyplot()
    panels = error_time_points(report)
    if plt is None or not panels:
        return None
    series = list(dict.fromkeys(p[0] for pts in panels.values() for p in pts))
    palette = plt.get_cmap("tab20" if len(series) > 10 else "tab10")
    markers = "osD^vPXd<>h*p8H"
    style = {s: (palette(k % palette.N), markers[k % len(markers)]) for k, s in enumerate(series)}
    ncols = min(3, len(panels))
    nrows = -(-len(panels) // ncols)
    width = max(7.0, 5.0 * ncols + 0.5)
    legend_cols = max(1, min(len(series), int(width * 72 / (30 + 4.8 * max(map(len, series))))))
    legend_height = 0.3 + 0.2 * -(-len(series) // legend_cols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(width, 4.0 * nrows + 0.7 + legend_height), squeeze=False)
    handles = {}
    for ax, (scene, pts) in zip(axes.flat, panels.items(), strict=False):
        for name in dict.fromkeys(p[0] for p in pts):
            colour, marker = style[name]
            mine = sorted((p[1:] for p in pts if p[0] == name),  # (time, error, label) by steps, then time
                          key=lambda p: (int(p[2]) if p[2].isdigit() else 0, p[0]))
            curve = len(mine) > 1 and bool(_MARCHER.search(name))
            (h,) = ax.plot([p[0] for p in mine], [p[1] for p in mine], marker=marker, color=colour, markersize=6,
                           linestyle="-" if curve else "none", linewidth=1.0)
            handles.setdefault(name, h)
            for t, e, label in mine:
                if label:
                    ax.annotate(label, (t, e), textcoords="offset points", xytext=(4, 3), fontsize=7, color=colour)
        ax.set_xscale("log")
        ax.set_yscale("log")
        log_ticks(ax.xaxis, [p[1] for p in pts])
        log_ticks(ax.yaxis, [p[2] for p in pts])
        ax.tick_params(labelsize=7)
        ax.margins(0.12)
        label = "median time (ms)" + (f": {report.meta['time']}" if report.meta.get("time") else "")
        ax.set_xlabel(textwrap.fill(label, 64), fontsize=7)  # wrapped: side-by-side panels' labels must not meet
        ax.set_ylabel("rel. L1 vs reference", fontsize=8)
        ax.set_title(scene, fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    for ax in list(axes.flat)[len(panels):]:
        ax.set_visible(False)
    fig.suptitle(chart_title(report, "error against time per scene"), fontsize=9)
    fig.tight_layout(rect=(0.0, legend_height / fig.get_figheight(), 1.0, 1.0))
    fig.legend(handles.values(), handles.keys(), loc="lower center", ncol=legend_cols, fontsize=8, frameon=False)
    return save_figure(fig, path, layout=False)


#: Signed error at which the error images saturate, as a fraction of the reference image's mean.
ERROR_IMAGE_RANGE = 0.25


def chart_error_images(report: BenchReport, name: str, reference: np.ndarray, images: dict[str, np.ndarray],
                       path: Path) -> Path | None:
    """The reference and each method's image side by side (one exposure), each method's signed error below (over the
    reference's mean, saturating at +-:data:`ERROR_IMAGE_RANGE`; Peters 2017 Figs. 15-16). None without matplotlib."""
    plt = pyplot()
    if plt is None:
        return None
    ref = np.asarray(reference, np.float64)
    scale = max(float(np.percentile(ref.mean(axis=-1), 99.5)), 1e-30)
    mean = max(float(ref.mean()), 1e-30)
    h, w = ref.shape[:2]
    cols = 1 + len(images)
    row_in = 2.2  # inches per image row
    fig, axes = plt.subplots(2, cols, figsize=(row_in * cols * max(w / h, 0.5) + 0.9, 2 * row_in + 0.9),
                             squeeze=False)
    fig.subplots_adjust(left=0.01, right=0.93, top=1.0 - 0.75 / (2 * row_in + 0.9), bottom=0.02, wspace=0.04,
                        hspace=0.16)

    def show(ax, img, title):
        ax.imshow(np.clip(np.asarray(img, np.float64) / scale, 0.0, 1.0) ** (1.0 / 2.2))
        ax.set_title(title, fontsize=8)

    show(axes[0, 0], ref, "reference")
    axes[1, 0].axis("off")
    axes[1, 0].text(0.0, 0.5, f"signed error / reference mean\nred: too bright, blue: too dark\n"
                              f"saturates at +-{100 * ERROR_IMAGE_RANGE:.0f} %", fontsize=8, va="center")
    for k, (method, img) in enumerate(images.items(), start=1):
        img = np.asarray(img, np.float64)
        rel = float(np.abs(img - ref).sum() / max(np.abs(ref).sum(), 1e-30))
        show(axes[0, k], img, method)
        err = (img - ref).mean(axis=-1) / mean
        im = axes[1, k].imshow(err, cmap="RdBu_r", vmin=-ERROR_IMAGE_RANGE, vmax=ERROR_IMAGE_RANGE)
        axes[1, k].set_title(f"{method}: rel. L1 {100 * rel:.2f} %", fontsize=8)
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    if images:
        fig.colorbar(im, cax=fig.add_axes((0.945, 0.06, 0.012, 0.36)))
    fig.suptitle(chart_title(report, f"error images, {name}"), fontsize=9)
    return save_figure(fig, path, layout=False)


def machine_meta() -> dict:
    """The machine and software of a run: CPU, cores, threads, device, OS, versions, git commit, UTC time (ISO 8601)."""
    from ..runtime.parallel import thread_count

    commit, dirty = source_commit()
    host = machine()
    return {"cpu": host["cpu"], "cpu_arch": platform.machine(), "cores": host["cores"], "threads": thread_count(),
            "device": default_device(), "os": host["os"], "python": platform.python_version(),
            "warp": wp.__version__, "numpy": np.__version__, "openimageio": package_version("OpenImageIO"),
            "warpscatter": package_version("warpscatter"), "commit": commit, "git_dirty": dirty,
            "timestamp": timestamp()}


__all__ = ["CSV_COLUMNS", "FORMAT", "BenchReport", "case_label", "chart_bars", "chart_error_time", "cpu_model",
           "errors", "hbar_chart", "log_ticks", "machine_meta", "measure", "pyplot", "save_figure", "scenes",
           "short_labels", "source_commit", "spread", "stage_medians", "thread_limit"]
