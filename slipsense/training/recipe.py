"""One way in to training, whatever the model: :func:`fit` takes a :class:`RunConfig` (built once
from a configuration tree by :meth:`RunConfig.from_tree`: ``model``, ``data`` and ``train`` sections,
as ``configs/*.yaml`` and ``--set`` write it) and an output folder.

``slipsense train`` and :func:`slipsense.fit` both build a tree, make it a run and call :func:`fit`,
so what it applies (the sensor spec, the one-sensor split of a one-finger detector, the held-out objects,
resume) applies the same way from each. The model's ``training_task`` names the trainer in
:data:`TRAINERS`: a plug-in table, so nothing here asks which kind of model it is.

    >>> run = RunConfig.from_tree({"model": {"name": "motionnet"}, "data": {"test_objects": ["mug"]},
    ...                            "train": {"epochs": 2}})                  # doctest: +SKIP
    >>> fit(run, "runs/mine")                                                # doctest: +SKIP
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import Any, Callable

import torch

from slipsense.atomic import check_output_dir, write_text
from slipsense.paths import portable_path
from slipsense.errors import ConfigError
from slipsense.models import build, model_class
from slipsense.recordings.recording_set import Recordings
from slipsense.recordings.runs import per_sensor
from slipsense.config_tree import dump_tree
from slipsense.training.clips import run_training
from slipsense.training.settings import RunConfig, recordings_read, recordings_sensor
from slipsense.training.folds import pool, run_folds
from slipsense.training.grasp_detector import object_folds_of, train_detector
from slipsense.training.grasps import load_grasp_data, recordings_shape


def fit(
    run: RunConfig,
    out: str | Path,
    *,
    progress: bool = True,
    resume: bool = False,
    workers: int | None = None,
    threads: int | None = None,
    command: str | None = None,
) -> dict[str, Any]:
    """Train ``run``'s model into ``out``; returns (on rank 0 under torchrun, ``{}`` on the others)
    what its trainer reports: for a grasp detector ``checkpoint``, ``operating_point``, ``history``
    and, with held-out objects (``data.test_objects``, or ``data.fold`` of ``data.folds``),
    ``per_grasp`` and ``clips``; for a clip model the held-out part's clip metrics. ``out`` is
    checked before any work (OutputError unless it takes files). ``workers``:
    trainings side by side (grasp detectors), ``threads``: torch threads of this process; ``command``
    is kept with the checkpoint (how it was made)."""
    check_output_dir(out, "--out")
    if threads is not None:
        torch.set_num_threads(threads)
    trainer = TRAINERS[model_class(run.name).training_task]
    return trainer(run, Path(out), progress=progress, resume=resume, workers=workers, command=command)


def cross_validate(
    run: RunConfig,
    out: str | Path,
    folds: int = 5,
    *,
    progress: bool = True,
    workers: int | None = None,
    threads: int | None = None,
    command: str | None = None,
) -> dict[str, Any]:
    """Leave objects out for any model: ``folds`` folds by object, each trained and judged on its
    unseen objects, pooled into ``out``. A grasp detector goes through
    :func:`slipsense.training.folds.run_folds` (per grasp, its report); a clip or marker model is
    :func:`fit` once per fold into ``out/fold<k>`` (a fold already judged is kept; a killed one
    resumes) and the held-out clips pooled into ``out/folds.json``
    (:func:`slipsense.training.folds.pool`). Returns the pooled report."""
    if run.data.fold is not None or run.data.test_objects:
        raise ConfigError("cross-validation holds out every fold in turn: leave --fold and --test-objects out")
    check_output_dir(out, "--out")
    if threads is not None:
        torch.set_num_threads(threads)
    cross = FOLDS[model_class(run.name).training_task]
    return cross(run, Path(out), folds, progress=progress, workers=workers, command=command)


def _grasp_folds(run: RunConfig, out: Path, folds: int, *, progress, workers, command) -> dict[str, Any]:
    runs, labels, data = grasp_data(run, progress)
    return run_folds(
        runs, labels, run.train, out, folds, meta={"command": command, **data}, progress=progress, workers=workers
    )


def _clip_folds(run: RunConfig, out: Path, folds: int, *, progress, workers, command) -> dict[str, Any]:
    """Each fold a clip model of its own (``workers`` does not apply: one process trains it)."""
    for k in range(folds):
        fold_out = out / f"fold{k}"
        if (fold_out / "evaluation.json").is_file():
            continue  # judged already
        fold = dataclasses.replace(run, data=dataclasses.replace(run.data, fold=k, folds=folds))
        resume = (fold_out / "resume.pt").is_file()
        fit_clips(fold, fold_out, progress=progress, resume=resume, command=command)
    report = pool([out / f"fold{k}" for k in range(folds)])
    write_text(out / "folds.json", json.dumps({"command": command, **report}, indent=2))
    return report


def fit_clips(run: RunConfig, out: Path, *, progress: bool, resume: bool, workers=None, command=None) -> dict:
    """A clip or marker-window model (:func:`slipsense.training.clips.run_training`)."""
    if workers not in (None, 1):
        raise ConfigError("a clip model trains in one process (torchrun shares it out between ranks)")
    return run_training(run, out, progress=progress, resume=resume)


def fit_grasps(
    run: RunConfig,
    out: Path,
    *,
    progress: bool,
    resume: bool,
    workers: int | None = None,
    command: str | None = None,
) -> dict[str, Any]:
    """A detector over whole grasps with its operating point chosen on inner folds of its training
    objects (:func:`slipsense.training.grasp_detector.train_detector`); writes ``out/config.yaml``."""
    ranked = int(os.environ.get("WORLD_SIZE", "1")) > 1
    if ranked and workers not in (None, 1):
        raise ConfigError("under torchrun every training is shared out between the ranks: leave --workers out")
    progress = progress and int(os.environ.get("RANK", "0")) == 0
    runs, labels, data = grasp_data(run, progress)
    held = list(run.data.test_objects)
    if run.data.fold is not None:
        split = object_folds_of([r for r in runs if r.usable], run.data.folds, run.train.folds_seed)
        if not 0 <= run.data.fold < len(split):
            raise ConfigError(f"--fold must be in 0..{len(split) - 1}, got {run.data.fold}")
        held = split[run.data.fold]
    data["command"] = command
    res = train_detector(
        runs, labels, run.train, out, held, data=data, progress=progress, workers=workers, resume=resume
    )
    if ranked and int(os.environ.get("RANK", "0")) != 0:
        return {}  # rank 0 writes and reports
    write_text(out / "config.yaml", dump_tree(data["config"]))
    return {**res, "held_out": held}


def grasp_data(run: RunConfig, progress: bool = True):
    """A grasp detector's data: ``(runs, labels, metadata)``; the runs are each camera on its own for
    a one-finger detector, read with the run's sensor spec (``data.sensor``, default the data's own,
    else the GelSight Mini). ``data.also``: another data set's recordings, read with their own sensor
    and labels and trained on alongside, never held out, judged or calibrated on
    (:attr:`GraspRun.extra`, their objects named ``<folder>/<object>``). The metadata is what
    checkpoints and reports keep (``config``: the run's tree)."""
    d, cfg = run.data, run.train
    image_size = tuple(cfg.model_config.get("image_size") or build(run.name).image_size)
    read = recordings_read(d)  # the folder listed once (or the set the caller read)
    root, sensor = read.root, recordings_sensor(dataclasses.replace(d, read=read))
    model = build(run.name, **cfg.model_config)
    sensors = model.sensors
    shape = recordings_shape(read)
    if shape is not None:  # before any frame is decoded (else the reading below names the problem)
        model.check_cameras([shape.cameras], f"the recordings ({root})")
    runs, labels = load_grasp_data(read, d.overrides, image_size, d.on_error, progress, sensor=sensor)
    model.check_cameras([r.gray.shape[0] for r in runs], f"the recordings ({root})")
    if d.also is not None:
        if d.also.resolve() == root.resolve():
            raise ConfigError(f"data.also ({d.also}) is the training recordings themselves")
        also = Recordings.open(d.also, None, d.on_error)  # read as the sensor it states
        extra, _ = load_grasp_data(also, None, image_size, d.on_error, progress, sensor=also.sensor)
        model.check_cameras([r.gray.shape[0] for r in extra], f"data.also ({d.also})")
        runs = runs + [dataclasses.replace(r, object=f"{d.also.name}/{r.object}", extra=True) for r in extra]
    if sensors == 1:  # a one-finger detector: each camera of a run is a grasp of its own
        runs = per_sensor(runs)
    data = {
        "recordings": portable_path(root),
        "overrides": d.overrides if d.overrides in (None, False) else portable_path(d.overrides),
        **({"also": portable_path(d.also)} if d.also is not None else {}),
        "image_size": list(image_size),
        "sensors_per_grasp": sensors,
        "sensor": sensor.to_dict(),
        "config": run.to_tree(),
    }
    return runs, labels, data


#: ``training_task`` (a model class attribute) -> its trainer, and its cross-validation
TRAINERS: dict[str, Callable[..., dict[str, Any]]] = {"clips": fit_clips, "grasps": fit_grasps}
FOLDS: dict[str, Callable[..., dict[str, Any]]] = {"clips": _clip_folds, "grasps": _grasp_folds}

__all__ = ["RunConfig", "cross_validate", "fit"]
