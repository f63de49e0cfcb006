"""``promise``: state what a detector trained before checkpoints carried it promises on new objects."""

from __future__ import annotations

import json
from typing import Any, Sequence

import numpy as np

from slipsense.checkpoint import read_info, update_info
from slipsense.errors import ConfigError, InputError
from slipsense.parallel import run_jobs
from slipsense.recordings.runs import GraspRun
from slipsense.training.grasp_detector import fit_job, held_alarm_of, job_weight, plan_training
from slipsense.training.grasps import GraspTrainConfig, with_settings
from slipsense.training.recipe import RunConfig, grasp_data


def inner_fold_traces(usable: Sequence[GraspRun], cfg: GraspTrainConfig, workers=1, progress=False) -> list[np.ndarray]:
    """P(slip) traces of ``usable`` runs but another data set's, each from the model of
    ``cfg.inner_folds`` inner folds by object that did not train on its object (what an operating
    point is chosen on)."""
    if cfg.choose:
        raise ConfigError("train.choose: give the chosen settings (GraspTrainConfig via with_settings)")
    jobs = plan_training(usable, (), cfg)[1:]
    results = run_jobs(fit_job, jobs, (usable, cfg), workers, [job_weight(j, cfg) for j in jobs], progress=progress)
    by_index = {i: p for job, res in zip(jobs, results) for i, p in zip(job.predict, res["probs"])}
    return [by_index[i] for i, r in enumerate(usable) if not r.extra]


def restate_promise(checkpoint, workers: int | None = 1, progress: bool = False) -> dict[str, Any]:
    """The held-alarm promise of a grasp detector trained before checkpoints stated one: its recipe's
    inner folds trained again on its training objects (its own configuration tree and seed), judged at
    its stored operating point, and written into the checkpoint (weights untouched). Returns it."""
    info = read_info(checkpoint)
    if not isinstance(info.get("config"), dict) or not (info.get("train_config") or {}).get("inner_folds"):
        raise InputError(checkpoint, "not a grasp detector whose operating point came from inner folds")
    tree = json.loads(json.dumps(info["config"]))
    tree["data"] = {**tree.get("data", {}), "recordings": info["data"]["recordings"]}
    if info["data"].get("also"):
        tree["data"]["also"] = info["data"]["also"]
    run = RunConfig.from_tree(tree)
    runs, _, _ = grasp_data(run, progress)
    cfg = run.train
    trained = set(info["data"]["objects"])
    usable = [r for r in runs if r.usable and r.object in trained]
    op = dict(info["operating_point"])
    cfg = with_settings(cfg, op.get("settings", {}))  # the settings train.choose chose, if it chose
    judged = [r for r in usable if not r.extra]  # the traces inner_fold_traces returns
    op["held_alarm"] = held_alarm_of(inner_fold_traces(usable, cfg, workers, progress), judged, op, cfg)
    op["held_alarm"]["restated"] = f"{cfg.inner_folds} inner folds trained again by `python -m studies grasp promise`"
    update_info(checkpoint, {"operating_point": op})
    return op["held_alarm"]
