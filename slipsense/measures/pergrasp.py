"""Per-grasp early warning: how a robot builder judges a slip detector.

A detector is replayed over whole runs from the first frame, exactly as it would run live, and each
run gets one outcome. With ``m`` the moment of slip (last frame before contact is lost), ``H`` the
warning horizon and ``S`` the camera start-up (not the scene, never scored), both given in seconds
(:data:`~slipsense.measures.registry.HORIZON_S`, :data:`~slipsense.measures.registry.STARTUP_S`) and
counted here in frames at the run's rate:

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

from slipsense.alarm import debounce  # the alarm rule every outcome is judged by
from slipsense.errors import ConfigError
from slipsense.measures.promise import wilson
from slipsense.measures.registry import Judged, horizon_frames, plural, register, startup_frames
from slipsense.measures.registry import HORIZON_S, STARTUP_S  # noqa: F401  (the times, beside their measure)

#: Frame counts (2 s and 0.4 s at 25 frames/s) kept only for the training settings that still state
#: their horizon and start-up in frames; everything judged takes seconds at its own rate.
HORIZON = 50
STARTUP = 10


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
    horizon: int,
    startup: int,
    rest: np.ndarray | None = None,
) -> GraspOutcome:
    """Score one run.

    Args:
        alarm: ``(N,)`` bool, the detector's alarm at every frame of the recording.
        moment: the moment of slip, or None for a run that held.
        horizon: frames before the moment in which a first alarm is a warning in time
            (:func:`~slipsense.measures.registry.horizon_frames` at the alarm's rate).
        startup: leading frames not scored (:func:`~slipsense.measures.registry.startup_frames`).
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
    horizon: int,
    startup: int,
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
    fps: float | None = None  # the rate the run's frames were taken at (required)
    model_fps: float | None = None  # the rate the detector runs at (its sensor's; None: the run's)
    fps_from: str = ""  # where the run's rate was read (sensor.json, the video's stated rate, ...)

    def __post_init__(self) -> None:
        # a rate left out would be a guess, and every time (the horizon, the leads) is read with it
        if self.fps is None:
            raise ConfigError(f"run {self.object} {self.experiment}: the rate its frames were taken at (fps) is needed")
        if self.model_fps is None:
            self.model_fps = self.fps

    def outcome(
        self, threshold: float, debounce: int = 1, horizon: int | None = None, startup: int | None = None
    ) -> GraspOutcome:
        """The run's verdict; ``horizon`` and ``startup`` count frames at the detector's rate (None:
        :data:`~slipsense.measures.registry.HORIZON_S` and ``STARTUP_S`` at that rate), so a run taken
        at another rate is judged over the same time."""
        horizon = horizon_frames(self.model_fps) if horizon is None else horizon
        startup = startup_frames(self.model_fps) if startup is None else startup
        scale = self.fps / self.model_fps
        h, s = (horizon, startup) if scale == 1 else (max(1, round(horizon * scale)), round(startup * scale))
        return trace_outcome(self.probability, threshold, debounce, self.moment_of_slip, self.slipped, h, s, self.rest)


def summarise(outcomes: Sequence[GraspOutcome], fps: float | Sequence[float]) -> dict[str, Any]:
    """Pool run outcomes into one row (without threshold/debounce). ``score`` = warned rate minus
    false-positive rate: 1 for a perfect detector, 0 for one that never alarms, -1 for one always on.
    ``fps``: the rate the outcomes' frames count at (one for all, or one per outcome): the leads in
    milliseconds are read with it."""
    rates = np.broadcast_to(np.asarray(fps, dtype=float), (len(outcomes),))
    slip = [o for o in outcomes if o.outcome in ("warned", "premature", "missed")]
    held = [o for o in outcomes if o.outcome in ("false_positive", "clean")]
    warned_at = [(o.lead, f) for o, f in zip(outcomes, rates) if o.outcome == "warned"]
    leads = np.array([lead for lead, _ in warned_at], dtype=float)
    lead_ms = np.array([1000.0 * lead / f for lead, f in warned_at], dtype=float)
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
        "median_lead_ms": float(np.median(lead_ms)) if lead_ms.size else math.nan,
        "held_runs": len(held),
        "false_positive_grasps": int(fp),
        "false_positive_rate": fp_rate,
        "held_alarm_fraction": float(np.mean([o.alarm_fraction for o in held])) if held else math.nan,
        "runs_alarming_at_rest": sum(o.rest_alarms > 0 for o in outcomes),
        "score": (0.0 if math.isnan(warned_rate) else warned_rate) - (0.0 if math.isnan(fp_rate) else fp_rate),
    }


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
    rates = [r.fps for r in judged.runs]  # a run's lead counts frames at the rate it was taken at
    return {
        **summarise(outcomes, rates),
        "slips_without_moment": sum(o.outcome == "slip_without_moment" for o in outcomes),
    }
