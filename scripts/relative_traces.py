"""Alarm on a grasp's change of slip probability rather than on the probability itself: each kept
trace of a `slipsense grasp folds` report (inner and held-out) is turned causally into the logit at
a frame minus a reference from the same grasp's past, every fold's operating point chosen again on
its inner traces (at most 5% of held grasps alarming, thresholds at quantiles of the inner traces),
and the held-out runs scored and pooled. No training; a post-processing a live detector could run.

    .venv/bin/python scripts/relative_traces.py reports/grasp-motionnet-k5 [--max-held-alarm 0.05]

References: `none` (the trace as it is), `grasp-mean` (the mean logit of the grasp so far),
`recent-max` (the largest logit 60-15 frames back), `mean3` (the mean of the last 3 frames, no reference).
"""

import argparse
import json
from pathlib import Path

import numpy as np

from slipsense.evaluation import pergrasp
from slipsense.evaluation.grasp_scores import stored_trace
from slipsense.evaluation.pergrasp import STARTUP


def _logit(p):
    p = np.clip(p, 1e-6, 1 - 1e-6)
    return np.log(p / (1 - p))


def _grasp_mean(z):
    seen = np.isfinite(z)
    total, count = np.cumsum(np.where(seen, z, 0.0)), np.cumsum(seen)
    before = np.concatenate([[np.nan], total[:-1] / np.maximum(count[:-1], 1)])
    before[np.concatenate([[0], count[:-1]]) == 0] = np.nan
    return z - before


def _recent_max(z, far=60, near=15):
    out = np.full_like(z, np.nan)
    for t in range(len(z)):
        w = z[max(STARTUP, t - far) : max(STARTUP, t - near)]
        w = w[np.isfinite(w)]
        out[t] = z[t] - w.max() if len(w) else np.nan  # no past yet: no alarm
    return out


def _mean3(z):
    out = np.full_like(z, np.nan)
    out[2:] = (z[2:] + z[1:-1] + z[:-2]) / 3
    return out


REFERENCES = {"none": lambda z: z, "grasp-mean": _grasp_mean, "recent-max": _recent_max, "mean3": _mean3}


def _trace(run, transform):
    p = stored_trace(run)
    z = transform(_logit(p))
    z[:STARTUP] = np.nan
    return 1 / (1 + np.exp(-np.clip(z, -50, 50)))


def pooled(report: Path, transform, max_held_alarm: float | None) -> dict:
    horizon = json.loads((report / "folds.json").read_text())["train_config"]["horizon"]
    outcomes = []
    for path in sorted(report.glob("fold[0-9]*.json")):
        fold = json.loads(path.read_text())
        inner = [_trace(r, transform) for r in fold["inner"]]
        values = np.concatenate([x[np.isfinite(x)] for x in inner])
        grid = set(np.round(np.quantile(values, np.linspace(0.5, 1, 400)), 8))
        op = pergrasp.choose_operating_point(
            inner,
            [r["moment_of_slip"] for r in fold["inner"]],
            thresholds=sorted(grid | set(pergrasp.THRESHOLDS) | set(pergrasp.FINE_TAIL)),
            horizon=horizon,
            max_held_alarm=max_held_alarm,
        )
        for r in fold["runs"]:
            x = _trace(r, transform)
            rest = np.zeros(len(x), dtype=bool)
            rest[r["rest"]] = True
            alarms = pergrasp.debounce(x, op["threshold"], op["debounce"])
            outcomes.append(pergrasp.grasp_outcome(alarms, r["moment_of_slip"], horizon, rest=rest))
    return pergrasp.summarise(outcomes)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("reports", nargs="+", type=Path)
    parser.add_argument("--max-held-alarm", type=float, default=0.05, help="a negative value: best score")
    args = parser.parse_args()
    k = None if args.max_held_alarm < 0 else args.max_held_alarm
    for report in args.reports:
        for name, transform in REFERENCES.items():
            s = pooled(report, transform, k)
            print(
                f"{report}  {name:10s}  warned {s['warned']}/{s['slip_runs']}  premature {s['premature']}  "
                f"false-positive grasps {s['false_positive_grasps']}/{s['held_runs']}  median lead {s['median_lead_frames']}"
            )
