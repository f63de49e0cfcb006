"""Binary classification metrics from confusion counts (class 1 = slip)."""

from __future__ import annotations

from typing import Any

import numpy as np


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
