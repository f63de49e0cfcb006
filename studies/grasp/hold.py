"""How long an alarm should hold: a detector replayed over recordings, its alarm onsets per slip and
per held grasp counted at several hold times (``python -m studies grasp hold``).

A probability that dips under the threshold for a few frames in the middle of one slip makes the
plain alarm rule report that slip twice; a hold keeps the alarm on over such a dip. The right hold is
the shortest that merges the dips inside one slip: longer ones only keep a controller's alarm on for
longer after the slip. Only what happens before the object is lost counts (after it the gel is free).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from slipsense.alarm import debounce, hold, hold_frames, onsets
from slipsense.evaluation.judge import judge

HOLDS_S = (0.0, 0.1, 0.2, 0.3, 0.5, 1.0, 2.0)


def hold_study(checkpoint: Path | None, recordings: Path | None, holds: Sequence[float] = HOLDS_S) -> dict[str, Any]:
    """Per hold time: alarm onsets on slip runs (before contact is lost) and on held runs, slip runs
    alarming more than once; and every dip (seconds) between two alarms inside one slip."""
    ev = judge(checkpoint, recordings, progress=False)
    traces = []
    for r in ev.runs:
        alarm = debounce(r.probability, ev.threshold, ev.debounce)
        if r.slipped and r.moment_of_slip is not None:
            alarm = alarm[: r.moment_of_slip + 1]
        traces.append((r, alarm))
    dips = []
    for r, alarm in traces:
        on = np.flatnonzero(alarm)
        gaps = np.diff(on) - 1
        dips += [float(g / r.fps) for g in gaps[gaps > 0]] if r.slipped else []
    rows = []
    for h in holds:
        per_run = [(r.slipped, len(onsets(hold(a, hold_frames(h, r.fps))))) for r, a in traces]
        rows.append(
            {
                "hold_s": h,
                "slip_onsets": sum(n for s, n in per_run if s),
                "slips_alarming": sum(1 for s, n in per_run if s and n),
                "slips_alarming_more_than_once": sum(1 for s, n in per_run if s and n > 1),
                "held_onsets": sum(n for s, n in per_run if not s),
                "held_alarming": sum(1 for s, n in per_run if not s and n),
            }
        )
    return {
        "checkpoint": str(checkpoint) if checkpoint else "the shipped detector",
        "operating_point": {"threshold": ev.threshold, "debounce": ev.debounce},
        "runs": len(ev.runs),
        "slip_runs": sum(1 for r in ev.runs if r.slipped),
        "dips_inside_a_slip_s": sorted(dips),
        "rows": rows,
    }


def table(doc: dict[str, Any]) -> str:
    head = "| hold (s) | alarm onsets, slips | slips alarming | of them more than once | onsets, held grasps |"
    lines = [head, "|---:|---:|---:|---:|---:|"]
    for r in doc["rows"]:
        lines.append(
            f"| {r['hold_s']:g} | {r['slip_onsets']} | {r['slips_alarming']} of {doc['slip_runs']} | "
            f"{r['slips_alarming_more_than_once']} | {r['held_onsets']} |"
        )
    dips = doc["dips_inside_a_slip_s"]
    lines.append("")
    lines.append(
        f"Dips of the alarm inside one slip: {len(dips)}" + (f", the longest {max(dips):.2f} s." if dips else ".")
    )
    return "\n".join(lines)
