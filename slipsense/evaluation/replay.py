"""Judge a detector as a gripper runs it: every run of a recordings folder replayed from its first
frame through the live detector, each run one per-grasp outcome (:mod:`slipsense.evaluation.pergrasp`).
``slipsense.evaluate`` is :func:`evaluate`."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from slipsense.config import gelsight_recordings
from slipsense.evaluation import pergrasp


def recordings_folder(recordings: str | Path | None) -> Path:
    return Path(recordings) if recordings is not None else gelsight_recordings()


def label_overrides(overrides: str | Path | None | bool) -> Path | None | bool:
    """As :func:`slipsense.data.label_runs` takes them: ``True`` (default) -> None (the shipped hand
    labels for runs of the shared recordings), ``False``/None -> False (none), else the CSV's path."""
    if overrides is True:
        return None
    return False if overrides is False or overrides is None else Path(overrides)


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

    def outcomes(self) -> list[pergrasp.GraspOutcome]:
        return [r.outcome(self.threshold, self.debounce, self.horizon) for r in self.runs]

    def summary(self) -> dict[str, Any]:
        """Slips warned in time / premature / missed, false-positive grasps, alarms at rest, lead times."""
        return pergrasp.summarise(self.outcomes())

    def clips(self, frames: int = 5) -> dict[str, Any]:
        """The papers' protocol on the same traces: every ``frames``-frame clip the project cuts from
        these runs, scored by the probability at its last frame, at the operating point and at 0.5
        (accuracy beside the always-wiggle baseline, balanced accuracy, precision, recall, F1)."""
        from slipsense.evaluation.grasp_scores import clip_metrics, clip_scores

        p, y = clip_scores(self.runs, [r.probability for r in self.runs], self.labels or {}, frames)
        return {"operating_point": clip_metrics(p, y, self.threshold), "at_0.5": clip_metrics(p, y, 0.5)}

    def to_json(self, path: str | Path) -> Path:
        from slipsense.atomic import write_text

        doc = {
            "threshold": self.threshold,
            "debounce": self.debounce,
            "horizon": self.horizon,
            "summary": self.summary(),
        }
        write_text(path, json.dumps(doc, indent=1, default=float))
        return Path(path)


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
    from slipsense.evaluation.early_warning import replay_recordings
    from slipsense.streaming.detector import SlipDetector
    from slipsense.recordings.folders import camera_counts, find_recordings, validate_recordings

    import warnings

    from slipsense.checkpoint import read_info
    from slipsense.resources import shipped_model

    from slipsense.errors import InputError
    from slipsense.sensors.spec import sensor_of

    root = recordings_folder(recordings)
    path = checkpoint or shipped_model()
    info = read_info(path)
    trained_on = set(((info.get("data") or {}).get("objects")) or ())
    found = find_recordings(root, on_error=on_error, sensor=sensor_of(info, path))
    recs = validate_recordings(found, on_error=on_error, expected_size=None)
    if objects is not None:
        recs = [r for r in recs if r.object in set(objects)]
    sensors = info["model_config"].get("sensors")
    if not sensors:  # a clip model: every camera of a run at once
        counts = camera_counts(recs)
        if len(counts) != 1:
            raise InputError(root, f"runs hold different numbers of camera videos ({counts}); a replay needs the same")
        sensors = counts[0]
    detector = (
        SlipDetector.pretrained(sensors=sensors, threshold=threshold, debounce=debounce, backend="torch")
        if checkpoint is None
        else SlipDetector.from_checkpoint(
            checkpoint, sensors=sensors, threshold=threshold, debounce=debounce, backend="torch"
        )
    )
    seen = sorted(trained_on & {r.object for r in recs})
    if seen:
        warnings.warn(
            f"the detector was trained on {len(seen)} of these objects ({', '.join(seen[:5])}"
            f"{', ...' if len(seen) > 5 else ''}): their runs do not measure objects it never saw",
            stacklevel=2,
        )
    from slipsense.data import label_runs

    labels = label_runs(recs, label_overrides(overrides), on_error=on_error, progress=progress)
    recs = [r for r in recs if r.key in labels]  # left out by on_error="skip"
    runs = replay_recordings(detector, recs, labels, progress=progress)
    return Evaluation(runs, detector.threshold, detector.debounce, horizon, labels)
