"""Training on whole grasps: per-frame targets from the moment of slip, chunks of runs, class
balance, the alarm operating point from inner folds, and leave-objects-out over 5 folds.

Targets (``frame_targets``), per frame of a run after the camera start-up, with ``m`` the moment
of slip, ``h`` the onset frames and ``H`` the warning horizon:

* 1 (onset of slip) for frames ``m-h .. m``;
* ignored for ``m-H .. m-h-1`` (an alarm there is still a warning in time: not pushed either way)
  and after ``m`` (contact is gone; what happens then is not scored);
* 0 everywhere else: the calm parts of slip runs, every frame of runs that held, frames without
  contact.

Each epoch draws chunks: one ending at (or a few frames after) the moment of every slip run, and
``negatives`` random ones from every run. A chunk carries the frames the model needs before its
scored frames (lags and temporal context) so its logits equal a replay of the whole run. Positive
and negative frames get equal total weight in the loss.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch
import torch.nn.functional as F

from slipsense import pergrasp
from slipsense.errors import ConfigError
from slipsense.recordings.runs import GraspRun


@dataclass
class GraspTrainConfig:
    """Settings of :func:`fit_runs` (stored whole in every checkpoint)."""

    model: str = "motionnet"
    model_config: dict = field(default_factory=dict)
    epochs: int = 20
    lr: float = 2e-3
    weight_decay: float = 1e-4
    batch_size: int = 16
    chunk: int = 48  # scored frames per chunk
    negatives: int = 3  # random chunks per run per epoch
    hard_negatives: int = 2  # chunks per run per epoch drawn where the model errs most (after epoch 1)
    mine_every: int = 3  # epochs between refreshes of where the model errs
    positive_weight: float = 0.5  # total weight of onset frames relative to the other frames
    onset_frames: int = 10  # h
    horizon: int = pergrasp.HORIZON  # H
    flips: bool = True  # random horizontal / vertical flips of whole chunks
    seed: int = 0
    inner_folds: int = 2  # for the operating point (0: choose it on the training runs themselves)
    split_seed: int | None = None  # objects -> folds and inner folds (None: seed); set it to vary training alone

    def __post_init__(self):
        checks = {
            "epochs": (1, 10_000),
            "batch_size": (1, 4096),
            "chunk": (1, 2048),
            "negatives": (0, 100),
            "hard_negatives": (0, 100),
            "mine_every": (1, 1000),
            "onset_frames": (0, 500),
            "horizon": (1, 5000),
            "seed": (0, 2**32 - 1),
            "inner_folds": (0, 20),
        }
        if self.split_seed is not None:
            checks["split_seed"] = (0, 2**32 - 1)
        for key, (lo, hi) in checks.items():
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ConfigError(f"{key} must be an integer in {lo}..{hi}, got {v!r}")
        for key in ("lr", "weight_decay", "positive_weight"):
            v = getattr(self, key)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0 or (key == "lr" and v == 0):
                raise ConfigError(f"{key} must be a finite number {'> 0' if key == 'lr' else '>= 0'}, got {v!r}")
        if self.inner_folds == 1:
            raise ConfigError("inner_folds must be 0 or at least 2")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @property
    def folds_seed(self) -> int:
        """The seed objects are split into folds by."""
        return self.seed if self.split_seed is None else self.split_seed


def frame_targets(n: int, moment: int | None, onset: int, horizon: int) -> np.ndarray:
    """``(n,)`` int8 targets of a run's frames (1 onset, 0 no slip, -1 ignored); indices as in the run."""
    y = np.zeros(n, dtype=np.int8)
    if moment is None:
        return y
    y[max(0, moment - horizon) : moment + 1] = -1
    y[max(0, moment - onset) : moment + 1] = 1
    y[moment + 1 :] = -1
    return y


