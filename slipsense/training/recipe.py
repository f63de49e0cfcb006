"""One way in to training, whatever the model: :func:`fit` takes a configuration tree (``model``,
``data`` and ``train`` sections, as ``configs/*.yaml`` and ``--set`` write it) and an output folder.

``slipsense train`` and :func:`slipsense.fit` all build a tree and call
:func:`fit`, so what it applies (the sensor spec, the one-sensor split of a one-finger detector, the
held-out objects, resume) applies the same way from each. The model's ``training_task`` names the
trainer in :data:`TRAINERS`: a plug-in table, so nothing here asks which kind of model it is.

    >>> fit({"model": {"name": "motionnet"}, "data": {"test_objects": ["mug"]}, "train": {"epochs": 2}},
    ...     "runs/mine")                                                     # doctest: +SKIP
"""

from __future__ import annotations

import copy
import os
from pathlib import Path
from typing import Any, Callable

from slipsense.errors import ConfigError

#: The model trained where none is named: the slip detector over whole grasps.
DEFAULT_MODEL = "motionnet"

#: Data settings that only cut clips from runs (a grasp model trains on whole runs).
CLIP_DATA_KEYS = (
    "markers",
    "frames",
    "horizon",
    "wiggle_per_video",
    "split",
    "test_fraction",
    "augment",
    "marker_copies",
)
#: Training settings of the clip trainer only.
CLIP_TRAIN_KEYS = ("num_workers", "device", "max_steps_per_epoch", "step_size", "gamma", "select_by")


def fit(
    tree: dict[str, Any],
    out: str | Path,
    *,
    progress: bool = True,
    resume: bool = False,
    workers: int | None = None,
    threads: int | None = None,
    command: str | None = None,
) -> dict[str, Any]:
    """Train the tree's model (``tree["model"]["name"]``) into ``out``; returns (on rank 0 under
    torchrun, ``{}`` on the others) what its trainer reports: for a grasp detector ``checkpoint``, ``operating_point``, ``history`` and, with held-out
    objects (``data.test_objects``, or ``data.fold`` of ``data.folds``), ``per_grasp`` and ``clips``;
    for a clip model the held-out part's clip metrics. ``command`` is kept with the checkpoint (how it
    was made). ``tree`` is left as it was given: the trainers work on a copy."""
    tree = copy.deepcopy(dict(tree))
    trainer = TRAINERS[_task(tree)]
    return trainer(tree, Path(out), progress=progress, resume=resume, workers=workers, threads=threads, command=command)


