"""``promise``: state what a detector promises on new objects: restated from its inner folds (a
detector trained before checkpoints carried it), or, with ``--unseen REPORT``, what its recipe did on
held grasps of objects it never saw (a leave-objects-out cross-validation report of the same recipe on
the same grasps), the one promise ``watch``, ``models``, the README and the docs then state."""

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


def unseen_figures(report, row: str | None = None) -> tuple[int, int, str]:
    """``(held grasps alarming, held grasps, where)`` on objects never seen, from a cross-validation
    report (its ``folds.json``) or, with ``row``, the adaptation study's row of that name."""
    from pathlib import Path

    report = Path(report)
    if row is None:
        doc = json.loads((report / "folds.json").read_text())
        pooled = doc["pooled"]["per_grasp"]
        where = f"its recipe's {doc['folds']} object folds, {report.as_posix()}"
        return pooled["false_positive_grasps"], pooled["held_runs"], where
    rows = json.loads((report / "adaptation.json").read_text())["rows"]
    found = [r for r in rows if r["row"].startswith(row)]
    if len(found) != 1:
        raise InputError(report, f"{len(found)} rows start with {row!r}: name one")
    r = found[0]
    return r["held_alarming"], r["grasps"] - r["slipped"], f"each object left out in turn, {report.as_posix()}"


def promise_from_report(checkpoint, report, row: str | None = None) -> dict[str, Any]:
    """Write into ``checkpoint`` (weights untouched) the held-alarm promise its recipe measured on held
    grasps of objects never seen (:func:`unseen_figures`), with the bound counting objects as units. The
    report must judge the same held grasps the detector's own promise counts (its units, the objects
    with held grasps, are taken from there: a report keeps no per-object outcome). Returns the promise."""
    from pathlib import Path

    from slipsense.measures.promise import wilson

    k, n, where = unseen_figures(report, row)
    info = read_info(checkpoint)
    own = (info.get("operating_point") or {}).get("held_alarm") or {}
    if own.get("held_grasps") != n:
        raise InputError(
            report, f"judges {n} held grasps, the detector's promise {own.get('held_grasps')}: not the same grasps"
        )
    units, rate = own["held_objects"], k / n
    promise = {
        "held_grasps": n,
        "held_objects": units,
        "alarming": k,
        "rate": rate,
        "bound_counting_objects": wilson(rate * units, units)[1],
        "bound_counting_grasps": wilson(k, n)[1],
        "measured_on": f"objects it never saw ({where})",
        "report": Path(report).as_posix(),
        **({"row": row} if row else {}),
    }
    update_info(checkpoint, {"operating_point": {**info["operating_point"], "held_alarm_unseen": promise}})
    return promise
