"""Training on whole grasps: per-frame targets from the moment of slip, chunks of runs, class
balance, the alarm operating point from inner folds, and leave-objects-out over 5 folds.

Targets (``frame_targets``), per frame of a run after the camera start-up, with ``m`` the moment
of slip, ``h`` the onset frames and ``H`` the warning horizon:

* 1 (onset of slip) for frames ``m-h .. m``;
* ignored for ``m-H .. m-h-1`` (an alarm there is still a warning in time: not pushed either way)
  and after ``m`` (contact is gone; what happens then is not scored);
* 0 everywhere else: the calm parts of slip runs, every frame of runs that held, frames without
  contact.

Each epoch draws chunks: one ending at (or a few frames after) the moment of every slip run,
and ``negatives`` random ones from every run. A chunk carries the frames the model needs before its
scored frames (lags and temporal context) so its logits equal a replay of the whole run. Positive
and negative frames get equal total weight in the loss.
"""

from __future__ import annotations

import itertools
import json
import math
import warnings
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Callable, Sequence

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from slipsense.checkpoint import load_model, read_info
from slipsense.paths import portable_path, resolve_path
from slipsense.errors import ConfigError, SlipsenseError
from slipsense.measures import pergrasp
from slipsense.models import build
from slipsense.models.base import RecordingsShape
from slipsense.recordings.folders import camera_counts
from slipsense.recordings.recording_set import Labelled, Recordings, labelled_set
from slipsense.recordings.runs import GraspRun, load_runs
from slipsense.config_tree import DEFAULT_MODEL, typed
from slipsense.streaming.clock import resample, slower_camera_frames
from slipsense.training.trainer import LoopSettings, Step, Task, train