class _Chunks:
    """Draws training chunks from runs (frames after the start-up only)."""

    def __init__(self, runs: Sequence[GraspRun], cfg: GraspTrainConfig):
        self.cfg = cfg
        self.items = []
        for r in runs:
            if not r.usable:
                continue
            s = pergrasp.STARTUP if r.n_frames > pergrasp.STARTUP + 1 else 0
            gray = r.gray[:, s:]
            moment = None if r.moment_of_slip is None else r.moment_of_slip - s
            if moment is not None and moment < 0:
                continue
            y = frame_targets(gray.shape[1], moment, cfg.onset_frames, cfg.horizon)
            self.items.append((gray, y, moment))

    def draw(
        self, rng: np.random.Generator, hardness: list[np.ndarray] | None = None
    ) -> list[tuple[int, list[int], np.ndarray]]:
        """Chunks of one epoch, grouped by run: ``(run index, chunk ends, targets (C, chunk))`` with
        the runs in random order. ``hardness``: per run, per frame P(slip) of the current model,
        from which ``hard_negatives`` chunk ends per run are drawn among the negative frames."""
        out = []
        for i, (gray, y, moment) in enumerate(self.items):
            n = gray.shape[1]
            ends = [int(rng.integers(0, n)) for _ in range(self.cfg.negatives)]
            if hardness is not None and self.cfg.hard_negatives:
                w = np.where(y == 0, np.nan_to_num(hardness[i], nan=0.0) + 1e-3, 0.0)
                if w.sum() > 0:
                    ends += [int(e) for e in rng.choice(n, self.cfg.hard_negatives, p=w / w.sum())]
            if moment is not None:
                ends.append(min(n - 1, moment + int(rng.integers(0, 6))))
            frames = np.asarray(ends)[:, None] + np.arange(1 - self.cfg.chunk, 1)[None]  # (C, chunk)
            targets = np.where(frames >= 0, y[frames.clip(min=0)], -1).astype(np.int64)
            out.append((i, ends, targets))
        return [out[i] for i in rng.permutation(len(out))]


def _batches(chunks, items, size: int, flips: bool, rng: np.random.Generator):
    """Batches of whole runs' chunks (about ``size`` chunks each): a run's frames are encoded once
    for all its chunks (:meth:`~slipsense.models.base.GraspModel.chunk_logits`)."""
    part: list = []
    for k, item in enumerate(chunks):
        part.append(item)
        if sum(len(c[1]) for c in part) < size and k < len(chunks) - 1:
            continue
        dims = [d for d, flip in ((-1, rng.random() < 0.5), (-2, rng.random() < 0.5)) if flips and flip]
        runs = []
        for i, ends, _ in part:
            x = torch.from_numpy(items[i][0])  # uint8 (S, N, h, w): flipped before it is 4x larger
            runs.append(((x.flip(dims) if dims else x).float().div_(255.0), ends))
        yield runs, torch.from_numpy(np.concatenate([c[2] for c in part]))
        part = []


