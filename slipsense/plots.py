"""Pictures a person would rather look at than read: curves, confusion matrices, heat maps."""

from __future__ import annotations

from pathlib import Path
import math
from typing import Any, Mapping, Sequence

import numpy as np

from slipsense.atomic import write_with


def _plt():
    import matplotlib  # here, not at the top: ~0.5 s to import, and only the plots need it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: str | Path) -> Path:
    """Save ``fig`` atomically (120 dpi) and close it."""
    plt = _plt()
    path = Path(path)
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=120, bbox_inches="tight"))
    plt.close(fig)
    return path


def plot_curves(history: Sequence[dict[str, Any]], path: str | Path, title: str = "") -> Path:
    """Loss and accuracy per epoch for train and validation from ``metrics.csv`` rows."""
    plt = _plt()
    epochs = [r["epoch"] for r in history]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.6))
    scored = {k.removesuffix("_accuracy") for r in history for k in r if k.endswith("_accuracy")}
    splits = ["train", "val"] + sorted(scored - {"train", "val"})
    for key, ax in (("loss", a1), ("accuracy", a2)):
        for split in splits:
            vals = [r.get(f"{split}_{key}") for r in history]
            if any(v is not None for v in vals):
                ax.plot(epochs, vals, marker=".", label=split)
        ax.set_xlabel("epoch")
        ax.set_ylabel(key)
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle(title)
    return save_figure(fig, path)


def plot_confusion(cm, path: str | Path, title: str = "") -> Path:
    """2x2 confusion matrix (rows: truth, columns: prediction; wiggle, slip) with counts in the cells."""
    plt = _plt()
    cm = np.asarray(cm)
    fig, ax = plt.subplots(figsize=(3.6, 3.2))
    ax.imshow(cm, cmap="Blues")
    for i in range(2):
        for j in range(2):
            colour = "white" if cm[i, j] > cm.max() / 2 else "black"
            ax.text(j, i, str(cm[i, j]), ha="center", va="center", color=colour, fontsize=13)
    ax.set_xticks([0, 1], ["pred wiggle", "pred slip"])
    ax.set_yticks([0, 1], ["true wiggle", "true slip"])
    ax.set_title(title)
    return save_figure(fig, path)


def plot_tradeoff(rows: Sequence[Mapping[str, Any]], path: str | Path, title: str = "") -> None:
    """Slips warned in time against grasps that held yet alarmed, one labelled point per threshold
    (with 95% bootstrap intervals over runs where the rows carry them)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.2, 4.2))
    xs = [r["false_positive_rate"] for r in rows]
    ys = [r["warned_rate"] for r in rows]
    if all("warned_low" in r for r in rows):  # bootstrap intervals over runs (operating_points.table)
        xerr = [[x - r["fp_low"] for x, r in zip(xs, rows)], [r["fp_high"] - x for x, r in zip(xs, rows)]]
        yerr = [[y - r["warned_low"] for y, r in zip(ys, rows)], [r["warned_high"] - y for y, r in zip(ys, rows)]]
        ax.errorbar(xs, ys, xerr=xerr, yerr=yerr, fmt="none", ecolor="tab:blue", alpha=0.25, lw=1)
    ax.plot(xs, ys, marker="o")
    points: dict[tuple[float, float], list[float]] = {}  # thresholds landing on one point share a label
    for r, x, y in zip(rows, xs, ys):
        if not (math.isnan(x) or math.isnan(y)):
            points.setdefault((x, y), []).append(r["threshold"])
    for xy, ths in points.items():
        label = f"{ths[0]:g}" if len(ths) == 1 else f"{min(ths):g}-{max(ths):g}"
        ax.annotate(label, xy, fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.plot([0, 1], [0, 1], ls=":", color="gray", lw=0.8)
    ax.set_xlabel("grasps that held yet alarmed (false-positive grasps)")
    ax.set_ylabel("slips warned in time (first alarm within the horizon)")
    ax.set_xlim(-0.02, 1.02)
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.set_title(title or "per-grasp early warning (labels: thresholds)", fontsize=9)
    save_figure(fig, path)
