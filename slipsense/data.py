"""From a folder or file a user names to the Datasets training and evaluation take.

Two kinds of data, read for the models by their ``clip_reader`` (:mod:`slipsense.readers`):

* ``video``: a GelSight recordings folder (``<object>/exp_num_<N>/camera_*.avi``) -> labelled
  clips (cached) -> :class:`~slipsense.datasets.ClipDataset`;
* ``markers``: an ``.npz`` of marker-cloud sequences (``x`` (N, T, M, 3), ``y`` (N,), optional
  ``groups`` (N,)) -> :class:`~slipsense.datasets.MarkerDataset`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from slipsense.errors import ConfigError, InputError
from slipsense.recordings.clips import ClipSpec, load_or_build_clips
from slipsense.recordings.splits import ObjectHoldOut
from slipsense.recordings.recording_set import labelled_set
from slipsense.sensors.marker_npz import load_marker_npz


def gelsight_clips(recordings_dir, spec, on_error="raise", overrides=None, progress=True, sensor=None):
    """Labelled clips of every video of a labelled set (:class:`~slipsense.recordings.recording_set.Labelled`,
    as it is), or of a :class:`~slipsense.recordings.recording_set.Recordings` or its folder
    ``recordings_dir``, labelled once here (labels and clips are cached).

    Returns ``(clipset, labels)``; ``spec`` is a :class:`~slipsense.recordings.clips.ClipSpec`;
    ``sensor`` (None: the sensor the data states) names the folder layout.
    """
    # any frame size: clips are resized to the spec's size, as grasps and the live detector resize
    data = labelled_set(recordings_dir, overrides, sensor, on_error, whole_runs=False, progress=progress)
    clips = load_or_build_clips(list(data), data.labels, spec, progress=progress)
    if len(clips) == 0:
        raise InputError(data.root, "no clips could be made (no slip moments and no contact phases found)")
    return clips, dict(data.labels)


def clip_spec_from(info: dict[str, Any]):
    """The ClipSpec stored in a checkpoint's or split's ``data`` section."""
    raw = info.get("clip_spec") if isinstance(info, dict) else None
    if not isinstance(raw, dict):
        raise ConfigError(f"clip_spec must be a mapping of clip settings, got {type(raw).__name__}")
    try:
        return ClipSpec(**raw)  # a size list read from JSON becomes a tuple there
    except TypeError as exc:
        raise ConfigError(f"clip_spec: {exc}") from None


def load_markers(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(x (N,T,M,3) float32, y (N,) int64, groups (N,))`` from a marker ``.npz`` (validated)."""
    ds = load_marker_npz(path)
    return ds.x, ds.y, ds.groups


def split_groups(groups: np.ndarray, test_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Split item indices so that no group (sequence, object) is on both sides: ``test_fraction`` of
    the groups held out by :class:`~slipsense.recordings.splits.ObjectHoldOut`.

    Overlapping windows of one sequence share a group: splitting by window would leak test data
    into training.
    """
    return next(ObjectHoldOut(test_fraction, seed).split(np.asarray(groups)))
