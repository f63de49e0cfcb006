"""The stream of a grasp model: push one frame per sensor, get the slip probability of that frame.

A grasp model (:class:`slipsense.models.base.GraspModel`) sees every frame from the start of the grasp,
so its stream keeps the model's own state from push to push instead of a window. What every grasp
stream shares lives here; a model's stream adds :meth:`GraspStream.reset` (its state) and
:meth:`GraspStream.push_gray` (one frame through its parts).
"""

from __future__ import annotations

import numpy as np
import torch

from slipsense.errors import ConfigError, InputError
from slipsense.models.runners import make_runner
from slipsense.models.streams import StreamBase, check_image, check_video_stream
from slipsense.sensors.spec import sensor_of
from slipsense.measures.registry import startup_frames
from slipsense.recordings.video import gray_frames


class GraspStream(StreamBase):
    """``sensors``: frames per push; the model fuses any number of sensors symmetrically, but was
    trained on ``model.sensors`` and is refused others. The first ``startup`` frames (the camera's
    start-up transient, from the checkpoint's operating point) get no answer. The model's parts run on
    PyTorch or, exported to ONNX, on ONNX Runtime (``backend``). The sensors are fused inside the
    model: one answer for all (``(1,)`` a push), no per-sensor probability, no heat map."""

    per_sensor = False
    has_attention = False

    def __init__(self, model, *, sensors=None, info=None, backend="torch", dtype="float32", onnx_dir=None):
        self.model = model.eval()
        self.sensors = model.sensors if sensors is None else int(sensors)
        if self.sensors != model.sensors:
            one = " (the shipped one-finger detector: SlipDetector.pretrained('motionnet-gelsight-1'))"
            hint = one if self.sensors == 1 else ""
            raise ConfigError(
                f"{model.model_name} was trained on {model.sensors} sensor(s) seen together; "
                f"the detector was given sensors={self.sensors}{hint}"
            )
        if dtype != "float32":
            raise ConfigError(f"{model.model_name} streams in float32 only")
        self.gray_size = tuple(model.image_size)
        stated = ((info or {}).get("operating_point") or {}).get("startup")
        # a checkpoint that states no start-up skips its sensor's start-up time, counted at its rate
        self.startup = int(stated) if stated is not None else startup_frames(sensor_of(info).fps)
        self.geometry = {**model.window_geometry({}), "startup": self.startup}
        self._run, self.tmpdir = make_runner(model, self.geometry, backend, dtype, onnx_dir)
        self.reset()

    def reset(self) -> None:
        """Forget the grasp: the next frame pushed is its first."""
        self._shapes: dict[int, tuple] = {}
        self._pushed = 0

    @property
    def ready(self) -> bool:
        return self._pushed > self.startup

    def push_gray(self, gray: np.ndarray) -> float:
        """``gray``: uint8 ``(S, h, w)``, one frame per sensor at the model's size. Returns P(slip)."""
        raise NotImplementedError

    def push(self, frames, index: int):
        gray = np.empty((self.sensors, *self.gray_size), dtype=np.uint8)
        images = [check_image(f, f"frame {index}, sensor {s}", None) for s, f in enumerate(frames)]
        for s, image in enumerate(images):  # every frame checked before the stream remembers any size
            known = self._shapes.get(s, image.shape)
            if known != image.shape:
                raise InputError(
                    None,
                    f"frame {index}, sensor {s}: image is {image.shape[1]}x{image.shape[0]}, "
                    f"the earlier frames of this sensor were {known[1]}x{known[0]} (call reset() to start a new stream)",
                )
        for s, image in enumerate(images):
            self._shapes[s] = image.shape
            gray[s] = gray_frames(image, self.gray_size)
        self._pushed += 1
        if self._pushed <= self.startup:  # the camera's start-up transient is not the scene
            return None
        return np.array([self.push_gray(gray)])

    def replay(self, streams) -> np.ndarray:
        streams = [check_video_stream(s, f"sensor {i}") for i, s in enumerate(streams)]
        return self.replay_gray(np.stack([gray_frames(s, self.gray_size) for s in streams]))

    @property
    def cache_product(self) -> str:
        """The frame cache's name of what :meth:`replay_cached` takes."""
        return f"gray:{self.gray_size[0]}x{self.gray_size[1]}"

    def replay_cached(self, gray: np.ndarray) -> np.ndarray:
        return self.replay_gray(gray)

    def replay_gray(self, gray: np.ndarray) -> np.ndarray:
        """:meth:`replay` from grey frames already at the model's size: uint8 ``(S, N, h, w)``
        (:func:`slipsense.recordings.runs.gray_frames`, as the frame cache keeps them) -> ``(N, 1)``,
        the fused answer.
        Runs the whole-run forward on PyTorch (the same numbers as pushing, faster)."""
        if (
            gray.dtype != np.uint8
            or gray.ndim != 4
            or gray.shape[0] != self.sensors
            or gray.shape[2:] != self.gray_size
        ):
            raise InputError(
                None,
                f"replay_gray takes uint8 (S={self.sensors}, N, {self.gray_size[0]}, {self.gray_size[1]}), "
                f"got {gray.dtype} {gray.shape}",
            )
        n = gray.shape[1]
        p = np.full(n, np.nan)
        if n > self.startup:
            with torch.no_grad():
                x = torch.from_numpy(np.ascontiguousarray(gray[None, :, self.startup :])).float().div_(255.0)
                logits = self.model(x)[0]
            p[self.startup :] = torch.softmax(logits, dim=-1)[:, 1].double().numpy()
        return p[:, None]

    def attention(self, sensor: int):
        return None
