"""Real marker sequences from GelSight recordings, for the point-cloud models (STNet, TemNet).

Each video's markers are tracked (pyramidal Lucas-Kanade, :mod:`slipsense.recordings.markers`),
reduced to a fixed count per sensor and cut into the same windows as the video clips
(:func:`slipsense.recordings.clips.plan_windows`): slip windows end right before the moment of
slip, wiggle windows come from the contact phase of runs that did not slip. ``groups`` is the
object name, so a grouped split leaves whole objects out.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from slipsense.atomic import write_with
from slipsense.errors import InputError
from slipsense.recordings.clips import ClipSpec, plan_windows
from slipsense.recordings.recording_set import Labelled, Recordings, labelled_set
from slipsense.recordings.markers import layout_name, marker_clouds, track_recordings


def real_marker_dataset(
    recordings_dir: "str | Path | Recordings | Labelled",
    frames: int = 12,
    n_markers: str | int = 32,
    horizon: int = 0,
    wiggle_per_video: int = 2,
    seed: int = 0,
    on_error: str = "raise",
    progress: bool = True,
    overrides: str | Path | None = None,
) -> dict[str, np.ndarray]:
    """Marker windows of every video of a labelled set (as it is), or of a recordings set or its
    folder ``recordings_dir``, labelled once here.

    Returns arrays ``x`` float32 ``(N, frames, n_markers, 3)`` — per marker x, y in mm from the
    image centre and the unitless intensity depth proxy —, ``y`` int64 ``(N,)`` (1 = onset of
    slip), ``groups`` str ``(N,)`` object names, ``experiment`` int, ``camera`` str, ``start`` int
    (first frame of the window) and ``marker_layout`` (0-d str, ``"7x9"`` or ``"32"``: :func:`~slipsense.recordings.markers.layout_name`). ``overrides``: a label overrides CSV (hand labels win), as for
    training; with ``on_error="skip"`` runs that cannot be labelled are left out with a warning.
    ``n_markers`` is a layout (:func:`slipsense.recordings.markers.marker_layout`): a count N, the N
    markers nearest the image centre, or ``"ROWSxCOLS"``, every tracked marker resampled onto that
    grid of virtual markers (:func:`slipsense.recordings.markers.grid_sequences`).
    """
    layout = layout_name(n_markers)
    spec = ClipSpec(frames=frames, horizon=horizon, wiggle_per_video=wiggle_per_video, seed=seed)
    data = labelled_set(recordings_dir, overrides, None, on_error, whole_runs=False, progress=progress)
    recs, labels = list(data), data.labels
    tracks = track_recordings(recs, progress=progress)
    rows = []  # per window: its clouds, label, object, experiment, camera, first frame
    for rec, track in zip(recs, tracks):
        windows = plan_windows(labels[rec.key], spec)
        if windows:
            cloud = marker_clouds(track, layout)  # (T, M, 3)
            rows += [
                (cloud[w.start : w.end + 1], w.y, rec.object, rec.experiment, rec.camera, w.start) for w in windows
            ]
    if not rows:
        raise InputError(data.root, "no marker windows could be made")
    xs, ys, groups, exps, cams, starts = zip(*rows)
    return {
        "marker_layout": np.asarray(layout),  # how the markers were taken: a replay takes them alike
        "sensor": np.asarray(json.dumps(data.sensor.to_dict())),  # whose videos: their rate and size
        "x": np.stack(xs).astype(np.float32),
        "y": np.asarray(ys, np.int64),
        "groups": np.asarray(groups),
        "experiment": np.asarray(exps, np.int64),
        "camera": np.asarray(cams),
        "start": np.asarray(starts, np.int64),
    }


def save_marker_npz(arrays: dict[str, np.ndarray], path: str | Path) -> Path:
    """Write a marker dataset atomically in the documented ``.npz`` format."""
    path = Path(path)
    if path.suffix != ".npz":
        raise InputError(path, "marker datasets are saved as .npz; give a path ending in .npz")
    write_with(path, lambda tmp: np.savez(tmp, **arrays))
    return path
