"""On-disk cache of marker tracks (used by :func:`slipsense.sensors.markers.track_recordings`).

Each entry is an ``.npz`` of :meth:`MarkerTrack.to_arrays` named by a hash of the video and the
tracking parameters, with a ``.json`` sidecar (sha256 and inputs) written last; an entry is used
only when it passes its checksum, records the same inputs and holds a consistent track
(:func:`check_track`).
"""

from __future__ import annotations

import hashlib
import json
import re
import warnings
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import file_sha256, write_text, write_with
from ..errors import CacheWarning
from ..recordings.frames import source_stat
from ..recordings.video import TRUNCATION_TOLERANCE, frame_count
from .marker_tracking import MarkerTrack

#: Bump when detection, tracking or the cache layout changes, so stale cache files are ignored.
CACHE_VERSION = 2  # 2: a .json sidecar (sha256, inputs) beside each entry


def _cache_file(cache_dir: Path, path: Path, params: dict[str, Any]) -> Path:
    """Cache file for ``path`` tracked with ``params``: keyed by path, size, mtime and params."""
    digest = hashlib.sha256(_identity(path, params).encode()).hexdigest()[:20]
    # Readable prefix (object, experiment, camera) so the folder can be browsed.
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", "-".join(path.parts[-3:-1] + (path.stem,)))
    return cache_dir / f"{stem}-{digest}.npz"


def _identity(path: Path, params: dict[str, Any]) -> str:
    """What a cached track was computed from (the same fields as its file name's hash)."""
    size, mtime = source_stat(path)
    return json.dumps(
        {
            "version": CACHE_VERSION,
            "path": str(path.resolve()),
            "size": size,
            "mtime_ns": mtime,
            "params": params,
        },
        sort_keys=True,
        default=str,
    )


def _save_cached_track(cfile: Path, path: Path, params: dict[str, Any], track: "MarkerTrack") -> None:
    """Write the track and, last, a sidecar with its sha256 and inputs (a write failure only warns)."""
    arrays = track.to_arrays()
    digest: list[str] = []

    def writer(tmp: Path) -> None:
        np.savez(tmp, **arrays)
        digest.append(file_sha256(tmp))

    try:
        write_with(cfile, writer)
        write_text(cfile.with_suffix(".json"), json.dumps({"sha256": digest[0], "inputs": _identity(path, params)}))
    except OSError as exc:
        warnings.warn(
            f"{cfile}: cannot write the marker cache ({exc}); continuing without it", CacheWarning, stacklevel=3
        )


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


def _load_cached_track(
    cfile: Path, path: Path, params: dict[str, Any], expected_size: tuple[int, int] | None
) -> "MarkerTrack | None":
    """A cached track that passes its checksum, records these inputs and is consistent; None when
    absent, otherwise warned about (:class:`~slipsense.errors.CacheWarning`) and None."""
    sidecar = cfile.with_suffix(".json")
    if not cfile.is_file() and not sidecar.is_file():
        return None
    try:
        info = json.loads(sidecar.read_text(encoding="utf-8"))
        if not isinstance(info, dict) or info.get("inputs") != _identity(path, params):
            raise ValueError("made from another video or other settings")
        if info.get("sha256") != file_sha256(cfile):
            raise ValueError("checksum mismatch")
        with np.load(cfile, allow_pickle=False) as data:
            track = MarkerTrack.from_arrays(data)
        check_track(track, expected_size)
        stated = frame_count(path)
        if stated is not None and not stated - TRUNCATION_TOLERANCE <= track.n_frames <= stated:
            raise ValueError(f"{track.n_frames} frames tracked but the video states {stated}")
    except (OSError, ValueError, KeyError, TypeError, IndexError, EOFError, zipfile.BadZipFile) as exc:
        warnings.warn(f"{cfile}: marker cache entry unusable ({exc}); tracking again", CacheWarning, stacklevel=3)
        return None
    return track
