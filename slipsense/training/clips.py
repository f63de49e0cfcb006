"""Clips and marker sequences for the one training loop (:class:`ClipTask`), and ``slipsense train``
for clip models: from a run configuration (:class:`~slipsense.training.settings.RunConfig`) to a run
folder (:func:`run_training`).

The loop (:mod:`slipsense.training.trainer`) gives the run its checkpoints, metrics, resume and
DDP. ``world_size x batch_size x accumulate`` is the global batch: 2 processes with ``--batch-size
8`` reproduce a 1-process ``--batch-size 16`` run (dropout-free models), and 1 process with
``--batch-size 8 --accumulate 2`` (any model: the dropout masks of a micro-batch do not depend on the
process that draws them).
"""

from __future__ import annotations

import copy
import functools
import json
import math
import os
import random
import warnings
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from safetensors.torch import load_file
from torch.utils.data import DataLoader, Dataset, default_collate

from slipsense.atomic import write_text
from slipsense.checkpoint import load_model, load_resume_state, read_info, update_info
from slipsense.paths import resolve_path
from slipsense.errors import ConfigError, InputError, SlipsenseError
from slipsense.evaluation.predict import evaluate_model, predict
from slipsense.measures.clips import metrics_from
from slipsense.models import available, build, model_class, settings_of
from slipsense.parallel import end_with_parent
from slipsense.readers import check_same_split
from slipsense.recordings.recording_set import Recordings
from slipsense.config_tree import dump_tree, typed
from slipsense.sensors.spec import sensor_of
from slipsense.training.distributed import Dist, RankBatches, StepPlan, setup  # noqa: F401
from slipsense.training.operating_point import choose_on_training_runs
from slipsense.training.trainer import LoopSettings, Step, Task, restore, rng_state, set_rng_state, train


def _loader_worker_start(parent: int, worker_id: int) -> None:
    """A data loader worker ends with this process, as every worker does (:mod:`slipsense.parallel`)."""
    end_with_parent(parent)


