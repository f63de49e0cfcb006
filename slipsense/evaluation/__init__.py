"""Judging a detector, one floor above the measures (:mod:`slipsense.measures`):

* :mod:`slipsense.evaluation.judge` — :func:`~slipsense.evaluation.judge.judge`: open a detector once,
  read the recordings once, replay each run once, hand the traces to every registered measure;
* :mod:`slipsense.evaluation.replay` — whole recordings replayed through a live detector;
* :mod:`slipsense.evaluation.checkpoints` — ``slipsense evaluate``: a checkpoint judged the way its task is;
* :mod:`slipsense.evaluation.predict` — clip and marker models judged per clip;
* :mod:`slipsense.evaluation.calibrate` — a detector's operating point chosen on the user's grasps;
* :mod:`slipsense.evaluation.summary` — what ``slipsense evaluate`` prints.

Cross-validation, which trains, sits above in :mod:`slipsense.training.folds`.
"""
