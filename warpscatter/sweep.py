"""Parameter sweeps: configs x a grid (or list) of overrides, each case rendered, timed and compared with a reference.

A sweep file (YAML; paths relative to it)::

    configs: [../configs/colonnade.yaml, ../configs/canopy.yaml, ../configs/window.yaml]
    set: {camera.width: 320, camera.height: 180}          # every case, and the references
    grid:                                                  # the cartesian product of these values
      render.scattering.method: [fourier, moments4, moments6, epipolar]
      render.scattering.shadow_map.resolution: [512, 1024]
    cases: []                                              # optional list of override sets, each x the grid
    reference: {render.scattering.method: raymarch, render.scattering.visibility: exact,
                render.scattering.steps: 512}             # optional: error of every case against it
    images: false                                          # true: write each case's output set

Every case's config is validated before the first render. Cases run through an executor
(:mod:`warpscatter.jobs`); a failed case is reported with its error and the others go on. Results: one row per case
(config, overrides, technique time = the render's stages without ``scene``, ``compile`` and ``write``, total time,
and with a reference its relative L1 and RMSE), written as ``NAME.json`` (with the provenance of
:mod:`warpscatter.provenance`), ``NAME.csv`` and, with matplotlib (the ``plot`` extra), ``NAME-error-time.png``
(error against time per config, one marker per method). Times measured with several workers on a shared machine
are contended: compare techniques with ``--workers 1`` or the inline executor.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import Field, ValidationError, field_validator, model_validator

from .config import Config, load_config, read_config_data
from .errors import ConfigError
from .jobs import Executor, InlineExecutor, TaskResult, run_tasks, task_for
from .metrics import errors
from .schema import Bool, PathStr, SettingsModel, existing_file, format_validation_errors, resolve_path

#: Stages that are not the technique's own work: left out of a case's technique time.
OVERHEAD_STAGES = ("scene", "compile", "write")


class SweepSettings(SettingsModel):
    """A sweep file (see the module docstring)."""

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
        return self

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
    if overrides:
        data.setdefault("set", {}).update(overrides)
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


@dataclass
class SweepCase:
    """One case: its label, config file, overrides (``set`` left out: the same for all) and validated config."""

    label: str
    config_file: Path
    overrides: dict[str, Any]
    config: Config


@dataclass
class SweepResult:
    """The rows of a sweep (one per case, in order), the files written and the reference renders' results."""

    rows: list[dict]
    files: list[Path] = field(default_factory=list)
    references: dict[str, TaskResult] = field(default_factory=dict)

    @property
    def failed(self) -> list[dict]:
        return [r for r in self.rows if r.get("error")]


