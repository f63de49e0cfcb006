"""Judge a detector as a gripper runs it: open it once, read the recordings once, replay every run once
from its first frame through the live detector, and hand the traces to every registered measure
(:mod:`slipsense.measures`). ``slipsense evaluate``, ``slipsense.evaluate``, ``calibrate``, ``adapt``
and the clip models' operating point all come through :func:`judge`."""

from __future__ import annotations

import json
import math
import warnings
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from slipsense.atomic import write_text
from slipsense.checkpoint import load_model
from slipsense.paths import gelsight_recordings
from slipsense.errors import InputError
from slipsense.evaluation.replay import replay_recordings
from slipsense.measures import MEASURES, Judged, measure_all, pergrasp, slipped_or_held
from slipsense.measures.baselines import NAMES, SIZE, frame_scores
from slipsense.recordings.clips import ClipSpec, plan_windows
from slipsense.recordings.folders import camera_counts
from slipsense.recordings.frame_cache import video_products
from slipsense.recordings.recording_set import Labelled, Recordings
from slipsense.recordings.video import probe_video
from slipsense.resources import shipped_model
from slipsense.sensors.spec import SensorSpec, sensor_of
from slipsense.streaming.detector import SlipDetector, shipped_name


def recordings_folder(recordings: str | Path | Recordings | Labelled | None) -> Path:
    """The folder of ``recordings`` (a set's own root), default the shared GelSight recordings."""
    if isinstance(recordings, (Recordings, Labelled)):
        return recordings.root
    return Path(recordings) if recordings is not None else gelsight_recordings()


def recordings_set(
    recordings: str | Path | Recordings | Labelled | None,
    sensor: SensorSpec | None = None,
    on_error: str = "raise",
    stated: SensorSpec | None = None,
) -> Recordings:
    """``recordings`` as a :class:`~slipsense.recordings.recording_set.Recordings` read as ``sensor``
    (None: the sensor the data states, or ``stated``, its user's): a given set as it is (nothing listed
    again), a folder scanned once (default: the shared GelSight recordings)."""
    given = isinstance(recordings, (Recordings, Labelled))
    return Recordings.of(recordings if given else recordings_folder(recordings), sensor, on_error, stated=stated)