def fit_runs(
    runs: Sequence[GraspRun],
    cfg: GraspTrainConfig,
    progress: bool = True,
    on_epoch: Callable[[dict[str, Any]], None] | None = None,
    state_path=None,
):
    """Train ``cfg.model`` on ``runs``; returns ``(model in eval mode, per-epoch metrics)``.

    ``state_path``: after every epoch the whole training state (weights, optimizer, schedule, both
    random generators, the mined hard negatives, the metrics) is written there atomically, and a
    training that finds a state there continues from it: killed at any moment and started again, it
    ends with the weights an uninterrupted training gives, bit for bit."""
    from slipsense.models import build

    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    model = build(cfg.model, **cfg.model_config)
    data = _Chunks(runs, cfg)
    if not data.items:
        raise ConfigError("no usable training runs (every run excluded, or slip runs without a moment)")
    if not any(m is not None for _, _, m in data.items):
        raise ConfigError("the training runs hold no slip with a known moment: nothing to learn onset from")
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=cfg.epochs)
    history = []
    hardness = None
    start = 0
    identity = {"config": cfg.to_dict(), "runs": [[r.object, r.experiment, list(r.cameras)] for r in runs]}
    if state_path is not None and Path(state_path).is_file():
        start, history, hardness = _restore(state_path, identity, model, opt, sched, rng)
    epochs = range(start, cfg.epochs)
    if progress:
        from tqdm import tqdm

        epochs = tqdm(epochs, desc=f"training {cfg.model}", unit="epoch")
    for epoch in epochs:
        model.train()
        t0 = time.perf_counter()
        if epoch > 0 and cfg.hard_negatives and (epoch - 1) % cfg.mine_every == 0:
            model.eval()
            hardness = [p for p in _predict_items(model, data.items)]
            model.train()
        chunks = data.draw(rng, hardness)
        ys = np.concatenate([c[2] for c in chunks])
        n_pos, n_neg = int((ys == 1).sum()), int((ys == 0).sum())
        weight = torch.tensor([1.0, cfg.positive_weight * n_neg / max(n_pos, 1)])
        total, seen, correct = 0.0, 0, 0
        for x, y in _batches(chunks, data.items, cfg.batch_size, cfg.flips, rng):
            logits = model.chunk_logits(x, cfg.chunk)
            keep = y >= 0
            if not bool(keep.any()):
                continue
            loss = F.cross_entropy(logits[keep], y[keep], weight=weight)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            total += float(loss.detach()) * int(keep.sum())
            seen += int(keep.sum())
            correct += int((logits[keep].argmax(-1) == y[keep]).sum())
        sched.step()
        _trim_heap()
        row = {
            "epoch": epoch + 1,
            "loss": total / max(seen, 1),
            "frame_accuracy": correct / max(seen, 1),
            "onset_frames": n_pos,
            "other_frames": n_neg,
            "seconds": time.perf_counter() - t0,
        }
        history.append(row)
        if state_path is not None:
            _save_state(state_path, identity, epoch + 1, model, opt, sched, rng, hardness, history)
        if on_epoch is not None:
            on_epoch(row)
    return model.eval(), history


def _save_state(path, identity, epoch, model, opt, sched, rng, hardness, history) -> None:
    from slipsense.checkpoint import save_resume_state

    save_resume_state(
        path,
        {
            "identity": json.dumps(identity, sort_keys=True),
            "epoch": epoch,
            "model": model.state_dict(),
            "optimizer": opt.state_dict(),
            "scheduler": sched.state_dict(),
            "rng": {"numpy": rng.bit_generator.state, "torch": torch.get_rng_state()},
            "hardness": None if hardness is None else [torch.from_numpy(np.asarray(h)) for h in hardness],
            "history": history,
            "best": 0.0,
        },
    )


def _restore(path, identity, model, opt, sched, rng):
    """Load a state :func:`_save_state` wrote into the training's objects; ``(epoch, history, hardness)``."""
    from slipsense.checkpoint import load_resume_state
    from slipsense.errors import InputError

    state = load_resume_state(path)
    if state.get("identity") != json.dumps(identity, sort_keys=True):
        raise InputError(path, "resume state of another training (settings or runs differ); use a new --out")
    try:
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
        rng.bit_generator.state = state["rng"]["numpy"]
        torch.set_rng_state(state["rng"]["torch"])
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise InputError(path, f"resume state does not fit this training ({type(exc).__name__}: {exc})") from None
    hardness = state.get("hardness")
    return state["epoch"], state["history"], None if hardness is None else [h.numpy() for h in hardness]


def _trim_heap() -> None:
    """Hand freed heap memory back to the OS (glibc only; elsewhere nothing). Each step allocates
    tensors of another size (a batch's distinct frames), which fragments the heap: without this a
    training process grew by ~200 MB per epoch, to about 3 GB; trimmed after every epoch it peaks near
    1.3 GB (fold 0's training runs), at no cost in speed."""
    global _LIBC
    if _LIBC is None:
        import ctypes
        import ctypes.util

        try:
            _LIBC = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
            _LIBC.malloc_trim  # noqa: B018 - raises AttributeError where the C library has none
        except (OSError, AttributeError):
            _LIBC = False
    if _LIBC:
        _LIBC.malloc_trim(0)