def sweep_cases(sweep: SweepSettings) -> tuple[list[SweepCase], dict[Path, Config]]:
    """Every case's validated config, and each config file's reference config (when the sweep has a reference).

    Raises:
        ConfigError: listing every case whose config is invalid (``CASE: key.path: reason``).
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
            try:
                cases.append(SweepCase(label, path, own, load_config(path, overrides)))
            except ConfigError as exc:
                problems += [f"{label}: {p}" for p in exc.problems]
        if sweep.reference is not None:
            try:
                references[path] = load_config(path, {**sweep.set, **sweep.reference})
            except ConfigError as exc:
                problems += [f"{path.stem} reference: {p}" for p in exc.problems]
    labels = [c.label for c in cases]
    duplicates = sorted({x for x in labels if labels.count(x) > 1})
    if duplicates:
        problems.append(f"cases: several cases have the same overrides: {', '.join(duplicates)}")
    if problems:
        raise ConfigError(problems)
    return cases, references


def run_sweep(sweep: SweepSettings, out_dir: str | Path, *, executor: Executor | None = None,
              progress: Callable[[str, float], None] | None = None) -> SweepResult:
    """Render every case (and each config's reference), and write the results.

    Args:
        sweep: the validated sweep.
        out_dir: where ``NAME.json``, ``NAME.csv``, the chart and (with ``images``) ``NAME/CASE.*`` go.
        executor: where the renders run (default: this process, one after the other).
        progress: ``progress(stage, fraction)`` per finished render.

    Raises:
        ConfigError: an invalid case (before any render).
    """
    from .provenance import provenance

    cases, references = sweep_cases(sweep)
    out = Path(out_dir)
    executor = executor or InlineExecutor()
    want = ("color",) if references else ()
    ref_tasks = [task_for(cfg, f"{path.stem} reference", None, ("color",)) for path, cfg in references.items()]
    ref_results = {r.label: r for r in run_tasks(ref_tasks, executor, skip_finished=False, progress=progress,
                                                  stage="references")} if ref_tasks else {}
    images_dir = out / sweep.name
    tasks = []
    for k, case in enumerate(cases):
        config = case.config
        if sweep.images:
            stem = case.label.replace("/", "__").replace("=", "-").replace(",", "_")
            config = config.model_copy(update={"output": {**config.output.model_dump(), "name":
                                                          stem.replace("{", "{{").replace("}", "}}")}})
        tasks.append(task_for(config, f"{k:04d} {case.label}", images_dir if sweep.images else None, want))
    results = run_tasks(tasks, executor, skip_finished=False, progress=progress, stage="cases")
    rows = []
    for case, result in zip(cases, results, strict=True):
        row: dict[str, Any] = {"case": case.label, "config": case.config_file.stem, **{
            f"set:{k}": v for k, v in case.overrides.items()}, "method": case.config.method}
        if not result.ok:
            row["error"] = result.error
            rows.append(row)
            continue
        total = sum(result.timings.values())
        row["technique_s"] = total - sum(result.timings.get(s, 0.0) for s in OVERHEAD_STAGES)
        row["total_s"] = total
        reference = ref_results.get(f"{case.config_file.stem} reference")
        if reference is not None and reference.ok and "color" in result.images:
            row.update(errors(result.images["color"], reference.images["color"]))
        elif reference is not None and not reference.ok:
            row["error"] = f"reference failed: {reference.error}"
        rows.append(row)
    meta = {"sweep": sweep.model_dump(mode="json"), "executor": executor.describe(), **provenance(),
            "references": {label: {"ok": r.ok, "error": r.error, "total_s": sum(r.timings.values())}
                           for label, r in ref_results.items()}}
    result = SweepResult(rows=rows, references=ref_results)
    result.files = write_results(rows, meta, out, sweep.name)
    return result


def write_results(rows: list[dict], meta: dict, out: Path, name: str) -> list[Path]:
    """``NAME.json`` (meta + rows), ``NAME.csv`` (one line per case) and, with matplotlib, ``NAME-error-time.png``;
    each written to a temporary name and renamed."""
    from .imageio import json_ready

    out.mkdir(parents=True, exist_ok=True)
    columns = list(dict.fromkeys(k for r in rows for k in r))
    files = []

    def put(path: Path, write) -> None:
        tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
        try:
            with open(tmp, "w", encoding="utf-8", newline="") as f:
                write(f)
            os.replace(tmp, path)
        finally:
            if tmp.exists():
                tmp.unlink()
        files.append(path)

    put(out / f"{name}.json", lambda f: json.dump(json_ready({"meta": meta, "rows": rows}), f, indent=2))

    def csv_rows(f):
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        for r in rows:
            writer.writerow({k: (_value_text(v) if isinstance(v, (list, dict)) else v) for k, v in r.items()})

    put(out / f"{name}.csv", csv_rows)
    chart = error_time_chart(rows, out / f"{name}-error-time.png")
    if chart is not None:
        files.append(chart)
    return files


def error_time_chart(rows: list[dict], path: Path) -> Path | None:
    """Error against technique time, one panel per config, one marker per method, log-log; None without
    matplotlib or without rows that have both."""
    points = [r for r in rows if r.get("rel_l1") and r.get("technique_s")]
    if not points:
        return None
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    configs = list(dict.fromkeys(r["config"] for r in points))
    methods = list(dict.fromkeys(r["method"] for r in points))
    markers = "osD^vP*Xh<>"
    fig, axes = plt.subplots(1, len(configs), figsize=(5.2 * len(configs), 4.4), squeeze=False)
    for ax, config in zip(axes[0], configs, strict=True):
        for m, method in enumerate(methods):
            mine = [r for r in points if r["config"] == config and r["method"] == method]
            if mine:
                ax.scatter([1e3 * r["technique_s"] for r in mine], [100 * r["rel_l1"] for r in mine],
                           marker=markers[m % len(markers)], s=42, label=method)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(config)
        ax.set_xlabel("technique time (ms)")
        ax.set_ylabel("relative L1 error (%)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    tmp = path.with_name(f".{path.stem}.tmp-{os.getpid()}.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)
    return path


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
           "rows_table", "run_sweep", "sweep_cases", "write_results"]
