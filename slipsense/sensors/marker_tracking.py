"""Marker tracking through a video: :func:`track_markers` (pyramidal Lucas-Kanade) and its result,
:class:`MarkerTrack`.

Steps 2 and 3 of the pipeline described in :mod:`slipsense.recordings.markers`; the markers are
found with :mod:`slipsense.sensors.marker_detection`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..errors import InputError
from .marker_detection import _DEFAULT_DIAMETER, _as_gray, _blackhat, _closing_kernel, _detect, _detect_scaled
from .marker_detection import _median_nn_distance, _odd, _require, order_markers

#: Frames skipped by default at the start of a recording (camera start-up transient).
STARTUP_FRAMES = 10

#: Nominal millimetres per pixel of a GelSight Mini at 320 x 240 px (18.6 mm / 320 px ~ 14.3 mm / 240 px).
DEFAULT_MM_PER_PX = 0.0585

# Neighbours (in the reference layout) used for the jump check and for predicting lost markers.
_K_NEIGHBOURS = 6

# A tracked point counts as on its marker while the image there is at least this fraction as
# dark (below the local background) as the marker was in the reference frame.
_MIN_CONTRAST_FRACTION = 0.35


@dataclass
class MarkerTrack:
    """Tracked markers of one video.

    Attributes:
        positions: float32 ``(T, N, 2)`` marker centres ``(x, y)`` in px. Where ``valid`` is False
            the value is an estimate: the reference position plus the median displacement of the
            marker's valid neighbours (of all valid markers when no neighbour is valid; its last
            position when none is valid at all).
        valid: bool ``(T, N)``: the marker was tracked (or re-acquired) in that frame.
        depth: float32 ``(T, N)`` intensity-based depth proxy, unitless, >= 0: how much the gel's
            shading changed at the marker since the reference frame, i.e. the Euclidean BGR
            distance between the marker-free background (markers removed by a morphological
            closing) of this frame and of the reference frame, both taken at the marker's current
            pixel position, divided by 255 (0 = unchanged, at most sqrt(3)). Indentation tilts the
            gel surface, which changes its shading under the sensor's coloured lights, so the value
            grows with contact and is largest where the gel is most inclined (the rim of an
            imprint); in-plane shear of a flat gel leaves it near 0. Not a calibrated depth: a flat
            pressed region changes less than its rim, and lighting flicker and codec noise give a
            floor of about 0.005-0.01 without contact.
        reference_positions: float32 ``(N, 2)`` positions in the reference frame, px, row-major.
        reference_index: the frame the markers were detected on.
        frame_size: ``(H, W)`` of the frames in px.
        spacing: median marker spacing in the reference frame, px.
        diameter: median marker diameter in the reference frame, px.
    """

    positions: np.ndarray
    valid: np.ndarray
    depth: np.ndarray
    reference_positions: np.ndarray
    reference_index: int
    frame_size: tuple[int, int]
    spacing: float
    diameter: float

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_markers(self) -> int:
        return int(self.positions.shape[1])

    def displacement(self) -> np.ndarray:
        """float32 ``(T, N, 2)`` displacement ``(dx, dy)`` in px from the reference positions."""
        return (self.positions - self.reference_positions[None]).astype(np.float32)

    def to_cloud(self, normalise: bool = True, *, mm_per_px: float = DEFAULT_MM_PER_PX) -> np.ndarray:
        """Per-frame marker clouds ``(x, y, depth)`` for STNet-style point-cloud models.

        Args:
            normalise: True: x, y relative to the image centre, divided by half the larger image
                side (x in [-1, 1], y in [-H/W, H/W]; one scale for both axes keeps directions);
                False: x, y in mm relative to the image centre, via ``mm_per_px``.
            mm_per_px: pixel size in mm, used when ``normalise`` is False.

        Returns:
            float32 ``(T, N, 3)``: x, y as above and the unitless depth proxy (:attr:`depth`).
        """
        h, w = self.frame_size
        xy = self.positions.astype(np.float64) - np.array([(w - 1) / 2.0, (h - 1) / 2.0])
        xy = xy / (max(h, w) / 2.0) if normalise else xy * mm_per_px
        return np.concatenate([xy, self.depth[..., None]], axis=-1).astype(np.float32)

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Plain arrays for ``np.savez`` (inverse: :meth:`from_arrays`)."""
        arrays = {k: getattr(self, k) for k in ("positions", "valid", "depth", "reference_positions")}
        sizes = {"reference_index": np.int64(self.reference_index), "frame_size": np.asarray(self.frame_size, np.int64)}
        return {**arrays, **sizes, "spacing": np.float64(self.spacing), "diameter": np.float64(self.diameter)}

    @classmethod
    def from_arrays(cls, arrays: Any) -> "MarkerTrack":
        """Rebuild from :meth:`to_arrays` output (or the ``np.load`` of its ``.npz``)."""
        fs = np.asarray(arrays["frame_size"]).tolist()
        kept = {k: np.asarray(arrays[k], np.float32) for k in ("positions", "depth", "reference_positions")}
        kept.update(valid=np.asarray(arrays["valid"], bool), reference_index=int(arrays["reference_index"]))
        kept.update(frame_size=(int(fs[0]), int(fs[1])), spacing=float(arrays["spacing"]))
        return cls(**kept, diameter=float(arrays["diameter"]))