_LIBC = None


@torch.no_grad()
def _predict_items(model, items) -> list[np.ndarray]:
    return [
        torch.softmax(model(torch.from_numpy(g[None]).float().div_(255.0))[0], -1)[:, 1].numpy() for g, _, _ in items
    ]


@torch.no_grad()
def predict_runs(model, runs: Sequence[GraspRun]) -> list[np.ndarray]:
    """P(slip) at every frame of every run, as a replay from the first frame gives it; NaN during
    the camera start-up (the detector does not answer there)."""
    out = []
    for r in runs:
        s = pergrasp.STARTUP if r.n_frames > pergrasp.STARTUP + 1 else 0
        p = np.full(r.n_frames, np.nan)
        x = torch.from_numpy(r.gray[None, :, s:]).float().div_(255.0)
        p[s:] = torch.softmax(model(x)[0], dim=-1)[:, 1].double().numpy()
        out.append(p)
    return out


def object_split(runs: Sequence[GraspRun], folds: int, seed: int = 0) -> list[list[str]]:
    """Objects of ``runs`` in ``folds`` folds (:func:`slipsense.recordings.clips.object_folds`)."""
    from slipsense.recordings.clips import object_folds

    return object_folds({r.object for r in runs}, folds, seed)


@dataclass(frozen=True)
class FitJob:
    """One training of a plan (:func:`plan_training`): runs named by index into a shared list."""

    train: tuple[int, ...]
    predict: tuple[int, ...]  # runs replayed by the trained model
    keep_model: bool = False  # return the weights (the detector itself, not an inner-fold one)
    state_path: str | None = None  # where the training keeps its resume state (None: nowhere)


def fit_job(shared: tuple[Sequence[GraspRun], GraspTrainConfig], job: FitJob, tick=lambda units: None):
    """Run one :class:`FitJob` (in this process or a worker, :func:`slipsense.parallel.run_jobs`):
    ``{"history", "probs" (per predicted run), "state" (weights, when kept)}``; ticks
    ``len(job.train)`` units per epoch."""
    runs, cfg = shared
    model, history = fit_runs(
        [runs[i] for i in job.train],
        cfg,
        progress=False,
        on_epoch=lambda _: tick(len(job.train)),
        state_path=job.state_path,
    )
    probs = predict_runs(model, [runs[i] for i in job.predict])
    state = {k: v.detach().clone() for k, v in model.state_dict().items()} if job.keep_model else None
    return {"history": history, "probs": probs, "state": state}


def job_weight(job: FitJob, cfg: GraspTrainConfig) -> float:
    """Progress units :func:`fit_job` ticks in all."""
    return float(len(job.train) * cfg.epochs)


def plan_training(runs: Sequence[GraspRun], held: Sequence[str], cfg: GraspTrainConfig) -> list[FitJob]:
    """The trainings behind one detector: first the detector on every usable run whose object is not
    in ``held`` (replaying the held-out objects' runs), then one per inner fold of those training
    objects (each replaying its own held-out runs), which choose the operating point. Indices are
    into ``runs``."""
    usable = [i for i, r in enumerate(runs) if r.usable]
    train = tuple(i for i in usable if runs[i].object not in set(held))
    jobs = [FitJob(train, tuple(i for i in usable if runs[i].object in set(held)), keep_model=True)]
    if cfg.inner_folds:
        for inner in object_split([runs[i] for i in train], cfg.inner_folds, cfg.folds_seed):
            jobs.append(
                FitJob(
                    tuple(i for i in train if runs[i].object not in inner),
                    tuple(i for i in train if runs[i].object in inner),
                )
            )
    return jobs


