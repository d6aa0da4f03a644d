"""The time left of a render (warpscatter.runtime.stages.EtaEstimator) and how the CLI shows it, on synthetic timings:
every time is passed in, nothing is timed."""

import io
import json

import pytest

from warpscatter.cli.main import ProgressDisplay, _previous_timings, eta_text, timing_table
from warpscatter.runtime.stages import Estimate, EtaEstimator


def feed(eta: EtaEstimator, reports) -> EtaEstimator:
    for stage, fraction, now in reports:
        eta.update(stage, fraction, now)
    return eta


def test_running_stage_uses_its_own_rate_after_its_set_up():
    # 2 s of set-up before the first report, then 10 % every second: 6 s left at 40 %, not 5 * 0.6 / 0.4 = 7.5
    eta = feed(EtaEstimator(), [("prefilter", 0.0, 10.0), ("prefilter", 0.1, 12.0), ("prefilter", 0.4, 15.0)])
    assert eta.estimate(15.0) == Estimate(pytest.approx(6.0), False)  # later stages unknown: this stage only
    assert eta.estimate(17.0).seconds == pytest.approx(4.0)  # time goes on between reports
    assert eta.estimate(30.0).seconds == 0.0  # overdue: never negative
    eta.update("prefilter", 1.0, 21.0)
    assert eta.estimate(21.0).seconds == 0.0


def test_a_single_report_measures_the_rate_from_the_stage_start():
    eta = feed(EtaEstimator(), [("scattering", 0.0, 0.0), ("scattering", 0.25, 2.0)])
    assert eta.estimate(2.0).seconds == pytest.approx(6.0)


def test_a_stage_without_progress_and_without_an_earlier_run_is_unknown():
    eta = feed(EtaEstimator(), [("scene", 0.0, 0.0), ("scene", 1.0, 0.1), ("compile", 0.0, 0.1)])
    estimate = eta.estimate(30.0)
    assert estimate.seconds is None
    assert eta_text("compile", estimate) == "ETA unknown: a compile reports no progress"
    assert eta_text("gbuffer", estimate) == "ETA unknown: no progress reported yet"


def test_an_earlier_run_adds_the_stages_still_to_come_scaled_by_the_finished_ones():
    earlier = {"scene": 1.0, "compile": 5.0, "prefilter": 10.0, "shading": 2.0, "write": 1.0}
    prior = EtaEstimator.PRIOR_SHARE * (1.0 + 10.0 + 2.0 + 1.0)  # the earlier run's own pace weighs in
    eta = feed(EtaEstimator(earlier), [("scene", 0.0, 0.0)])  # nothing finished: the earlier run as it was
    assert eta.scale() == 1.0 and eta.estimate(0.5) == Estimate(pytest.approx(0.5 + 5.0 + 10.0 + 2.0 + 1.0), True)
    eta = feed(EtaEstimator(earlier), [("scene", 0.0, 0.0), ("scene", 1.0, 2.0), ("compile", 0.0, 2.0)])
    # scene took twice its earlier time (the scale moves towards 2 by its weight); compile keeps its own time (it
    # depends on the kernel cache): 5 - 1 s left
    scale = (2.0 + prior) / (1.0 + prior)
    assert eta.scale() == pytest.approx(scale)
    assert eta.estimate(3.0) == Estimate(pytest.approx(4.0 + scale * (10.0 + 2.0 + 1.0)), True)
    # compile took 0.5 s (a warm cache): it does not change the scale; prefilter at half after 5 s: 5 s left
    feed(eta, [("compile", 1.0, 2.5), ("prefilter", 0.0, 2.5), ("prefilter", 0.5, 7.5)])
    assert eta.scale() == pytest.approx(scale) and eta.later_stages() == ["shading", "write"]
    assert eta.estimate(7.5) == Estimate(pytest.approx(5.0 + scale * (2.0 + 1.0)), True)
    assert eta_text("prefilter", eta.estimate(7.5)) == "ETA 9 s"
    # a stage that reported nothing yet but ran before: its earlier time, scaled (now by scene and prefilter)
    feed(eta, [("prefilter", 1.0, 12.5), ("shading", 0.0, 12.5)])
    scale = (2.0 + 10.0 + prior) / (1.0 + 10.0 + prior)
    assert eta.scale() == pytest.approx(scale)
    assert eta.estimate(13.0).seconds == pytest.approx(2.0 * scale - 0.5 + 1.0 * scale)


