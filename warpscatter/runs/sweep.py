"""Parameter sweeps: configs x a grid (or list) of overrides, each case rendered, timed and compared with a reference.

A sweep file's keys are :class:`SweepSettings`' (an example: docs/guide/runs.md). Every case is validated before the
first render and runs through an executor (:mod:`.jobs`); a failed case is reported and the others go on. One row per
case (technique time = stages without ``scene``, ``compile`` and ``write``; errors against the reference) goes to
``NAME.json``, ``NAME.csv`` and ``NAME-error-time.png``. Compare times with ``--workers 1``: several workers on a
shared machine contend.
"""

from __future__ import annotations

import csv
import hashlib
import itertools
import json
import math
import os
import re
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import Field, ValidationError, field_validator, model_validator

from ..config import Config, load_config, read_config_data
from ..errors import ConfigError
from ..io.metrics import errors
from ..schema import Bool, PathStr, SettingsModel, existing_file, format_validation_errors, resolve_path
from .jobs import Executor, InlineExecutor, TaskResult, run_tasks, task_for

#: Stages that are not the technique's own work: left out of a case's technique time.
OVERHEAD_STAGES = ("scene", "compile", "write")


#: Most renders one sweep may make (configs x cases x grid points), checked before any case is built.
MAX_SWEEP_CASES = 10_000


class SweepSettings(SettingsModel):
    """A sweep file (YAML; relative paths resolve against its folder)."""

    configs: list[PathStr] = Field(min_length=1, description="the configs (scenes) every case is rendered on")
    set: dict[str, Any] = Field(default_factory=dict, description="overrides of every case and reference")
    grid: dict[str, list[Any]] = Field(default_factory=dict, description="key -> values: their cartesian product")
    cases: list[dict[str, Any]] = Field(default_factory=list, description="override sets, each combined with the "
                                                                          "grid")
    reference: dict[str, Any] | None = Field(None, description="overrides of the reference render (errors against "
                                                               "it); null: no errors")
    images: Bool = Field(False, description="write each case's output set (NAME/CASE.*)")
    name: str = Field("sweep", description="file stem of the results (NAME.json, NAME.csv, NAME-error-time.png)")

    @field_validator("configs")
    @classmethod
    def _exist(cls, v: list[Path], info) -> list[Path]:
        return [existing_file(resolve_path(p, info)) for p in v]

    @field_validator("grid")
    @classmethod
    def _non_empty(cls, v: dict[str, list[Any]]) -> dict[str, list[Any]]:
        empty = [k for k, values in v.items() if not values]
        if empty:
            raise ValueError(f"{', '.join(empty)}: give at least one value")
        return v

    @model_validator(mode="after")
    def _some_case(self) -> SweepSettings:
        if not self.name or any(c in self.name for c in '/\\:*?"<>|\0'):
            raise ValueError(f"name: must be a plain file stem, got {self.name!r}")
        count = self.case_count()
        if count > MAX_SWEEP_CASES:  # counted, not built: a grid of a few long lists is astronomically many cases
            raise ValueError(f"grid: {count:.3g} cases (configs x cases x grid points); at most {MAX_SWEEP_CASES}")
        return self

    def case_count(self) -> int:
        """How many renders :meth:`override_sets` makes over every config, computed without building them."""
        return len(self.configs) * max(1, len(self.cases)) * math.prod(len(v) for v in self.grid.values())

    def override_sets(self) -> list[dict[str, Any]]:
        """Every case's overrides (``set``, then the case, then the grid point), in order."""
        keys = list(self.grid)
        points = [dict(zip(keys, values, strict=True)) for values in itertools.product(*self.grid.values())]
        return [{**self.set, **case, **point} for case in (self.cases or [{}]) for point in points]