def finish_training(
    runs: Sequence[GraspRun], jobs: Sequence[FitJob], results: Sequence[dict[str, Any]], cfg: GraspTrainConfig
):
    """From a finished :func:`plan_training`: ``(model in eval mode, history, operating point,
    P(slip) traces of the held-out runs)``. The operating point is chosen on the inner folds'
    out-of-fold traces (or, with ``inner_folds=0``, on the model's own traces of its training runs)."""
    from slipsense.models import build

    model = build(cfg.model, **cfg.model_config)
    model.load_state_dict(results[0]["state"])
    model.eval()
    train = [runs[i] for i in jobs[0].train]
    if cfg.inner_folds:
        by_index = {i: p for job, res in zip(jobs[1:], results[1:]) for i, p in zip(job.predict, res["probs"])}
        probs = [by_index[i] for i in jobs[0].train]
    else:
        probs = predict_runs(model, train)
    return model, results[0]["history"], _chosen_operating_point(probs, train, cfg), results[0]["probs"]


def train_with_operating_point(
    runs: Sequence[GraspRun],
    held: Sequence[str],
    cfg: GraspTrainConfig,
    workers: int | None = 1,
    progress: bool = False,
    state_dir=None,
):
    """Train a detector on the runs of every object but ``held`` and choose its operating point on
    those runs only (:func:`plan_training` on ``workers`` processes); returns :func:`finish_training`'s
    ``(model, history, operating point, held-out traces)``. ``state_dir``: each training keeps its
    resume state there (``job<k>.state``) and continues from one it finds (:func:`fit_runs`)."""
    import dataclasses

    from slipsense.parallel import run_jobs

    jobs = plan_training(runs, held, cfg)
    if state_dir is not None:
        Path(state_dir).mkdir(parents=True, exist_ok=True)
        jobs = [dataclasses.replace(j, state_path=str(Path(state_dir) / f"job{k}.state")) for k, j in enumerate(jobs)]
    if not jobs[0].train:
        raise ConfigError("no usable training runs (every run excluded, or slip runs without a moment)")
    results = run_jobs(
        fit_job, jobs, (runs, cfg), workers, [job_weight(j, cfg) for j in jobs], progress=progress, desc=cfg.model
    )
    return finish_training(runs, jobs, results, cfg)


def operating_point(
    runs: Sequence[GraspRun], cfg: GraspTrainConfig, progress: bool = False, model=None, workers: int | None = 1
) -> dict[str, Any]:
    """The alarm threshold and debounce for a model trained on ``runs``, chosen on those runs only:
    on out-of-fold predictions of ``cfg.inner_folds`` inner folds by object (each inner model trained
    like the outer one), or, with ``inner_folds=0``, on ``model``'s own predictions of ``runs``."""
    usable = [r for r in runs if r.usable]
    if cfg.inner_folds == 0:
        if model is None:
            raise ConfigError("inner_folds=0 needs the trained model")
        probs = predict_runs(model, usable)
    else:
        from slipsense.parallel import run_jobs

        jobs = plan_training(usable, (), cfg)[1:]
        results = run_jobs(fit_job, jobs, (usable, cfg), workers, [job_weight(j, cfg) for j in jobs], progress=progress)
        by_index = {i: p for job, res in zip(jobs, results) for i, p in zip(job.predict, res["probs"])}
        probs = [by_index[i] for i in range(len(usable))]
    return _chosen_operating_point(probs, usable, cfg)


def _chosen_operating_point(probs: Sequence[np.ndarray], runs: Sequence[GraspRun], cfg: GraspTrainConfig) -> dict:
    """The threshold and debounce that best separate ``runs``' slips from their held grasps, and on what."""
    op = pergrasp.choose_operating_point(probs, [r.moment_of_slip for r in runs], horizon=cfg.horizon)
    op["chosen_on"] = (
        f"{cfg.inner_folds} inner folds of the training objects" if cfg.inner_folds else "the training runs themselves"
    )
    return op


