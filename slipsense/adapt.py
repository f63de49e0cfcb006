"""Fit a detector to your own sensor from your own grasps: ``slipsense adapt``.

One guided path from "the shipped detector never alarms on my sensor" to a detector you can trust,
judged the way it will be used: on objects it never saw.

1. **Read the grasps**: how many, of how many objects, slipped or held, cameras per grasp, frame size
   and rate. Too few to judge anything (:data:`MIN_OBJECTS`, :data:`MIN_EACH`) ends here, saying what
   to record next.
2. **Candidates**, each judged leave-objects-out (every grasp scored by a detector whose threshold,
   and weights where it learns, never saw that grasp's object):

   * ``as is``: the shipped detector for the sensor, its own operating point;
   * ``recalibrated``: the same weights, the threshold chosen on the other objects' grasps (at most
     ``budget`` of their held grasps alarming, :func:`~slipsense.evaluation.calibrate.calibrated_threshold`);
   * ``fine-tuned``: the shipped weights trained further on the other objects' grasps (``folds``
     object folds), the threshold chosen on those grasps;
   * beside them the non-learned baselines (frame differences, thresholds chosen on the other objects).

3. **Choose** the candidate of best balanced accuracy at its own operating point (what a gripper
   gets), and keep it only where it beats both the shipped detector as is and the best baseline;
   then make it on every grasp (recalibrate, or fine-tune) into ``<out>/detector.safetensors``.
   Otherwise nothing is written and the summary says why.

Every fold's training is kept under ``<out>/folds``, so a killed run resumes where it stopped.
"""

from __future__ import annotations

import json
import shutil
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from slipsense.api import fit
from slipsense.atomic import write_text
from slipsense.checkpoint import read_info
from slipsense.evaluation import outcome
from slipsense.evaluation.calibrate import calibrate, calibrated_threshold
from slipsense.evaluation.replay import Evaluation, evaluate, shipped_for
from slipsense.evaluation.summary import BASELINE_WORDS, rate_lines
from slipsense.progress import progress_bar
from slipsense.recordings.frame_folders import data_sensor

#: The fewest objects, and the fewest slipped and held grasps, from which a leave-objects-out
#: judgement says anything (one object out leaves at least two to choose a threshold on).
MIN_OBJECTS = 3
MIN_EACH = 3


@dataclass
class Candidate:
    """One way to get a detector, judged leave-objects-out.

    Attributes:
        name: ``"as is"``, ``"recalibrated"`` or ``"fine-tuned"``.
        scores: ``(N,)`` each grasp's peak alarm score (:func:`~slipsense.evaluation.outcome.peak_alarm_score`).
        alarmed: ``(N,)`` whether the grasp alarmed at the operating point chosen without its object.
        slipped: ``(N,)`` the grasps' labels.
    """

    name: str
    scores: np.ndarray
    alarmed: np.ndarray
    slipped: np.ndarray
    objects: np.ndarray

    def __post_init__(self):
        self.measure = outcome.outcome_measure(self.scores, self.slipped, self.objects, self.alarmed)

    @property
    def catches(self) -> bool:
        """Whether it alarms on any grasp that slipped."""
        return bool(self.alarmed[self.slipped].any())

    @property
    def balanced_accuracy(self) -> float:
        return self.measure["operating_point"]["balanced_accuracy"]["value"]

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "measure": self.measure,
            "slips_caught": int(self.alarmed[self.slipped].sum()),
            "held_alarming": int(self.alarmed[~self.slipped].sum()),
        }


def _pct(m: dict[str, Any]) -> str:
    lo, hi = m["interval"]
    return f"{100 * m['value']:.0f}% (95% range {100 * lo:.0f}-{100 * hi:.0f}%)"


def _object_folds(objects: Sequence[str], folds: int, seed: int) -> list[list[str]]:
    """The objects shuffled with ``seed`` and dealt into ``min(folds, len)`` folds."""
    names = sorted(set(objects))
    order = np.random.default_rng(seed).permutation(len(names))
    return [sorted(names[i] for i in part) for part in np.array_split(order, min(folds, len(names)))]


def _keys(ev: Evaluation) -> list[tuple]:
    return [(r.object, r.experiment, r.cameras) for r in ev.runs]


