"""Judge a detector as a gripper runs it: every run of a recordings folder replayed from its first
frame through the live detector, each run one per-grasp outcome (:mod:`slipsense.evaluation.pergrasp`).
``slipsense.evaluate`` is :func:`evaluate`."""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from slipsense.atomic import write_text
from slipsense.checkpoint import read_info
from slipsense.config import gelsight_recordings
from slipsense.data import label_runs
from slipsense.errors import InputError
from slipsense.evaluation import outcome, pergrasp
from slipsense.evaluation.baselines import baseline_scores
from slipsense.evaluation.early_warning import replay_recordings
from slipsense.evaluation.grasp_scores import clip_metrics, clip_scores
from slipsense.recordings.folders import SkippedInputWarning, camera_counts, find_recordings, validate_recordings
from slipsense.recordings.frame_folders import data_sensor
from slipsense.recordings.video import probe_video
from slipsense.resources import shipped_model
from slipsense.sensors.spec import sensor_of
from slipsense.streaming.detector import SlipDetector, shipped_name


def recordings_folder(recordings: str | Path | None) -> Path:
    return Path(recordings) if recordings is not None else gelsight_recordings()


def label_overrides(overrides: str | Path | None | bool) -> Path | None | bool:
    """As :func:`slipsense.data.label_runs` takes them: ``True`` (default) -> None (the shipped hand
    labels for runs of the shared recordings), ``False``/None -> False (none), else the CSV's path."""
    if overrides is True:
        return None
    return False if overrides is False or overrides is None else Path(overrides)


def shipped_for(recordings: str | Path | None) -> Path:
    """The shipped detector for a recordings folder (:func:`~slipsense.streaming.detector.shipped_name`):
    the one of its sensor where one is shipped (the frame size its ``sensor.json`` or layout states,
    else its first recording's), for one finger where its grasps have one camera each."""
    root = recordings_folder(recordings)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the evaluation that follows reports them
        found = find_recordings(root, on_error="skip")
    sensor = data_sensor(root)
    size = sensor.image_size if sensor is not None else None
    for rec in found if size is None else ():  # the first video that reads (the evaluation reports the others)
        try:
            info = probe_video(rec.path, expected_size=None)
        except InputError:
            continue
        size = (info.height, info.width)
        break
    if size is None:
        probe_video(found[0].path, expected_size=None)  # none reads: the first one's problem
    return shipped_model(shipped_name(1 if camera_counts(found) == [1] else 2, size))


@dataclass
class Evaluation:
    """What :func:`evaluate` returns: every run replayed as live use would, judged per grasp.

    Attributes:
        runs: one :class:`~slipsense.evaluation.early_warning.RunTrace` per replayed run (probabilities per frame).
        threshold, debounce, horizon: the operating point and horizon (frames) the outcomes use.
    """

    runs: list[Any]
    threshold: float
    debounce: int
    horizon: int = pergrasp.HORIZON
    labels: dict | None = None  # {(object, experiment, camera): VideoLabel} of the replayed videos
    recordings: list | None = None  # the replayed Recordings (their frames feed the baselines)
    startup: int = pergrasp.STARTUP  # leading frames never scored (0 for grasps labelled as a whole)

    def outcomes(self) -> list[pergrasp.GraspOutcome]:
        return [r.outcome(self.threshold, self.debounce, self.horizon, self.startup) for r in self.runs]

    def peak_scores(self) -> np.ndarray:
        """``(runs,)`` each run's :func:`~slipsense.evaluation.outcome.peak_alarm_score` at this
        debounce: it alarms somewhere at threshold t exactly when its score is >= t."""
        return np.array([outcome.peak_alarm_score(r.probability, self.debounce, self.startup) for r in self.runs])

    def grasp_measure(self, draws: int = outcome.BOOTSTRAP) -> dict[str, Any]:
        """Slipped against held grasps (:mod:`slipsense.evaluation.outcome`): the detector's ROC AUC,
        accuracy and balanced accuracy at its operating point and with thresholds chosen on the other
        objects, 95% intervals over objects; beside it the non-learned baselines
        (:mod:`slipsense.evaluation.baselines`) on the same frames, and where it does not beat them."""
        slipped = [r.slipped for r in self.runs]
        objects = [r.object for r in self.runs]
        score = self.peak_scores()
        alarmed = [v >= self.threshold for v in score]  # anywhere in the grasp, after the slip too
        detector = outcome.outcome_measure(score, slipped, objects, alarmed, draws)
        baselines = {"majority_class": outcome.majority_measure(slipped, objects, draws)}
        if self.recordings is not None:
            for name, s in baseline_scores(self.runs, self.recordings, self.labels or {}, self.startup).items():
                baselines[name] = outcome.outcome_measure(s, slipped, objects, None, draws)
        return {"detector": detector, "baselines": baselines, "not_beaten": outcome.beats(detector, baselines)}

    def summary(self) -> dict[str, Any]:
        """Slips warned in time / premature / missed, false-positive grasps, alarms at rest, lead times
        (:func:`~slipsense.evaluation.pergrasp.summarise`), and ``slips_without_moment``: the slipped
        runs whose moment of slip was not found, counted in neither ``slip_runs`` nor ``held_runs``
        (``slip_runs + slips_without_moment`` is every run that slipped)."""
        outcomes = self.outcomes()
        return {
            **pergrasp.summarise(outcomes),
            "slips_without_moment": sum(o.outcome == "slip_without_moment" for o in outcomes),
        }

    def clips(self, frames: int = 5) -> dict[str, Any]:
        """The papers' protocol on the same traces: every ``frames``-frame clip the project cuts from
        these runs, scored by the probability at its last frame, at the operating point and at 0.5
        (accuracy beside the always-wiggle baseline, balanced accuracy, precision, recall, F1)."""
        p, y = clip_scores(self.runs, [r.probability for r in self.runs], self.labels or {}, frames)
        return {"operating_point": clip_metrics(p, y, self.threshold), "at_0.5": clip_metrics(p, y, 0.5)}

    def frame_rates(self) -> dict[str, Any]:
        """The rate the detector runs at and the rates the runs were read at (frames per second),
        each with where it was read and how many runs: ``{"detector": 25.0, "recordings": [{"fps": 12.5,
        "from": ".../sensor.json", "runs": 26}]}``. Runs at another rate were resampled to the detector's clock."""
        counts: dict[tuple[float, str], int] = {}
        for r in self.runs:
            counts[(r.fps, r.fps_from)] = counts.get((r.fps, r.fps_from), 0) + 1
        detector = self.runs[0].model_fps if self.runs else math.nan
        return {"detector": detector, "recordings": [{"fps": f, "from": w, "runs": n} for (f, w), n in counts.items()]}

    def to_json(self, path: str | Path) -> Path:
        doc = {
            "threshold": self.threshold,
            "debounce": self.debounce,
            "horizon": self.horizon,
            "summary": self.summary(),
        }
        write_text(path, json.dumps(doc, indent=1, default=float))
        return Path(path)


