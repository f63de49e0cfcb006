"""Per-grasp early warning: how a robot builder judges a slip detector.

A detector is replayed over whole runs from the first frame, exactly as it would run live, and each
run gets one outcome. With ``m`` the moment of slip (last frame before contact is lost), ``H`` the
warning horizon in frames and ``S`` the camera start-up frames (not the scene, never scored):

* a run that slipped is **warned in time** when its first alarm in ``S..m`` falls in ``m-H..m``
  (lead = ``m - first alarm`` frames), **premature** when that first alarm comes before ``m-H``
  (a false alarm: the gripper would have reacted to nothing), **missed** when there is none;
* a run that held is a **false-positive grasp** when it alarms at any frame from ``S`` on; the
  fraction of its frames in alarm is reported too.

Alarms while the gel is at rest (no contact on any sensor) are counted separately: a detector must
not fire before anything touches it. A detector that is always on scores 0 warned and 100%
false-positive grasps; one that is always off scores 0 warned and 0 false positives; one that
alarms only in ``m-H..m`` scores 100% and 0 (tests hold all three).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Mapping, Sequence

import numpy as np

from slipsense.alarm import HOLD_S, debounce  # the alarm rule every outcome is judged by
from slipsense.errors import ConfigError
from slipsense.sensors.spec import GELSIGHT_MINI
from slipsense.measures.registry import HORIZON, STARTUP, Judged, plural, register


#: Thresholds an operating point is chosen among: class-balanced training inflates probabilities,
#: so the grid is dense near 1.
THRESHOLDS = tuple(float(t) for t in np.round(np.linspace(0.05, 0.95, 19), 3)) + (0.97, 0.98, 0.99, 0.995, 0.998, 0.999)


@dataclass(frozen=True)
class GraspOutcome:
    """One run's verdict. ``first_alarm``: first alarm frame scored (None: none); ``lead``: frames
    from it to the moment (warned runs); ``alarm_fraction``: frames in alarm over frames scored;
    ``rest_alarms``: alarm frames while no gel is touched."""

    outcome: str
    first_alarm: int | None
    lead: int | None
    alarm_fraction: float
    rest_alarms: int


def grasp_outcome(
    alarm: np.ndarray,
    moment: int | None,
    horizon: int = HORIZON,
    startup: int = STARTUP,
    rest: np.ndarray | None = None,
) -> GraspOutcome:
    """Score one run.

    Args:
        alarm: ``(N,)`` bool, the detector's alarm at every frame of the recording.
        moment: the moment of slip, or None for a run that held.
        horizon: frames before the moment in which a first alarm is a warning in time.
        startup: leading frames not scored.
        rest: optional ``(N,)`` bool, True where no sensor is touched (:func:`slipsense.recordings.contact.rest_mask`).
    """
    a = np.asarray(alarm, dtype=bool)
    start = min(startup, len(a))
    end = len(a) if moment is None else min(moment + 1, len(a))
    scored = a[start:end]
    on = np.flatnonzero(scored)
    first = None if on.size == 0 else start + int(on[0])
    fraction = float(scored.mean()) if scored.size else 0.0
    rest_alarms = 0 if rest is None else int((scored & np.asarray(rest, dtype=bool)[start:end]).sum())
    if moment is None:
        return GraspOutcome("false_positive" if first is not None else "clean", first, None, fraction, rest_alarms)
    if first is None:
        return GraspOutcome("missed", None, None, fraction, rest_alarms)
    if first < moment - horizon:
        return GraspOutcome("premature", first, None, fraction, rest_alarms)
    return GraspOutcome("warned", first, moment - first, fraction, rest_alarms)


def trace_outcome(
    probability: np.ndarray,
    threshold: float,
    debounce_frames: int,
    moment: int | None,
    slipped: bool,
    horizon: int = HORIZON,
    startup: int = STARTUP,
    rest: np.ndarray | None = None,
) -> GraspOutcome:
    """:func:`grasp_outcome` of a ``(N,)`` P(slip) trace alarming at ``threshold`` for ``debounce_frames``
    frames; a slip labelled as a whole (``slipped``, no moment to warn before) is
    ``slip_without_moment``, neither slip nor held."""
    o = grasp_outcome(debounce(probability, threshold, debounce_frames), moment, horizon, startup, rest)
    return replace(o, outcome="slip_without_moment") if slipped and moment is None else o


def run_fields(r: Any) -> dict[str, Any]:
    """How reports name a run (a :class:`RunTrace` or a training run) beside its figures."""
    return dict(object=r.object, experiment=r.experiment, cameras=list(r.cameras), moment_of_slip=r.moment_of_slip)


@dataclass
class RunTrace:
    """One replayed run: its labels, its probability trace and where no gel was touched."""

    object: str
    experiment: int
    slipped: bool
    moment_of_slip: int | None  # last frame before the object loses contact (slip runs)
    n_frames: int
    probability: np.ndarray  # (N,) combined; NaN where the detector gives no answer yet
    rest: np.ndarray | None = field(default=None, repr=False)  # (N,) bool: no sensor touched
    cameras: tuple[str, ...] = ()  # the cameras replayed: one for a one-finger detector, else all
    fps: float = 25.0  # the rate the run's frames were taken at
    model_fps: float = 25.0  # the rate the detector runs at (its sensor's)
    fps_from: str = ""  # where the run's rate was read (sensor.json, the video's stated rate, ...)

    def outcome(
        self, threshold: float, debounce: int = 1, horizon: int = HORIZON, startup: int = STARTUP
    ) -> GraspOutcome:
        """The run's verdict; ``horizon`` and ``startup`` count frames at the detector's rate (50 and 10
        at 25 frames/s: 2 s and 0.4 s), so a run taken at another rate is judged over the same time."""
        scale = self.fps / self.model_fps
        h, s = (horizon, startup) if scale == 1 else (max(1, round(horizon * scale)), round(startup * scale))
        return trace_outcome(self.probability, threshold, debounce, self.moment_of_slip, self.slipped, h, s, self.rest)


def summarise(outcomes: Sequence[GraspOutcome], fps: float = GELSIGHT_MINI.fps) -> dict[str, Any]:
    """Pool run outcomes into one row (without threshold/debounce). ``score`` = warned rate minus
    false-positive rate: 1 for a perfect detector, 0 for one that never alarms, -1 for one always on."""
    slip = [o for o in outcomes if o.outcome in ("warned", "premature", "missed")]
    held = [o for o in outcomes if o.outcome in ("false_positive", "clean")]
    leads = np.array([o.lead for o in slip if o.outcome == "warned"], dtype=float)
    warned = int(leads.size)
    fp = sum(o.outcome == "false_positive" for o in held)
    med = float(np.median(leads)) if leads.size else math.nan
    warned_rate = warned / len(slip) if slip else math.nan
    fp_rate = fp / len(held) if held else math.nan
    return {
        "slip_runs": len(slip),
        "warned": warned,
        "premature": sum(o.outcome == "premature" for o in slip),
        "missed": sum(o.outcome == "missed" for o in slip),
        "warned_rate": warned_rate,
        "median_lead_frames": med,
        "median_lead_ms": med * 1000.0 / fps,
        "held_runs": len(held),
        "false_positive_grasps": int(fp),
        "false_positive_rate": fp_rate,
        "held_alarm_fraction": float(np.mean([o.alarm_fraction for o in held])) if held else math.nan,
        "runs_alarming_at_rest": sum(o.rest_alarms > 0 for o in outcomes),
        "score": (0.0 if math.isnan(warned_rate) else warned_rate) - (0.0 if math.isnan(fp_rate) else fp_rate),
    }


def table(
    probabilities: Sequence[np.ndarray],
    moments: Sequence[int | None],
    thresholds: Sequence[float],
    debounces: Sequence[int] = (1,),
    horizon: int = HORIZON,
    startup: int = STARTUP,
    rests: Sequence[np.ndarray | None] | None = None,
    fps: float = GELSIGHT_MINI.fps,
    intervals: int = 0,
) -> list[dict[str, Any]]:
    """One row (``threshold``, ``debounce``, :func:`summarise`) per (threshold, debounce) over runs given as
    probability traces; with ``intervals`` bootstrap draws, also ``warned_low``/``warned_high`` and
    ``fp_low``/``fp_high``: 95% intervals over runs (:func:`bootstrap_rates`, the same draws for every row)."""
    rests = rests if rests is not None else [None] * len(probabilities)
    rows = []
    for k in debounces:
        for th in thresholds:
            outs = [
                grasp_outcome(debounce(p, th, k), m, horizon, startup, r)
                for p, m, r in zip(probabilities, moments, rests)
            ]
            rows.append({"threshold": float(th), "debounce": int(k), **summarise(outs, fps)})
            if intervals:
                ci = bootstrap_rates([o.outcome for o in outs], intervals)
                rows[-1].update({c: ci[c] for c in ("warned_low", "warned_high", "fp_low", "fp_high")})
    return rows


#: Thresholds the "at most K% of held grasps alarm" rule may also take: a class-balanced detector
#: puts many calm frames above 0.999.
FINE_TAIL = (0.9995, 0.9998, 0.9999)


def choose_operating_point(
    probabilities: Sequence[np.ndarray],
    moments: Sequence[int | None],
    thresholds: Sequence[float] | None = None,
    debounces: Sequence[int] = (1, 2, 3, 5),
    horizon: int = HORIZON,
    startup: int = STARTUP,
    max_held_alarm: float | None = None,
) -> dict[str, Any]:
    """The (threshold, debounce) to alarm at, chosen on these runs. Call it on training runs only
    (out-of-fold predictions of inner folds): choosing it on test runs is tuning on the test set.

    ``max_held_alarm`` None: the best :func:`summarise` score (warned rate minus false-positive
    rate; ties: the shortest debounce, then the middle of the tying thresholds, for a margin on both
    sides). ``max_held_alarm=K``: the rule a user states, "at most a fraction K of the grasps that
    hold may alarm": among the points whose false-positive grasps are at most ``K`` of the held runs,
    the one that warns in time of the most slips (ties: fewer false positives, fewer premature
    warnings, the shortest debounce, the middle threshold); when none is that quiet, the quietest.
    """
    if thresholds is None:
        thresholds = THRESHOLDS if max_held_alarm is None else tuple(sorted(set(THRESHOLDS) | set(FINE_TAIL)))
    rows = table(probabilities, moments, thresholds, debounces, horizon, startup)
    if max_held_alarm is None:
        top = max(round(r["score"], 9) for r in rows)
        tied = [r for r in rows if round(r["score"], 9) == top]
        rule = "best score (warned rate - false-positive rate)"
    else:
        if not 0.0 <= float(max_held_alarm) <= 1.0:
            raise ConfigError(f"max_held_alarm must be a fraction in [0, 1], got {max_held_alarm!r}")
        ok = [r for r in rows if r["false_positive_grasps"] <= max_held_alarm * r["held_runs"] + 1e-9]
        if not ok:
            least = min(r["false_positive_grasps"] for r in rows)
            ok = [r for r in rows if r["false_positive_grasps"] == least]
        key = lambda r: (r["warned"], -r["false_positive_grasps"], -r["premature"])  # noqa: E731
        top = max(key(r) for r in ok)
        tied = [r for r in ok if key(r) == top]
        rule = f"at most {100 * max_held_alarm:g}% of held grasps alarming"
    k = min(r["debounce"] for r in tied)
    tied = sorted((r for r in tied if r["debounce"] == k), key=lambda r: r["threshold"])
    best = tied[(len(tied) - 1) // 2]
    point = {"threshold": best["threshold"], "debounce": best["debounce"], "hold_s": HOLD_S}
    on_training_runs = {f"{k}_on_training_runs": best[k] for k in ("score", "warned_rate", "false_positive_rate")}
    return {**point, "horizon": horizon, "startup": startup, "rule": rule, **on_training_runs}


def bootstrap_rates(outcomes: Sequence[str], samples: int = 2000, seed: int = 0, level: float = 0.95) -> dict[str, Any]:
    """Bootstrap intervals over runs of the warned-in-time and false-positive rates of fixed
    outcomes (e.g. folds pooled, each at its own operating point): ``{"warned_low", "warned_high",
    "fp_low", "fp_high", "samples"}``."""
    rng = np.random.default_rng(seed)
    slip = np.array([o == "warned" for o in outcomes if o in ("warned", "premature", "missed")], dtype=float)
    held = np.array([o == "false_positive" for o in outcomes if o in ("false_positive", "clean")], dtype=float)
    lo, hi = 100 * (1 - level) / 2, 100 * (1 + level) / 2
    out: dict[str, Any] = {"samples": samples, "level": level}
    for name, hits in (("warned", slip), ("fp", held)):
        if not hits.size:
            out.update({f"{name}_low": math.nan, f"{name}_high": math.nan})
            continue
        means = hits[rng.integers(0, hits.size, (samples, hits.size))].mean(axis=1)
        out.update({f"{name}_low": float(np.percentile(means, lo)), f"{name}_high": float(np.percentile(means, hi))})
        # resampling none (or all) of n events gives a zero-width interval: the Wilson interval does not
        out[f"{name}_wilson"] = list(wilson(int(hits.sum()), hits.size))
    return out


def held_alarm_promise(alarmed: Sequence[bool], objects: Sequence[str]) -> dict[str, Any]:
    """What a held-alarm rate promises on objects not seen: the rate over these held grasps with the
    upper end of its 95% Wilson interval counting *objects*, not grasps, as the independent units.

    The grasps of one object share its surface, weight and the way it was grasped: when one alarms,
    others tend to. Counting each object as one trial, with the pooled rate (a design effect with
    the within-object correlation taken as 1), is the conservative reading: 0 alarms on 85 held
    grasps of 21 objects promises at most 15.5% on new objects, not the 4.3% that counting grasps
    gives. Both bounds are returned.

    Args:
        alarmed: ``(N,)`` whether each held grasp alarmed at the operating point.
        objects: ``(N,)`` each held grasp's object.
    """
    a, objs = np.asarray(alarmed, bool), np.asarray(objects)
    n, k = len(a), int(a.sum())
    units = len(np.unique(objs))
    rate = k / n if n else math.nan
    return {
        "held_grasps": n,
        "held_objects": units,
        "alarming": k,
        "rate": rate,
        "bound_counting_objects": wilson(rate * units, units)[1] if n else math.nan,
        "bound_counting_grasps": wilson(k, n)[1] if n else math.nan,
    }


def promise_text(op: Any) -> str:
    """What a checkpoint's operating point promises about held grasps, in one line, with where it was
    measured: ``held_alarm_unseen`` (held grasps of objects its family never saw, as ``adapt`` judged
    it) where there is one, else ``held_alarm`` (:func:`held_alarm_promise` on the grasps the operating
    point was chosen on); older checkpoints say what they have."""
    if not isinstance(op, dict):
        return "no operating point stored: nothing is promised about held grasps"
    unseen = op.get("held_alarm_unseen")
    if isinstance(unseen, dict) and unseen.get("held_grasps"):  # measured on objects it never saw: the promise
        h = unseen
        return (
            f"held grasps alarming on {h['measured_on']}: {100 * h['rate']:.1f}% ({h['alarming']} of "
            f"{h['held_grasps']}); on new objects at most {100 * h['bound_counting_objects']:.0f}% (95%, counting "
            f"each of the {h['held_objects']} objects with held grasps as one unit)"
        )
    h = op.get("held_alarm")
    if isinstance(h, dict) and h.get("held_grasps"):
        return (
            f"held grasps alarming: {100 * h['rate']:.1f}% ({h['alarming']} of {h['held_grasps']}) on "
            f"{op.get('chosen_on', 'the grasps it was chosen on')}; on new objects at most "
            f"{100 * h['bound_counting_objects']:.0f}% (95%, counting each of the {h['held_objects']} objects with held "
            "grasps as one unit)"
        )
    rate = op.get("false_positive_rate_on_training_runs")
    if isinstance(rate, (int, float)):
        return (
            f"held grasps alarming: {100 * rate:.1f}% on {op.get('chosen_on', 'its training runs')} "
            "(no bound counting objects stored: `slipsense calibrate` states one)"
        )
    return "nothing is promised about held grasps (no rate stored)"


def wilson(k: float, n: int, z: float = 1.959964) -> tuple[float, float]:
    """The 95% Wilson score interval of a rate of ``k`` events in ``n`` runs (``(0, 0.043)`` for 0 of 85)."""
    if n == 0:
        return (math.nan, math.nan)
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (max(0.0, centre - half), min(1.0, centre + half))


def early_warning_lines(g: Mapping[str, Any], context: Mapping[str, Any]) -> list[str]:
    """Warned in time / too early / missed, on the slips with a moment of slip; false alarms on held grasps."""
    horizon, fps = context.get("horizon"), context.get("fps")
    lines = []
    held = g["held_runs"]
    fp = f"False alarms: {g['false_positive_grasps']} of {plural(held, 'held grasp')} alarmed at some point."
    without = g.get("slips_without_moment", 0)
    if g["slip_runs"] == 0:
        if without:
            lines.append(
                "No slipped grasp has a moment of slip in these labels (they say only whether a grasp slipped, not "
                "when): the early-warning figures do not apply."
            )
        return lines + [fp]
    window = f"{horizon} frames" if horizon is not None else "the warning window"
    if horizon is not None and fps:
        window += f" = {horizon / fps:.1f} s"
    lead = g.get("median_lead_ms")
    lead_text = "" if lead is None or math.isnan(lead) else f"; median warning {lead:.0f} ms before the slip"
    lines.append(
        f"Early warning on the {plural(g['slip_runs'], 'slipped grasp')} whose moment of slip is known: "
        f"{g['warned']} warned in time (first alarm at most {window} before the object slipped away), "
        f"{g['premature']} too early (first alarm before that: the gripper would react to nothing), "
        f"{g['missed']} missed{lead_text}."
    )
    if without:
        lines.append(
            f"  {plural(without, 'more slipped grasp')} without a moment of slip found in the video: judged only as "
            "slipped or held above."
        )
    return lines + [fp]


@register("per_grasp", early_warning_lines, pools=False, rank=lambda g: g["warned_rate"], label="slips warned in time")
def per_grasp(judged: Judged) -> dict[str, Any]:
    """Slips warned in time / premature / missed, false-positive grasps, alarms at rest, lead times
    (:func:`summarise`), and ``slips_without_moment``: the slipped runs whose moment of slip was not
    found, counted in neither ``slip_runs`` nor ``held_runs``."""
    outcomes = [r.outcome(th, k, judged.horizon, judged.startup) for r, (th, k, _) in zip(judged.runs, judged.points)]
    return {**summarise(outcomes), "slips_without_moment": sum(o.outcome == "slip_without_moment" for o in outcomes)}
