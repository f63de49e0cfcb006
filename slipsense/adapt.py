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
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from slipsense.api import fit
from slipsense.atomic import write_text
from slipsense.checkpoint import read_info, update_info
from slipsense.measures import MEASURES, Judged, cell, measure_all, ranked, slipped_or_held
from slipsense.measures.promise import held_alarm_promise
from slipsense.evaluation.calibrate import calibrate, calibrated_threshold
from slipsense.evaluation.judge import Evaluation, judge, recordings_set, shipped_for
from slipsense.evaluation.summary import rate_lines
from slipsense.measures.slipped_or_held import BASELINE_WORDS
from slipsense.models import available, model_class
from slipsense.progress import progress_bar
from slipsense.recordings.recording_set import Recordings

#: The fewest objects, and the fewest slipped and held grasps, from which a leave-objects-out
#: judgement says anything (one object out leaves at least two to choose a threshold on); and the
#: fewest objects with slipped grasps and with held ones (one object out still leaves a slip to learn
#: from and a held grasp to set the threshold on).
MIN_OBJECTS = 3
MIN_EACH = 3
MIN_OBJECTS_EACH = 2
#: A kept detector's nested balanced accuracy below this is no detector: nothing is kept.
USEFUL = 0.6
#: The registered measure adapt ranks candidates by (its value: balanced accuracy of slipped against
#: held grasps at the candidate's operating points; the grasps adapt judges are labelled as a whole).
RANK_BY = "grasp_measure"
#: Inner object folds on which every family's operating point is chosen (its threshold, and the settings
#: a recipe chooses among): on grasps of objects the model in question never saw, for the detectors
#: judged and for the one kept alike.
INNER_FOLDS = 2
#: Grasps whose first frame is searched for gel markers, and the markers that make a grid.
MARKER_GRASPS, MIN_MARKERS = 3, 20


@dataclass
class Grasps:
    """What ``adapt`` knows of the user's grasps: what a family's ``adapt_reason`` reads."""

    count: int
    objects: list[str]
    cameras: int
    image_size: tuple[int, int] | None
    fps: float | None
    recordings: list = field(default_factory=list, repr=False)
    _markers: tuple[bool, str] | None = field(default=None, repr=False)

    def markers(self) -> tuple[bool, str]:
        """Whether the gels carry a marker grid, and the evidence in words: the markers found on the
        first frame of a few grasps (:func:`slipsense.sensors.marker_detection.detect_markers`)."""
        if self._markers is None:
            self._markers = find_markers(self.recordings[:MARKER_GRASPS])
        return self._markers


def find_markers(recordings: Sequence[Any]) -> tuple[bool, str]:
    """``(found, evidence)``: a grid where at least :data:`MIN_MARKERS` evenly spaced dark dots are
    found on the first frame of most of ``recordings``."""
    from slipsense.errors import InputError
    from slipsense.recordings.video import read_video
    from slipsense.sensors.marker_detection import detect_markers

    counts, spacings = [], []
    for rec in recordings:
        try:
            frame = read_video(rec.path, expected_size=None)[0]
            pts = detect_markers(frame)
        except InputError:
            counts.append(0)
            continue
        d = np.linalg.norm(pts[:, None] - pts[None], axis=-1) + np.eye(len(pts)) * 1e9
        nearest = d.min(axis=1)
        regular = np.std(nearest) < 0.35 * np.median(nearest)
        counts.append(len(pts) if regular else 0)
        spacings.append(float(np.median(nearest)))
    hits = sum(c >= MIN_MARKERS for c in counts)
    if hits > len(counts) / 2:
        return True, (
            f"a marker grid on {hits} of {len(counts)} grasps checked "
            f"({int(np.median([c for c in counts if c]))} markers, {np.median(spacings):.0f} px apart)"
        )
    most = max(counts, default=0)
    return False, f"no marker grid on the {len(counts)} grasps checked (at most {most} evenly spaced dots)"


