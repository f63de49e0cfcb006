"""Training: every registered model through one entry, :func:`slipsense.training.recipe.fit` (what
``slipsense train`` and :func:`slipsense.fit` call with the :class:`~slipsense.training.settings.RunConfig`
made once from a configuration tree).

One loop, :mod:`slipsense.training.trainer` (torchrun DDP, seeds, resume after a kill, best/last
checkpoints, metrics and curves, progress), trains every model; a model declares its task
(:attr:`slipsense.models.base.SlipModel.training_task`), which supplies the data, batches and loss:

* ``"clips"`` — windows cut from recordings or marker sequences: :class:`slipsense.training.clips.ClipTask`,
  from a run configuration to a run folder in :mod:`slipsense.training.clips`, its data
  read and split by the model's reader (:mod:`slipsense.readers`) and ranks in :mod:`slipsense.training.distributed`;
* ``"grasps"`` — whole runs of every sensor, per-frame targets: :class:`slipsense.training.grasps.GraspTask`
  and :mod:`slipsense.training.grasp_detector` (the detector with its operating point chosen on inner
  folds, trainings side by side in :mod:`slipsense.parallel`).
"""
