"""False alarms per hour of holding: how often a grasp that holds makes the gripper react for nothing.

The figure a robot builder feels: a detector that alarms once a minute on a steady grasp is unusable
whatever its per-grasp rates. Counted on the live alarm (threshold, debounce and the hold after it,
:func:`slipsense.alarm.alarm_trace`), so one dip inside a slip is one alarm: each **onset** (the alarm
turning on, or on when a gel comes to be touched) while a gel is touched, on the *held part* of every
grasp:

* a grasp that held: every frame from the camera's start-up on;
* a grasp that slipped with a known moment of slip: the frames before its warning horizon (an alarm
  in the horizon is a warning, counted by :mod:`slipsense.measures.pergrasp`);
* a grasp labelled slipped as a whole (no moment): left out, its held part is not known.

Divided by the hours of contact of those frames (frames in contact at the run's own rate). The 95%
interval comes from a bootstrap over objects (ratio of sums), as in
:mod:`slipsense.measures.slipped_or_held`. A detector always off scores 0; one always on, one onset
per grasp with a held part.

A rate over seconds of contact means nothing (one alarm in 6 s of holding is "600 an hour"): below
:data:`MIN_MINUTES` of contact the sentence gives the count and the minutes, and says why no rate
(the JSON keeps the value, with ``"enough": false`` and the ``"minimum_minutes"``).
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from slipsense.alarm import alarm_trace, hold_frames, onsets
from slipsense.measures.registry import Judged, plural, register
from slipsense.measures.slipped_or_held import BOOTSTRAP, object_interval

#: The fewest minutes of contact on which a rate per hour is stated (at 10 minutes, no alarm at all
#: still leaves up to 18 an hour possible: Poisson, 95%).
MIN_MINUTES = 10.0


def held_part(run: Any, horizon: int, startup: int) -> tuple[int, int] | None:
    """``(start, end)`` frames of ``run``'s held part (a :class:`~slipsense.measures.pergrasp.RunTrace`;
    ``horizon``/``startup`` in frames of the detector's clock, scaled to the run's rate); None for a
    slip without a moment."""
    scale = run.fps / run.model_fps
    h, s = (horizon, startup) if scale == 1 else (max(1, round(horizon * scale)), round(startup * scale))
    if run.slipped and run.moment_of_slip is None:
        return None
    end = run.n_frames if not run.slipped else max(0, run.moment_of_slip - h)
    return min(s, end), end


def onsets_and_seconds(run: Any, point: tuple[float, int, float], horizon: int, startup: int) -> tuple[int, float]:
    """Alarm onsets while touched in ``run``'s held part at ``point`` ``(threshold, debounce, hold_s)``,
    and the seconds of contact there; ``(0, 0.0)`` where it has none."""
    part = held_part(run, horizon, startup)
    if part is None or part[1] <= part[0]:
        return 0, 0.0
    (a, b), (threshold, debounce, hold_s) = part, point
    alarm = alarm_trace(run.probability, threshold, debounce, hold_frames(hold_s, run.fps))[a:b]
    touched = np.ones(b - a, bool) if run.rest is None else ~np.asarray(run.rest, bool)[a:b]
    # an alarm already on when the gel is first touched counts from that frame: always on is not quiet
    return len(onsets(alarm & touched)), float(touched.sum()) / run.fps


def _per_hour(counts: np.ndarray, seconds: np.ndarray) -> float:
    total = seconds.sum()
    return float(counts.sum() / (total / 3600.0)) if total > 0 else math.nan


def words(result: Mapping[str, Any], context: Mapping[str, Any] | None = None) -> list[str]:
    """One line: the rate, its range and what it counts."""
    v, (lo, hi) = result["per_hour"]["value"], result["per_hour"]["interval"]
    if v is None or math.isnan(v):
        return ["False alarms per hour of holding: no held grasp in contact to count them on."]
    minutes = 60 * result["hours"]
    if minutes < MIN_MINUTES:
        return [
            f"False alarms per hour of holding: not stated: {plural(result['false_alarms'], 'alarm')} raised over "
            f"{minutes:.1f} minutes of contact while {result['grasps']} grasps held (before any slip); a rate needs "
            f"at least {MIN_MINUTES:g} minutes of contact."
        ]
    span = "" if lo is None or math.isnan(lo) else f" (95% range {lo:.0f}-{hi:.0f}, objects drawn again at random)"
    return [
        f"False alarms per hour of holding: {v:.0f}{span}: {plural(result['false_alarms'], 'alarm')} raised "
        f"over {60 * result['hours']:.1f} minutes of contact while {result['grasps']} grasps held (before any slip)."
    ]


@register(
    "false_alarms_per_hour",
    words,
    rank=lambda r: r["per_hour"]["value"] if r["enough"] else math.nan,  # a rate it does not state is no rank
    label="false alarms per hour",
    lower_is_better=True,
)
def false_alarms_per_hour(judged: Judged, draws: int = BOOTSTRAP, seed: int = 0) -> dict[str, Any]:
    """``{"false_alarms", "hours", "grasps", "per_hour": {"value", "interval"}, "enough"}``: alarm onsets
    on the held part of every grasp per hour of contact (see the module notes); ``enough``: at least
    :data:`MIN_MINUTES` of contact, the basis on which the rate is stated."""
    rows = [
        (r.object, *onsets_and_seconds(r, p, judged.horizon, judged.startup))
        for r, p in zip(judged.runs, judged.points)
        if held_part(r, judged.horizon, judged.startup) is not None
    ]
    objects = np.array([o for o, _, _ in rows])
    counts = np.array([c for _, c, _ in rows], float)
    seconds = np.array([s for _, _, s in rows], float)
    draws = draws if len(np.unique(objects)) > 1 else 0
    interval = object_interval(_per_hour, (counts, seconds), objects, draws, seed)
    return {
        "false_alarms": int(counts.sum()),
        "hours": float(seconds.sum() / 3600.0),
        "grasps": len(rows),
        "per_hour": {"value": _per_hour(counts, seconds), "interval": interval},
        "enough": bool(seconds.sum() >= 60 * MIN_MINUTES),
        "minimum_minutes": MIN_MINUTES,
    }
