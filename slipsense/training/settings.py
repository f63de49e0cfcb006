"""What a training run is configured with: one :class:`RunConfig`, built once from a configuration tree
(:mod:`slipsense.config_tree`: ``model``, ``data`` and ``train`` sections) by :meth:`RunConfig.from_tree`,
which makes every check and resolves every path (a :class:`~slipsense.errors.ConfigError` names the
key), and written back whole by :meth:`RunConfig.to_tree` (what checkpoints and ``config.yaml`` keep).

The model's ``training_task`` decides which settings apply: a clip model (``"clips"``) cuts clips from
recordings or a marker file and trains with :class:`~slipsense.training.clips.TrainConfig`; a grasp
detector (``"grasps"``) trains on whole runs with :class:`~slipsense.training.grasps.GraspTrainConfig`
and refuses the settings that only cut clips, by name. A :class:`RunConfig` is frozen: training reads
it and never changes it.

    >>> run = RunConfig.from_tree({"model": {"name": "motionnet"}, "data": {"test_objects": ["mug"]}})
    >>> run.data.test_objects, run.train.epochs                               # doctest: +SKIP
    (('mug',), 20)
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Mapping

from slipsense.paths import gelsight_recordings, portable_path, resolve_path
from slipsense.datasets import check_marker_copies
from slipsense.errors import ConfigError, InputError, SlipsenseError
from slipsense.models import available, model_class, settings_of
from slipsense.models.base import RecordingsShape
from slipsense.recordings.folders import state_sensor, stated_sensor
from slipsense.recordings.recording_set import Recordings
from slipsense.config_tree import DEFAULT_MODEL, SECTIONS, check_keys, check_seed, to_plain
from slipsense.sensors.spec import SensorSpec, sensor_named
from slipsense.training.clips import TrainConfig, paper_settings
from slipsense.training.grasps import GraspTrainConfig, make_config, recordings_shape


@dataclass(frozen=True)
class DataConfig:
    """The ``data`` section: what is read and what is held out; paths resolved (``$SLIPSENSE_DATA/...``
    as checkpoints write them). A value left out, or None, is the default below."""

    recordings: Path | None = None  # None: the shared GelSight recordings ($SLIPSENSE_DATA/gelsight-slip)
    markers: Path | None = None  # marker-sequence .npz (STNet, TemNet)
    frames: int = 5  # clip models: frames per clip
    horizon: int = 0  # clip models: slip clips end this many frames before the moment of slip
    size: tuple[int, int] | None = None  # (height, width) in pixels the model sees; None: the model's
    wiggle_per_video: int = 2  # clip models: calm clips per recording
    split: str = "objects"  # clip models: objects (leave objects out), clips (random) or all
    test_objects: tuple[str, ...] = ()  # objects held out and judged on
    fold: int | None = None  # else hold out fold k of `folds` folds by object
    folds: int = 5
    test_fraction: float = 0.1  # clip models, split clips (and marker groups)
    augment: bool = True  # clip models: the papers' transformed copies
    marker_copies: int = 4  # with augment, marker windows: itself and copies-1 mirrored, shifted copies
    on_error: str = "raise"  # or "skip": a bad recording is named and left out
    overrides: Path | bool | None = None  # CSV of hand labels; None: the shipped ones; False: none
    sensor: str | None = None  # the registered sensor the recordings were taken with; None: the one they state
    also: Path | None = None  # grasp detectors: another data set's recordings, trained on alongside
    # the recordings as read already where the caller holds them (``recordings`` is then their folder):
    # not a setting, never stored; training lists nothing again
    read: Recordings | None = field(default=None, compare=False, repr=False)

    @classmethod
    def from_section(cls, values: Mapping[str, Any]) -> "DataConfig":
        """From a tree's ``data`` section whose keys are known: paths resolved, ``size`` and
        ``test_objects`` (a list, or comma-separated names) checked."""
        data = {k: v for k, v in values.items() if v is not None}
        if isinstance(data.get("recordings"), Recordings):
            data["read"] = data["recordings"]
            data["recordings"] = data["read"].root
        for key in ("recordings", "markers", "overrides", "also"):
            if data.get(key) not in (None, False):  # overrides False: no hand labels at all
                data[key] = resolve_path(data[key])
        if "size" in data:
            size = data["size"]
            if not (isinstance(size, (list, tuple)) and len(size) == 2 and all(isinstance(v, int) for v in size)):
                raise ConfigError(f"data.size must be [height, width] in pixels, got {size!r}")
            data["size"] = (int(size[0]), int(size[1]))
        held = data.get("test_objects", ())
        data["test_objects"] = tuple(o for o in held.split(",") if o) if isinstance(held, str) else tuple(held)
        check_marker_copies(data.get("marker_copies", 1), "data.marker_copies")
        return cls(**data)


def recordings_root(data: DataConfig) -> Path:
    """The recordings folder a run reads: ``data.recordings``, else the shared GelSight recordings."""
    return data.recordings or gelsight_recordings()


def recordings_sensor(data: DataConfig) -> SensorSpec:
    """The sensor a grasp detector's recordings are read with: ``data.sensor`` by name, else the
    data's own (its ``sensor.json`` or a registered layout); InputError saying how to state one where
    neither names one."""
    if data.sensor:
        return sensor_named(data.sensor)
    root = recordings_root(data)
    stated = data.read.stated if data.read is not None else stated_sensor(root)
    if stated is None:
        raise InputError(root, state_sensor())
    return stated


def recordings_read(data: DataConfig) -> Recordings:
    """The run's recordings read with its sensor's layout (:func:`recordings_sensor`): the set it was
    given, else its folder scanned once."""
    named = sensor_named(data.sensor) if data.sensor else None
    return Recordings.of(data.read or recordings_root(data), named, data.on_error, stated=named)


def read_once(data: DataConfig) -> DataConfig:
    """``data`` holding its recordings as read (:func:`recordings_read`): the scan the run's recipe
    defaults look at is the one its training reads; as it was where they cannot be read here (the
    trainer names the problem when it reads them)."""
    try:
        return replace(data, read=recordings_read(data))
    except SlipsenseError:
        return data


def data_shape(data: DataConfig) -> RecordingsShape | None:
    """The run's recordings as the model's :meth:`~slipsense.models.base.SlipModel.training_defaults`
    take them (cameras per grasp, labelled as a whole), from the folder structure alone; None where
    they cannot be looked at here."""
    return recordings_shape(data.read) if data.read is not None else None


def under(defaults: Mapping[str, Any], model: dict, train: dict) -> tuple[dict, dict]:
    """``model`` and ``train`` sections over a model's :meth:`~slipsense.models.base.SlipModel.training_defaults`
    (``model.KEY`` to the model, any other key to training): what the tree gives wins."""
    below_model = {k[len("model.") :]: v for k, v in defaults.items() if k.startswith("model.")}
    below_train = {k: v for k, v in defaults.items() if not k.startswith("model.")}
    return {**below_model, **model}, {**below_train, **train}


#: ``data`` keys of a clip model, in the order its stored tree lists them
CLIP_DATA_KEYS = tuple(f.name for f in fields(DataConfig) if f.name not in ("also", "read"))
#: ``data`` keys of a grasp detector that its stored tree keeps (what it held out is in its checkpoint)
GRASP_STORED_KEYS = ("recordings", "overrides", "on_error", "sensor", "also")
#: every ``data`` key of a grasp detector (``size`` becomes its ``model.image_size``)
GRASP_DATA_KEYS = (*GRASP_STORED_KEYS, "size", "test_objects", "fold", "folds")
#: Settings that only cut clips or drive the clip trainer, refused by name for a grasp detector
CLIP_ONLY_DATA = tuple(k for k in CLIP_DATA_KEYS if k not in GRASP_DATA_KEYS)
CLIP_ONLY_TRAIN = ("num_workers", "device", "max_steps_per_epoch", "step_size", "gamma", "select_by")


#: ``training_task`` (a model class attribute) -> the class of its training settings
TRAIN_SETTINGS: dict[str, type] = {"clips": TrainConfig, "grasps": GraspTrainConfig}


def train_keys(train_config: type) -> set[str]:
    """The ``train`` keys of a trainer's settings class (those that are not run options or the model)."""
    return {f.name for f in fields(train_config)} - {"progress", "model", "model_config"}


