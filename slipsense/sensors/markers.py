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
   per sensor for models.

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
"""
from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Sequence

import cv2
import numpy as np

from ..errors import InputError

#: Frames skipped by default at the start of a recording (camera start-up transient).
STARTUP_FRAMES = 10

#: Nominal millimetres per pixel of a GelSight Mini at 320 x 240 px (18.6 mm / 320 px ~ 14.3 mm / 240 px).
DEFAULT_MM_PER_PX = 0.0585

#: Marker diameter assumed before one is measured, in pixels (GelSight Mini at 320 x 240: 10-18 px).
_DEFAULT_DIAMETER = 17.0

#: Bump when detection, tracking or the cache layout changes, so stale cache files are ignored.
CACHE_VERSION = 2  # 2: a .json sidecar (sha256, inputs) beside each entry

# Neighbours (in the reference layout) used for the jump check and for predicting lost markers.
_K_NEIGHBOURS = 6

# A tracked point counts as on its marker while the image there is at least this fraction as
# dark (below the local background) as the marker was in the reference frame.
_MIN_CONTRAST_FRACTION = 0.35


# --------------------------------------------------------------------------------------------
# Detection
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Blobs:
    centres: np.ndarray  # (N, 2) float32, (x, y) px
    areas: np.ndarray  # (N,) float32, px^2 (component area at the threshold level it was found)
    base: np.ndarray  # (N,) bool, found at the base threshold (its area measures the marker size)


def _odd(n: float) -> int:
    n = int(round(n))
    return n if n % 2 else n + 1


def _as_gray(frame: np.ndarray, source: Any = None) -> np.ndarray:
    """uint8 (H, W) grey image from a uint8 BGR (H, W, 3) or grey (H, W) frame."""
    frame = np.asarray(frame)
    if frame.dtype != np.uint8:
        raise InputError(source, f"marker frame must be uint8, got {frame.dtype}")
    if frame.ndim == 3 and frame.shape[2] == 3:
        return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    if frame.ndim == 2:
        return frame
    raise InputError(source, f"marker frame must be (H, W, 3) BGR or (H, W) grey, got shape {frame.shape}")


def _closing_kernel(diameter: float) -> np.ndarray:
    # The closing must fill a whole (blurred) marker, so the element has to be wider than one;
    # much wider only lets more of the broad contact shading into the black-hat.
    size = _odd(max(1.4 * diameter, diameter + 6.0))
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))


def _median_nn_distance(points: np.ndarray) -> float:
    """Median distance (px) from each point to its nearest neighbour; nan for fewer than 2 points."""
    if len(points) < 2:
        return float("nan")
    d = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    return float(np.median(d.min(axis=1)))


def _diameter_from_areas(areas: np.ndarray) -> float:
    """Equivalent-circle diameter (px) of the median thresholded area (px^2)."""
    return float(2.0 * np.sqrt(np.median(areas) / np.pi))


def _blob_diameter(blobs: "_Blobs") -> float:
    """Marker diameter (px) from the blobs found at the base threshold (all blobs if none)."""
    areas = blobs.areas[blobs.base] if blobs.base.any() else blobs.areas
    return _diameter_from_areas(areas)


#: Thresholds, as multiples of the base (Otsu) threshold, tried in turn. Under contact a marker
#: can touch a dark imprint edge and merge with it at the base level; its darker core separates
#: again at a higher level, while faint shading never reaches those levels.
_LEVELS = (1.0, 1.7, 2.5)


def _components(
    blackhat: np.ndarray, thresh: float, ref_area: float | None, min_frac: float, border: int
) -> tuple[np.ndarray, np.ndarray, float]:
    """Round blobs of ``blackhat > thresh``: centres ``(K, 2)`` px, areas ``(K,)`` px^2, ref area.

    ``ref_area`` None takes the median area of the non-speck components as the marker area.
    """
    h, w = blackhat.shape
    none = (np.zeros((0, 2), np.float32), np.zeros((0,), np.float32), ref_area or 0.0)
    mask = (blackhat > thresh).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return none
    areas = stats[1:, cv2.CC_STAT_AREA].astype(np.float64)
    if ref_area is None:
        big = areas[areas >= 20]
        if len(big) == 0:
            return none
        ref_area = float(np.median(big))
    # Shape and border rules, on the component statistics of all blobs at once.
    x, y = stats[1:, cv2.CC_STAT_LEFT], stats[1:, cv2.CC_STAT_TOP]
    bw, bh = stats[1:, cv2.CC_STAT_WIDTH], stats[1:, cv2.CC_STAT_HEIGHT]
    good = (areas >= min_frac * ref_area) & (areas <= 2.5 * ref_area)
    # Blobs cut by the image edge have biased centroids and leave the view first.
    good &= (x >= border) & (y >= border) & (x + bw <= w - border) & (y + bh <= h - border)
    # Lines and edges of imprinted objects are not round: low fill ratio or elongated boxes.
    good &= (areas / (bw * bh) >= 0.45) & (np.maximum(bw, bh) <= 2.5 * np.minimum(bw, bh))
    if not good.any():
        return none[:2] + (ref_area,)
    # Sub-pixel centres: black-hat-weighted centroids over each component grown by one pixel,
    # since the grey-level falloff at the marker rim carries the sub-pixel position. Growing the
    # label image by a 3x3 dilation hands each rim pixel to its (only) neighbouring component.
    # (float32 labels: exact below 2**24 and accepted by cv2.dilate, unlike int32.)
    grown = cv2.dilate(labels.astype(np.float32), np.ones((3, 3), np.uint8)).ravel()
    pix = np.flatnonzero(grown)  # only blob pixels: a few percent of the frame
    lab = grown[pix].astype(np.int64)
    wts = blackhat.ravel()[pix].astype(np.float64)
    ys, xs = np.divmod(pix, w)
    total = np.bincount(lab, weights=wts, minlength=n)[1:]
    cx = np.bincount(lab, weights=wts * xs, minlength=n)[1:]
    cy = np.bincount(lab, weights=wts * ys, minlength=n)[1:]
    good &= total > 0
    pts = np.stack([cx[good] / total[good], cy[good] / total[good]], axis=1).astype(np.float32)
    return pts, areas[good].astype(np.float32), ref_area


def _dedupe(pts: np.ndarray, rank: np.ndarray, radius: float) -> np.ndarray:
    """bool mask keeping, of points closer than ``radius`` px, the one ranked first (lowest rank)."""
    keep = np.ones(len(pts), bool)
    if len(pts) < 2:
        return keep
    d = np.linalg.norm(pts[:, None, :] - pts[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    for i in np.argsort(rank, kind="stable"):
        if keep[i]:
            close = (d[i] < radius) & keep
            close[i] = False
            keep[close] = False
    return keep


def _blackhat(gray: np.ndarray, diameter: float | None) -> np.ndarray:
    """uint8 ``(H, W)`` darkness below the local background (grey levels), markers bright."""
    # A light blur stops the markers' speckled interior from splitting them into pieces.
    smooth = cv2.GaussianBlur(gray, (3, 3), 0)
    return cv2.morphologyEx(smooth, cv2.MORPH_BLACKHAT, _closing_kernel(diameter or _DEFAULT_DIAMETER))


def _detect(
    gray: np.ndarray,
    diameter: float | None,
    min_contrast: float,
    border: int,
    blackhat: np.ndarray | None = None,
) -> _Blobs:
    """Dark-blob candidates on a grey frame (see :func:`detect_markers` for the rules).

    ``blackhat``: :func:`_blackhat` of ``gray`` with the same ``diameter``, when already computed.
    """
    if blackhat is None:
        blackhat = _blackhat(gray, diameter)
    otsu, _ = cv2.threshold(blackhat, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    # The floor keeps a frame without markers (flat or noisy) from yielding noise blobs.
    base = max(float(otsu), float(min_contrast))
    # A known diameter fixes the expected area (a contact frame can be dominated by deformed
    # blobs); otherwise the base level's median blob sets it.
    ref_area = None if diameter is None else np.pi * (diameter / 2.0) ** 2
    peak = float(blackhat.max())

    pts, areas, ref_area = _components(blackhat, base, ref_area, 0.3, border)
    empty = _Blobs(np.zeros((0, 2), np.float32), np.zeros((0,), np.float32), np.zeros((0,), bool))
    if not ref_area:
        return empty
    # Grid rule: markers are never closer than about one spacing. A pair much closer than the
    # median spacing is a marker plus a speck (or a split marker): keep the larger blob.
    spacing = _median_nn_distance(pts) if len(pts) > 2 else np.nan
    if not np.isfinite(spacing):
        spacing = 2.0 * _diameter_from_areas(np.array([ref_area]))  # typical pitch / diameter ~ 2-3
    keep = _dedupe(pts, -areas, 0.5 * spacing)
    pts, areas = pts[keep], areas[keep]
    base_level = np.ones(len(pts), bool)

    for level in _LEVELS[1:]:
        if base * level >= peak:
            break
        # Blobs shrink as the threshold rises, hence the lower area bound.
        cand, cand_areas, _ = _components(blackhat, base * level, ref_area, 0.3 / level, border)
        if len(cand) == 0:
            continue
        if len(pts):
            far = np.linalg.norm(cand[:, None, :] - pts[None, :, :], axis=-1).min(axis=1) > 0.6 * spacing
            cand, cand_areas = cand[far], cand_areas[far]
        # A marker cut by the image edge can have a core that no longer touches the edge at a
        # high level: judge it by its full (base-level) radius instead.
        r = np.sqrt(ref_area / np.pi)
        h, w = blackhat.shape
        inside = (cand[:, 0] - r >= border) & (cand[:, 0] + r <= w - 1 - border)
        inside &= (cand[:, 1] - r >= border) & (cand[:, 1] + r <= h - 1 - border)
        cand, cand_areas = cand[inside], cand_areas[inside]
        keep = _dedupe(cand, -cand_areas, 0.5 * spacing)
        pts = np.concatenate([pts, cand[keep]])
        areas = np.concatenate([areas, cand_areas[keep]])
        base_level = np.concatenate([base_level, np.zeros(int(keep.sum()), bool)])
    return _Blobs(pts.astype(np.float32), areas.astype(np.float32), base_level)


def _detect_scaled(
    gray: np.ndarray, diameter: float | None, min_contrast: float, border: int
) -> tuple[_Blobs, float]:
    """Detect; without a known diameter, measure it and redo once if the first guess was far off.

    Returns the blobs and the marker diameter in px (measured, given, or the default guess).
    """
    blobs = _detect(gray, diameter, min_contrast, border)
    if diameter is not None:
        return blobs, float(diameter)
    if len(blobs.areas) == 0:
        return blobs, _DEFAULT_DIAMETER
    measured = _blob_diameter(blobs)
    if abs(measured - _DEFAULT_DIAMETER) > 0.3 * _DEFAULT_DIAMETER:
        # The black-hat element was sized for the default; a very different marker size needs
        # its own (too small an element hollows large markers out).
        blobs = _detect(gray, measured, min_contrast, border)
        if len(blobs.areas):
            measured = _blob_diameter(blobs)
    return blobs, measured


def detect_markers(
    frame: np.ndarray,
    *,
    marker_diameter: float | None = None,
    min_contrast: float = 12.0,
    border: int = 1,
    min_markers: int = 4,
    source: str | Path | None = None,
) -> np.ndarray:
    """Find the dark gel markers on one tactile frame.

    Args:
        frame: uint8 image, ``(H, W, 3)`` BGR or ``(H, W)`` grey. Use a frame after the camera
            start-up transient (e.g. frame :data:`STARTUP_FRAMES` of a recording).
        marker_diameter: expected marker diameter in px; None measures it (first pass sized for
            17 px, repeated once with the measured size when that differs by more than 30 %).
        min_contrast: least darkness of a marker below its surroundings, in grey levels (0-255);
            the Otsu threshold on the black-hat image is never set below it.
        border: blobs whose bounding box comes closer than this many px to the image edge are
            rejected (1 = reject blobs touching the edge).
        min_markers: fewer markers than this is an error.
        source: file named in errors.

    Returns:
        float32 ``(N, 2)`` marker centres ``(x, y)`` in px, sub-pixel, in row-major order
        (see :func:`order_markers`).

    Raises:
        InputError: the frame is not a uint8 image, or fewer than ``min_markers`` markers were
            found (a frame without markers, or not a marker-gel image at all).
    """
    gray = _as_gray(frame, source)
    blobs, _ = _detect_scaled(gray, marker_diameter, min_contrast, border)
    _require(blobs, min_markers, "the frame", source)
    return blobs.centres[order_markers(blobs.centres)]


def _require(blobs: _Blobs, min_markers: int, what: str, source: Any) -> None:
    if len(blobs.centres) < min_markers:
        raise InputError(
            source,
            f"found {len(blobs.centres)} markers on {what}, need at least {min_markers} "
            "(is it a marker-gel tactile image, after the camera start-up?)",
        )


def order_markers(points: np.ndarray, spacing: float | None = None) -> np.ndarray:
    """Row-major order of grid points: indices sorting them into rows (top to bottom), then by x.

    A new row starts where a point's y exceeds the current row's mean y by more than half the
    grid spacing (``spacing`` px, default: median nearest-neighbour distance), which tolerates the
    few-pixel waviness and small rotation of a real marker grid.

    Args:
        points: ``(N, 2)`` positions ``(x, y)`` in px.
    Returns:
        int64 ``(N,)`` indices into ``points``.
    """
    points = np.asarray(points, np.float64).reshape(-1, 2)
    if len(points) == 0:
        return np.zeros((0,), np.int64)
    if spacing is None:
        spacing = _median_nn_distance(points)
    if not np.isfinite(spacing) or spacing <= 0:
        return np.lexsort((points[:, 0], points[:, 1]))
    by_y = np.argsort(points[:, 1], kind="stable")
    rows: list[list[int]] = [[int(by_y[0])]]
    for i in by_y[1:]:
        row_y = points[rows[-1], 1].mean()
        if points[i, 1] - row_y > 0.5 * spacing:
            rows.append([int(i)])
        else:
            rows[-1].append(int(i))
    order = [i for row in rows for i in sorted(row, key=lambda j: points[j, 0])]
    return np.asarray(order, np.int64)


# --------------------------------------------------------------------------------------------
# Track container
# --------------------------------------------------------------------------------------------


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

    def lost_fraction(self, start: int | None = None, stop: int | None = None) -> float:
        """Fraction of (frame, marker) entries in frames ``[start, stop)`` that are not valid."""
        v = self.valid[start:stop]
        return float(1.0 - v.mean()) if v.size else 0.0

    def to_cloud(
        self,
        normalise: bool = True,
        *,
        mm_per_px: float = DEFAULT_MM_PER_PX,
        relative: bool = False,
    ) -> np.ndarray:
        """Per-frame marker clouds ``(x, y, depth)`` for STNet-style point-cloud models.

        Args:
            normalise: True: x, y relative to the image centre, divided by half the larger image
                side (x in [-1, 1], y in [-H/W, H/W]; one scale for both axes keeps directions);
                False: x, y in mm relative to the image centre, via ``mm_per_px``.
            mm_per_px: pixel size in mm, used when ``normalise`` is False.
            relative: use the displacement from the reference frame instead of the position
                (same scaling, no centring).

        Returns:
            float32 ``(T, N, 3)``: x, y as above and the unitless depth proxy (:attr:`depth`).
        """
        h, w = self.frame_size
        if relative:
            xy = self.displacement().astype(np.float64)
        else:
            centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
            xy = self.positions.astype(np.float64) - centre
        xy = xy / (max(h, w) / 2.0) if normalise else xy * mm_per_px
        return np.concatenate([xy, self.depth[..., None]], axis=-1).astype(np.float32)

    # -- persistence (cache) ------------------------------------------------------------------

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Plain arrays for ``np.savez`` (inverse: :meth:`from_arrays`)."""
        return {
            "positions": self.positions,
            "valid": self.valid,
            "depth": self.depth,
            "reference_positions": self.reference_positions,
            "reference_index": np.int64(self.reference_index),
            "frame_size": np.asarray(self.frame_size, np.int64),
            "spacing": np.float64(self.spacing),
            "diameter": np.float64(self.diameter),
        }

    @classmethod
    def from_arrays(cls, arrays: Any) -> "MarkerTrack":
        """Rebuild from :meth:`to_arrays` output (or the ``np.load`` of its ``.npz``)."""
        fs = np.asarray(arrays["frame_size"]).tolist()
        return cls(
            positions=np.asarray(arrays["positions"], np.float32),
            valid=np.asarray(arrays["valid"], bool),
            depth=np.asarray(arrays["depth"], np.float32),
            reference_positions=np.asarray(arrays["reference_positions"], np.float32),
            reference_index=int(arrays["reference_index"]),
            frame_size=(int(fs[0]), int(fs[1])),
            spacing=float(arrays["spacing"]),
            diameter=float(arrays["diameter"]),
        )


