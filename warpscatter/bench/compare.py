"""Comparing two bench JSONs (``bench-<suite>.json``, :mod:`.report`): ``compare_reports(a_path, b_path) -> str``.

Rows are matched on their case (:func:`~.report.case_label`; repeats in one file get ``#2``, ...). Per case and stage
the text lists A's and B's medians, B/A and a verdict: ``slower`` / ``faster`` when both have 2+ repeats and the
[fastest, slowest] intervals do not overlap, ``within spread`` when they do, ``no spread`` otherwise. Different
suites, machines or ``--quick`` give warnings, different versions notes, never a failure.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from .report import TABLE_WIDTH, case_label, format_value, shorten

#: The meta keys that must agree for times to be comparable (a warning when they differ).
MACHINE_KEYS = ("cpu", "cores", "threads", "device", "os", "quick")
#: The meta keys of software versions (a note when they differ).
VERSION_KEYS = ("python", "warp", "numpy", "openimageio")


@dataclass
class StageDiff:
    """One stage of a matched case: medians (ms, None where a side lacks the stage), B/A and the verdict."""

    stage: str
    a_ms: float | None
    b_ms: float | None
    ratio: float | None
    verdict: str


@dataclass
class CaseDiff:
    """A case in both files: its stages and the rows' errors (``rel_l1``, ``rmse``; None where absent)."""

    case: str
    stages: list[StageDiff]
    a_errors: dict
    b_errors: dict


@dataclass
class Comparison:
    """Two bench JSONs side by side (:func:`compare_data`)."""

    a: dict
    b: dict
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    cases: list[CaseDiff] = field(default_factory=list)
    only_a: list[str] = field(default_factory=list)
    only_b: list[str] = field(default_factory=list)


def load_bench_json(path: str | Path) -> dict:
    """A bench JSON's document (``suite``, ``meta``, ``rows``).

    Raises:
        FileNotFoundError: no such file.
        ValueError: the file is not a bench JSON (the message names it).
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not a warpscatter bench JSON (not JSON: {exc})") from None
    if not (isinstance(data, dict) and isinstance(data.get("suite"), str) and isinstance(data.get("rows"), list)
            and all(isinstance(r, dict) and "name" in r for r in data["rows"])):
        raise ValueError(f"{path}: not a warpscatter bench JSON (expected an object with 'suite' and 'rows', each row "
                         "with a 'name'; bench-<suite>.json files of `warpscatter bench` are)")
    data.setdefault("meta", {})
    return data


def cases(data: dict) -> dict[tuple[str, str], dict]:
    """The rows of a bench JSON by ("", case), repeats numbered ``#2``, ... (the suite is not part of the key)."""
    out: dict[tuple[str, str], dict] = {}
    for row in data["rows"]:
        case = case_label(row)
        key, k = ("", case), 1
        while key in out:
            k += 1
            key = ("", f"{case} #{k}")
        out[key] = row
    return out


def _timings(row: dict) -> dict[str, dict]:
    """Stage -> {median_ms, min_ms, max_ms, n} of a row, ``total`` first (the row's medians; spreads where known)."""
    timing = row.get("timing") or {}
    out = {"total": {**(timing.get("total") or {}), "median_ms": row.get("median_ms")}}
    for stage, median in (row.get("stages_ms") or {}).items():
        out[stage] = {**((timing.get("stages") or {}).get(stage) or {}), "median_ms": median}
    return out


def verdict(a: dict, b: dict) -> str:
    """The module rule on two stage timings: slower, faster, within spread or no spread."""
    if min(a.get("n") or 0, b.get("n") or 0) < 2 or None in (a.get("min_ms"), a.get("max_ms"), b.get("min_ms"),
                                                                 b.get("max_ms")):
        return "no spread"
    if b["min_ms"] > a["max_ms"]:
        return "slower"
    if b["max_ms"] < a["min_ms"]:
        return "faster"
    return "within spread"


def _ratio(a, b) -> float | None:
    ok = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (a, b))
    return b / a if ok and a > 0 else None