@dataclass
class GraspTrainConfig:
    """Settings of :func:`fit_runs` (stored whole in every checkpoint)."""

    model: str = DEFAULT_MODEL
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
    # operating point: at most this fraction of held grasps alarm (None: best score)
    max_held_alarm: float | None = None
    accumulate: int = 1  # micro-batches per process per step (a step's runs cut into world x accumulate groups)
    startup: int = pergrasp.STARTUP  # leading frames never trained on or scored (the camera's start-up; 0: none)
    init: str | None = None  # a checkpoint of cfg.model whose weights training starts from (fine-tuning)
    # model settings to choose among on the training objects, e.g. {"gate": [0.3, 0.5]}: every
    # combination is trained and judged as the detector is (its operating point on the inner folds);
    # the best by the rule's score on the training runs is the detector (ties: the better ROC AUC)
    choose: dict = field(default_factory=dict)
    # train also on each run as a slower camera would give it: at these fractions of the recorded rate
    # (0.6: 15 of 25 frames/s), resampled to the model's clock as the live detector does; each run of a
    # step takes the recorded rate or one of these at random (empty: the recorded rate only)
    slower: list = field(default_factory=list)
    # train on each run of a step as a unit of another exposure would see it: its grey levels times a
    # gain drawn uniformly from [low, high] (e.g. [0.7, 1.3]; empty: as recorded)
    gain: list = field(default_factory=list)

    def __post_init__(self):
        # epochs 0: no gradient training (a model of fixed settings: its operating point only)
        checks = dict(epochs=(0, 10_000), batch_size=(1, 4096), chunk=(1, 2048), negatives=(0, 100))
        checks.update(hard_negatives=(0, 100), mine_every=(1, 1000), onset_frames=(0, 500), horizon=(1, 5000))
        checks.update(seed=(0, 2**32 - 1), inner_folds=(0, 20), accumulate=(1, 1024), startup=(0, 1000))
        if self.split_seed is not None:
            checks["split_seed"] = (0, 2**32 - 1)
        for key, (lo, hi) in checks.items():
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ConfigError(f"{key} must be an integer in {lo}..{hi}, got {v!r}")
        for key in ("lr", "weight_decay", "positive_weight"):
            v = getattr(self, key)
            positive = key in ("lr", "positive_weight")
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0 or (positive and v == 0):
                raise ConfigError(f"{key} must be a finite number {'> 0' if positive else '>= 0'}, got {v!r}")
        if self.init is not None and not isinstance(self.init, str):
            raise ConfigError(f"init must be the path of a checkpoint, got {self.init!r}")
        if not isinstance(self.choose, dict) or not all(
            isinstance(k, str) and isinstance(v, list) and v for k, v in self.choose.items()
        ):
            raise ConfigError(f"choose must map model settings to lists of values to try, got {self.choose!r}")
        if self.choose and self.init is not None:
            raise ConfigError("choose: a fine-tuned model's settings are its train.init checkpoint's, not chosen")
        combinations = math.prod(len(v) for v in self.choose.values())
        if combinations > 64:
            raise ConfigError(f"choose: {combinations} combinations (at most 64)")
        if self.inner_folds == 1:
            raise ConfigError("inner_folds must be 0 or at least 2")
        if not isinstance(self.slower, list) or not all(
            isinstance(f, (int, float)) and not isinstance(f, bool) and 0.1 <= f < 1 for f in self.slower
        ):
            raise ConfigError(f"slower must list fractions of the recorded rate in [0.1, 1), got {self.slower!r}")
        g = self.gain
        if g and not (
            isinstance(g, list) and len(g) == 2 and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in g)
            and 0.1 <= g[0] <= g[1] <= 10
        ):  # fmt: skip
            raise ConfigError(f"gain must be [low, high] with 0.1 <= low <= high <= 10, got {g!r}")
        k = self.max_held_alarm
        if k is not None and (isinstance(k, bool) or not isinstance(k, (int, float)) or not 0 <= k <= 1):
            raise ConfigError(f"max_held_alarm must be a fraction in [0, 1] (0.05: at most 5%), got {k!r}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @property
    def folds_seed(self) -> int:
        """The seed objects are split into folds by."""
        return self.seed if self.split_seed is None else self.split_seed


#: Target of the frames of a grasp labelled slipped as a whole: some frame among them is slip (a
#: bag, scored by its most slip-like frame), which one is not known.
BAG = 2


def frame_targets(n: int, moment: int | None, onset: int, horizon: int, bag: bool = False) -> np.ndarray:
    """``(n,)`` int8 targets of a run's frames (1 onset, 0 no slip, -1 ignored, :data:`BAG` every frame
    of a grasp labelled slipped as a whole); indices as in the run."""
    if bag:
        return np.full(n, BAG, dtype=np.int8)
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
            # a grasp labelled as a whole was cut from a stream (no camera start-up in it)
            s = cfg.startup if r.n_frames > cfg.startup + 1 and not r.whole else 0
            gray = r.gray[:, s:]
            moment = None if r.moment_of_slip is None else r.moment_of_slip - s
            if moment is not None and moment < 0:
                continue  # lost during the camera start-up: none of its frames is scored
            bag = r.slipped and r.moment_of_slip is None  # labelled as a whole (usable: r.whole)
            y = frame_targets(gray.shape[1], moment, cfg.onset_frames, cfg.horizon, bag)
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
            if y[0] == BAG:  # the bag: the grasp's last `chunk` frames, by which it has slipped
                out.append((i, [n - 1], _chunk_targets(y, [n - 1], self.cfg.chunk)))
                continue
            ends = [int(rng.integers(0, n)) for _ in range(self.cfg.negatives)]
            if hardness is not None and self.cfg.hard_negatives:
                w = np.where(y == 0, np.nan_to_num(hardness[i], nan=0.0) + 1e-3, 0.0)
                if w.sum() > 0:
                    ends += [int(e) for e in rng.choice(n, self.cfg.hard_negatives, p=w / w.sum())]
            if moment is not None:
                ends.append(min(n - 1, moment + int(rng.integers(0, 6))))
            if not ends:
                continue  # a held run when no random chunks are drawn (negatives=0) before any mining
            out.append((i, ends, _chunk_targets(y, ends, self.cfg.chunk)))
        return [out[i] for i in rng.permutation(len(out))]


def as_slower_camera(gray: np.ndarray, fraction: float) -> np.ndarray:
    """uint8 ``(S, N, h, w)`` frames at the recorded rate -> the same span as a camera at ``fraction``
    of that rate takes it (the recorded frame at or before each of its moments), resampled back to the
    recorded rate's clock (:func:`~slipsense.streaming.clock.resample`): what the live detector feeds
    the model from such a camera. ``(S, N', h, w)``, ``N' <= N``; frame k is still the moment k/rate."""
    nominal = 25.0  # the clock's unit only: the result depends on the fraction, not on this rate
    taken = slower_camera_frames(gray.shape[1], fraction)
    ticks, _ = resample(list(gray[:, taken]), np.arange(len(taken)) / (nominal * fraction), nominal)
    return np.ascontiguousarray(np.stack(ticks))


def _chunk_targets(y: np.ndarray, ends: Sequence[int], chunk: int) -> np.ndarray:
    frames = np.asarray(ends, dtype=np.int64)[:, None] + np.arange(1 - chunk, 1)[None]
    return np.where(frames >= 0, y[frames.clip(min=0)], -1).astype(np.int64)


def _weights(y: np.ndarray, w: np.ndarray) -> float:
    """Loss weight of chunk targets ``y`` (C, chunk): the class weight of each labelled frame, the
    slip weight once for each bag."""
    frames = y[(y == 0) | (y == 1)]
    return float(w[frames].sum() + w[1] * (y == BAG).any(axis=1).sum())


class _ChunkForward(nn.Module):
    """``forward(runs, n_out)`` = the model's :meth:`~slipsense.models.base.GraspModel.chunk_logits`,
    so DDP sees the forward it synchronises."""

    def __init__(self, model):
        super().__init__()
        self.model = model

    def forward(self, runs, n_out: int):
        return self.model.chunk_logits(runs, n_out)


class GraspTask(Task):
    """Whole grasps for the training loop (:mod:`slipsense.training.trainer`).

    An epoch draws chunks (:class:`_Chunks`), every ``mine_every`` epochs after the first from where
    the current model errs most, and groups whole runs' chunks into steps of about ``batch_size``
    chunks, each with its random flips: a run's frames are encoded once for all its chunks. Under
    torchrun (or with ``accumulate``) a step's runs are cut into ``world x accumulate`` consecutive
    groups; the loss weight of a frame is its class weight (onset frames weigh ``positive_weight`` of
    the other frames in total, per epoch)."""

    def __init__(self, runs: Sequence[GraspRun], cfg: GraspTrainConfig):
        self.cfg = cfg
        self.rng = np.random.default_rng(cfg.seed)
        self.data = _Chunks(runs, cfg)
        if not self.data.items:
            raise ConfigError("no usable training runs (every run excluded, or slip runs without a moment)")
        if not any(m is not None or y[0] == BAG for _, y, m in self.data.items):
            raise ConfigError("the training runs hold no slip (with a known moment, or labelled as a whole)")
        self.hardness: list[np.ndarray] | None = None
        self._slower: dict[tuple[int, float], np.ndarray] = {}
        self.weight = torch.ones(2)
        self._stats: dict[str, Any] = {}
        trained_on = [[r.object, r.experiment, list(r.cameras), r.slipped, r.moment_of_slip, r.n_frames] for r in runs]
        self._identity = json.dumps({"config": cfg.to_dict(), "runs": trained_on}, sort_keys=True)

    def trainable(self, model):
        return _ChunkForward(model)

    def optimizer(self, model):
        opt = torch.optim.AdamW(model.parameters(), lr=self.cfg.lr, weight_decay=self.cfg.weight_decay)
        return opt, torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=self.cfg.epochs)

    def plan(self, model, epoch: int, d, accumulate: int) -> list[Step]:
        cfg = self.cfg
        if epoch > 0 and cfg.hard_negatives and (epoch - 1) % cfg.mine_every == 0:
            model.eval()
            self.hardness = _predict_items(model, self.data.items)
        chunks = self.data.draw(self.rng, self.hardness)
        ys = np.concatenate([c[2] for c in chunks])
        n_pos, n_neg = int((ys == 1).sum() + (ys == BAG).any(axis=1).sum()), int((ys == 0).sum())
        self.weight = torch.tensor([1.0, cfg.positive_weight * n_neg / max(n_pos, 1)])
        self._stats = {"onset_frames": n_pos, "other_frames": n_neg}
        w = self.weight.double().numpy()
        weigh = lambda runs: _weights(np.concatenate([c[2] for c in runs]), w) if runs else 0.0  # loss weight
        return _steps(chunks, cfg, self.rng, d.world * accumulate, weigh)

    def batches(self, steps, epoch: int, d, accumulate: int):
        mine = range(d.rank * accumulate, (d.rank + 1) * accumulate)
        rates = [1.0, *self.cfg.slower]
        for k, step in enumerate(steps):
            for m in mine:
                if step.micro[m] is not None:
                    runs, dims, weight = step.micro[m]
                    x = []
                    for i, ends, _ in runs:
                        g = self.data.items[i][0]  # uint8 (S, N, h, w): flipped before 4x larger
                        rng = np.random.default_rng([self.cfg.seed, epoch, k, i])
                        rate = rates[rng.integers(len(rates))]
                        if rate < 1:  # the same seconds as a slower camera gives them, on the model's clock
                            g = self._slower_camera(i, rate)
                            ends = [min(e, g.shape[1] - 1) for e in ends]
                        if self.cfg.gain:  # another unit's exposure
                            gain = rng.uniform(*self.cfg.gain)
                            g = np.clip(g.astype(np.float32) * gain + 0.5, 0, 255).astype(np.uint8)
                        g = torch.from_numpy(g)
                        x.append(((g.flip(dims) if dims else g).float().div_(255.0), ends))
                    yield x, torch.from_numpy(np.concatenate([c[2] for c in runs])), weight

    def _slower_camera(self, item: int, rate: float) -> np.ndarray:
        """:func:`as_slower_camera` of a run, made once a training: it depends on the run and the rate
        alone, and making it again each epoch was a seventh of the shipped recipe's training time."""
        key = (item, rate)
        if key not in self._slower:
            self._slower[key] = as_slower_camera(self.data.items[item][0], rate)
        return self._slower[key]

    def loss(self, net, batch, step_weight: float, world: int):
        x, y, weight = batch
        logits = net(x, self.cfg.chunk)
        keep = (y == 0) | (y == 1)
        w = self.weight.to(logits.dtype)
        total = (F.cross_entropy(logits[keep], y[keep], reduction="none") * w[y[keep]]).sum()
        bags = (y == BAG).any(dim=1)
        if bags.any():  # each bag as slip by its most slip-like frame (multiple-instance learning)
            margin = (logits[bags, :, 1] - logits[bags, :, 0]).masked_fill(y[bags] != BAG, float("-inf"))
            total = total + w[1] * F.softplus(-margin.amax(dim=1)).sum()
        mean = total / (w[y[keep]].sum() + w[1] * bags.sum())
        n = int(keep.sum())
        correct = int((logits[keep].argmax(-1) == y[keep]).sum())
        stats = torch.tensor([float(mean.detach()) * weight, weight, correct, n], dtype=torch.float64)
        return mean * (weight * world / step_weight), stats  # train_loss: the class-weighted mean

    def filler_loss(self, net):
        gray = torch.from_numpy(self.data.items[0][0]).float().div_(255.0)
        return net([(gray, [gray.shape[1] - 1])], self.cfg.chunk).sum()

    def epoch_stats(self) -> dict[str, Any]:
        return dict(self._stats)

    def identity(self) -> str:
        return self._identity

    def state(self) -> dict[str, Any]:
        hard = None if self.hardness is None else [torch.from_numpy(np.asarray(h)) for h in self.hardness]
        return {"numpy": self.rng.bit_generator.state, "hardness": hard}

    def restore(self, state: dict[str, Any]) -> None:
        self.rng.bit_generator.state = state["numpy"]
        hard = state.get("hardness")
        self.hardness = None if hard is None else [h.numpy() for h in hard]