def _too_few(slipped: np.ndarray, objects: np.ndarray) -> str | None:
    """What is missing for a judgement on objects left out, in words; None when nothing is."""
    n_obj, n_slip, n_held = len(set(objects)), int(slipped.sum()), int((~slipped).sum())
    missing = []
    if n_obj < MIN_OBJECTS:
        missing.append(f"grasps of {MIN_OBJECTS - n_obj} more object(s)")
    if n_slip < MIN_EACH:
        missing.append(f"{MIN_EACH - n_slip} more grasp(s) that slipped")
    if n_held < MIN_EACH:
        missing.append(f"{MIN_EACH - n_held} more grasp(s) that held")
    if not missing:
        return None
    return (
        f"{n_slip} slipped and {n_held} held grasps of {n_obj} object(s) are too few to judge a detector on objects "
        f"it never saw: record at least {' and '.join(missing)} (slipsense record; s + Enter marks a slip)"
    )


def adapt(
    recordings: str | Path,
    out: str | Path,
    *,
    budget: float = 0.05,
    folds: int = 5,
    epochs: int = 10,
    seed: int = 0,
    progress: bool = True,
    echo: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Judge the shipped detector, a recalibrated and a fine-tuned one on ``recordings`` leave-objects-
    out, and write the best into ``<out>/detector.safetensors`` where it beats the detector as is and
    the best non-learned baseline (see the module notes).

    Args:
        recordings: the user's grasps (any recordings layout; frame folders need a ``sensor.json``).
        out: a folder: ``detector.safetensors``, ``adapt.json`` (every figure), ``folds/`` (the trainings).
        budget: the fraction of held grasps allowed to alarm where a threshold is chosen on held grasps.
        folds: object folds of the fine-tuning judgement (the objects are split into this many).
        epochs: fine-tuning epochs.
        seed: of the object folds and the trainings.
        echo: where the plain-words summary goes, line by line.

    Returns ``adapt.json``'s content: ``{"chosen": name or None, "why": ..., "candidates": [...],
    "baselines": {...}, "checkpoint": path or None}``.
    """
    root, out = Path(recordings), Path(out)
    out.mkdir(parents=True, exist_ok=True)
    shipped = shipped_for(root)
    as_is = evaluate(shipped, root, progress=progress)
    slipped = np.array([r.slipped for r in as_is.runs], bool)
    objects = np.array([r.object for r in as_is.runs])
    sensor = data_sensor(root)
    size = f"{sensor.image_size[1]}x{sensor.image_size[0]} px, " if sensor and sensor.image_size else ""
    cameras = {len(r.cameras) for r in as_is.runs}
    echo(
        f"your grasps: {len(slipped)} ({int(slipped.sum())} slipped, {int((~slipped).sum())} held) of "
        f"{len(set(objects))} objects, {size}{'/'.join(map(str, sorted(cameras)))} camera(s) a grasp"
    )
    for line in rate_lines(as_is.frame_rates()):
        echo(line)
    doc: dict[str, Any] = {"recordings": str(root), "shipped": shipped.name, "budget": budget, "checkpoint": None}
    why = _too_few(slipped, objects)
    if why is not None:
        return _finish(doc, out, None, why, echo)

    measure = as_is.grasp_measure()
    baselines = measure["baselines"]
    best_name = max(baselines, key=lambda b: baselines[b]["leave_objects_out"]["balanced_accuracy"]["value"])
    best = baselines[best_name]["leave_objects_out"]["balanced_accuracy"]
    scores = as_is.peak_scores()
    candidates = [Candidate("as is", scores, scores >= as_is.threshold, slipped, objects)]
    recal = np.zeros(len(scores), bool)
    for o in sorted(set(objects)):
        other, mine = objects != o, objects == o
        recal[mine] = scores[mine] >= calibrated_threshold(scores[other & ~slipped], scores[other & slipped], budget)
    candidates.append(Candidate("recalibrated", scores, recal, slipped, objects))
    tuned_scores, tuned_alarmed = _fine_tuned_out_of_fold(
        as_is, root, out / "folds", shipped, epochs, folds, seed, progress
    )
    candidates.append(Candidate("fine-tuned", tuned_scores, tuned_alarmed, slipped, objects))
    doc["candidates"] = [c.to_dict() for c in candidates]
    doc["baselines"] = baselines
    echo(
        "judged on objects each detector never saw (balanced accuracy: the mean of slips caught and held grasps quiet):"
    )
    for c in candidates:
        caught, quiet = int(c.alarmed[slipped].sum()), int(c.alarmed[~slipped].sum())
        echo(
            f"  {c.name:13s} {_pct(c.measure['operating_point']['balanced_accuracy'])}; {caught} of "
            f"{int(slipped.sum())} slips caught, {quiet} of {int((~slipped).sum())} held grasps alarm"
        )
    echo(f"  best baseline {_pct(best)}: {best_name} ({BASELINE_WORDS.get(best_name, best_name)})")

    chosen, why = choose(candidates, best_name, best, shipped.stem)
    if chosen is None:
        return _finish(doc, out, None, why, echo)
    path = out / "detector.safetensors"
    if chosen.name == "recalibrated":
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the same grasps again: their warnings were given above
            calibrate(path, shipped, root, budget=budget, progress=progress)
    else:
        trained = _fine_tune(root, out / "fine-tuned", shipped, epochs, seed, progress, held_out=())
        shutil.copyfile(trained, path.with_suffix(".partial"))
        path.with_suffix(".partial").replace(path)
    doc["checkpoint"] = str(path)
    return _finish(doc, out, chosen.name, why, echo)


def choose(
    candidates: Sequence[Candidate], best_name: str, best: dict[str, Any], shipped: str
) -> tuple[Candidate | None, str]:
    """The candidate to keep (of those after ``candidates[0]``, the detector as is) and why, in words:
    the best balanced accuracy at its own operating point, kept only where it is above both the
    detector as is and the best baseline (``best``: its ``{"value", "interval"}``) and catches a slip."""
    as_is = candidates[0]
    chosen = max(candidates[1:], key=lambda c: (c.balanced_accuracy, c.measure["roc_auc"]["value"]))
    if chosen.balanced_accuracy > max(as_is.balanced_accuracy, best["value"]) and chosen.catches:
        ranges = chosen.measure["operating_point"]["balanced_accuracy"]["interval"][0] <= max(
            as_is.measure["operating_point"]["balanced_accuracy"]["interval"][1], best["interval"][1]
        )
        return chosen, (
            f"{chosen.name}: the best on objects it never saw, above the shipped detector as is and the best baseline"
            + ("; their 95% ranges overlap, so more grasps would make the gain certain" if ranges else "")
        )
    if as_is.balanced_accuracy >= max(best["value"], chosen.balanced_accuracy):
        return None, (
            "the shipped detector as is does at least as well as recalibrating or fine-tuning it on objects it "
            f"never saw: keep using it ({shipped}, slipsense watch picks it); no detector is written"
        )
    return None, (
        f"no detector beats the best baseline ({best_name}, {best['value']:.2f} balanced accuracy) or catches a slip "
        "on objects it never saw: no detector is written. Record more grasps, of more objects, slipped and held "
        "alike, and adapt again"
    )


def _fine_tune(
    root: Path, out: Path, shipped: Path, epochs: int, seed: int, progress: bool, held_out: Sequence[str]
) -> Path:
    """The shipped weights trained further on ``root``'s grasps but ``held_out``'s into ``out`` (kept:
    a finished training is not repeated, a killed one resumes); the checkpoint's path."""
    done = out / "detector.safetensors"
    if done.is_file():
        return done
    if out.exists():
        shutil.rmtree(out)  # a training killed half-way: its folder holds no checkpoint yet
    info = read_info(shipped)
    res = fit(
        root,
        out,
        model=info["model"],
        held_out=list(held_out),
        overrides=True,
        seed=seed,
        progress=progress,
        init=str(shipped),
        epochs=epochs,
        inner_folds=0,
    )
    return res.checkpoint


