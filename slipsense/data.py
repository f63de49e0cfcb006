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
from slipsense.recordings.recording_set import Recordings
from slipsense.recordings.labelling import label_runs
from slipsense.sensors.marker_npz import load_marker_npz
from slipsense.sensors.spec import GELSIGHT_MINI


def gelsight_clips(recordings_dir, spec, on_error="raise", overrides=None, progress=True, sensor=None):
    """Labelled clips of every video of a :class:`~slipsense.recordings.recording_set.Recordings` or its
    folder ``recordings_dir`` (labels and clips are cached).

    Returns ``(clipset, labels)``; ``spec`` is a :class:`~slipsense.recordings.clips.ClipSpec`;
    ``sensor`` (default the GelSight Mini) names the folder layout.
    """
    read = Recordings.of(recordings_dir, sensor or GELSIGHT_MINI, on_error)
    recordings_dir = read.root
    # any frame size: clips are resized to the spec's size, as grasps and the live detector resize
    recordings = read.checked(on_error)
    if not recordings:
        raise InputError(recordings_dir, "no usable recordings")
    labels = label_runs(recordings, overrides=overrides, on_error=on_error, progress=progress)
    recordings = [r for r in recordings if r.key in labels]  # runs skipped while labelling
    if not recordings:
        raise InputError(recordings_dir, "no usable recordings")
    clips = load_or_build_clips(recordings, labels, spec, progress=progress)
    if len(clips) == 0:
        raise InputError(recordings_dir, "no clips could be made (no slip moments and no contact phases found)")
    return clips, labels


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
    """Split item indices so that no group (sequence, object) is on both sides.

    Overlapping windows of one sequence share a group: splitting by window would leak test data
    into training.
    """
    if not 0 < test_fraction < 1:
        raise ConfigError("test fraction must be in (0, 1)")
    uniq = np.unique(groups)
    if len(uniq) < 2:
        raise ConfigError(f"a split by group needs at least 2 groups, got {len(uniq)}: one side would be empty")
    rng = np.random.default_rng(seed)
    perm = rng.permutation(uniq)
    n_test = min(max(1, int(round(len(uniq) * test_fraction))), len(uniq) - 1)  # neither side empty
    test_groups = set(perm[:n_test].tolist())
    is_test = np.array([g in test_groups for g in groups.tolist()])
    return np.flatnonzero(~is_test), np.flatnonzero(is_test)
