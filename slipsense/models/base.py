"""The model contract and the registry: what every slipsense model declares about itself.

Code outside :mod:`slipsense.models` (training, evaluation, the live detector, ONNX export,
experiments) only talks to a model through this contract, so a new model is one file that
subclasses one of the three kinds below and registers itself::

    @register("mynet")
    class MyNet(VideoModel):
        def __init__(self, frames=5, image_size=(240, 320)): ...
        def config(self): ...          # the keyword arguments that rebuild it (stored in checkpoints)
        def check_input(self, x): ...  # InputError on a wrong shape or non-finite values
        def forward(self, x): ...      # (B, 2) logits, class 1 = slip

The kinds:

* :class:`VideoModel` — clips ``(B, T, 3, H, W)`` float32 in [0, 1], BGR as OpenCV decodes;
* :class:`MarkerModel` — marker clouds ``(B, T, M, 3)`` float32, mm;
* :class:`GraspModel` — whole grasps of all sensors at once, ``(B, S, N, h, w)`` grey in [0, 1],
  logits at every frame ``(B, N, 2)``; streams itself (:meth:`GraspModel.stream`).

Every model streams (:meth:`SlipModel.stream`, :class:`Stream`): clip models get a window stream
(:mod:`slipsense.models.streams`), a grasp model brings its own; the named modules inside run on
PyTorch or, exported through :meth:`SlipModel.onnx_parts`, on ONNX Runtime
(:mod:`slipsense.models.runners`). Every other hook of :class:`SlipModel` has a default that suits a
plain network.
"""

from __future__ import annotations

import copy
import inspect
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Protocol, Sequence

import numpy as np
import torch
from torch import Tensor, nn

from slipsense.errors import ConfigError, InputError
from slipsense.measures.registry import horizon_frames, startup_frames
from slipsense.models.streams import WindowStream
from slipsense.readers import MARKER_CLIPS, VIDEO_CLIPS, ClipReader
from slipsense.recordings.markers import layout_name, marker_clouds, marker_layout, marker_sequences, track_markers

_REGISTRY: dict[str, type] = {}

#: Window length used for a video model whose checkpoint states none (the study's 5-frame clips).
DEFAULT_FRAMES = 5
#: No setting of any model is an integer this large (widths, depths, heads, frames, pixels).
MAX_SETTING = 100_000
#: Models with more parameters are refused before their weights are allocated.
MAX_PARAMETERS = 1_000_000_000


@dataclass
class OnnxPart:
    """One ONNX file of a model: ``module(*example)`` exported with these input and output names;
    ``dynamic`` names the axes left free per input/output name (``{"video": {0: "batch"}}``), the rest
    are fixed to the example's."""

    module: nn.Module
    example: tuple[Tensor, ...]
    inputs: list[str]
    outputs: list[str]
    dynamic: dict[str, dict[int, str]]


class ModelPart(nn.Module):
    """A module that runs part of ``model`` (a streaming or ONNX part), sharing its weights."""

    def __init__(self, model: nn.Module):
        super().__init__()
        self.model = model


class Stream(Protocol):
    """What :meth:`SlipModel.stream` returns: the model run one frame per sensor at a time.

    ``push(frames, index)``: one raw frame per sensor (uint8 ``(H, W, 3)`` BGR images, or float
    ``(M, 3)`` marker clouds), checked (InputError naming frame ``index`` and the sensor; nothing
    changes then) -> ``(S,)`` per-sensor slip probabilities where the stream judges each sensor
    apart (``per_sensor`` True), ``(1,)`` where the model fuses the sensors into one answer, or None
    while the model cannot answer yet (window not full, camera start-up). ``replay(streams)``: the
    same for whole recordings at once, one ``(N, ...)`` array per sensor -> ``(N, S)`` (or
    ``(N, 1)``) with NaN where push would give None. ``attention(sensor)``: a heat map of the latest
    window, or None (always None where ``has_attention`` is False). ``ready``: True once the model
    answers. ``describe()``: what one pushed frame must look like (``{"kind", "frames", ...}``).
    ``close()``: frees what the stream holds (a temporary folder of ONNX files).
    """

    sensors: int
    per_sensor: bool
    has_attention: bool  #: the model's :attr:`SlipModel.attention_map` is not None

    @property
    def ready(self) -> bool: ...

    def reset(self) -> None: ...

    def close(self) -> None: ...

    def push(self, frames: Sequence[Any], index: int) -> np.ndarray | None: ...

    def replay(self, streams: Sequence[np.ndarray]) -> np.ndarray: ...

    def attention(self, sensor: int) -> np.ndarray | None: ...

    def describe(self) -> dict[str, Any]: ...