def shipped_for(recordings: str | Path | Recordings | None) -> Path:
    """The shipped detector for a set of recordings (:func:`~slipsense.streaming.detector.shipped_name`):
    the one of its sensor where one is shipped (the frame size its ``sensor.json`` or layout states,
    else its first recording's), for one finger where its grasps have one camera each."""
    if isinstance(recordings, Labelled):
        recordings = recordings.recordings
    if not isinstance(recordings, Recordings):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the evaluation that follows reports them
            recordings = recordings_set(recordings, on_error="skip")
    found, sensor = recordings.listed, recordings.stated
    # frames carry no size of their own beyond their files; a video's container states its own
    size = sensor.image_size if sensor is not None and recordings.frames else None
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
    """What :func:`judge` returns: every run replayed as live use would, ready for every measure.

    Attributes:
        runs: one :class:`~slipsense.measures.pergrasp.RunTrace` per replayed run (probabilities per frame).
        threshold, debounce, hold_s, horizon: the operating point and horizon (frames) the measures use.
    """

    runs: list[Any]
    threshold: float
    debounce: int
    horizon: int  # frames at the detector's rate (judge() takes seconds)
    labels: dict | None = None  # {(object, experiment, camera): VideoLabel} of the replayed videos
    recordings: Recordings | None = None  # the replayed recordings (their frames feed the baselines)
    startup: int = pergrasp.STARTUP  # leading frames never scored (0 for grasps labelled as a whole)
    hold_s: float = 0.0
    checkpoint: Path | None = None  # the detector judged
    _results: dict = field(default_factory=dict, repr=False)

    def judged(self, keys: Sequence[str] = ()) -> Judged:
        """The runs as the measures take them; the baselines' frames and the short clips are read
        only where a measure of ``keys`` reads them (:attr:`~slipsense.measures.Measure.reads`)."""
        point, labels, base = (self.threshold, self.debounce, self.hold_s), self.labels or {}, None
        reads = {what for k in keys for what in MEASURES[k].reads}
        if "baselines" in reads and self.recordings is not None:
            base = baseline_scores(self.runs, self.recordings, labels, self.startup)
        clips = clip_scores(self.runs, [r.probability for r in self.runs], labels) if "clips" in reads else None
        return Judged(self.runs, [point] * len(self.runs), self.horizon, self.startup, base, clips)

    def measure(self, key: str) -> dict[str, Any] | None:
        """One registered measure's result (computed once)."""
        if key not in self._results:
            self._results.update(measure_all(self.judged([key]), [key]) or {key: None})
        return self._results[key]

    def measures(self) -> dict[str, Any]:
        """Every registered measure that applies: ``{key: result}``."""
        return {k: v for k in MEASURES if (v := self.measure(k)) is not None}

    def peak_scores(self) -> np.ndarray:
        """``(runs,)`` each run's :func:`~slipsense.measures.slipped_or_held.peak_alarm_score` at this
        debounce: it alarms somewhere at threshold t exactly when its score is >= t."""
        return np.array(
            [slipped_or_held.peak_alarm_score(r.probability, self.debounce, self.startup) for r in self.runs]
        )

    def grasp_measure(self, draws: int | None = None) -> dict[str, Any]:
        """Slipped against held grasps (:func:`slipsense.measures.slipped_or_held.grasp_measure`);
        ``draws``: bootstrap draws for its intervals (default: the registered measure's)."""
        if draws is None:
            return self.measure("grasp_measure")
        return slipped_or_held.grasp_measure(self.judged(["grasp_measure"]), draws)

    def per_grasp(self) -> dict[str, Any]:
        """Early warning per grasp (:func:`slipsense.measures.pergrasp.per_grasp`); every measure:
        :meth:`measures`."""
        return self.measure("per_grasp")

    def frame_rates(self) -> dict[str, Any]:
        """The rate the detector runs at and the rates the runs were read at (frames per second),
        each with where it was read and how many runs: ``{"detector": 25.0, "recordings": [{"fps": 12.5,
        "from": ".../sensor.json", "runs": 26}]}``. Runs at another rate were resampled to the detector's clock."""
        counts = Counter((r.fps, r.fps_from) for r in self.runs)
        detector = self.runs[0].model_fps if self.runs else math.nan
        return {"detector": detector, "recordings": [{"fps": f, "from": w, "runs": n} for (f, w), n in counts.items()]}

    def to_dict(self) -> dict[str, Any]:
        """The operating point, the rates, every measure under its key and each run's outcome."""
        at = (self.threshold, self.debounce, self.horizon, self.startup)
        return {
            "threshold": self.threshold,
            "debounce": self.debounce,
            "horizon": self.horizon,
            "frame_rate": self.frame_rates(),
            **self.measures(),
            "runs": [{**pergrasp.run_fields(r), **asdict(r.outcome(*at))} for r in self.runs],
        }

    def to_json(self, path: str | Path) -> Path:
        """:meth:`to_dict` written to ``path`` (atomically)."""
        write_text(path, json.dumps(self.to_dict(), indent=1, default=float))
        return Path(path)


def clip_scores(
    runs: Sequence[Any], probs: Sequence[np.ndarray], labels: dict, frames: int = 5
) -> tuple[np.ndarray, np.ndarray]:
    """The paper's clip protocol on per-frame traces: every ``frames``-frame clip the project cuts
    (:func:`slipsense.recordings.clips.plan_windows`: the clip ending right before the moment of
    slip, two wiggle windows per video of a run that held) is scored by the detector's probability
    at its last frame. Returns ``(p, y)``; a run's cameras share one fused trace, so both cameras'
    clips of a run get the probability of their own end frames."""
    spec = ClipSpec(frames=frames)
    p, y = [], []
    for run, trace in zip(runs, probs):
        for cam in run.cameras:
            label = labels.get((run.object, run.experiment, cam))
            if label is None:
                continue
            for w in plan_windows(label, spec):
                p.append(trace[w.end])
                y.append(w.y)
    return np.asarray(p, dtype=np.float64), np.asarray(y, dtype=np.int64)


def baseline_scores(runs: Sequence, recordings: Sequence, labels: Mapping, start: int = 0) -> dict[str, np.ndarray]:
    """``{name: (len(runs),) scores}`` for replayed ``runs`` (each with ``object``, ``experiment``,
    ``cameras``), reading the frames of ``recordings`` and the contact starts of ``labels``."""
    by_key = {r.key: r for r in recordings}
    product = f"gray:{SIZE[0]}x{SIZE[1]}"
    out = {name: np.zeros(len(runs)) for name in NAMES}
    for i, run in enumerate(runs):
        for camera in run.cameras:
            rec = by_key[(run.object, run.experiment, camera)]
            label = labels.get(rec.key)
            gray = video_products(rec.path, [product])[product]
            scores = frame_scores(gray, getattr(label, "contact_start", 0), start)
            for name in NAMES:
                out[name][i] = max(out[name][i], scores[name])
    return out


