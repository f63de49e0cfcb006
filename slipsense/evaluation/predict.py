"""Clip and marker models judged per clip: predictions over a data set, their metrics to JSON and a
confusion-matrix picture, and the runs replayed per grasp where the model reads video."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
from torch import nn
from torch.utils.data import DataLoader, Dataset, Subset

from slipsense.atomic import write_text
from slipsense.paths import portable_path
from slipsense.errors import ConfigError, InputError, SlipsenseError
from slipsense.evaluation.judge import judge
from slipsense.measures.clips import metrics_from
from slipsense.models import at_dtype
from slipsense.plots import plot_confusion
from slipsense.progress import progress_bar


@torch.inference_mode()
def predict(
    model: nn.Module, data: Dataset, batch_size: int = 32, device="cpu", d=None, progress: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Slip probabilities and labels for every item of ``data`` -> ``(p (N,), y (N,))``.

    Under DDP each rank predicts a strided share and the shares are gathered, so no item is
    counted twice (a DistributedSampler would pad).
    """
    rank, world, main = (d.rank, d.world, d.main) if d is not None else (0, 1, True)  # a training.distributed.Dist
    idx = list(range(rank, len(data), world))
    loader = DataLoader(Subset(data, idx), batch_size=batch_size, shuffle=False)
    model.eval()
    probs, labels = [], []
    for x, y in progress_bar(loader, progress and main, "predict"):
        logits = model(x.to(device))
        probs.append(torch.softmax(logits.float(), dim=-1)[:, 1].cpu())
        labels.append(y)
    p = torch.cat(probs) if probs else torch.zeros(0)
    y = torch.cat(labels) if labels else torch.zeros(0, dtype=torch.long)
    if world > 1:
        gathered = [None] * world
        dist.all_gather_object(gathered, (idx, p.numpy(), y.numpy()))
        order = np.concatenate([g[0] for g in gathered]).astype(np.int64)
        p_all = np.empty(len(data), np.float32)
        y_all = np.empty(len(data), np.int64)
        p_all[order] = np.concatenate([g[1] for g in gathered])
        y_all[order] = np.concatenate([g[2] for g in gathered])
        return p_all, y_all
    return p.numpy(), y.numpy()


def evaluate_model(
    model,
    data,
    json_out: str | Path | None = None,
    png: str | Path | None = None,
    extra: dict[str, Any] | None = None,
    batch_size: int = 32,
    progress: bool = False,
) -> dict[str, Any]:
    """Metrics of ``model`` on a Dataset of ``(x, y)``: accuracy, precision, recall, F1, counts,
    confusion matrix; optionally written to ``json_out`` and drawn to ``png``."""
    if len(data) == 0:
        raise InputError(None, "nothing to evaluate: the data set is empty")
    p, y = predict(model, data, batch_size=batch_size, progress=progress)
    m = {**metrics_from(p, y), **(extra or {})}
    if json_out is not None:
        write_text(json_out, json.dumps(m, indent=2, default=str))
        png = png or Path(json_out).with_suffix(".png")
    if png is not None:
        plot_confusion(m["confusion"], png, title=f"acc {m['accuracy']:.3f}  F1 {m['f1']:.3f}  n={m['n_clips']}")
    return m


def evaluate_clip_checkpoint(
    checkpoint: str | Path,
    loaded: tuple[Any, dict[str, Any]],
    recordings=None,
    split=None,
    markers=None,
    json_out=None,
    png=None,
    noise_std: float = 0.0,
    on_error: str = "raise",
    overrides=None,
    progress: bool = True,
    dtype: str = "float32",
    per_grasp: bool = True,
    sensor=None,
) -> dict[str, Any]:
    """Score a clip or marker model's checkpoint per clip on one data source (the data it reads:
    ``model.clip_reader``, :mod:`slipsense.readers`).

    Exactly one of ``recordings`` (every clip of that folder: zero-shot on unseen objects),
    ``split`` (a run's ``split.json``: its held-out part) or ``markers`` (an ``.npz``) is given.
    Clips are made with the clip settings stored in the checkpoint. ``dtype`` ("float32",
    "bfloat16", "int8"; see :func:`slipsense.models.at_dtype`) scores a reduced-precision
    inference copy of the model instead, to compare its F1 with float32's.

    A video clip model is also judged per grasp with ``per_grasp``: the same runs (every run of ``recordings``, or the
    held-out objects' runs of a split by objects) replayed through it as the live detector runs it,
    at the checkpoint's operating point (``"per_grasp"`` in the result).
    """
    if not isinstance(noise_std, (int, float)) or not math.isfinite(noise_std) or noise_std < 0:
        raise ConfigError(f"--noise-std must be a finite number >= 0, got {noise_std!r}")
    if sensor is not None:  # clips are cut at the checkpoint's own size and carry no time
        raise ConfigError("--sensor is for grasp detectors, which replay whole runs at the recordings' rate")
    sources = [s for s in (recordings, split, markers) if s is not None]
    if len(sources) != 1:
        raise ConfigError("give exactly one of --recordings, --split-file or --markers")
    model, info = loaded
    model = at_dtype(model.eval(), dtype)
    found = model.clip_reader.evaluation_data(
        checkpoint,
        model,
        info,
        recordings=recordings,
        split=split,
        markers=markers,
        noise_std=noise_std,
        on_error=on_error,
        overrides=overrides,
        progress=progress,
    )
    extra: dict[str, Any] = {
        "checkpoint": portable_path(checkpoint),
        "model": info["model"],
        "noise_std": noise_std,
        "inference_dtype": dtype,
        **found.extra,
    }
    if found.replay is not None and per_grasp and dtype == "float32":
        extra["per_grasp"] = _replayed(checkpoint, loaded, progress=progress, **found.replay)
    data = found.data
    if len(data) == 0:
        raise InputError(split or recordings or markers, "holds nothing to evaluate")
    with torch.inference_mode():
        return evaluate_model(model, data, json_out, png, extra=extra, progress=progress)


def _replayed(checkpoint, loaded, *, recordings, overrides, progress, objects, on_error="raise") -> dict[str, Any]:
    """Per-grasp outcomes of a clip model's replay (:func:`slipsense.evaluation.judge.judge`) with its
    operating point. Data the replay cannot take (runs of different camera counts) leaves the clip
    metrics standing: ``{"skipped": why}`` and a warning instead."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # trained-on objects / no threshold: stated in the result instead
            ev = judge(
                checkpoint,
                recordings,
                overrides=overrides,
                progress=progress,
                objects=objects,
                on_error=on_error,
                loaded=loaded,
            )
    except SlipsenseError as exc:
        warnings.warn(f"per-grasp replay left out ({exc}); the clip metrics stand", stacklevel=2)
        return {"skipped": str(exc)}
    return {
        **ev.per_grasp(),
        "threshold": ev.threshold,
        "debounce": ev.debounce,
        "horizon": ev.horizon,
        "frame_rate": ev.frame_rates(),
    }
