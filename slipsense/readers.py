"""What a clip model reads, handed out by the model itself (``SlipModel.clip_reader``), so that training
and evaluation never ask which kind of model they hold.

* :data:`VIDEO_CLIPS`: a GelSight recordings folder (``<object>/exp_num_<N>/camera_*.avi``) ->
  labelled clips, split by object (leave objects out: ``--fold`` k of ``--folds`` object folds, or
  named ``--test-objects``), by clip (the ViViT paper's random 90/10) or not at all (``all``: a model
  to ship);
* :data:`MARKER_CLIPS`: an ``.npz`` of marker-cloud sequences, split by group, so windows of one
  sequence never land on both sides.

Training writes the split to ``split.json``: the held-out indices and everything needed to rebuild the
same clips (``slipsense evaluate --split-file``); a resumed run must find the same split there.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from slipsense.paths import gelsight_recordings, portable_path, resolve_path
from slipsense.data import clip_spec_from, gelsight_clips, load_markers, split_groups
from slipsense.datasets import ClipDataset, MarkerDataset
from slipsense.errors import ConfigError, InputError
from slipsense.recordings.augment import AugmentConfig
from slipsense.recordings.clips import ClipSpec, object_folds, split_by_clip, split_by_object
from slipsense.recordings.markers import layout_name, marker_layout
from slipsense.recordings.recording_set import Recordings
from slipsense.sensors.spec import BINOCULAR_MARKERS, SensorSpec, fps_problem, sensor_named, sensor_of


@dataclass
class EvaluationData:
    """What a reader found to score a checkpoint on: ``data`` (a Dataset of ``(x, y)``), ``extra``
    (where it came from, for the report) and ``replay`` (keyword arguments to replay the same runs
    per grasp, or None where the clips are not of whole recorded runs)."""

    data: Any
    extra: dict[str, Any]
    replay: dict[str, Any] | None = None


class ClipReader(Protocol):
    """What a clip model's data is read from: a recordings folder, a marker file."""

    kind: str  #: a split file's ``kind``
    describes: str  #: what one item is, in words
    pictures: bool  #: items are camera pictures (clip size settings and image noise apply)

    def training_data(self, run, progress: bool) -> tuple[Any, Any, dict[str, Any], dict[str, Any]]: ...

    def replays(self, split_info: dict[str, Any]) -> bool: ...

    def evaluation_data(
        self, checkpoint, model, info, *, recordings, split, markers, noise_std, on_error, overrides, progress
    ) -> EvaluationData: ...


