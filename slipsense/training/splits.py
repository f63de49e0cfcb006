"""Train/test splits of a training request, and the ``split.json`` that records them.

Video clips are split by object (leave objects out: ``--fold`` k of ``--folds`` object folds, or
named ``--test-objects``), by clip (the ViViT paper's random 90/10) or not at all (``all``: a model
to ship); marker sequences by group, so windows of one sequence never land on both sides.
``split.json`` holds the held-out indices and everything needed to rebuild the same clips
(``slipsense evaluate --split-file``), and a resumed run must find the same split there.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from slipsense.errors import ConfigError, InputError


def prepare_data(req, reads: str):
    """Datasets and the split description for a :class:`~slipsense.training.clips.TrainRequest` ->
    ``(train, test, split_info, data_config)``; ``reads``: what the model reads (video clips of
    ``"frames"``, or ``"markers"`` sequences)."""
    from slipsense.datasets import ClipDataset, MarkerDataset

    if reads == "frames":
        from slipsense.config import gelsight_recordings
        from slipsense.data import gelsight_clips, spec_dict
        from slipsense.recordings.augment import AugmentConfig
        from slipsense.recordings.clips import ClipSpec, object_folds, split_by_clip, split_by_object

        if req.markers is not None:
            raise ConfigError(f"model {req.model!r} takes video clips: use --recordings, not --markers")
        root = Path(req.recordings) if req.recordings else gelsight_recordings()
        spec_kw = dict(frames=req.frames, horizon=req.horizon, wiggle_per_video=req.wiggle_per_video, seed=req.seed)
        if req.size is not None:
            spec_kw["size"] = req.size
        spec = ClipSpec(**spec_kw)
        from slipsense.sensors.spec import GELSIGHT_MINI, sensor_named

        sensor = sensor_named(req.sensor) if req.sensor else GELSIGHT_MINI
        clips, _ = gelsight_clips(
            root, spec, on_error=req.on_error, overrides=req.overrides, progress=req.progress, sensor=sensor
        )
        if req.split == "all":  # a model to ship: every clip trains, nothing is held out
            tr, te = np.arange(len(clips)), np.zeros(0, np.int64)
            test_objects = []
        elif req.split == "clips":
            tr, te = split_by_clip(clips, test_fraction=req.test_fraction, seed=req.seed)
            test_objects: list[str] = []
        elif req.split == "objects":
            objects = sorted(set(clips.objects))
            if req.test_objects:
                unknown = sorted(set(req.test_objects) - set(objects))
                if unknown:
                    raise ConfigError(f"--test-objects not in {root}: {unknown}")
                test_objects = sorted(req.test_objects)
            else:
                k = 0 if req.fold is None else req.fold
                if not 0 <= k < req.folds:
                    raise ConfigError(f"--fold must be in 0..{req.folds - 1}")
                test_objects = sorted(object_folds(objects, n_folds=req.folds, seed=req.seed)[k])
            tr, te = split_by_object(clips, test_objects)
            if len(tr) == 0:
                raise ConfigError(
                    f"every object of {root} is held out ({', '.join(test_objects)}): nothing is left to train on"
                )
        else:
            raise ConfigError(f"--split must be objects, clips or all, got {req.split!r}")
        size = tuple(clips.x.shape[2:4])
        from slipsense.config import portable_path

        split_info = {
            "kind": "video",
            "recordings": portable_path(root),
            "clip_spec": spec_dict(spec),
            "split": req.split,
            "test_objects": test_objects,
            "test_indices": [int(i) for i in te],
            "on_error": req.on_error,
            # "default": the shipped hand labels of the shared recordings (data.label_runs); older
            # split files say null for "none", and evaluation rebuilds their clips that way
            "overrides": portable_path(req.overrides) if req.overrides else "default",
        }
        train = ClipDataset(clips.subset(tr), AugmentConfig(enabled=req.augment), seed=req.seed)
        test = ClipDataset(clips.subset(te))
        return train, test, split_info, {"frames": req.frames, "image_size": size, "sensor": sensor.to_dict()}
    if reads == "markers":
        from slipsense.data import load_markers, split_groups

        if req.markers is None:
            raise ConfigError(f"model {req.model!r} takes marker sequences: give --markers FILE.npz")
        x, y, groups = load_markers(req.markers)
        n_groups = len(np.unique(groups))
        if n_groups < 2:
            raise InputError(
                req.markers,
                f"all {len(groups)} samples are in one group: a split that never cuts a "
                "group leaves nothing to train on (give groups with several values)",
            )
        tr, te = split_groups(groups, 0.2 if req.test_fraction == 0.1 else req.test_fraction, req.seed)
        from slipsense.config import portable_path

        train = MarkerDataset(x[tr], y[tr], copies=req.marker_copies if req.augment else 1, seed=req.seed)
        split_info = {
            "kind": "markers",
            "markers": portable_path(req.markers),
            "test_indices": [int(i) for i in te],
            "marker_copies": train.copies,  # as applied: 1 off a grid or without augment
        }
        layout = marker_file_layout(req.markers, x)
        if layout is not None:  # tracked in videos: a replay must take a camera's markers the same way
            split_info["clip_spec"] = {"marker_layout": layout}
        return (
            train,
            MarkerDataset(x[te], y[te]),
            split_info,
            {"frames": int(x.shape[1]), "markers": int(x.shape[2]), "sensor": _marker_sensor(req.markers, x, layout)},
        )
    raise ConfigError(f"model {req.model!r} reads {reads!r}: clips are cut from frames or markers only")


def marker_file_layout(path, x: np.ndarray) -> str | None:
    """How a marker file's markers were taken from videos (its ``marker_layout``, written by
    ``slipsense markers``: ``"7x9"``, ``"32"``; :func:`slipsense.sensors.markers.marker_layout`), or
    None for markers that were not tracked in videos (simulated, a user's own)."""
    from slipsense.errors import ConfigError
    from slipsense.sensors.markers import layout_name, marker_layout

    try:
        with np.load(path, allow_pickle=False) as z:
            if "marker_layout" not in z.files:
                return None
            value = z["marker_layout"]
        count, _ = marker_layout(value.item() if value.ndim == 0 else value.tolist())
    except (ValueError, ConfigError) as exc:
        raise InputError(path, f"marker_layout is unreadable ({exc})") from None
    if count != x.shape[2]:
        raise InputError(path, f"marker_layout {value.item()!r} holds {count} markers, x has {x.shape[2]}")
    return layout_name(value.item())


def _marker_sensor(path, x: np.ndarray, layout: str | None) -> dict[str, Any]:
    """The sensor of a marker file: the GelSight Mini for markers tracked in its videos (``layout``,
    :func:`marker_file_layout`), else its frame rate (the file's ``fps``, else the binocular
    sensor's) and marker count."""
    from dataclasses import replace

    from slipsense.sensors.spec import BINOCULAR_MARKERS

    if layout is not None:  # tracked in GelSight videos: their frame rate
        from slipsense.sensors.spec import GELSIGHT_MINI

        return replace(GELSIGHT_MINI, output="markers", markers=int(x.shape[2])).to_dict()
    fps = BINOCULAR_MARKERS.fps
    with np.load(path, allow_pickle=False) as z:
        if "fps" in z.files and np.ndim(z["fps"]) == 0 and 0 < float(z["fps"]) <= 10_000:
            fps = float(z["fps"])
    return replace(BINOCULAR_MARKERS, name="markers", fps=fps, markers=int(x.shape[2])).to_dict()


#: split.json entries that must not change when a run is resumed.
SPLIT_IDENTITY = ("kind", "split", "test_objects", "test_indices", "clip_spec", "overrides", "marker_copies")
#: what a split file written before a key existed meant by its absence
SPLIT_DEFAULTS = {"marker_copies": 1}


def check_same_split(path: Path, split_info: dict[str, Any]) -> None:
    """Refuse to resume a run whose ``split.json`` describes another split than ``split_info``."""
    if not path.is_file():
        return
    try:
        old = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(path, f"cannot be read to check the resumed run's split ({exc})") from None
    if not isinstance(old, dict):
        raise InputError(path, "is not a split description (a JSON object)")
    # compared as JSON reads them back: a clip size (48, 64) is written as the list [48, 64]
    now = json.loads(json.dumps(split_info, default=str))
    changed = [
        k
        for k in SPLIT_IDENTITY
        if (k in old or k in now) and old.get(k, SPLIT_DEFAULTS.get(k)) != now.get(k, SPLIT_DEFAULTS.get(k))
    ]
    if changed:
        raise InputError(
            path,
            f"the run was started with another data split ({', '.join(changed)} differ); "
            "resume with the same data and split options, or use a new --out",
        )