def _whole_runs(found: Sequence[Any], kept: Sequence[Any]) -> list[Any]:
    """``kept`` without the runs that lost a camera video among ``found`` (skipped with
    ``on_error="skip"``), each named in a :class:`~slipsense.recordings.folders.SkippedInputWarning`:
    a detector on both fingers cannot judge a grasp from one."""
    have = {r.key for r in kept}
    broken = {}
    for r in found:
        if r.key not in have:
            broken.setdefault((r.object, r.experiment), (r.path.parent, r.path.name))
    for folder, name in broken.values():
        warnings.warn(
            f"{folder}: run left out, its video {name} was skipped and the detector needs every camera of a run",
            SkippedInputWarning,
            stacklevel=3,
        )
    return [r for r in kept if (r.object, r.experiment) not in broken]


def evaluate(
    checkpoint: str | Path | None = None,
    recordings: str | Path | None = None,
    *,
    overrides: str | Path | None | bool = True,
    horizon: int = pergrasp.HORIZON,
    threshold: float | None = None,
    debounce: int | None = None,
    progress: bool = True,
    objects: Sequence[str] | None = None,
    on_error: str = "raise",
) -> Evaluation:
    """Replay every run of a recordings folder through a detector, both sensors from the first frame.

    Args:
        checkpoint: default: the shipped detector.
        recordings: default: the shared GelSight recordings.
        overrides: label overrides CSV; True = the shipped hand labels for runs of the shared
            recordings; False = none.
        horizon: frames before the moment of slip in which an alarm counts as a warning in time.
        threshold, debounce: default: the checkpoint's operating point.
        objects: only the runs of these objects (default: every run).
        on_error: ``"raise"`` (default) or ``"skip"`` (leave out bad videos with a warning).

    A model trained on a fixed number of sensors (the grasp detectors) sees that many cameras per run
    (one: each camera is a grasp of its own); a clip model sees every camera of a run at once and
    alarms on either.
    """
    root = recordings_folder(recordings)
    path = checkpoint or shipped_for(root)
    info = read_info(path)
    calibrated = ((info.get("operating_point") or {}).get("calibrated") or {}).get("objects") or ()
    # another data set's objects are stored as <folder>/<object> (data.also): they count by their own name
    trained_on = {o.rsplit("/", 1)[-1] for o in ((info.get("data") or {}).get("objects")) or ()} | set(calibrated)
    found = find_recordings(root, on_error=on_error, sensor=sensor_of(info, path))
    recs = validate_recordings(found, on_error=on_error, expected_size=None)
    sensors = info["model_config"].get("sensors")
    if sensors != 1:  # a run replayed with all its cameras is left out whole where one was skipped
        recs = _whole_runs(found, recs)
    if objects is not None:
        recs = [r for r in recs if r.object in set(objects)]
    if not recs:
        raise InputError(root, "no recording left to judge (every one was skipped)")
    if not sensors:  # a clip model: every camera of a run at once
        counts = camera_counts(recs)
        if len(counts) != 1:
            raise InputError(root, f"runs hold different numbers of camera videos ({counts}); a replay needs the same")
        sensors = counts[0]
    detector = SlipDetector.from_checkpoint(
        path, sensors=sensors, threshold=threshold, debounce=debounce, backend="torch"
    )
    seen = sorted(trained_on & {r.object for r in recs})
    if seen:
        warnings.warn(
            f"the detector was trained or calibrated on {len(seen)} of these objects ({', '.join(seen[:5])}"
            f"{', ...' if len(seen) > 5 else ''}): their runs do not measure objects it never saw",
            stacklevel=2,
        )

    labels = label_runs(recs, label_overrides(overrides), on_error=on_error, progress=progress)
    recs = [r for r in recs if r.key in labels]  # left out by on_error="skip"
    runs = replay_recordings(detector, recs, labels, progress=progress, keep_without_moment=True)
    startup = 0 if recs and all(r.per_grasp for r in recs) else pergrasp.STARTUP
    return Evaluation(runs, detector.threshold, detector.debounce, horizon, labels, recs, startup)
