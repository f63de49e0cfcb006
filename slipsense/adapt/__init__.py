"""Fit a detector to your own sensor from your own grasps: ``slipsense adapt``.

One guided path from "the shipped detector never alarms on my sensor" to the best detector the
library knows how to make for it, judged the way it will be used: on objects it never saw.

1. **Read the grasps**: how many, of how many objects, slipped or held, cameras per grasp, frame size
   and rate. Too few to judge anything (:data:`MIN_OBJECTS`, :data:`MIN_EACH`,
   :data:`MIN_OBJECTS_EACH`) ends here, saying what to record next.
2. **Candidates**, cheap ones first, each judged leave-objects-out (every grasp scored by a detector
   whose threshold, and weights where it learns, never saw that grasp's object):

   * ``as is``: the shipped detector for the sensor, its own operating point;
   * ``recalibrated``: the same weights, the threshold chosen on the other objects' grasps;
   * every registered family that can learn from the grasps (the model says so itself,
     :meth:`~slipsense.models.base.SlipModel.adapt_reason`: the shear-retention family where the
     gels carry markers, MotionNet from scratch where there are enough grasps, the motion-energy
     detector always, whatever a future model registers), trained with its own recipe on the other
     objects' grasps (``folds`` object folds); a family that cannot prints why;
   * ``fine-tuned``: the shipped weights trained further on the other objects' grasps;
   * beside them the non-learned baselines of the evaluation (reference rows: not kept).

3. **An honest figure**: the candidate of best balanced accuracy is chosen again without each object
   in turn, on the other objects' grasps only, and that choice scores the object's grasps: the figure
   for what is kept (:func:`nested_choice`), with 95% ranges over objects. The best of several
   candidates on the same grasps would flatter the winner.
4. **Keep** the best on all grasps, trained on every grasp with its family's recipe, where the
   nested figure is better than chance; the shipped detector itself where it is the best (nothing is
   written then). The advice says which, why, and when the figure is near chance.

Every training is kept under ``<out>/folds``, so a killed run resumes where it stopped.
"""

from __future__ import annotations

import json
import shutil
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from slipsense.atomic import write_text
from slipsense.evaluation.calibrate import calibrate, calibrated_threshold
from slipsense.evaluation.judge import Evaluation, judge, recordings_set, shipped_for
from slipsense.evaluation.summary import rate_lines
from slipsense.measures import Judged
from slipsense.measures.slipped_or_held import BASELINE_WORDS
from slipsense.models import model_class
from slipsense.progress import progress_bar
from slipsense.recordings.recording_set import Recordings
from slipsense.recordings.splits import ObjectFolds

from .choice import (
    MARKER_GRASPS,
    MIN_EACH,
    MIN_OBJECTS,
    MIN_OBJECTS_EACH,
    RANK_BY,
    USEFUL,
    Candidate,
    Grasps,
    _pct,
    _too_few,
    advise,
    best_of,
    families,
    find_markers,
    nested_choice,
)
from .making import INNER_FOLDS, _fine_tune, _promise_unseen, _train


def _keys(ev: Evaluation) -> list[tuple]:
    return [(r.object, r.experiment, r.cameras) for r in ev.runs]


