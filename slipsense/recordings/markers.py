"""Marker detection and tracking on marker-gel tactile images (GelSight Mini and alike).

The gel of a GelSight Mini carries a grid of dark markers. In the shared 320 x 240 recordings two
layouts occur: a pitch of about 31 px (markers 11-16 px wide; 62-80 whole markers in view, grids
of 10 x 8 or 9 x 7) and a pitch of about 44 px (markers 15-21 px; 26-42 whole markers). Tracking
them turns a video into a sparse displacement field: the input of marker-based slip detectors
such as STNet, which tracks markers with KLT (pyramidal Lucas-Kanade) and feeds per-frame 3-D
marker clouds to a transformer.

Pipeline
--------
1. :func:`detect_markers` finds the markers on one reference frame: black-hat morphology (the
   closing of the image minus the image) removes the smooth, coloured gel shading and keeps dark
   spots smaller than the structuring element; Otsu's threshold splits markers from the rest
   (two higher thresholds then recover markers merged with dark imprint edges); connected
   components are filtered by area, fill ratio, elongation, border contact and grid spacing; each
   centre is the black-hat-weighted centroid (sub-pixel).
2. :func:`track_markers` follows them frame to frame with ``cv2.calcOpticalFlowPyrLK`` plus a
   forward-backward check, a jump check against neighbouring markers, a darkness check, an
   image-edge check and a collision check. A marker failing a check is marked lost (``valid``
   False) and later re-acquired by re-detecting blobs and assigning them to the nearest free lost
   marker.
3. :class:`MarkerTrack` holds positions, the valid mask and an intensity-based depth proxy, and
   converts them to ``(x, y, depth)`` clouds; :func:`marker_sequences` gives a fixed marker count
   per sensor for models (the markers nearest the centre), :func:`grid_sequences` every marker
   resampled onto a fixed grid (the same layout for gel pads of any marker count).

Reference frame
---------------
The shared recordings open with a camera start-up transient: frame 0 often differs strongly from
the scene and frames 1 to about 9 form a plateau with occasional jumps. Tracking therefore starts
from :data:`STARTUP_FRAMES` (frame 10) by default, and runs backward from there too; markers in the
transient frames are often reported lost.

Units
-----
Pixel positions are ``(x, y)`` = (column, row) in the image, float32, origin at the top-left
pixel's centre. Millimetres use :data:`DEFAULT_MM_PER_PX`, the GelSight Mini's nominal sensing
area (18.6 mm x 14.3 mm) over 320 x 240 px; it is approximate (no per-sensor calibration).

Modules
-------
Detection lives in :mod:`slipsense.sensors.marker_detection`, tracking and :class:`MarkerTrack`
in :mod:`slipsense.sensors.marker_tracking`, the track cache in
:mod:`slipsense.recordings.marker_cache`. This module re-exports their public names and holds what
works on whole recordings and finished tracks: :func:`track_recording`, :func:`track_recordings`,
:func:`marker_sequences`, :func:`grid_sequences` and :func:`marker_clouds`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
from tqdm.auto import tqdm

from ..paths import cache_root
from ..errors import ConfigError, InputError
from .video import read_video
from .marker_cache import read_track, track_entry
from ..sensors.marker_detection import detect_markers, order_markers  # noqa: F401 (re-exported)
from ..sensors.marker_tracking import DEFAULT_MM_PER_PX, MarkerTrack, track_markers


def select_markers(track: MarkerTrack, n_markers: int) -> np.ndarray:
    """Indices of at most ``n_markers`` markers: the ones closest to the image centre, row-major.

    The rule (used by :func:`marker_sequences`): rank markers by the distance of their reference
    position to the image centre (ties: lower index first), keep the first ``n_markers``, then order
    the kept ones row-major with :func:`order_markers`. Central markers are preferred because they
    see the contact and are the least likely to leave the view.
    """
    if n_markers <= 0:
        raise ValueError("n_markers must be positive")
    h, w = track.frame_size
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    dist = np.linalg.norm(track.reference_positions - centre, axis=1)
    keep = np.sort(np.argsort(dist, kind="stable")[:n_markers])
    return keep[order_markers(track.reference_positions[keep], track.spacing)]


def marker_sequences(track: MarkerTrack, n_markers: int, *, normalise: bool = True) -> np.ndarray:
    """A fixed number of marker clouds per frame, in a stable order, for models.

    Markers are chosen and ordered by :func:`select_markers` (closest to the image centre, then
    row-major). Values are :meth:`MarkerTrack.to_cloud` (``normalise`` passed through). When the
    track has fewer than ``n_markers`` markers the missing slots are padded at the end with zeros
    (the image centre and zero depth).

    Returns:
        float32 ``(T, n_markers, 3)``.
    """
    idx = select_markers(track, n_markers)
    out = np.zeros((track.n_frames, n_markers, 3), np.float32)
    out[:, : len(idx)] = track.to_cloud(normalise)[:, idx]
    return out


def marker_layout(layout: str | int) -> tuple[int, tuple[int, int] | None]:
    """A layout of markers for models: ``"ROWSxCOLS"`` (every tracked marker resampled onto that grid,
    :func:`grid_sequences`) or a count ``N`` (the N markers nearest the image centre,
    :func:`marker_sequences`) -> ``(markers per frame, grid or None)``. ConfigError otherwise."""
    text = str(layout).strip().lower()
    try:
        if "x" in text:
            rows, cols = (int(v) for v in text.split("x"))
            if rows >= 1 and cols >= 1:
                return rows * cols, (rows, cols)
        elif int(text) >= 1:
            return int(text), None
    except ValueError:
        pass
    raise ConfigError(
        f"a marker layout is ROWSxCOLS (every marker on a grid, e.g. 7x9) or a count >= 1, got {layout!r}"
    )


def layout_name(layout: str | int) -> str:
    """The canonical name of a :func:`marker_layout` (``"7x9"``, ``"32"``), as checkpoints record it."""
    count, grid = marker_layout(layout)
    return f"{grid[0]}x{grid[1]}" if grid else str(count)


def marker_clouds(track: MarkerTrack, layout: str | int) -> np.ndarray:
    """A video's markers as a marker model reads them: float32 ``(T, M, 3)``, x, y in mm from the image
    centre and the depth proxy, in ``layout`` (:func:`marker_layout`)."""
    count, grid = marker_layout(layout)
    return grid_sequences(track, grid) if grid else marker_sequences(track, count, normalise=False)


def grid_sequences(track: MarkerTrack, grid: tuple[int, int], *, neighbours: int = 4) -> np.ndarray:
    """Every tracked marker, resampled onto a fixed grid of virtual markers, for models.

    Gel pads differ in how many markers they show (the shared recordings: about 35 or 62-80), while
    a model takes a fixed layout. ``grid = (rows, cols)`` virtual markers sit at the centres of a
    ``rows x cols`` tiling of the image; each moves by the inverse-square-distance weighted mean
    displacement of its ``neighbours`` nearest tracked markers (nearest in the reference frame, so
    the weights are fixed for the video) and takes their depth proxy the same way. Lost markers
    contribute their estimates (:class:`MarkerTrack`). Row-major, rows from the image top.

    Returns:
        float32 ``(T, rows * cols, 3)``: x, y in mm from the image centre (as
        :meth:`MarkerTrack.to_cloud` with ``normalise=False``) and the unitless depth proxy.
    """
    rows, cols = (int(v) for v in grid)
    if rows < 1 or cols < 1:
        raise ValueError(f"grid must be (rows, cols) >= 1, got {grid!r}")
    if int(neighbours) < 1:
        raise ValueError(f"neighbours must be >= 1, got {neighbours!r}")
    h, w = track.frame_size
    # tile centres in pixel-centre coordinates (pixel i covers i-0.5..i+0.5), as the positions are
    ys = (np.arange(rows) + 0.5) * h / rows - 0.5
    xs = (np.arange(cols) + 0.5) * w / cols - 0.5
    base = np.stack([np.tile(xs, rows), np.repeat(ys, cols)], axis=1)  # (G, 2) px
    ref = track.reference_positions.astype(np.float64)
    dist = np.linalg.norm(base[:, None] - ref[None], axis=-1)  # (G, N)
    k = min(int(neighbours), len(ref))
    near = np.argsort(dist, axis=1, kind="stable")[:, :k]
    wts = 1.0 / (np.take_along_axis(dist, near, axis=1) + 1.0) ** 2  # +1 px: a marker on the spot does not take all
    weights = np.zeros_like(dist)
    np.put_along_axis(weights, near, wts / wts.sum(axis=1, keepdims=True), axis=1)
    disp = track.positions.astype(np.float64) - ref[None]  # (T, N, 2)
    xy = base[None] + np.einsum("gn,tnc->tgc", weights, disp) - np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    depth = track.depth.astype(np.float64) @ weights.T  # (T, G)
    return np.concatenate([xy * DEFAULT_MM_PER_PX, depth[..., None]], axis=-1).astype(np.float32)


def track_recording(
    path: str | Path,
    reference_index: int | None = None,
    *,
    expected_size: tuple[int, int] | None = None,
    **track_kwargs: Any,
) -> MarkerTrack:
    """Decode a video (:func:`slipsense.recordings.video.read_video`) and track its markers.

    ``track_kwargs`` go to :func:`track_markers`. Raises InputError naming ``path`` for unreadable
    videos and for reference frames without markers.
    """
    frames = read_video(path, expected_size=expected_size, min_frames=2)
    return track_markers(frames, reference_index, source=path, **track_kwargs)


def track_recordings(
    recordings: Iterable[Any],
    reference_index: int | None = None,
    *,
    cache_dir: str | Path | None = None,
    progress: bool = True,
    expected_size: tuple[int, int] | None = None,
    **track_kwargs: Any,
) -> list[MarkerTrack]:
    """Track many recordings, caching each result as ``.npz``.

    Args:
        recordings: objects with a ``.path`` (e.g. :class:`slipsense.recordings.types.Recording`)
            or plain paths.
        reference_index, expected_size, track_kwargs: as for :func:`track_recording`.
        cache_dir: the cache (default ``config.cache_root()/markers``) of verified entries
            (:mod:`slipsense.cache`) keyed by the video's resolved path, size, mtime and all tracking
            parameters; an entry that fails its checks, or whose arrays do not fit together or the
            video, is tracked again with a :class:`~slipsense.errors.CacheWarning` and overwritten.
        progress: show a tqdm progress bar.

    Returns:
        one :class:`MarkerTrack` per recording, in order.
    """
    items: Sequence[Any] = list(recordings)
    folder = Path(cache_dir) if cache_dir is not None else cache_root() / "markers"
    params = {"reference_index": reference_index, "expected_size": expected_size, **track_kwargs}
    tracks: list[MarkerTrack] = []
    for item in tqdm(items, desc="tracking markers", unit="video", disable=not progress):
        path = Path(getattr(item, "path", item))
        if not path.is_file():
            raise InputError(path, "video file does not exist")
        track = track_entry(folder, path, params).get(
            lambda f: read_track(f, path, expected_size),
            lambda: track_recording(path, reference_index, expected_size=expected_size, **track_kwargs),
            lambda tmp, track: np.savez(tmp, **track.to_arrays()),
        )
        tracks.append(track)
    return tracks
