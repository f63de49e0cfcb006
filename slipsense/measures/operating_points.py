"""The operating point: the (threshold, debounce) a detector alarms at, chosen on training runs only
from the per-grasp outcomes (:mod:`~slipsense.measures.pergrasp`) at every point of a grid."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from slipsense.alarm import HOLD_S, debounce
from slipsense.errors import ConfigError
from slipsense.measures.pergrasp import bootstrap_rates, grasp_outcome, summarise
from slipsense.measures.registry import horizon_frames, startup_frames


#: Thresholds an operating point is chosen among: class-balanced training inflates probabilities,
#: so the grid is dense near 1.
THRESHOLDS = tuple(float(t) for t in np.round(np.linspace(0.05, 0.95, 19), 3)) + (0.97, 0.98, 0.99, 0.995, 0.998, 0.999)


def table(
    probabilities: Sequence[np.ndarray],
    moments: Sequence[int | None],
    thresholds: Sequence[float],
    debounces: Sequence[int] = (1,),
    horizon: int | None = None,
    startup: int | None = None,
    rests: Sequence[np.ndarray | None] | None = None,
    *,
    fps: float,
    intervals: int = 0,
) -> list[dict[str, Any]]:
    """One row (``threshold``, ``debounce``, :func:`summarise`) per (threshold, debounce) over runs given as
    probability traces taken at ``fps`` frames/s; ``horizon`` and ``startup`` in frames at that rate (None:
    :data:`~slipsense.measures.registry.HORIZON_S` and ``STARTUP_S`` at it). With ``intervals`` bootstrap
    draws, also ``warned_low``/``warned_high`` and ``fp_low``/``fp_high``: 95% intervals over runs
    (:func:`bootstrap_rates`, the same draws for every row)."""
    horizon = horizon_frames(fps) if horizon is None else horizon
    startup = startup_frames(fps) if startup is None else startup
    rests = rests if rests is not None else [None] * len(probabilities)
    rows = []
    for k in debounces:
        for th in thresholds:
            outs = [
                grasp_outcome(debounce(p, th, k), m, horizon, startup, r)
                for p, m, r in zip(probabilities, moments, rests)
            ]
            rows.append({"threshold": float(th), "debounce": int(k), **summarise(outs, fps)})
            if intervals:
                ci = bootstrap_rates([o.outcome for o in outs], intervals)
                rows[-1].update({c: ci[c] for c in ("warned_low", "warned_high", "fp_low", "fp_high")})
    return rows


#: Thresholds the "at most K% of held grasps alarm" rule may also take: a class-balanced detector
#: puts many calm frames above 0.999.
FINE_TAIL = (0.9995, 0.9998, 0.9999)


def choose_operating_point(
    probabilities: Sequence[np.ndarray],
    moments: Sequence[int | None],
    thresholds: Sequence[float] | None = None,
    debounces: Sequence[int] = (1, 2, 3, 5),
    horizon: int | None = None,
    startup: int | None = None,
    max_held_alarm: float | None = None,
    *,
    fps: float,
) -> dict[str, Any]:
    """The (threshold, debounce) to alarm at, chosen on these runs. Call it on training runs only
    (out-of-fold predictions of inner folds): choosing it on test runs is tuning on the test set.
    ``fps``: the rate the traces were taken at; ``horizon``, ``startup``: frames at it (None: the
    seconds of :data:`~slipsense.measures.registry.HORIZON_S` and ``STARTUP_S`` at it).

    ``max_held_alarm`` None: the best :func:`summarise` score (warned rate minus false-positive
    rate; ties: the shortest debounce, then the middle of the tying thresholds, for a margin on both
    sides). ``max_held_alarm=K``: the rule a user states, "at most a fraction K of the grasps that
    hold may alarm": among the points whose false-positive grasps are at most ``K`` of the held runs,
    the one that warns in time of the most slips (ties: fewer false positives, fewer premature
    warnings, the shortest debounce, the middle threshold); when none is that quiet, the quietest.
    """
    if thresholds is None:
        thresholds = THRESHOLDS if max_held_alarm is None else tuple(sorted(set(THRESHOLDS) | set(FINE_TAIL)))
    horizon = horizon_frames(fps) if horizon is None else horizon
    startup = startup_frames(fps) if startup is None else startup
    rows = table(probabilities, moments, thresholds, debounces, horizon, startup, fps=fps)
    if max_held_alarm is None:
        top = max(round(r["score"], 9) for r in rows)
        tied = [r for r in rows if round(r["score"], 9) == top]
        rule = "best score (warned rate - false-positive rate)"
    else:
        if not 0.0 <= float(max_held_alarm) <= 1.0:
            raise ConfigError(f"max_held_alarm must be a fraction in [0, 1], got {max_held_alarm!r}")
        ok = [r for r in rows if r["false_positive_grasps"] <= max_held_alarm * r["held_runs"] + 1e-9]
        if not ok:
            least = min(r["false_positive_grasps"] for r in rows)
            ok = [r for r in rows if r["false_positive_grasps"] == least]
        key = lambda r: (r["warned"], -r["false_positive_grasps"], -r["premature"])  # noqa: E731
        top = max(key(r) for r in ok)
        tied = [r for r in ok if key(r) == top]
        rule = f"at most {100 * max_held_alarm:g}% of held grasps alarming"
    k = min(r["debounce"] for r in tied)
    tied = sorted((r for r in tied if r["debounce"] == k), key=lambda r: r["threshold"])
    best = tied[(len(tied) - 1) // 2]
    point = {"threshold": best["threshold"], "debounce": best["debounce"], "hold_s": HOLD_S}
    on_training_runs = {f"{k}_on_training_runs": best[k] for k in ("score", "warned_rate", "false_positive_rate")}
    times = {"horizon_s": horizon / fps, "startup_s": startup / fps}  # what the frame counts stand for
    return {**point, "horizon": horizon, "startup": startup, **times, "rule": rule, **on_training_runs}
