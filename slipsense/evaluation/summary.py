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

from typing import Any, Mapping

from slipsense.measures import measure_lines
from slipsense.measures.pergrasp import early_warning_lines
from slipsense.measures.registry import pct as _pct
from slipsense.measures.registry import plural as _plural


def alarm_rule(threshold: float, debounce: int) -> str:
    """The operating point in words: ``"slip probability at or above 0.9 for 2 frames in a row"``."""
    frames = "1 frame" if debounce == 1 else f"{debounce} frames in a row"
    return f"slip probability at or above {threshold:.3g} for {frames}"


def rate_lines(rate: Mapping[str, Any] | None) -> list[str]:
    """The rates the runs were read at and the detector's, in words (:meth:`Evaluation.frame_rates
    <slipsense.evaluation.judge.Evaluation.frame_rates>`)."""
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


def _grasp_detector_lines(m: Mapping[str, Any], fps: float | None) -> list[str]:
    """The runs and the alarm rule, then every registered measure's sentences (:mod:`slipsense.measures`)."""
    d = m["grasp_measure"]["detector"]
    return [
        f"per grasp: {d['slipped']} of {d['grasps']} grasps slipped, {d['objects']} objects "
        f"({d['grasps'] - d['slipped']} held).",
        f"Alarm: {alarm_rule(m['threshold'], m['debounce'])}.",
        *rate_lines(m.get("frame_rate")),
        *measure_lines(m, {"horizon": m.get("horizon"), "fps": fps}),
    ]


def _clip_model_lines(m: Mapping[str, Any], fps: float | None) -> list[str]:
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
    return lines + early_warning_lines(g, {"horizon": g.get("horizon"), "fps": fps})


def summary_lines(metrics: Mapping[str, Any], fps: float | None = None) -> list[str]:
    """The evaluation's result as lines of plain text (no JSON), every count as the result holds it.

    Args:
        metrics: what :func:`slipsense.evaluation.checkpoints.evaluate_checkpoint` returns: a grasp detector's
            (``per_grasp``, ``grasp_measure``, ``clips``, ``threshold``, ``debounce``, ``horizon``) or a clip
            or marker model's (``accuracy``, ``confusion``, ``n_clips``, ... and ``per_grasp`` where its
            runs were replayed).
        fps: frames per second, to state the warning window in seconds (default: the detector's rate
            the result records; where it records none, the window is stated in frames only).
    """
    if fps is None:  # the horizon counts frames of the detector's clock
        rate = metrics.get("frame_rate") or (metrics.get("per_grasp") or {}).get("frame_rate") or {}
        fps = rate.get("detector") or None
    if "grasp_measure" in metrics:
        return _grasp_detector_lines(metrics, fps)
    return _clip_model_lines(metrics, fps)


__all__ = ["alarm_rule", "rate_lines", "summary_lines"]
