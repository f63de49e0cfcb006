"""The stream of a clip model: a sliding window over cached frame-part outputs.

A clip model classifies a window of its ``frames`` (T) latest frames. The stream keeps that window
(a deque) and runs the network as two parts (:meth:`SlipModel.streaming_parts`) so that no work is
repeated as the window slides:

* a **frame part**, run once on each new frame (all sensors in one batch), whose output stays valid
  for every window the frame will be part of;
* a **window part**, run on each push over the T cached frame outputs.

A model with :attr:`SlipModel.slot_tokens` (ViViT's slot position embedding) encodes a new frame at
*every* window slot at once, ``(T, dim)``; it sits in slot T-1 when it arrives, T-2 on the next push,
..., so the window reads the diagonal (frame ``i - T + 1 + s`` at slot ``s``). A model with no frame
part (the 3D ResNet-50: nothing carries from one window to the next) gets the raw window.
"""

from __future__ import annotations

import collections
from typing import Any, Mapping, Sequence

import numpy as np
import torch

from slipsense.errors import InputError
from slipsense.models.runners import make_runner
from slipsense.recordings.video import resize

#: Frames per batch when replaying a recording (bounds memory: 64 frames of 240 x 320 = 59 MB float).
REPLAY_CHUNK = 64


def slip_probability(logits: np.ndarray) -> np.ndarray:
    """Softmax probability of class 1 (slip): ``(B, classes)`` logits -> ``(B,)`` float64."""
    z = np.asarray(logits, dtype=np.float64)
    z = z - z.max(axis=1, keepdims=True)
    e = np.exp(z)
    return e[:, 1] / e.sum(axis=1)


class StreamBase:
    """What every stream shares: the geometry it describes and the runner's temporary folder."""

    def describe(self) -> dict[str, Any]:
        return dict(self.geometry)

    def close(self) -> None:
        if self.tmpdir is not None:
            self.tmpdir.cleanup()
            self.tmpdir = None