def _steps(chunks, cfg: GraspTrainConfig, rng: np.random.Generator, parts: int, weigh) -> list[Step]:
    """Steps of whole runs' chunks (:func:`_groups`), each cut into ``parts`` micro-batches
    ``(runs, flips, weight)`` (None where ``weigh(runs)``, the loss weight, is 0)."""
    steps = []
    for part, dims in _groups(chunks, cfg.batch_size, cfg.flips, rng):
        micro = []
        for idx in np.array_split(np.arange(len(part)), parts):
            runs = [part[i] for i in idx]
            weight = weigh(runs)
            micro.append((runs, dims, weight) if weight > 0 else None)
        steps.append(Step(micro, sum(m[2] for m in micro if m is not None)))
    return steps


def _groups(chunks, size: int, flips: bool, rng: np.random.Generator):
    """Whole runs' chunks in groups of about ``size`` chunks, each with its flips (dims)."""
    part: list = []
    for k, item in enumerate(chunks):
        part.append(item)
        if sum(len(c[1]) for c in part) < size and k < len(chunks) - 1:
            continue
        dims = [d for d, flip in ((-1, rng.random() < 0.5), (-2, rng.random() < 0.5)) if flips and flip]
        yield part, dims
        part = []


def fit_runs(
    runs: Sequence[GraspRun],
    cfg: GraspTrainConfig,
    progress: bool = True,
    on_epoch: Callable[[dict[str, Any]], None] | None = None,
    state_path=None,
    out=None,
    info: dict[str, Any] | None = None,
):
    """Train ``cfg.model`` on ``runs`` through the one training loop (:func:`~slipsense.training.trainer.train`,
    which writes the resume state to ``state_path`` and the checkpoints, with ``info``, metrics and
    curves to ``out``); returns ``(model in eval mode, per-epoch metrics)``."""
    torch.manual_seed(cfg.seed)
    if cfg.init is None:
        model = build(cfg.model, **cfg.model_config)
    else:  # the checkpoint's model (its own settings) trained further; another model than cfg.model is refused
        model = load_model(resolve_path(cfg.init), expect_model=cfg.model)[0].train()
    if cfg.epochs == 0:
        return model.eval(), []
    settings = LoopSettings(
        epochs=cfg.epochs, seed=cfg.seed, accumulate=cfg.accumulate, device="cpu", progress=progress, desc=cfg.model
    )
    task = GraspTask(runs, cfg)
    history = train(model, task, settings, out=out, info=info, state_path=state_path, on_epoch=on_epoch)
    return model.eval(), history


