"""The bench's outputs (warpscatter.bench.report, .compare) on hand-made rows: no suite is run, no Warp kernel.

JSON with every repeat, spread and machine meta; CSV layout; a table of short lines without dicts; the comparison
of two JSONs; the charts (when matplotlib is installed).
"""

from __future__ import annotations

import csv
import datetime
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from warpscatter import bench
from warpscatter.bench import report as report_module
from warpscatter.bench.compare import compare_reports, load_bench_json
from warpscatter.bench.report import CSV_COLUMNS, TABLE_WIDTH, BenchReport, short_labels, stage_medians

#: Meta keys every bench JSON has (the machine and the run).
META_KEYS = {"cpu", "cores", "threads", "os", "python", "warp", "numpy", "openimageio", "warpscatter", "commit",
             "timestamp", "suite", "repeats", "warmup", "quick", "argv"}


def add_render_row(report: BenchReport, name: str, stage_runs_ms: list[dict], **row) -> dict:
    """Add a row the way the suites do: per-stage medians of several runs (ms here, seconds in the runs)."""
    stages = stage_medians([{k: v / 1e3 for k, v in run.items()} for run in stage_runs_ms])
    return report.add(name=name, median_ms=sum(stages.values()), stages_ms=stages, **row)


def runs(scale: float = 1.0, jitter=(1.0, 1.02, 0.98, 1.01, 0.99)) -> list[dict]:
    """Five repeats of a two-stage render: gbuffer 2 ms and scattering 8 ms (times ``scale``), a few % apart."""
    return [{"gbuffer": 2.0 * scale * j, "scattering": 8.0 * scale * j} for j in jitter]


def fake_suite(report: BenchReport, repeats, warmup, quick, progress):
    """Two scenes, a marcher curve and a fast method each (errors against a reference), a measured primitive."""
    for scene, base in (("colonnade", 1.0), ("canopy", 1.5)):
        for steps, err in ((16, 0.08), (32, 0.05), (64, 0.03)):
            add_render_row(report, f"{scene}: marcher shadow_map", runs(base * steps / 16), params={"steps": steps},
                           rel_l1=err, rmse=err / 2)
        add_render_row(report, f"{scene}: fourier", runs(base * 0.7), params={"map": 256}, rel_l1=0.04, rmse=0.02,
                       speedup=2.5, extra={"compile_s": 0.1, "nested": {"a": 1, "b": [1, 2]}})
    m = bench.measure(lambda: sum(range(1000)), repeats, warmup)
    report.add(name="prefix sums " + "with a very long label " * 8, params={"mode": "x" * 90},
               median_ms=1e3 * m["median_s"], extra={"note": "y" * 300})
    report.meta["bar"] = {"fourier": {"speedup": 2.5, "ok": True}}
    report.meta["cases"] = {f"case {k}": {"ms": k, "rel_l1": 0.1} for k in range(20)}


@pytest.fixture
def no_charts(monkeypatch):
    """Reports write no PNG (as without matplotlib)."""
    monkeypatch.setattr(report_module, "pyplot", lambda: None)


@pytest.fixture
def fake_run(monkeypatch, tmp_path):
    """``bench.run`` of the fake suite (3 repeats) into ``tmp_path``: its report."""
    monkeypatch.setitem(bench.SUITES, "fake", bench.Suite("fake", "hand-made rows", fake_suite))
    return bench.run("fake", repeats=3, warmup=0, out_dir=tmp_path)


def test_json_has_every_repeat_the_spread_and_the_machine(no_charts, fake_run, tmp_path):
    assert {p.name for p in tmp_path.iterdir()} == {"bench-fake.json", "bench-fake.csv"}
    data = json.loads((tmp_path / "bench-fake.json").read_text())
    assert data["format"] == report_module.FORMAT and data["suite"] == "fake"
    assert META_KEYS <= set(data["meta"])
    meta = data["meta"]
    assert meta["repeats"] == 3 and meta["warmup"] == 0 and meta["quick"] is False and meta["suite"] == "fake"
    assert isinstance(meta["argv"], list) and meta["cores"] >= 1 and meta["cpu"]
    assert datetime.datetime.fromisoformat(meta["timestamp"]).utcoffset() == datetime.timedelta(0)
    row = next(r for r in data["rows"] if r["name"] == "colonnade: fourier")
    assert row["case"] == "colonnade: fourier [map=256]"
    stages = row["timing"]["stages"]
    assert set(stages) == {"gbuffer", "scattering"}
    expected = [8.0 * 0.7 * j for j in (1.0, 1.02, 0.98, 1.01, 0.99)]
    assert stages["scattering"]["repeats_ms"] == pytest.approx(expected)
    assert stages["scattering"]["n"] == 5
    assert stages["scattering"]["median_ms"] == pytest.approx(row["stages_ms"]["scattering"])
    assert stages["scattering"]["min_ms"] == pytest.approx(min(expected))
    assert stages["scattering"]["max_ms"] == pytest.approx(max(expected))
    s = stages["scattering"]
    assert s["iqr_ms"] == pytest.approx(s["q3_ms"] - s["q1_ms"]) and s["min_ms"] <= s["q1_ms"] <= s["q3_ms"]
    total = row["timing"]["total"]  # a render's repeats: the per-repeat sums of its stages
    assert total["repeats_ms"] == pytest.approx([10.0 * 0.7 * j for j in (1.0, 1.02, 0.98, 1.01, 0.99)])
    measured = next(r for r in data["rows"] if r["name"].startswith("prefix sums"))
    assert measured["timing"]["total"]["n"] == 3 and len(measured["timing"]["total"]["repeats_ms"]) == 3
    assert measured["extra"]["note"] == "y" * 300  # the JSON keeps the full text the table cuts


