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


def _interval(metric, arrays: Sequence[np.ndarray], objects: np.ndarray, draws: int, seed: int) -> list[float]:
    """95% percentile interval of ``metric(*arrays)`` over bootstrap draws of whole objects; draws
    where the metric is undefined (one class only) are left out."""
    names = np.unique(objects)
    groups = [np.flatnonzero(objects == o) for o in names]
    rng = np.random.default_rng(seed)
    values = []
    for _ in range(draws):
        idx = np.concatenate([groups[i] for i in rng.integers(0, len(groups), len(groups))])
        v = metric(*(a[idx] for a in arrays))
        if not math.isnan(v):
            values.append(v)
    if not values:
        return [math.nan, math.nan]
    return [float(np.percentile(values, 2.5)), float(np.percentile(values, 97.5))]


def _with_interval(metric, arrays, objects, draws, seed) -> dict[str, Any]:
    return {"value": metric(*arrays), "interval": _interval(metric, arrays, objects, draws, seed)}


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
    out: dict[str, Any] = {
        "grasps": int(len(y)),
        "slipped": int(y.sum()),
        "objects": int(len(np.unique(objs))),
        "roc_auc": _with_interval(roc_auc, (s, y), objs, draws, seed),
    }
    if alarmed is not None:
        a = np.asarray(alarmed, bool)
        out["operating_point"] = {
            "accuracy": _with_interval(accuracy, (a, y), objs, draws, seed),
            "balanced_accuracy": _with_interval(balanced_accuracy, (a, y), objs, draws, seed),
        }
    if len(np.unique(objs)) > 1:
        lo = leave_objects_out(s, y, objs)
        out["leave_objects_out"] = {
            "accuracy": _with_interval(accuracy, (lo, y), objs, draws, seed),
            "balanced_accuracy": _with_interval(balanced_accuracy, (lo, y), objs, draws, seed),
        }
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
        "grasps": int(len(y)),
        "slipped": int(y.sum()),
        "objects": int(len(np.unique(objs))),
        "roc_auc": {"value": 0.5, "interval": [0.5, 0.5]},
        "leave_objects_out": {
            "accuracy": _with_interval(accuracy, (predicted, y), objs, draws, seed),
            "balanced_accuracy": _with_interval(balanced_accuracy, (predicted, y), objs, draws, seed),
        },
    }


def beats(detector: Mapping[str, Any], baselines: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Sentences saying where the detector does not beat a baseline (its AUC, its leave-objects-out
    accuracy); empty when it beats every one."""
    said = []
    for name, b in baselines.items():
        for key, label in (("roc_auc", "ROC AUC"), ("leave_objects_out", "leave-objects-out accuracy")):
            mine, theirs = detector.get(key), b.get(key)
            if mine is None or theirs is None:
                continue
            mine_v = mine["value"] if key == "roc_auc" else mine["accuracy"]["value"]
            theirs_v = theirs["value"] if key == "roc_auc" else theirs["accuracy"]["value"]
            if not mine_v > theirs_v:
                said.append(f"the detector does not beat {name} on {label} ({mine_v:.3f} against {theirs_v:.3f})")
    return said
