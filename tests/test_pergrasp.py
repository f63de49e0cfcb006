"""Per-grasp early-warning measure: trivial detectors must score badly, a good one well."""

import numpy as np
import pytest

from slipsense.evaluation import pergrasp


def _runs(rng, n_slip=6, n_held=6, n=200):
    moments = [int(m) for m in rng.integers(60, 180, n_slip)] + [None] * n_held
    return moments, [n] * len(moments)


def _score(alarms, moments):
    return pergrasp.summarise([pergrasp.grasp_outcome(a, m) for a, m in zip(alarms, moments)])


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
    assert pergrasp.grasp_outcome(a, None).outcome == "clean"
    a[:] = False
    a[20] = True
    assert pergrasp.grasp_outcome(a, 70, horizon=50).outcome == "warned"  # exactly m - H
    assert pergrasp.grasp_outcome(a, 71, horizon=50).outcome == "premature"
    b = np.zeros(100, bool)
    b[80] = True  # after the moment: too late
    assert pergrasp.grasp_outcome(b, 70).outcome == "missed"


def test_debounce_and_nan():
    p = np.array([np.nan, 0.9, 0.9, 0.1, 0.9, 0.9, 0.9])
    assert pergrasp.debounce(p, 0.5, 1).tolist() == [False, True, True, False, True, True, True]
    assert pergrasp.debounce(p, 0.5, 3).tolist() == [False] * 6 + [True]


def test_rest_alarms_counted():
    contact = np.full((2, 100), 1.0)
    contact[:, 40:90] = 20.0
    rest = pergrasp.rest_mask(contact)
    assert rest[20] and not rest[50]
    a = np.zeros(100, bool)
    a[20] = True
    assert pergrasp.grasp_outcome(a, None, rest=rest).rest_alarms == 1


def test_operating_point_prefers_separating_threshold():
    rng = np.random.default_rng(3)
    moments, lengths = _runs(rng)
    probs = []
    for m, n in zip(moments, lengths):
        p = rng.uniform(0, 0.3, n)
        if m is not None:
            p[m - 5 : m + 1] = 0.8
        probs.append(p)
    op = pergrasp.choose_operating_point(probs, moments)
    assert 0.3 <= op["threshold"] < 0.8 and op["score_on_training_runs"] == pytest.approx(1.0)