def load_sweep(path: str | Path, overrides: dict[str, Any] | None = None) -> SweepSettings:
    """Read and validate a sweep file.

    Raises:
        ConfigError: every problem as ``key.path: reason``.
    """
    path = Path(path)
    data, _ = read_config_data(path)
    if overrides and isinstance(data.get("set", {}), dict):  # else validation names the bad "set"
        data["set"] = {**(data.get("set") or {}), **overrides}
    try:
        return SweepSettings.model_validate(data, context={"config_dir": path.resolve().parent})
    except ValidationError as exc:
        raise ConfigError(format_validation_errors(exc, SweepSettings), path) from None


def _short_keys(keys: list[str]) -> dict[str, str]:
    """A label for each varied key: its last segment, or the whole path where two would share it."""
    last = [k.rsplit(".", 1)[-1] for k in keys]
    return {k: (s if last.count(s) == 1 else k) for k, s in zip(keys, last, strict=True)}


def _value_text(v: Any) -> str:
    return json.dumps(v, separators=(",", ":")) if isinstance(v, (list, dict)) else str(v)


#: Overrides under this prefix change the technique; others change what is rendered, so the reference takes them.
TECHNIQUE_PREFIX = "render."


@dataclass
class SweepCase:
    """One case: label, config file, overrides (without ``set``), validated config and its reference's key."""

    label: str
    config_file: Path
    overrides: dict[str, Any]
    config: Config
    reference: str | None = None


@dataclass
class SweepResult:
    """The rows of a sweep (one per case, in order), the files written and the reference renders' results."""

    rows: list[dict]
    files: list[Path] = field(default_factory=list)
    references: dict[str, TaskResult] = field(default_factory=dict)

    @property
    def failed(self) -> list[dict]:
        return [r for r in self.rows if r.get("error")]


def sweep_cases(sweep: SweepSettings) -> tuple[list[SweepCase], dict[str, Config]]:
    """Every case's validated config and the reference configs, one per config file and set of scene overrides
    (keys outside ``render.``), keyed as each case's ``reference``.

    Raises:
        ConfigError: listing every case whose config (or reference) is invalid (``CASE: key.path: reason``).
    """
    sets = sweep.override_sets()
    varied = [k for k in dict.fromkeys(k for s in sets for k in s) if k not in sweep.set or
              any(s.get(k) != sweep.set[k] for s in sets)]
    short = _short_keys(varied)
    cases, problems, references = [], [], {}
    for path in sweep.configs:
        for overrides in sets:
            own = {k: overrides[k] for k in varied if k in overrides}
            label = path.stem + ("/" + ",".join(f"{short[k]}={_value_text(v)}" for k, v in own.items()) if own
                                 else "")
            scene = {k: v for k, v in overrides.items() if not k.startswith(TECHNIQUE_PREFIX)}
            ref_key = None
            if sweep.reference is not None:
                changed = {k: v for k, v in own.items() if not k.startswith(TECHNIQUE_PREFIX)}
                ref_key = path.stem + " reference" + ("" if not changed else " (" + ",".join(
                    f"{short[k]}={_value_text(v)}" for k, v in changed.items()) + ")")
                if ref_key not in references:
                    try:
                        references[ref_key] = load_config(path, {**scene, **sweep.reference})
                    except ConfigError as exc:
                        problems += [f"{ref_key}: {p}" for p in exc.problems]
            try:
                cases.append(SweepCase(label, path, own, load_config(path, overrides), ref_key))
            except ConfigError as exc:
                problems += [f"{label}: {p}" for p in exc.problems]
    labels = [c.label for c in cases]
    duplicates = sorted({x for x in labels if labels.count(x) > 1})
    if duplicates:
        problems.append(f"cases: several cases have the same overrides: {', '.join(duplicates)}")
    if problems:
        raise ConfigError(problems)
    return cases, references


#: Longest readable part of a case's file stem (a short digest of the label follows when it is cut).
_STEM_CHARS = 96


def _label_digest(label: str) -> str:
    return hashlib.sha256(label.encode("utf-8")).hexdigest()[:8]


def _file_stem(label: str) -> str:
    """A case label as a file stem: other than letters, digits, ``.``, ``_`` and ``-`` becomes ``_``; a label longer
    than :data:`_STEM_CHARS` is cut and a digest of the whole label appended."""
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", label.replace("=", "-")).strip("._") or "case"
    if len(stem) > _STEM_CHARS:
        stem = stem[:_STEM_CHARS].rstrip("._-") + "-" + _label_digest(label)
    return stem


