"""Combine a folds report's network traces with a physical signal of the gels: the network may alarm
only where the grasp's contact is fading (or the signal alone), every fold's gate and threshold chosen
again on its inner traces (at most 5% of held grasps alarming) and the held-out runs scored and pooled.
No training; every signal is causal (computed from the frames so far), so a live detector could run it.

    .venv/bin/python scripts/gated_traces.py reports/grasp-motionnet-k5 [--max-held-alarm 0.05]

Signals per frame, over the two sensors: `fading` (the largest drop of contact strength over the last
`k` frames, relative to the grasp's strongest contact so far), `loss` (how far the weaker sensor's
contact is below its strongest so far, as a fraction).
"""

import argparse
import json
from pathlib import Path

import numpy as np

from slipsense import config
from slipsense.evaluation import pergrasp
from slipsense.evaluation.grasp_scores import stored_trace
from slipsense.evaluation.pergrasp import STARTUP
from slipsense.recordings.folders import find_recordings
from slipsense.recordings.labels import label_recordings
from slipsense.recordings.runs import load_runs


def _peak_so_far(c):
    return np.maximum(np.maximum.accumulate(c, axis=1), 1e-6)


def fading(contact, k):
    c = contact.astype(np.float64)
    out = np.full(c.shape[1], -np.inf)
    out[k:] = ((c[:, :-k] - c[:, k:]) / _peak_so_far(c)[:, k:]).max(axis=0)
    return out


def loss(contact):
    c = contact.astype(np.float64)
    return (1 - c / _peak_so_far(c)).max(axis=0)


SIGNALS = {
    "fading3": lambda c: fading(c, 3),
    "fading5": lambda c: fading(c, 5),
    "fading10": lambda c: fading(c, 10),
    "loss": loss,
}


def _probability(run):
    p = stored_trace(run)
    p[:STARTUP] = np.nan
    return p


def _alone(signal):
    x = np.where(np.isfinite(signal), signal, np.nan)
    x[:STARTUP] = np.nan
    return x


def _gate_levels(values):
    finite = values[np.isfinite(values)]
    return sorted(set(np.round(np.quantile(finite, np.linspace(0.5, 0.995, 24)), 6)))


def _score(report, contacts, signal, mode, k):
    horizon = json.loads((report / "folds.json").read_text())["train_config"]["horizon"]
    outcomes, chosen = [], []
    for path in sorted(report.glob("fold[0-9]*.json")):
        fold = json.loads(path.read_text())
        inner_p = [_probability(r) for r in fold["inner"]]
        inner_s = [
            SIGNALS[signal](contacts[(r["object"], r["experiment"])])[: len(p)] for r, p in zip(fold["inner"], inner_p)
        ]
        moments = [r["moment_of_slip"] for r in fold["inner"]]
        best = None
        if mode == "alone":
            levels = [None]
        else:
            levels = _gate_levels(np.concatenate(inner_s))
        for level in levels:
            if mode == "alone":
                traces = [_alone(s) for s in inner_s]
                values = np.concatenate([t[np.isfinite(t)] for t in traces])
                thresholds = sorted(set(np.round(np.quantile(values, np.linspace(0.5, 1, 300)), 8)))
            else:
                traces = [np.where(s >= level, p, 0.0) for p, s in zip(inner_p, inner_s)]
                thresholds = None
            op = pergrasp.choose_operating_point(
                traces, moments, thresholds=thresholds, horizon=horizon, max_held_alarm=k
            )
            fp = op["false_positive_rate_on_training_runs"]
            kept = k is None or fp <= k + 1e-9  # a gate that cannot keep the promise only if none can
            rank = (kept, op["warned_rate_on_training_runs"], -fp)
            if best is None or rank > best[0]:
                best = (rank, level, op)
        _, level, op = best
        chosen.append((level, op["threshold"], op["debounce"]))
        for r in fold["runs"]:
            p = _probability(r)
            s = SIGNALS[signal](contacts[(r["object"], r["experiment"])])[: len(p)]
            if mode == "alone":
                x = _alone(s)
            else:
                x = np.where(s >= level, p, 0.0)
            rest = np.zeros(len(x), dtype=bool)
            rest[r["rest"]] = True
            alarms = pergrasp.debounce(x, op["threshold"], op["debounce"])
            outcomes.append(pergrasp.grasp_outcome(alarms, r["moment_of_slip"], horizon, rest=rest))
    return pergrasp.summarise(outcomes), chosen


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("reports", nargs="+", type=Path)
    parser.add_argument("--max-held-alarm", type=float, default=0.05, help="a negative value: best score")
    parser.add_argument("--overrides", default="configs/gelsight-label-overrides.csv")
    args = parser.parse_args()
    k = None if args.max_held_alarm < 0 else args.max_held_alarm
    recs = find_recordings(config.gelsight_recordings())
    labels = label_recordings(recs, overrides=args.overrides, progress=False)
    contacts = {r.key: r.contact for r in load_runs(recs, labels, (30, 40), progress=False)}
    for report in args.reports:
        for signal in SIGNALS:
            for mode in ("gate", "alone"):
                s, chosen = _score(report, contacts, signal, mode, k)
                print(
                    f"{report}  {signal:9s} {mode:5s}  warned {s['warned']}/{s['slip_runs']}  premature {s['premature']}  "
                    f"false-positive grasps {s['false_positive_grasps']}/{s['held_runs']}  median lead {s['median_lead_frames']}  "
                    f"points {[(None if g is None else round(float(g), 3), t, d) for g, t, d in chosen]}",
                    flush=True,
                )
