"""From a folder or file a user names to the Datasets training and evaluation take.

Two kinds of data, read for the models by their ``clip_reader`` (:mod:`slipsense.readers`):

* ``video``: a GelSight recordings folder (``<object>/exp_num_<N>/camera_*.avi``) -> labelled
  clips (cached) -> :class:`~slipsense.datasets.ClipDataset`;
* ``markers``: an ``.npz`` of marker-cloud sequences (``x`` (N, T, M, 3), ``y`` (N,), optional
  ``groups`` (N,)) -> :class:`~slipsense.datasets.MarkerDataset`.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np

from slipsense.paths import gelsight_recordings
from slipsense.errors import ConfigError, InputError
from slipsense.progress import progress_bar
from slipsense.recordings.clips import ClipSpec, load_or_build_clips
from slipsense.recordings.folders import SkippedInputWarning, check_on_error, find_recordings, validate_recordings
from slipsense.recordings.frame_cache import prefetch
from slipsense.recordings.label_csv import Overrides, apply_overrides, read_overrides_csv
from slipsense.recordings.labels import LABEL_PRODUCTS, label_recordings
from slipsense.recordings.types import by_run
from slipsense.resources import shipped_overrides
from slipsense.sensors.marker_npz import load_marker_npz
from slipsense.sensors.spec import GELSIGHT_MINI


def gelsight_clips(recordings_dir: str | Path, spec, on_error="raise", overrides=None, progress=True, sensor=None):
    """Labelled clips of every video under ``recordings_dir`` (labels and clips are cached).

    Returns ``(clipset, labels)``; ``spec`` is a :class:`~slipsense.recordings.clips.ClipSpec`;
    ``sensor`` (default the GelSight Mini) names the folder layout.
    """
    recordings = find_recordings(recordings_dir, on_error=on_error, sensor=sensor or GELSIGHT_MINI)
    # any frame size: clips are resized to the spec's size, as grasps and the live detector resize
    recordings = validate_recordings(recordings, on_error=on_error, expected_size=None)
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


def shipped_overrides_for(recordings):
    """The shipped hand labels (:func:`slipsense.resources.shipped_overrides`) of those ``recordings``
    that are the shared GelSight recordings (``$SLIPSENSE_DATA/gelsight-slip``), or None."""
    shared = gelsight_recordings().resolve()
    present: dict[tuple[str, int], set] = {}
    for r in recordings:
        if Path(r.path).resolve().is_relative_to(shared):
            present.setdefault((r.object, r.experiment), set()).add(r.camera)
    if not present:
        return None
    rows = read_overrides_csv(shipped_overrides())
    keep = {k: v for k, v in rows.items() if k[:2] in present and (k[2] is None or k[2] in present[k[:2]])}
    return Overrides(keep, rows.path, rows.lines) if keep else None


def label_runs(recordings, overrides=None, on_error: str = "raise", progress: bool = True):
    """Label recordings run by run (:func:`~slipsense.recordings.labels.label_recordings`) and
    apply the overrides (a CSV path, read against the recordings so errors name its file and line).
    ``overrides=None`` (default): runs of the shared recordings get the shipped hand labels
    (:func:`shipped_overrides_for`), other folders none; ``overrides=False``: no hand labels at all.

    With ``on_error="skip"`` a run that cannot be labelled (a video that does not decode, cameras
    that differ in frame count) is left out with a
    :class:`~slipsense.recordings.folders.SkippedInputWarning`, together with its override rows;
    with ``"raise"`` its InputError stops everything. Returns ``{key: VideoLabel}``.
    """
    check_on_error(on_error)
    runs = by_run(recordings)
    known = {key: [r.camera for r in recs] for key, recs in runs.items()}
    if overrides is None:
        overrides = shipped_overrides_for(recordings)
    elif overrides is False:
        overrides = None
    ov = read_overrides_csv(overrides, known=known) if isinstance(overrides, (str, Path)) else overrides

    if on_error == "raise":  # runs not labelled yet are labelled on every core, decoding as they go
        labels = label_recordings(recordings, overrides=ov, progress=progress)
        prefetch([r.path for r in recordings], LABEL_PRODUCTS, progress=progress)  # labels cached, frames not
        return labels
    prefetch([r.path for r in recordings], LABEL_PRODUCTS, progress=progress)  # decoding on every core
    labels: dict = {}
    skipped: set = set()
    for key, recs in progress_bar(list(runs.items()), progress, "labelling runs"):
        try:
            labels.update(label_recordings(recs, progress=False))
        except InputError as exc:
            warnings.warn(f"{exc}; run skipped", SkippedInputWarning, stacklevel=2)
            skipped.add(key)
    if ov:  # without the rows of the runs skipped
        keep = {k: v for k, v in ov.items() if k[:2] not in skipped}
        labels = apply_overrides(labels, Overrides(keep, ov.path, ov.lines) if isinstance(ov, Overrides) else keep)
    return dict(sorted(labels.items()))


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
