"""Evaluation: a checkpoint against labelled data, to JSON and a confusion-matrix picture."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
from torch import nn
from torch.utils.data import DataLoader, Dataset, Subset

from slipsense.atomic import write_text
from slipsense.progress import progress_bar
from slipsense.training.distributed import Dist
from slipsense.errors import ConfigError, InputError


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
    from slipsense.plots import plot_confusion
    from slipsense.evaluation.metrics import metrics_from

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


def evaluate_checkpoint(
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
    """Run the whole pipeline a checkpoint needs on one data source and score it.

    Exactly one of ``recordings`` (every clip of that folder: zero-shot on unseen objects),
    ``split`` (a run's ``split.json``: its held-out part) or ``markers`` (an ``.npz``) is given.
    Clips are made with the clip settings stored in the checkpoint. ``dtype`` ("float32",
    "bfloat16", "int8"; see :func:`slipsense.models.at_dtype`) scores a reduced-precision
    inference copy of the model instead, to compare its F1 with float32's.

    A grasp detector is judged per grasp (and per clip on the same traces); a video clip model per
    clip and, with ``per_grasp``, also per grasp: the same runs (every run of ``recordings``, or the
    held-out objects' runs of a split by objects) replayed through it as the live detector runs it,
    at the checkpoint's operating point (``"per_grasp"`` in the result).
    """
    from slipsense.models import at_dtype

    from slipsense.checkpoint import load_model
    from slipsense.config import resolve_path
    from slipsense.data import clip_spec_from, gelsight_clips, load_markers
    from slipsense.datasets import ClipDataset, MarkerDataset

    import math

    if not isinstance(noise_std, (int, float)) or not math.isfinite(noise_std) or noise_std < 0:
        raise ConfigError(f"--noise-std must be a finite number >= 0, got {noise_std!r}")
    model, info = load_model(checkpoint)
    if model.training_task == "grasps":  # trained and judged on whole runs
        return _evaluate_grasps(checkpoint, recordings, split, markers, json_out, overrides, progress, dtype)
    sources = [s for s in (recordings, split, markers) if s is not None]
    if len(sources) != 1:
        raise ConfigError("give exactly one of --recordings, --split-file or --markers")
    model = at_dtype(model.eval(), dtype)
    from slipsense.config import portable_path

    extra: dict[str, Any] = {
        "checkpoint": portable_path(checkpoint),
        "model": info["model"],
        "noise_std": noise_std,
        "inference_dtype": dtype,
    }
    if model.reads == "frames":
        if markers is not None:
            raise InputError(checkpoint, "this checkpoint holds a video model; use --recordings or --split-file")
        from slipsense.sensors.spec import sensor_of

        data_info = info.get("data", {})
        sensor = sensor_of(info, checkpoint)  # the recordings layout of the sensor it was trained on
        if split is not None:
            split_info = _read_split(split, "video")
            try:
                spec = clip_spec_from(split_info)
            except ConfigError as exc:
                raise InputError(split, str(exc)) from None
            clips, _ = gelsight_clips(
                resolve_path(split_info["recordings"]),
                spec,
                on_error=split_info.get("on_error") or on_error,
                overrides=_split_overrides(split_info.get("overrides")),
                progress=progress,
                sensor=sensor,
            )
            idx = split_info["test_indices"]
            if max(idx) >= len(clips):
                raise InputError(
                    split,
                    f"test index {max(idx)} is out of range: the clips rebuilt from its recordings are {len(clips)}",
                )
            clips = clips.subset(idx)
            extra.update(split=portable_path(split), test_objects=split_info.get("test_objects"))
            if per_grasp and dtype == "float32" and split_info.get("split") == "objects":
                extra["per_grasp"] = _replayed(
                    checkpoint,
                    resolve_path(split_info["recordings"]),
                    _split_overrides(split_info.get("overrides")),
                    progress,
                    split_info.get("test_objects"),
                    split_info.get("on_error") or on_error,
                )
        else:
            if "clip_spec" not in data_info:
                raise InputError(checkpoint, "checkpoint has no clip settings (data.clip_spec)")
            clips, _ = gelsight_clips(
                recordings,
                clip_spec_from(data_info),
                on_error=on_error,
                overrides=overrides,
                progress=progress,
                sensor=sensor,
            )
            extra.update(recordings=portable_path(recordings), objects=sorted(set(clips.objects)))
            if per_grasp and dtype == "float32":
                extra["per_grasp"] = _replayed(checkpoint, recordings, overrides, progress, None, on_error)
        data = ClipDataset(clips, noise_std=noise_std, seed=0)
    else:
        if recordings is not None:
            raise InputError(checkpoint, "this checkpoint holds a marker model; use --markers or --split-file")
        if split is not None:
            split_info = _read_split(split, "markers")
            x, y, _ = load_markers(resolve_path(split_info["markers"]))
            _check_marker_layout(resolve_path(split_info["markers"]), x, model, info, checkpoint)
            idx = split_info["test_indices"]
            if max(idx) >= len(y):
                raise InputError(
                    split, f"test index {max(idx)} is out of range: {split_info['markers']} holds {len(y)} samples"
                )
            x, y = x[idx], y[idx]
        else:
            x, y, _ = load_markers(markers)
            _check_marker_layout(markers, x, model, info, checkpoint)
            extra["markers"] = portable_path(markers)
        data = MarkerDataset(x, y)
    if len(data) == 0:
        raise InputError(split or recordings or markers, "holds nothing to evaluate")
    import torch

    with torch.inference_mode():
        return evaluate_model(model, data, json_out, png, extra=extra, progress=progress)


def _check_marker_layout(path, x, model, info, checkpoint) -> None:
    """Refuse markers taken from videos otherwise than the checkpoint's (``marker_layout``: a 7 x 9
    grid of every marker is not the 63 markers nearest the centre, though both hold 63)."""
    from slipsense.models.base import window_geometry
    from slipsense.training.splits import marker_file_layout

    trained = window_geometry(model, info).get("marker_layout")
    given = marker_file_layout(path, x)
    if given != trained:

        def said(layout):
            return f"markers taken from videos as {layout!r}" if layout else "markers not tracked in videos"

        raise InputError(path, f"holds {said(given)}; {checkpoint} was trained on {said(trained)}")


def _replayed(checkpoint, recordings, overrides, progress, objects, on_error="raise") -> dict[str, Any]:
    """Per-grasp outcomes of a clip model's replay (:func:`slipsense.evaluation.replay.evaluate`) with its
    operating point. Data the replay cannot take (runs of different camera counts) leaves the clip
    metrics standing: ``{"skipped": why}`` and a warning instead."""
    import warnings

    from slipsense.evaluation.replay import evaluate as evaluate_grasps
    from slipsense.errors import SlipsenseError

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
    return {**ev.summary(), "threshold": ev.threshold, "debounce": ev.debounce, "horizon": ev.horizon}


def _evaluate_grasps(checkpoint, recordings, split, markers, json_out, overrides, progress, dtype) -> dict[str, Any]:
    """A grasp detector is judged per grasp (:func:`slipsense.evaluation.replay.evaluate`: every run of the
    recordings folder replayed from its first frame, both sensors, at the checkpoint's operating
    point); the JSON holds the summary and each run's outcome."""
    from dataclasses import asdict

    from slipsense.evaluation.replay import evaluate as evaluate_grasps
    from slipsense.config import portable_path

    if split is not None or markers is not None:
        raise InputError(
            split or markers,
            f"{checkpoint} holds a grasp detector (whole runs of both sensors): evaluate it on a "
            "recordings folder (--recordings; default: the shared recordings)",
        )
    if dtype != "float32":
        raise ConfigError(f"a grasp detector is evaluated in float32 (--dtype {dtype} is for clip and marker models)")
    ev = evaluate_grasps(checkpoint, recordings, overrides=True if overrides is None else overrides, progress=progress)
    doc = {
        "checkpoint": portable_path(checkpoint),
        "recordings": None if recordings is None else portable_path(recordings),
        "threshold": ev.threshold,
        "debounce": ev.debounce,
        "horizon": ev.horizon,
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
        from slipsense import atomic

        atomic.write_text(json_out, json.dumps(doc, indent=1, default=float))
    return doc


#: Keys a split file (a run's ``split.json``) needs, by data kind.
SPLIT_KEYS = {"video": ("recordings", "clip_spec", "test_indices"), "markers": ("markers", "test_indices")}


def _read_split(path, kind: str | None = None) -> dict[str, Any]:
    """A run's ``split.json``, checked: InputError naming the file for anything a split cannot be.

    ``kind`` ("video" or "markers") is the kind of data the model's clips are; a split of the other kind, missing
    keys, and test indices that are not a non-empty list of distinct integers >= 0 are refused
    (indices beyond the data are checked once the data is loaded).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "split file not found")
    try:
        info = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(path, f"not a JSON split file ({exc})") from None
    except OSError as exc:
        raise InputError(path, f"split file cannot be read ({exc.strerror or exc})") from None
    if not isinstance(info, dict):
        raise InputError(path, f"a split file is a JSON object, got a {type(info).__name__}")
    split_kind = info.get("kind", "markers" if "markers" in info else "video")
    if split_kind not in SPLIT_KEYS:
        raise InputError(path, f"kind must be 'video' or 'markers', got {split_kind!r}")
    if kind is not None and split_kind != kind:
        raise InputError(path, f"this split is of {split_kind} data but the checkpoint holds a {kind} model")
    missing = [k for k in SPLIT_KEYS[split_kind] if k not in info]
    if missing:
        raise InputError(path, f"split file lacks {', '.join(missing)}")
    for key in ("recordings", "markers", "overrides", "on_error"):
        if key in info and info[key] is not None and not isinstance(info[key], str):
            raise InputError(path, f"{key} must be a string, got {type(info[key]).__name__}")
    if info.get("on_error") not in (None, "raise", "skip"):
        raise InputError(path, f"on_error must be 'raise' or 'skip', got {info['on_error']!r}")
    idx = info["test_indices"]
    if not isinstance(idx, list) or not all(isinstance(i, int) and not isinstance(i, bool) for i in idx):
        raise InputError(path, "test_indices must be a list of integers")
    if not idx:
        raise InputError(
            path,
            "the split holds no test items (test_indices is empty; a run trained with "
            "--split all has no held-out part): nothing to evaluate",
        )
    if min(idx) < 0:
        raise InputError(path, f"test_indices holds a negative index ({min(idx)})")
    if len(set(idx)) != len(idx):
        raise InputError(path, "test_indices repeats an index")
    return info


def _split_overrides(stored):
    """The hand labels a split file's clips were cut with: ``"default"`` -> the shipped ones of the
    shared recordings (None for data.label_runs), null (split files written before that default) ->
    none (False), else the CSV's path."""
    from slipsense.config import resolve_path

    if stored == "default":
        return None
    return False if stored is None else resolve_path(stored)
