"""The alarm rule: a probability trace becomes an alarm when it stays at or above a threshold for a
number of frames in a row (debounce), and an alarm once raised holds for a hold time, so that one slip
whose probability dips for a moment is one alarm onset, not two. The live detector and every
per-grasp measure apply this one rule; holding never moves a first alarm nor makes a grasp alarm that
did not, so the per-grasp outcomes (warned in time, too early, missed, held grasps alarming) are the
same with any hold: it changes how many onsets a slip gives."""

from __future__ import annotations

import numpy as np

#: Seconds an alarm holds once raised, in the operating points training writes. On the shipped
#: two-finger detector's replay of the 150 shared runs (``python -m studies grasp hold``), the
#: longest dip of an alarm inside one slip was 0.24 s: 6 slip runs alarmed two or three times
#: without a hold, none from a 0.3 s hold on; 0.5 s leaves a margin.
HOLD_S = 0.5


def debounce(probability: np.ndarray, threshold: float, frames: int = 1) -> np.ndarray:
    """``(N,)`` bool: alarm at ``t`` when the probability is ``>= threshold`` at ``t`` and the
    ``frames - 1`` frames before it. NaN (no answer yet) counts as below the threshold."""
    above = np.nan_to_num(np.asarray(probability, dtype=np.float64), nan=-np.inf) >= threshold
    t = np.arange(len(above))  # below: t minus the last frame below the threshold = frames above in a row
    return above if frames <= 1 else t - np.maximum.accumulate(np.where(above, -1, t)) >= frames


def hold(alarm: np.ndarray, frames: int) -> np.ndarray:
    """``(N,)`` bool: on at ``t`` when ``alarm`` was on at ``t`` or at any of the ``frames`` frames
    before it (an alarm, once raised, stays on for ``frames`` frames after it last held)."""
    alarm = np.asarray(alarm, dtype=bool)
    t = np.arange(len(alarm))  # below: t minus the last frame the alarm held = frames since
    return alarm if frames <= 0 else t - np.maximum.accumulate(np.where(alarm, t, -frames - 1)) <= frames


def alarm_trace(
    probability: np.ndarray, threshold: float, debounce_frames: int = 1, hold_frames: int = 0
) -> np.ndarray:
    """``(N,)`` bool: the alarm of a probability trace: :func:`debounce`, then :func:`hold`."""
    return hold(debounce(probability, threshold, debounce_frames), hold_frames)


def hold_frames(hold_s: float, fps: float) -> int:
    """A hold time in seconds as whole frames of a stream at ``fps`` (rounded to the nearest)."""
    return max(0, int(round(float(hold_s) * float(fps))))


def shown_probability(p: float, threshold: float, digits: int = 3) -> str:
    """``p`` with ``digits`` decimals, rounded toward the side of ``threshold`` it lies on, so a
    printed value never reads as crossing the threshold (0.9975 under 0.998 prints 0.997)."""
    scale = 10**digits
    value = np.floor(p * scale) / scale if p < threshold else np.ceil(p * scale - 1e-9) / scale
    return f"{value:.{digits}f}"


def onsets(alarm: np.ndarray) -> np.ndarray:
    """Frame indices where the alarm turns on."""
    alarm = np.asarray(alarm, dtype=bool)
    return np.flatnonzero(alarm & ~np.concatenate([[False], alarm[:-1]]))