def clip_scores(
    runs: Sequence[GraspRun], probs: Sequence[np.ndarray], labels: dict, frames: int = 5
) -> tuple[np.ndarray, np.ndarray]:
    """The paper's clip protocol on per-frame traces: every ``frames``-frame clip the project cuts
    (:func:`slipsense.recordings.clips.plan_windows`: the clip ending right before the moment of
    slip, two wiggle windows per video of a run that held) is scored by the detector's probability
    at its last frame. Returns ``(p, y)``; a run's cameras share one fused trace, so both cameras'
    clips of a run get the probability of their own end frames."""
    from slipsense.recordings.clips import ClipSpec, plan_windows

    spec = ClipSpec(frames=frames)
    p, y = [], []
    for run, trace in zip(runs, probs):
        for cam in run.cameras:
            label = labels.get((run.object, run.experiment, cam))
            if label is None:
                continue
            for w in plan_windows(label, spec):
                p.append(trace[w.end])
                y.append(w.y)
    return np.asarray(p, dtype=np.float64), np.asarray(y, dtype=np.int64)


def clip_metrics(p: np.ndarray, y: np.ndarray, threshold: float) -> dict[str, Any]:
    """Accuracy, balanced accuracy, precision, recall, F1 and the always-wiggle baseline."""
    pred = np.nan_to_num(p, nan=0.0) >= threshold
    tp, fp = int((pred & (y == 1)).sum()), int((pred & (y == 0)).sum())
    fn, tn = int((~pred & (y == 1)).sum()), int((~pred & (y == 0)).sum())
    prec = tp / (tp + fp) if tp + fp else 0.0
    rec = tp / (tp + fn) if tp + fn else 0.0
    spec = tn / (tn + fp) if tn + fp else 0.0
    return {
        "clips": len(y),
        "slip_clips": int((y == 1).sum()),
        "accuracy": (tp + tn) / max(len(y), 1),
        "balanced_accuracy": (rec + spec) / 2,
        "precision": prec,
        "recall": rec,
        "f1": 2 * prec * rec / (prec + rec) if prec + rec else 0.0,
        "always_wiggle_accuracy": float((y == 0).mean()) if len(y) else math.nan,
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "tn": tn,
    }


def fold_result(
    test: Sequence[GraspRun],
    probs: Sequence[np.ndarray],
    op: dict[str, Any],
    history: list[dict[str, Any]],
    labels: dict,
    held: Sequence[str],
    cfg: GraspTrainConfig,
) -> dict[str, Any]:
    """A fold's per-grasp summary and clip metrics at its operating point, plus what pooling needs:
    every held-out run's trace and the clips' probabilities and labels."""
    rests = [pergrasp.rest_mask(r.contact) for r in test]
    outs = _outcomes(test, probs, op, cfg.horizon, rests)
    p, y = clip_scores(test, probs, labels)
    return {
        "objects": sorted(held),
        "operating_point": op,
        "per_grasp": pergrasp.summarise(outs),
        "clips": clip_metrics(p, y, op["threshold"]),
        "history": history,
        "clip_probability": [round(float(v), 5) for v in p],
        "clip_label": [int(v) for v in y],
        "runs": [
            {
                "object": r.object,
                "experiment": r.experiment,
                "cameras": list(r.cameras),
                "moment_of_slip": r.moment_of_slip,
                "outcome": o.outcome,
                "first_alarm": o.first_alarm,
                "lead": o.lead,
                "rest": np.flatnonzero(rest).tolist(),
                "probability": [None if math.isnan(v) else round(float(v), 4) for v in pr],
            }
            for r, o, pr, rest in zip(test, outs, probs, rests)
        ],
    }