def adapt(
    recordings: str | Path | Recordings,
    out: str | Path,
    *,
    budget: float = 0.05,
    folds: int = 5,
    epochs: int = 10,
    seed: int = 0,
    progress: bool = True,
    echo: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Judge the shipped detector, a recalibrated one, every registered family that can learn from
    ``recordings`` and the shipped weights fine-tuned, leave-objects-out; keep the best (see the
    module notes).

    Args:
        recordings: the user's grasps (any recordings layout; frame folders need a ``sensor.json``), a
            :class:`~slipsense.recordings.recording_set.Recordings` or its folder: listed once, every
            fold, training and judgement below reads that one listing.
        out: a folder: ``detector.safetensors``, ``adapt.json`` (every figure), ``folds/`` (the trainings).
        budget: the fraction of held grasps allowed to alarm where a threshold is chosen on held grasps.
        folds: object folds of the trained candidates' judgement (the objects are split into this many).
        epochs: fine-tuning epochs (a family trains with its own recipe).
        seed: of the object folds and the trainings.
        echo: where the plain-words summary goes, line by line.

    Returns ``adapt.json``'s content: ``{"chosen", "why", "advice", "candidates", "kept", "baselines",
    "checkpoint", ...}``.
    """
    data, out = recordings_set(recordings), Path(out)
    shipped = shipped_for(data)
    as_is = judge(shipped, data, progress=progress)
    out.mkdir(parents=True, exist_ok=True)  # once the grasps were read: a bad folder leaves no empty --out
    slipped = np.array([r.slipped for r in as_is.runs], bool)
    objects = np.array([r.object for r in as_is.runs])
    sensor = data.stated
    size = tuple(sensor.image_size) if sensor and sensor.image_size else None
    cameras = max(len(r.cameras) for r in as_is.runs)
    replayed = list(as_is.recordings or ())
    grasps = Grasps(len(slipped), sorted(set(objects)), cameras, size, sensor.fps if sensor else None, replayed)
    echo(
        f"your grasps: {len(slipped)} ({int(slipped.sum())} slipped, {int((~slipped).sum())} held) of "
        f"{len(set(objects))} objects, {f'{size[1]}x{size[0]} px, ' if size else ''}{cameras} camera(s) a grasp"
    )
    for line in rate_lines(as_is.frame_rates()):
        echo(line)
    doc: dict[str, Any] = {"recordings": str(data.root), "shipped": shipped.name, "budget": budget, "checkpoint": None}
    why = _too_few(slipped, objects)
    if why is not None:
        return _finish(doc, out, None, why, [why], echo)

    measure = as_is.grasp_measure()
    baselines = measure["baselines"]
    best_name = max(baselines, key=lambda b: baselines[b]["leave_objects_out"]["balanced_accuracy"]["value"])
    best = baselines[best_name]["leave_objects_out"]["balanced_accuracy"]
    echo("each judged on objects it never saw (balanced accuracy: the mean of slips caught and held grasps quiet):")
    candidates: list[Candidate] = []

    def add(c: Candidate) -> None:
        candidates.append(c)
        echo(f"  {c.name:16s} {c.line()}")

    scores, judged = as_is.peak_scores(), as_is.judged()
    add(Candidate("as is", scores, scores >= as_is.threshold, slipped, objects, f"the shipped {shipped.stem}", judged))
    recal, thresholds = np.zeros(len(scores), bool), np.zeros(len(scores))
    for o in sorted(set(objects)):
        other, mine = objects != o, objects == o
        thresholds[mine] = calibrated_threshold(scores[other & ~slipped], scores[other & slipped], budget)
        recal[mine] = scores[mine] >= thresholds[mine]
    words = f"the shipped {shipped.stem}, its threshold chosen on your grasps"
    points = [(float(t), as_is.debounce, as_is.hold_s) for t in thresholds]
    add(Candidate("recalibrated", scores, recal, slipped, objects, words, replace(judged, points=points)))
    names, not_tried = families(grasps)
    for reason in dict.fromkeys(not_tried.values()):  # families alike in why said once
        echo(f"  {', '.join(n for n, r in not_tried.items() if r == reason):16s} not tried: {reason}")
    # the folds training cuts with the same seed; never more folds than objects (each fold tests one at least)
    keys, parts = _keys(as_is), ObjectFolds(min(folds, len(set(objects))), seed).test_objects(objects)
    for name in names:
        train = lambda held, k, name=name: _train(data, out / "folds" / name / f"fold{k}", name, seed + k, held)  # noqa: E731
        s, a, j = _out_of_fold(keys, parts, train, data, f"{name}, one fold at a time", progress)
        add(Candidate(name, s, a, slipped, objects, model_class(name).adapt_words, j))
    tuned = lambda held, k: _fine_tune(data, out / "folds" / "fine-tuned" / f"fold{k}", shipped, epochs, seed + k, held)  # noqa: E731
    s, a, j = _out_of_fold(keys, parts, tuned, data, "fine-tuning, one fold at a time", progress)
    words = f"the shipped {shipped.stem}'s weights trained further on your grasps"
    add(Candidate("fine-tuned", s, a, slipped, objects, words, j))
    echo(
        f"  {'best baseline':16s} {_pct(best)} balanced: {best_name} ({BASELINE_WORDS.get(best_name, best_name)}; not kept)"
    )

    kept_figure, per_object = nested_choice(candidates)
    chosen = best_of(candidates)
    doc.update(candidates=[c.to_dict() for c in candidates], not_tried=not_tried, baselines=baselines)
    doc["kept"] = {**kept_figure.to_dict(), "chosen_without_each_object": per_object}
    keep, advice = advise(chosen, kept_figure, per_object, candidates[0], best_name, best)
    if not keep or chosen.name == "as is":
        return _finish(doc, out, None, advice[0], advice, echo)
    path = out / "detector.safetensors"
    if chosen.name == "recalibrated":
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the same grasps again: their warnings were given above
            calibrate(path, shipped, data, budget=budget, progress=progress)
    else:
        if chosen.name == "fine-tuned":
            trained = _fine_tune(data, out / "fine-tuned", shipped, epochs, seed, ())
        else:
            trained = _train(data, out / "final" / chosen.name, chosen.name, seed, ())
        shutil.copyfile(trained, path.with_suffix(".partial"))
        path.with_suffix(".partial").replace(path)
    _promise_unseen(path, chosen, len(parts))
    doc["checkpoint"] = str(path)
    return _finish(doc, out, chosen.name, advice[0], advice, echo)


def _out_of_fold(keys, parts, train, data, desc, progress) -> tuple[np.ndarray, np.ndarray, Judged]:
    """Each grasp's peak score and alarm from the detector ``train(held, k)`` makes without its fold, and
    every fold's replayed grasps pooled, each at its fold's operating point (what the measures read)."""
    where = {key: i for i, key in enumerate(keys)}
    scores, alarmed = np.full(len(keys), -np.inf), np.zeros(len(keys), bool)
    runs, points, ev = [], [], None
    for k, held in enumerate(progress_bar(parts, progress, desc)):
        ckpt = train(held, k)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # judged on its own held-out objects only
            ev = judge(ckpt, data, objects=held, progress=False)
        for key, s in zip(_keys(ev), ev.peak_scores()):
            scores[where[key]], alarmed[where[key]] = s, s >= ev.threshold
        fold = ev.judged()
        runs += list(fold.runs)
        points += list(fold.points)
    return scores, alarmed, Judged(runs, points, ev.horizon, ev.startup)


def _finish(doc: dict[str, Any], out: Path, chosen: str | None, why: str, advice: list[str], echo) -> dict[str, Any]:
    doc.update(chosen=chosen, why=why, advice=advice)
    write_text(out / "adapt.json", json.dumps(doc, indent=1, default=float))
    for line in advice:
        echo(line)
    if chosen:
        echo(f"-> {doc['checkpoint']} (slipsense watch --checkpoint {doc['checkpoint']} ...)")
    return doc


__all__ = [
    "INNER_FOLDS",
    "MARKER_GRASPS",
    "MIN_EACH",
    "MIN_OBJECTS",
    "MIN_OBJECTS_EACH",
    "RANK_BY",
    "USEFUL",
    "Candidate",
    "Grasps",
    "adapt",
    "advise",
    "best_of",
    "families",
    "find_markers",
    "nested_choice",
]
