"""Replay recordings through a streaming detector, every run from its first frame, for judging it per grasp.

Every run is replayed from its first frame with all its cameras, exactly as the live detector
would see it (:meth:`slipsense.streaming.detector.SlipDetector.replay`), then scored with
:mod:`slipsense.measures.pergrasp`: slips warned in time (first alarm within ``horizon`` frames before the
moment of slip), premature and missed; grasps that held yet alarmed; alarms while no gel is
touched. One row per alarm threshold, at the detector's debounce.

An earlier version of this report counted an alarm held since the grasp as a warning and counted
false alarms as rising edges, so that a detector always on scored well; the tests now hold the
opposite.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from slipsense.errors import InputError
from slipsense.measures.pergrasp import RunTrace
from slipsense.progress import progress_bar
from slipsense.recordings.contact import rest_mask
from slipsense.recordings.frame_cache import video_products
from slipsense.recordings.recording_set import Recordings
from slipsense.recordings.video import read_video


def replay_recordings(
    detector,
    recordings: Recordings,
    labels: Mapping[tuple, Any],
    progress: bool = True,
    limit: int | None = None,
    keep_without_moment: bool = False,
) -> list[RunTrace]:
    """Replay every run (all cameras of an experiment as the detector's sensors) through ``detector``.

    Args:
        detector: a :class:`~slipsense.streaming.detector.SlipDetector` on video frames or on the
            cameras' tracked markers (a marker model); ``sensors`` = cameras per run.
        recordings: the :class:`~slipsense.recordings.recording_set.Recordings` to replay (each run's
            rate read from it).
        labels: ``{(object, experiment, camera): VideoLabel}``
            (:func:`slipsense.recordings.labels.label_runs`).
        limit: replay at most this many runs (in sorted order).
        keep_without_moment: replay slipped runs without a moment of slip too (grasps labelled as a
            whole, judged by :mod:`slipsense.measures.slipped_or_held`); by default they are left out
            (nothing to warn of).
    """
    detector.model.check_video_replay(detector.geometry)
    runs = recordings.runs()
    keys = list(runs)[:limit] if limit is not None else list(runs)
    out = []
    for key in progress_bar(keys, progress, "replaying runs"):
        cams = runs[key]
        # one finger: each camera is a grasp of its own
        for group in [[c] for c in cams] if detector.sensors == 1 and len(cams) > 1 else [cams]:
            trace = _replay_run(detector, key, group, cams, labels, keep_without_moment, recordings.rate(group[0]))
            if trace is not None:
                out.append(trace)
    return out


def _replay_run(detector, key, cams, run_cams, labels, keep, rate) -> RunTrace | None:
    """One run (or one camera of it) replayed; None for a slip without a moment of slip. ``rate``:
    ``(fps, where it was read)``."""
    if len(cams) != detector.sensors:
        raise InputError(
            cams[0].path.parent,
            f"run has {len(cams)} camera video(s), the detector takes {detector.sensors} sensor(s)",
        )
    for r in run_cams:
        if r.key not in labels:
            raise InputError(r.path, "no label for this video")
    labs = [labels[r.key] for r in run_cams]  # the run's label is its cameras' (the grasp is lost for both fingers)
    moment = next((l.moment_of_slip for l in labs if l.moment_of_slip is not None), None)
    slipped = any(l.slipped for l in labs)
    if slipped and moment is None and not keep:
        return None
    # what the model reads (grey frames, tracked markers) and the contact signal come from the
    # frame cache (no decode after labelling); a model on colour frames replays the decoded video
    product = detector.cache_product
    cached = [video_products(r.path, ["contact", *([product] if product else [])], min_frames=1) for r in cams]
    n = len(cached[0]["contact"])
    if any(len(c[k]) != n for c in cached for k in c):
        counts = [{k: len(v) for k, v in c.items()} for c in cached]
        raise InputError(cams[0].path.parent, f"the cameras of this run differ in frame count: {counts}")
    # the detector runs on its own clock: frames taken at another rate are resampled to it
    fps, fps_from = rate
    stamps = None if abs(fps - detector.sensor.fps) < 1e-6 * fps else np.arange(n) / fps
    if product:
        trace = detector.replay_cached(np.stack([c[product] for c in cached]), stamps=stamps)
    else:
        videos = [read_video(r.path, expected_size=None, min_frames=1) for r in cams]
        trace = detector.replay(*videos, stamps=stamps)
    rest = rest_mask(np.stack([c["contact"] for c in cached])) if n > 1 else None
    cameras = tuple(c.camera for c in cams)
    return RunTrace(
        key[0], key[1], slipped, moment, n, trace.probability, rest, cameras, fps, detector.sensor.fps, fps_from
    )