class SlipModel(nn.Module):
    """Base of every registered model; see the module notes for the contract."""

    #: set by :func:`register`
    model_name: str = ""
    #: "video", "markers" or "grasp": the model's own description of its input (code outside
    #: slipsense/models hands out :attr:`clip_reader` and :attr:`training_task` instead)
    input_kind: str = ""
    #: the data its clips are read from, for training and evaluation (:mod:`slipsense.readers`):
    #: clips of camera pictures cut from recordings, or windows of 3D marker clouds
    clip_reader: ClipReader = VIDEO_CLIPS
    #: True when the frame part's output holds the frame's token at every window slot, ``(N, T, dim)``,
    #: so a window takes row ``k`` of its ``k``-th frame (ViViT's slot position embedding)
    slot_tokens: bool = False
    #: where ``backend="auto"`` streams it: ``"onnx"`` (ONNX Runtime where installed: several times
    #: faster for most small streaming models) or ``"torch"`` for a model measured faster on PyTorch
    auto_backend: str = "onnx"
    #: the training settings of the model's paper (slipsense.training.clips.TrainConfig keys)
    paper_training: dict[str, Any] = {}
    #: training settings a preset comes with, over :attr:`paper_training` (a compact network trains
    #: best with other settings than the paper's large one)
    preset_training: dict[str, dict[str, Any]] = {}
    #: named configurations, e.g. the paper's size and a compact one (``slipsense train --preset``)
    presets: dict[str, dict[str, Any]] = {}
    #: what ``slipsense train`` runs for it: ``"clips"`` (windows cut from recordings or marker
    #: sequences, :mod:`slipsense.training.clips`) or ``"grasps"`` (whole runs, :mod:`slipsense.training.grasps`)
    training_task: str = "clips"
    #: how the model is made by default (``slipsense train --model NAME``, ``slipsense.fit(model=NAME)``):
    #: training settings by name and model settings as ``model.KEY``, under whatever the user gives
    #: (``--config``, the command's options, ``--set``); see :meth:`training_defaults`. Empty: the
    #: trainer's own defaults.
    recipe: dict[str, Any] = {}
    #: ``slipsense adapt``: the relative cost of learning this family from a user's grasps (cheap
    #: ones are judged first); the words a user reads of it
    adapt_cost: float = 100.0
    adapt_words: str = ""
    #: settings adapt trains it with, over its recipe (e.g. fewer epochs where its own are many)
    adapt_settings: dict[str, Any] = {}

    @classmethod
    def adapt_reason(cls, grasps: Any) -> str | None:
        """Why ``slipsense adapt`` cannot make this family from ``grasps`` (a user's grasps: their
        ``count``, ``objects``, ``cameras``, ``image_size``, ``fps``, and ``markers()``, which says
        whether the gels carry a marker grid, with the evidence in words), one line; None where it can
        (then it is trained on them with its own recipe, ``slipsense train --model NAME``)."""
        return "a clip model (it learns from short clips with a moment of slip); adapt judges detectors of whole grasps"

    @classmethod
    def training_defaults(cls, data: "RecordingsShape | None", init: bool = False) -> dict[str, Any]:
        """The settings a training of this model starts from, before the user's (``--config``,
        options and ``--set`` win over every one): ``{"KEY": value}`` for a training setting,
        ``{"model.KEY": value}`` for a model setting. ``data``: what the recordings are (None where
        they could not be looked at: the trainer names the problem when it reads them); ``init``:
        training starts from a checkpoint (``train.init``), whose own settings the model keeps, so
        no recipe applies. A clip model: its :attr:`recipe`."""
        return {} if init else dict(cls.recipe)

    def config(self) -> dict[str, Any]:
        """The keyword arguments that rebuild this model (JSON-ready; stored in checkpoints); by default
        a copy of the ``_config`` its constructor keeps."""
        if "_config" not in self.__dict__:
            raise NotImplementedError(f"{type(self).__name__} must define config()")
        return {k: list(v) if isinstance(v, list) else v for k, v in self._config.items()}

    def check_input(self, x: Tensor) -> None:
        raise NotImplementedError(f"{type(self).__name__} must define check_input()")

    @classmethod
    def small_config(cls) -> dict[str, Any]:
        """A small configuration for fast tests of the contract (default: the defaults)."""
        return {}

    def prepare(self, train_data) -> None:
        """Fit what the model takes from its training data before the first step (a reference, a
        normaliser; kept in its weights, so a resumed or loaded model has it); the clip task calls it
        on the training set. Default: nothing."""

    def streaming_parts(self) -> tuple[nn.Module | None, nn.Module]:
        """``(frame_part, window_part)``: the live detector runs ``frame_part`` once per pushed frame and
        caches its output, then ``window_part`` on the cached window. ``frame_part`` None: nothing can
        be cached and ``window_part`` (the model) sees the raw window."""
        return None, self

    def exportable(self) -> nn.Module:
        """An eval-mode copy set up for ONNX tracing."""
        return copy.deepcopy(self).eval()

    def stream(self, *, sensors=1, info=None, backend="torch", dtype="float32", onnx_dir=None) -> Stream:
        """A fresh :class:`Stream` of this model over ``sensors`` sensors (default: a sliding window
        over the frame-part outputs, :class:`slipsense.models.streams.WindowStream`). ``info``: the
        checkpoint's config; ``backend``/``dtype``/``onnx_dir`` as :class:`slipsense.streaming.detector.SlipDetector`."""
        geometry = window_geometry(self, info)
        return WindowStream(self, geometry, sensors=sensors, backend=backend, dtype=dtype, onnx_dir=onnx_dir)

    def inputs_from_videos(
        self, videos: Sequence[np.ndarray], paths: Sequence[Any], geometry: Mapping[str, Any] | None = None
    ) -> list[Any]:
        """Per sensor, what a stream of recorded camera videos (uint8 ``(N, H, W, 3)`` each, read
        from ``paths``) pushes frame by frame: the frames themselves for a model of pictures.
        ``geometry``: the checkpoint's :func:`window_geometry`."""
        return list(videos)

    def inputs_from_array(self, array: np.ndarray, path: Any) -> np.ndarray:
        """A saved input stream (a ``.npy`` file) as ``(sensors, T, ...)``; a model of pictures takes none."""
        raise InputError(path, f"a marker .npy needs a marker model (stnet, temnet); {self.model_name} takes video")

    def check_live_cameras(self, cameras: str) -> None:
        """InputError unless live camera frames can be pushed as they come (a model of pictures: yes)."""

    def check_video_replay(self, geometry: Mapping[str, Any]) -> None:
        """ConfigError unless recorded videos can be replayed through the model (pictures: yes)."""

    def streaming_modules(self, geometry: Mapping[str, Any]) -> dict[str, nn.Module]:
        """The named modules a stream runs (``{"frame", "window"}`` by default, from
        :meth:`streaming_parts`; no ``"frame"`` when nothing can be cached)."""
        frame_part, window_part = self.streaming_parts()
        return {**({"frame": frame_part} if frame_part is not None else {}), "window": window_part}

    def onnx_parts(self, geometry: Mapping[str, Any], batch: int | None = None) -> dict[str, OnnxPart]:
        """What ``slipsense export`` writes (call it on :meth:`exportable`): ``"model"`` (the whole
        network) and the :meth:`streaming_modules` with example inputs. ``batch`` None leaves the
        batch axis free, an int fixes it. A clip model: the whole network and its frame/window parts,
        batch axis 0, on random example inputs (seed 0) of ``batch`` (default 2) items."""
        g, t, b = torch.Generator().manual_seed(0), geometry["frames"], batch or 2
        video = geometry["kind"] == "video"
        if video:
            full = torch.rand(b, t, 3, *geometry["image_size"], generator=g)
        else:
            full = torch.randn(b, t, geometry["markers"], 3, generator=g)
        examples = {"model": full, "window": full}
        frame_part, _ = self.streaming_parts()
        if frame_part is not None:
            with torch.no_grad():
                tokens = frame_part(full.flatten(0, 1)).unflatten(0, (b, t))
            if self.slot_tokens:
                tokens = tokens[:, torch.arange(t), torch.arange(t)]  # frame k at slot k
            examples.update(frame=full[:, 0], window=tokens.contiguous())
        names = {
            "model": ("video" if video else "markers", "logits"),
            "frame": ("frames" if video else "clouds", "tokens"),
            "window": ("tokens", "logits"),
        }
        modules = {"model": self, **self.streaming_modules(geometry)}
        if "frame" not in modules:  # the window part is the whole model and takes the model's input
            names["window"] = names["model"]
        parts = {}
        for key, module in modules.items():
            inp, out = names[key]
            dyn = {} if batch is not None else {inp: {0: "batch"}, out: {0: "batch"}}
            parts[key] = OnnxPart(module, (examples[key],), [inp], [out], dyn)
        return parts

    #: what :meth:`attention` draws (e.g. "attention rollout"), None for a model that has no heat map
    attention_map: str | None = None

    def attention(self, window: Tensor) -> np.ndarray | None:
        """Where the model looks in one window ``(1, T, ...)``, for heat maps; None when it cannot say."""
        return None

    def reduced_precision(self, precision: str) -> nn.Module:
        """An inference copy at ``precision`` ("bfloat16" or "int8"); refused unless the model offers it."""
        raise ConfigError(f"{precision} inference is implemented for STNet and TemNet, not {type(self).__name__}")

    def window_geometry(self, spec: Mapping[str, Any]) -> dict[str, Any]:
        """What one pushed frame must look like, ``{"kind", "frames", ...}``; ``spec`` is the checkpoint's
        training clip spec, used where the model does not fix a size itself."""
        raise NotImplementedError


