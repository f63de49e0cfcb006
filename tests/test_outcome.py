"""The per-grasp outcome measure: trivially bad detectors score as bad, intervals count objects, the
leave-objects-out threshold never sees the object it judges."""

from __future__ import annotations

import numpy as np
import pytest

from slipsense.measures import pergrasp, slipped_or_held


def _data(seed=0, objects=6, per_object=8):
    rng = np.random.default_rng(seed)
    objs = np.repeat([f"o{i}" for i in range(objects)], per_object)
    slipped = rng.random(len(objs)) < 0.3  # unbalanced on purpose: the majority is "held"
    return objs, slipped


@pytest.mark.parametrize("always", [True, False])
def test_always_on_or_off_scores_chance_whatever_the_balance(always):
    objs, slipped = _data()
    score = np.full(len(objs), 1.0 if always else 0.0)
    m = slipped_or_held.outcome_measure(score, slipped, objs, alarmed=score > 0.5, draws=200)
    assert m["roc_auc"]["value"] == 0.5
    assert m["operating_point"]["balanced_accuracy"]["value"] == 0.5
    assert m["leave_objects_out"]["balanced_accuracy"]["value"] == 0.5
    # plain accuracy would flatter "always off" (the majority): the table shows the majority baseline beside it
    majority = slipped_or_held.majority_measure(slipped, objs, draws=200)
    if not always:
        assert m["operating_point"]["accuracy"]["value"] == majority["leave_objects_out"]["accuracy"]["value"]
    assert slipped_or_held.beats(m, {"majority_class": majority})  # said, not hidden


def test_a_perfect_score_is_perfect_and_its_intervals_hold_it():
    objs, slipped = _data(1)
    score = slipped.astype(float) + 0.01 * np.arange(len(objs)) / len(objs)
    m = slipped_or_held.outcome_measure(score, slipped, objs, alarmed=slipped, draws=300)
    assert m["roc_auc"]["value"] == 1.0
    for part in ("operating_point", "leave_objects_out"):
        for key in ("accuracy", "balanced_accuracy"):
            v = m[part][key]
            assert v["value"] == 1.0 and v["interval"] == [1.0, 1.0]
    assert slipped_or_held.beats(m, {"majority_class": slipped_or_held.majority_measure(slipped, objs)}) == []


def test_bootstrap_draws_objects_not_grasps():
    """Two objects, one all right and one all wrong: drawing grasps would give a narrow interval
    round 0.5; drawing objects gives draws of 0, 0.5 and 1."""
    objs = np.repeat(["a", "b"], 50)
    y = np.tile([True, False], 50)
    predicted = np.where(objs == "a", y, ~y)
    m = slipped_or_held.outcome_measure(predicted.astype(float), y, objs, alarmed=predicted, draws=400)
    assert m["operating_point"]["accuracy"]["value"] == 0.5
    assert m["operating_point"]["accuracy"]["interval"] == [0.0, 1.0]


def test_leave_objects_out_thresholds_never_see_the_judged_object():
    """Object "odd" scores every grasp 10 (all held); the others separate at about 0.5. A threshold
    chosen with "odd" inside would sit above 10; chosen without it, it calls all of "odd" slipped."""
    objs = np.array(["odd"] * 4 + ["a"] * 4 + ["b"] * 4)
    y = np.array([False] * 4 + [True, False] * 4)
    score = np.where(objs == "odd", 10.0, np.where(y, 0.9, 0.1))
    predicted = slipped_or_held.leave_objects_out(score, y, objs)
    assert predicted[objs == "odd"].all()
    assert (predicted[objs != "odd"] == y[objs != "odd"]).all()


def test_peak_alarm_score_is_where_the_debounced_alarm_fires():
    rng = np.random.default_rng(3)
    for _ in range(50):
        p = rng.random(30)
        p[:3] = np.nan
        k = int(rng.integers(1, 4))
        s = slipped_or_held.peak_alarm_score(p, k, start=2)
        for t in (0.1, 0.3, 0.5, 0.7, 0.9, s):
            fires = bool(pergrasp.debounce(p, t, k)[2:].any())
            assert fires == (s >= t)


def test_roc_auc_counts_ties_half_and_needs_both_classes():
    assert slipped_or_held.roc_auc([1, 1], [True, False]) == 0.5
    assert slipped_or_held.roc_auc([2, 1, 0], [True, False, False]) == 1.0
    assert np.isnan(slipped_or_held.roc_auc([1, 2], [True, True]))