def test_short_stages_cannot_swing_the_scale():
    earlier = {"scene": 0.003, "compile": 1.0, "gbuffer": 0.1, "prefilter": 3.0, "shading": 1.0}
    eta = feed(EtaEstimator(earlier), [("scene", 0.0, 0.0), ("compile", 0.0, 0.1)])  # scene: 33 times slower
    assert eta.scale() < 1.1


def test_a_stage_the_earlier_run_did_not_have():
    eta = feed(EtaEstimator({"scene": 1.0, "raymarch": 4.0, "write": 1.0}),
               [("scene", 0.0, 0.0), ("scene", 1.0, 1.0), ("fourier", 0.0, 1.0), ("fourier", 0.5, 3.0)])
    assert eta.later_stages() == ["raymarch", "write"]  # not seen yet: they may still come
    assert eta.estimate(3.0).seconds == pytest.approx(2.0 + 4.0 + 1.0)


def test_the_issue_case_says_what_it_knows():
    # issue 50: "66 %, ETA 5 s at 10.6 s; done at 21.4 s": the stage's own rest was shown as the whole run's
    stage_only = feed(EtaEstimator(), [("scattering", 0.0, 0.6), ("scattering", 0.66, 10.6)])
    assert eta_text("scattering", stage_only.estimate(10.6)) == "ETA 5 s for this stage"
    with_earlier = feed(EtaEstimator({"scattering": 15.0, "shading": 2.0, "write": 3.5}),
                        [("scattering", 0.0, 0.6), ("scattering", 0.66, 10.6)])
    assert with_earlier.estimate(10.6).seconds == pytest.approx(0.34 / 0.066 + 2.0 + 3.5)


def test_eta_wording():
    assert eta_text("x", Estimate(4.6, True)) == "ETA 5 s"
    assert eta_text("x", Estimate(150.0, True)) == "ETA 2.5 min"
    assert eta_text("x", Estimate(7200.0, False)) == "ETA 2.0 h for this stage"


def test_plain_progress_lines_use_the_earlier_run():
    stream = io.StringIO()
    show = ProgressDisplay(stream=stream, interval=0.0, expected={"scattering": 1.0, "write": 1.0})
    show("scattering", 0.0)
    show("scattering", 0.5)
    show.close()
    line = stream.getvalue().splitlines()[1]
    assert "scattering  50% (ETA " in line and "for this stage" not in line


def test_previous_timings_come_from_the_sidecar(tmp_path):
    assert _previous_timings(tmp_path, "shot") is None
    (tmp_path / "shot.json").write_text(json.dumps({"timings_s": {"scene": 0.5, "raymarch": 2.0}}))
    assert _previous_timings(tmp_path, "shot") == {"scene": 0.5, "raymarch": 2.0}
    (tmp_path / "bad.json").write_text("{not json")
    assert _previous_timings(tmp_path, "bad") is None


def test_timing_table_condensed_to_the_longest_stages():
    timings = {"scene": 0.01, "compile": 0.7, "upload": 0.001, "gbuffer": 0.004, "shadow_map": 0.04,
               "prefilter": 0.3, "evaluate": 0.01, "write": 0.026}
    lines = timing_table(timings, max_rows=4).splitlines()
    assert [line.split()[0] for line in lines[2:6]] == ["compile", "shadow_map", "prefilter", "(5"]
    assert lines[5].split()[:3] == ["(5", "other", "stages)"]
    assert lines[-1].split()[:3] == ["total", "1.091", "s"]
    assert timing_table(timings) == timing_table(timings, max_rows=8)  # short enough: every stage