class VideoModel(SlipModel):
    input_kind = "video"

    def check_input(self, x: Tensor) -> None:
        """InputError unless ``x`` is a finite float tensor of the shape the model's ``_check_shape`` takes."""
        self._check_shape(x)
        check_video_values(x)

    def window_geometry(self, spec: Mapping[str, Any]) -> dict[str, Any]:
        frames = getattr(self, "frames", None) or spec.get("frames") or DEFAULT_FRAMES
        size = getattr(self, "image_size", None) or spec.get("size")
        if not size:  # a model that states no frame size has no window to cut
            raise ConfigError(f"{type(self).__name__} states no frame size (image_size) and its clip spec none")
        return {"kind": "video", "frames": int(frames), "image_size": (int(size[0]), int(size[1]))}


class MarkerModel(SlipModel):
    input_kind = "markers"
    clip_reader = MARKER_CLIPS

    def inputs_from_videos(
        self, videos: Sequence[np.ndarray], paths: Sequence[Any], geometry: Mapping[str, Any] | None = None
    ) -> list[Any]:
        """Markers tracked through each whole video (:mod:`slipsense.recordings.markers`), ``(N, M, 3)``:
        in the checkpoint's ``marker_layout`` (mm, as it was trained and as replays read them), or,
        for a model trained on markers not tracked in videos, the markers nearest the centre."""
        layout = (geometry or {}).get("marker_layout")
        tracks = [track_markers(v, source=p) for v, p in zip(videos, paths)]
        if layout is None:
            return [marker_sequences(track, self.markers) for track in tracks]
        return [marker_clouds(track, layout) for track in tracks]

    def inputs_from_array(self, array: np.ndarray, path: Any) -> np.ndarray:
        """A marker stream ``(T, M, 3)`` or ``(sensors, T, M, 3)`` (mm) -> ``(sensors, T, M, 3)``."""
        x = array[None] if array.ndim == 3 else array
        if x.ndim != 4 or x.shape[-1] != 3:
            raise InputError(path, f"expected a marker stream (T, M, 3) or (sensors, T, M, 3), got shape {array.shape}")
        return x

    def check_video_replay(self, geometry: Mapping[str, Any]) -> None:
        if geometry.get("marker_layout") is None:
            raise ConfigError(
                "early warning replays videos: this marker model was trained on markers that were not tracked "
                "in videos (simulated, or a marker file without marker_layout), so nothing says how to take "
                "its markers from one"
            )

    def check_live_cameras(self, cameras: str) -> None:
        raise InputError(
            None, f"camera {cameras}: live cameras need a video model; marker models take a video file or a marker .npy"
        )

    def window_geometry(self, spec: Mapping[str, Any]) -> dict[str, Any]:
        frames = getattr(self, "frames", None) or spec.get("frames") or DEFAULT_FRAMES
        out = {"kind": "markers", "frames": int(frames), "markers": int(self.markers)}
        if spec.get("marker_layout") is not None:  # trained on markers tracked in videos, taken so
            count, _ = marker_layout(spec["marker_layout"])
            if count != int(self.markers):
                raise ConfigError(
                    f"marker layout {spec['marker_layout']!r} holds {count} markers, the model takes {self.markers}"
                )
            out["marker_layout"] = layout_name(spec["marker_layout"])
        return out


