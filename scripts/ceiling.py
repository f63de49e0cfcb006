"""How many slips a folds report's detectors could warn of at all at a given number of false-positive
grasps: one threshold and debounce for every fold, tuned on the held-out runs themselves. Tuning on
the test objects is what no user can do, so this is a bound on what any choice of the operating point
could give these traces, not a result: when it is below a target, the target needs a better ranking
of frames (a better detector), not a better threshold.

    .venv/bin/python scripts/ceiling.py reports/grasp-motionnet-k5 reports/grasp-motion-energy [--fp 4 8 13]

Reports whose fold files were not committed (only folds.json) are skipped. `--phases` also prints
where the ten highest peaks of the held grasps lie (the alarms any threshold must stay above) and when
the slips are lost (frames from the start of the recording).
"""

import argparse
import json
from pathlib import Path

import numpy as np

from slipsense.evaluation import pergrasp
from slipsense.evaluation.pergrasp import STARTUP


def held_out_traces(report: Path):
    """``(probabilities, moments, horizon)`` of every held-out run of a report (None if incomplete)."""
    summary = json.loads((report / "folds.json").read_text())
    files = sorted(report.glob("fold[0-9]*.json"))
    if len(files) != summary.get("folds", len(files)) or not files:
        return None
    horizon = summary.get("train_config", {}).get("horizon", pergrasp.HORIZON)
    probabilities, moments = [], []
    for path in files:
        for run in json.loads(path.read_text())["runs"]:
            p = np.array([np.nan if v is None else v for v in run["probability"]], dtype=float)
            p[:STARTUP] = np.nan
            probabilities.append(p)
            moments.append(run["moment_of_slip"])
    return probabilities, moments, horizon


def ceiling(probabilities, moments, horizon, max_false_positives):
    """The table row warning in time of the most slips with at most that many false-positive grasps."""
    values = np.concatenate([p[np.isfinite(p)] for p in probabilities])
    grid = sorted(set(np.round(np.quantile(values, np.linspace(0.9, 1, 300)), 9)) | set(pergrasp.THRESHOLDS))
    rows = pergrasp.table(probabilities, moments, grid, (1, 2, 3, 5), horizon, STARTUP)
    ok = [r for r in rows if r["false_positive_grasps"] <= max_false_positives]
    return max(ok, key=lambda r: (r["warned"], -r["premature"], -r["false_positive_grasps"]))


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("reports", nargs="+", type=Path)
    parser.add_argument("--phases", action="store_true", help="where held grasps peak and slips are lost")
    parser.add_argument("--fp", nargs="+", type=int, default=[4, 8, 13], help="false-positive grasps allowed")
    args = parser.parse_args()
    for report in args.reports:
        traces = held_out_traces(report)
        if traces is None:
            print(f"{report}: skipped (fold files missing)")
            continue
        cells = []
        for fp in args.fp:
            r = ceiling(*traces, fp)
            cells.append(
                f"<= {fp} FP: {r['warned']}/{r['slip_runs']} warned, {r['premature']} premature, "
                f"{r['false_positive_grasps']}/{r['held_runs']} FP, lead {r['median_lead_frames']}"
            )
        print(f"{report}: " + " | ".join(cells), flush=True)
        if args.phases:
            probabilities, moments, _ = traces
            held = sorted(((np.nanmax(p), int(np.nanargmax(p))) for p, m in zip(probabilities, moments) if m is None))
            lost = np.array([m for m in moments if m is not None])
            print(
                f"  held grasps' 10 highest peaks at frames {sorted(t for _, t in held[-10:])}; "
                f"slips lost at frames < 60: {(lost < 60).sum()}, 60-150: {((lost >= 60) & (lost <= 150)).sum()}, "
                f"> 150: {(lost > 150).sum()}"
            )
