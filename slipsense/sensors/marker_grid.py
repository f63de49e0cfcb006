"""Markers on a grid: find the grid, and the symmetries of a displacement field on it.

A marker sensor's markers usually sit on a ``rows x cols`` lattice, stored row by row with ``x``
varying fastest (the simulated binocular sensor: 23 x 24). A slip looks the same mirrored or moved
across the gel, so a training window can be turned into another plausible one: mirror the
displacement field left-right or up-down (negating the mirrored component) and shift it by whole
markers (gel the shift uncovers is at rest). This is the marker counterpart of the video models'
flips and crops (:mod:`slipsense.recordings.augment`).

All arrays are millimetres: windows ``(T, M, 3)``, rest positions ``(M, 3)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def rest_estimate(first_frames: np.ndarray, quantile: float = 0.9) -> np.ndarray:
    """The gel at rest ``(M, 3)`` estimated from windows' first frames ``(N, M, 3)``: x and y are the
    per-marker median; z is its upper ``quantile`` (indentation is towards negative z and most
    windows start with something pressed in somewhere, so a median of z sits inside the usual
    contact: on the simulator it is 0.17 mm deep at the gel's centre, where 0.9 is within noise)."""
    f = np.asarray(first_frames, dtype=np.float64)
    rest = np.median(f, axis=0)
    rest[:, 2] = np.quantile(f[:, :, 2], quantile, axis=0)
    return rest.astype(np.float32)


def grid_layout(rest: np.ndarray, tolerance: float = 0.25) -> tuple[int, int] | None:
    """``(rows, cols)`` when the rest positions ``(M, 3)`` form a row-major lattice (``x`` fastest,
    rows in rising ``y``), each marker within ``tolerance`` pitches of its lattice node; else None
    (tracked markers scattered over the gel, for instance)."""
    rest = np.asarray(rest, dtype=np.float64)
    m = len(rest)
    if rest.ndim != 2 or rest.shape[1] < 2 or m < 4:
        return None
    jumps = np.flatnonzero(np.diff(rest[:, 0]) < 0)  # x falls back at the start of every new row
    if len(jumps) == 0:
        return None
    cols = int(jumps[0]) + 1
    if m % cols or cols < 2 or m // cols < 2:
        return None
    rows = m // cols
    g = rest[:, :2].reshape(rows, cols, 2)
    pitch_x = np.median(np.diff(g[:, :, 0], axis=1))
    pitch_y = np.median(np.diff(g[:, :, 1], axis=0))
    if not (pitch_x > 0 and pitch_y > 0):
        return None
    node_x = g[:, :, 0].mean(axis=0, keepdims=True)  # every row shares its columns' x
    node_y = g[:, :, 1].mean(axis=1, keepdims=True)  # every column shares its rows' y
    off = np.maximum(np.abs(g[:, :, 0] - node_x) / pitch_x, np.abs(g[:, :, 1] - node_y) / pitch_y)
    return (rows, cols) if off.max() <= tolerance else None


@dataclass(frozen=True)
class GridMove:
    """One symmetry of the gel: mirror in x and/or y, then shift by ``(shift_rows, shift_cols)``
    markers."""

    flip_x: bool = False
    flip_y: bool = False
    shift_rows: int = 0
    shift_cols: int = 0

    @classmethod
    def draw(cls, rng: np.random.Generator, max_shift: int) -> GridMove:
        flip_x, flip_y = (bool(v) for v in rng.integers(0, 2, 2))
        rows, cols = (int(v) for v in rng.integers(-max_shift, max_shift + 1, 2))
        return cls(flip_x, flip_y, rows, cols)

    def apply(self, window: np.ndarray, rest: np.ndarray, grid: tuple[int, int]) -> np.ndarray:
        """The moved window ``(T, M, 3)``: its displacement from ``rest``, mirrored and shifted on
        the ``grid``, added back to ``rest``."""
        rows, cols = grid
        t = window.shape[0]
        d = (window - rest).reshape(t, rows, cols, 3)
        if self.flip_x:
            d = d[:, :, ::-1].copy()
            d[..., 0] *= -1
        if self.flip_y:
            d = d[:, ::-1].copy()
            d[..., 1] *= -1
        out = np.zeros_like(d)
        sr, sc = self.shift_rows, self.shift_cols
        if abs(sr) < rows and abs(sc) < cols:
            dst_r, src_r = slice(max(sr, 0), rows + min(sr, 0)), slice(max(-sr, 0), rows - max(sr, 0))
            dst_c, src_c = slice(max(sc, 0), cols + min(sc, 0)), slice(max(-sc, 0), cols - max(sc, 0))
            out[:, dst_r, dst_c] = d[:, src_r, src_c]
        return (rest + out.reshape(t, rows * cols, 3)).astype(window.dtype, copy=False)


__all__ = ["GridMove", "grid_layout", "rest_estimate"]