@torch.no_grad()
def _predict_items(model, items) -> list[np.ndarray]:
    return [
        torch.softmax(model(torch.from_numpy(g[None]).float().div_(255.0))[0], -1)[:, 1].numpy() for g, _, _ in items
    ]


@torch.no_grad()
def predict_runs(model, runs: Sequence[GraspRun], startup: int) -> list[np.ndarray]:
    """P(slip) at every frame of every run, as a replay from the first frame gives it; NaN during
    the ``startup`` frames at the runs' rate (the detector does not answer there). The model's own stream replays them
    (:meth:`~slipsense.models.base.SlipModel.stream`): the numbers the live detector gives."""
    stream = model.stream(info={"operating_point": {"startup": startup}})
    return [stream.replay_cached(r.gray)[:, 0] for r in runs]


def make_config(model: str, settings: dict[str, Any]) -> GraspTrainConfig:
    """A :class:`GraspTrainConfig` from ``--set`` pairs: training keys by name, anything else (or
    ``model.KEY``) goes to the model's config."""
    train_keys = set(GraspTrainConfig.__dataclass_fields__) - {"model", "model_config"}
    train, model_cfg = {}, {}
    for key, value in settings.items():  # "model.KEY" is never a training key
        if key in train_keys:
            train[key] = value
        else:
            model_cfg[key.removeprefix("model.")] = value
    if train.get("init") is not None:  # fine-tuning: the model is the checkpoint's, settings and all
        train["init"] = portable_path(resolve_path(train["init"]))  # kept as the checkpoint says it, resolvable
        theirs = dict(read_info(resolve_path(train["init"]))["model_config"])
        other = sorted(k for k, v in model_cfg.items() if theirs.get(k) != v)
        if other:
            raise ConfigError(f"model settings ({', '.join(other)}) come from train.init's checkpoint")
        model_cfg = theirs
    cfg = GraspTrainConfig(model=model, model_config=model_cfg, **typed(GraspTrainConfig, train, "grasp training"))
    for settings in candidates(cfg):  # unknown or out-of-range model settings fail here, before any work
        build(cfg.model, **{**cfg.model_config, **settings})
    return cfg


