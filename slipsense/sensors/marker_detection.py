"""Marker detection on one marker-gel tactile frame: :func:`detect_markers` and :func:`order_markers`.

Step 1 of the pipeline described in :mod:`slipsense.recordings.markers`. The blob search
(:func:`_detect`) is shared with :mod:`slipsense.sensors.marker_tracking`, which uses it to
re-acquire lost markers.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..errors import InputError

#: Marker diameter assumed before one is measured, in pixels (GelSight Mini at 320 x 240: 10-18 px).
_DEFAULT_DIAMETER = 17.0


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


def _blob_diameter(blobs: "_Blobs") -> float:
    """Marker diameter (px): the equivalent circle of the median area of the blobs found at the base
    threshold (all blobs if none)."""
    areas = blobs.areas[blobs.base] if blobs.base.any() else blobs.areas
    return float(2.0 * np.sqrt(np.median(areas) / np.pi))


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
        spacing = 4.0 * np.sqrt(ref_area / np.pi)  # twice the diameter: typical pitch / diameter ~ 2-3
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


def _detect_scaled(gray: np.ndarray, diameter: float | None, min_contrast: float, border: int) -> tuple[_Blobs, float]:
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