def compare_data(a: dict, b: dict) -> Comparison:
    """Match two loaded bench JSONs (:func:`load_bench_json`) case by case (see the module doc)."""
    out = Comparison(a, b)
    if a["suite"] != b["suite"]:
        out.warnings.append(f"suites differ: A is {a['suite']!r}, B is {b['suite']!r} (cases are matched by name and "
                            f"parameters)")
    ma, mb = a.get("meta") or {}, b.get("meta") or {}
    differ = [f"{k} {format_value(ma.get(k))!r} vs {format_value(mb.get(k))!r}" for k in MACHINE_KEYS
              if k in ma and k in mb and ma[k] != mb[k]]
    if differ:
        out.warnings.append("machines or run settings differ: " + "; ".join(differ))
    versions = [f"{k} {ma.get(k)} vs {mb.get(k)}" for k in VERSION_KEYS if k in ma and k in mb and ma[k] != mb[k]]
    if versions:
        out.notes.append("versions differ: " + "; ".join(versions))
    ca, cb = cases(a), cases(b)
    out.only_a = [case for key, case in ((k, k[1]) for k in ca) if key not in cb]
    out.only_b = [case for key, case in ((k, k[1]) for k in cb) if key not in ca]
    for key, row_a in ca.items():
        if key not in cb:
            continue
        row_b = cb[key]
        ta, tb = _timings(row_a), _timings(row_b)
        stages = []
        for stage in dict.fromkeys([*ta, *tb]):
            sa, sb = ta.get(stage), tb.get(stage)
            if sa is None or sb is None:
                stages.append(StageDiff(stage, (sa or {}).get("median_ms"), (sb or {}).get("median_ms"), None,
                                        "only in A" if sb is None else "only in B"))
                continue
            stages.append(StageDiff(stage, sa["median_ms"], sb["median_ms"], _ratio(sa["median_ms"], sb["median_ms"]),
                                    verdict(sa, sb)))
        out.cases.append(CaseDiff(key[1], stages, {k: row_a.get(k) for k in ("rel_l1", "rmse")},
                                  {k: row_b.get(k) for k in ("rel_l1", "rmse")}))
    return out


def _describe(path: Path, data: dict) -> str:
    m = data.get("meta") or {}
    commit = str(m["commit"])[:10] + ("+dirty" if m.get("git_dirty") else "") if m.get("commit") else "no commit"
    quick = ", quick" if m.get("quick") else ""
    return shorten(f"{path} (suite {data['suite']}, {m.get('timestamp', 'no time stamp')}, {commit}, "
                   f"{m.get('cpu', '?')}, {m.get('threads', '?')} threads, repeats {m.get('repeats', '?')}{quick})",
                   TABLE_WIDTH - 5)


def _cell(v, fmt: str) -> str:
    return format(v, fmt) if isinstance(v, (int, float)) and not isinstance(v, bool) else ""


def format_comparison(c: Comparison, a_path: str | Path = "A", b_path: str | Path = "B") -> str:
    """The text of a :class:`Comparison`: files, warnings, a block per case, one-sided cases and a summary."""
    lines = [f"A: {_describe(Path(a_path), c.a)}", f"B: {_describe(Path(b_path), c.b)}"]
    lines += [f"warning: {w}" for w in c.warnings] + [f"note: {n}" for n in c.notes]
    lines.append("verdict: slower/faster when both have >= 2 repeats and their [fastest, slowest] repeats do not "
                 "overlap")
    head = f"{'  stage':<34}{'A ms':>11}{'B ms':>11}{'B/A':>8}  {'verdict':<14}{'A rel_l1':>10}{'B rel_l1':>10}" \
           f"{'A rmse':>10}{'B rmse':>10}"
    lines += ["", head, "-" * len(head)]
    counts: dict[str, int] = {}
    for case in c.cases:
        lines.append(shorten(case.case, TABLE_WIDTH))
        for k, s in enumerate(case.stages):
            err = (f"{_cell(case.a_errors['rel_l1'], '.4f'):>10}{_cell(case.b_errors['rel_l1'], '.4f'):>10}"
                   f"{_cell(case.a_errors['rmse'], '.3g'):>10}{_cell(case.b_errors['rmse'], '.3g'):>10}") if k == 0 \
                else ""
            ratio = f"{s.ratio:.2f}x" if s.ratio is not None else ""
            lines.append(f"  {shorten(s.stage, 32):<32}{_cell(s.a_ms, '.2f'):>11}{_cell(s.b_ms, '.2f'):>11}"
                         f"{ratio:>8}  {s.verdict:<14}{err}".rstrip())
        total = case.stages[0].verdict
        counts[total] = counts.get(total, 0) + 1
    for side, only in (("A", c.only_a), ("B", c.only_b)):
        if only:
            lines += ["", f"only in {side} ({len(only)}):"] + [shorten(f"  {case}", TABLE_WIDTH) for case in only]
    summary = ", ".join(f"{n} {v}" for v, n in sorted(counts.items())) or "none"
    lines += ["", f"{len(c.cases)} cases in both (total time: {summary}); {len(c.only_a)} only in A, "
                  f"{len(c.only_b)} only in B"]
    return "\n".join(lines)


def compare_reports(a_path: str | Path, b_path: str | Path) -> str:
    """The comparison text of two bench JSON files, B against A (see the module doc for the matching and the rule).

    Raises:
        FileNotFoundError: a file does not exist.
        ValueError: a file is not a bench JSON (the message names it).
    """
    return format_comparison(compare_data(load_bench_json(a_path), load_bench_json(b_path)), a_path, b_path)


__all__ = ["CaseDiff", "Comparison", "StageDiff", "cases", "compare_data", "compare_reports", "format_comparison",
           "load_bench_json", "verdict"]