def pool_folds(folds: Sequence[dict[str, Any]], thresholds: Sequence[float] | None = None) -> dict[str, Any]:
    """Pool :func:`fold_result` s: per-grasp outcomes and clip decisions, each fold at its own
    operating point; and, for the trade-off curve, every fold's runs at shared ``thresholds``."""
    outcomes = [
        pergrasp.GraspOutcome(r["outcome"], r["first_alarm"], r["lead"], 0.0, 0) for f in folds for r in f["runs"]
    ]
    per_grasp = pergrasp.summarise(outcomes)
    per_grasp["runs_alarming_at_rest"] = sum(f["per_grasp"]["runs_alarming_at_rest"] for f in folds)
    per_grasp["held_alarm_fraction"] = float(np.mean([f["per_grasp"]["held_alarm_fraction"] for f in folds]))
    decisions = np.concatenate([np.asarray(f["clip_probability"]) >= f["operating_point"]["threshold"] for f in folds])
    y = np.concatenate([np.asarray(f["clip_label"], dtype=np.int64) for f in folds])
    if thresholds is None:
        thresholds = pergrasp.THRESHOLDS
    traces, moments, rests = [], [], []
    for f in folds:
        for r in f["runs"]:
            p = np.array([np.nan if v is None else v for v in r["probability"]], dtype=np.float64)
            rest = np.zeros(len(p), dtype=bool)
            rest[r["rest"]] = True
            traces.append(p)
            moments.append(r["moment_of_slip"])
            rests.append(rest)
    debounce = int(np.median([f["operating_point"]["debounce"] for f in folds]))
    curve = pergrasp.table(traces, moments, thresholds, (debounce,), rests=rests)
    p_all = np.concatenate([np.asarray(f["clip_probability"], dtype=np.float64) for f in folds])
    return {
        "per_grasp": per_grasp,
        "clips": clip_metrics(decisions.astype(np.float64), y, 0.5),
        "clips_at_half": clip_metrics(p_all, y, 0.5),
        "operating_points": [f["operating_point"] for f in folds],
        "curve": curve,
    }


# ---------------------------------------------------------------------------------------------
# What the commands run: data, one detector, the folds
# ---------------------------------------------------------------------------------------------


def make_config(model: str, settings: dict[str, Any], size: tuple[int, int] | None = None) -> GraspTrainConfig:
    """A :class:`GraspTrainConfig` from ``--set`` pairs: training keys by name, anything else (or
    ``model.KEY``) goes to the model's config; ``size`` sets the model's ``image_size``."""
    train_keys = set(GraspTrainConfig.__dataclass_fields__) - {"model", "model_config"}
    train, model_cfg = {}, {}
    for key, value in settings.items():
        if key.startswith("model."):
            model_cfg[key[len("model.") :]] = value
        elif key in train_keys:
            train[key] = value
        else:
            model_cfg[key] = value
    if size is not None:
        model_cfg["image_size"] = list(size)
    from slipsense.run_config import typed

    cfg = GraspTrainConfig(model=model, model_config=model_cfg, **typed(GraspTrainConfig, train, "grasp training"))
    from slipsense.models import build

    build(cfg.model, **cfg.model_config)  # unknown or out-of-range model settings fail here, before any work
    return cfg


def load_grasp_data(
    recordings, overrides=None, image_size: tuple[int, int] = (30, 40), on_error: str = "raise", progress: bool = True
) -> tuple[list[GraspRun], dict]:
    """Labelled whole runs of a recordings folder (``(runs, labels)``), labels with overrides."""
    from slipsense.data import label_runs
    from slipsense.recordings.folders import find_recordings, validate_recordings
    from slipsense.recordings.runs import load_runs

    recs = validate_recordings(find_recordings(recordings, on_error=on_error), on_error=on_error, expected_size=None)
    if not recs:
        from slipsense.errors import InputError

        raise InputError(recordings, "no usable recordings")
    labels = label_runs(recs, overrides, on_error=on_error, progress=progress)
    recs = [r for r in recs if r.key in labels]  # runs left out by on_error="skip"
    return load_runs(recs, labels, image_size, progress=progress), labels