class WindowStream(StreamBase):
    """The :class:`~slipsense.models.base.Stream` of a clip model (video or marker windows): each
    sensor's window is judged apart, so it answers per sensor."""

    per_sensor = True

    def __init__(
        self, model, geometry: Mapping[str, Any], *, sensors=1, backend="torch", dtype="float32", onnx_dir=None
    ):
        self.model, self.sensors = model.eval(), int(sensors)
        self.has_attention = model.attention_map is not None
        self.geometry = dict(geometry)
        self.kind: str = self.geometry["kind"]
        self.frames: int = self.geometry["frames"]
        self.image_size: tuple[int, int] | None = self.geometry.get("image_size")
        self.markers: int | None = self.geometry.get("markers")
        self._slot_tokens = model.slot_tokens
        self._has_frame_part = model.streaming_parts()[0] is not None
        self._run, self.tmpdir = make_runner(model, self.geometry, backend, dtype, onnx_dir)
        self.reset()

    def reset(self) -> None:
        self._cache: collections.deque[np.ndarray] = collections.deque(maxlen=self.frames)  # frame-part outputs
        self._inputs: collections.deque[np.ndarray] = collections.deque(maxlen=self.frames)  # inputs (S, ...)

    @property
    def ready(self) -> bool:
        return len(self._cache) == self.frames

    def push(self, frames: Sequence[Any], index: int) -> np.ndarray | None:
        if self.kind == "video":  # converted straight into the batch: no per-sensor copies
            x = np.empty((self.sensors, 3, *self.image_size), dtype=np.float32)
            for s, f in enumerate(frames):
                video_input(check_image(f, f"frame {index}, sensor {s}", self.image_size), out=x[s])
        else:
            x = np.stack([check_cloud(f, f"frame {index}, sensor {s}", self.markers) for s, f in enumerate(frames)])
        self._cache.append(self._run("frame", x)[0] if self._has_frame_part else x)
        self._inputs.append(x)
        if not self.ready:
            return None
        if self._slot_tokens:  # frame k of the window (k = 0 oldest) sits in slot k: its token row k
            window = np.stack([tokens[:, k] for k, tokens in enumerate(self._cache)], axis=1)
        else:
            window = np.stack(self._cache, axis=1)  # (S, T, ...)
        return slip_probability(self._run("window", window)[0])

    def replay(self, streams: Sequence[np.ndarray]) -> np.ndarray:
        streams = [self._check_stream(s, i) for i, s in enumerate(streams)]
        n, t, s_count = len(streams[0]), self.frames, self.sensors
        per_sensor = np.full((n, s_count), np.nan)
        if n < t:
            return per_sensor
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
            if not self._has_frame_part and self.kind == "video":
                win = win.astype(np.float32) / 255.0  # uint8 (S, W, T, H, W, 3) -> model layout
                win = np.ascontiguousarray(win.transpose(0, 1, 2, 5, 3, 4))
            w = win.shape[1]
            logits = self._run("window", np.ascontiguousarray(win.reshape(s_count * w, *win.shape[2:])))[0]
            probs.append(slip_probability(logits).reshape(s_count, w))
        per_sensor[t - 1 :] = np.concatenate(probs, axis=1).T
        return per_sensor

    @property
    def cache_product(self) -> str | None:
        """What of a recording a marker model is replayed from, as the frame cache names it: each
        camera's tracked markers in the layout its checkpoint records (``"markers:7x9"``, ``"markers:32"``:
        :func:`slipsense.recordings.markers.marker_clouds`, the values its real training windows hold).
        None for a video model (the decoded video) and for a marker model that records no layout
        (simulated, or a user's marker file: nothing says how to take its markers from a video)."""
        layout = self.geometry.get("marker_layout")
        return f"markers:{layout}" if layout else None

    def replay_cached(self, clouds: np.ndarray) -> np.ndarray:
        """:meth:`replay` from :attr:`cache_product` of every sensor, stacked: float ``(S, N, M, 3)``."""
        return self.replay(list(clouds))

    def _check_stream(self, stream: Any, sensor: int) -> np.ndarray:
        where = f"sensor {sensor}"
        if not isinstance(stream, np.ndarray):
            raise InputError(None, f"{where}: replay takes numpy arrays, got {type(stream).__name__}")
        if self.kind == "video":
            return check_video_stream(stream, where)
        if stream.ndim != 3 or stream.shape[1:] != (self.markers, 3):
            raise InputError(None, f"{where}: expected marker clouds (N, {self.markers}, 3), got {stream.shape}")
        if not (np.issubdtype(stream.dtype, np.floating) or np.issubdtype(stream.dtype, np.integer)):
            raise InputError(None, f"{where}: expected float marker positions (mm), got dtype {stream.dtype}")
        if not np.isfinite(stream).all():
            i = int(np.argwhere(~np.isfinite(stream))[0][0])
            check_cloud(stream[i], f"frame {i}, {where}", self.markers)  # raises, naming the marker
        return stream.astype(np.float32, copy=False)

    def _replay_features(self, streams: list[np.ndarray]) -> np.ndarray:
        """Frame-part outputs of every frame of every stream, ``(S, N, ...)`` (uint8 frames for a 3D ResNet)."""
        out = []
        for stream in streams:
            chunks = []
            for a in range(0, len(stream), REPLAY_CHUNK):
                part = stream[a : a + REPLAY_CHUNK]
                if self.kind == "video":
                    part = np.stack([resize(f, self.image_size) for f in part])
                    if self._has_frame_part:
                        part = video_input(part)
                part = np.ascontiguousarray(part)
                chunks.append(self._run("frame", part)[0] if self._has_frame_part else part)
            out.append(np.concatenate(chunks))
        return np.stack(out)

    def attention(self, sensor: int) -> np.ndarray | None:
        if not self.ready:
            return None
        window = torch.from_numpy(np.stack([x[sensor] for x in self._inputs])[None])  # (1, T, ...)
        return self.model.attention(window)


def check_video_stream(stream: np.ndarray, where: str) -> np.ndarray:
    """A whole recording as uint8 ``(N, H, W, 3)`` BGR, or InputError."""
    if stream.dtype != np.uint8 or stream.ndim != 4 or stream.shape[-1] != 3:
        raise InputError(None, f"{where}: expected a uint8 (N, H, W, 3) BGR video, got {stream.dtype} {stream.shape}")
    return stream


def check_image(frame: Any, where: str, size: tuple[int, int] | None) -> np.ndarray:
    """A uint8 (H, W, 3) BGR image resized to ``size``, or InputError."""
    if not isinstance(frame, np.ndarray):
        raise InputError(
            None, f"{where}: expected a uint8 (H, W, 3) BGR image as a numpy array, got {type(frame).__name__}"
        )
    if frame.dtype != np.uint8:
        raise InputError(None, f"{where}: expected a uint8 (H, W, 3) BGR image, got dtype {frame.dtype}")
    if frame.ndim != 3 or frame.shape[2] != 3 or min(frame.shape[:2]) < 1:
        raise InputError(None, f"{where}: expected a (H, W, 3) BGR image, got shape {frame.shape}")
    return resize(frame, size)


def video_input(frames: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """uint8 ``(..., H, W, 3)`` BGR -> float32 ``(..., 3, H, W)`` in [0, 1] (as ``datasets.clip_to_tensor``,
    bit for bit), written into ``out`` when given. One pass over the frame: it sits on the live path."""
    if out is None:
        out = np.empty((*frames.shape[:-3], 3, *frames.shape[-3:-1]), dtype=np.float32)
    return np.divide(np.moveaxis(frames, -1, -3), np.float32(255.0), out=out, dtype=np.float32)


def check_cloud(cloud: Any, where: str, markers: int) -> np.ndarray:
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
