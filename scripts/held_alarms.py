"""Where held grasps raise a detector's alarms: for each `slipsense grasp folds` report, the frame at
which every held run's inner-fold trace peaks above a threshold, and the first alarm of every
false-positive grasp on held-out objects (frames from the start of the recording; the wiggle spans
about frames 105-200, the release 285-333).

    .venv/bin/python scripts/held_alarms.py reports/grasp-motionnet-k5 reports/grasp-motionnet-fast [--above 0.99]
"""

import argparse
import json
from pathlib import Path

import numpy as np

from slipsense.evaluation.grasp_scores import stored_trace
from slipsense.evaluation.pergrasp import STARTUP

parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
parser.add_argument("reports", nargs="+", type=Path)
parser.add_argument("--above", type=float, default=0.99, help="inner traces peaking at or above this are listed")
args = parser.parse_args()
for report in args.reports:
    peaks, firsts, held = [], [], 0
    for path in sorted(report.glob("fold[0-9]*.json")):
        fold = json.loads(path.read_text())
        for run in fold.get("inner", []):
            if run["moment_of_slip"] is not None:
                continue
            held += 1
            p = stored_trace(run)
            p[:STARTUP] = np.nan
            if np.nanmax(p) >= args.above:
                peaks.append(int(np.nanargmax(p)))
        firsts += [run["first_alarm"] for run in fold.get("runs", []) if run["outcome"] == "false_positive"]
    print(f"{report}: {len(peaks)} of {held} held inner traces reach {args.above:g}, peaking at frames {sorted(peaks)}")
    print(f"{report}: first alarms of false-positive grasps on held-out objects at frames {sorted(firsts)}")
