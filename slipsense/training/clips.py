"""Training: one loop for every model, single-process or under ``torchrun`` (DDP).

* seeded, with a progress bar, per-epoch metrics in ``metrics.csv`` and ``curves.png``;
* ``best.safetensors`` / ``last.safetensors`` checkpoints (weights + full config);
* ``resume.pt`` after every epoch (data only: safetensors + JSON) so a killed run continues with
  ``resume=True`` and ends with the same weights as an uninterrupted one (the item order depends
  only on seed and epoch, dropout masks only on seed, epoch, step and micro-batch);
* under ``torchrun`` each step's items are split between the ranks by a :class:`StepPlan` (no
  padding: no item is seen twice, for any dataset size), gradients are averaged by DDP (gloo on
  CPU, NCCL on GPU) with each rank's loss weighted by its share of the step, metrics are summed
  across ranks and only rank 0 writes files. ``world_size x batch_size x accumulate`` is the
  global batch: 2 processes with ``--batch-size 8`` reproduce a 1-process ``--batch-size 16`` run
  (dropout-free models), and 1 process with ``--batch-size 8 --accumulate 2`` (any model: the
  dropout masks of a micro-batch do not depend on the process that draws them).
"""

from __future__ import annotations

import contextlib
import copy
import csv
import io
import json
import math
import random
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
import torch.nn as nn
import torch.nn.functional as F
from torch.utils.data import DataLoader, Dataset, default_collate

from slipsense.atomic import write_text
from slipsense.models import available, model_class, settings_of
from slipsense.checkpoint import load_resume_state, save_checkpoint, save_resume_state
from slipsense.errors import ConfigError, InputError
from slipsense.training.distributed import Dist, RankBatches, StepPlan, all_sum, micro_batch_rng, setup  # noqa: F401
from slipsense.evaluation.evaluate import predict, progress_bar
from slipsense.evaluation.metrics import metrics_from  # noqa: F401  (re-exported)
from slipsense.training.splits import SPLIT_IDENTITY, check_same_split, prepare_data  # noqa: F401


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
        from slipsense.run_config import typed

        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ConfigError(f"train config: unknown keys {unknown}; known: {sorted(known)}")
        values = typed(cls, values, "train config")
        return cls(**values)


def paper_settings(name: str) -> dict[str, Any]:
    """The training settings of model ``name``'s paper (ViViT paper III; STNet paper III)."""
    return dict(model_class(name).paper_training)


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


# --------------------------------------------------------------------------- training
def _rng_state() -> dict[str, Any]:
    return {"python": random.getstate(), "numpy": np.random.get_state(), "torch": torch.get_rng_state()}


def _set_rng_state(s: dict[str, Any]) -> None:
    py = s["python"]
    # random.setstate wants (version, tuple of 625 ints, gauss); a list would be refused
    random.setstate((py[0], tuple(py[1]), py[2]))
    np.random.set_state(tuple(s["numpy"]))
    torch.set_rng_state(s["torch"])


def make_optimizer(model: nn.Module, cfg: TrainConfig):
    """``(optimizer, scheduler)``: Adam with a StepLR schedule, as in both papers."""
    optimizer = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    scheduler = torch.optim.lr_scheduler.StepLR(optimizer, step_size=cfg.step_size, gamma=cfg.gamma)
    return optimizer, scheduler


