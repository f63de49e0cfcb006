"""Evaluation: replay -> per-frame traces -> scores.

* :mod:`slipsense.evaluation.pergrasp` — per-grasp verdicts on alarm traces (warned in time,
  premature, missed, false-positive grasps), operating points and trade-off tables;
* :mod:`slipsense.evaluation.grasp_scores` — the papers' clip protocol on the same traces, a fold's
  result and folds pooled;
* :mod:`slipsense.evaluation.early_warning` — whole recordings replayed through a live detector;
* :mod:`slipsense.evaluation.folds` — leave objects out over whole grasps (``slipsense train --cross-validate``);
* :mod:`slipsense.evaluation.evaluate` — ``slipsense evaluate``: a checkpoint on a data source,
  per grasp for grasp detectors, per clip for clip and marker models;
* :mod:`slipsense.evaluation.clip_folds` — pooling clip-model folds; :mod:`slipsense.evaluation.metrics`
  — clip metrics from confusion counts.
"""