def candidates(cfg: GraspTrainConfig) -> list[dict[str, Any]]:
    """Every combination of ``cfg.choose``'s model settings (``[{}]`` when it chooses none)."""
    keys = sorted(cfg.choose)
    return [dict(zip(keys, values)) for values in itertools.product(*(cfg.choose[k] for k in keys))]


def with_settings(cfg: GraspTrainConfig, settings: dict[str, Any]) -> GraspTrainConfig:
    """``cfg`` training the model with ``settings`` (one of :func:`candidates`) and choosing nothing more."""
    return replace(cfg, model_config={**cfg.model_config, **settings}, choose={})


def load_grasp_data(
    recordings,
    overrides=None,
    image_size: tuple[int, int] = (30, 40),
    on_error: str = "raise",
    progress: bool = True,
    sensor=None,
) -> tuple[list[GraspRun], dict]:
    """Labelled whole runs (``(runs, labels)``) of a labelled set
    (:class:`~slipsense.recordings.recording_set.Labelled`, taken as it is), or of a
    :class:`~slipsense.recordings.recording_set.Recordings` or its folder, labelled once here with
    ``overrides`` and read as ``sensor`` (None: the sensor the data states). Read once per set
    (:meth:`Recordings.kept`): every training that asks for the same runs shares their frames, so
    nothing writes into them."""
    data = labelled_set(recordings, overrides, sensor, on_error, progress=progress)
    size = tuple(image_size)
    labels = tuple((k, repr(v)) for k, v in sorted(data.labels.items()))  # other labels: other runs
    runs = data.recordings.kept(("grasp runs", size, labels), lambda: _read_grasp_data(data, size, progress))
    return list(runs), dict(data.labels)