def _fine_tuned_out_of_fold(
    as_is: Evaluation, root: Path, out: Path, shipped: Path, epochs: int, folds: int, seed: int, progress: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Each grasp's peak score and alarm from the fine-tuned detector of the fold that held its object out."""
    keys = _keys(as_is)
    where = {key: i for i, key in enumerate(keys)}
    scores, alarmed = np.full(len(keys), -np.inf), np.zeros(len(keys), bool)
    parts = _object_folds([k[0] for k in keys], folds, seed)
    for k, held in enumerate(progress_bar(parts, progress, "fine-tuning, one fold at a time")):
        ckpt = _fine_tune(root, out / f"fold{k}", shipped, epochs, seed + k, False, held)
        ev = evaluate(ckpt, root, objects=held, progress=False)
        for key, s in zip(_keys(ev), ev.peak_scores()):
            scores[where[key]], alarmed[where[key]] = s, s >= ev.threshold
    return scores, alarmed


def _finish(doc: dict[str, Any], out: Path, chosen: str | None, why: str, echo) -> dict[str, Any]:
    doc.update(chosen=chosen, why=why)
    write_text(out / "adapt.json", json.dumps(doc, indent=1, default=float))
    echo(("kept " if chosen else "not adapted: ") + why)
    if chosen:
        echo(f"-> {doc['checkpoint']} (slipsense watch --checkpoint {doc['checkpoint']} ...)")
    return doc