@dataclass(frozen=True)
class RunConfig:
    """One training run: the model (``{"name": ..., **its settings}``), what it reads
    (:class:`DataConfig`) and how it trains (:class:`~slipsense.training.clips.TrainConfig` for a clip
    model, :class:`~slipsense.training.grasps.GraspTrainConfig` for a grasp detector, every setting
    resolved). ``preset``: a clip model's named configuration, its settings under ``model``'s."""

    model: dict[str, Any]
    data: DataConfig
    train: TrainConfig | GraspTrainConfig
    preset: str | None = None

    @property
    def name(self) -> str:
        return self.model["name"]

    @property
    def settings(self) -> dict[str, Any]:
        """The model's settings (``model`` without its name)."""
        return {k: v for k, v in self.model.items() if k != "name"}

    @property
    def seed(self) -> int:
        return self.train.seed

    @classmethod
    def from_tree(cls, tree: Mapping[str, Mapping[str, Any]]) -> "RunConfig":
        """Check a configuration tree and resolve it (the tree is left as it was given). The model is
        ``model.name`` (default :data:`~slipsense.config_tree.DEFAULT_MODEL`); a ``model`` key that is
        not a setting of the model but a training setting goes to ``train`` (a bare ``--set KEY=VALUE``);
        unknown keys and bad values are refused naming them. Every run starts from its model's
        :meth:`~slipsense.models.base.SlipModel.training_defaults` (its recipe; a grasp detector's also
        what the recordings are, :func:`data_shape`), under every setting the tree gives."""
        model, data, train = ({**(tree.get(s) or {})} for s in SECTIONS)
        name = model.pop("name", None) or DEFAULT_MODEL
        if name not in available():
            raise ConfigError(f"unknown model {name!r}; available: {', '.join(available())}")
        trainer = TRAIN_SETTINGS[model_class(name).training_task]
        accepted = settings_of(model_class(name))
        for key in [k for k in model if k not in accepted and k in train_keys(trainer)]:
            train[key] = model.pop(key)
        train["seed"] = check_seed(train.get("seed") or 0)
        if trainer is GraspTrainConfig:
            return cls._grasps(name, model, data, train)
        model, train = under(model_class(name).training_defaults(None), model, train)  # its recipe, if any
        check_keys({"data": data, "train": train}, {"data": CLIP_DATA_KEYS, "train": train_keys(TrainConfig)})
        preset = model.pop("preset", None)
        unknown = sorted(set(model) - accepted)
        if unknown:  # before any data is decoded
            raise ConfigError(
                f"model {name!r} has no setting {', '.join(unknown)}; settings: {', '.join(sorted(accepted))}"
            )
        data_config = DataConfig.from_section(data)
        settings = TrainConfig.from_dict({**paper_settings(name, preset), **train})
        return cls({"name": name, **model}, data_config, settings, preset)

    @classmethod
    def _grasps(cls, name: str, model: dict, data: dict, train: dict) -> "RunConfig":
        """A grasp detector's run: the clip-only settings refused, ``data.size`` its ``model.image_size``,
        its training settings made (:func:`~slipsense.training.grasps.make_config`, which builds the
        model once to check its settings)."""
        clip_only = [k for k in CLIP_ONLY_DATA if data.get(k) is not None]
        clip_only += [f"train.{k}" for k in CLIP_ONLY_TRAIN if train.get(k) is not None]
        clip_only += ["preset"] if model.get("preset") is not None else []
        if clip_only:
            raise ConfigError(
                f"{name} trains on whole grasps: {', '.join(clip_only)} only apply to clip models "
                f"(grasp settings: slipsense train --help)"
            )
        model.pop("preset", None)
        data = {k: v for k, v in data.items() if k not in CLIP_ONLY_DATA}
        train = {k: v for k, v in train.items() if k not in CLIP_ONLY_TRAIN}
        keys = {"train": train_keys(GraspTrainConfig), "data": GRASP_DATA_KEYS}
        check_keys({"train": train, "data": data}, keys, "grasp configuration")
        data_config = DataConfig.from_section(data)
        if data_config.size is not None:
            model["image_size"] = list(data_config.size)
            data_config = replace(data_config, size=None)
        # the model's recipe and what the recordings imply, under every setting the tree gives
        data_config = read_once(data_config)
        defaults = model_class(name).training_defaults(data_shape(data_config), init=train.get("init") is not None)
        model, train = under(defaults, model, train)
        settings = make_config(name, {**train, **{f"model.{k}": v for k, v in model.items()}})
        return cls({"name": name, **settings.model_config}, data_config, settings)

    def to_tree(self) -> dict[str, dict[str, Any]]:
        """The run as a configuration tree, every training setting included (what checkpoints store
        and ``config.yaml`` holds: ``--config RUN/config.yaml`` repeats the run). A grasp detector's
        tree leaves out what it held out (its checkpoint says that) and the settings it does not take."""
        grasps = isinstance(self.train, GraspTrainConfig)
        data = {k: getattr(self.data, k) for k in (GRASP_STORED_KEYS if grasps else CLIP_DATA_KEYS)}
        for key in ("recordings", "markers", "overrides", "also"):
            if data.get(key) not in (None, False):
                data[key] = portable_path(data[key])
        if grasps:
            data = {k: v for k, v in data.items() if v is not None}
        model = {"name": self.name, **({"preset": self.preset} if self.preset else {}), **self.settings}
        train = {k: v for k, v in asdict(self.train).items() if k in train_keys(type(self.train))}
        return to_plain({"model": model, "data": data, "train": train})


__all__ = ["CLIP_DATA_KEYS", "DataConfig", "RunConfig"]