class VideoClips:
    """Clips of camera pictures cut from recordings (video models)."""

    kind = "video"
    describes = "video clip"
    pictures = True

    def training_data(self, run, progress: bool) -> tuple[Any, Any, dict[str, Any], dict[str, Any]]:
        """``(train, test, split_info, data_config)`` for a clip model's
        :class:`~slipsense.training.settings.RunConfig` (its ``data`` section and seed); ``data_config``
        holds the sizes the model is built with and its ``sensor``."""
        data = run.data
        if data.markers is not None:
            raise ConfigError(f"model {run.name!r} takes video clips: use --recordings, not --markers")
        root = Path(data.recordings) if data.recordings else gelsight_recordings()
        named = sensor_named(data.sensor) if data.sensor else None
        read = Recordings.open(root, named, data.on_error, stated=named)  # the sensor named, else the data's own
        sensor = read.sensor
        size = data.size or sensor.image_size  # clips at the sensor's frame size unless --size says otherwise
        spec = ClipSpec(
            frames=data.frames, horizon=data.horizon, wiggle_per_video=data.wiggle_per_video, seed=run.seed, size=size
        )
        clips, _ = gelsight_clips(read, spec, on_error=data.on_error, overrides=data.overrides, progress=progress)
        test_objects: list[str] = []
        if data.split == "all":  # a model to ship: every clip trains, nothing is held out
            tr, te = np.arange(len(clips)), np.zeros(0, np.int64)
        elif data.split == "clips":
            tr, te = split_by_clip(clips, test_fraction=data.test_fraction, seed=run.seed)
        elif data.split == "objects":
            objects = sorted(set(clips.objects))
            if data.test_objects:
                unknown = sorted(set(data.test_objects) - set(objects))
                if unknown:
                    raise ConfigError(f"--test-objects not in {root}: {unknown}")
                test_objects = sorted(data.test_objects)
            else:
                k = 0 if data.fold is None else data.fold
                if not 0 <= k < data.folds:
                    raise ConfigError(f"--fold must be in 0..{data.folds - 1}")
                test_objects = sorted(object_folds(objects, n_folds=data.folds, seed=run.seed)[k])
            tr, te = split_by_object(clips, test_objects)
            if len(tr) == 0:
                raise ConfigError(
                    f"every object of {root} is held out ({', '.join(test_objects)}): nothing is left to train on"
                )
        else:
            raise ConfigError(f"--split must be objects, clips or all, got {data.split!r}")
        split_info = {
            "kind": self.kind,
            "recordings": portable_path(root),
            "clip_spec": asdict(spec),
            "split": data.split,
            "test_objects": test_objects,
            "test_indices": [int(i) for i in te],
            "on_error": data.on_error,
            # "default": the shipped hand labels of the shared recordings (data.label_runs); older
            # split files say null for "none", and evaluation rebuilds their clips that way
            "overrides": portable_path(data.overrides) if data.overrides else "default",
        }
        train = ClipDataset(clips.subset(tr), AugmentConfig(enabled=data.augment), seed=run.seed)
        test = ClipDataset(clips.subset(te))
        size = tuple(clips.x.shape[2:4])
        return train, test, split_info, {"frames": data.frames, "image_size": size, "sensor": sensor.to_dict()}

    def replays(self, split_info: dict[str, Any]) -> bool:
        """Whether the training runs can be replayed whole (to choose where the model alarms)."""
        return split_info.get("split") in ("objects", "all")

    def evaluation_data(
        self, checkpoint, model, info, *, recordings, split, markers, noise_std, on_error, overrides, progress
    ) -> EvaluationData:
        """The clips to score ``checkpoint`` on: a split file's held-out part (rebuilt with its clip
        settings) or every clip of ``recordings`` (with the checkpoint's clip settings)."""
        if markers is not None:
            raise InputError(checkpoint, "this checkpoint holds a video model; use --recordings or --split-file")
        data_info = info.get("data", {})
        sensor = sensor_of(info, checkpoint)  # the recordings layout of the sensor it was trained on
        if split is not None:
            split_info = read_split(split, self.kind)
            try:
                spec = clip_spec_from(split_info)
            except ConfigError as exc:
                raise InputError(split, str(exc)) from None
            root = resolve_path(split_info["recordings"])
            # the hand labels the clips were cut with: "default" the shipped ones of the shared recordings
            # (None for data.label_runs), null (split files from before that default) none, else a CSV
            stored = split_info.get("overrides")
            labels = None if stored == "default" else False if stored is None else resolve_path(stored)
            on_error = split_info.get("on_error") or on_error
            clips, _ = gelsight_clips(root, spec, on_error=on_error, overrides=labels, progress=progress, sensor=sensor)
            idx = split_info["test_indices"]
            if max(idx) >= len(clips):
                raise InputError(
                    split,
                    f"test index {max(idx)} is out of range: the clips rebuilt from its recordings are {len(clips)}",
                )
            extra = {"split": portable_path(split), "test_objects": split_info.get("test_objects")}
            replay = None
            if split_info.get("split") == "objects":
                objects = split_info.get("test_objects")
                replay = dict(recordings=root, overrides=labels, objects=objects, on_error=on_error)
            return EvaluationData(ClipDataset(clips.subset(idx), noise_std=noise_std, seed=0), extra, replay)
        if "clip_spec" not in data_info:
            raise InputError(checkpoint, "checkpoint has no clip settings (data.clip_spec)")
        spec = clip_spec_from(data_info)
        clips, _ = gelsight_clips(
            recordings, spec, on_error=on_error, overrides=overrides, progress=progress, sensor=sensor
        )
        extra = {"recordings": portable_path(recordings), "objects": sorted(set(clips.objects))}
        replay = dict(recordings=recordings, overrides=overrides, objects=None, on_error=on_error)
        return EvaluationData(ClipDataset(clips, noise_std=noise_std, seed=0), extra, replay)


