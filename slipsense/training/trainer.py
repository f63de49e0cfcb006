"""One training loop for every model, single-process or under ``torchrun`` (DDP).

The loop never asks what kind of data it trains on: a task (:class:`~slipsense.training.clips.ClipTask`
for clips and marker sequences, :class:`~slipsense.training.grasps.GraspTask` for whole grasps)
supplies the optimizer, each epoch's plan of steps, the loaded micro-batches, their loss and the
validation metrics. Every task gets from the loop:

* DDP (gloo on CPU, NCCL on GPU): a step is ``world x accumulate`` micro-batches, micro-batch ``m``
  runs on rank ``m // accumulate``; each micro-batch's loss is scaled by its share of the step's
  loss weight, so the all-reduced gradient is the step's, whoever computed which part. A rank whose
  micro-batch is empty (the short last step) runs a weight-0 filler so it joins every all-reduce.
* seeds: a step cut into several micro-batches runs each under
  :func:`~slipsense.training.distributed.micro_batch_rng`; otherwise torch's generator runs on.
* resume: after every epoch the whole state (weights, optimizer, schedule, every random generator,
  the task's own state, metrics, best score) is written atomically (safetensors + JSON); a training
  started again from it ends with the weights of an uninterrupted one, bit for bit.
* ``last.safetensors`` / ``best.safetensors`` (weights + everything in ``info``), ``metrics.csv``,
  ``curves.png``, ``run.json``, ``summary.json`` in ``out``; a progress bar per epoch; the heap handed
  back to the OS after every epoch.
"""

from __future__ import annotations

import contextlib
import csv
import ctypes
import io
import json
import math
import random
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
import torch
import torch.distributed as dist
import torch.nn as nn

from slipsense.atomic import write_text
from slipsense.checkpoint import load_resume_state, save_checkpoint, save_resume_state
from slipsense.errors import InputError
from slipsense.progress import progress_bar
from slipsense.training.distributed import Dist, all_sum, micro_batch_rng, setup


@dataclass
class Step:
    """One optimizer step: its ``world x accumulate`` micro-batches as the task describes them (an
    empty one: None or empty) and the step's total loss weight (items, or weighted frames)."""

    micro: list
    weight: float


class Task:
    """What the loop asks of a kind of training data (a task subclasses it; the defaults here are a
    task's without validation, extra columns or state of its own)."""

    def trainable(self, model: nn.Module) -> nn.Module:
        """The module whose forward the loss calls (wrapped in DDP under torchrun)."""
        return model

    def optimizer(self, model: nn.Module) -> tuple[Any, Any]:
        """``(optimizer, scheduler)``; the scheduler steps once per epoch."""

    def plan(self, model: nn.Module, epoch: int, d: Dist, accumulate: int) -> list[Step]:
        """Epoch ``epoch``'s steps, the same on every rank."""

    def batches(self, steps: list[Step], epoch: int, d: Dist, accumulate: int) -> Iterator[Any]:
        """This rank's non-empty micro-batches of ``steps``, loaded, in order."""

    def loss(self, net: nn.Module, batch: Any, step_weight: float, world: int) -> tuple[torch.Tensor, torch.Tensor]:
        """``(loss to backpropagate, float64 [weighted loss sum, its weight, correct, counted])`` of one
        micro-batch; the loss already scaled by the micro-batch's share of ``step_weight`` times ``world``."""

    def filler_loss(self, net: nn.Module) -> torch.Tensor:
        """A loss over one real item (run in eval mode, multiplied by 0) for an empty micro-batch."""

    def epoch_stats(self) -> dict[str, Any]:
        """Extra columns of the epoch's metrics row (after :meth:`plan`)."""
        return {}

    def validate(self, model: nn.Module, d: Dist) -> dict[str, float]:
        """Validation metrics after an epoch (``val_<metric>`` and others), or ``{}``."""
        return {}

    def identity(self) -> str | None:
        """What a resume state must have been written for (settings, data), or None."""

    def state(self) -> dict[str, Any]:
        """The task's own state for a resume (its generators, what it mined)."""
        return {}

    def restore(self, state: dict[str, Any]) -> None:
        """Take back what :meth:`state` gave."""


@dataclass
class LoopSettings:
    """What the loop itself needs of a task's configuration."""

    epochs: int
    seed: int = 0
    accumulate: int = 1
    device: str = "auto"
    progress: bool = True
    max_steps_per_epoch: int | None = None
    select_by: str = "accuracy"  # validation metric (else training accuracy) that picks best.safetensors
    desc: str = ""