def judge(
    checkpoint: str | Path | None = None,
    recordings: str | Path | Recordings | None = None,
    *,
    overrides: str | Path | None | bool = None,
    horizon: float = pergrasp.HORIZON_S,
    threshold: float | None = None,
    debounce: int | None = None,
    progress: bool = True,
    objects: Sequence[str] | None = None,
    on_error: str = "raise",
    loaded: tuple[Any, Mapping[str, Any]] | None = None,
    sensor: SensorSpec | None = None,
) -> Evaluation:
    """Replay every run of a recordings folder through a detector, both sensors from the first frame.

    Args:
        checkpoint: default: the shipped detector for the recordings (:func:`shipped_for`).
        recordings: a :class:`~slipsense.recordings.recording_set.Recordings` or its folder (read once
            here); default: the shared GelSight recordings.
        overrides: None (default) = the shipped hand labels for runs of the shared recordings
            (:mod:`~slipsense.recordings.labels`; True says the same); False = none; else a CSV.
        horizon: seconds before the moment of slip in which an alarm counts as a warning in time.
        threshold, debounce: default: the checkpoint's operating point.
        objects: only the runs of these objects (default: every run).
        on_error: ``"raise"`` (default) or ``"skip"`` (leave out bad videos with a warning).
        loaded: ``(model, info)`` of ``checkpoint`` where the caller loaded it already.
        sensor: the sensor the recordings were taken with, where they state none (a user's ``--sensor``:
            a frame folder's rate, the shipped detector's choice); None: the data's own statement.

    The checkpoint is opened once and the folder scanned once. A model trained on a fixed number of
    sensors (the grasp detectors) sees that many cameras per run (one: each camera is a grasp of its
    own); a clip model sees every camera of a run at once and alarms on either.
    """
    root, scanned = recordings_folder(recordings), None
    if checkpoint is None:  # the folder says which shipped detector: read as the sensor it states
        scanned = recordings_set(recordings, None, on_error, stated=sensor)
    path = Path(checkpoint) if checkpoint is not None else shipped_for(scanned)
    model, info = loaded if loaded is not None else load_model(path)
    calibrated = ((info.get("operating_point") or {}).get("calibrated") or {}).get("objects") or ()
    # another data set's objects are stored as <folder>/<object> (data.also): they count by their own name
    trained_on = {o.rsplit("/", 1)[-1] for o in ((info.get("data") or {}).get("objects")) or ()} | set(calibrated)
    sensors = info["model_config"].get("sensors")
    if isinstance(recordings, Labelled):  # labelled by the caller: judged as it is
        data = recordings if objects is None else recordings.only(objects)
    else:  # the detector's file layout, one listing; a run replayed with all its cameras is left out whole where one was skipped
        read = recordings_set(scanned or recordings, sensor_of(info, path), on_error, stated=sensor)
        read = read if objects is None else read.subset(objects)
        if not read.listed:
            raise InputError(root, "no recording left to judge (none of the objects asked for)")
        data = read.labelled(overrides, whole_runs=sensors != 1, progress=progress, on_error=on_error)
    if not sensors:  # a clip model: every camera of a run at once
        counts = camera_counts(data)
        if len(counts) != 1:
            raise InputError(root, f"runs hold different numbers of camera videos ({counts}); a replay needs the same")
        sensors = counts[0]
    detector = SlipDetector.from_checkpoint(
        path, sensors=sensors, threshold=threshold, debounce=debounce, backend="torch", loaded=(model, info)
    )
    seen = sorted(trained_on & set(data.objects))
    if seen:
        warnings.warn(
            f"the detector was trained or calibrated on {len(seen)} of these objects ({', '.join(seen[:5])}"
            f"{', ...' if len(seen) > 5 else ''}): their runs do not measure objects it never saw",
            stacklevel=2,
        )
    recs, labels, replayed = list(data), dict(data.labels), data.recordings
    runs = replay_recordings(detector, replayed, labels, progress=progress, keep_without_moment=True)
    startup = 0 if recs and all(r.per_grasp for r in recs) else pergrasp.startup_frames(detector.sensor.fps)
    horizon = pergrasp.horizon_frames(detector.sensor.fps, horizon)  # the measures count the detector's frames
    return Evaluation(
        runs, detector.threshold, detector.debounce, horizon, labels, replayed, startup, detector.hold, path
    )
