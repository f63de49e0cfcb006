"""Live slip detection: push one frame per sensor, get a slip probability once a window is full.

    >>> det = SlipDetector.from_checkpoint("models/motionnet-gelsight.safetensors", sensors=2)  # doctest: +SKIP
    >>> for left, right in camera_pairs:          # uint8 (H, W, 3) BGR images at 25 frames/s
    ...     reading = det.push(left, right)       # Reading(index, probability, per_sensor, alarm)

A model classifies a window of its ``frames`` (T) latest frames. The detector keeps that window
(a deque) and splits each network into two parts so that no work is repeated as the window slides:

* a **frame part**, run once on each new frame (all sensors in one batch), whose output stays valid
  for every window the frame will be part of;
* a **window part**, run on each push over the T cached frame outputs.

ViViT. With the paper's position embedding (``positions="slot"``) it belongs to a frame's *slot* in the window (0 = oldest), so the
spatial transformer's token of a frame changes as the frame slides back: a frame's
``encode_frames`` token cannot simply be cached. The frame part therefore encodes a new frame at
*every* slot at once: the patch embedding once (:meth:`ViViT.embed_patches`, nearly all of the
cost), then the spatial transformer on T copies of the patch tokens, each with its slot's position
embedding: ``(3, H, W) -> (T, dim)``. A frame sits in slot T-1 when it arrives, T-2 on the next
push, ..., so the window part reads the diagonal (frame ``i - T + 1 + s`` at slot ``s``) and runs
only :meth:`ViViT.classify_frames` (temporal transformer + head). Per push that is one patch
embedding, T spatial-transformer sequences and one temporal one; a full forward would embed T
frames. The numbers equal ``model(window)`` to float rounding (tests check < 1e-5).
A ViViT built with ``positions="factorised"`` (beyond the paper) gives each frame one spatial token
whatever its slot: its frame part runs the spatial transformer once per frame (the T rows of its
output are one row repeated, so the window part reads them the same way), and a push costs one frame
encoding plus the temporal transformer.

STNet / TemNet. The S codecs and the fusion layer act on each frame alone: that is the frame part
``(M, 3) -> (d_model,)``. The window part adds the frame embedding and runs the MSA blocks and the
head. (Those blocks mix all frames and stream all weights once per window: at the paper size they
are nearly all of the cost.)

3D ResNet-50. Convolutions over time, zero-padded at the window's edges: nothing carries from one
window to the next. The frame part is preprocessing only and the window part is the network.

Backends: ``"torch"`` runs the two parts as PyTorch modules; ``"onnx"`` exports them once
(:mod:`slipsense.export`, cached under ``<cache_root>/onnx``) and runs them on ONNX Runtime.
Heat maps (:meth:`SlipDetector.heatmap`) always use the PyTorch model.

:meth:`SlipDetector.replay` computes the same probabilities for whole recordings at once (frame
part over all frames in batches, then every window): what :mod:`slipsense.early_warning` uses.
"""

from __future__ import annotations

import collections
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import cv2
import numpy as np
import torch
from torch import nn

from slipsense.errors import ConfigError, InputError
from slipsense.models.base import SlipModel, window_geometry
from slipsense.resources import shipped_model
from slipsense.runners import OnnxRunner, TorchRunner, exported_parts, onnx_cache_dir
from slipsense.sensors.spec import GELSIGHT_MINI

#: Frame rate of the GelSight recordings (frames per second): converts frames to milliseconds.
FPS = GELSIGHT_MINI.fps
#: The shipped default detector (package data: :mod:`slipsense.resources`).
DEFAULT_CHECKPOINT = shipped_model()
#: Frames per batch when replaying a recording (bounds memory: 64 frames of 240 x 320 = 59 MB float).
REPLAY_CHUNK = 64
COMBINE = ("max", "mean")
BACKENDS = ("torch", "onnx")
DTYPES = ("float32", "int8")


def slip_probability(logits: np.ndarray) -> np.ndarray:
    """Softmax probability of class 1 (slip): ``(B, classes)`` logits -> ``(B,)`` float64."""
    z = np.asarray(logits, dtype=np.float64)
    z = z - z.max(axis=1, keepdims=True)
    e = np.exp(z)
    return e[:, 1] / e.sum(axis=1)


