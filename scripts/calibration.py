"""Does the operating point transfer to the detector that uses it? Trains the shipped recipe's five
folds like `slipsense grasp folds` (each fold: the detector and its 3 inner-fold models), but every
model replays every run, then compares ways of setting each fold's alarm on training objects only:

* `inner rule` (shipped): threshold and debounce chosen on the inner models' out-of-fold traces,
  used by the fold's detector;
* `offset qQ`: the same threshold moved by how the detector's own training held grasps peak against
  the inner models' own training held grasps (the Q-quantile of the peaks, in logits): a detector
  trained on more objects may sit higher or lower than the models its threshold was chosen on;
* `committee V`: the inner models themselves are the detector, each at the threshold chosen on its
  own out-of-fold runs, alarming when at least V of the 3 alarm.

Every rule "at most 5% of held grasps alarm" on training objects; the held-out runs only scored.

    .venv/bin/python scripts/calibration.py --out reports/calibration [--workers 2]

The traces are kept in OUT/traces.npz (float16, NaN-padded; reruns reuse them).
"""

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np
import yaml
from ceiling import _levels  # this folder is on the path when the script runs

from slipsense import config
from slipsense.evaluation import pergrasp
from slipsense.evaluation.pergrasp import STARTUP
from slipsense.training.grasp_detector import fit_job, job_weight, object_split, plan_training
from slipsense.training.grasps import load_grasp_data, make_config
from slipsense.training.parallel import run_jobs

K = 0.05
DEBOUNCES = (1, 2, 3, 5)


def _recipe():
    doc = yaml.safe_load(Path("configs/motionnet.yaml").read_text())
    model = dict(doc["model"])
    name = model.pop("name")
    return make_config(name, {**model, **doc["train"]})


def _logit(p):
    p = np.clip(p, 1e-7, 1 - 1e-7)
    return np.log(p / (1 - p))


def _peak(p, frames):
    return _levels(p, frames)[STARTUP:].max(initial=-np.inf)


def _alarms(p, op):
    return pergrasp.debounce(p, op["threshold"], op["debounce"])


def _choose(traces, moments, horizon):
    return pergrasp.choose_operating_point(traces, moments, horizon=horizon, max_held_alarm=K)


def train_all(runs, cfg, workers):
    split = object_split(runs, 5, cfg.folds_seed)
    everyone = tuple(range(len(runs)))
    plans = [plan_training(runs, held, cfg) for held in split]
    jobs = [dataclasses.replace(j, predict=everyone) for plan in plans for j in plan]
    results = run_jobs(fit_job, jobs, (runs, cfg), workers, [job_weight(j, cfg) for j in jobs], progress=True)
    n = max(r.n_frames for r in runs)
    traces = np.full((len(jobs), len(runs), n), np.nan, dtype=np.float16)
    for j, res in enumerate(results):
        for i, p in enumerate(res["probs"]):
            traces[j, i, : len(p)] = p
    return plans, traces


def evaluate(runs, plans, traces, horizon):
    moments = [r.moment_of_slip for r in runs]
    lengths = [r.n_frames for r in runs]
    tr = lambda j, i: traces[j, i, : lengths[i]].astype(np.float64)  # noqa: E731
    outcomes: dict[str, list] = {}
    chosen: dict[str, list] = {}
    j0 = 0
    for k, plan in enumerate(plans):
        outer, inner = j0, list(range(j0 + 1, j0 + len(plan)))
        j0 += len(plan)
        train, test = plan[0].train, plan[0].predict
        owner = {i: j for j, job in zip(inner, plan[1:]) for i in job.predict}  # the inner model that held it out
        oof = [tr(owner[i], i) for i in train]
        op = _choose(oof, [moments[i] for i in train], horizon)
        rules = {"inner rule": [lambda i, op=op: _alarms(tr(outer, i), op)]}
        held_train = [i for i in train if moments[i] is None]
        for q in (0.5, 0.9, 1.0):
            ref = lambda j, d: np.quantile(  # noqa: E731
                [_logit(_peak(tr(j, i), d)) for i in held_train if owner.get(i) != j], q
            )
            d = op["debounce"]
            shift = ref(outer, d) - np.mean([ref(j, d) for j in inner])
            moved = {**op, "threshold": float(1 / (1 + np.exp(-(_logit(op["threshold"]) + shift))))}
            rules[f"offset q{q:g}"] = [lambda i, o=moved: _alarms(tr(outer, i), o)]
            chosen.setdefault(f"offset q{q:g}", []).append(round(moved["threshold"], 6))
        own = []
        for j, job in zip(inner, plan[1:]):
            o = _choose([tr(j, i) for i in job.predict], [moments[i] for i in job.predict], horizon)
            own.append((j, o))
        for v in (1, 2, 3):
            rules[f"committee {v}"] = [lambda i, v=v: np.sum([_alarms(tr(j, i), o) for j, o in own], axis=0) >= v]
        chosen.setdefault("inner rule", []).append((op["threshold"], op["debounce"]))
        chosen.setdefault("committee", []).append([(o["threshold"], o["debounce"]) for _, o in own])
        for name, (alarm,) in rules.items():
            outcomes.setdefault(name, []).extend(pergrasp.grasp_outcome(alarm(i), moments[i], horizon) for i in test)
    return {name: pergrasp.summarise(outs) for name, outs in outcomes.items()}, chosen


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--overrides", default="configs/gelsight-label-overrides.csv")
    parser.add_argument("--epochs", type=int, default=None, help="fewer epochs, for a quick check of the script")
    args = parser.parse_args()
    cfg = _recipe()
    if args.epochs:
        cfg = dataclasses.replace(cfg, epochs=args.epochs)
    runs, _ = load_grasp_data(config.gelsight_recordings(), overrides=args.overrides, progress=False)
    runs = [r for r in runs if r.usable]
    args.out.mkdir(parents=True, exist_ok=True)
    saved = args.out / "traces.npz"
    plans = [plan_training(runs, held, cfg) for held in object_split(runs, 5, cfg.folds_seed)]
    if saved.exists():
        traces = np.load(saved, allow_pickle=False)["traces"]
    else:
        plans, traces = train_all(runs, cfg, args.workers)
        np.savez_compressed(saved, traces=traces)
    scores, chosen = evaluate(runs, plans, traces, cfg.horizon)
    lines = []
    for name, s in scores.items():
        lines.append(
            f"{name:14s} warned {s['warned']}/{s['slip_runs']}  premature {s['premature']}  "
            f"false-positive grasps {s['false_positive_grasps']}/{s['held_runs']}  median lead {s['median_lead_frames']}"
        )
    print("\n".join(lines))
    print(json.dumps(chosen))
    (args.out / "summary.txt").write_text("\n".join(lines) + "\n" + json.dumps(chosen) + "\n")
