"""Evaluation: a checkpoint against labelled data, to JSON and a confusion-matrix picture."""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
from torch import nn
from torch.utils.data import DataLoader, Dataset, Subset

from slipsense.atomic import write_text
from slipsense.checkpoint import load_model
from slipsense.config import portable_path
from slipsense.errors import ConfigError, InputError, SlipsenseError
from slipsense.evaluation.metrics import metrics_from
from slipsense.evaluation.replay import evaluate as evaluate_grasps
from slipsense.models import at_dtype
from slipsense.plots import plot_confusion
from slipsense.progress import progress_bar
from slipsense.training.distributed import Dist


@torch.inference_mode()
def predict(
    model: nn.Module, data: Dataset, batch_size: int = 32, device="cpu", d: Dist | None = None, progress: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Slip probabilities and labels for every item of ``data`` -> ``(p (N,), y (N,))``.

    Under DDP each rank predicts a strided share and the shares are gathered, so no item is
    counted twice (a DistributedSampler would pad).
    """
    d = d or Dist()
    idx = list(range(d.rank, len(data), d.world))
    loader = DataLoader(Subset(data, idx), batch_size=batch_size, shuffle=False)
    model.eval()
    probs, labels = [], []
    for x, y in progress_bar(loader, progress and d.main, "predict"):
        logits = model(x.to(device))
        probs.append(torch.softmax(logits.float(), dim=-1)[:, 1].cpu())
        labels.append(y)
    p = torch.cat(probs) if probs else torch.zeros(0)
    y = torch.cat(labels) if labels else torch.zeros(0, dtype=torch.long)
    if d.world > 1:
        gathered = [None] * d.world
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
    sources = [s for s in (recordings, split, markers) if s is not None]
    if len(sources) != 1:
        raise ConfigError("give exactly one of --recordings, --split-file or --markers")
    model, info = load_model(checkpoint)
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
        extra["per_grasp"] = _replayed(checkpoint, progress=progress, **found.replay)
    data = found.data
    if len(data) == 0:
        raise InputError(split or recordings or markers, "holds nothing to evaluate")
    with torch.inference_mode():
        return evaluate_model(model, data, json_out, png, extra=extra, progress=progress)


def _replayed(checkpoint, *, recordings, overrides, progress, objects, on_error="raise") -> dict[str, Any]:
    """Per-grasp outcomes of a clip model's replay (:func:`slipsense.evaluation.replay.evaluate`) with its
    operating point. Data the replay cannot take (runs of different camera counts) leaves the clip
    metrics standing: ``{"skipped": why}`` and a warning instead."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # trained-on objects / no threshold: stated in the result instead
            ev = evaluate_grasps(
                checkpoint,
                recordings,
                overrides=True if overrides is None else overrides,
                progress=progress,
                objects=objects,
                on_error=on_error,
            )
    except SlipsenseError as exc:
        warnings.warn(f"per-grasp replay left out ({exc}); the clip metrics stand", stacklevel=2)
        return {"skipped": str(exc)}
    return {
        **ev.summary(),
        "threshold": ev.threshold,
        "debounce": ev.debounce,
        "horizon": ev.horizon,
        "frame_rate": ev.frame_rates(),
    }


def evaluate_grasp_checkpoint(
    checkpoint,
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
) -> dict[str, Any]:
    """A grasp detector is judged per grasp (:func:`slipsense.evaluation.replay.evaluate`: every run of the
    recordings folder replayed from its first frame, both sensors, at the checkpoint's operating
    point); the JSON holds the summary and each run's outcome. Takes the arguments of
    :func:`evaluate_clip_checkpoint` (``on_error="skip"`` leaves out the runs of videos that cannot be
    read, each named in a warning); ``png``, ``noise_std`` and ``per_grasp`` are for clip models and
    not used."""
    if split is not None or markers is not None:
        raise InputError(
            split or markers,
            f"{checkpoint} holds a grasp detector (whole runs of both sensors): evaluate it on a "
            "recordings folder (--recordings; default: the shared recordings)",
        )
    if dtype != "float32":
        raise ConfigError(f"a grasp detector is evaluated in float32 (--dtype {dtype} is for clip and marker models)")
    ev = evaluate_grasps(
        checkpoint,
        recordings,
        overrides=True if overrides is None else overrides,
        progress=progress,
        on_error=on_error,
    )
    doc = {
        "checkpoint": portable_path(checkpoint),
        "recordings": None if recordings is None else portable_path(recordings),
        "threshold": ev.threshold,
        "debounce": ev.debounce,
        "horizon": ev.horizon,
        "frame_rate": ev.frame_rates(),
        "per_grasp": ev.summary(),
        "clips": ev.clips(),
        "grasp_measure": ev.grasp_measure(),
        "runs": [
            {
                "object": r.object,
                "experiment": r.experiment,
                "cameras": list(r.cameras),
                "moment_of_slip": r.moment_of_slip,
                **asdict(o),
            }
            for r, o in zip(ev.runs, ev.outcomes())
        ],
    }
    if json_out is not None:
        write_text(json_out, json.dumps(doc, indent=1, default=float))
    return doc
