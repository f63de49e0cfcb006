"""Measures: how well a detector did, from its replayed traces alone: the bottom floor of judging.

Nothing here reads a file, runs a model or trains one; every function takes arrays and labels.
:func:`slipsense.evaluation.judge.judge` replays the runs once and hands one :class:`Judged` to every
measure of :data:`MEASURES`; ``slipsense evaluate``'s JSON (under each measure's key), its printed
summary, held-out results, the cross-validation's fold tables (:mod:`slipsense.training.folds`) and
adapt's table iterate that registry, and each measure names the one value it ranks detectors by, so a
new measure is one function and one :func:`register` call.

* :mod:`~slipsense.measures.pergrasp`: early warning per grasp (warned in time, premature, missed,
  false-positive grasps) from the replayed traces;
* :mod:`~slipsense.measures.operating_points`: the (threshold, debounce) chosen on training runs;
* :mod:`~slipsense.measures.promise`: what an operating point promises about held grasps, in words;
* :mod:`~slipsense.measures.slipped_or_held`: ranking and accuracy of slipped against held grasps,
  with intervals over objects, beside the non-learned :mod:`~slipsense.measures.baselines`;
* :mod:`~slipsense.measures.clips`: the papers' short-clip metrics;
* :mod:`~slipsense.measures.holding`: false alarms per hour of holding.
"""

from __future__ import annotations

# imported in the order the summary says their measures
from slipsense.measures import slipped_or_held, pergrasp, holding, clips  # noqa: F401  (each registers its own)
from slipsense.measures.registry import (
    MEASURES,
    Judged,
    Measure,
    cell,
    measure_all,
    measure_lines,
    ranked,
    ranked_columns,
    register,
)

__all__ = [
    "MEASURES",
    "Judged",
    "Measure",
    "cell",
    "measure_all",
    "measure_lines",
    "ranked",
    "ranked_columns",
    "register",
]