class MarkerClips:
    """Windows of marker-cloud sequences from an ``.npz`` (``x`` (N, T, M, 3), ``y`` (N,), optional
    ``groups`` (N,)): marker models."""

    kind = "markers"
    describes = "marker sequence"
    pictures = False

    def training_data(self, run, progress: bool) -> tuple[Any, Any, dict[str, Any], dict[str, Any]]:
        """As :meth:`VideoClips.training_data`, for ``run.data.markers``."""
        data = run.data
        if data.markers is None:
            raise ConfigError(f"model {run.name!r} takes marker sequences: give --markers FILE.npz")
        x, y, groups = load_markers(data.markers)
        if len(np.unique(groups)) < 2:
            raise InputError(
                data.markers,
                f"all {len(groups)} samples are in one group: a split that never cuts a "
                "group leaves nothing to train on (give groups with several values)",
            )
        tr, te = split_groups(groups, 0.2 if data.test_fraction == 0.1 else data.test_fraction, run.seed)
        train = MarkerDataset(x[tr], y[tr], copies=data.marker_copies if data.augment else 1, seed=run.seed)
        split_info = {
            "kind": self.kind,
            "markers": portable_path(data.markers),
            "test_indices": [int(i) for i in te],
            "marker_copies": train.copies,  # as applied: 1 off a grid or without augment
        }
        layout = marker_file_layout(data.markers, x)
        if layout is not None:  # tracked in videos: a replay must take a camera's markers the same way
            split_info["clip_spec"] = {"marker_layout": layout}
        sizes = {"frames": int(x.shape[1]), "markers": int(x.shape[2])}
        sizes["sensor"] = _marker_sensor(data.markers, x, layout)
        return train, MarkerDataset(x[te], y[te]), split_info, sizes

    def replays(self, split_info: dict[str, Any]) -> bool:
        return False  # marker files hold windows, not whole recorded runs

    def evaluation_data(
        self, checkpoint, model, info, *, recordings, split, markers, noise_std, on_error, overrides, progress
    ) -> EvaluationData:
        """A split file's held-out windows, or every window of ``markers``; markers taken from videos
        otherwise than the checkpoint's are refused."""
        if recordings is not None:
            raise InputError(checkpoint, "this checkpoint holds a marker model; use --markers or --split-file")
        extra: dict[str, Any] = {}
        if split is not None:
            split_info = read_split(split, self.kind)
            path = resolve_path(split_info["markers"])
            x, y, _ = load_markers(path)
            _check_marker_layout(path, x, model, info, checkpoint)
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
        return EvaluationData(MarkerDataset(x, y), extra)


VIDEO_CLIPS = VideoClips()
MARKER_CLIPS = MarkerClips()


def marker_file_layout(path, x: np.ndarray) -> str | None:
    """How a marker file's markers were taken from videos (its ``marker_layout``, written by
    ``slipsense markers``: ``"7x9"``, ``"32"``; :func:`slipsense.recordings.markers.marker_layout`), or
    None for markers that were not tracked in videos (simulated, a user's own)."""
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


def _check_marker_layout(path, x, model, info, checkpoint) -> None:
    """Refuse markers taken from videos otherwise than the checkpoint's (``marker_layout``: a 7 x 9
    grid of every marker is not the 63 markers nearest the centre, though both hold 63)."""
    data = info.get("data")
    spec = (data.get("clip_spec") if isinstance(data, dict) else None) or {}
    trained = model.window_geometry(spec).get("marker_layout")
    given = marker_file_layout(path, x)
    if given != trained:

        def said(layout):
            return f"markers taken from videos as {layout!r}" if layout else "markers not tracked in videos"

        raise InputError(path, f"holds {said(given)}; {checkpoint} was trained on {said(trained)}")


def _marker_sensor(path, x: np.ndarray, layout: str | None) -> dict[str, Any]:
    """The sensor of a marker file: for markers tracked in videos (``layout``, :func:`marker_file_layout`)
    the sensor of those videos (the file's ``sensor``, written by ``slipsense markers``), else its frame
    rate (the file's ``fps``, else the binocular sensor's) and marker count."""
    fps = BINOCULAR_MARKERS.fps
    with np.load(path, allow_pickle=False) as z:
        stated = str(z["sensor"]) if "sensor" in z.files and np.ndim(z["sensor"]) == 0 else None
        if "fps" in z.files and np.ndim(z["fps"]) == 0 and fps_problem(float(z["fps"])) is None:
            fps = float(z["fps"])
    if layout is not None:  # tracked in videos: their sensor's rate
        if stated is not None:
            try:
                videos = SensorSpec.from_dict(json.loads(stated))
            except ValueError as exc:
                raise InputError(path, f"its sensor is malformed ({exc})") from None
        else:  # files written before the sensor was stored were all tracked in the study's recordings
            videos = sensor_named("gelsight-mini")
        return replace(videos, output="markers", markers=int(x.shape[2])).to_dict()
    return replace(BINOCULAR_MARKERS, name="markers", fps=fps, markers=int(x.shape[2])).to_dict()


#: split.json entries that must not change when a run is resumed.
SPLIT_IDENTITY = ("kind", "split", "test_objects", "test_indices", "clip_spec", "overrides", "marker_copies")
#: what a split file written before a key existed meant by its absence
SPLIT_DEFAULTS = {"marker_copies": 1}
#: Keys a split file needs, by its ``kind``.
SPLIT_KEYS = {"video": ("recordings", "clip_spec", "test_indices"), "markers": ("markers", "test_indices")}


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


def read_split(path, kind: str | None = None) -> dict[str, Any]:
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
