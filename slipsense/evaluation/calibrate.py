"""Calibration to the user's own sensor: a new operating point from a few of their grasps.

A detector trained on one GelSight can rank another sensor's grasps well and still never alarm (the
shipped detector's probabilities on the ``gelsight-lift`` grasps stay below its 0.995 threshold).
Recording some grasps on one's own sensor, held ones at least, and choosing the threshold on them
costs minutes, not a data set: :func:`calibrate` replays them through the detector as
:func:`slipsense.evaluation.judge.judge` does, puts the threshold just above all but a
``budget`` fraction of the held grasps' peak scores (:func:`calibrated_threshold`) and writes a copy
of the checkpoint with that operating point, what it was chosen on and what it promises on new
objects (:func:`slipsense.measures.promise.held_alarm_promise`, objects as the unit). The weights
are not touched.
"""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from slipsense.atomic import atomic_path
from slipsense.checkpoint import read_info, update_info
from slipsense.errors import ConfigError, InputError
from slipsense.evaluation.judge import judge
from slipsense.evaluation.summary import rate_lines
from slipsense.measures.promise import held_alarm_promise
from slipsense.recordings.recording_set import Recordings
from slipsense.sensors.spec import sensor_of


def calibrated_threshold(held: Sequence[float], others: Sequence[float], budget: float) -> float:
    """The threshold (alarm at score >= it) that leaves at most ``floor(budget * len(held))`` of the
    ``held`` grasps' scores at or above it, as low as that allows (so that slipped grasps are caught):
    halfway between the highest held score that must stay quiet and the next higher score of any
    grasp (``others``: the slipped grasps'), or halfway to 1 when there is none. Scores in [0, 1]."""
    h = np.sort(np.asarray(held, float))[::-1]
    if h.size == 0:
        raise ValueError("no held grasps")
    allowed = int(math.floor(budget * h.size + 1e-9))
    if allowed >= h.size:
        return float(max(0.0, h.min() / 2))
    quiet = h[allowed]  # the highest held score that must not alarm
    above = [v for v in list(h) + list(others) if v > quiet]
    return float((quiet + (min(above) if above else 1.0)) / 2)


@dataclass
class Calibration:
    """What :func:`calibrate` did: the checkpoint it wrote, its operating point, and the figures on
    the calibration grasps before (the original operating point) and after."""

    checkpoint: Path
    threshold: float
    debounce: int
    held_alarm: dict[str, Any]
    slipped: int
    slipped_caught: int
    before: dict[str, Any]
    source: Path | None = None  # the checkpoint calibrated (the weights a fine-tuning would start from)
    frame_rate: dict[str, Any] | None = None  # the rates the grasps were read at and the detector's

    def lines(self) -> list[str]:
        h, b = self.held_alarm, self.before
        caught = f"{self.slipped_caught} of {self.slipped}" if self.slipped else "none given"
        return [
            *rate_lines(self.frame_rate),
            f"before: threshold {b['threshold']:g}: {b['held_alarming']} of {h['held_grasps']} held grasps alarm, "
            f"{b['slipped_caught']} of {self.slipped} slipped grasps caught",
            f"after:  threshold {self.threshold:.6g} x{self.debounce}: {h['alarming']} of {h['held_grasps']} held "
            f"grasps alarm ({100 * h['rate']:.1f}%; at most {100 * h['bound_counting_objects']:.0f}% on new objects "
            f"counting the {h['held_objects']} objects, {100 * h['bound_counting_grasps']:.0f}% counting grasps), "
            f"slipped grasps caught: {caught}",
            f"-> {self.checkpoint}",
            *self.advice(),
        ]

    def advice(self) -> list[str]:
        """What to do next where the calibrated detector cannot be trusted to catch slips: none caught,
        or no slipped grasp to tell."""
        if not self.slipped:
            return [
                "warning: no slipped grasps among these, so nothing says what it catches: record a few slips "
                "(slipsense record ... then s + Enter) and calibrate again"
            ]
        if self.slipped_caught:
            return []
        return [
            f"warning: the calibrated detector catches none of the {self.slipped} slipped grasps: on this sensor "
            "its weights do not tell them from held ones, and a threshold cannot fix that",
            f"next: fine-tune it on your grasps, from its weights: slipsense train --recordings RECORDINGS --set "
            f"train.init={self.source} --out mine (docs/new-sensor.md); judge it with slipsense evaluate",
        ]


