"""Per-grasp outcome measure: did the detector tell the grasps that slipped from those that held?

For data labelled per grasp only (no moment of slip, e.g. the shared ``gelsight-lift`` grasps) and,
beside the early-warning figures, for any other. Each grasp gets one score (a detector's: the highest
threshold at which its debounced alarm fires, :func:`peak_alarm_score`; a baseline's: its own). From
the scores and the labels:

* ``roc_auc``: how well the score ranks slipped above held grasps (0.5: no better than chance);
* at the detector's own operating point (``alarmed``): accuracy and balanced accuracy;
* ``leave_objects_out``: the threshold for each object's grasps chosen on the other objects' grasps
  only (best balanced accuracy there), then accuracy and balanced accuracy of those predictions.

Each figure comes with a 95% interval from a bootstrap over objects: objects, not grasps, are drawn
with replacement, since the grasps of one object are not independent of each other. A detector
that is always on or always off scores balanced accuracy 0.5 and AUC 0.5 here, whatever the classes'
balance (the tests check it).
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from slipsense.measures.registry import Judged, pct, register, with_range

#: Bootstrap draws for the intervals.
BOOTSTRAP = 2000


def peak_alarm_score(probability: np.ndarray, debounce: int = 1, start: int = 0) -> float:
    """The highest threshold at which ``debounce`` consecutive frames from ``start`` on are at or
    above it: alarm at threshold t somewhere in the grasp <=> score >= t. NaN frames (no answer yet)
    never alarm; -inf when no frame answers."""
    p = np.asarray(probability, dtype=float)[start:]
    p = np.where(np.isnan(p), -np.inf, p)
    k = max(1, int(debounce))
    if len(p) < k:
        return -math.inf
    windows = np.lib.stride_tricks.sliding_window_view(p, k)
    return float(windows.min(axis=1).max())


def roc_auc(score: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve (ties count one half); NaN without both classes."""
    score, positive = np.asarray(score, float), np.asarray(positive, bool)
    pos, neg = score[positive], score[~positive]
    if len(pos) == 0 or len(neg) == 0:
        return math.nan
    greater = (pos[:, None] > neg[None, :]).sum()
    ties = (pos[:, None] == neg[None, :]).sum()
    return float((greater + 0.5 * ties) / (len(pos) * len(neg)))


def accuracy(predicted: np.ndarray, positive: np.ndarray) -> float:
    predicted, positive = np.asarray(predicted, bool), np.asarray(positive, bool)
    return float((predicted == positive).mean()) if len(positive) else math.nan


def balanced_accuracy(predicted: np.ndarray, positive: np.ndarray) -> float:
    """Mean of the recall on each class; NaN without both classes."""
    predicted, positive = np.asarray(predicted, bool), np.asarray(positive, bool)
    if positive.all() or not positive.any():
        return math.nan
    return float((predicted[positive].mean() + (~predicted[~positive]).mean()) / 2)