@dataclass
class TrainConfig:
    """Optimisation settings (defaults: the ViViT paper's)."""

    epochs: int = 75
    batch_size: int = 16  # per process
    lr: float = 3e-4
    weight_decay: float = 1e-4
    step_size: int = 30  # StepLR period, epochs
    gamma: float = 0.1
    seed: int = 0
    num_workers: int = 0
    device: str = "auto"  # "auto", "cpu", "cuda", "cuda:1"...
    select_by: str = "accuracy"  # validation metric that picks best.safetensors
    progress: bool = True
    max_steps_per_epoch: int | None = None  # cap for smoke runs and tests
    accumulate: int = 1  # micro-batches per process per step: global batch = world x batch_size x accumulate
    operating_point: bool = True  # after training, choose the alarm threshold on the training runs (video models)

    def __post_init__(self):
        checks = [
            (self.epochs >= 1, "epochs must be >= 1"),
            (self.batch_size >= 1, "batch_size must be >= 1"),
            (self.lr > 0 and math.isfinite(self.lr), "lr must be a positive number"),
            (self.weight_decay >= 0, "weight_decay must be >= 0"),
            (self.step_size >= 1, "step_size must be >= 1"),
            (0 < self.gamma <= 1, "gamma must be in (0, 1]"),
            (self.num_workers >= 0, "num_workers must be >= 0"),
            (self.select_by in ("accuracy", "f1", "loss"), "select_by must be accuracy, f1 or loss"),
            (self.max_steps_per_epoch is None or self.max_steps_per_epoch >= 1, "max_steps_per_epoch must be >= 1"),
            (self.accumulate >= 1, "accumulate must be >= 1"),
            (isinstance(self.seed, int) and 0 <= self.seed < 2**32, f"seed must be an integer in 0..{2**32 - 1}"),
        ]
        for ok, msg in checks:
            if not ok:
                raise ConfigError(f"train config: {msg}")

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> "TrainConfig":
        """From ``train`` settings by name (YAML spellings typed: :func:`slipsense.config_tree.typed`);
        ConfigError naming an unknown key or a bad value."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ConfigError(f"train config: unknown keys {unknown}; known: {sorted(known)}")
        return cls(**typed(cls, values, "train config"))


def paper_settings(name: str, preset: str | None = None) -> dict[str, Any]:
    """The training settings of model ``name``'s paper (ViViT paper III; STNet paper III), with those
    its ``preset`` comes with (``preset_training``) over them."""
    cls = model_class(name)
    return {**cls.paper_training, **cls.preset_training.get(preset or "", {})}


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def make_optimizer(model: nn.Module, cfg: TrainConfig):
    """``(optimizer, scheduler)``: Adam with a StepLR schedule, as in both papers."""
    optimizer = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    scheduler = torch.optim.lr_scheduler.StepLR(optimizer, step_size=cfg.step_size, gamma=cfg.gamma)
    return optimizer, scheduler


class ClipTask(Task):
    """Labelled clips (videos or marker sequences) for the training loop (:mod:`slipsense.training.trainer`),
    in the micro-batches of a :class:`~slipsense.training.distributed.StepPlan`: no item is repeated or
    dropped (a DistributedSampler pads with repeats), so 2 x 8 sees the batches 1 x 16 sees, for any
    dataset size. A micro-batch's loss is its summed cross-entropy over the step's item count."""

    def __init__(self, train_data: Dataset, val_data: Dataset | None, cfg: TrainConfig, extra_eval=None):
        if len(train_data) == 0:
            raise ConfigError("the training set is empty: nothing to train on")
        self.train_data, self.val_data, self.cfg, self.extra_eval = train_data, val_data, cfg, extra_eval or {}
        self._loader = None
        self.device = torch.device("cpu")

    def optimizer(self, model):
        return make_optimizer(model, self.cfg)

    def plan(self, model, epoch: int, d: Dist, accumulate: int) -> list[Step]:
        if self._loader is None:
            self.device = d.device
            self._plan = StepPlan(len(self.train_data), self.cfg.batch_size, d.world, accumulate, self.cfg.seed)
            self._rank_batches = RankBatches(self._plan, d.rank)
            n = self.cfg.num_workers
            start = functools.partial(_loader_worker_start, os.getpid()) if n > 0 else None
            workers = dict(num_workers=n, persistent_workers=n > 0, worker_init_fn=start)
            self._loader = DataLoader(self.train_data, batch_sampler=self._rank_batches, **workers)
        return [Step(micro, float(sum(len(m) for m in micro))) for micro in self._plan.steps(epoch)]

    def batches(self, steps, epoch: int, d: Dist, accumulate: int):
        self._rank_batches.set_epoch(epoch)
        return iter(self._loader)

    def loss(self, net, batch, step_weight: float, world: int):
        x, y = (t.to(self.device, non_blocking=True) for t in batch)
        logits = net(x)
        total = F.cross_entropy(logits, y, reduction="sum")
        correct = (logits.argmax(-1) == y).sum().item()
        stats = torch.tensor([total.item(), len(y), correct, len(y)], dtype=torch.float64)
        return total * (world / step_weight), stats

    def filler_loss(self, net):
        x, _ = default_collate([self.train_data[0]])
        return net(x.to(self.device)).sum()

    def validate(self, model, d: Dist) -> dict[str, float]:
        row = {}
        sets = {"val": self.val_data, **self.extra_eval}
        for name, data in sets.items():
            if data is None or not len(data):
                continue
            p, y = predict(model, data, batch_size=max(self.cfg.batch_size, 32), device=d.device, d=d)
            m = metrics_from(p, y)
            row.update({f"{name}_{k}": m[k] for k in ("loss", "accuracy", "precision", "recall", "f1")})
        return row

    def identity(self) -> str:
        return settings_identity(self.cfg)


def settings_identity(cfg: TrainConfig) -> str:
    """The optimisation settings a resume must share (the data split is checked on its own:
    readers.check_same_split); epochs may grow, progress and workers may change."""
    free = ("epochs", "progress", "num_workers", "device", "max_steps_per_epoch", "operating_point")
    return json.dumps({k: v for k, v in asdict(cfg).items() if k not in free}, sort_keys=True)


def fit(
    model: nn.Module,
    train_data: Dataset,
    val_data: Dataset | None,
    cfg: TrainConfig,
    out_dir: str | Path,
    info: dict[str, Any] | None = None,
    resume: bool = False,
    extra_eval: dict[str, Dataset] | None = None,
    resume_state: dict[str, Any] | None = None,
) -> list[dict[str, Any]]:
    """Train ``model`` on ``train_data`` through the one training loop (:func:`~slipsense.training.trainer.train`);
    validate on ``val_data`` after every epoch.

    Args:
        model: a registry model (``forward(x) -> (B, 2)`` logits), already built (seed first!).
        train_data, val_data: Datasets of ``(x, y)``; ``val_data`` may be None.
        cfg: optimisation settings.
        out_dir: run folder; receives ``metrics.csv``, ``curves.png``, ``best.safetensors``,
            ``last.safetensors``, ``resume.pt`` and ``run.json``.
        info: extra config stored in every checkpoint (data settings, split...).
        resume: continue from ``out_dir/resume.pt`` if it exists.
        extra_eval: more labelled sets scored after every epoch (columns ``<name>_accuracy``...),
            e.g. held-out objects beside a clip-level test split; they do not pick the best epoch.
        resume_state: a state already read by :func:`~slipsense.checkpoint.load_resume_state`
            (checked before anything was written); used instead of reading ``resume.pt``.

    Returns:
        The per-epoch metric rows (also written to ``metrics.csv``).
    """
    task = ClipTask(train_data, val_data, cfg, extra_eval)
    model.prepare(train_data)  # what it takes from its data (a resumed state overwrites it with the same)
    world = setup(cfg.device).world
    info = {**(info or {}), "train": asdict(cfg), "global_batch": world * cfg.batch_size * cfg.accumulate}
    loop = ("epochs", "seed", "accumulate", "device", "progress", "max_steps_per_epoch", "select_by")
    settings = LoopSettings(**{k: getattr(cfg, k) for k in loop})  # what the loop needs of cfg
    out = Path(out_dir)
    state = out / "resume.pt"
    return train(model, task, settings, out=out, info=info, state_path=state, resume_state=resume_state, resume=resume)


def _store_operating_point(out: Path, split_info: dict[str, Any], overrides, progress: bool) -> None:
    """Choose the alarm operating point on the training objects' runs (labels: ``overrides``, as
    :func:`slipsense.recordings.labels.label_runs` takes them) and write it into the run's checkpoints
    (:mod:`slipsense.training.operating_point`)."""
    root = resolve_path(split_info["recordings"])
    held = set(split_info.get("test_objects") or ())
    sensor = sensor_of(read_info(out / "last.safetensors"))
    data = Recordings.open(root, sensor, on_error="skip")  # listed once for both checkpoints' judges
    objects = sorted(set(data.objects) - held)
    chosen: list[tuple[dict, dict]] = []  # (weights, operating point): best often holds last's weights
    for name in ("last.safetensors", "best.safetensors"):
        path = out / name
        if not path.is_file():
            continue
        weights = load_file(str(path))
        op = next((o for w, o in chosen if w.keys() == weights.keys() and all(w[k].equal(weights[k]) for k in w)), None)
        if op is None:
            try:
                op = choose_on_training_runs(path, data, objects, overrides, progress)
            except SlipsenseError as exc:  # the training stands; the checkpoint alarms at 0.5 with a warning
                warnings.warn(f"{path}: no operating point chosen ({exc})", stacklevel=2)
                continue
            chosen.append((weights, op))
        update_info(path, {"operating_point": op})
        print(f"{name}: operating point threshold {op['threshold']:g}, debounce {op['debounce']} ({op['chosen_on']})")


def build_model(name: str, preset: str | None, overrides: dict[str, Any], data_config: dict[str, Any]):
    """Build a model: preset (if any) < data-implied sizes < explicit overrides."""
    config: dict[str, Any] = {}
    cls = model_class(name)
    if preset is not None:
        if not cls.presets:
            with_presets = [n for n in available() if model_class(n).presets]
            raise ConfigError(f"--preset is defined for {'/'.join(with_presets)}, not {name!r}")
        if preset not in cls.presets:
            raise ConfigError(f"unknown preset {preset!r}; known: {sorted(cls.presets)}")
        config.update(cls.presets[preset])
    # Data-implied sizes only where the network has such a setting (a 3D ResNet takes any T, H, W).
    accepted = settings_of(cls)
    config.update({k: v for k, v in data_config.items() if k in accepted})
    config.update(overrides)
    return build(name, **config)


def run_training(run, out: Path, progress: bool = True, resume: bool = False) -> dict[str, Any]:
    """Prepare ``run``'s data (a :class:`~slipsense.training.settings.RunConfig` of a clip model: its
    model's reader cuts the clips), build and train the model into ``out``, then evaluate
    ``last.safetensors`` on the held-out part. Returns (rank 0; ``{}`` on other ranks)
    ``{"checkpoint", "operating_point" (None unless one was chosen), "history" (a row per epoch),
    "clips" (the held-out part's metrics, None without one)}``."""
    cls = model_class(run.name)
    cfg = replace(run.train, progress=progress)
    train_data, test_data, split_info, data_config = cls.clip_reader.training_data(run, progress)
    sensor = data_config.pop("sensor")
    seed_everything(run.seed)
    model = build_model(run.name, run.preset, run.settings, data_config)
    d = setup(cfg.device)
    state = None
    if resume and (out / "resume.pt").exists():
        # Everything a resume needs is read and checked before the first file is written, so a
        # refused resume leaves the run folder as it was.
        state = load_resume_state(out / "resume.pt")
        if state.get("identity", "") != settings_identity(cfg):
            raise InputError(out / "resume.pt", "resume state of another training (settings differ); use a new --out")
        probe = copy.deepcopy(model)
        rng = rng_state()
        try:
            restore(out / "resume.pt", state, probe, *make_optimizer(probe, cfg))
        finally:
            set_rng_state(rng)
        del probe
        check_same_split(out / "split.json", split_info)
    tree = run.to_tree()  # every optimisation setting, defaults included
    if d.main:
        out.mkdir(parents=True, exist_ok=True)
        write_text(out / "split.json", json.dumps(split_info, indent=1))
        write_text(out / "config.yaml", dump_tree(tree))
    data = {k: v for k, v in split_info.items() if k != "test_indices"}
    info = {"data": data, "sensor": sensor, "preset": run.preset, "config": tree}
    history = fit(model, train_data, test_data, cfg, out, info=info, resume=resume, resume_state=state)
    # a model reading frames is replayed over its training objects' runs to choose where it alarms
    replayable = cls.clip_reader.replays(split_info)
    if d.main and cfg.operating_point and replayable:
        _store_operating_point(out, split_info, run.data.overrides, progress)
    if not d.main:
        return {}
    last = out / "last.safetensors"
    result = {"checkpoint": last, "operating_point": read_info(last).get("operating_point"), "history": history}
    if len(test_data) == 0:
        return {**result, "clips": None}

    # The held-out part is also the validation set that picked best.safetensors, so scoring that
    # checkpoint on it would be optimistic: the reported model is the last epoch's.
    extra = {"checkpoint": last.as_posix(), **{k: split_info.get(k) for k in ("split", "test_objects")}}
    metrics = evaluate_model(
        load_model(last)[0], test_data, out / "evaluation.json", out / "confusion.png", extra=extra, progress=progress
    )
    print(json.dumps({k: metrics[k] for k in ("accuracy", "precision", "recall", "f1", "n_clips")}))
    return {**result, "clips": metrics}