def file_stems(labels: list[str]) -> list[str]:
    """One file stem per case label, unique (letter case aside, for case-insensitive file systems): labels that map
    to the same :func:`_file_stem` each get a digest of their own label appended, so every stem depends only on its
    label and the set of labels, not on the order of the cases."""
    stems = [_file_stem(label) for label in labels]
    counts = Counter(s.casefold() for s in stems)
    stems = [f"{s}-{_label_digest(label)}" if counts[s.casefold()] > 1 else s
             for s, label in zip(stems, labels, strict=True)]
    counts = Counter(s.casefold() for s in stems)
    seen: Counter = Counter()
    unique = []
    for k, s in enumerate(stems):  # a digest colliding with another case's plain stem: the case index decides
        seen[s.casefold()] += 1
        unique.append(s if counts[s.casefold()] == 1 or seen[s.casefold()] == 1 else f"{s}-{k:04d}")
    return unique


def run_sweep(sweep: SweepSettings, out_dir: str | Path, *, executor: Executor | None = None,
              progress: Callable[[str, float], None] | None = None, device=None,
              verbose: bool = False) -> SweepResult:
    """Render every case (and each reference) and write the results; a failing case is a row with its error.

    Args:
        sweep: the validated sweep.
        out_dir: where ``NAME.json``, ``NAME.csv``, the chart and (with ``images``) ``NAME/CASE.*`` go.
        executor: where the renders run (default: this process, one after the other).
        progress: ``progress(stage, fraction)`` per finished render.
        device: the Warp device of every render (default: :func:`..runtime.device.default_device`).
        verbose: show Warp's own messages (its banner, module loads), as :func:`warpscatter.render` does.

    Raises:
        ConfigError: an invalid case (before any render).
    """
    from ..runtime.device import warp_messages

    with warp_messages(verbose):
        return _run_sweep(sweep, out_dir, executor, progress, device)


def _run_sweep(sweep: SweepSettings, out_dir, executor, progress, device) -> SweepResult:
    from ..io.provenance import provenance
    from ..runtime.device import default_device

    cases, references = sweep_cases(sweep)
    out = Path(out_dir)
    executor = executor or InlineExecutor()
    # the caller's device travels only when asked for: a worker otherwise renders on its own default
    device = default_device(device) if device is not None or os.environ.get("WARPSCATTER_DEVICE") else None
    want = ("color",) if references else ()
    ref_tasks = [task_for(cfg, label, None, ("color",), device=device) for label, cfg in references.items()]
    ref_results = {r.label: r for r in run_tasks(ref_tasks, executor, skip_finished=False, progress=progress,
                                                  stage="references")} if ref_tasks else {}
    images_dir = out / sweep.name
    stems = file_stems([case.label for case in cases])
    tasks = []
    for k, case in enumerate(cases):
        config = case.config
        if sweep.images:
            config = config.model_copy(update={"output": {**config.output.model_dump(), "name": stems[k]}})
        tasks.append(task_for(config, f"{k:04d} {case.label}", images_dir if sweep.images else None, want,
                              device=device))
    results = run_tasks(tasks, executor, skip_finished=False, progress=progress, stage="cases")
    rows = [_row(case, result, ref_results.get(case.reference)) for case, result in zip(cases, results, strict=True)]
    meta = {"sweep": sweep.model_dump(mode="json"), "executor": executor.describe(), **provenance(),
            "references": {label: {"ok": r.ok, "error": r.error, "total_s": sum(r.timings.values())}
                           for label, r in ref_results.items()}}
    result = SweepResult(rows=rows, references=ref_results)
    result.files = write_results(rows, meta, out, sweep.name)
    return result