def cross_validate(
    tree: dict[str, Any],
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
    :func:`slipsense.evaluation.folds.run_folds` (per grasp, its report); a clip or marker model is
    :func:`fit` once per fold into ``out/fold<k>`` (a fold already judged is kept; a killed one
    resumes) and the held-out clips pooled into ``out/folds.json``
    (:func:`slipsense.evaluation.clip_folds.pool`). Returns the pooled report; ``tree`` is left as given."""
    tree = copy.deepcopy(dict(tree))
    task = _task(tree)
    if tree["data"].get("fold") is not None or tree["data"].get("test_objects"):
        raise ConfigError("cross-validation holds out every fold in turn: leave --fold and --test-objects out")
    tree["data"].pop("folds", None)
    return FOLDS[task](tree, Path(out), folds, progress=progress, workers=workers, threads=threads, command=command)


def evaluate(checkpoint: str | Path, **options: Any) -> dict[str, Any]:
    """Judge a checkpoint the way its task is judged: a grasp detector per grasp
    (:func:`slipsense.evaluation.evaluate.evaluate_grasp_checkpoint`), a clip or marker model per clip on
    the data its reader takes (:func:`slipsense.evaluation.evaluate.evaluate_clip_checkpoint`, whose
    keyword ``options`` both take)."""
    from slipsense.checkpoint import load_model
    from slipsense.evaluation.evaluate import evaluate_clip_checkpoint, evaluate_grasp_checkpoint

    model, _ = load_model(checkpoint)  # a damaged checkpoint is refused before any data is read
    judge = {"clips": evaluate_clip_checkpoint, "grasps": evaluate_grasp_checkpoint}[model.training_task]
    return judge(checkpoint, **options)


def _task(tree: dict[str, Any]) -> str:
    """The training task of the tree's model (its sections made present); ConfigError for an unknown model."""
    from slipsense.models import available, model_class

    for section in ("model", "data", "train"):
        tree.setdefault(section, {})
    name = tree["model"].get("name")
    if name not in available():
        raise ConfigError(f"unknown model {name!r}; available: {', '.join(available())}")
    return model_class(name).training_task


def _grasp_folds(tree, out: Path, folds: int, *, progress, workers, threads, command) -> dict[str, Any]:
    from slipsense.evaluation.folds import run_folds

    grasp_split(tree)  # the clip-only settings refused, data.size moved to the model (nothing is held out)
    cfg, runs, labels, data = prepare_grasps(tree, progress, threads, out)
    meta = {"command": command, **data}
    return run_folds(runs, labels, cfg, out, folds, meta=meta, progress=progress, workers=workers)


def _clip_folds(tree, out: Path, folds: int, *, progress, workers, threads, command) -> dict[str, Any]:
    import json

    from slipsense.atomic import write_text
    from slipsense.evaluation.clip_folds import pool

    for k in range(folds):
        fold_out = out / f"fold{k}"
        if (fold_out / "evaluation.json").is_file():
            continue  # judged already
        sub = copy.deepcopy(tree)
        sub["data"].update(fold=k, folds=folds)  # fit's checks of the tree apply to each fold
        fit(
            sub,
            fold_out,
            progress=progress,
            resume=(fold_out / "resume.pt").is_file(),
            threads=threads,
            command=command,
        )
    report = pool([out / f"fold{k}" for k in range(folds)])
    write_text(out / "folds.json", json.dumps({"command": command, **report}, indent=2))
    return report


def fit_clips(tree, out: Path, *, progress: bool, resume: bool, workers=None, threads=None, command=None) -> dict:
    """A clip or marker-window model (:func:`slipsense.training.clips.run_training`)."""
    from slipsense.training.clips import TrainRequest, run_training

    if workers not in (None, 1):
        raise ConfigError("a clip model trains in one process (torchrun shares it out between ranks)")
    if threads is not None:
        import torch

        torch.set_num_threads(threads)
    return run_training(TrainRequest.from_tree(tree, out=out, progress=progress), resume=resume)


def fit_grasps(
    tree,
    out: Path,
    *,
    progress: bool,
    resume: bool,
    workers: int | None = None,
    threads: int | None = None,
    command: str | None = None,
) -> dict[str, Any]:
    """A detector over whole grasps with its operating point chosen on inner folds of its training
    objects (:func:`slipsense.training.grasp_detector.train_detector`); writes ``out/config.yaml``."""
    from slipsense.atomic import write_text
    from slipsense.run_config import dump_tree
    from slipsense.training.grasp_detector import object_split, train_detector

    ranked = int(os.environ.get("WORLD_SIZE", "1")) > 1
    if ranked and workers not in (None, 1):
        raise ConfigError("under torchrun every training is shared out between the ranks: leave --workers out")
    progress = progress and int(os.environ.get("RANK", "0")) == 0
    held, fold, folds = grasp_split(tree)
    cfg, runs, labels, data = prepare_grasps(tree, progress, threads, out)
    if fold is not None:
        split = object_split([r for r in runs if r.usable], folds, cfg.folds_seed)
        if not 0 <= fold < len(split):
            raise ConfigError(f"--fold must be in 0..{len(split) - 1}, got {fold}")
        held = split[fold]
    data["command"] = command
    res = train_detector(runs, labels, cfg, out, held, data=data, progress=progress, workers=workers, resume=resume)
    if ranked and int(os.environ.get("RANK", "0")) != 0:
        return {}  # rank 0 writes and reports
    write_text(out / "config.yaml", dump_tree(data["config"]))
    return {**res, "held_out": held}


def grasp_split(tree) -> tuple[list[str], int | None, int]:
    """The held-out objects of a grasp training: ``(data.test_objects, data.fold, data.folds)``,
    taken out of ``tree``; settings that only cut clips are refused by name."""
    data, train = tree["data"], tree["train"]
    clip_only = [k for k in CLIP_DATA_KEYS if data.get(k) is not None]
    clip_only += [f"train.{k}" for k in CLIP_TRAIN_KEYS if train.get(k) is not None]
    if tree["model"].get("preset") is not None:
        clip_only.append("preset")
    if clip_only:
        raise ConfigError(
            f"{tree['model']['name']} trains on whole grasps: {', '.join(clip_only)} only apply to clip models "
            f"(grasp settings: slipsense train --help)"
        )
    tree["model"].pop("preset", None)
    for key in CLIP_DATA_KEYS:
        data.pop(key, None)
    for key in CLIP_TRAIN_KEYS:
        train.pop(key, None)
    if data.get("size") is not None:
        tree["model"]["image_size"] = list(data.pop("size"))
    data.pop("size", None)
    from slipsense.models import model_class, settings_of
    from slipsense.training.grasps import GraspTrainConfig

    model_keys = settings_of(model_class(tree["model"]["name"])) | {"name"}
    for key in [k for k in tree["model"] if k not in model_keys and k in GraspTrainConfig.__dataclass_fields__]:
        train[key] = tree["model"].pop(key)  # a bare --set KEY=VALUE naming a training setting
    held = data.pop("test_objects", None)
    held = [o for o in held.split(",") if o] if isinstance(held, str) else list(held or [])
    fold, folds = data.pop("fold", None), data.pop("folds", None) or 5
    return held, fold, folds


def prepare_grasps(tree, progress: bool = True, threads: int | None = None, out=None):
    """From a grasp configuration tree: ``(training config, runs, labels, metadata)``; the runs are
    each camera on its own for a one-finger detector, read with the tree's sensor spec
    (``data.sensor``, default the GelSight Mini). ``data.also``: another data set's recordings, read
    with their own sensor and labels and trained on alongside, never held out, judged or calibrated on
    (:attr:`GraspRun.extra`, their objects named ``<folder>/<object>``). The metadata is what
    checkpoints and reports keep."""
    import dataclasses

    from slipsense.atomic import check_output_dir
    from slipsense.config import gelsight_recordings, portable_path, resolve_path
    from slipsense.models import build
    from slipsense.recordings.frame_folders import data_sensor
    from slipsense.recordings.runs import per_sensor
    from slipsense.run_config import check_keys, check_seed, to_plain
    from slipsense.sensors.spec import GELSIGHT_MINI, sensor_named
    from slipsense.training.grasps import GraspTrainConfig, load_grasp_data, make_config

    if threads is not None:
        import torch

        torch.set_num_threads(threads)
    check_output_dir(out, "--out")
    train_keys = set(GraspTrainConfig.__dataclass_fields__) - {"model", "model_config"}
    check_keys(
        tree,
        {"train": train_keys, "data": ("recordings", "overrides", "on_error", "sensor", "also"), "model": None},
        "grasp configuration",
    )
    name = tree["model"].pop("name", "motionnet")
    tree["train"]["seed"] = check_seed(tree["train"].get("seed", 0))
    cfg = make_config(name, {**tree["train"], **{f"model.{k}": v for k, v in tree["model"].items()}})
    image_size = tuple(cfg.model_config.get("image_size") or build(name).image_size)
    root = resolve_path(tree["data"].get("recordings") or gelsight_recordings())
    overrides = tree["data"].get("overrides")  # None: the shipped hand labels; False: none
    overrides = overrides if overrides in (None, False) else resolve_path(overrides)
    sensor = sensor_named(tree["data"]["sensor"]) if tree["data"].get("sensor") else data_sensor(root) or GELSIGHT_MINI
    runs, labels = load_grasp_data(
        root, overrides, image_size, tree["data"].get("on_error", "raise"), progress, sensor=sensor
    )
    sensors = build(name, **cfg.model_config).sensors
    also = resolve_path(tree["data"]["also"]) if tree["data"].get("also") else None
    if also is not None:
        if also.resolve() == root.resolve():
            raise ConfigError(f"data.also ({also}) is the training recordings themselves")
        extra, _ = load_grasp_data(
            also,
            None,
            image_size,
            tree["data"].get("on_error", "raise"),
            progress,
            sensor=data_sensor(also) or GELSIGHT_MINI,
        )
        cameras = sorted({r.gray.shape[0] for r in extra})
        if sensors != 1 and cameras != [sensors]:
            raise ConfigError(
                f"data.also ({also}) has grasps of {'/'.join(map(str, cameras))} camera(s); {name} takes {sensors} "
                "sensors together (model.sensors=1 trains on each camera alone)"
            )
        runs = runs + [dataclasses.replace(r, object=f"{also.name}/{r.object}", extra=True) for r in extra]
    if sensors == 1:  # a one-finger detector: each camera of a run is a grasp of its own
        runs = per_sensor(runs)
    tree["model"] = {"name": name, **cfg.model_config}
    data = {
        "recordings": portable_path(root),
        "overrides": overrides if overrides in (None, False) else portable_path(overrides),
        **({"also": portable_path(also)} if also is not None else {}),
        "image_size": list(image_size),
        "sensors_per_grasp": sensors,
        "sensor": sensor.to_dict(),
        "config": to_plain(tree),
    }
    return cfg, runs, labels, data


#: ``training_task`` (a model class attribute) -> its trainer, and its cross-validation
TRAINERS: dict[str, Callable[..., dict[str, Any]]] = {"clips": fit_clips, "grasps": fit_grasps}
FOLDS: dict[str, Callable[..., dict[str, Any]]] = {"clips": _clip_folds, "grasps": _grasp_folds}
