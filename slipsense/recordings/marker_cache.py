"""On-disk cache of marker tracks (used by :func:`slipsense.recordings.markers.track_recordings`).

Each entry is a verified ``.npz`` of :meth:`MarkerTrack.to_arrays` (:mod:`slipsense.cache`), keyed by
the video's path, size and mtime and the tracking parameters; it is used only when it holds a
consistent track of the video too (:func:`check_track`).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from ..cache import Entry
from .frames import source_stat
from .video import TRUNCATION_TOLERANCE, frame_count
from ..sensors.marker_tracking import MarkerTrack

#: Bump when detection or tracking changes, so stale cache files are ignored.
CACHE_VERSION = 2


def track_entry(cache_dir: Path, path: Path, params: dict[str, Any]) -> Entry:
    """The entry of ``path`` tracked with ``params``, its name prefixed by object, experiment, camera."""
    size, mtime = source_stat(path)
    inputs = {"version": CACHE_VERSION, "path": str(path.resolve()), "size": size, "mtime_ns": mtime, "params": params}
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", "-".join(path.parts[-3:-1] + (path.stem,)))
    return Entry(cache_dir, inputs, "marker cache", prefix=f"{stem}-", suffix=".npz")


def check_track(track: "MarkerTrack", expected_size: tuple[int, int] | None = None) -> None:
    """Raise ValueError unless ``track``'s arrays fit together (shapes, ranges, finite values)."""
    t, n = track.positions.shape[:2] if track.positions.ndim == 3 else (-1, -1)
    if track.positions.ndim != 3 or track.positions.shape[2] != 2 or n < 1 or t < 1:
        raise ValueError(f"positions have shape {track.positions.shape}")
    if track.valid.shape != (t, n) or track.depth.shape != (t, n):
        raise ValueError("valid/depth do not match positions")
    if track.reference_positions.shape != (n, 2):
        raise ValueError("reference positions do not match positions")
    for name in ("positions", "depth", "reference_positions"):
        if not np.isfinite(getattr(track, name)).all():
            raise ValueError(f"{name} hold non-finite values")
    if not 0 <= track.reference_index < t:
        raise ValueError(f"reference index {track.reference_index} outside 0..{t - 1}")
    h, w = track.frame_size
    if h < 1 or w < 1 or (expected_size is not None and (h, w) != tuple(expected_size)):
        raise ValueError(f"frame size {track.frame_size}")
    if not (np.isfinite(track.spacing) and track.spacing > 0 and np.isfinite(track.diameter) and track.diameter > 0):
        raise ValueError("marker spacing or diameter not positive")
    if float(track.depth.min()) < 0:
        raise ValueError("negative depth")


def read_track(cfile: Path, path: Path, expected_size: tuple[int, int] | None) -> MarkerTrack:
    """The track in ``cfile``; ValueError unless it is consistent and fits the video ``path``."""
    with np.load(cfile, allow_pickle=False) as data:
        track = MarkerTrack.from_arrays(data)
    check_track(track, expected_size)
    stated = frame_count(path)
    if stated is not None and not stated - TRUNCATION_TOLERANCE <= track.n_frames <= stated:
        raise ValueError(f"{track.n_frames} frames tracked but the video states {stated}")
    return track