def _row(case: SweepCase, result: TaskResult, reference: TaskResult | None) -> dict:
    """A case's row: overrides, method, times and errors against its reference (or its error)."""
    row: dict[str, Any] = {"case": case.label, "config": case.config_file.stem, **{
        f"set:{k}": v for k, v in case.overrides.items()}, "method": case.config.method}
    if not result.ok:
        row["error"] = result.error
        return row
    total = sum(result.timings.values())
    row["technique_s"] = total - sum(result.timings.get(s, 0.0) for s in OVERHEAD_STAGES)
    row["total_s"] = total
    if reference is None:
        return row
    if not reference.ok:
        row["error"] = f"reference failed: {reference.error}"
    elif "color" in result.images:
        try:
            row.update(errors(result.images["color"], reference.images["color"]))
        except ValueError as exc:  # an image that does not match its reference's shape
            row["error"] = f"cannot compare with {case.reference}: {exc}"
    return row


def write_results(rows: list[dict], meta: dict, out: Path, name: str) -> list[Path]:
    """Write ``NAME.json``, ``NAME.csv`` and, with matplotlib, ``NAME-error-time.png``, each atomically."""
    from ..io.images import json_ready
    from ..io.output_sets import write_file_atomic

    out.mkdir(parents=True, exist_ok=True)
    columns = list(dict.fromkeys(k for r in rows for k in r))
    files = [write_file_atomic(out / f"{name}.json", lambda tmp: tmp.write_text(
        json.dumps(json_ready({"meta": meta, "rows": rows}), indent=2), encoding="utf-8"))]

    def csv_rows(tmp: Path) -> None:
        with open(tmp, "w", encoding="utf-8", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=columns)
            writer.writeheader()
            for r in rows:
                writer.writerow({k: (_value_text(v) if isinstance(v, (list, dict)) else v) for k, v in r.items()})

    files.append(write_file_atomic(out / f"{name}.csv", csv_rows))
    chart = error_time_chart(rows, meta, out / f"{name}-error-time.png")
    if chart is not None:
        files.append(chart)
    return files


def error_time_chart(rows: list[dict], meta: dict, path: Path) -> Path | None:
    """The bench's error-vs-time chart of the rows; None without matplotlib or two comparable rows in a config."""
    from ..bench.report import BenchReport, chart_error_time

    machine = meta.get("machine") or {}
    report = BenchReport(suite="sweep", meta={"cpu": machine.get("cpu"), "timestamp": meta.get("created"),
                                              "time": "technique stages (scene, compile, write apart)"})
    for r in rows:
        if r.get("rel_l1") and r.get("technique_s"):
            report.rows.append({"name": f"{r['config']}: {r['case'].split('/', 1)[-1]}", "params": {
                "scene": r["config"]}, "median_ms": 1e3 * r["technique_s"], "rel_l1": r["rel_l1"]})
    return chart_error_time(report, path)


def rows_table(rows: list[dict]) -> str:
    """The rows as a text table: case, method, technique and total time (ms), rel. L1 (%), RMSE, error."""
    head = f"{'case':<48} {'method':<9} {'tech ms':>9} {'total ms':>9} {'rel L1 %':>9} {'rmse':>9}"
    lines = [head, "-" * len(head)]

    def num(v, scale=1.0, fmt="9.2f"):
        return format(v * scale, fmt) if isinstance(v, (int, float)) and math.isfinite(v) else f"{'-':>9}"

    for r in rows:
        case = r["case"] if len(r["case"]) <= 48 else r["case"][:47] + "…"
        line = (f"{case:<48} {r.get('method', ''):<9} {num(r.get('technique_s'), 1e3, '9.1f')} "
                f"{num(r.get('total_s'), 1e3, '9.1f')} {num(r.get('rel_l1'), 100.0, '9.3f')} "
                f"{num(r.get('rmse'), 1.0, '9.2e')}")
        if r.get("error"):
            line += f"  FAILED: {r['error'][:80]}"
        lines.append(line)
    return "\n".join(lines)


__all__ = ["OVERHEAD_STAGES", "SweepCase", "SweepResult", "SweepSettings", "error_time_chart", "load_sweep",
           "file_stems", "rows_table", "run_sweep", "sweep_cases", "write_results"]