# ---------------------------------------------------------------------------------------------
# The detector
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Reading:
    """The detector's answer to one push.

    ``index``: 0-based frame number since the start (or :meth:`SlipDetector.reset`);
    ``probability``: combined slip probability in [0, 1], None until the window is full;
    ``per_sensor``: one probability per sensor (None until the window is full);
    ``alarm``: ``probability >= threshold`` (False while None).
    """

    index: int
    probability: float | None
    per_sensor: tuple[float, ...] | None
    alarm: bool


@dataclass
class Trace:
    """Probabilities of a whole replayed recording, frame by frame (what pushing every frame gives).

    ``probability``: ``(N,)`` combined, NaN for the first ``frames - 1`` frames (window not full);
    ``per_sensor``: ``(N, S)``; ``threshold`` the detector's.
    """

    probability: np.ndarray
    per_sensor: np.ndarray
    threshold: float
    debounce: int = 1

    @property
    def alarm(self) -> np.ndarray:
        """``(N,)`` bool: probability >= threshold for ``debounce`` frames in a row (NaN: no answer yet)."""
        from slipsense.pergrasp import debounce

        return debounce(self.probability, self.threshold, self.debounce)


def alarm_at(probability: np.ndarray, threshold: float) -> np.ndarray:
    """``(N,)`` bool alarm state of a probability trace at ``threshold``; NaN counts as no alarm."""
    p = np.asarray(probability, dtype=np.float64)
    return np.nan_to_num(p, nan=-1.0) >= threshold


def combine_probabilities(per_sensor: np.ndarray, combine: str) -> np.ndarray:
    """``(..., S)`` -> ``(...)``: the largest (``"max"``) or the mean (``"mean"``) over sensors."""
    if combine == "max":
        return per_sensor.max(axis=-1)
    if combine == "mean":
        return per_sensor.mean(axis=-1)
    raise ConfigError(f"combine must be one of {COMBINE}, got {combine!r}")