# --------------------------------------------------------------------------------------------
# Tracking
# --------------------------------------------------------------------------------------------


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
    n = len(ref)
    spacing = _median_nn_distance(ref)
    if not np.isfinite(spacing):
        spacing = 2.0 * diameter  # a single marker: assume the usual grid pitch
    if win_size is None:
        win_size = int(np.clip(_odd(0.7 * spacing), 11, 41))
    win = (int(win_size), int(win_size))
    jump = float(max_jump) if max_jump is not None else 0.25 * spacing
    # Per-marker edge margin: half a marker radius (a marker cut that far loses about a fifth of
    # its disc and its LK position drifts by up to ~1 px), but never more than the marker's own
    # margin in the reference frame less 1 px. Losing markers as soon as they touch the edge
    # instead would drop whole border rows at the slightest shear.
    ref_margin = np.minimum(ref.min(axis=1), np.minimum(w - 1 - ref[:, 0], h - 1 - ref[:, 1]))
    edge = np.clip(np.minimum(diameter / 4.0, ref_margin - 1.0), 0.0, None)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
    nbrs = _neighbours(ref, _K_NEIGHBOURS)

    positions = np.empty((n_frames, n, 2), np.float32)
    valid = np.zeros((n_frames, n), bool)
    positions[reference_index] = ref
    valid[reference_index] = True
    # Each marker's darkness in the reference frame, for the appearance check.
    ref_contrast = _sample(_blackhat(grays[reference_index], diameter).astype(np.float32), ref)[:, 0]

    # The Python binding of calcOpticalFlowPyrLK in OpenCV 5 takes images only (not prebuilt
    # pyramids), so each call builds its own; at 320 x 240 that costs well under a millisecond.
    def lk(src: Any, dst: Any, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        out, status, _err = cv2.calcOpticalFlowPyrLK(
            src, dst, pts.reshape(-1, 1, 2).astype(np.float32), None,
            winSize=win, maxLevel=max_level, criteria=criteria,
        )
        return out.reshape(-1, 2), status.reshape(-1).astype(bool)

    def step(t_prev: int, t: int) -> None:
        prev_pos, prev_ok = positions[t_prev], valid[t_prev]
        pos = prev_pos.copy()
        ok = np.zeros(n, bool)
        idx = np.flatnonzero(prev_ok)
        blackhat = _blackhat(grays[t], diameter)
        if len(idx):
            p0 = prev_pos[idx]
            src, dst = grays[t_prev], grays[t]
            p1, st1 = lk(src, dst, p0)
            p0r, st2 = lk(dst, src, p1)
            fb = np.full(n, np.inf)
            fb[idx] = np.linalg.norm(p0r - p0, axis=1)
            # A marker reaching the edge is cut by it and its LK position is biased: lost.
            m = edge[idx]
            inside = (p1[:, 0] >= m) & (p1[:, 0] <= w - 1 - m) & (p1[:, 1] >= m) & (p1[:, 1] <= h - 1 - m)
            pos[idx] = p1
            ok[idx] = st1 & st2 & inside & (fb[idx] <= fb_threshold)
            # Jump check: compare each step with the median step of its valid neighbours.
            motion = pos - prev_pos
            med = _neighbour_median(motion, ok, nbrs)
            dev = np.linalg.norm(motion - med, axis=1)
            dev = np.where(np.isnan(dev), 0.0, dev)  # no valid neighbour: nothing to compare with
            ok &= (dev <= jump) & (np.linalg.norm(motion, axis=1) <= 0.5 * spacing)
            # Appearance check: LK happily holds a point on a flat patch where a marker vanished
            # (covered, out of focus, left the gel), so the point must still be on a dark spot.
            darkness = _sample(blackhat.astype(np.float32), pos)[:, 0]
            ok &= darkness >= _MIN_CONTRAST_FRACTION * ref_contrast
            _drop_collisions(pos, ok, fb, 0.35 * spacing)
        lost = np.flatnonzero(~ok)
        if len(lost):
            pos[lost] = _estimate_lost(pos, ok, ref, nbrs, prev_pos, lost)
            if redetect:
                _reacquire(grays[t], blackhat, pos, ok, lost, diameter, spacing, min_contrast)
        positions[t] = pos
        valid[t] = ok

    for t in range(reference_index + 1, n_frames):
        step(t - 1, t)
    for t in range(reference_index - 1, -1, -1):
        step(t + 1, t)

    depth = _depth_proxy(frames, positions, reference_index, diameter)
    return MarkerTrack(
        positions=positions,
        valid=valid,
        depth=depth,
        reference_positions=ref.astype(np.float32),
        reference_index=int(reference_index),
        frame_size=(int(h), int(w)),
        spacing=float(spacing),
        diameter=float(diameter),
    )


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


# --------------------------------------------------------------------------------------------
# Fixed-size marker sets for models
# --------------------------------------------------------------------------------------------


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


def marker_sequences(
    track: MarkerTrack,
    n_markers: int,
    *,
    normalise: bool = True,
    mm_per_px: float = DEFAULT_MM_PER_PX,
    relative: bool = False,
    return_mask: bool = False,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """A fixed number of marker clouds per frame, in a stable order, for models.

    Markers are chosen and ordered by :func:`select_markers` (closest to the image centre, then
    row-major). Values are :meth:`MarkerTrack.to_cloud` (``normalise``, ``mm_per_px`` and
    ``relative`` passed through). When the track has fewer than ``n_markers`` markers the missing
    slots are padded at the end with zeros (the image centre and zero depth; zero displacement
    when ``relative``) and masked out.

    Returns:
        float32 ``(T, n_markers, 3)``; with ``return_mask`` also bool ``(T, n_markers)``, True where
        the slot holds a real marker that was validly tracked in that frame.
    """
    idx = select_markers(track, n_markers)
    cloud = track.to_cloud(normalise, mm_per_px=mm_per_px, relative=relative)
    out = np.zeros((track.n_frames, n_markers, 3), np.float32)
    mask = np.zeros((track.n_frames, n_markers), bool)
    out[:, : len(idx)] = cloud[:, idx]
    mask[:, : len(idx)] = track.valid[:, idx]
    return (out, mask) if return_mask else out


# --------------------------------------------------------------------------------------------
# Recordings and cache
# --------------------------------------------------------------------------------------------


def track_recording(
    path: str | Path,
    reference_index: int | None = None,
    *,
    expected_size: tuple[int, int] | None = (240, 320),
    **track_kwargs: Any,
) -> MarkerTrack:
    """Decode a video (:func:`slipsense.recordings.video.read_video`) and track its markers.

    ``track_kwargs`` go to :func:`track_markers`. Raises InputError naming ``path`` for unreadable
    videos and for reference frames without markers.
    """
    from ..recordings.video import read_video

    frames = read_video(path, expected_size=expected_size, min_frames=2)
    return track_markers(frames, reference_index, source=path, **track_kwargs)


def _cache_file(cache_dir: Path, path: Path, params: dict[str, Any]) -> Path:
    """Cache file for ``path`` tracked with ``params``: keyed by path, size, mtime and params."""
    st = path.stat()
    key = json.dumps(
        {
            "version": CACHE_VERSION,
            "path": str(path.resolve()),
            "size": st.st_size,
            "mtime_ns": st.st_mtime_ns,
            "params": params,
        },
        sort_keys=True,
        default=str,
    )
    digest = hashlib.sha256(key.encode()).hexdigest()[:20]
    # Readable prefix (object, experiment, camera) so the folder can be browsed.
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", "-".join(path.parts[-3:-1] + (path.stem,)))
    return cache_dir / f"{stem}-{digest}.npz"


def track_recordings(
    recordings: Iterable[Any],
    reference_index: int | None = None,
    *,
    cache: bool = True,
    cache_dir: str | Path | None = None,
    progress: bool = True,
    expected_size: tuple[int, int] | None = (240, 320),
    **track_kwargs: Any,
) -> list[MarkerTrack]:
    """Track many recordings, caching each result as ``.npz``.

    Args:
        recordings: objects with a ``.path`` (e.g. :class:`slipsense.recordings.types.Recording`)
            or plain paths.
        reference_index, expected_size, track_kwargs: as for :func:`track_recording`.
        cache: read and write the cache. Files live in ``cache_dir`` (default
            ``config.cache_root()/markers``), named by a hash of the video's resolved path, size,
            mtime and all tracking parameters, and are written atomically with a ``.json``
            sidecar (sha256 and inputs, written last); an entry whose checksum or inputs do not
            match, or whose arrays do not fit together or the video, is tracked again with a
            :class:`~slipsense.errors.CacheWarning` and overwritten.
        progress: show a tqdm progress bar.

    Returns:
        one :class:`MarkerTrack` per recording, in order.
    """
    from tqdm.auto import tqdm

    from ..config import cache_root

    items: Sequence[Any] = list(recordings)
    folder = Path(cache_dir) if cache_dir is not None else cache_root() / "markers"
    params = {"reference_index": reference_index, "expected_size": expected_size, **track_kwargs}
    tracks: list[MarkerTrack] = []
    for item in tqdm(items, desc="tracking markers", unit="video", disable=not progress):
        path = Path(getattr(item, "path", item))
        cfile = None
        if cache:
            if not path.is_file():
                raise InputError(path, "video file does not exist")
            cfile = _cache_file(folder, path, params)
            cached = _load_cached_track(cfile, path, params, expected_size)
            if cached is not None:
                tracks.append(cached)
                continue
        track = track_recording(path, reference_index, expected_size=expected_size, **track_kwargs)
        if cfile is not None:
            _save_cached_track(cfile, path, params, track)
        tracks.append(track)
    return tracks


def _identity(path: Path, params: dict[str, Any]) -> str:
    """What a cached track was computed from (the same fields as its file name's hash)."""
    st = path.stat()
    return json.dumps({"version": CACHE_VERSION, "path": str(path.resolve()), "size": st.st_size,
                       "mtime_ns": st.st_mtime_ns, "params": params}, sort_keys=True, default=str)


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _save_cached_track(cfile: Path, path: Path, params: dict[str, Any], track: "MarkerTrack") -> None:
    """Write the track and, last, a sidecar with its sha256 and inputs (a write failure only warns)."""
    import warnings

    from ..atomic import write_text, write_with
    from ..errors import CacheWarning

    arrays = track.to_arrays()
    digest: list[str] = []

    def writer(tmp: Path) -> None:
        np.savez(tmp, **arrays)
        digest.append(_sha256(tmp))

    try:
        write_with(cfile, writer)
        write_text(cfile.with_suffix(".json"), json.dumps({"sha256": digest[0], "inputs": _identity(path, params)}))
    except OSError as exc:
        warnings.warn(f"{cfile}: cannot write the marker cache ({exc}); continuing without it", CacheWarning,
                      stacklevel=3)


def check_track(track: "MarkerTrack", expected_size: tuple[int, int] | None = None,
                n_frames: int | None = None) -> None:
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
    if n_frames is not None and t != n_frames:
        raise ValueError(f"{t} frames tracked but the video has {n_frames}")


def _load_cached_track(cfile: Path, path: Path, params: dict[str, Any],
                       expected_size: tuple[int, int] | None) -> "MarkerTrack | None":
    """A cached track that passes its checksum, records these inputs and is consistent; None when
    absent, otherwise warned about (:class:`~slipsense.errors.CacheWarning`) and None."""
    import warnings
    import zipfile

    from ..errors import CacheWarning
    from ..recordings.video import TRUNCATION_TOLERANCE, frame_count

    sidecar = cfile.with_suffix(".json")
    if not cfile.is_file() and not sidecar.is_file():
        return None
    try:
        info = json.loads(sidecar.read_text(encoding="utf-8"))
        if not isinstance(info, dict) or info.get("inputs") != _identity(path, params):
            raise ValueError("made from another video or other settings")
        if info.get("sha256") != _sha256(cfile):
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


# --------------------------------------------------------------------------------------------
# Figures
# --------------------------------------------------------------------------------------------


def plot_displacement(
    track: MarkerTrack,
    frame_index: int,
    image: np.ndarray | None = None,
    ax: Any = None,
    *,
    scale: float | None = None,
) -> Any:
    """Quiver plot of marker displacement in one frame, over the tactile image.

    Arrows start at the reference positions and show the displacement to ``frame_index``,
    magnified ``scale`` times (None: so the longest arrow is one marker spacing long, at least 1x;
    the factor is in the title). Lost markers are drawn as red crosses at their estimated position.

    Args:
        track: the tracked video.
        frame_index: frame to show.
        image: uint8 ``(H, W, 3)`` BGR frame to draw under the arrows (usually
            ``frames[frame_index]``), or None for an empty axis in image coordinates.
        ax: matplotlib axes; None creates a figure.

    Returns:
        the matplotlib axes.
    """
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(6.4, 4.8))
    h, w = track.frame_size
    if image is not None:
        img = np.asarray(image)
        if img.ndim == 3:
            ax.imshow(img[..., ::-1])  # BGR -> RGB
        else:
            ax.imshow(img, cmap="gray")
    disp = track.displacement()[frame_index]
    ok = track.valid[frame_index]
    ref = track.reference_positions
    if scale is None:
        longest = float(np.linalg.norm(disp[ok], axis=1).max()) if ok.any() else 0.0
        scale = max(1.0, track.spacing / longest) if longest > 0 else 1.0
    ax.quiver(
        ref[ok, 0], ref[ok, 1], disp[ok, 0], disp[ok, 1],
        angles="xy", scale_units="xy", scale=1.0 / scale, color="yellow", width=0.004,
    )
    ax.plot(ref[:, 0], ref[:, 1], ".", color="white", markersize=3)
    if (~ok).any():
        lost = track.positions[frame_index][~ok]
        ax.plot(lost[:, 0], lost[:, 1], "x", color="red", markersize=6)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_title(f"frame {frame_index}: displacement x{scale:.1f} ({int(ok.sum())}/{len(ok)} tracked)")
    return ax
