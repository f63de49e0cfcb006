"""The most slips a folds report's detectors could warn of at a given number of false-positive grasps,
with the operating point tuned on the held-out runs themselves (``python -m studies grasp ceiling REPORT``).

Tuning on the test objects is what no user can do, so these are bounds on what any choice of the
operating point could give these traces, not results:

* **one threshold** (and debounce) for every fold: how well the pooled traces rank the frames before
  a slip above the held grasps';
* **a threshold per fold** (each fold's detector its own, as ``grasp folds`` does), the false-positive
  grasps counted over all folds. Tuned on each fold's ~30 runs, it is optimistic as well as a bound.

The search is exact: a run's outcome changes only where the threshold crosses its highest debounced
value (held runs) or its highest before and inside the warning window (slip runs), and every such
value is tried (debounces 1, 2, 3, 5).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from slipsense.errors import InputError
from slipsense.measures.registry import horizon_frames
from slipsense.training.grasp_detector import sensor_rate, stored_trace
from slipsense.measures.pergrasp import STARTUP

DEBOUNCES = (1, 2, 3, 5)


def held_out_traces(report: Path):
    """``(probabilities, moments, horizon, fold of each run)`` of a report's held-out runs; InputError
    naming the report when its fold files (the per-run traces, kept out of git) are missing."""
    try:
        summary = json.loads((report / "folds.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(report / "folds.json", f"not a readable folds report ({exc})") from None
    files = sorted(report.glob("fold[0-9]*.json"))
    if not files or len(files) != summary.get("folds", len(files)):
        raise InputError(report, "its fold files (per-run traces) are missing: rerun its `grasp folds` command")
    # the report's own horizon (frames at its sensor's rate), else the horizon's seconds at that rate
    horizon = summary.get("train_config", {}).get("horizon") or horizon_frames(sensor_rate(summary, str(report)))
    probabilities, moments, folds = [], [], []
    for k, path in enumerate(files):
        for run in json.loads(path.read_text())["runs"]:
            probabilities.append(stored_trace(run))
            moments.append(run["moment_of_slip"])
            folds.append(k)
    return probabilities, moments, horizon, np.array(folds)


def _levels(p: np.ndarray, frames: int) -> np.ndarray:
    """``(N,)`` the highest threshold at which :func:`pergrasp.debounce` alarms at each frame."""
    x = np.nan_to_num(p, nan=-np.inf)
    out = x.copy()
    for d in range(1, frames):
        out[d:] = np.minimum(out[d:], x[:-d])
        out[:d] = -np.inf
    return out


def run_extremes(probabilities, moments, horizon, frames):
    """Per run ``(highest level before the warning window, highest inside it)``; a held run's whole
    scored trace counts as "before" (any alarm is a false positive)."""
    out = []
    for p, m in zip(probabilities, moments):
        lv = _levels(p, frames)
        end = len(lv) if m is None else min(m + 1, len(lv))
        cut = end if m is None else max(STARTUP, min(end, m - horizon))
        before, inside = lv[STARTUP:cut], lv[cut:end]
        out.append((before.max(initial=-np.inf), inside.max(initial=-np.inf)))
    return np.array(out)


def points(probabilities, moments, horizon):
    """Every distinct outcome of one threshold and debounce over these runs: rows of
    ``(false-positive grasps, warned, premature, threshold, debounce)``."""
    slip = np.array([m is not None for m in moments])
    rows = []
    for frames in DEBOUNCES:
        ext = run_extremes(probabilities, moments, horizon, frames)
        values = np.unique(ext[np.isfinite(ext)])
        for th in np.concatenate([values, [np.inf]]):
            before, inside = ext[:, 0] >= th, ext[:, 1] >= th
            fp = int((before & ~slip).sum())
            premature = int((before & slip).sum())
            warned = int((~before & inside & slip).sum())
            rows.append((fp, warned, premature, float(th), frames))
    return rows


def best_by_fp(rows, max_fp):
    """``best[k]``: the row warning of the most slips (then fewest premature) at exactly ``k`` or
    fewer false-positive grasps, for ``k`` in ``0..max_fp``."""
    best = [None] * (max_fp + 1)
    for row in rows:
        for k in range(row[0], max_fp + 1):
            if best[k] is None or (row[1], -row[2]) > (best[k][1], -best[k][2]):
                best[k] = row
    return best


def one_threshold(traces, max_fp):
    probabilities, moments, horizon, _ = traces
    return best_by_fp(points(probabilities, moments, horizon), max_fp)[max_fp]


def per_fold(traces, max_fp):
    """``(warned, premature)`` at most ``max_fp`` false-positive grasps over all folds, each fold at
    its own threshold (a knapsack over folds)."""
    probabilities, moments, horizon, folds = traces
    total = {0: (0, 0)}  # false positives so far -> (warned, -premature)
    for k in np.unique(folds):
        idx = np.flatnonzero(folds == k)
        best = best_by_fp(points([probabilities[i] for i in idx], [moments[i] for i in idx], horizon), max_fp)
        step = {}
        for used, (w, neg_p) in total.items():
            for fp, row in enumerate(best):
                if row is None or used + fp > max_fp:
                    continue
                cand = (w + row[1], neg_p - row[2])
                if cand > step.get(used + fp, (-1, 0)):
                    step[used + fp] = cand
        total = step
    w, neg_p = max(total.values())
    return w, -neg_p


def phases(traces) -> dict[str, list[int] | int]:
    """Where the held grasps' ten highest peaks lie, and when the slips are lost (frames from the start)."""
    probabilities, moments = traces[0], traces[1]
    scored = [np.where(np.arange(len(p)) >= STARTUP, p, np.nan) for p in probabilities]
    held = sorted((np.nanmax(p), int(np.nanargmax(p))) for p, m in zip(scored, moments) if m is None)
    lost = np.array([m for m in moments if m is not None])
    return {
        "held_peaks": sorted(t for _, t in held[-10:]),
        "lost_before_60": int((lost < 60).sum()),
        "lost_60_150": int(((lost >= 60) & (lost <= 150)).sum()),
        "lost_after_150": int((lost > 150).sum()),
    }