def train(
    model: nn.Module,
    task: Task,
    s: LoopSettings,
    out: str | Path | None = None,
    info: dict[str, Any] | None = None,
    state_path: str | Path | None = None,
    resume_state: dict[str, Any] | None = None,
    on_epoch: Callable[[dict[str, Any]], None] | None = None,
    resume: bool = True,
) -> list[dict[str, Any]]:
    """Train ``model`` (built and seeded by the caller) on ``task``; returns the per-epoch metric rows.

    ``out``: where checkpoints, metrics and curves go (rank 0; None: nowhere). ``state_path``: the
    resume state, written after every epoch and continued from when it exists and ``resume`` (or
    ``resume_state``, already read and checked by the caller); with ``resume=False`` a state there is
    never read, and the first epoch overwrites it."""
    d = setup(s.device)
    out = None if out is None else Path(out)
    if out is not None and d.main:
        out.mkdir(parents=True, exist_ok=True)
    model.to(d.device)
    module = task.trainable(model)
    net = nn.parallel.DistributedDataParallel(module) if d.world > 1 else module
    optimizer, scheduler = task.optimizer(model)
    info = {**(info or {}), "world_size": d.world, "accumulate": s.accumulate}
    history: list[dict[str, Any]] = []
    best, start = -math.inf, 0
    if resume_state is None and resume and state_path is not None and Path(state_path).is_file():
        resume_state = load_resume_state(state_path)
    if resume_state is not None:
        start, history, best = restore(state_path, resume_state, model, optimizer, scheduler, task)
        if d.main and s.progress:
            print(f"resuming {out or state_path} after epoch {start}/{s.epochs}")
    if out is not None and d.main:
        run = {**info, "model": model.model_name, "model_config": model.config()}
        write_text(out / "run.json", json.dumps(run, indent=2, default=str))
    t_run = time.perf_counter()
    split = d.world * s.accumulate > 1
    for epoch in range(start, s.epochs):
        t0 = time.perf_counter()
        _sync_buffers(model, d)
        steps = task.plan(model, epoch, d, s.accumulate)[: s.max_steps_per_epoch]  # None: every step
        net.train()
        sums = torch.zeros(4, dtype=torch.float64)  # weighted loss sum, its weight, correct, counted
        batches = task.batches(steps, epoch, d, s.accumulate)
        bar = progress_bar(steps, s.progress and d.main, f"{s.desc} epoch {epoch + 1}/{s.epochs}".strip())
        for k, step in enumerate(bar):
            if step.weight <= 0:
                continue  # nothing scored anywhere in this step: no update at all
            optimizer.zero_grad(set_to_none=True)
            for j in range(s.accumulate):
                m = d.rank * s.accumulate + j
                sync = net.no_sync() if d.world > 1 and j < s.accumulate - 1 else contextlib.nullcontext()
                seeded = micro_batch_rng(s.seed, epoch, k, m, d.device) if split else contextlib.nullcontext()
                with sync, seeded:
                    if step.micro[m]:  # an empty micro-batch: None or empty
                        loss, stats = task.loss(net, next(batches), step.weight, d.world)
                        loss.backward()
                        sums += stats
                    else:  # eval mode (no dropout, no batch-norm update) and weight 0: changes nothing
                        net.eval()
                        (task.filler_loss(net) * 0.0).backward()
                        net.train()
            optimizer.step()
            if bar is not steps and sums[1] > 0:
                bar.set_postfix(loss=f"{sums[0].item() / sums[1].item():.4f}")
        sums = all_sum(sums, d)
        row: dict[str, Any] = {
            "epoch": epoch + 1,
            "lr": optimizer.param_groups[0]["lr"],
            "train_loss": sums[0].item() / sums[1].item() if sums[1] > 0 else math.nan,
            "train_accuracy": sums[2].item() / max(sums[3].item(), 1),
            "train_items": int(sums[3].item()),
            **task.epoch_stats(),
        }
        scheduler.step()
        row.update(task.validate(model, d))
        _trim_heap()
        row["seconds"] = time.perf_counter() - t0
        history.append(row)
        score = row.get(f"val_{s.select_by}", row["train_accuracy"])
        if s.select_by == "loss" and "val_loss" in row:
            score = -row["val_loss"]  # lower is better
        improved = score > best
        best = max(best, score)
        if d.main:
            if out is not None:
                card = {**info, "epoch": epoch + 1, "metrics": row}
                save_checkpoint(out / "last.safetensors", model, card)
                if improved:
                    save_checkpoint(out / "best.safetensors", model, card)
                write_metrics_csv(out / "metrics.csv", history)
            if state_path is not None:  # everything a resume needs
                state = {"identity": task.identity() or "", "epoch": epoch + 1}
                objects = {"model": model, "optimizer": optimizer, "scheduler": scheduler}
                state.update({k: o.state_dict() for k, o in objects.items()}, rng=rng_state(), task=task.state())
                save_resume_state(state_path, {**state, "history": history, "best": best})
            if s.progress:
                print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}), flush=True)
        if on_epoch is not None:
            on_epoch(row)
        if d.world > 1:
            dist.barrier()  # nobody races ahead of rank 0's files
    _sync_buffers(model, d)
    if out is not None and d.main and history:
        from slipsense.plots import plot_curves

        plot_curves(history, out / "curves.png", title=model.model_name)
        summary = {"train_seconds": time.perf_counter() - t_run, "epochs": len(history), "final": history[-1]}
        write_text(out / "summary.json", json.dumps(summary, indent=2))
    return history