def _checkpoint_info(
    cfg: GraspTrainConfig,
    op: dict[str, Any],
    runs: Sequence[GraspRun],
    data: dict[str, Any],
    history: list[dict[str, Any]],
) -> dict[str, Any]:
    data = dict(data)
    tree = data.pop("config", None)  # the whole configuration tree, where every checkpoint keeps it
    from slipsense.sensors.spec import GELSIGHT_MINI

    return {
        "train_config": cfg.to_dict(),
        "sensor": GELSIGHT_MINI.to_dict(),  # grasps are read from GelSight recording folders
        "operating_point": op,
        "history": history,
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
    write ``out/detector.safetensors`` (weights, full config, operating point), ``metrics.csv`` and
    ``curves.png``; with ``held`` objects, also ``held_out.json`` (their per-grasp outcomes and clip
    metrics, never used for any choice).

    Every training keeps its state in ``out/resume/`` after each epoch; ``resume=True`` continues
    from there (a killed run ends with the weights of an uninterrupted one), else it starts afresh."""
    from slipsense import atomic
    from slipsense.checkpoint import save_checkpoint

    out = Path(out)
    state_dir = out / "resume"
    if not resume and state_dir.is_dir():
        for stale in state_dir.glob("job*.state"):
            stale.unlink()
    usable = [r for r in runs if r.usable]
    train = [r for r in usable if r.object not in set(held)]
    unknown = sorted(set(held) - {r.object for r in usable})
    if unknown:
        raise ConfigError(f"held-out objects without usable runs: {', '.join(unknown)}")
    model, history, op, held_probs = train_with_operating_point(runs, held, cfg, workers, progress, state_dir)
    info = _checkpoint_info(cfg, op, train, {**(data or {}), "held_out_objects": sorted(held)}, history)
    path = save_checkpoint(out / "detector.safetensors", model, info)
    _write_history(out, history)
    result = {"checkpoint": str(path), "operating_point": op, "history": history}
    if held:
        test = [r for r in usable if r.object in set(held)]
        fold = evaluate_held_out(held_probs, op, test, labels, cfg.horizon)
        atomic.write_text(out / "held_out.json", json.dumps({"objects": sorted(held), **fold}, indent=1))
        result.update(fold)
    return result


def evaluate_held_out(
    probs: Sequence[np.ndarray], op: dict[str, Any], runs: Sequence[GraspRun], labels: dict, horizon: int
) -> dict[str, Any]:
    """Per-grasp outcomes and clip metrics of ``runs`` from their P(slip) traces at ``op``."""
    outs = _outcomes(runs, probs, op, horizon, [pergrasp.rest_mask(r.contact) for r in runs])
    p, y = clip_scores(runs, probs, labels)
    return {"per_grasp": pergrasp.summarise(outs), "clips": clip_metrics(p, y, op["threshold"])}


def _outcomes(runs, probs, op: dict[str, Any], horizon: int, rests) -> list[pergrasp.GraspOutcome]:
    """Each run's per-grasp verdict at the operating point ``op``."""
    return [
        pergrasp.grasp_outcome(
            pergrasp.debounce(p, op["threshold"], op["debounce"]), r.moment_of_slip, horizon, rest=rest
        )
        for r, p, rest in zip(runs, probs, rests)
    ]


def _write_history(out, history: list[dict[str, Any]]) -> None:
    import csv
    import io

    from slipsense import atomic
    from slipsense.plots import _plt, save_figure

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(history[0]), lineterminator="\n")
    w.writeheader()
    w.writerows(history)
    atomic.write_text(out / "metrics.csv", buf.getvalue())
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.2, 3.4))
    ax.plot([h["epoch"] for h in history], [h["loss"] for h in history], marker=".", label="loss (weighted)")
    ax.plot([h["epoch"] for h in history], [h["frame_accuracy"] for h in history], marker=".", label="frame accuracy")
    ax.set_xlabel("epoch")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    save_figure(fig, out / "curves.png")
