"""What ``slipsense evaluate`` prints: its metrics in a few sentences a robot builder reads.

:func:`summary_lines` takes the dictionary the evaluation returns (and writes as JSON with
``--json``) and says only what the labels support:

* every grasp labelled slipped or held: how well the detector tells the two apart, beside simple
  rules that learn nothing;
* slipped grasps whose moment of slip is known (found in the video): how many were warned of in
  time, too early or not at all; where no grasp has a moment of slip (grasps labelled as a whole,
  e.g. the shared ``gelsight-lift`` data) the early-warning figures are left out and the lines say so;
* short clips (the published papers' measure): only where some clip ends before a slip and some
  comes from a grasp that held; otherwise accuracy over clips of one kind says nothing.

Every count printed is a count of the dictionary, under the name the JSON gives it, so the two
always agree.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

from slipsense.sensors.spec import GELSIGHT_MINI

#: Plain words for the baselines of :meth:`slipsense.evaluation.replay.Evaluation.grasp_measure`.
BASELINE_WORDS = {
    "majority_class": "always answers the outcome most grasps of the other objects had",
    "frame_difference": "the largest change between consecutive frames",
    "mean_frame_difference": "the mean change between consecutive frames",
    "difference_to_contact": "the largest change from the first frame of contact",
}


def _pct(value: float) -> str:
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{100 * value:.0f}%"


def _with_range(m: Mapping[str, Any] | None, percent: bool = True) -> str:
    """``{"value", "interval"}`` -> ``"83% (95% range 70-95%)"``."""
    if not m:
        return "n/a"
    v, (lo, hi) = m["value"], m["interval"]
    if v is None or math.isnan(v):
        return "n/a"
    if percent:
        if math.isnan(lo) or math.isnan(hi):
            return _pct(v)
        return f"{_pct(v)} (95% range {100 * lo:.0f}-{100 * hi:.0f}%)"
    if math.isnan(lo) or math.isnan(hi):
        return f"{v:.2f}"
    return f"{v:.2f} (95% range {lo:.2f}-{hi:.2f})"


def _plural(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


def alarm_rule(threshold: float, debounce: int) -> str:
    """The operating point in words: ``"slip probability at or above 0.9 for 2 frames in a row"``."""
    frames = "1 frame" if debounce == 1 else f"{debounce} frames in a row"
    return f"slip probability at or above {threshold:.3g} for {frames}"


def _telling_apart(measure: Mapping[str, Any]) -> list[str]:
    """Slipped against held grasps: the detector's figures, then the baselines'."""
    d = measure["detector"]
    own = (d.get("operating_point") or {}).get("accuracy")
    loo = (d.get("leave_objects_out") or {}).get("accuracy")
    lines = [
        "Telling slipped grasps from held ones (ranking: 50% = chance, 100% = every slipped grasp scored above "
        "every held one; 95% ranges: objects drawn again at random):",
        f"  detector: ranking {_with_range(d['roc_auc'])}; right on {_with_range(own)} of grasps at its own "
        "alarm threshold",
    ]
    if loo:
        lines.append(
            f"            right on {_with_range(loo)} with each object's threshold chosen on the other objects only"
        )
    for name, b in measure.get("baselines", {}).items():
        b_loo = (b.get("leave_objects_out") or {}).get("accuracy")
        words = BASELINE_WORDS.get(name, "a rule that learns nothing")
        lines.append(
            f"  baseline {name} ({words}): ranking {_pct(b['roc_auc']['value'])}, right on "
            f"{_pct(b_loo['value']) if b_loo else 'n/a'} with thresholds chosen on the other objects"
        )
    lines += _not_beaten(d, measure.get("baselines", {}))
    return lines


def _not_beaten(d: Mapping[str, Any], baselines: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """One line per baseline the detector does not beat, as :func:`slipsense.evaluation.outcome.beats`
    judges it (the ``not_beaten`` sentences of the JSON)."""
    lines = []
    for name, b in baselines.items():
        said = []
        if not d["roc_auc"]["value"] > b["roc_auc"]["value"]:
            said.append(f"ranking {_pct(d['roc_auc']['value'])} against {_pct(b['roc_auc']['value'])}")
        mine, theirs = d.get("leave_objects_out"), b.get("leave_objects_out")
        if mine and theirs and not mine["accuracy"]["value"] > theirs["accuracy"]["value"]:
            said.append(
                f"right on {_pct(mine['accuracy']['value'])} against {_pct(theirs['accuracy']['value'])} "
                "with thresholds chosen on the other objects"
            )
        if said:
            lines.append(f"  the detector does not beat {name}: {'; '.join(said)}")
    return lines


def rate_lines(rate: Mapping[str, Any] | None) -> list[str]:
    """The rates the runs were read at and the detector's, in words (:meth:`Evaluation.frame_rates
    <slipsense.evaluation.replay.Evaluation.frame_rates>`)."""
    if not rate or not rate.get("recordings"):
        return []
    model = rate["detector"]
    read = "; ".join(
        f"{r['fps']:g} frames/s ({r['from']}{'' if len(rate['recordings']) == 1 else ', ' + _plural(r['runs'], 'run')})"
        for r in rate["recordings"]
    )
    other = any(abs(r["fps"] - model) > 1e-6 * model for r in rate["recordings"])
    tail = ": frames taken at another rate are resampled to its clock" if other else ""
    return [f"Frame rate: read at {read}; the detector runs at {model:g} frames/s{tail}."]


def _early_warning(g: Mapping[str, Any], slipped: int, horizon: int | None, fps: float) -> list[str]:
    """Warned in time / too early / missed, on the slips with a moment of slip; false alarms on held grasps."""
    lines = []
    held = g["held_runs"]
    fp = f"False alarms: {g['false_positive_grasps']} of {_plural(held, 'held grasp')} alarmed at some point."
    without = g.get("slips_without_moment", 0)
    if g["slip_runs"] == 0:
        if slipped:
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
        f"Early warning on the {_plural(g['slip_runs'], 'slipped grasp')} whose moment of slip is known: "
        f"{g['warned']} warned in time (first alarm at most {window} before the object slipped away), "
        f"{g['premature']} too early (first alarm before that: the gripper would react to nothing), "
        f"{g['missed']} missed{lead_text}."
    )
    if without:
        lines.append(
            f"  {_plural(without, 'more slipped grasp')} without a moment of slip found in the video: judged only as "
            "slipped or held above."
        )
    return lines + [fp]


def _clip_lines(c: Mapping[str, Any], frames: int = 5) -> list[str]:
    """The papers' clip figures (:func:`slipsense.evaluation.grasp_scores.clip_metrics`), only where
    both kinds of clip are there."""
    n, slip = c["clips"], c["slip_clips"]
    if slip == 0 or slip == n:
        return [
            f"Short clips: all {n} clips are {'slip' if slip else 'no-slip'} clips, so clip accuracy says nothing "
            "here and is left out."
        ]
    return [
        f"Short clips ({frames} frames, as published papers measure): {n} clips, {slip} ending just before a slip; "
        f"right on {_pct(c['accuracy'])} (calling every clip no-slip would be right on "
        f"{_pct(c['always_wiggle_accuracy'])}); mean of the rates on slip and no-slip clips {_pct(c['balanced_accuracy'])}; "
        f"F1 {c['f1']:.2f} (balance of precision {_pct(c['precision'])}, recall {_pct(c['recall'])})."
    ]


def _grasp_detector_lines(m: Mapping[str, Any], fps: float) -> list[str]:
    measure, g = m["grasp_measure"], m["per_grasp"]
    d = measure["detector"]
    lines = [
        f"per grasp: {d['slipped']} of {d['grasps']} grasps slipped, {d['objects']} objects "
        f"({d['grasps'] - d['slipped']} held).",
        f"Alarm: {alarm_rule(m['threshold'], m['debounce'])}.",
        *rate_lines(m.get("frame_rate")),
        *_telling_apart(measure),
        *_early_warning(g, d["slipped"], m.get("horizon"), fps),
    ]
    if g["slip_runs"] > 0:
        lines += _clip_lines(m["clips"]["operating_point"])
    return lines


def _clip_model_lines(m: Mapping[str, Any], fps: float) -> list[str]:
    (tn, fp), (fn, tp) = m["confusion"]
    n, slip, wiggle = m["n_clips"], m["n_slip"], m["n_wiggle"]
    lines = [f"{n} clips: {slip} ending just before a slip, {wiggle} from grasps that held (no-slip)."]
    if slip == 0 or wiggle == 0:
        lines.append(
            f"All clips are of one kind, so accuracy, precision and recall say nothing here: the model called "
            f"{fp + tp} of {n} clips a slip."
        )
    else:
        lines.append(
            f"At slip probability {m['threshold']:.3g}: right on {_pct(m['accuracy'])} of clips (calling every clip "
            f"no-slip would be right on {_pct(wiggle / n)}); {tp} of {slip} slip clips caught (recall "
            f"{_pct(m['recall'])}), {fp} of {wiggle} no-slip clips called a slip (precision {_pct(m['precision'])}, "
            f"F1 {m['f1']:.2f}: the balance of the two)."
        )
    g = m.get("per_grasp")
    if g is None:
        return lines
    if "skipped" in g:
        return lines + [f"Whole grasps: not replayed ({g['skipped']})."]
    slipped = g["slip_runs"] + g.get("slips_without_moment", 0)
    lines.append(
        f"Whole grasps replayed as a gripper runs the model: {slipped} of {slipped + g['held_runs']} grasps slipped. "
        f"Alarm: {alarm_rule(g['threshold'], g['debounce'])}."
    )
    lines += rate_lines(g.get("frame_rate"))
    return lines + _early_warning(g, slipped, g.get("horizon"), fps)


def summary_lines(metrics: Mapping[str, Any], fps: float | None = None) -> list[str]:
    """The evaluation's result as lines of plain text (no JSON), every count as the result holds it.

    Args:
        metrics: what :func:`slipsense.training.recipe.evaluate` returns: a grasp detector's
            (``per_grasp``, ``grasp_measure``, ``clips``, ``threshold``, ``debounce``, ``horizon``) or a clip
            or marker model's (``accuracy``, ``confusion``, ``n_clips``, ... and ``per_grasp`` where its
            runs were replayed).
        fps: frames per second, to state the warning window in seconds (default: the GelSight Mini's).
    """
    if fps is None:  # the horizon counts frames of the detector's clock
        rate = metrics.get("frame_rate") or (metrics.get("per_grasp") or {}).get("frame_rate") or {}
        fps = rate.get("detector") or GELSIGHT_MINI.fps
    if "grasp_measure" in metrics:
        return _grasp_detector_lines(metrics, fps)
    return _clip_model_lines(metrics, fps)


__all__ = ["BASELINE_WORDS", "alarm_rule", "rate_lines", "summary_lines"]
