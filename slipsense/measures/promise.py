"""What an operating point promises about held grasps on objects not seen, and the words a checkpoint
states it in (``watch``, ``models``, the README): a rate with the upper end of its 95% Wilson interval."""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np


def wilson(k: float, n: int, z: float = 1.959964) -> tuple[float, float]:
    """The 95% Wilson score interval of a rate of ``k`` events in ``n`` runs (``(0, 0.043)`` for 0 of 85)."""
    if n == 0:
        return (math.nan, math.nan)
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (max(0.0, centre - half), min(1.0, centre + half))


def held_alarm_promise(alarmed: Sequence[bool], objects: Sequence[str]) -> dict[str, Any]:
    """What a held-alarm rate promises on objects not seen: the rate over these held grasps with the
    upper end of its 95% Wilson interval counting *objects*, not grasps, as the independent units.

    The grasps of one object share its surface, weight and the way it was grasped: when one alarms,
    others tend to. Counting each object as one trial, with the pooled rate (a design effect with
    the within-object correlation taken as 1), is the conservative reading: 0 alarms on 85 held
    grasps of 21 objects promises at most 15.5% on new objects, not the 4.3% that counting grasps
    gives. Both bounds are returned.

    Args:
        alarmed: ``(N,)`` whether each held grasp alarmed at the operating point.
        objects: ``(N,)`` each held grasp's object.
    """
    a, objs = np.asarray(alarmed, bool), np.asarray(objects)
    n, k = len(a), int(a.sum())
    units = len(np.unique(objs))
    rate = k / n if n else math.nan
    return {
        "held_grasps": n,
        "held_objects": units,
        "alarming": k,
        "rate": rate,
        "bound_counting_objects": wilson(rate * units, units)[1] if n else math.nan,
        "bound_counting_grasps": wilson(k, n)[1] if n else math.nan,
    }


def promise_text(op: Any) -> str:
    """What a checkpoint's operating point promises about held grasps, in one line, with where it was
    measured: ``held_alarm_unseen`` (held grasps of objects its family never saw, as ``adapt`` judged
    it) where there is one, else ``held_alarm`` (:func:`held_alarm_promise` on the grasps the operating
    point was chosen on); older checkpoints say what they have."""
    if not isinstance(op, dict):
        return "no operating point stored: nothing is promised about held grasps"
    unseen = op.get("held_alarm_unseen")
    if isinstance(unseen, dict) and unseen.get("held_grasps"):  # measured on objects it never saw: the promise
        h = unseen
        return (
            f"held grasps alarming on {h['measured_on']}: {100 * h['rate']:.1f}% ({h['alarming']} of "
            f"{h['held_grasps']}); on new objects at most {100 * h['bound_counting_objects']:.0f}% (95%, counting "
            f"each of the {h['held_objects']} objects with held grasps as one unit)"
        )
    h = op.get("held_alarm")
    if isinstance(h, dict) and h.get("held_grasps"):
        return (
            f"held grasps alarming: {100 * h['rate']:.1f}% ({h['alarming']} of {h['held_grasps']}) on "
            f"{op.get('chosen_on', 'the grasps it was chosen on')}; on new objects at most "
            f"{100 * h['bound_counting_objects']:.0f}% (95%, counting each of the {h['held_objects']} objects with held "
            "grasps as one unit)"
        )
    rate = op.get("false_positive_rate_on_training_runs")
    if isinstance(rate, (int, float)):
        return (
            f"held grasps alarming: {100 * rate:.1f}% on {op.get('chosen_on', 'its training runs')} "
            "(no bound counting objects stored: `slipsense calibrate` states one)"
        )
    return "nothing is promised about held grasps (no rate stored)"