def _sync_buffers(model: nn.Module, d: Dist) -> None:
    """Every rank takes rank 0's buffers (batch-norm running statistics): DDP broadcasts them at each
    forward, so after a step the other ranks' are stale; a task planning from the model (mining hard
    negatives) and the trained model itself must be the same on every rank."""
    if d.world > 1:
        for b in model.buffers():
            dist.broadcast(b, 0)


def rng_state() -> dict[str, Any]:
    """Python's, numpy's and torch's global generators (and every CUDA device's, where there are any)."""
    state = {"python": random.getstate(), "numpy": np.random.get_state(), "torch": torch.get_rng_state()}
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(s: dict[str, Any]) -> None:
    py = s["python"]
    # random.setstate wants (version, tuple of 625 ints, gauss); a list would be refused
    random.setstate((py[0], tuple(py[1]), py[2]))
    np.random.set_state(tuple(s["numpy"]))
    torch.set_rng_state(s["torch"])
    if s.get("cuda") and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(list(s["cuda"]))


def restore(path, state: dict[str, Any], model, optimizer=None, scheduler=None, task=None):
    """Load a resume state into the training's objects; ``(epochs done, history, best score)``.
    InputError naming ``path`` when it was written for another training or does not fit."""

    def fail(what: str, exc: BaseException):
        raise InputError(path, f"resume state does not fit {what} ({' '.join(str(exc).split())[:200]})") from None

    if task is not None and state.get("identity", "") != (task.identity() or ""):
        raise InputError(path, "resume state of another training (settings or data differ); use a new --out")
    unfit = (RuntimeError, KeyError, TypeError, ValueError, IndexError)
    for part, obj in (("model", model), ("optimizer", optimizer), ("scheduler", scheduler)):
        if obj is not None:
            try:
                obj.load_state_dict(state[part])
            except unfit as exc:
                fail(f"the {part}", exc)
    try:
        set_rng_state(state["rng"])
        if task is not None:
            task.restore(state.get("task") or {})
    except unfit as exc:
        fail("the random number generators", exc)
    if not all(isinstance(r, dict) for r in state["history"]):
        raise InputError(path, "resume state history is not a list of metric rows")
    return int(state["epoch"]), [dict(r) for r in state["history"]], float(state["best"])


def write_metrics_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(dict.fromkeys(k for r in rows for k in r)))  # columns as first seen
    w.writeheader()
    w.writerows(rows)
    write_text(path, buf.getvalue())


def _trim_heap() -> None:
    """Hand freed heap memory back to the OS (glibc only; elsewhere nothing). Steps allocate tensors
    of changing sizes (a grasp batch's distinct frames), which fragments the heap: without this a
    grasp training grew by ~200 MB per epoch, to about 3 GB; trimmed after every epoch it peaks near
    1.3 GB, at no cost in speed."""
    with contextlib.suppress(OSError, AttributeError, TypeError):  # a C library without malloc_trim
        ctypes.CDLL(None).malloc_trim(0)  # the C library this process runs on