class GraspModel(SlipModel):
    """Sees every frame of all sensors from the start of the grasp; the live detector pushes frames to
    :meth:`stream` instead of cutting windows."""

    input_kind = "grasp"
    training_task = "grasps"

    @classmethod
    def adapt_reason(cls, grasps: Any) -> str | None:
        return None

    @classmethod
    def training_defaults(cls, data: "RecordingsShape | None", init: bool = False) -> dict[str, Any]:
        """Its :attr:`recipe`, then what the grasps imply: ``model.sensors``, the cameras per grasp of
        the recordings where that is not the model's own default (1: each camera a grasp of its own),
        the warning ``horizon`` and the ``startup`` (2 s and 0.4 s: :data:`~slipsense.measures.registry.HORIZON_S`)
        in frames at the recordings' sensor's rate, and ``startup`` 0 for grasps labelled as a whole (cut
        from a stream: no camera start-up to skip). From a checkpoint (``init``) the model keeps its
        settings: horizon and start-up only."""
        out = super().training_defaults(data, init)
        if data is None:
            return out
        if not init and "sensors" in settings_of(cls) and data.cameras != setting_default(cls, "sensors"):
            out["model.sensors"] = data.cameras
        if data.fps is not None:  # the warning window and the start-up are times: frames at the sensor's rate
            out.setdefault("horizon", horizon_frames(data.fps))
            out.setdefault("startup", startup_frames(data.fps))
        if data.per_grasp:
            out["startup"] = 0
        return out

    def check_cameras(self, cameras: Sequence[int], where: str = "the recordings") -> None:
        """ConfigError, one line in words, unless grasps of ``cameras`` cameras each train this model:
        one sensor takes each camera of a grasp as a grasp of its own; more take that many at once."""
        cameras = sorted({int(c) for c in cameras})
        if self.sensors == 1 or cameras == [self.sensors]:
            return
        have = "/".join(map(str, cameras))
        h, w = self.image_size
        raise ConfigError(
            f"{where}: {have} camera{'' if cameras == [1] else 's'} per grasp, read as {h}x{w} grey frames; "
            f"{self.model_name} was built for {self.sensors} sensors (model.sensors={self.sensors}), "
            f"{self.sensors} cameras of a grasp at once: leave model.sensors out to take the data's, or set "
            f"model.sensors=1 to train on each camera alone"
        )

    #: what :meth:`stream` runs: a :class:`~slipsense.models.grasp_stream.GraspStream` (see MotionStream)
    stream_class: type

    def stream(self, *, sensors=None, info=None, backend="torch", dtype="float32", onnx_dir=None) -> Stream:
        """A fresh :class:`Stream` over whole grasps (a grasp model has no clip window to slide): its
        :attr:`stream_class`, frame by frame (eval mode)."""
        return self.stream_class(self, sensors=sensors, info=info, backend=backend, dtype=dtype, onnx_dir=onnx_dir)

    def check_input(self, x) -> None:
        """Grey frames ``(B, sensors, N >= 1, h, w)`` at the model's ``image_size``, finite floats."""
        if x.ndim != 5 or x.shape[1] != self.sensors or x.shape[2] < 1 or tuple(x.shape[3:]) != tuple(self.image_size):
            raise InputError(
                None,
                f"{self.model_name} takes grey frames (B, {self.sensors}, N, {self.image_size[0]}, "
                f"{self.image_size[1]}), got {tuple(x.shape)}",
            )
        if not x.dtype.is_floating_point or not bool(torch.isfinite(x).all()):
            raise InputError(None, f"{self.model_name} input must be finite floats in [0, 1]")

    def chunk_logits(self, runs, n_out: int):
        """What training on whole grasps calls: ``runs`` is a list of ``(gray (S, N, h, w) float,
        chunk ends)``; returns ``(C, n_out, 2)`` logits of the ``n_out`` frames ending at each end,
        equal (in eval mode) to ``forward`` of the whole run at those frames. A model should encode
        a frame shared by several chunks once: training time is mostly this call."""
        raise NotImplementedError

    def chunk_rows(self, gray: Tensor, ends: Sequence[int], n: int) -> Tensor:
        """For :meth:`chunk_logits`: InputError unless ``gray`` is one run ``(S, N, h, w)``; the frame
        indices of the ``n`` frames ending at each of ``ends``, ``(C, n)`` (below 0: frame 0)."""
        if gray.ndim != 4 or gray.shape[0] != self.sensors or tuple(gray.shape[2:]) != tuple(self.image_size):
            raise InputError(None, f"{self.model_name} chunk_logits takes runs (S, N, h, w), got {tuple(gray.shape)}")
        return (torch.as_tensor(list(ends))[:, None] + torch.arange(1 - n, 1)[None]).clamp(min=0)

    def streaming_parts(self):
        raise ConfigError(
            f"{self.model_name} takes whole grasps: it streams itself (stream()) and has no frame/window parts"
        )

    def window_geometry(self, spec: Mapping[str, Any]) -> dict[str, Any]:
        return {"kind": "grasp", "frames": 1, "sensors": int(self.sensors), "gray_size": tuple(self.image_size)}