def default_reference_index(n_frames: int) -> int:
    """First frame after the camera start-up transient, :data:`STARTUP_FRAMES`, or the last frame."""
    return max(0, min(STARTUP_FRAMES, n_frames - 1))


def _neighbours(ref: np.ndarray, k: int) -> np.ndarray:
    """int ``(N, k)`` indices of each marker's k nearest other markers in the reference layout."""
    n = len(ref)
    k = min(k, n - 1)
    if k <= 0:
        return np.zeros((n, 0), np.int64)
    d = np.linalg.norm(ref[:, None, :] - ref[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    return np.argsort(d, axis=1, kind="stable")[:, :k]


def _neighbour_median(values: np.ndarray, ok: np.ndarray, nbrs: np.ndarray) -> np.ndarray:
    """``(N, 2)`` median of ``values`` over each marker's ``ok`` neighbours; nan where none is ok."""
    n, k = nbrs.shape
    if k == 0:
        return np.full((n, 2), np.nan)
    # A masked median by sorting (np.nanmedian is ~20x slower on these small arrays): invalid
    # entries sort to the end as +inf, and the median sits at the middle of the valid ones.
    v = values[nbrs].astype(np.float64)  # (N, k, 2)
    v[~ok[nbrs]] = np.inf
    v.sort(axis=1)
    cnt = ok[nbrs].sum(axis=1)  # (N,)
    lo = np.clip((cnt - 1) // 2, 0, k - 1)
    hi = np.clip(cnt // 2, 0, k - 1)
    rows = np.arange(n)
    med = 0.5 * (v[rows, lo] + v[rows, hi])
    med[cnt == 0] = np.nan
    return med


def _background(frame: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Marker-free shading of a BGR frame at half resolution, float32 ``(H/2, W/2, 3)``.

    The closing removes the dark markers; half resolution is plenty for shading (it varies over
    tens of pixels) and makes the closing about four times cheaper.
    """
    small = cv2.resize(frame, (frame.shape[1] // 2, frame.shape[0] // 2), interpolation=cv2.INTER_AREA)
    closed = cv2.morphologyEx(small, cv2.MORPH_CLOSE, kernel)
    return cv2.blur(closed, (5, 5)).astype(np.float32)


def _sample(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear samples ``(N, C)`` of ``image`` (h, w, C) at ``xy`` (N, 2) in its own px."""
    maps = np.ascontiguousarray(xy.reshape(-1, 1, 2).astype(np.float32))
    out = cv2.remap(image, maps, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(len(xy), -1)


class MarkerFollower:
    """Follows markers from one frame to the next with the checks of :func:`track_markers`, one step at
    a time: what the batch tracker runs over a video, and a live stream runs frame by frame
    (:class:`slipsense.sensors.gel_motion.GelMotionStream`).

    Args: the reference frame (grey uint8), its marker centres ``(N, 2)`` px, the marker diameter px,
    and ``win_size``, ``max_level``, ``fb_threshold``, ``max_jump`` as for :func:`track_markers`.
    """

    redetect: bool = True
    min_contrast: float = 12.0

    def __init__(
        self,
        ref_gray: np.ndarray,
        ref: np.ndarray,
        diameter: float,
        win_size: int | None = None,
        max_level: int = 3,
        fb_threshold: float = 1.0,
        max_jump: float | None = None,
    ):
        h, w = ref_gray.shape[:2]
        self.h, self.w, self.ref, self.diameter, self.fb_threshold = h, w, ref, diameter, fb_threshold
        spacing = _median_nn_distance(ref)
        if not np.isfinite(spacing):
            spacing = 2.0 * diameter  # a single marker: assume the usual grid pitch
        self.spacing = float(spacing)
        if win_size is None:
            win_size = int(np.clip(_odd(0.7 * spacing), 11, 41))
        self.jump = float(max_jump) if max_jump is not None else 0.25 * spacing
        # Per-marker edge margin: half a marker radius (a marker cut that far loses about a fifth of
        # its disc and its LK position drifts by up to ~1 px), but never more than the marker's own
        # margin in the reference frame less 1 px. Losing markers as soon as they touch the edge
        # instead would drop whole border rows at the slightest shear.
        ref_margin = np.minimum(ref.min(axis=1), np.minimum(w - 1 - ref[:, 0], h - 1 - ref[:, 1]))
        self.edge = np.clip(np.minimum(diameter / 4.0, ref_margin - 1.0), 0.0, None)
        criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
        self.lk_settings = dict(winSize=(int(win_size), int(win_size)), maxLevel=max_level, criteria=criteria)
        self.nbrs = _neighbours(ref, _K_NEIGHBOURS)
        # Each marker's darkness in the reference frame, for the appearance check.
        self.ref_contrast = _sample(_blackhat(ref_gray, diameter).astype(np.float32), ref)[:, 0]

    # The Python binding of calcOpticalFlowPyrLK in OpenCV 5 takes images only (not prebuilt
    # pyramids), so each call builds its own; at 320 x 240 that costs well under a millisecond.
    def _lk(self, src: Any, dst: Any, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pts = pts.reshape(-1, 1, 2).astype(np.float32)
        out, status, _err = cv2.calcOpticalFlowPyrLK(src, dst, pts, None, **self.lk_settings)
        return out.reshape(-1, 2), status.reshape(-1).astype(bool)

    def step(
        self, prev_gray: np.ndarray, prev_pos: np.ndarray, prev_ok: np.ndarray, gray: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Positions ``(N, 2)`` and valid ``(N,)`` in ``gray`` from those in ``prev_gray``."""
        n, h, w, spacing = len(self.ref), self.h, self.w, self.spacing
        pos = prev_pos.copy()
        ok = np.zeros(n, bool)
        idx = np.flatnonzero(prev_ok)
        blackhat = _blackhat(gray, self.diameter)
        if len(idx):
            p0 = prev_pos[idx]
            p1, st1 = self._lk(prev_gray, gray, p0)
            p0r, st2 = self._lk(gray, prev_gray, p1)
            fb = np.full(n, np.inf)
            fb[idx] = np.linalg.norm(p0r - p0, axis=1)
            # A marker reaching the edge is cut by it and its LK position is biased: lost.
            m = self.edge[idx]
            inside = (p1[:, 0] >= m) & (p1[:, 0] <= w - 1 - m) & (p1[:, 1] >= m) & (p1[:, 1] <= h - 1 - m)
            pos[idx] = p1
            ok[idx] = st1 & st2 & inside & (fb[idx] <= self.fb_threshold)
            # Jump check: compare each step with the median step of its valid neighbours.
            motion = pos - prev_pos
            med = _neighbour_median(motion, ok, self.nbrs)
            dev = np.linalg.norm(motion - med, axis=1)
            dev = np.where(np.isnan(dev), 0.0, dev)  # no valid neighbour: nothing to compare with
            ok &= (dev <= self.jump) & (np.linalg.norm(motion, axis=1) <= 0.5 * spacing)
            # Appearance check: LK happily holds a point on a flat patch where a marker vanished
            # (covered, out of focus, left the gel), so the point must still be on a dark spot.
            darkness = _sample(blackhat.astype(np.float32), pos)[:, 0]
            ok &= darkness >= _MIN_CONTRAST_FRACTION * self.ref_contrast
            _drop_collisions(pos, ok, fb, 0.35 * spacing)
        lost = np.flatnonzero(~ok)
        if len(lost):
            pos[lost] = _estimate_lost(pos, ok, self.ref, self.nbrs, prev_pos, lost)
            if self.redetect:
                _reacquire(gray, blackhat, pos, ok, lost, self.diameter, spacing, self.min_contrast)
        return pos, ok


def track_markers(
    frames: np.ndarray,
    reference_index: int | None = None,
    *,
    reference_positions: np.ndarray | None = None,
    marker_diameter: float | None = None,
    win_size: int | None = None,
    max_level: int = 3,
    fb_threshold: float = 1.0,
    max_jump: float | None = None,
    redetect: bool = True,
    min_contrast: float = 12.0,
    min_markers: int = 4,
    source: str | Path | None = None,
) -> MarkerTrack:
    """Track gel markers through a video with pyramidal Lucas-Kanade (KLT).

    Markers are detected on ``frames[reference_index]`` (or given) and followed frame to frame,
    forward to the end and backward to frame 0. In each step a marker is lost when

    - LK fails (status 0) forward or backward, or lands less than half a marker radius from the
      image edge (the marker is largely cut off there and its position biased),
    - the forward-backward error (track forward, then back, distance to the start) exceeds
      ``fb_threshold`` px,
    - its frame-to-frame motion differs from the median motion of its valid neighbours by more
      than ``max_jump`` px, or exceeds 0.5 marker spacings (the gel moves smoothly; a jump means
      LK slid onto another marker or an object edge),
    - it comes within 0.35 spacings of another tracked marker (two tracks on one blob: the one
      with the larger forward-backward error is dropped),
    - the image at its new position is less than 35 % as dark (black-hat value: darkness below
      the local background) as the marker was in the reference frame: the marker vanished.

    A lost marker gets ``valid`` False and an estimated position (see :class:`MarkerTrack`) until
    it is re-acquired: with ``redetect`` each frame with lost markers is searched for marker blobs
    not claimed by a tracked marker, and each blob goes to the nearest lost marker whose estimate
    lies within 0.3 spacings (greedy, nearest pair first).

    Args:
        frames: uint8 ``(T, H, W, 3)`` BGR (or ``(T, H, W)`` grey) video.
        reference_index: frame to detect on; None = :func:`default_reference_index`. Negative
            values count from the end.
        reference_positions: ``(N, 2)`` px positions in the reference frame, to skip detection.
        marker_diameter: marker diameter in px; None measures it on the reference frame (or
            assumes 17 px with ``reference_positions``).
        win_size: LK window side in px; None = 0.7 marker spacings (odd, 11..41).
        max_level: LK pyramid levels above the full image.
        fb_threshold: forward-backward error limit, px.
        max_jump: neighbour-consistency limit per frame, px; None = 0.25 marker spacings.
        redetect: try to re-acquire lost markers by detection.
        min_contrast, min_markers: as for :func:`detect_markers`.
        source: file named in errors.

    Returns:
        :class:`MarkerTrack` with ``T`` frames; the reference frame is all valid.

    Raises:
        InputError: bad frames array, bad reference index, or too few markers in the reference frame.
    """
    frames = np.asarray(frames)
    if frames.dtype != np.uint8 or frames.ndim not in (3, 4) or (frames.ndim == 4 and frames.shape[3] != 3):
        raise InputError(
            source, f"frames must be uint8 (T, H, W, 3) BGR or (T, H, W) grey, got {frames.shape} {frames.dtype}"
        )
    n_frames = frames.shape[0]
    if n_frames == 0:
        raise InputError(source, "no frames to track")
    if reference_index is None:
        reference_index = default_reference_index(n_frames)
    if not -n_frames <= reference_index < n_frames:
        raise InputError(source, f"reference frame {reference_index} is outside the {n_frames}-frame video")
    reference_index %= n_frames
    h, w = frames.shape[1:3]

    grays = [_as_gray(f, source) for f in frames]
    if reference_positions is None:
        blobs, diameter = _detect_scaled(grays[reference_index], marker_diameter, min_contrast, 1)
        _require(blobs, min_markers, f"reference frame {reference_index}", source)
        ref = blobs.centres[order_markers(blobs.centres)]
    else:
        ref = np.asarray(reference_positions, np.float32).reshape(-1, 2)
        if len(ref) == 0:
            raise InputError(source, "no reference positions given")
        diameter = float(marker_diameter) if marker_diameter else _DEFAULT_DIAMETER
    follow = MarkerFollower(grays[reference_index], ref, diameter, win_size, max_level, fb_threshold, max_jump)
    follow.redetect, follow.min_contrast = redetect, min_contrast
    n = len(ref)
    positions = np.empty((n_frames, n, 2), np.float32)
    valid = np.zeros((n_frames, n), bool)
    positions[reference_index] = ref
    valid[reference_index] = True

    def step(t_prev: int, t: int) -> None:
        positions[t], valid[t] = follow.step(grays[t_prev], positions[t_prev], valid[t_prev], grays[t])

    for t in range(reference_index + 1, n_frames):
        step(t - 1, t)
    for t in range(reference_index - 1, -1, -1):
        step(t + 1, t)

    depth = _depth_proxy(frames, positions, reference_index, diameter)
    ref, size = ref.astype(np.float32), (int(h), int(w))
    return MarkerTrack(positions, valid, depth, ref, int(reference_index), size, float(follow.spacing), float(diameter))


def _drop_collisions(pos: np.ndarray, ok: np.ndarray, fb: np.ndarray, radius: float) -> None:
    """Invalidate (in place) the worse of any two valid tracks closer than ``radius`` px."""
    idx = np.flatnonzero(ok)
    if len(idx) < 2:
        return
    p = pos[idx]
    d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=-1)
    iu, ju = np.nonzero(np.triu(d < radius, k=1))
    for a, b in zip(idx[iu], idx[ju]):
        if ok[a] and ok[b]:
            ok[a if fb[a] >= fb[b] else b] = False


def _estimate_lost(
    pos: np.ndarray, ok: np.ndarray, ref: np.ndarray, nbrs: np.ndarray, prev_pos: np.ndarray, lost: np.ndarray
) -> np.ndarray:
    """Estimated ``(len(lost), 2)`` positions: reference + median displacement of valid neighbours.

    Falls back to the median displacement of all valid markers, then to the previous position.
    """
    if not ok.any():
        return prev_pos[lost]
    disp = pos - ref
    med = _neighbour_median(disp, ok, nbrs)[lost]
    med = np.where(np.isnan(med), np.median(disp[ok], axis=0), med)
    return (ref[lost] + med).astype(np.float32)


def _reacquire(
    gray: np.ndarray,
    blackhat: np.ndarray,
    pos: np.ndarray,
    ok: np.ndarray,
    lost: np.ndarray,
    diameter: float,
    spacing: float,
    min_contrast: float,
) -> None:
    """Give free detected blobs to the nearest lost markers (in place on ``pos`` and ``ok``)."""
    blobs = _detect(gray, diameter, min_contrast, 1, blackhat).centres
    if len(blobs) == 0:
        return
    tracked = pos[ok]
    if len(tracked):
        # A blob near a tracked marker belongs to it, not to a lost one.
        d_tr = np.linalg.norm(blobs[:, None, :] - tracked[None, :, :], axis=-1).min(axis=1)
        blobs = blobs[d_tr > 0.4 * spacing]
    if len(blobs) == 0:
        return
    d = np.linalg.norm(pos[lost][:, None, :] - blobs[None, :, :], axis=-1)
    radius = 0.3 * spacing
    while d.size and d.min() < radius:
        i, j = np.unravel_index(np.argmin(d), d.shape)
        pos[lost[i]] = blobs[j]
        ok[lost[i]] = True
        d[i, :] = np.inf
        d[:, j] = np.inf


def _depth_proxy(frames: np.ndarray, positions: np.ndarray, reference_index: int, diameter: float) -> np.ndarray:
    """float32 ``(T, N)`` shading-change magnitude at each marker vs the reference (see MarkerTrack)."""
    if frames.ndim == 3:  # grey video: one channel
        frames = frames[..., None]
    kernel = _closing_kernel(diameter / 2.0)  # the backgrounds are at half resolution
    # Both frames are sampled at the marker's current pixel: the lighting varies across the image
    # (vignetting, colour gradients), so comparing against the reference at the marker's old
    # position would report in-plane shear of a flat gel as "depth". The closing has replaced the
    # marker by the shading around it, so the marker's own darkness does not enter.
    ref_bg = _background(frames[reference_index], kernel)
    depth = np.empty(positions.shape[:2], np.float32)
    for t in range(len(frames)):
        xy = positions[t] / 2.0
        diff = _sample(_background(frames[t], kernel), xy) - _sample(ref_bg, xy)
        depth[t] = np.linalg.norm(diff, axis=1) / 255.0
    return depth