@dataclass
class Candidate:
    """One way to get a detector, judged leave-objects-out.

    Attributes:
        name: ``"as is"``, ``"recalibrated"``, ``"fine-tuned"`` or a registered family's name.
        scores: ``(N,)`` each grasp's peak alarm score (:func:`~slipsense.measures.slipped_or_held.peak_alarm_score`).
        alarmed: ``(N,)`` whether the grasp alarmed at the operating point chosen without its object.
        slipped, objects: ``(N,)`` the grasps' labels and objects.
        words: what it is, in words.
        judged: its grasps replayed, each at the operating point chosen without its object, where it
            has them (the nested choice has alarms only): every registered measure is read from them.

    ``measure`` is the slipped-against-held figure of :data:`RANK_BY` that adapt ranks by; ``measures``
    the value each registered measure that ranks gives (:func:`~slipsense.measures.ranked`), for its
    table and ``adapt.json``.
    """

    name: str
    scores: np.ndarray
    alarmed: np.ndarray
    slipped: np.ndarray
    objects: np.ndarray
    words: str = ""
    judged: Judged | None = field(default=None, repr=False)

    def __post_init__(self):
        self.measure = slipped_or_held.outcome_measure(self.scores, self.slipped, self.objects, self.alarmed)
        others = [k for k in MEASURES if k != RANK_BY]  # that one is ``measure``, computed above
        self.measures = {RANK_BY: MEASURES[RANK_BY].value({"detector": self.measure})}
        if self.judged is not None:
            self.measures.update(ranked(measure_all(self.judged, others)))

    @property
    def catches(self) -> bool:
        """Whether it alarms on any grasp that slipped."""
        return bool(self.alarmed[self.slipped].any())

    @property
    def balanced_accuracy(self) -> float:
        return self.measure["operating_point"]["balanced_accuracy"]["value"]

    def line(self) -> str:
        caught, loud = int(self.alarmed[self.slipped].sum()), int(self.alarmed[~self.slipped].sum())
        op = self.measure["operating_point"]
        others = [
            f"{MEASURES[k].label} {cell(k, v)}" for k, v in self.measures.items() if k != RANK_BY and not math.isnan(v)
        ]
        return (
            f"{_pct(op['balanced_accuracy'])} balanced, right on {_pct(op['accuracy'], False)}; {caught} of "
            f"{int(self.slipped.sum())} slips caught, {loud} of {int((~self.slipped).sum())} held grasps alarm"
            + "".join(f"; {o}" for o in others)
        )

    def to_dict(self) -> dict[str, Any]:
        caught, loud = int(self.alarmed[self.slipped].sum()), int(self.alarmed[~self.slipped].sum())
        return dict(
            name=self.name,
            words=self.words,
            measure=self.measure,
            measures=self.measures,
            slips_caught=caught,
            held_alarming=loud,
        )


def _pct(m: dict[str, Any], ranged: bool = True) -> str:
    lo, hi = m["interval"]
    return f"{100 * m['value']:.0f}%" + (f" (95% range {100 * lo:.0f}-{100 * hi:.0f}%)" if ranged else "")


def best_of(candidates: Sequence[Candidate], mask: np.ndarray | None = None) -> Candidate:
    """The candidate best by the value :data:`RANK_BY` ranks by (a registered measure: balanced accuracy
    of slipped against held at the candidate's operating points) on the grasps of ``mask`` (ties: ROC
    AUC, then the one listed first, the cheaper)."""
    mask = np.ones(len(candidates[0].slipped), bool) if mask is None else mask
    rank, auc = MEASURES[RANK_BY], slipped_or_held.roc_auc

    def figure(c: Candidate) -> dict[str, Any]:  # the measure on those grasps (its value, no intervals)
        m = slipped_or_held.outcome_measure(c.scores[mask], c.slipped[mask], c.objects[mask], c.alarmed[mask], 0)
        return {"detector": m}

    ranks = [(rank.better_first(figure(c)), auc(c.scores[mask], c.slipped[mask])) for c in candidates]
    ranks = [tuple(float(np.nan_to_num(v, nan=-np.inf)) for v in r) for r in ranks]
    top = max(range(len(candidates)), key=lambda i: (ranks[i], -i))
    return candidates[top]


def nested_choice(candidates: Sequence[Candidate]) -> tuple[Candidate, dict[str, str]]:
    """The figure of choosing among ``candidates``: each object's grasps scored by the candidate
    chosen (:func:`best_of`) on the other objects' grasps only. Returns that as a candidate and the
    choice made without each object. Its scores are alarms (0/1): candidates' scores are on
    different scales, so its ROC AUC is the alarms' own."""
    first = candidates[0]
    alarmed = np.zeros(len(first.slipped), bool)
    chosen: dict[str, str] = {}
    for o in sorted(set(first.objects)):
        mine = first.objects == o
        pick = best_of(candidates, ~mine)
        alarmed[mine] = pick.alarmed[mine]
        chosen[str(o)] = pick.name
    kept = Candidate("chosen without each object", alarmed.astype(float), alarmed, first.slipped, first.objects)
    return kept, chosen


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
    for kind, mask in (("slipped", slipped), ("held", ~slipped)):
        n_with = len(set(objects[mask]))
        if n_with < MIN_OBJECTS_EACH:
            missing.append(f"{kind} grasps of {MIN_OBJECTS_EACH - n_with} more object(s)")
    if not missing:
        return None
    return (
        f"{n_slip} slipped and {n_held} held grasps of {n_obj} object(s) are too few to judge a detector on objects "
        f"it never saw: record at least {' and '.join(missing)} (slipsense record; s + Enter marks a slip)"
    )


def families(grasps: Grasps) -> tuple[list[str], dict[str, str]]:
    """The registered families that can learn from ``grasps``, cheapest first, and why the others cannot."""
    reasons = {name: model_class(name).adapt_reason(grasps) for name in available()}
    fit_ = sorted((n for n, r in reasons.items() if r is None), key=lambda n: model_class(n).adapt_cost)
    return fit_, {n: r for n, r in reasons.items() if r is not None}


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
    keys, objs = _keys(as_is), sorted(set(objects))  # the objects shuffled with ``seed``, in min(folds, n) folds
    order = np.random.default_rng(seed).permutation(len(objs))
    parts = [sorted(objs[i] for i in part) for part in np.array_split(order, min(folds, len(objs)))]
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


