"""Per-grasp early-warning measure: trivial detectors must score badly, a good one well."""

import numpy as np
import pytest

from slipsense.measures import pergrasp
from slipsense.measures import promise
from slipsense.measures import operating_points
from slipsense.recordings.contact import rest_mask


#: the rate these traces are taken at: 2 s = 50 frames, 0.4 s = 10
FPS = 25.0


def _runs(rng, n_slip=6, n_held=6, n=200):
    moments = [int(m) for m in rng.integers(60, 180, n_slip)] + [None] * n_held
    return moments, [n] * len(moments)


def _score(alarms, moments):
    return pergrasp.summarise([pergrasp.grasp_outcome(a, m, 50, 10) for a, m in zip(alarms, moments)], FPS)


def test_always_on_scores_badly():
    moments, lengths = _runs(np.random.default_rng(0))
    row = _score([np.ones(n, bool) for n in lengths], moments)
    assert row["warned"] == 0 and row["premature"] == 6
    assert row["false_positive_rate"] == 1.0 and row["score"] == -1.0


def test_always_off_warns_nothing():
    moments, lengths = _runs(np.random.default_rng(1))
    row = _score([np.zeros(n, bool) for n in lengths], moments)
    assert row["warned"] == 0 and row["missed"] == 6 and row["false_positive_grasps"] == 0
    assert row["score"] == 0.0


def test_alarm_only_before_the_moment_scores_well():
    moments, lengths = _runs(np.random.default_rng(2))
    alarms = []
    for m, n in zip(moments, lengths):
        a = np.zeros(n, bool)
        if m is not None:
            a[m - 10 : m + 1] = True
        alarms.append(a)
    row = _score(alarms, moments)
    assert row["warned_rate"] == 1.0 and row["median_lead_frames"] == 10
    assert row["false_positive_grasps"] == 0 and row["score"] == 1.0


def test_outcome_boundaries_and_startup():
    a = np.zeros(100, bool)
    a[3] = True  # camera start-up: not scored
    assert pergrasp.grasp_outcome(a, None, 50, 10).outcome == "clean"
    a[:] = False
    a[20] = True
    assert pergrasp.grasp_outcome(a, 70, horizon=50, startup=10).outcome == "warned"  # exactly m - H
    assert pergrasp.grasp_outcome(a, 71, horizon=50, startup=10).outcome == "premature"
    b = np.zeros(100, bool)
    b[80] = True  # after the moment: too late
    assert pergrasp.grasp_outcome(b, 70, 50, 10).outcome == "missed"


def test_debounce_and_nan():
    p = np.array([np.nan, 0.9, 0.9, 0.1, 0.9, 0.9, 0.9])
    assert pergrasp.debounce(p, 0.5, 1).tolist() == [False, True, True, False, True, True, True]
    assert pergrasp.debounce(p, 0.5, 3).tolist() == [False] * 6 + [True]


def test_rest_alarms_counted():
    contact = np.full((2, 100), 1.0)
    contact[:, 40:90] = 20.0
    rest = rest_mask(contact)
    assert rest[20] and not rest[50]
    a = np.zeros(100, bool)
    a[20] = True
    assert pergrasp.grasp_outcome(a, None, 50, 10, rest=rest).rest_alarms == 1


def test_operating_point_prefers_separating_threshold():
    rng = np.random.default_rng(3)
    moments, lengths = _runs(rng)
    probs = []
    for m, n in zip(moments, lengths):
        p = rng.uniform(0, 0.3, n)
        if m is not None:
            p[m - 5 : m + 1] = 0.8
        probs.append(p)
    op = operating_points.choose_operating_point(probs, moments, fps=FPS)
    assert 0.3 <= op["threshold"] < 0.8 and op["score_on_training_runs"] == pytest.approx(1.0)


def _peaks(slip_peak: float, held_peaks, n=200, moment=150):
    """Traces of 0.01 with one 10-frame peak: before the moment in slip runs, mid-run in held ones."""
    probs, moments = [], []
    for _ in range(10):
        p = np.full(n, 0.01)
        p[moment - 10 : moment + 1] = slip_peak
        probs.append(p)
        moments.append(moment)
    for peak in held_peaks:
        p = np.full(n, 0.01)
        p[80:90] = peak
        probs.append(p)
        moments.append(None)
    return probs, moments


def test_at_most_k_percent_of_held_grasps_rule():
    held = [i / 20 for i in range(20)]  # 0 .. 0.95: the quietest held grasp never alarms above 0.95
    probs, moments = _peaks(0.97, held)
    op = operating_points.choose_operating_point(probs, moments, max_held_alarm=0.05, fps=FPS)
    assert op["threshold"] == 0.97 and op["warned_rate_on_training_runs"] == 1.0
    assert op["false_positive_rate_on_training_runs"] == 0.0 and "5%" in op["rule"]
    # slips no louder than the held grasps: the rule keeps its promise and warns of nothing
    probs, moments = _peaks(0.5, held)
    op = operating_points.choose_operating_point(probs, moments, max_held_alarm=0.05, fps=FPS)
    assert op["false_positive_rate_on_training_runs"] <= 0.05 and op["warned_rate_on_training_runs"] == 0.0
    # an always-on detector: no point is quiet enough, the quietest is taken (still 100%)
    on = [np.ones(200) for _ in moments]
    op = operating_points.choose_operating_point(on, moments, max_held_alarm=0.05, fps=FPS)
    assert op["false_positive_rate_on_training_runs"] == 1.0
    with pytest.raises(Exception, match="fraction"):
        operating_points.choose_operating_point(probs, moments, max_held_alarm=5, fps=FPS)


def test_bootstrap_intervals_hold_the_rates_and_trivial_detectors_have_none():
    probs, moments = _peaks(0.97, [i / 20 for i in range(20)])
    rows = operating_points.table(probs, moments, [0.5, 0.97], fps=FPS, intervals=500)
    for r in rows:
        assert r["warned_low"] <= r["warned_rate"] <= r["warned_high"]
        assert r["fp_low"] <= r["false_positive_rate"] <= r["fp_high"]
    assert rows[0]["false_positive_rate"] == 0.5 and rows[0]["fp_low"] < 0.5 < rows[0]["fp_high"]  # peaks 0.5 .. 0.95
    on = operating_points.table([np.ones(200) for _ in moments], moments, [0.5], fps=FPS, intervals=200)[0]
    assert on["fp_low"] == on["fp_high"] == 1.0 and on["warned_low"] == on["warned_high"] == 0.0


def test_wilson_interval_is_not_zero_width_at_zero_events():
    lo, hi = promise.wilson(0, 85)
    assert lo == 0.0 and 0.03 < hi < 0.05  # none of 85 held grasps alarmed: the rate may still be ~4%
    lo, hi = promise.wilson(11, 51)
    assert lo < 11 / 51 < hi
    rates = pergrasp.bootstrap_rates(["warned"] * 11 + ["missed"] * 40 + ["clean"] * 85, samples=300)
    assert rates["fp_low"] == rates["fp_high"] == 0.0 and rates["fp_wilson"][1] > 0.03
