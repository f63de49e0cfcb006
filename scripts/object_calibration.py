"""Calibrate the alarm on the object itself: each held-out run alarms above the highest peak of the
*other* held grasps of its object in a folds report (plus a margin in logits, and at least 0.9 with
`floor`), as a user could by recording a few grasps of a new object that hold. Objects with no other
held grasp keep their fold's operating point. No training; seconds.

    .venv/bin/python scripts/object_calibration.py reports/grasp-motionnet-k5
"""

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from slipsense.evaluation import pergrasp
from slipsense.evaluation.grasp_scores import stored_trace
from slipsense.evaluation.pergrasp import STARTUP


def _logit(x):
    x = np.clip(x, 1e-7, 1 - 1e-7)
    return np.log(x / (1 - x))


def _peak(p):
    return np.nanmax(np.where(np.arange(len(p)) >= STARTUP, p, np.nan))


def held_out_runs(report: Path):
    """``[(object, moment of slip, P(slip) trace, the fold's operating point)]`` of every held-out run."""
    runs = []
    for path in sorted(report.glob("fold[0-9]*.json")):
        fold = json.loads(path.read_text())
        for r in fold["runs"]:
            runs.append((r["object"], r["moment_of_slip"], stored_trace(r), fold["operating_point"]))
    return runs


def calibrated(runs, margin: float, floor: float, horizon: int):
    by_object = defaultdict(list)
    for r in runs:
        by_object[r[0]].append(r)
    outcomes = []
    for group in by_object.values():
        held = [r for r in group if r[1] is None]
        for r in group:
            others = [h for h in held if h is not r]
            if others:
                top = max(_peak(h[2]) for h in others)
                threshold, frames = max(floor, float(1 / (1 + np.exp(-(_logit(top) + margin))))), 1
            else:
                threshold, frames = r[3]["threshold"], r[3]["debounce"]
            alarms = pergrasp.debounce(r[2], threshold, frames)
            outcomes.append(pergrasp.grasp_outcome(alarms, r[1], horizon))
    return pergrasp.summarise(outcomes)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("report", type=Path)
    args = parser.parse_args()
    horizon = json.loads((args.report / "folds.json").read_text())["train_config"]["horizon"]
    runs = held_out_runs(args.report)
    for floor in (0.0, 0.9):
        for margin in (0.0, 0.5, 1.0, 2.0):
            s = calibrated(runs, margin, floor, horizon)
            print(
                f"margin {margin:g} floor {floor:g}: warned {s['warned']}/{s['slip_runs']}  premature {s['premature']}  "
                f"false-positive grasps {s['false_positive_grasps']}/{s['held_runs']}  median lead {s['median_lead_frames']}"
            )
