"""Smoke test of the benchmark suites (warpscatter.bench): every suite runs in --quick mode and reports honest rows.

Speed is never asserted here (DESIGN.md: speed lives in ``warpscatter bench``); this checks that each suite runs,
writes its JSON, and that the errors and ratios it reports are finite and come with the same-run marcher rows.
"""

from __future__ import annotations

import json
import math

from warpscatter import bench


def test_every_suite_runs_quick_and_writes_finite_rows(tmp_path):
    report = bench.run("all", repeats=1, warmup=0, quick=True, out_dir=tmp_path)
    written = {p.name for p in tmp_path.glob("bench-*") if p.suffix in (".json", ".csv")}
    assert written == {f"bench-{s}.{ext}" for s in bench.SUITES for ext in ("json", "csv")}
    for suite in bench.SUITES:
        data = json.loads((tmp_path / f"bench-{suite}.json").read_text())
        assert data["rows"], suite
        assert data["meta"]["suite"] == suite and data["meta"]["timestamp"] and data["meta"]["cpu"], suite
        for row in data["rows"]:
            assert row["median_ms"] is None or row["median_ms"] >= 0.0, (suite, row["name"])
            assert row["case"] and "total" in row["timing"], (suite, row["name"])
            for key in ("rel_l1", "rmse", "speedup"):
                if row.get(key) is not None:
                    assert math.isfinite(row[key]), (suite, row["name"], key)
    assert len(report.rows) == sum(len(json.loads((tmp_path / f"bench-{s}.json").read_text())["rows"])
                                   for s in bench.SUITES)
    # the bars of the issues are computed in the same run as the brute-force marcher they compare against
    pre = json.loads((tmp_path / "bench-prefiltered.json").read_text())
    names = {r["name"] for r in pre["rows"]}
    assert {"raymarch exact (reference)", "raymarch exact 32", "fourier M=32"} <= names
    assert pre["meta"]["bar"]["fourier_speedup_vs_exact_raymarch128"] > 0.0
    epi = json.loads((tmp_path / "bench-epipolar.json").read_text())
    assert epi["meta"]["bar"]["per_pixel"]["speedup_vs_per_pixel"] > 0.0
    # csm against raytrace: the largest scene's figures, and (none in --quick, under 100k triangles) every large one
    csm_bar = json.loads((tmp_path / "bench-csm.json").read_text())["meta"]["bar"]
    assert csm_bar["speedup_per_pass"] > 0.0 and csm_bar["met"] is False and csm_bar["scenes"] == []
    csm_rows = json.loads((tmp_path / "bench-csm.json").read_text())["rows"]
    assert not any("terrain" in r["params"].get("scene", "") for r in csm_rows)  # full mode only
    # quality per unit of time: every fast method has an equal-error speed-up against the same run's marcher curve
    par = json.loads((tmp_path / "bench-pareto.json").read_text())
    for scene in ("colonnade", "canopy", "window"):
        for method in ("fourier", "moments4", "moments6", "epipolar"):
            row = next(r for r in par["rows"] if r["name"] == f"{scene}: {method}")
            assert row["speedup"] > 0.0 and 0.0 < row["rel_l1"] < 1.0, (scene, method)
            assert row["extra"]["speedup_bound"] in ("=", ">=", "<="), (scene, method)


def test_equal_error_time_interpolates_log_log_on_the_envelope_and_bounds_outside():
    from warpscatter.bench.suites_pareto import equal_error_time

    # (time, error): 10 ms -> 0.4, 40 ms -> 0.1; a dominated point (slower and worse) is ignored
    points = [(10.0, 0.4), (40.0, 0.1), (30.0, 0.5)]
    t, bound = equal_error_time(points, 0.2)  # halfway in log error -> geometric mean of the times
    assert bound == "" and math.isclose(t, 20.0, rel_tol=1e-12)
    assert equal_error_time(points, 0.05) == (40.0, ">=")  # more accurate than the best marcher: a lower bound
    assert equal_error_time(points, 0.8) == (10.0, "<=")  # worse than the fastest: an upper bound
    assert equal_error_time(points, 0.1) == (40.0, "")


def test_the_marcher_curve_extends_only_below_its_smallest_error():
    from warpscatter.bench.suites_pareto import curve_too_short

    errors = [0.4, 0.1, 0.3, 0.08]  # both step patterns' points so far
    assert curve_too_short(errors, 0.05)  # a method more accurate than every marcher point
    assert not curve_too_short(errors, 0.08) and not curve_too_short(errors, 0.2)


def test_timing_rounds_interleave_the_configurations():
    from warpscatter.bench.suites_pareto import interleaved_rounds

    # a round times every configuration once, in turn, so a slow phase of the machine is shared out among them
    calls = []
    runs = interleaved_rounds({"fourier": [1.0], "marcher 8": [2.0]}, 2, lambda key: calls.append(key) or len(calls))
    assert calls == ["fourier", "marcher 8", "fourier", "marcher 8"]
    assert runs == {"fourier": [1.0, 1, 3], "marcher 8": [2.0, 2, 4]}
    assert interleaved_rounds({"a": [1.0]}, 0, lambda key: 1 / 0) == {"a": [1.0]}