class SlipDetector:
    """Streaming slip detector over any slipsense checkpoint (ViViT, 3D ResNet-50, STNet, TemNet).

    Args:
        model: a slipsense model (eval mode is set here).
        threshold: alarm when the combined probability is >= this, in [0, 1].
        sensors: frames per push (1, or 2 for both fingers); default: what a grasp model was
            trained on (both fingers for the shipped detector), else 1.
        combine: ``"max"`` (default: alarm when either sensor sees slip) or ``"mean"``.
        backend: ``"torch"`` or ``"onnx"`` (ONNX Runtime; the parts are exported on first use).
        dtype: ``"float32"`` (default) or, with ``backend="onnx"``, ``"int8"``: the exported parts'
            matrix products dynamically quantized to int8 weights (``onnxruntime.quantization``).
            A quarter of the weight bytes: what makes the paper-size STNet fast on a CPU, at the cost
            of probabilities that differ slightly from the float model's.
        info: the checkpoint's config (window length / frame size of models that do not fix them).
        onnx_dir: where the ONNX parts are written for ``backend="onnx"`` (default: a temporary folder).
            Parts already there are reused, so give each model its own folder.

    Attributes: ``frames`` (window length T), ``kind`` (``"video"`` or ``"markers"``),
    ``image_size`` ``(H, W)`` (video) or ``markers`` M (markers).
    """

    def __init__(
        self,
        model: nn.Module,
        *,
        threshold: float = 0.5,
        sensors: int | None = None,
        combine: str = "max",
        backend: str = "torch",
        info: Mapping[str, Any] | None = None,
        onnx_dir: str | Path | None = None,
        dtype: str = "float32",
        debounce: int = 1,
    ):
        if sensors is None:
            sensors = getattr(model, "sensors", 1) if getattr(model, "input_kind", None) == "grasp" else 1
        _check_settings(threshold, sensors, combine, backend, dtype)
        if isinstance(debounce, bool) or not isinstance(debounce, (int, np.integer)) or not 1 <= debounce <= 1000:
            raise ConfigError(f"debounce must be a whole number of frames in 1..1000, got {debounce!r}")
        self.dtype = dtype
        self.model = model.eval()
        if not isinstance(model, SlipModel):
            raise ConfigError(f"{type(model).__name__} is not a slipsense model (see slipsense.models.base)")
        self.model_name = model.model_name
        self.threshold, self.sensors, self.combine, self.backend = float(threshold), int(sensors), combine, backend
        self.debounce = int(debounce)
        self._tmpdir = None
        if model.input_kind == "grasp":  # the model streams itself over all sensors at once
            self._init_grasp(model, info)
            return
        geo = window_geometry(model, info)
        self.kind: str = geo["kind"]
        self.frames: int = geo["frames"]
        self.image_size: tuple[int, int] | None = geo.get("image_size")
        self.markers: int | None = geo.get("markers")
        parts = model.streaming_parts()
        self._slot_tokens = model.slot_tokens
        if backend == "torch":
            self._runner = TorchRunner(*parts)
        else:
            if onnx_dir is None:
                self._tmpdir = tempfile.TemporaryDirectory(prefix="slipsense-onnx-")
                onnx_dir = self._tmpdir.name
            self._runner = OnnxRunner(*exported_parts(model, self.geometry, Path(onnx_dir), dtype))
        self._has_frame_part = parts[0] is not None
        self.reset()

    @classmethod
    def from_checkpoint(
        cls,
        path: str | Path,
        threshold: float | None = None,
        sensors: int | None = None,
        combine: str = "max",
        backend: str = "torch",
        onnx_dir: str | Path | None = None,
        dtype: str = "float32",
        debounce: int | None = None,
    ) -> "SlipDetector":
        """Load a checkpoint (:func:`slipsense.checkpoint.load_model`) into a detector.

        ``threshold`` / ``debounce`` default to the operating point stored in the checkpoint (chosen
        on its training objects only); a checkpoint without one gets 0.5 / 1 and a warning.

        With ``backend="onnx"`` the ONNX parts are cached under ``onnx_dir`` (default
        ``<cache_root>/onnx/<hash of the checkpoint file>``), so only the first use pays the export.
        """
        from slipsense.checkpoint import load_model

        model, info = load_model(path)
        threshold, debounce = stored_operating_point(path, info, threshold, debounce)
        _check_settings(threshold, 1 if sensors is None else sensors, combine, backend, dtype)
        if backend == "onnx" and onnx_dir is None:
            onnx_dir = onnx_cache_dir(Path(path))
        return cls(
            model,
            threshold=threshold,
            sensors=sensors,
            combine=combine,
            backend=backend,
            info=info,
            onnx_dir=onnx_dir,
            dtype=dtype,
            debounce=debounce,
        )

    @classmethod
    def pretrained(cls, name: str = "motionnet-gelsight", **kwargs: Any) -> "SlipDetector":
        """A shipped detector (:func:`slipsense.resources.shipped_models`): ``"motionnet-gelsight"``
        (default, both sensors: pass ``sensors=2``) or ``"vivit-gelsight"`` (the paper's ViViT);
        ``kwargs`` as :meth:`from_checkpoint`."""
        from slipsense.resources import shipped_models

        if name not in shipped_models():
            raise ConfigError(f"no shipped detector {name!r}; shipped: {', '.join(shipped_models())}")
        return cls.from_checkpoint(shipped_model(name), **kwargs)

    def _init_grasp(self, model: nn.Module, info: Mapping[str, Any] | None) -> None:
        from slipsense.pergrasp import STARTUP

        if self.backend != "torch" or self.dtype != "float32":
            raise ConfigError(
                f"{self.model_name} streams on PyTorch in float32 (backend='torch'): it needs "
                f"no more to stay under 2 ms per push"
            )
        if self.sensors != model.sensors:
            raise ConfigError(
                f"{self.model_name} was trained on {model.sensors} sensor(s) seen together; "
                f"the detector was given sensors={self.sensors}"
            )
        self.kind, self.frames = "grasp", 1
        self.image_size, self.markers = None, None
        self.gray_size: tuple[int, int] = tuple(model.image_size)
        self.startup = int(((info or {}).get("operating_point") or {}).get("startup", STARTUP))
        self._stream = model.stream()
        self._has_frame_part = False
        self.reset()

    @property
    def geometry(self) -> dict[str, Any]:
        if self.kind == "grasp":
            return {"kind": "grasp", "frames": 1, "gray_size": self.gray_size, "startup": self.startup}
        g = {"kind": self.kind, "frames": self.frames}
        g.update({"image_size": self.image_size} if self.kind == "video" else {"markers": self.markers})
        return g

    def reset(self) -> None:
        """Forget the window and restart frame numbering at 0."""
        self._index = 0
        self._above = 0  # consecutive pushes at or above the threshold (debounce)
        self._shapes: dict[int, tuple[int, ...]] = {}  # image shape per sensor, fixed by the first push
        if self.kind == "grasp":
            self._stream.reset()
        self._cache: collections.deque[np.ndarray] = collections.deque(
            maxlen=self.frames
        )  # frame-part outputs (S, ...)
        self._inputs: collections.deque[np.ndarray] = collections.deque(maxlen=self.frames)  # model inputs (S, ...)

    @property
    def window_full(self) -> bool:
        if self.kind == "grasp":
            return self._index > self.startup
        return len(self._cache) == self.frames

    def _reading(self, index: int, per_sensor: np.ndarray, p: float) -> Reading:
        # NaN must never read as "safe": a model answer that is not a number raises the alarm
        above = not (p < self.threshold)
        self._above = self._above + 1 if above else 0
        return Reading(index, p, tuple(float(v) for v in per_sensor), self._above >= self.debounce)

    def _push_grasp(self, frames: Sequence[Any]) -> Reading:
        from slipsense.recordings.runs import gray_frames

        index = self._index
        gray = np.empty((self.sensors, *self.gray_size), dtype=np.uint8)
        for s, f in enumerate(frames):
            image = _check_image(f, f"frame {index}, sensor {s}", None)
            if self._shapes.setdefault(s, image.shape) != image.shape:
                raise InputError(
                    None,
                    f"frame {index}, sensor {s}: image is {image.shape[1]}x{image.shape[0]}, "
                    f"the earlier frames of this sensor were {self._shapes[s][1]}x"
                    f"{self._shapes[s][0]} (call reset() to start a new stream)",
                )
            gray[s] = gray_frames(image, self.gray_size)
        self._index += 1
        if index < self.startup:  # the camera's start-up transient is not the scene
            return Reading(index, None, None, False)
        p = self._stream.push(gray)
        return self._reading(index, np.full(self.sensors, p), p)

    # pushing frames

    def push(self, *frames: np.ndarray) -> Reading:
        """Add one frame per sensor and classify the window ending with them.

        Video models take uint8 ``(H, W, 3)`` BGR images (resized to ``image_size`` when their size
        differs); marker models take float ``(M, 3)`` marker positions in mm. Raises
        :class:`InputError` (naming the frame and sensor) for a wrong count, type, shape, dtype or
        a non-finite value; the window is left unchanged then.
        """
        if len(frames) != self.sensors:
            raise InputError(
                None, f"frame {self._index}: push takes {self.sensors} frame(s), one per sensor, got {len(frames)}"
            )
        if self.kind == "grasp":
            return self._push_grasp(frames)
        if self.kind == "video":  # converted straight into the batch: no per-sensor copies
            x = np.empty((self.sensors, 3, *self.image_size), dtype=np.float32)
            for s, f in enumerate(frames):
                self._prepare(f, s, self._index, out=x[s])
        else:
            x = np.stack([self._prepare(f, s, self._index) for s, f in enumerate(frames)])  # (S, M, 3) float32
        index = self._index
        self._cache.append(self._runner.frame(x) if self._has_frame_part else x)
        self._inputs.append(x)
        self._index += 1
        if not self.window_full:
            return Reading(index, None, None, False)
        per_sensor = slip_probability(self._runner.window(self._window()))
        p = float(combine_probabilities(per_sensor, self.combine))
        return self._reading(index, per_sensor, p)

    def _window(self) -> np.ndarray:
        """The window part's input from the cache: ``(S, T, ...)``."""
        if self._slot_tokens:
            # frame k of the window (k = 0 oldest) sits in slot k: its token row k
            return np.stack([tokens[:, k] for k, tokens in enumerate(self._cache)], axis=1)
        return np.stack(self._cache, axis=1)

    def _prepare(self, frame: Any, sensor: int, index: int, out: np.ndarray | None = None) -> np.ndarray:
        """Check one frame and turn it into the model's per-frame input (float32); a video frame is
        written into ``out`` (``(3, H, W)``) when given."""
        where = f"frame {index}, sensor {sensor}"
        if self.kind == "video":
            return _video_input(_check_image(frame, where, self.image_size), out=out)
        return _check_cloud(frame, where, self.markers)

    # replay of whole recordings

    def replay(self, *streams: np.ndarray) -> Trace:
        """Probabilities for whole recordings at once: the numbers pushing every frame would give.

        Args:
            streams: one per sensor, all N frames long: uint8 ``(N, H, W, 3)`` BGR videos (video
                models) or float ``(N, M, 3)`` marker clouds (marker models).

        Returns:
            :class:`Trace`. Does not touch the streaming window.
        """
        if len(streams) != self.sensors:
            raise InputError(None, f"replay takes {self.sensors} stream(s), one per sensor, got {len(streams)}")
        streams = [self._check_stream(s, i) for i, s in enumerate(streams)]
        n = len(streams[0])
        if any(len(s) != n for s in streams):
            raise InputError(None, f"replay streams differ in length: {[len(s) for s in streams]}")
        if self.kind == "grasp":
            return self._replay_grasp(streams)
        t, s_count = self.frames, self.sensors
        per_sensor = np.full((n, s_count), np.nan)
        if n >= t:
            feats = self._replay_features(streams)  # (S, N, ...)
            starts = np.arange(n - t + 1)
            probs = []
            # a 3D ResNet's windows are raw frames (T x 3 x H x W floats each): fewer per batch
            chunk = REPLAY_CHUNK if self._has_frame_part else max(1, REPLAY_CHUNK // (4 * t))
            for a in range(0, len(starts), chunk):
                rows = starts[a : a + chunk, None] + np.arange(t)[None]  # (W, T) frame indices
                if self._slot_tokens:
                    win = feats[:, rows, np.arange(t)[None]]  # (S, W, T, dim): frame rows[w, k] at slot k
                else:
                    win = feats[:, rows]  # (S, W, T, ...)
                if not self._has_frame_part:
                    win = win.astype(np.float32) / 255.0  # uint8 (S, W, T, H, W, 3) -> model layout
                    win = np.ascontiguousarray(win.transpose(0, 1, 2, 5, 3, 4))
                w = win.shape[1]
                logits = self._runner.window(np.ascontiguousarray(win.reshape(s_count * w, *win.shape[2:])))
                probs.append(slip_probability(logits).reshape(s_count, w))
            per_sensor[t - 1 :] = np.concatenate(probs, axis=1).T
        combined = combine_probabilities(per_sensor, self.combine)
        return Trace(combined, per_sensor, self.threshold, self.debounce)

    def _replay_grasp(self, streams: list[np.ndarray]) -> Trace:
        from slipsense.recordings.runs import gray_frames

        return self.replay_gray(np.stack([gray_frames(s, self.gray_size) for s in streams]))

    def replay_gray(self, gray: np.ndarray) -> Trace:
        """:meth:`replay` of a grasp model from grey frames already at its size: uint8 ``(S, N, h,
        w)`` (:func:`slipsense.recordings.runs.gray_frames`, as the frame cache keeps them)."""
        if self.kind != "grasp":
            raise ConfigError(f"{self.model_name} does not read grey frames: use replay()")
        if (
            gray.dtype != np.uint8
            or gray.ndim != 4
            or gray.shape[0] != self.sensors
            or gray.shape[2:] != self.gray_size
        ):
            raise InputError(
                None,
                f"replay_gray takes uint8 (S={self.sensors}, N, {self.gray_size[0]}, {self.gray_size[1]}), got {gray.dtype} {gray.shape}",
            )
        n = gray.shape[1]
        p = np.full(n, np.nan)
        if n > self.startup:
            with torch.no_grad():
                x = torch.from_numpy(np.ascontiguousarray(gray[None, :, self.startup :])).float().div_(255.0)
                logits = self.model(x)[0]
            p[self.startup :] = torch.softmax(logits, dim=-1)[:, 1].double().numpy()
        return Trace(p, np.repeat(p[:, None], self.sensors, axis=1), self.threshold, self.debounce)

    def _check_stream(self, stream: Any, sensor: int) -> np.ndarray:
        where = f"sensor {sensor}"
        if not isinstance(stream, np.ndarray):
            raise InputError(None, f"{where}: replay takes numpy arrays, got {type(stream).__name__}")
        if self.kind in ("video", "grasp"):
            if stream.dtype != np.uint8 or stream.ndim != 4 or stream.shape[-1] != 3:
                raise InputError(
                    None, f"{where}: expected a uint8 (N, H, W, 3) BGR video, got {stream.dtype} {stream.shape}"
                )
            return stream
        if stream.ndim != 3 or stream.shape[1:] != (self.markers, 3):
            raise InputError(None, f"{where}: expected marker clouds (N, {self.markers}, 3), got {stream.shape}")
        if not (np.issubdtype(stream.dtype, np.floating) or np.issubdtype(stream.dtype, np.integer)):
            raise InputError(None, f"{where}: expected float marker positions (mm), got dtype {stream.dtype}")
        if not np.isfinite(stream).all():
            i = int(np.argwhere(~np.isfinite(stream))[0][0])
            _check_cloud(stream[i], f"frame {i}, {where}", self.markers)  # raises, naming the marker
        return stream.astype(np.float32, copy=False)

    def _replay_features(self, streams: list[np.ndarray]) -> np.ndarray:
        """Frame-part outputs of every frame of every stream, ``(S, N, ...)`` (uint8 frames for a 3D ResNet)."""
        out = []
        for stream in streams:
            chunks = []
            for a in range(0, len(stream), REPLAY_CHUNK):
                part = stream[a : a + REPLAY_CHUNK]
                if self.kind == "video":
                    part = np.stack([_resize(f, self.image_size) for f in part])
                    if self._has_frame_part:
                        part = _video_input(part)
                chunks.append(self._runner.frame(np.ascontiguousarray(part)) if self._has_frame_part else part)
            out.append(np.concatenate(chunks))
        return np.stack(out)

    # heat maps

    def heatmap(self, sensor: int = 0) -> np.ndarray | None:
        """Where the model looks in the latest window of ``sensor`` (None until the window is full).

        ViViT: attention rollout of the latest frame (:meth:`ViViT.cls_attention_map`),
        ``(Hp, Wp)`` on the patch grid, sums to 1. STNet/TemNet: marker saliency
        (:meth:`STNet.marker_saliency`) ``(M,)``, max 1. 3D ResNet and grasp models: None (no
        attention to show).
        """
        if self.kind == "grasp" or not self.window_full or not 0 <= sensor < self.sensors:
            return None
        window = torch.from_numpy(np.stack([x[sensor] for x in self._inputs])[None])  # (1, T, ...)
        return self.model.attention(window)

    def close(self) -> None:
        if self._tmpdir is not None:
            self._tmpdir.cleanup()
            self._tmpdir = None


def stored_operating_point(
    path: str | Path, info: Mapping[str, Any], threshold: float | None, debounce: int | None
) -> tuple[float, int]:
    """The threshold and debounce to use: the caller's where given, else the checkpoint's operating
    point, else 0.5 / 1 with a warning naming the checkpoint."""
    import warnings

    op = info.get("operating_point") if isinstance(info, Mapping) else None
    if threshold is None:
        if isinstance(op, Mapping) and isinstance(op.get("threshold"), (int, float)):
            threshold = float(op["threshold"])
        else:
            warnings.warn(
                f"{path}: checkpoint stores no alarm threshold; using 0.5 (pass a threshold to choose)", stacklevel=3
            )
            threshold = 0.5
    if debounce is None:
        k = op.get("debounce", 1) if isinstance(op, Mapping) else 1
        debounce = int(k) if isinstance(k, int) and not isinstance(k, bool) else 1
    return threshold, debounce


def _check_settings(threshold: Any, sensors: Any, combine: str, backend: str, dtype: str = "float32") -> None:
    try:
        ok = 0.0 <= float(threshold) <= 1.0
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ConfigError(f"threshold must be a number in [0, 1], got {threshold!r}")
    if isinstance(sensors, bool) or not isinstance(sensors, (int, np.integer)) or sensors < 1:
        raise ConfigError(f"sensors must be a positive integer, got {sensors!r}")
    if combine not in COMBINE:
        raise ConfigError(f"combine must be one of {COMBINE}, got {combine!r}")
    if backend not in BACKENDS:
        raise ConfigError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if dtype not in DTYPES:
        raise ConfigError(f"dtype must be one of {DTYPES}, got {dtype!r}")
    if dtype == "int8" and backend != "onnx":
        raise ConfigError("dtype 'int8' needs backend 'onnx' (ONNX Runtime dynamic quantization)")


def _check_image(frame: Any, where: str, size: tuple[int, int]) -> np.ndarray:
    """A uint8 (H, W, 3) BGR image resized to ``size``, or InputError."""
    if not isinstance(frame, np.ndarray):
        raise InputError(
            None, f"{where}: expected a uint8 (H, W, 3) BGR image as a numpy array, got {type(frame).__name__}"
        )
    if frame.dtype != np.uint8:
        raise InputError(None, f"{where}: expected a uint8 (H, W, 3) BGR image, got dtype {frame.dtype}")
    if frame.ndim != 3 or frame.shape[2] != 3 or min(frame.shape[:2]) < 1:
        raise InputError(None, f"{where}: expected a (H, W, 3) BGR image, got shape {frame.shape}")
    return _resize(frame, size)


def _resize(frame: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize like the training clips do (area filter when shrinking, bilinear when enlarging);
    ``size`` None keeps the frame as it is."""
    if size is None:
        return frame
    h, w = size
    if frame.shape[:2] == (h, w):
        return frame
    shrink = frame.shape[0] >= h and frame.shape[1] >= w
    return cv2.resize(np.ascontiguousarray(frame), (w, h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


def _video_input(frames: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """uint8 ``(..., H, W, 3)`` BGR -> float32 ``(..., 3, H, W)`` in [0, 1] (as ``datasets.clip_to_tensor``,
    bit for bit), written into ``out`` when given. One pass over the frame: it sits on the live path."""
    if out is None:
        out = np.empty((*frames.shape[:-3], 3, *frames.shape[-3:-1]), dtype=np.float32)
    return np.divide(np.moveaxis(frames, -1, -3), np.float32(255.0), out=out, dtype=np.float32)


def _check_cloud(cloud: Any, where: str, markers: int) -> np.ndarray:
    """A finite float32 (M, 3) marker cloud, or InputError."""
    if not isinstance(cloud, np.ndarray):
        raise InputError(
            None, f"{where}: expected a float (M, 3) marker cloud as a numpy array, got {type(cloud).__name__}"
        )
    if not (np.issubdtype(cloud.dtype, np.floating) or np.issubdtype(cloud.dtype, np.integer)):
        raise InputError(None, f"{where}: expected float marker positions (mm), got dtype {cloud.dtype}")
    if cloud.shape != (markers, 3):
        raise InputError(None, f"{where}: expected a marker cloud of shape ({markers}, 3), got {cloud.shape}")
    finite = np.isfinite(cloud)
    if not finite.all():
        m = int(np.argwhere(~finite)[0][0])
        raise InputError(None, f"{where}: marker {m} has a non-finite position {cloud[m].tolist()}")
    return cloud.astype(np.float32, copy=False)


__all__ = [
    "DEFAULT_CHECKPOINT",
    "FPS",
    "Reading",
    "SlipDetector",
    "Trace",
    "alarm_at",
    "combine_probabilities",
    "onnx_cache_dir",
    "slip_probability",
    "stored_operating_point",
    "window_geometry",
]
