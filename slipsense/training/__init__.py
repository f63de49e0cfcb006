"""Training: every registered model through ``slipsense train`` (and :func:`slipsense.fit`).

A model declares its task (:attr:`slipsense.models.base.SlipModel.training_task`):

* ``"clips"`` — windows cut from recordings or marker sequences: :mod:`slipsense.training.clips`
  (seeded, torchrun DDP, resume after a kill, best/last checkpoints, metrics and curves), with its
  data split in :mod:`slipsense.training.splits` and ranks in :mod:`slipsense.training.distributed`;
* ``"grasps"`` — whole runs of every sensor, per-frame targets: :mod:`slipsense.training.grasps`
  (one training, resumable) and :mod:`slipsense.training.grasp_detector` (the detector with its
  operating point chosen on inner folds, trainings side by side in :mod:`slipsense.training.parallel`).
"""