def choose_threshold(score: np.ndarray, positive: np.ndarray) -> float:
    """The threshold (predict slipped at score >= it) of best balanced accuracy on these grasps;
    among equally good ones the middle one. With one class only: above every score when it is
    "held", below every score when "slipped" (the majority rule)."""
    score, positive = np.asarray(score, float), np.asarray(positive, bool)
    finite = np.unique(score[np.isfinite(score)])
    if finite.size == 0:
        return math.inf
    cuts = np.concatenate([[finite[0] - 1.0], (finite[1:] + finite[:-1]) / 2, [finite[-1] + 1.0]])
    if positive.all() or not positive.any():
        return float(cuts[0] if positive.all() else cuts[-1])
    values = np.array([balanced_accuracy(score >= c, positive) for c in cuts])
    best = np.flatnonzero(values >= values.max() - 1e-12)
    return float(cuts[best[len(best) // 2]])


def leave_objects_out(score: np.ndarray, positive: np.ndarray, objects: Sequence[str]) -> np.ndarray:
    """Each grasp predicted with the threshold chosen on the other objects' grasps -> ``(N,)`` bool."""
    score, positive, objects = np.asarray(score, float), np.asarray(positive, bool), np.asarray(objects)
    predicted = np.zeros(len(score), bool)
    for o in np.unique(objects):
        mine = objects == o
        predicted[mine] = score[mine] >= choose_threshold(score[~mine], positive[~mine])
    return predicted


def object_interval(
    metric, arrays: Sequence[np.ndarray], objects: np.ndarray, draws: int, seed: int, order_free: bool = False
) -> list[float]:
    """95% percentile interval of ``metric(*arrays)`` over bootstrap draws of whole objects; draws
    where the metric is undefined (one class only) are left out. ``order_free``: the metric counts
    (integer sums), so a draw's value depends on how often each object was drawn, not in which order:
    each such multiset is measured once (5 objects: at most 126 of the 2000 draws), the same values."""
    names = np.unique(objects)
    groups = [np.flatnonzero(objects == o) for o in names]
    rng = np.random.default_rng(seed)
    values, seen = [], {}
    for _ in range(draws):
        drawn = rng.integers(0, len(groups), len(groups))
        key = tuple(np.sort(drawn)) if order_free else None
        v = seen.get(key) if order_free else None
        if v is None:
            idx = np.concatenate([groups[i] for i in drawn])
            v = metric(*(a[idx] for a in arrays))
            if order_free:
                seen[key] = v
        if not math.isnan(v):
            values.append(v)
    if not values:
        return [math.nan, math.nan]
    return [float(np.percentile(values, 2.5)), float(np.percentile(values, 97.5))]


def _with_interval(metric, arrays, objects, draws, seed) -> dict[str, Any]:
    """The metric (accuracy, balanced accuracy, ROC AUC: counts of grasps and of pairs) and its interval."""
    return {"value": metric(*arrays), "interval": object_interval(metric, arrays, objects, draws, seed, True)}


def _accuracies(predicted: np.ndarray, y: np.ndarray, objects: np.ndarray, draws: int, seed: int) -> dict[str, Any]:
    return {m.__name__: _with_interval(m, (predicted, y), objects, draws, seed) for m in (accuracy, balanced_accuracy)}


def _counts(y: np.ndarray, objects: np.ndarray) -> dict[str, int]:
    return {"grasps": int(len(y)), "slipped": int(y.sum()), "objects": int(len(np.unique(objects)))}


def outcome_measure(
    score: Sequence[float],
    slipped: Sequence[bool],
    objects: Sequence[str],
    alarmed: Sequence[bool] | None = None,
    draws: int = BOOTSTRAP,
    seed: int = 0,
) -> dict[str, Any]:
    """The per-grasp measure of one scorer (see the module notes).

    Args:
        score: ``(N,)`` one score per grasp, higher = more likely slipped.
        slipped: ``(N,)`` the grasps' labels.
        objects: ``(N,)`` each grasp's object: the unit of the leave-objects-out thresholds and of
            the bootstrap.
        alarmed: ``(N,)`` whether the detector alarmed at its own operating point (None for a
            scorer without one, e.g. a baseline).
    """
    s, y, objs = np.asarray(score, float), np.asarray(slipped, bool), np.asarray(objects)
    if not (len(s) == len(y) == len(objs)):
        raise ValueError("score, slipped and objects differ in length")
    out: dict[str, Any] = {**_counts(y, objs), "roc_auc": _with_interval(roc_auc, (s, y), objs, draws, seed)}
    if alarmed is not None:
        out["operating_point"] = _accuracies(np.asarray(alarmed, bool), y, objs, draws, seed)
    if len(np.unique(objs)) > 1:
        out["leave_objects_out"] = _accuracies(leave_objects_out(s, y, objs), y, objs, draws, seed)
    return out


def majority_measure(slipped: Sequence[bool], objects: Sequence[str], draws: int = BOOTSTRAP, seed: int = 0):
    """The majority-class baseline: every grasp of an object predicted as the class most grasps of
    the other objects have (no score: its AUC is 0.5)."""
    y, objs = np.asarray(slipped, bool), np.asarray(objects)
    predicted = np.zeros(len(y), bool)
    for o in np.unique(objs):
        mine = objs == o
        predicted[mine] = y[~mine].mean() > 0.5 if (~mine).any() else False
    return {
        **_counts(y, objs),
        "roc_auc": {"value": 0.5, "interval": [0.5, 0.5]},
        "leave_objects_out": _accuracies(predicted, y, objs, draws, seed),
    }


def _shortfalls(detector: Mapping[str, Any], baselines: Mapping[str, Mapping[str, Any]]):
    """``(baseline, key, the detector's value, the baseline's)`` where the detector does not beat a baseline
    on its ROC AUC (``roc_auc``) or its leave-objects-out accuracy (``leave_objects_out``)."""
    for name, b in baselines.items():
        for key in ("roc_auc", "leave_objects_out"):
            mine, theirs = detector.get(key), b.get(key)
            if mine is None or theirs is None:
                continue
            mine_v = mine["value"] if key == "roc_auc" else mine["accuracy"]["value"]
            theirs_v = theirs["value"] if key == "roc_auc" else theirs["accuracy"]["value"]
            if not mine_v > theirs_v:
                yield name, key, mine_v, theirs_v


def beats(detector: Mapping[str, Any], baselines: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Sentences saying where the detector does not beat a baseline (its AUC, its leave-objects-out
    accuracy); empty when it beats every one."""
    label = {"roc_auc": "ROC AUC", "leave_objects_out": "leave-objects-out accuracy"}
    return [
        f"the detector does not beat {name} on {label[key]} ({mine:.3f} against {theirs:.3f})"
        for name, key, mine, theirs in _shortfalls(detector, baselines)
    ]


#: Plain words for the baselines of :meth:`grasp_measure`.
BASELINE_WORDS = {
    "majority_class": "always answers the outcome most grasps of the other objects had",
    "frame_difference": "the largest change between consecutive frames",
    "mean_frame_difference": "the mean change between consecutive frames",
    "difference_to_contact": "the largest change from the first frame of contact",
}


def telling_apart(measure: Mapping[str, Any], context: Mapping[str, Any] | None = None) -> list[str]:
    """Slipped against held grasps: the detector's figures, then the baselines'."""
    d = measure["detector"]
    own = (d.get("operating_point") or {}).get("accuracy")
    loo = (d.get("leave_objects_out") or {}).get("accuracy")
    lines = [
        "Telling slipped grasps from held ones (ranking: 50% = chance, 100% = every slipped grasp scored above "
        "every held one; 95% ranges: objects drawn again at random):",
        f"  detector: ranking {with_range(d['roc_auc'])}; right on {with_range(own)} of grasps at its own "
        "alarm threshold",
    ]
    if loo:
        lines.append(
            f"            right on {with_range(loo)} with each object's threshold chosen on the other objects only"
        )
    for name, b in measure.get("baselines", {}).items():
        b_loo = (b.get("leave_objects_out") or {}).get("accuracy")
        words = BASELINE_WORDS.get(name, "a rule that learns nothing")
        lines.append(
            f"  baseline {name} ({words}): ranking {pct(b['roc_auc']['value'])}, right on "
            f"{pct(b_loo['value']) if b_loo else 'n/a'} with thresholds chosen on the other objects"
        )
    lines += _not_beaten(d, measure.get("baselines", {}))
    return lines


def _not_beaten(d: Mapping[str, Any], baselines: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """One line per baseline the detector does not beat (the ``not_beaten`` sentences of the JSON)."""
    said: dict[str, list[str]] = {}
    for name, key, mine, theirs in _shortfalls(d, baselines):
        line = f"{pct(mine)} against {pct(theirs)}"
        line = f"ranking {line}" if key == "roc_auc" else f"right on {line} with thresholds chosen on the other objects"
        said.setdefault(name, []).append(line)
    return [f"  the detector does not beat {name}: {'; '.join(s)}" for name, s in said.items()]


def _balanced(m: Mapping[str, Any]) -> float:
    op = m["detector"].get("operating_point")
    return op["balanced_accuracy"]["value"] if op else math.nan


@register("grasp_measure", telling_apart, pools=False, reads=("baselines",), rank=_balanced, label="balanced accuracy")
def grasp_measure(judged: Judged, draws: int = BOOTSTRAP) -> dict[str, Any]:
    """Slipped against held grasps: the detector's ROC AUC of each grasp's
    :func:`peak_alarm_score`, accuracy and balanced accuracy at its operating point and with
    thresholds chosen on the other objects, 95% intervals over objects; beside it the majority class
    and the non-learned baselines' scores (``judged.baselines``), and where it does not beat them."""
    runs = judged.runs
    slipped = [r.slipped for r in runs]
    objects = [r.object for r in runs]
    score = np.array([peak_alarm_score(r.probability, k, judged.startup) for r, (_, k, _) in zip(runs, judged.points)])
    alarmed = [v >= th for v, (th, _, _) in zip(score, judged.points)]  # anywhere in the grasp, after the slip too
    detector = outcome_measure(score, slipped, objects, alarmed, draws)
    baselines = {"majority_class": majority_measure(slipped, objects, draws)}
    for name, s in (judged.baselines or {}).items():
        baselines[name] = outcome_measure(s, slipped, objects, None, draws)
    return {"detector": detector, "baselines": baselines, "not_beaten": beats(detector, baselines)}