def test_a_row_without_recorded_repeats_says_so():
    report = BenchReport("x")
    row = report.add(name="one build", median_ms=123.0)
    assert row["timing"]["total"]["repeats_ms"] is None and row["timing"]["total"]["median_ms"] == 123.0


def test_csv_has_a_total_and_a_line_per_stage(no_charts, fake_run, tmp_path):
    with open(tmp_path / "bench-fake.csv", newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        lines = list(reader)
    assert tuple(reader.fieldnames) == CSV_COLUMNS
    assert len(lines) == sum(1 + len(r.get("stages_ms") or {}) for r in fake_run.rows)
    fourier = [x for x in lines if x["name"] == "colonnade: fourier"]
    assert [x["stage"] for x in fourier] == ["total", "gbuffer", "scattering"]
    total = fourier[0]
    assert float(total["rel_l1"]) == 0.04 and float(total["speedup"]) == 2.5 and total["n"] == "5"
    assert len(total["repeats_ms"].split(";")) == 5 and float(total["min_ms"]) <= float(total["max_ms"])
    assert fourier[1]["rel_l1"] == ""  # errors only on the total line
    assert float(fourier[2]["median_ms"]) == pytest.approx(fake_run.rows[3]["stages_ms"]["scattering"])


def test_table_lines_are_short_and_hold_no_dict(fake_run):
    fake_run.meta["embree"] = "not installed " * 30
    text = fake_run.table()
    lines = text.splitlines()
    assert max(map(len, lines)) <= TABLE_WIDTH
    assert "{" not in text and "}" not in text
    assert "…" in text  # the long cells are cut
    assert "bar.fourier.speedup=2.5" in text and "cases=(" in text  # nested meta: flattened, or counted
    assert str(fake_run.meta["cpu"])[:20] in text


def test_short_labels_name_the_distinguishing_parameters():
    rows = [{"name": "epipolar", "params": {"lines": 256, "size": "320x180"}},
            {"name": "epipolar", "params": {"lines": 1024, "size": "320x180"}},
            {"name": "raymarch", "params": {"size": "320x180"}}]
    assert short_labels(rows) == ["epipolar (lines=256)", "epipolar (lines=1024)", "raymarch"]


# ---- compare ----------------------------------------------------------------------------------------------------


def write_report(path: Path, suite: str, cases: dict[str, float], cpu: str = "cpu A") -> Path:
    """A bench JSON with one render row per case, its times scaled by the case's factor."""
    report = BenchReport(suite, meta={"cpu": cpu, "threads": 2, "repeats": 5})
    for name, scale in cases.items():
        add_render_row(report, name, runs(scale), rel_l1=0.01 * scale)
    path.write_text(json.dumps(report.to_dict()))
    return path


def stage_line(text: str, case: str, stage: str) -> str:
    lines = text.splitlines()
    start = lines.index(case)
    return next(line for line in lines[start + 1:] if line.split()[0] == stage)


def test_compare_flags_a_2x_slowdown_not_a_1_percent_change(tmp_path):
    a = write_report(tmp_path / "a.json", "s", {"doubled": 1.0, "steady": 1.0, "gone": 1.0})
    b = write_report(tmp_path / "b.json", "s", {"doubled": 2.0, "steady": 1.01, "new": 1.0})
    text = compare_reports(a, b)
    assert max(map(len, text.splitlines())) <= TABLE_WIDTH
    doubled = stage_line(text, "doubled", "total")
    assert "2.00x" in doubled and "slower" in doubled
    assert "0.0100" in doubled and "0.0200" in doubled  # the error columns
    assert "slower" in stage_line(text, "doubled", "scattering")
    steady = stage_line(text, "steady", "total")
    assert "1.01x" in steady and "within spread" in steady
    assert "only in A (1):\n  gone" in text and "only in B (1):\n  new" in text
    assert "warning" not in text
    faster = compare_reports(b, a)
    assert "faster" in stage_line(faster, "doubled", "total")


def test_compare_warns_about_other_suites_and_machines(tmp_path):
    a = write_report(tmp_path / "a.json", "moments", {"x": 1.0})
    b = write_report(tmp_path / "b.json", "epipolar", {"x": 1.0}, cpu="cpu B")
    text = compare_reports(a, b)
    assert "warning: suites differ" in text and "cpu 'cpu A' vs 'cpu B'" in text
    assert "1 cases in both" in text  # the same case measured by two suites still matches


def test_compare_without_repeats_gives_no_verdict(tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps({"suite": "s", "rows": [{"name": "x", "median_ms": 10.0}]}))  # the old layout
    b.write_text(json.dumps({"suite": "s", "rows": [{"name": "x", "median_ms": 20.0}]}))
    assert "no spread" in stage_line(compare_reports(a, b), "x", "total")


@pytest.mark.parametrize("content", ['{"rows": []}', "[1, 2]", "not json {", '{"suite": "s", "rows": [1]}'])
def test_compare_rejects_a_file_that_is_not_a_bench_json(tmp_path, content):
    bad = tmp_path / "other.json"
    bad.write_text(content)
    good = write_report(tmp_path / "a.json", "s", {"x": 1.0})
    with pytest.raises(ValueError, match="other.json"):
        compare_reports(good, bad)
    with pytest.raises(ValueError, match="not a warpscatter bench JSON"):
        load_bench_json(bad)


# ---- machine meta -----------------------------------------------------------------------------------------------


def test_source_commit_never_fails(monkeypatch):
    def broken(*args, **kwargs):
        raise subprocess.TimeoutExpired("git", 2.0)

    from warpscatter.io import provenance

    monkeypatch.setattr(provenance.subprocess, "run", broken)
    provenance.source_commit.cache_clear()
    try:
        assert report_module.source_commit() == (None, None)
        assert report_module.machine_meta()["commit"] is None
    finally:
        provenance.source_commit.cache_clear()


# ---- charts -----------------------------------------------------------------------------------------------------


def test_charts_are_written_with_matplotlib(fake_run, tmp_path):
    pytest.importorskip("matplotlib")
    names = {p.name for p in fake_run.files}
    assert names == {"bench-fake.json", "bench-fake.csv", "bench-fake.png", "bench-fake-error-time.png"}
    assert all((tmp_path / n).stat().st_size > 0 for n in names)
    points = report_module.error_time_points(fake_run)
    assert set(points) == {"colonnade", "canopy"}
    marcher = [p for p in points["colonnade"] if p[0] == "marcher shadow_map"]
    assert [p[3] for p in sorted(marcher)] == ["16", "32", "64"]  # the marcher's curve, labelled by steps


def test_no_error_time_chart_without_errors(tmp_path):
    pytest.importorskip("matplotlib")
    report = BenchReport("plain", meta={"repeats": 5})
    add_render_row(report, "a", runs())
    add_render_row(report, "b", runs(3.0))
    assert {p.name for p in report.write(tmp_path)} == {"bench-plain.json", "bench-plain.csv", "bench-plain.png"}


def test_error_images_of_a_comparison(tmp_path):
    """A suite's comparisons (bench papers: Peters Figs. 15-16's scenes for both bases) become one PNG each: the
    reference, each method's image and its signed error image."""
    plt = pytest.importorskip("matplotlib.pyplot")
    rng = np.random.default_rng(0)
    ref = rng.uniform(0.1, 1.0, (30, 48, 3))
    bright = ref * 1.2
    report = BenchReport("pics", meta={"repeats": 1})
    add_render_row(report, "a", runs())
    report.comparisons["colonnade"] = (ref, {"fourier": ref.copy(), "moments6": bright})
    written = {p.name for p in report.write(tmp_path)}
    assert "bench-pics-errors-colonnade.png" in written
    img = plt.imread(tmp_path / "bench-pics-errors-colonnade.png")
    assert img.shape[0] > 200 and img.shape[1] > 400
    # the too-bright method's error panel is red (RdBu_r at +20 %), the exact one's white
    red = img[..., 0] > 0.6
    assert (red & (img[..., 2] < 0.4)).mean() > 0.02
