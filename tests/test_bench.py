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
    written = {p.name for p in tmp_path.glob("bench-*.json")}
    assert written == {f"bench-{s}.json" for s in bench.SUITES}
    for suite in bench.SUITES:
        data = json.loads((tmp_path / f"bench-{suite}.json").read_text())
        assert data["rows"], suite
        for row in data["rows"]:
            assert row["median_ms"] is None or row["median_ms"] >= 0.0, (suite, row["name"])
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
