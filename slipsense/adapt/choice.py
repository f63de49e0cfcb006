"""Choosing a detector for a user's sensor (``slipsense adapt``): what the grasps allow, every candidate
judged on objects it never saw, the one kept ranked by a registered measure (:data:`RANK_BY`), the
figure of making that choice (:func:`nested_choice`) and the advice in words. Nothing here trains,
calibrates or writes a detector: :mod:`slipsense.adapt.making` does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from slipsense.measures import MEASURES, Judged, cell, measure_all, ranked, slipped_or_held
from slipsense.models import available, model_class

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