def window_geometry(model: nn.Module, info: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """What one pushed frame must look like for ``model``: ``{"kind", "frames", "image_size" | "markers"}``.

    ``frames`` and ``image_size`` come from the model where it fixes them (ViViT, STNet), else from
    the checkpoint's training clip spec (``info["data"]["clip_spec"]``), else (the size) from its
    sensor; a frame size stated nowhere is a ConfigError.
    """
    if not isinstance(model, SlipModel):
        raise ConfigError(f"{type(model).__name__} is not a slipsense model (subclass slipsense.models.base)")
    data = (info or {}).get("data")
    spec = dict((data.get("clip_spec") if isinstance(data, Mapping) else None) or {})
    sensor = (info or {}).get("sensor")
    if not spec.get("size") and isinstance(sensor, Mapping) and sensor.get("image_size"):
        spec["size"] = sensor["image_size"]  # no clip size stated: the frames of the sensor it was trained on
    return model.window_geometry(spec)


@dataclass(frozen=True)
class RecordingsShape:
    """What a training knows of its recordings before decoding them
    (:meth:`SlipModel.training_defaults`): the cameras per grasp (1: frame folders of one finger,
    or one camera per run; 2: both fingers), whether every grasp is labelled as a whole
    (slipped or held, cut from a stream: no camera start-up in it) and the frame rate of the sensor
    they are read as (the detector's clock; None: not known here)."""

    cameras: int
    per_grasp: bool
    fps: float | None = None


def setting_default(cls: type, key: str) -> Any:
    """The default of model class ``cls``'s keyword setting ``key`` (None where it has none)."""
    for klass in cls.__mro__:
        params = inspect.signature(klass.__init__).parameters
        if key in params:
            default = params[key].default
            return None if default is inspect.Parameter.empty else default
    return None


def settings_of(cls: type) -> set[str]:
    """Keyword settings a model class takes; a class forwarding ``**kwargs`` takes its parent's."""
    for klass in cls.__mro__:
        params = inspect.signature(klass.__init__).parameters
        if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
            return set(params) - {"self"}
    return set()


def register(name: str) -> Callable[[type], type]:
    """Class decorator: make ``build(name, **config)`` construct this class (a :class:`SlipModel`)."""

    def deco(cls: type) -> type:
        if not (isinstance(cls, type) and issubclass(cls, (VideoModel, MarkerModel, GraspModel))):
            raise TypeError(f"register({name!r}): {cls!r} must subclass VideoModel, MarkerModel or GraspModel")
        _REGISTRY[name] = cls
        cls.model_name = name
        return cls

    return deco


def registered() -> dict[str, type]:
    """``{name: class}`` of the models registered so far (see :func:`slipsense.models.available`)."""
    return dict(_REGISTRY)


def build_registered(name: str, **config: Any) -> SlipModel:
    """Build registered model ``name``; see :func:`slipsense.models.build`."""
    if name not in _REGISTRY:
        raise ConfigError(f"unknown model {name!r}; available: {', '.join(sorted(_REGISTRY))}")

    def walk(key, v):
        if isinstance(v, bool):
            return
        if isinstance(v, (int, float)) and abs(v) > MAX_SETTING and key not in ("lr", "eps"):
            raise ConfigError(f"model {name!r}: setting {key}={v!r} is beyond {MAX_SETTING:,}")
        if isinstance(v, (list, tuple)):
            for x in v:
                walk(key, x)

    for key, value in config.items():
        walk(key, value)
    cls = _REGISTRY[name]
    try:
        if torch.empty(0).device.type == "meta":  # already building without memory (checkpoint checks)
            return cls(**config)
        with torch.device("meta"):
            n = sum(p.numel() for p in cls(**config).parameters())
        if n > MAX_PARAMETERS:
            raise ConfigError(f"model {name!r}: {n:,} parameters is beyond {MAX_PARAMETERS:,}")
        return cls(**config)
    except (TypeError, ValueError) as exc:  # a setting of the wrong type: int("abc"), a number for a list
        raise ConfigError(f"model {name!r}: {exc}") from None


def check_video_values(x: Tensor) -> None:
    """Raise InputError unless the video tensor ``x`` is float and finite (shape checked by the model)."""
    if not x.dtype.is_floating_point:
        raise InputError(None, f"video must be a float tensor in [0, 1], got dtype {x.dtype}")
    if not bool(torch.isfinite(x).all()):
        raise InputError(None, "video contains NaN or infinite values")
