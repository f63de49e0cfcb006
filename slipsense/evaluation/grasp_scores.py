"""Scores of per-frame traces of whole grasps: each run's verdict at an operating point, the papers'
clip protocol on the same traces, a fold's result and folds pooled (:mod:`slipsense.evaluation.folds`).

Everything here is numpy on traces that a replay (:meth:`slipsense.streaming.detector.SlipDetector.replay`)
or a training's out-of-fold predictions gave.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from slipsense.evaluation import pergrasp
from slipsense.recordings.clips import ClipSpec, plan_windows
from slipsense.recordings.runs import GraspRun


def stored_trace(run: dict[str, Any]) -> np.ndarray:
    """``(N,)`` float64 P(slip) of a run as a fold file keeps it (``null`` where the detector gave
    no answer, NaN here)."""
    return np.array([np.nan if v is None else v for v in run["probability"]], dtype=np.float64)


def clip_scores(
    runs: Sequence[GraspRun], probs: Sequence[np.ndarray], labels: dict, frames: int = 5
) -> tuple[np.ndarray, np.ndarray]:
    """The paper's clip protocol on per-frame traces: every ``frames``-frame clip the project cuts
    (:func:`slipsense.recordings.clips.plan_windows`: the clip ending right before the moment of
    slip, two wiggle windows per video of a run that held) is scored by the detector's probability
    at its last frame. Returns ``(p, y)``; a run's cameras share one fused trace, so both cameras'
    clips of a run get the probability of their own end frames."""
    spec = ClipSpec(frames=frames)
    p, y = [], []
    for run, trace in zip(runs, probs):
        for cam in run.cameras:
            label = labels.get((run.object, run.experiment, cam))
            if label is None:
                continue
            for w in plan_windows(label, spec):
                p.append(trace[w.end])
                y.append(w.y)
    return np.asarray(p, dtype=np.float64), np.asarray(y, dtype=np.int64)


def clip_metrics(p: np.ndarray, y: np.ndarray, threshold: float) -> dict[str, Any]:
    """Accuracy, balanced accuracy, precision, recall, F1 and the always-wiggle baseline."""
    pred = np.nan_to_num(p, nan=0.0) >= threshold
    tp, fp = int((pred & (y == 1)).sum()), int((pred & (y == 0)).sum())
    fn, tn = int((~pred & (y == 1)).sum()), int((~pred & (y == 0)).sum())
    prec = tp / (tp + fp) if tp + fp else 0.0
    rec = tp / (tp + fn) if tp + fn else 0.0
    spec = tn / (tn + fp) if tn + fp else 0.0
    return {
        "clips": len(y),
        "slip_clips": int((y == 1).sum()),
        "accuracy": (tp + tn) / max(len(y), 1),
        "balanced_accuracy": (rec + spec) / 2,
        "precision": prec,
        "recall": rec,
        "f1": 2 * prec * rec / (prec + rec) if prec + rec else 0.0,
        "always_wiggle_accuracy": float((y == 0).mean()) if len(y) else math.nan,
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "tn": tn,
    }


def fold_result(
    test: Sequence[GraspRun],
    probs: Sequence[np.ndarray],
    op: dict[str, Any],
    history: list[dict[str, Any]],
    labels: dict,
    held: Sequence[str],
    cfg,
) -> dict[str, Any]:
    """A fold's per-grasp summary and clip metrics at its operating point, plus what pooling needs:
    every held-out run's trace and the clips' probabilities and labels."""
    rests = [pergrasp.rest_mask(r.contact) for r in test]
    outs = _outcomes(test, probs, op, cfg.horizon, rests)
    p, y = clip_scores(test, probs, labels)
    return {
        "objects": sorted(held),
        "operating_point": op,
        "per_grasp": pergrasp.summarise(outs),
        "clips": clip_metrics(p, y, op["threshold"]),
        "history": history,
        "clip_probability": [round(float(v), 5) for v in p],
        "clip_label": [int(v) for v in y],
        "runs": [
            {
                "object": r.object,
                "experiment": r.experiment,
                "cameras": list(r.cameras),
                "moment_of_slip": r.moment_of_slip,
                "slipped": r.slipped,
                "outcome": o.outcome,
                "first_alarm": o.first_alarm,
                "lead": o.lead,
                "rest": np.flatnonzero(rest).tolist(),
                "probability": [None if math.isnan(v) else round(float(v), 6) for v in pr],
            }
            for r, o, pr, rest in zip(test, outs, probs, rests)
        ],
    }


def pool_folds(folds: Sequence[dict[str, Any]], thresholds: Sequence[float] | None = None) -> dict[str, Any]:
    """Pool :func:`fold_result` s: per-grasp outcomes and clip decisions, each fold at its own
    operating point; and, for the trade-off curve, every fold's runs at shared ``thresholds``."""
    outcomes = [
        pergrasp.GraspOutcome(r["outcome"], r["first_alarm"], r["lead"], 0.0, 0) for f in folds for r in f["runs"]
    ]
    per_grasp = pergrasp.summarise(outcomes)
    per_grasp["runs_alarming_at_rest"] = sum(f["per_grasp"]["runs_alarming_at_rest"] for f in folds)
    per_grasp["held_alarm_fraction"] = float(np.mean([f["per_grasp"]["held_alarm_fraction"] for f in folds]))
    decisions = np.concatenate([np.asarray(f["clip_probability"]) >= f["operating_point"]["threshold"] for f in folds])
    y = np.concatenate([np.asarray(f["clip_label"], dtype=np.int64) for f in folds])
    if thresholds is None:
        thresholds = pergrasp.THRESHOLDS
    traces, moments, rests = [], [], []
    for f in folds:
        for r in f["runs"]:
            p = stored_trace(r)
            rest = np.zeros(len(p), dtype=bool)
            rest[r["rest"]] = True
            traces.append(p)
            moments.append(r["moment_of_slip"])
            rests.append(rest)
    debounce = int(np.median([f["operating_point"]["debounce"] for f in folds]))
    curve = pergrasp.table(traces, moments, thresholds, (debounce,), rests=rests)
    intervals = pergrasp.bootstrap_curve(traces, moments, thresholds, debounce)
    for row, ci in zip(curve, intervals):
        row.update({k: ci[k] for k in ("warned_low", "warned_high", "fp_low", "fp_high")})
    per_grasp["intervals"] = pergrasp.bootstrap_rates([o.outcome for o in outcomes])
    p_all = np.concatenate([np.asarray(f["clip_probability"], dtype=np.float64) for f in folds])
    return {
        "per_grasp": per_grasp,
        "clips": clip_metrics(decisions.astype(np.float64), y, 0.5),
        "clips_at_half": clip_metrics(p_all, y, 0.5),
        "operating_points": [f["operating_point"] for f in folds],
        "curve": curve,
    }


def evaluate_held_out(
    probs: Sequence[np.ndarray], op: dict[str, Any], runs: Sequence[GraspRun], labels: dict, horizon: int
) -> dict[str, Any]:
    """Per-grasp outcomes and clip metrics of ``runs`` from their P(slip) traces at ``op``."""
    outs = _outcomes(runs, probs, op, horizon, [pergrasp.rest_mask(r.contact) for r in runs])
    p, y = clip_scores(runs, probs, labels)
    return {"per_grasp": pergrasp.summarise(outs), "clips": clip_metrics(p, y, op["threshold"])}


def _outcomes(runs, probs, op: dict[str, Any], horizon: int, rests) -> list[pergrasp.GraspOutcome]:
    """Each run's per-grasp verdict at the operating point ``op`` (from its ``startup``); a slip
    labelled as a whole (no moment to warn before) is ``slip_without_moment``, neither slip nor held."""
    startup = int(op.get("startup", pergrasp.STARTUP))
    return [
        pergrasp.trace_outcome(p, op["threshold"], op["debounce"], r.moment_of_slip, r.slipped, horizon, startup, rest)
        for r, p, rest in zip(runs, probs, rests)
    ]
