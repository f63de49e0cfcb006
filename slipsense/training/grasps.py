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

from slipsense.evaluation import pergrasp
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
    max_held_alarm: float | None = (
        None  # operating point: at most this fraction of held grasps alarm (None: best score)
    )

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
        k = self.max_held_alarm
        if k is not None and (isinstance(k, bool) or not isinstance(k, (int, float)) or not 0 <= k <= 1):
            raise ConfigError(f"max_held_alarm must be a fraction in [0, 1] (0.05: at most 5%), got {k!r}")

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
    identity = {
        "config": cfg.to_dict(),
        "runs": [[r.object, r.experiment, list(r.cameras), r.slipped, r.moment_of_slip, r.n_frames] for r in runs],
    }
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
    the camera start-up (the detector does not answer there). The model's own stream replays them
    (:meth:`~slipsense.models.base.SlipModel.stream`): the numbers the live detector gives."""
    stream = model.stream()
    return [stream.replay_cached(r.gray)[:, 0] for r in runs]


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
    recordings,
    overrides=None,
    image_size: tuple[int, int] = (30, 40),
    on_error: str = "raise",
    progress: bool = True,
    sensor=None,
) -> tuple[list[GraspRun], dict]:
    """Labelled whole runs of a recordings folder (``(runs, labels)``), labels with overrides;
    ``sensor`` (a :class:`~slipsense.sensors.spec.SensorSpec`, default the GelSight Mini) names the
    folder layout."""
    from slipsense.data import label_runs
    from slipsense.recordings.folders import find_recordings, validate_recordings
    from slipsense.recordings.runs import load_runs
    from slipsense.sensors.spec import GELSIGHT_MINI

    found = find_recordings(recordings, on_error=on_error, sensor=sensor or GELSIGHT_MINI)
    recs = validate_recordings(found, on_error=on_error, expected_size=None)
    if not recs:
        from slipsense.errors import InputError

        raise InputError(recordings, "no usable recordings")
    labels = label_runs(recs, overrides, on_error=on_error, progress=progress)
    recs = [r for r in recs if r.key in labels]  # runs left out by on_error="skip"
    return load_runs(recs, labels, image_size, progress=progress), labels