def calibrate(
    out: str | Path,
    checkpoint: str | Path | None = None,
    recordings: str | Path | Recordings | None = None,
    *,
    budget: float = 0.05,
    overrides: str | Path | None | bool = None,
    objects: Sequence[str] | None = None,
    progress: bool = True,
    on_error: str = "raise",
) -> Calibration:
    """Choose a detector's operating point on the user's grasps and write the calibrated copy.

    Args:
        out: the calibrated checkpoint's path (weights of ``checkpoint``, the new operating point).
        checkpoint: default: the shipped detector for the data (one finger for one camera per grasp).
        recordings: the user's grasps (any recordings layout, e.g. frame folders labelled per grasp; a
            :class:`~slipsense.recordings.recording_set.Recordings` or its folder); held grasps are
            required, slipped ones make the figures say what is caught.
        budget: the fraction of held grasps allowed to alarm (on these grasps; the promise on new
            objects is the bound stated beside it).
        objects: only the grasps of these objects.
        on_error: ``"raise"`` (default) stops at a video that cannot be read; ``"skip"`` leaves its
            run out with a warning naming it.
    """
    if isinstance(budget, bool) or not isinstance(budget, (int, float)) or not 0.0 <= budget < 1.0:
        raise ConfigError(f"--budget must be a fraction in [0, 1), got {budget!r}")
    ev = judge(checkpoint, recordings, overrides=overrides, progress=progress, objects=objects, on_error=on_error)
    data = ev.recordings  # as the judge read them, with the detector's layout
    root = data.root
    source = ev.checkpoint
    scores = ev.peak_scores()
    slipped = np.array([r.slipped for r in ev.runs], bool)
    if not (~slipped).any():
        raise InputError(root, "no grasp that held: calibration needs held grasps (slipped ones are optional)")
    threshold = min(1.0, calibrated_threshold(scores[~slipped], scores[slipped], budget))
    held_objects = [r.object for r in ev.runs if not r.slipped]
    promise = held_alarm_promise(scores[~slipped] >= threshold, held_objects)
    before = {
        "threshold": ev.threshold,
        "held_alarming": int((scores[~slipped] >= ev.threshold).sum()),
        "slipped_caught": int((scores[slipped] >= ev.threshold).sum()),
    }
    info, names = read_info(source), sorted({r.object for r in ev.runs})
    op = {
        **(info.get("operating_point") or {}),
        "threshold": threshold,
        "debounce": ev.debounce,
        "rule": f"at most {100 * budget:g}% of held grasps alarming",
        "chosen_on": f"calibration on {len(ev.runs)} grasps of {len(names)} objects",
        "held_alarm": promise,
        "calibrated": {"from": source.name, "recordings": root.name, "objects": names, "before": before},
    }

    out = Path(out)
    sensor = data.stated
    with atomic_path(out) as tmp:  # copied and calibrated before it takes the name: never half of it
        shutil.copyfile(source, tmp)
        # the data's layout and frame size, but the clock the weights were trained on: frames at the
        # data's rate are resampled to it (lags and windows keep their durations)
        trained = {"fps": sensor_of(info, source).fps}
        update_info(tmp, {"operating_point": op, **({"sensor": {**sensor.to_dict(), **trained}} if sensor else {})})
    caught = int((scores[slipped] >= threshold).sum())
    return Calibration(
        out, threshold, ev.debounce, promise, int(slipped.sum()), caught, before, source, ev.frame_rates()
    )


def check_by_objects(
    checkpoint: str | Path | None = None,
    recordings: str | Path | Recordings | None = None,
    *,
    budget: float = 0.05,
    overrides: str | Path | None | bool = None,
    progress: bool = True,
    on_error: str = "raise",
) -> dict[str, Any]:
    """Does calibration keep its promise on objects it was not calibrated on? Each object in turn is
    left out, the threshold chosen on the others' grasps (:func:`calibrated_threshold`), and the
    left-out object's grasps judged at it. Returns per-object rows and the pooled figures: held grasps
    alarming on the left-out objects against the largest bound the calibrations stated, slipped grasps
    caught, accuracy. ``on_error`` as :func:`calibrate` takes it."""
    ev = judge(checkpoint, recordings, overrides=overrides, progress=progress, on_error=on_error)
    root = ev.recordings.root
    scores = ev.peak_scores()
    slipped = np.array([r.slipped for r in ev.runs], bool)
    objects = np.array([r.object for r in ev.runs])
    rows = []
    for o in np.unique(objects):
        mine, rest = objects == o, objects != o
        held_rest = rest & ~slipped
        if not held_rest.any():
            raise InputError(root, f"leaving out {o} leaves no held grasp to calibrate on")
        th = min(1.0, calibrated_threshold(scores[held_rest], scores[rest & slipped], budget))
        promise = held_alarm_promise(scores[held_rest] >= th, objects[held_rest])
        alarm = scores[mine] >= th
        rows.append(
            {
                "object": str(o),
                "threshold": th,
                "bound_counting_objects": promise["bound_counting_objects"],
                "held": int((mine & ~slipped).sum()),
                "held_alarming": int((alarm & ~slipped[mine]).sum()),
                "slipped": int((mine & slipped).sum()),
                "slipped_caught": int((alarm & slipped[mine]).sum()),
            }
        )
    held, alarming, slips, caught = (
        sum(r[k] for r in rows) for k in ("held", "held_alarming", "slipped", "slipped_caught")
    )
    return {
        "checkpoint": ev.checkpoint.name,
        "budget": budget,
        "objects": rows,
        "held": held,
        "held_alarming": alarming,
        "held_alarm_rate": alarming / held if held else math.nan,
        "largest_stated_bound": max(r["bound_counting_objects"] for r in rows),
        "slipped": slips,
        "slipped_caught": caught,
        "accuracy": (caught + held - alarming) / (held + slips),
    }


def check_lines(doc: dict[str, Any]) -> list[str]:
    lines = [f"{'left out':<14}{'threshold':>10}{'bound':>8}{'held alarming':>15}{'slipped caught':>16}"]
    for r in doc["objects"]:
        lines.append(
            f"{r['object']:<14}{r['threshold']:>10.4g}{100 * r['bound_counting_objects']:>7.0f}%"
            f"{r['held_alarming']:>9} of {r['held']:<3}{r['slipped_caught']:>10} of {r['slipped']:<3}"
        )
    rate, bound = doc["held_alarm_rate"], doc["largest_stated_bound"]
    lines.append(
        f"pooled: {doc['held_alarming']} of {doc['held']} held grasps of left-out objects alarm "
        f"({100 * rate:.1f}%; stated bounds up to {100 * bound:.0f}%: {'kept' if rate <= bound else 'NOT kept'}), "
        f"{doc['slipped_caught']} of {doc['slipped']} slips caught, accuracy {100 * doc['accuracy']:.1f}%"
    )
    return lines
