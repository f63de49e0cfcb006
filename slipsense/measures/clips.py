"""The papers' short-clip measure: binary classification metrics of clips (class 1 = slip)."""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from slipsense.measures.registry import Judged, pct, register


def confusion(y_true, y_pred) -> np.ndarray:
    """2x2 counts ``[[tn, fp], [fn, tp]]`` (rows: true class, columns: predicted class)."""
    y_true = np.asarray(y_true, dtype=np.int64)
    y_pred = np.asarray(y_pred, dtype=np.int64)
    cm = np.zeros((2, 2), dtype=np.int64)
    np.add.at(cm, (y_true, y_pred), 1)
    return cm


def scores(cm: np.ndarray) -> dict[str, float]:
    """accuracy, precision, recall and F1 of the slip class from a 2x2 confusion matrix.

    Precision/recall/F1 are 0.0 where undefined (no predicted / no true slips), as scikit-learn's
    ``zero_division=0``.
    """
    (tn, fp), (fn, tp) = np.asarray(cm, dtype=np.float64)
    n = tn + fp + fn + tp
    precision = tp / (tp + fp) if tp + fp else 0.0
    recall = tp / (tp + fn) if tp + fn else 0.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    return {
        "accuracy": float((tp + tn) / n) if n else 0.0,
        "precision": float(precision),
        "recall": float(recall),
        "f1": float(f1),
    }


def metrics_from(p: np.ndarray, y: np.ndarray, threshold: float = 0.5) -> dict[str, Any]:
    """Scores, counts and the confusion matrix for probabilities ``p`` against labels ``y``."""
    pred = (p >= threshold).astype(np.int64)
    cm = confusion(y, pred)
    eps = 1e-7
    loss = float(-np.mean(np.where(y == 1, np.log(p + eps), np.log(1 - p + eps)))) if len(y) else 0.0
    return {
        **scores(cm),
        "loss": loss,
        "n_clips": int(len(y)),
        "n_slip": int((y == 1).sum()),
        "n_wiggle": int((y == 0).sum()),
        "confusion": cm.tolist(),
        "threshold": threshold,
    }


def clip_metrics(p: np.ndarray, y: np.ndarray, threshold: float) -> dict[str, Any]:
    """Accuracy, balanced accuracy, precision, recall, F1 and the always-wiggle baseline."""
    cm = confusion(y, np.nan_to_num(p, nan=0.0) >= threshold)
    (tn, fp), (fn, tp) = cm.tolist()
    s = scores(cm)
    return {
        "clips": len(y),
        "slip_clips": int((y == 1).sum()),
        "accuracy": (tp + tn) / max(len(y), 1),
        "balanced_accuracy": (s["recall"] + (tn / (tn + fp) if tn + fp else 0.0)) / 2,
        **{k: s[k] for k in ("precision", "recall", "f1")},
        "always_wiggle_accuracy": float((y == 0).mean()) if len(y) else math.nan,
        **{"tp": tp, "fp": fp, "fn": fn, "tn": tn},
    }


def clip_lines(result: Mapping[str, Any], context: Mapping[str, Any] | None = None, frames: int = 5) -> list[str]:
    """The papers' clip figures (:func:`clip_metrics`), only where
    both kinds of clip are there."""
    c = result["operating_point"]
    n, slip = c["clips"], c["slip_clips"]
    if slip == 0:
        return []  # no slip with a known moment to end a clip: the early-warning lines say so
    if slip == n:
        return [f"Short clips: all {n} clips are slip clips, so clip accuracy says nothing here and is left out."]
    return [
        f"Short clips ({frames} frames, as published papers measure): {n} clips, {slip} ending just before a slip; "
        f"right on {pct(c['accuracy'])} (calling every clip no-slip would be right on "
        f"{pct(c['always_wiggle_accuracy'])}); mean of the rates on slip and no-slip clips {pct(c['balanced_accuracy'])}; "
        f"F1 {c['f1']:.2f} (balance of precision {pct(c['precision'])}, recall {pct(c['recall'])})."
    ]


@register(
    "clips", clip_lines, pools=False, reads=("clips",), rank=lambda r: r["operating_point"]["f1"], label="clip F1"
)
def clips(judged: Judged) -> dict[str, Any] | None:
    """The papers' protocol on the replayed traces (``judged.clips``: every 5-frame clip scored by the
    probability at its last frame), at the operating point and at 0.5."""
    if judged.clips is None:
        return None
    p, y = judged.clips
    threshold = judged.points[0][0] if judged.points else 0.5
    return {"operating_point": clip_metrics(p, y, threshold), "at_0.5": clip_metrics(p, y, 0.5)}
