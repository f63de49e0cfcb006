"""Scores with no learning, computed on the frames a detector is judged on: what a detector's figure
must beat before it says anything about the network.

* ``frame_difference``: the grasp's largest mean absolute difference between consecutive frames
  (any sudden change of the gel's image);
* ``mean_frame_difference``: the same difference averaged over the grasp (how much the gel's image
  keeps moving: motion energy);
* ``difference_to_contact``: the largest mean absolute difference of a frame to the first frame in
  contact (how far the gel's image moves from the grasp's start);
* the majority class (:func:`slipsense.measures.slipped_or_held.majority_measure`), which needs no frames.

The judge (:func:`slipsense.evaluation.judge.baseline_scores`) reads grey frames of :data:`SIZE` from the frame cache (the conversion the detectors
use) and take the largest value over a run's cameras; intensities are 8-bit units.
"""

from __future__ import annotations

import numpy as np


#: ``(h, w)`` of the grey frames the baselines read.
SIZE = (60, 80)

NAMES = ("frame_difference", "mean_frame_difference", "difference_to_contact")


def frame_scores(gray: np.ndarray, contact_start: int = 0, start: int = 0) -> dict[str, float]:
    """Both frame scores of one camera's grey frames ``(N, h, w)`` uint8, from frame ``start`` on."""
    g = np.asarray(gray, np.float32)[start:]
    if len(g) < 2:
        return {name: 0.0 for name in NAMES}
    first = min(max(contact_start - start, 0), len(g) - 1)
    step = np.abs(np.diff(g, axis=0)).mean(axis=(1, 2))
    return {
        "frame_difference": float(step.max()),
        "mean_frame_difference": float(step.mean()),
        "difference_to_contact": float(np.abs(g[first:] - g[first]).mean(axis=(1, 2)).max()),
    }
