"""The alarm rule: a probability trace becomes an alarm when it stays at or above a threshold for a
number of frames in a row. The live detector and every per-grasp measure apply this one rule."""

from __future__ import annotations

import numpy as np


def debounce(probability: np.ndarray, threshold: float, frames: int = 1) -> np.ndarray:
    """``(N,)`` bool: alarm at ``t`` when the probability is ``>= threshold`` at ``t`` and the
    ``frames - 1`` frames before it. NaN (no answer yet) counts as below the threshold."""
    above = np.nan_to_num(np.asarray(probability, dtype=np.float64), nan=-np.inf) >= threshold
    if frames <= 1:
        return above
    run = np.zeros(len(above), dtype=np.int64)
    count = 0
    for i, a in enumerate(above):  # consecutive count; N is a few hundred
        count = count + 1 if a else 0
        run[i] = count
    return run >= frames
