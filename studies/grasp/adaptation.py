"""Adaptation to a new sensor, measured leave-objects-out: what does a user gain from a few grasps?

On a data set of another sensor labelled per grasp (e.g. the shared ``gelsight-lift``), each object
in turn is held out and, from the other objects' grasps only:

* ``as is``: the shipped one-finger detector with its own operating point;
* ``recalibrated``: the same weights, the threshold chosen on the other objects' grasps
  (:func:`slipsense.evaluation.calibrate.calibrated_threshold`, at most 5% of held grasps alarming);
* ``fine-tuned, n grasps``: the shipped weights trained further on ``n`` grasps drawn from the other
  objects (both outcomes among them; ``all``: every one), grasps that slipped as bags of frames
  (:data:`slipsense.training.grasps.BAG`), the threshold then chosen on those same grasps (``all``:
  on :data:`INNER_FOLDS` inner folds of those objects, as the shipped detectors are made);
* ``this set alone``: the same recipe from random weights on all the other objects' grasps;
* ``trained on both sets`` (with ``also``): the shipped detector's own recipe from random weights on
  the runs it was trained on and the other objects' grasps, the threshold chosen on those grasps;
* ``slip velocity``: physics too (:mod:`slipsense.models.slip_velocity`): how fast the object's footprint
  slides over the gel's material; its ``floor`` and ``window`` chosen among its recipe's on the other
  objects, as shear retention's settings.
* ``shear retention``: physics, no gradient training (:mod:`slipsense.models.shear`): how much of the
  shear the lift put on the gel's markers has been given up; its ``gate`` and ``letgo`` chosen among
  :attr:`~slipsense.models.shear.ShearRetention.recipe` and its threshold set on the other
  objects' grasps (``train.choose``, :func:`slipsense.training.grasp_detector.finish_training`);
* the non-learned baselines (:mod:`slipsense.measures.baselines`) and the majority class, their
  thresholds chosen on the other objects.

Every row is judged on the held-out objects' grasps: ROC AUC of the per-grasp peak score (pooled over
the folds' detectors), accuracy and balanced accuracy at each fold's own threshold, accuracy with each
object's threshold chosen on the other objects' held-out scores, and the held grasps that alarm; rows
trained on a few grasps pool three draws of them; 95% intervals from a bootstrap over objects
(:mod:`slipsense.measures.slipped_or_held`). ``python -m studies grasp adaptation`` writes ``adaptation.json``,
``adaptation.md`` and ``adaptation.png``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from slipsense.evaluation.calibrate import calibrated_threshold
from slipsense.measures import slipped_or_held

#: Training grasps drawn for the fine-tuning rows (None: all of the other objects').
SIZES = (5, 10, 20, None)
BUDGET = 0.05
SHEAR_ROW = "shear retention (gate and letgo chosen on the other objects)"
VELOCITY_ROW = "slip velocity (floor and window chosen on the other objects)"
#: Inner folds by object that choose the threshold of a detector trained on every other object's grasps
#: (the shipped recipe's); one trained on a few grasps takes its threshold on those grasps.
INNER_FOLDS = 2


def _subset(runs: Sequence, n: int | None, rng: np.random.Generator) -> list:
    """``n`` of ``runs`` at random, with at least one slipped and one held grasp (all for None)."""
    if n is None or n >= len(runs):
        return list(runs)
    slipped = [r for r in runs if r.slipped]
    held = [r for r in runs if not r.slipped]
    if not slipped or not held:
        from slipsense.errors import InputError

        raise InputError(None, f"the grasps to draw {n} from are all {'held' if held else 'slipped'}")
    first = [slipped[rng.integers(len(slipped))], held[rng.integers(len(held))]]
    rest = [r for r in runs if all(r is not f for f in first)]
    return first + [rest[i] for i in rng.choice(len(rest), n - 2, replace=False)]


def _peaks(model, runs: Sequence, startup: int) -> np.ndarray:
    from slipsense.training.grasps import predict_runs

    return np.array([slipped_or_held.peak_alarm_score(p, 1, 0) for p in predict_runs(model, runs, startup)])


def _both_sets_job(shared, job, tick=lambda units: None) -> tuple[np.ndarray, np.ndarray]:
    """One held-out object of the both-sets row (:func:`slipsense.parallel.run_jobs`): the recipe
    ``cfg`` with ``seed`` trained on ``pool[train]`` -> the peak scores of ``pool[own]`` (its threshold is
    chosen on them) and of ``pool[held]``."""
    from dataclasses import replace

    from slipsense.training.grasps import fit_runs

    pool, cfg = shared
    seed, train, own, held = job
    fitted, _ = fit_runs(
        [pool[i] for i in train], replace(cfg, seed=seed), progress=False, on_epoch=lambda _: tick(len(train))
    )
    return _peaks(fitted, [pool[i] for i in own], 0), _peaks(fitted, [pool[i] for i in held], 0)


def _row(name: str, scores, alarmed, slipped, objects, seconds: float, draws: int) -> dict[str, Any]:
    m = slipped_or_held.outcome_measure(scores, slipped, objects, alarmed, draws)
    held = ~np.asarray(slipped, bool)
    m.update(row=name, held_alarming=int(np.asarray(alarmed, bool)[held].sum()), seconds=round(seconds, 1))
    return m


def adaptation_study(
    recordings: str | Path,
    sizes: Sequence[int | None] = SIZES,
    epochs: int = 10,
    seed: int = 0,
    draws: int = slipped_or_held.BOOTSTRAP,
    progress: bool = True,
    repeats: int = 3,
    also: str | Path | None = None,
    also_epochs: int | None = None,
    workers: int | None = 1,
) -> dict[str, Any]:
    """The rows of the module notes on ``recordings`` (one camera per grasp): ``{"rows": [...]}``.
    Rows trained on ``n`` of the grasps pool ``repeats`` draws of them (each draw a grasp judged once
    more: a single draw of 5 grasps is mostly luck). ``also``: the recordings the shipped detector was
    trained on (another sensor's), for the row trained from scratch on both sets (``also_epochs``:
    other than the recipe's). ``workers``: processes that train a detector and its inner folds (and the
    both-sets row's detectors) side by side (None: one per core; each training is seeded and
    single-threaded, so the numbers do not depend on it)."""
    from slipsense.checkpoint import load_model
    from slipsense.measures.baselines import frame_scores
    from slipsense.progress import progress_bar
    from slipsense.resources import ONE_SENSOR_DETECTOR, shipped_model
    from slipsense.training.grasp_detector import train_with_operating_point
    from slipsense.training.grasps import load_grasp_data, make_config

    shipped = shipped_model(ONE_SENSOR_DETECTOR)
    model, info = load_model(shipped)
    op = info["operating_point"]
    from slipsense.paths import resolve_path

    from slipsense.recordings.recording_set import Recordings

    recordings = Recordings.open(resolve_path(recordings))  # read once, as the sensor its data states
    fps = recordings.sensor.fps
    runs, _ = load_grasp_data(recordings, None, tuple(model.image_size), progress=progress)
    slipped = np.array([r.slipped for r in runs], bool)
    objects = np.array([r.object for r in runs])
    names = sorted(set(objects))
    rows = []

    t0 = time.perf_counter()
    as_is = _peaks(model.eval(), runs, int(op.get("startup", 0)))
    rows.append(_row("as is", as_is, as_is >= op["threshold"], slipped, objects, time.perf_counter() - t0, draws))
    t0 = time.perf_counter()
    alarmed = np.zeros(len(runs), bool)
    for o in names:
        other, mine = objects != o, objects == o
        th = calibrated_threshold(as_is[other & ~slipped], as_is[other & slipped], BUDGET)
        alarmed[mine] = as_is[mine] >= th
    rows.append(_row("recalibrated", as_is, alarmed, slipped, objects, time.perf_counter() - t0, draws))

    from slipsense.models import model_class

    shear = model_class("shear-retention")
    shear_size = tuple(shear().image_size)
    by_size = {tuple(model.image_size): runs}  # the grasps read at each model's frame size
    plans = [(f"fine-tuned, {n or 'all'} grasps", "motionnet", {"init": str(shipped)}, n) for n in sizes]
    plans.append(("this set alone", "motionnet", {"model.sensors": 1}, None))
    plans.append(
        (
            SHEAR_ROW,
            "shear-retention",
            {"model.sensors": 1, "model.image_size": list(shear_size), **shear.recipe},
            None,
        )
    )
    velocity = model_class("slip-velocity")
    velocity_size = list(velocity().image_size)
    plans.append(
        (
            VELOCITY_ROW,
            "slip-velocity",
            {"model.sensors": 1, "model.image_size": velocity_size, **velocity.recipe},
            None,
        )
    )
    for name, model_name, settings, n in progress_bar(plans, progress, "adaptation rows"):
        t0 = time.perf_counter()
        size = tuple(settings.get("model.image_size") or model.image_size)
        if size not in by_size:
            by_size[size] = load_grasp_data(recordings, None, size, progress=False)[0]
        grasps = by_size[size]  # the same grasps in the same order as ``runs``
        parts = []  # (scores, alarmed) of every grasp, once per draw of the training grasps
        for rep in range(repeats if n is not None else 1):
            scores, alarmed = np.zeros(len(grasps)), np.zeros(len(grasps), bool)
            for k, o in enumerate(names):
                rng = np.random.default_rng([seed, rep, k])
                train = _subset([r for r in grasps if r.object != o], n, rng)
                inner = INNER_FOLDS if n is None else 0  # a few grasps: the threshold on those grasps
                cfg = make_config(
                    model_name, {"startup": 0, "epochs": epochs, "inner_folds": inner, "seed": seed + k, **settings}
                )
                mine = objects == o
                _, _, op, probs = train_with_operating_point(
                    train + [r for r in grasps if r.object == o], [o], cfg, workers=workers, fps=fps
                )
                scores[mine] = [slipped_or_held.peak_alarm_score(p, 1, 0) for p in probs]
                alarmed[mine] = scores[mine] >= op["threshold"]
            parts.append((scores, alarmed))
        k = len(parts)  # the draws pooled: each grasp judged once per draw, objects still the unit
        row = _row(
            name,
            np.concatenate([p[0] for p in parts]),
            np.concatenate([p[1] for p in parts]),
            np.tile(slipped, k),
            np.tile(objects, k),
            time.perf_counter() - t0,
            draws,
        )
        rows.append({**row, "draws_of_training_grasps": k})

    if also is not None:  # the shipped recipe from scratch on the other sensor's runs and these grasps
        t0 = time.perf_counter()
        others, _ = load_grasp_data(resolve_path(also), None, tuple(model.image_size), progress=progress)
        from slipsense.recordings.runs import per_sensor

        others = [r for r in per_sensor(others) if r.usable]
        recipe = info["config"]  # the shipped detector's own tree: its model and training settings
        cfg = make_config(
            recipe["model"]["name"],
            {
                **{f"model.{key}": v for key, v in recipe["model"].items() if key != "name"},
                **{key: v for key, v in recipe["train"].items() if key not in ("inner_folds", "seed")},
                "inner_folds": 0,
                **({"epochs": also_epochs} if also_epochs else {}),
            },
        )
        pool, n = list(others) + list(runs), len(others)  # a fold trains on every other-sensor run too
        jobs = []
        for k, o in enumerate(names):
            own, held = tuple(np.flatnonzero(objects != o) + n), tuple(np.flatnonzero(objects == o) + n)
            jobs.append((seed + k, tuple(range(n)) + own, own, held))
        from slipsense.parallel import run_jobs

        weights = [len(j[1]) * cfg.epochs for j in jobs]
        results = run_jobs(_both_sets_job, jobs, (pool, cfg), workers, weights, progress=progress, desc="both sets")
        scores, alarmed = np.zeros(len(runs)), np.zeros(len(runs), bool)
        for o, (own_peaks, held_peaks) in zip(names, results):
            own_slipped, mine = slipped[objects != o], objects == o
            th = calibrated_threshold(own_peaks[~own_slipped], own_peaks[own_slipped], BUDGET)
            scores[mine], alarmed[mine] = held_peaks, held_peaks >= th
        name = f"trained on both sets ({len(others)} grasps of {Path(str(also)).name} too)"
        rows.append(_row(name, scores, alarmed, slipped, objects, time.perf_counter() - t0, draws))
    for name in ("mean_frame_difference", "difference_to_contact", "frame_difference"):
        s = np.array([frame_scores(r.gray[0], 0)[name] for r in runs])  # on the detector's own grey frames
        lo = slipped_or_held.leave_objects_out(s, slipped, objects)
        rows.append(_row(f"baseline: {name}", s, lo, slipped, objects, 0.0, draws))
    m = slipped_or_held.majority_measure(slipped, objects, draws)
    m.update(row="baseline: majority class", held_alarming=0, seconds=0.0)
    m["operating_point"] = m["leave_objects_out"]
    rows.append(m)
    return {
        "recordings": recordings.root.name,
        "grasps": len(runs),
        "objects": names,
        "epochs": epochs,
        "seed": seed,
        "budget": BUDGET,
        "rows": rows,
    }


def table(doc: dict[str, Any]) -> str:
    """The study as a Markdown table."""

    def cell(m: dict | None) -> str:
        return "-" if m is None else f"{m['value']:.3f} [{m['interval'][0]:.2f}, {m['interval'][1]:.2f}]"

    lines = [
        "| detector | ROC AUC | accuracy, own threshold | balanced accuracy, own threshold | "
        "accuracy, threshold from the other objects | held grasps alarming | seconds |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in doc["rows"]:
        own, other = r.get("operating_point") or {}, r.get("leave_objects_out") or {}
        n_held = r["grasps"] - r["slipped"]
        lines.append(
            f"| {r['row']} | {cell(r['roc_auc'])} | {cell(own.get('accuracy'))} | "
            f"{cell(own.get('balanced_accuracy'))} | {cell(other.get('accuracy'))} | {r['held_alarming']} of "
            f"{n_held} | {r['seconds']} |"
        )
    return "\n".join(lines)


def plot(doc: dict[str, Any], path: str | Path) -> Path:
    """Accuracy and ROC AUC against the grasps fine-tuned on, the as-is and recalibrated detectors and
    the best baseline as lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from slipsense.atomic import atomic_path

    rows = {r["row"]: r for r in doc["rows"]}
    tuned = [r for r in doc["rows"] if r["row"].startswith("fine-tuned")]
    xs = list(range(len(tuned)))
    fig, ax = plt.subplots(figsize=(6.4, 4))
    for key, style in (("roc_auc", "o-"), ("accuracy", "s-")):
        vals = [r["roc_auc"]["value"] if key == "roc_auc" else r["operating_point"]["accuracy"]["value"] for r in tuned]
        ax.plot(xs, vals, style, label=f"fine-tuned: {key.replace('_', ' ')}")
    for name, color in (("as is", "grey"), ("recalibrated", "tab:green")):
        ax.axhline(rows[name]["operating_point"]["accuracy"]["value"], color=color, ls="--", label=f"{name}: accuracy")
    best = max(
        (r for r in doc["rows"] if r["row"].startswith("baseline")),
        key=lambda r: r["operating_point"]["accuracy"]["value"],
    )
    ax.axhline(best["operating_point"]["accuracy"]["value"], color="black", ls=":", label=f"{best['row']}: accuracy")
    ax.set_xticks(xs, [r["row"].split(", ")[1] for r in tuned])
    ax.set_xlabel("grasps of the new sensor trained on")
    ax.set_ylim(0.3, 1.0)
    ax.set_title(f"{doc['recordings']}: leave-objects-out, {len(doc['objects'])} objects")
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    with atomic_path(Path(path)) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return Path(path)


def write(doc: dict[str, Any], out: str | Path) -> list[Path]:
    from slipsense.atomic import write_text

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_text(out / "adaptation.json", json.dumps(doc, indent=1, default=float))
    write_text(out / "adaptation.md", table(doc) + "\n")
    return [out / "adaptation.json", out / "adaptation.md", plot(doc, out / "adaptation.png")]