def restore_state(path: Path, state: dict[str, Any], model: nn.Module, optimizer=None, scheduler=None) -> None:
    """Load a resume state into ``model`` (and optimizer, scheduler, RNG); InputError naming
    ``path`` when it does not fit them (another model, other settings, a damaged file)."""

    def fail(what: str, exc: BaseException):
        text = " ".join(str(exc).split())
        raise InputError(path, f"resume state does not fit {what} ({text[:200]})") from None

    try:
        model.load_state_dict(state["model"])
    except (RuntimeError, KeyError, TypeError, ValueError) as exc:
        fail("the model", exc)
    for part, obj in (("optimizer", optimizer), ("scheduler", scheduler)):
        if obj is None:
            continue
        try:
            obj.load_state_dict(state[part])
        except (RuntimeError, KeyError, TypeError, ValueError, IndexError) as exc:
            fail(f"the {part}", exc)
    try:
        _set_rng_state(state["rng"])
    except (RuntimeError, KeyError, TypeError, ValueError, IndexError) as exc:
        fail("the random number generators", exc)
    if not all(isinstance(r, dict) for r in state["history"]):
        raise InputError(path, "resume state history is not a list of metric rows")


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
    """Train ``model`` on ``train_data``; validate on ``val_data`` after every epoch.

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
    if len(train_data) == 0:
        raise ConfigError("the training set is empty: nothing to train on")
    d = setup(cfg.device)
    out = Path(out_dir)
    if d.main:
        out.mkdir(parents=True, exist_ok=True)
    model.to(d.device)
    net = nn.parallel.DistributedDataParallel(model) if d.world > 1 else model
    optimizer, scheduler = make_optimizer(model, cfg)
    # One plan for every world size: each step takes the next world x batch x accumulate items of a
    # seeded shuffle and cuts them into micro-batches; rank r runs micro-batches r*A .. r*A+A-1. No
    # item is repeated or dropped (a DistributedSampler pads with repeats), so 2 x 8 sees the
    # batches 1 x 16 sees, for any dataset size.
    plan = StepPlan(len(train_data), cfg.batch_size, d.world, cfg.accumulate, cfg.seed)
    batches = RankBatches(plan, d.rank)
    loader = DataLoader(
        train_data, batch_sampler=batches, num_workers=cfg.num_workers, persistent_workers=cfg.num_workers > 0
    )
    info = {
        **(info or {}),
        "train": asdict(cfg),
        "world_size": d.world,
        "global_batch": d.world * cfg.batch_size * cfg.accumulate,
    }
    history: list[dict[str, Any]] = []
    best = -math.inf
    start_epoch = 0
    resume_path = out / "resume.pt"
    if resume_state is None and resume and resume_path.exists():
        resume_state = load_resume_state(resume_path)
    if resume_state is not None:
        state = resume_state
        restore_state(resume_path, state, model, optimizer, scheduler)
        history, best, start_epoch = [dict(r) for r in state["history"]], float(state["best"]), state["epoch"] + 1
        if d.main:
            print(f"resuming {out} after epoch {state['epoch'] + 1}/{cfg.epochs}")
    if d.main:
        write_text(
            out / "run.json",
            json.dumps({**info, "model": model.model_name, "model_config": model.config()}, indent=2, default=str),
        )
    t_run = time.perf_counter()
    dummy: list = []  # one real item, run with weight 0 by a rank whose micro-batch is empty
    for epoch in range(start_epoch, cfg.epochs):
        t0 = time.perf_counter()
        batches.set_epoch(epoch)
        net.train()
        sums = torch.zeros(3, dtype=torch.float64)  # loss * n, correct, n
        items = iter(loader)
        steps = plan.steps(epoch)
        if cfg.max_steps_per_epoch is not None:
            steps = steps[: cfg.max_steps_per_epoch]
        bar = progress_bar(steps, cfg.progress and d.main, f"epoch {epoch + 1}/{cfg.epochs}")
        for step, micro in enumerate(bar):
            n_global = sum(len(m) for m in micro)
            optimizer.zero_grad(set_to_none=True)
            mine = range(d.rank * cfg.accumulate, (d.rank + 1) * cfg.accumulate)
            for k, m in enumerate(mine):
                last = k == cfg.accumulate - 1
                sync = contextlib.nullcontext() if (last or d.world == 1) else net.no_sync()
                with sync, micro_batch_rng(cfg.seed, epoch, step, m, d.device):
                    if micro[m]:
                        x, y = next(items)
                        x, y = x.to(d.device, non_blocking=True), y.to(d.device, non_blocking=True)
                        logits = net(x)
                        total = F.cross_entropy(logits, y, reduction="sum")
                        # DDP averages over ranks: scaled so the step's gradient is the mean over
                        # the n_global items of the step, wherever they were computed.
                        (total * (d.world / n_global)).backward()
                        sums += torch.tensor(
                            [total.item(), (logits.argmax(-1) == y).sum().item(), len(y)], dtype=torch.float64
                        )
                    else:
                        # Every rank joins every gradient all-reduce; in eval mode (no dropout, no
                        # batch-norm update) and with weight 0, the item changes nothing.
                        if not dummy:
                            dummy.append(default_collate([train_data[0]]))
                        net.eval()
                        (net(dummy[0][0].to(d.device)).sum() * 0.0).backward()
                        net.train()
            optimizer.step()
            if bar is not steps and sums[2] > 0:
                bar.set_postfix(loss=f"{sums[0].item() / sums[2].item():.4f}")
        sums = all_sum(sums, d)
        row: dict[str, Any] = {
            "epoch": epoch + 1,
            "lr": optimizer.param_groups[0]["lr"],
            "train_loss": sums[0].item() / max(sums[2].item(), 1),
            "train_accuracy": sums[1].item() / max(sums[2].item(), 1),
            "train_items": int(sums[2].item()),
        }
        scheduler.step()
        if val_data is not None and len(val_data):
            p, y = predict(model, val_data, batch_size=max(cfg.batch_size, 32), device=d.device, d=d)
            m = metrics_from(p, y)
            row.update({f"val_{k}": m[k] for k in ("loss", "accuracy", "precision", "recall", "f1")})
        for name, extra in (extra_eval or {}).items():
            p, y = predict(model, extra, batch_size=max(cfg.batch_size, 32), device=d.device, d=d)
            m = metrics_from(p, y)
            row.update({f"{name}_{k}": m[k] for k in ("loss", "accuracy", "precision", "recall", "f1")})
        row["seconds"] = time.perf_counter() - t0
        history.append(row)
        score = (
            -row["val_loss"]
            if cfg.select_by == "loss" and "val_loss" in row
            else row.get(f"val_{cfg.select_by}", row["train_accuracy"])
        )
        improved = score > best
        best = max(best, score)
        if d.main:
            ck_info = {**info, "epoch": epoch + 1, "metrics": row}
            save_checkpoint(out / "last.safetensors", model, ck_info)
            if improved:
                save_checkpoint(out / "best.safetensors", model, ck_info)
            write_metrics_csv(out / "metrics.csv", history)
            save_resume_state(
                resume_path,
                {
                    "model": model.state_dict(),
                    "optimizer": optimizer.state_dict(),
                    "scheduler": scheduler.state_dict(),
                    "rng": _rng_state(),
                    "history": history,
                    "best": best,
                    "epoch": epoch,
                },
            )
            shown = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}
            print(json.dumps(shown), flush=True)
        if d.world > 1:
            dist.barrier()  # nobody races ahead of rank 0's checkpoint
    if d.main and history:
        from slipsense.plots import plot_curves

        plot_curves(history, out / "curves.png", title=f"{model.model_name}")
        summary = {"train_seconds": time.perf_counter() - t_run, "epochs": len(history), "final": history[-1]}
        write_text(out / "summary.json", json.dumps(summary, indent=2))
    return history


def write_metrics_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=keys)
    w.writeheader()
    w.writerows(rows)
    write_text(path, buf.getvalue())


# --------------------------------------------------------------------------- from a request to a run
@dataclass
class TrainRequest:
    """Everything ``slipsense train`` was asked: model, data, split and optimisation overrides."""

    model: str = "vivit"
    recordings: Path | None = None
    markers: Path | None = None
    out: Path = Path("runs/latest")
    preset: str | None = None
    model_overrides: dict[str, Any] = field(default_factory=dict)
    frames: int = 5
    horizon: int = 0
    size: tuple[int, int] | None = None
    wiggle_per_video: int = 2
    split: str = "objects"
    test_objects: list[str] = field(default_factory=list)
    fold: int | None = None
    folds: int = 5
    test_fraction: float = 0.1
    augment: bool = True
    seed: int = 0
    on_error: str = "raise"
    overrides: Path | None = None  # CSV of hand labels replacing automatic moments of slip
    sensor: str | None = None  # a registered sensor's name (its recordings layout); None: the GelSight Mini
    progress: bool = True
    train_overrides: dict[str, Any] = field(default_factory=dict)

    #: ``data`` keys of the configuration tree (:mod:`slipsense.run_config`)
    DATA_KEYS = (
        "recordings",
        "markers",
        "frames",
        "horizon",
        "size",
        "wiggle_per_video",
        "split",
        "test_objects",
        "fold",
        "folds",
        "test_fraction",
        "augment",
        "on_error",
        "overrides",
        "sensor",
    )

    @classmethod
    def from_tree(
        cls, tree: dict[str, dict[str, Any]], out: Path | str = Path("runs/latest"), progress: bool = True
    ) -> "TrainRequest":
        """A request from a configuration tree (``model``/``data``/``train`` sections); missing keys keep
        the defaults above, unknown keys are refused naming them."""
        from slipsense.run_config import check_keys

        train_keys = {f.name for f in fields(TrainConfig)} - {"progress"}
        check_keys(tree, {"data": cls.DATA_KEYS, "train": train_keys, "model": None})
        model = dict(tree.get("model") or {})
        data = dict(tree.get("data") or {})
        train = dict(tree.get("train") or {})
        from slipsense.config import resolve_path

        for key in ("recordings", "markers", "overrides"):
            if data.get(key) is not None:
                data[key] = resolve_path(data[key])  # "$SLIPSENSE_DATA/..." as checkpoints write it
        if data.get("size") is not None:
            size = data["size"]
            if not (isinstance(size, (list, tuple)) and len(size) == 2 and all(isinstance(v, int) for v in size)):
                raise ConfigError(f"data.size must be [height, width] in pixels, got {size!r}")
            data["size"] = (int(size[0]), int(size[1]))
        if isinstance(data.get("test_objects"), str):
            data["test_objects"] = [o for o in data["test_objects"].split(",") if o]
        optional = {f.name for f in fields(cls) if f.default is None}  # None is their default anyway
        data = {k: v for k, v in data.items() if v is not None or k in optional}
        seed = train.pop("seed", 0)
        return cls(
            model=model.pop("name", cls.model),
            preset=model.pop("preset", None),
            model_overrides=model,
            out=Path(out),
            progress=progress,
            seed=seed,
            train_overrides=train,
            **data,
        )

    def to_tree(self) -> dict[str, dict[str, Any]]:
        """The whole request as a configuration tree (what checkpoints store and ``config.yaml`` holds)."""
        from slipsense.config import portable_path
        from slipsense.run_config import to_plain

        data = {k: getattr(self, k) for k in self.DATA_KEYS}
        for key in ("recordings", "markers", "overrides"):
            if data[key] is not None:
                data[key] = portable_path(data[key])
        model = {"name": self.model, **({"preset": self.preset} if self.preset else {}), **self.model_overrides}
        return to_plain({"model": model, "data": data, "train": {**self.train_overrides, "seed": self.seed}})


def _store_operating_point(out: Path, split_info: dict[str, Any], req: "TrainRequest") -> None:
    """Choose the alarm operating point on the training objects' runs and write it into the run's
    checkpoints (:mod:`slipsense.training.operating_point`)."""
    from slipsense.checkpoint import read_info, update_info
    from slipsense.config import resolve_path
    from slipsense.recordings.folders import find_recordings
    from slipsense.sensors.spec import sensor_of
    from slipsense.training.operating_point import choose_on_training_runs

    import warnings

    from safetensors.torch import load_file

    from slipsense.errors import SlipsenseError

    root = resolve_path(split_info["recordings"])
    held = set(split_info.get("test_objects") or ())
    sensor = sensor_of(read_info(out / "last.safetensors"))
    objects = sorted({r.object for r in find_recordings(root, on_error="skip", sensor=sensor)} - held)
    chosen: list[tuple[dict, dict]] = []  # (weights, operating point): best often holds last's weights
    for name in ("last.safetensors", "best.safetensors"):
        path = out / name
        if not path.is_file():
            continue
        weights = load_file(str(path))
        op = next((o for w, o in chosen if w.keys() == weights.keys() and all(w[k].equal(weights[k]) for k in w)), None)
        if op is None:
            try:
                op = choose_on_training_runs(path, root, objects, req.overrides, req.progress)
            except SlipsenseError as exc:  # the training stands; the checkpoint alarms at 0.5 with a warning
                warnings.warn(f"{path}: no operating point chosen ({exc})", stacklevel=2)
                continue
            chosen.append((weights, op))
        update_info(path, {"operating_point": op})
        print(f"{name}: operating point threshold {op['threshold']:g}, debounce {op['debounce']} ({op['chosen_on']})")


def build_model(name: str, preset: str | None, overrides: dict[str, Any], data_config: dict[str, Any]):
    """Build a model: preset (if any) < data-implied sizes < explicit overrides."""
    from slipsense.models import build

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


def run_training(req: TrainRequest, resume: bool = False) -> dict[str, Any]:
    """Prepare data, build and train the model, then evaluate ``last.safetensors`` on the held-out
    part; returns the evaluation metrics (rank 0) or ``{}`` (other ranks)."""
    from slipsense.evaluation.evaluate import evaluate_model

    cls = model_class(req.model)
    kind = cls.input_kind
    accepted = settings_of(cls)
    unknown = sorted(set(req.model_overrides) - accepted)
    if unknown:  # before any data is decoded
        raise ConfigError(
            f"model {req.model!r} has no setting {', '.join(unknown)}; settings: {', '.join(sorted(accepted))}"
        )
    settings = {**paper_settings(req.model), "seed": req.seed, "progress": req.progress, **req.train_overrides}
    cfg = TrainConfig.from_dict(settings)
    train_data, test_data, split_info, data_config = prepare_data(req, kind)
    sensor = data_config.pop("sensor")
    seed_everything(req.seed)
    model = build_model(req.model, req.preset, req.model_overrides, data_config)
    out = Path(req.out)
    d = setup(cfg.device)
    state = None
    if resume and (out / "resume.pt").exists():
        # Everything a resume needs is read and checked before the first file is written, so a
        # refused resume leaves the run folder as it was.
        state = load_resume_state(out / "resume.pt")
        probe = copy.deepcopy(model)
        rng = _rng_state()
        try:
            restore_state(out / "resume.pt", state, probe, *make_optimizer(probe, cfg))
        finally:
            _set_rng_state(rng)
        del probe
        check_same_split(out / "split.json", split_info)
    if d.main:
        out.mkdir(parents=True, exist_ok=True)
        write_text(out / "split.json", json.dumps(split_info, indent=1))
    tree = req.to_tree()
    resolved = {k: v for k, v in asdict(cfg).items() if k != "progress"}
    tree["train"] = {**resolved, **tree["train"]}  # every optimisation setting, defaults included
    if d.main:
        from slipsense.run_config import dump_tree

        write_text(out / "config.yaml", dump_tree(tree))
    info = {
        "data": {k: v for k, v in split_info.items() if k != "test_indices"},
        "sensor": sensor,
        "preset": req.preset,
        "config": tree,
    }
    fit(model, train_data, test_data, cfg, out, info=info, resume=resume, resume_state=state)
    if d.main and cfg.operating_point and kind == "video" and split_info.get("split") in ("objects", "all"):
        _store_operating_point(out, split_info, req)
    if not d.main or len(test_data) == 0:
        return {}
    from slipsense.checkpoint import load_model

    # The held-out part is also the validation set that picked best.safetensors, so scoring that
    # checkpoint on it would be optimistic: the reported model is the last epoch's.
    final, _ = load_model(out / "last.safetensors")
    metrics = evaluate_model(
        final,
        test_data,
        out / "evaluation.json",
        out / "confusion.png",
        extra={
            "checkpoint": (out / "last.safetensors").as_posix(),
            "split": split_info.get("split"),
            "test_objects": split_info.get("test_objects"),
        },
        progress=req.progress,
    )
    print(json.dumps({k: metrics[k] for k in ("accuracy", "precision", "recall", "f1", "n_clips")}))
    return metrics
