"""A grasp detector as users get it: its trainings planned (the detector itself and the inner folds
that choose its operating point), run side by side (:mod:`slipsense.parallel`), and written
as one checkpoint with its operating point, metrics and curves.

:func:`train_detector` is what ``slipsense train`` runs; :func:`plan_training` / :func:`fit_job` /
:func:`finish_training` are its parts, which ``slipsense train --cross-validate`` runs for every fold in
one pool (:mod:`slipsense.training.folds`).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from safetensors.torch import load_file

from slipsense import atomic
from slipsense.alarm import HOLD_S, debounce
from slipsense.checkpoint import save_checkpoint, update_info
from slipsense.errors import ConfigError
from slipsense.measures import Judged, measure_all, pergrasp, ranked
from slipsense.measures import promise
from slipsense.measures import operating_points
from slipsense.measures.registry import startup_frames
from slipsense.evaluation.calibrate import calibrated_threshold
from slipsense.evaluation.judge import clip_scores
from slipsense.measures.clips import clip_metrics
from slipsense.recordings.contact import rest_mask
from slipsense.measures.slipped_or_held import peak_alarm_score, roc_auc
from slipsense.models import build
from slipsense.parallel import run_jobs
from slipsense.recordings.runs import GraspRun
from slipsense.recordings.splits import ObjectFolds
from slipsense.training.distributed import setup
from slipsense.training.grasps import GraspTrainConfig, candidates, fit_runs, predict_runs, with_settings


def object_folds_of(runs: Sequence[GraspRun], folds: int, seed: int = 0) -> list[list[str]]:
    """The objects each of ``folds`` folds of ``runs`` holds out
    (:meth:`slipsense.recordings.splits.ObjectFolds.test_objects`); another data set's grasps
    (``extra``) are never held out."""
    return ObjectFolds(folds, seed).test_objects(r.object for r in runs if not r.extra)


@dataclass(frozen=True)
class FitJob:
    """One training of a plan (:func:`plan_training`): runs named by index into a shared list."""

    train: tuple[int, ...]
    predict: tuple[int, ...]  # runs replayed by the trained model
    keep_model: bool = False  # return the weights (the detector itself, not an inner-fold one)
    state_path: str | None = None  # where the training keeps its resume state (None: nowhere)
    out: str | None = None  # where it writes last/best checkpoints, metrics.csv and curves (None: nowhere)
    info: dict | None = None  # what those checkpoints carry besides the weights
    settings: tuple = ()  # (key, value) model settings of this candidate (GraspTrainConfig.choose)
    judge: tuple[int, ...] = ()  # training runs replayed to choose its own operating point (inner_folds=0)


def fit_job(shared: tuple[Sequence[GraspRun], GraspTrainConfig], job: FitJob, tick=lambda units: None):
    """Run one :class:`FitJob` (in this process or a worker, :func:`slipsense.parallel.run_jobs`):
    ``{"history", "probs" (per predicted run), "judged" (per judged run), "state" (weights, when
    kept)}``; ticks ``len(job.train)`` units per epoch."""
    runs, cfg = shared
    cfg = with_settings(cfg, dict(job.settings))
    model, history = fit_runs(
        [runs[i] for i in job.train],
        cfg,
        progress=False,
        on_epoch=lambda _: tick(len(job.train)),
        state_path=job.state_path,
        out=job.out,
        info=job.info,
    )
    probs = predict_runs(model, [runs[i] for i in job.predict], cfg.startup)
    judged = predict_runs(model, [runs[i] for i in job.judge], cfg.startup) if job.judge else []
    state = {k: v.detach().clone() for k, v in model.state_dict().items()} if job.keep_model else None
    return {"history": history, "probs": probs, "judged": judged, "state": state}


def job_weight(job: FitJob, cfg: GraspTrainConfig) -> float:
    """Progress units :func:`fit_job` ticks in all."""
    return float(len(job.train) * max(cfg.epochs, 1))


def plan_training(runs: Sequence[GraspRun], held: Sequence[str], cfg: GraspTrainConfig) -> list[FitJob]:
    """The trainings behind one detector: first the detector on every usable run whose object is not
    in ``held`` (replaying the held-out objects' runs), then one per inner fold of those training
    objects (each replaying its own held-out runs), which choose the operating point (without inner
    folds the detector replays its own training runs for it, in its job: candidates side by side);
    all that once per candidate of ``cfg.choose``. Indices are into ``runs``."""

    def split(ids, objects):  # (the runs not on ``objects``, the runs on them)
        on = [runs[i].object in objects for i in ids]
        return tuple(i for i, o in zip(ids, on) if not o), tuple(i for i, o in zip(ids, on) if o)

    train, tested = split([i for i, r in enumerate(runs) if r.usable], set(held))
    inner = object_folds_of([runs[i] for i in train], cfg.inner_folds, cfg.folds_seed) if cfg.inner_folds else []
    if not all(any(_teaches_slip(runs[i]) for i in split(train, objects)[0]) for objects in inner):
        # an inner fold would train on no slip (its objects hold every slip of the training runs):
        # the operating point is chosen on the training runs themselves, and says so
        inner = []
    judge = () if inner else tuple(i for i in train if not runs[i].extra)
    jobs = []
    for settings in candidates(cfg):
        s = tuple(settings.items())
        jobs += [FitJob(train, tested, True, settings=s, judge=judge)]
        jobs += [FitJob(*split(train, objects), settings=s) for objects in inner]
    return jobs


def _teaches_slip(run: GraspRun) -> bool:
    """A slipped run a detector can learn the slip from: with a known moment, or labelled as a whole."""
    return run.slipped and (run.moment_of_slip is not None or run.whole)


def finish_training(
    runs: Sequence[GraspRun], jobs: Sequence[FitJob], results: Sequence[dict], cfg: GraspTrainConfig, *, fps: float
):
    """From a finished :func:`plan_training`: ``(model in eval mode, history, operating point,
    P(slip) traces of the held-out runs)``; ``fps``: the rate the runs were taken at. The operating point is chosen on the inner folds'
    out-of-fold traces (or, with ``inner_folds=0``, on the model's own traces of its training runs).
    Of several candidates (``cfg.choose``) the one whose operating point scores best on those
    traces is returned (ties: the better ROC AUC of the grasps' peaks); its operating point names
    its ``settings`` and every candidate's score."""
    best, tried = None, []
    for settings, js, rs in _candidate_parts(jobs, results):
        c = with_settings(cfg, settings)
        model = build(c.model, **c.model_config)  # the init checkpoint's settings where fine-tuned
        model.load_state_dict(rs[0]["state"])
        model.eval()
        judged = [runs[i] for i in judged_indices(runs, js)]
        inner = len(js) > 1  # the plan's inner folds (none where one would train on no slip)
        probs = inner_traces(runs, js, rs) if inner else rs[0]["judged"]
        op = _chosen_operating_point(probs, judged, c, inner, fps)
        rank = (op.get("score_on_training_runs", 0.0), _peak_auc(probs, judged, c.startup))
        tried.append({"settings": settings, "score": rank[0], "roc_auc": rank[1]})
        if best is None or rank > best[0]:
            best = (rank, model, rs[0], op, settings)
    _, model, first, op, settings = best
    if len(tried) > 1:
        op = {**op, "settings": settings, "tried": tried}
    return model, first["history"], op, first["probs"]


def _candidate_parts(jobs: Sequence[FitJob], results: Sequence[Any]) -> list[tuple[dict, list, list]]:
    """``(settings, jobs, results)`` of each candidate of a plan, in plan order: its detector and its
    inner folds, which :func:`plan_training` puts one after another (one part where nothing is chosen)."""
    parts: list[tuple[tuple, list, list]] = []
    for j, r in zip(jobs, results):
        if not parts or parts[-1][0] != j.settings:  # settings may hold lists: compared, not hashed
            parts.append((j.settings, [], []))
        parts[-1][1].append(j)
        parts[-1][2].append(r)
    return [(dict(key), js, rs) for key, js, rs in parts]


def chosen_part(jobs: Sequence[FitJob], results: Sequence[Any], op: dict[str, Any]):
    """The jobs and results of the candidate :func:`finish_training` kept (``op["settings"]``; all of
    them when nothing was chosen): its detector and its inner folds."""
    parts = _candidate_parts(jobs, results)
    return next((js, rs) for settings, js, rs in parts if "settings" not in op or settings == op["settings"])


def _peak_auc(probs: Sequence[np.ndarray], runs: Sequence[GraspRun], startup: int) -> float:
    """ROC AUC of the grasps' peak P(slip), slipped against held (0 where one kind is missing)."""
    slipped = np.array([r.slipped for r in runs], bool)
    if slipped.all() or not slipped.any():
        return 0.0
    return float(roc_auc(np.array([peak_alarm_score(p, 1, startup) for p in probs]), slipped))


def judged_indices(runs: Sequence[GraspRun], jobs: Sequence[FitJob]) -> list[int]:
    """The detector's training runs that choose its operating point: all but another data set's."""
    return [i for i in jobs[0].train if not runs[i].extra]


def inner_traces(runs: Sequence[GraspRun], jobs: Sequence[FitJob], results: Sequence[dict]) -> list[np.ndarray]:
    """The out-of-fold P(slip) traces of the detector's judged training runs (:func:`judged_indices`,
    in that order), each from the inner-fold model that did not train on its object."""
    by_index = {i: p for job, res in zip(jobs[1:], results[1:]) for i, p in zip(job.predict, res["probs"])}
    return [by_index[i] for i in judged_indices(runs, jobs)]


def train_with_operating_point(
    runs: Sequence[GraspRun],
    held: Sequence[str],
    cfg: GraspTrainConfig,
    workers: int | None = 1,
    progress: bool = False,
    state_dir=None,
    out=None,
    info: dict | None = None,
    *,
    fps: float,
):
    """Train a detector on the runs of every object but ``held`` (taken at ``fps``) and choose its operating point on
    those runs only (:func:`plan_training` on ``workers`` processes); returns :func:`finish_training`'s
    ``(model, history, operating point, held-out traces)``. ``state_dir``: each training keeps its
    resume state there (``job<k>.state``) and continues from one it finds (:func:`fit_runs`).
    ``out``: the detector's own training writes ``last``/``best.safetensors`` (with ``info``),
    ``metrics.csv`` and ``curves.png`` there after every epoch."""
    jobs = plan_training(runs, held, cfg)
    if state_dir is not None:
        Path(state_dir).mkdir(parents=True, exist_ok=True)
        jobs = [replace(j, state_path=str(Path(state_dir) / f"job{k}.state")) for k, j in enumerate(jobs)]
    if out is not None and len(candidates(cfg)) == 1:  # of several, the one chosen is known only at the end
        jobs[0] = replace(jobs[0], out=str(out), info=info)
    if not jobs[0].train:
        raise ConfigError("no usable training runs (every run excluded, or slip runs without a moment)")
    results = run_jobs(
        fit_job,
        jobs,
        (runs, cfg),
        workers,
        [job_weight(j, cfg) for j in jobs],
        progress=progress,
        desc=cfg.model,
        longest_first=True,  # the detector's result is wanted with all the others: none is written early
    )
    return finish_training(runs, jobs, results, cfg, fps=fps)


def held_alarm_of(probs: Sequence[np.ndarray], runs: Sequence[GraspRun], op: dict, cfg: GraspTrainConfig) -> dict:
    """:func:`~slipsense.measures.promise.held_alarm_promise` of the held ``runs`` at ``op``."""
    held = [(p, r.object) for p, r in zip(probs, runs) if not r.slipped]
    alarmed = [bool(debounce(p, op["threshold"], op["debounce"])[cfg.startup :].any()) for p, _ in held]
    return promise.held_alarm_promise(alarmed, [o for _, o in held])


def _chosen_operating_point(
    probs: Sequence[np.ndarray], runs: Sequence[GraspRun], cfg: GraspTrainConfig, inner: bool, fps: float
) -> dict:
    """The threshold and debounce that best separate ``runs``' slips from their held grasps, and on what.
    Runs labelled as a whole (no moment to warn before) are judged per grasp: the threshold just above
    all but ``max_held_alarm`` (default 5%) of the held grasps' peaks
    (:func:`~slipsense.evaluation.calibrate.calibrated_threshold`), debounce 1."""
    at = {"horizon": cfg.horizon, "startup": cfg.startup}
    if any(r.whole for r in runs):
        budget = 0.05 if cfg.max_held_alarm is None else cfg.max_held_alarm
        peak = np.array([peak_alarm_score(p, 1, cfg.startup) for p in probs])
        slipped = np.array([r.slipped for r in runs], bool)
        if slipped.all():
            raise ConfigError("no held grasp among the training runs: the alarm threshold needs some")
        threshold = min(1.0, calibrated_threshold(peak[~slipped], peak[slipped], budget))
        op = {
            "threshold": threshold,
            "score_on_training_runs": float(((peak >= threshold) == slipped).mean()),  # per-grasp accuracy
            "debounce": 1,
            "hold_s": HOLD_S,
            **at,
            **{f"{k}_s": v / fps for k, v in at.items()},  # what the frame counts stand for
            "rule": f"at most {100 * budget:g}% of held grasps alarming (grasps labelled as a whole)",
        }
    else:
        moments = [r.moment_of_slip for r in runs]
        op = operating_points.choose_operating_point(probs, moments, **at, max_held_alarm=cfg.max_held_alarm, fps=fps)
    if inner:
        op["chosen_on"] = f"{cfg.inner_folds} inner folds of the training objects"
    elif cfg.inner_folds:
        op["chosen_on"] = (
            f"the training runs themselves ({cfg.inner_folds} inner folds of the training objects would "
            "leave one fold no slip to learn from)"
        )
    else:
        op["chosen_on"] = "the training runs themselves"
    op["held_alarm"] = held_alarm_of(probs, runs, op, cfg)
    return op


def _checkpoint_info(cfg: GraspTrainConfig, runs: Sequence[GraspRun], data: dict[str, Any], **trained) -> dict:
    """What a detector's checkpoints carry besides the weights; ``trained``: its ``operating_point`` and ``history``."""
    data = dict(data)
    tree = data.pop("config", None)  # the whole configuration tree, where every checkpoint keeps it
    sensor = data.pop("sensor", None)  # the sensor whose recordings it read: every time it reports is at its rate
    if not sensor:
        raise ConfigError("the training data names no sensor: its frame rate is needed (data.sensor or sensor.json)")
    return {
        "train_config": cfg.to_dict(),
        "sensor": sensor,
        **trained,
        "data": {**data, "objects": sorted({r.object for r in runs}), "runs": len(runs)},
        **({"config": tree} if tree is not None else {}),
    }


def train_detector(
    runs: Sequence[GraspRun],
    labels: dict,
    cfg: GraspTrainConfig,
    out,
    held: Sequence[str] = (),
    data: dict[str, Any] | None = None,
    progress: bool = True,
    workers: int | None = None,
    resume: bool = False,
) -> dict[str, Any]:
    """Train a detector on every run whose object is not in ``held``, choose its operating point on
    those runs (inner folds, trained beside it on ``workers`` processes, default one per core), and
    write ``out/detector.safetensors`` (the last epoch's weights, full config, operating point),
    ``last.safetensors`` and ``best.safetensors`` (by training accuracy: nothing of the training objects
    is set aside to pick an epoch; the operating point goes into those holding the last epoch's
    weights), ``metrics.csv`` and ``curves.png``; with ``held`` objects, also ``held_out.json`` (their
    per-grasp outcomes and clip metrics, never used for any choice).

    Every training keeps its state in ``out/resume/`` after each epoch; ``resume=True`` continues
    from there (a killed run ends with the weights of an uninterrupted one), else it starts afresh."""
    out = Path(out)
    d = setup("cpu")  # under torchrun: every training runs on all ranks in turn, each step shared out
    if d.world > 1:
        workers = 1
    state_dir = out / "resume"
    if d.main and not resume and state_dir.is_dir():
        for stale in state_dir.glob("job*.state"):
            stale.unlink()
    if d.world > 1:
        import torch.distributed as dist

        dist.barrier()  # no rank reads a stale state rank 0 is removing
    usable = [r for r in runs if r.usable]
    train = [r for r in usable if r.object not in set(held)]
    unknown = sorted(set(held) - {r.object for r in usable if not r.extra})
    if unknown:
        raise ConfigError(
            f"held-out objects without usable runs: {', '.join(unknown)} (data.also's grasps are never held out)"
        )
    data = {**(data or {}), "held_out_objects": sorted(held)}
    card = _checkpoint_info(cfg, train, data)
    fps = sensor_rate(card, "the training data")
    model, history, op, probs = train_with_operating_point(
        runs, held, cfg, workers, progress, state_dir, out, card, fps=fps
    )
    result = {"checkpoint": str(out / "detector.safetensors"), "operating_point": op, "history": history}
    if held:
        test = [r for r in usable if r.object in set(held)]
        judged = held_out_result(test, probs, op, labels, cfg.horizon, fps)
        # every registered measure that ranks, on the held-out runs (as the fold tables show them)
        measures = ranked(measure_all(pooled_runs([{**judged, "operating_point": op}], fps, cfg.horizon)))
        result.update({**{k: judged[k] for k in ("per_grasp", "clips")}, "measures": measures})
    if not d.main:
        return result
    info = _checkpoint_info(cfg, train, data, operating_point=op, history=history)
    path = save_checkpoint(out / "detector.safetensors", model, info)
    for name in ("last.safetensors", "best.safetensors"):
        # the inner folds trained for every epoch: their operating point is the last epoch's, which
        # best.safetensors holds only where no later epoch scored higher
        if (out / name).is_file() and _same_weights(out / name, path):
            update_info(out / name, {"operating_point": op})
    if held:
        fold = {k: v for k, v in result.items() if k not in ("checkpoint", "operating_point", "history")}
        atomic.write_text(out / "held_out.json", json.dumps({"objects": sorted(held), **fold}, indent=1))
    return result


def _same_weights(a, b) -> bool:
    wa, wb = load_file(str(a)), load_file(str(b))
    return wa.keys() == wb.keys() and all(wa[k].equal(wb[k]) for k in wa)


def traces_json(runs: Sequence[GraspRun], probs) -> list[dict[str, Any]]:
    """Runs with their P(slip) traces (6 decimals: thresholds go up to 0.9999; None for no answer)."""
    rounded = [[None if math.isnan(v) else round(float(v), 6) for v in p] for p in probs]
    return [{**pergrasp.run_fields(r), "probability": p} for r, p in zip(runs, rounded)]


def stored_trace(run: dict[str, Any]) -> np.ndarray:
    """``(N,)`` float64 P(slip) of a run as a fold file keeps it (``null`` where the detector gave
    no answer, NaN here)."""
    return np.array([np.nan if v is None else v for v in run["probability"]], dtype=np.float64)


def sensor_rate(doc: Mapping[str, Any] | None, what: str) -> float:
    """The frame rate of the sensor ``doc`` (a checkpoint's info, a report's head) records; ConfigError
    where it names none (a rate assumed would put every time it reports on another clock)."""
    fps = ((doc or {}).get("sensor") or {}).get("fps")
    if not fps:
        raise ConfigError(f"{what} names no sensor with a frame rate: its times cannot be read without one")
    return float(fps)


def pooled_runs(folds: Sequence[dict[str, Any]], fps: float, horizon: int) -> Judged:
    """Every fold's held-out runs as the measures take them, each at its fold's operating point
    (``fps``: the rate the runs were read at, the detector's; ``horizon``: frames at it; the start-up
    is each fold's operating point's, else :data:`~slipsense.measures.registry.STARTUP_S` at ``fps``)."""
    runs, points = [], []
    for f in folds:
        op = f["operating_point"]
        for r in f["runs"]:
            p, rest = stored_trace(r), np.zeros(len(r["probability"]), dtype=bool)
            rest[r["rest"]] = True
            at = (r["object"], r["experiment"], r["slipped"], r["moment_of_slip"], len(p), p, rest, tuple(r["cameras"]))
            runs.append(pergrasp.RunTrace(*at, fps, fps))
            points.append((op["threshold"], op["debounce"], op.get("hold_s", 0.0)))
    default = startup_frames(fps)
    startup = int(folds[0]["operating_point"].get("startup", default)) if folds else default
    return Judged(runs, points, horizon, startup)


def held_out_result(
    runs: Sequence[GraspRun], probs, op: dict[str, Any], labels: dict, horizon: int, fps: float
) -> dict:
    """The held-out ``runs`` (taken at ``fps``; ``horizon`` in frames at it) judged from their P(slip)
    traces at ``op`` (from its ``startup``, else :data:`~slipsense.measures.registry.STARTUP_S`): the per-grasp
    summary and clip metrics, and what pooling folds needs: each run's outcome (a slip labelled as a whole is
    ``slip_without_moment``, neither slip nor held), frames at rest and trace, the clips' probabilities and labels."""
    startup = int(op.get("startup", startup_frames(fps)))
    th, k = op["threshold"], op["debounce"]
    rests = [rest_mask(r.contact) for r in runs]
    outs = [
        pergrasp.trace_outcome(p, th, k, r.moment_of_slip, r.slipped, horizon, startup, rest)
        for r, p, rest in zip(runs, probs, rests)
    ]
    p, y = clip_scores(runs, probs, labels)
    return {
        "per_grasp": pergrasp.summarise(outs, fps),
        "clips": clip_metrics(p, y, th),
        "clip_probability": [round(float(v), 5) for v in p],
        "clip_label": [int(v) for v in y],
        "runs": [
            dict(t, slipped=r.slipped, outcome=o.outcome, first_alarm=o.first_alarm, lead=o.lead, rest=rest)
            for t, r, o, rest in zip(traces_json(runs, probs), runs, outs, [np.flatnonzero(m).tolist() for m in rests])
        ],
    }