def _promise_unseen(path: Path, chosen: Candidate, folds: int) -> None:
    """The kept detector's promise, in its checkpoint: what its family did on the held grasps of objects
    it never saw (adapt's table), not what its operating point measured on the objects it was chosen on,
    so ``watch`` and ``models`` state the figure adapt printed (:func:`~slipsense.measures.promise.promise_text`)."""
    held = ~chosen.slipped
    promise = held_alarm_promise(chosen.alarmed[held], chosen.objects[held])
    promise["measured_on"] = f"objects it never saw ({folds} object folds of these grasps, slipsense adapt)"
    op = dict(read_info(path).get("operating_point") or {})
    update_info(path, {"operating_point": {**op, "held_alarm_unseen": promise}})


def advise(
    chosen: Candidate,
    kept: Candidate,
    per_object: dict[str, str],
    as_is: Candidate,
    best_name: str,
    best: dict[str, Any],
) -> tuple[bool, list[str]]:
    """Whether to keep ``chosen`` (the best on all grasps), and sentences each true of the figures:
    ``kept`` is the nested figure of making that choice (:func:`nested_choice`)."""
    op = kept.measure["operating_point"]
    ba, acc = op["balanced_accuracy"], op["accuracy"]
    picks = sorted(set(per_object.values()))
    stable = (
        f"chosen the same way without each object in turn, {picks[0]} won every time"
        if len(picks) == 1
        else f"chosen the same way without each object in turn, the choice went to {', '.join(picks)}"
    )
    figure = (
        f"what to expect on objects it never saw: {_pct(ba)} balanced accuracy, right on {_pct(acc)} of grasps "
        f"({stable})"
    )
    if ba["value"] < USEFUL or not chosen.catches:
        return False, [
            f"nothing is kept: the best candidate ({chosen.name}) is near chance on objects it never saw "
            f"({100 * ba['value']:.0f}% balanced accuracy when chosen without each object; the best baseline, "
            f"{best_name}, {100 * best['value']:.0f}%). Record more grasps, of more objects, slipped and held alike, "
            "and adapt again",
            figure,
        ]
    near = ba["interval"][0] <= 0.5
    caveat = "; near chance: its 95% range reaches 50%, so record more grasps before trusting it" if near else ""
    if chosen.name == "as is":
        return True, [
            f"keep using the shipped detector as it is ({as_is.words.removeprefix('the shipped ')}, slipsense watch "
            f"picks it): nothing made from your grasps did better on objects it never saw{caveat}; no detector is written",
            figure,
        ]
    return True, [
        f"kept {chosen.name} ({chosen.words}): the best of the candidates on objects it never saw, "
        f"{100 * chosen.balanced_accuracy:.0f}% balanced accuracy against {100 * as_is.balanced_accuracy:.0f}% for "
        f"the shipped detector as is{caveat}",
        figure,
    ]


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


def _train(data: Recordings, out: Path, name: str, seed: int, held_out: Sequence[str], **settings) -> Path:
    """Family ``name`` trained on ``data``'s grasps but ``held_out``'s into ``out``, with ``settings``
    where given, else with its own recipe, its operating point chosen on :data:`INNER_FOLDS` inner folds
    (over a recipe that chooses it on the grasps themselves), then the family's own ``adapt_settings``.
    The detector a finished training left in ``out`` is kept; a half-done one's folder is cleared."""
    done = out / "detector.safetensors"
    if done.is_file():
        return done
    if out.exists():
        shutil.rmtree(out)  # a training killed half-way: its folder holds no checkpoint yet
    settings = settings or {"inner_folds": INNER_FOLDS, **model_class(name).adapt_settings}
    return fit(data, out, model=name, held_out=list(held_out), seed=seed, progress=False, **settings).checkpoint


def _fine_tune(data: Recordings, out: Path, shipped: Path, epochs: int, seed: int, held_out: Sequence[str]) -> Path:
    """The shipped weights trained further on ``data``'s grasps but ``held_out``'s into ``out``."""
    tuning = {"init": str(shipped), "epochs": epochs, "inner_folds": 0}
    return _train(data, out, read_info(shipped)["model"], seed, held_out, **tuning)


def _finish(doc: dict[str, Any], out: Path, chosen: str | None, why: str, advice: list[str], echo) -> dict[str, Any]:
    doc.update(chosen=chosen, why=why, advice=advice)
    write_text(out / "adapt.json", json.dumps(doc, indent=1, default=float))
    for line in advice:
        echo(line)
    if chosen:
        echo(f"-> {doc['checkpoint']} (slipsense watch --checkpoint {doc['checkpoint']} ...)")
    return doc