def _read_grasp_data(data: Labelled, image_size, progress: bool):
    recs = list(data)
    return load_runs(recs, data.labels, image_size, sensors=cameras_per_grasp(recs), progress=progress)


def cameras_per_grasp(recordings) -> int:
    """The cameras a grasp of ``recordings`` has: one (frame folders of one finger, one-camera runs)
    or both fingers; 2 where the runs differ (the one-camera runs are then refused by name)."""
    counts = camera_counts(recordings)
    return counts[0] if len(counts) == 1 else 2


def recordings_shape(recordings, sensor=None, on_error: str = "raise") -> RecordingsShape | None:
    """What the grasps of a :class:`~slipsense.recordings.recording_set.Recordings` (or its folder) are,
    from its folder structure alone (nothing decoded): the cameras per grasp and whether every grasp is
    labelled as a whole; None where the folder cannot be read so (missing, empty, a bad layout:
    :func:`load_grasp_data` names the problem)."""
    try:
        with warnings.catch_warnings():  # what on_error="skip" leaves out is said when the data is read
            warnings.simplefilter("ignore")
            read = Recordings.of(recordings, sensor, on_error)
    except SlipsenseError:
        return None
    found = read.listed
    return (
        RecordingsShape(cameras_per_grasp(found), all(r.per_grasp for r in found), read.sensor.fps) if found else None
    )
