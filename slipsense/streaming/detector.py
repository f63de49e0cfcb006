"""Live slip detection: push one frame per sensor, get a slip probability at each frame.

    >>> det = SlipDetector.pretrained()            # the shipped detector, both fingers  # doctest: +SKIP
    >>> for left, right in camera_pairs:          # uint8 (H, W, 3) BGR images at 25 frames/s
    ...     reading = det.push(left, right)       # Reading(index, probability, per_sensor, alarm)

The detector holds the model's stream (:meth:`slipsense.models.base.SlipModel.stream`): a clip
model's sliding window over cached frame-part outputs (:mod:`slipsense.models.streams`), or a grasp
model's own incremental state (:class:`slipsense.models.motion.MotionStream`). What is the
detector's own: the operating point (threshold, debounce, hold), combining sensors where the model
judges each apart, frame numbering and the readings. Nothing here depends on the kind of model.

The stream's modules run on PyTorch or ONNX Runtime (``backend``); heat maps
(:meth:`SlipDetector.heatmap`) always use the PyTorch model.

:meth:`SlipDetector.replay` computes the same probabilities for whole recordings at once: what
:mod:`slipsense.evaluation.replay` and the evaluation use.
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import InitVar, dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from torch import nn

from slipsense.alarm import alarm_trace, hold_frames
from slipsense.checkpoint import load_model, read_info
from slipsense.errors import ConfigError, InputError
from slipsense.models.base import SlipModel, window_geometry
from slipsense.models.runners import check_backend, onnx_cache_dir, resolve_backend
from slipsense.resources import default_model_name, shipped_model, shipped_models
from slipsense.sensors.gel_motion import GelMotion, motion_stream
from slipsense.sensors.spec import sensor_of
from slipsense.streaming.clock import ModelClock, resample

#: The shipped default detector (package data: :mod:`slipsense.resources`).
DEFAULT_CHECKPOINT = shipped_model()
COMBINE = ("max", "mean")
#: Longest alarm hold accepted (seconds).
MAX_HOLD_S = 60.0


@dataclass(frozen=True)
class Reading:
    """The detector's answer to one push.

    ``index``: 0-based frame number since the start (or :meth:`SlipDetector.reset`);
    ``probability``: combined slip probability in [0, 1], None until the window is full;
    ``per_sensor``: one probability per sensor, for models that judge each sensor apart; None for
    models that fuse the sensors into one answer (the shipped grasp detectors), and until the window
    is full;
    ``alarm``: the alarm rule (:mod:`slipsense.alarm`): ``probability >= threshold`` for ``debounce``
    steps in a row, held for ``hold`` seconds after (False while None);
    ``gel``: per sensor, what its gel's markers say (:class:`~slipsense.sensors.gel_motion.GelMotion`:
    the slip and the shear field; None for a sensor before its marker grid is found); None where the
    sensor's gel has no markers (or the detector was made with ``gel_motion=False``);
    ``length_unit``: the length unit of ``gel`` (``"mm"`` or ``"px"``, as :attr:`GelMotion.unit`),
    given by the detector; the reading states it as :attr:`slip_velocity_unit`, the JSON record's
    word and string.
    """

    index: int
    probability: float | None
    per_sensor: tuple[float, ...] | None
    alarm: bool
    gel: tuple[GelMotion | None, ...] | None = None
    length_unit: InitVar[str | None] = None
    #: the unit of each finger's ``translation``: ``"mm/s"`` where the sensor states its pixel size,
    #: ``"px/s"`` otherwise; None where ``gel`` is None
    slip_velocity_unit: str | None = field(init=False, default=None)

    def __post_init__(self, length_unit: str | None) -> None:
        # stored as the JSON record says it, so that the reading and the record name one unit one way
        object.__setattr__(self, "slip_velocity_unit", None if length_unit is None else f"{length_unit}/s")

    @property
    def slip(self) -> tuple[dict | None, ...] | None:
        """Per sensor ``{"translation": [vx, vy], "omega": w, "stick": s, "speed": v}``
        (:meth:`GelMotion.slip_dict`: the translation and the speed over the contact in
        :attr:`slip_velocity_unit`, image axes x right, y down; omega in :attr:`slip_omega_unit`; the
        share of the contact that sticks), None per sensor without contact; None where the gel has no
        markers. The JSON record's ``slip``."""
        return None if self.gel is None else tuple(None if g is None else g.slip_dict() for g in self.gel)

    @property
    def slip_omega_unit(self) -> str | None:
        """``"rad/s"``, whatever the sensor (an angle needs no pixel size); None without markers."""
        return None if self.gel is None else "rad/s"


@dataclass
class Trace:
    """Probabilities of a whole replayed recording, frame by frame (what pushing every frame gives).

    ``probability``: ``(N,)`` combined, NaN for the first ``frames - 1`` frames (window not full);
    ``per_sensor``: ``(N, S)`` where the model judges each sensor apart, ``(N, 1)`` (the fused
    answer) where it fuses them; ``threshold`` the detector's; ``hold``: frames of this trace an
    alarm holds for.
    """

    probability: np.ndarray
    per_sensor: np.ndarray
    threshold: float
    debounce: int = 1
    hold: int = 0

    @property
    def alarm(self) -> np.ndarray:
        """``(N,)`` bool: probability >= threshold for ``debounce`` frames in a row, held for ``hold``
        frames after (NaN: no answer yet): :func:`slipsense.alarm.alarm_trace`."""
        return alarm_trace(self.probability, self.threshold, self.debounce, self.hold)


def combine_probabilities(per_sensor: np.ndarray, combine: str) -> np.ndarray:
    """``(..., S)`` -> ``(...)``: the largest (``"max"``) or the mean (``"mean"``) over sensors."""
    if combine == "max":
        return per_sensor.max(axis=-1)
    if combine == "mean":
        return per_sensor.mean(axis=-1)
    raise ConfigError(f"combine must be one of {COMBINE}, got {combine!r}")


class SlipDetector:
    """Streaming slip detector over any slipsense checkpoint (MotionNet, ViViT, 3D ResNet-50, STNet, TemNet).

    Args:
        model: a slipsense model (eval mode is set here).
        threshold: alarm when the combined probability is >= this, in [0, 1].
        sensors: frames per push (1, or 2 for both fingers); default: what a grasp model was
            trained on (both fingers for the shipped detector), else 1.
        combine: for models that judge each sensor apart (clip models): ``"max"`` (default: alarm
            when either sensor sees slip) or ``"mean"``. Models that fuse the sensors inside (the
            grasp models) give one answer and no per-sensor probability: a combine is refused there.
        hold: seconds an alarm, once raised, stays on (default 0; checkpoints store their own), so
            that a probability dipping under the threshold for a moment does not make one slip two
            alarm onsets.
        backend: ``"torch"``, ``"onnx"`` (ONNX Runtime; the parts are exported on first use) or
            ``"auto"`` (ONNX Runtime where it is installed). ``self.backend`` is the one running.
        dtype: ``"float32"`` (default) or, with ``backend="onnx"``, ``"int8"``: the exported parts'
            matrix products dynamically quantized to int8 weights (``onnxruntime.quantization``).
            A quarter of the weight bytes: what makes the paper-size STNet fast on a CPU, at the cost
            of probabilities that differ slightly from the float model's.
        info: the checkpoint's config (window length / frame size of models that do not fix them,
            the camera start-up of grasp models).
        onnx_dir: where the ONNX parts are written for ``backend="onnx"`` (default: a temporary folder).
            Parts already there are reused, so give each model its own folder.
        gel_motion: follow the gel's markers in every pushed frame, where the sensor's gel has them
            (:attr:`Reading.gel`: slip velocity, shear field; a few milliseconds a frame on one
            thread); False: readings carry none.

    Attributes: ``geometry`` (what the model takes: ``kind``, ``frames``, ``image_size`` /
    ``markers`` / ``gray_size``), ``sensors``, ``threshold``, ``debounce``, ``sensor`` (the
    :class:`~slipsense.sensors.spec.SensorSpec` the checkpoint was trained on: frame rate, size).
    """

    def __init__(
        self,
        model: nn.Module,
        *,
        threshold: float = 0.5,
        sensors: int | None = None,
        combine: str | None = None,
        backend: str = "torch",
        info: Mapping[str, Any] | None = None,
        onnx_dir: str | Path | None = None,
        dtype: str = "float32",
        debounce: int = 1,
        hold: float = 0.0,
        gel_motion: bool = True,
    ):
        if not isinstance(model, SlipModel):
            raise ConfigError(f"{type(model).__name__} is not a slipsense model (see slipsense.models.base)")
        if sensors is None:
            sensors = window_geometry(model, info).get("sensors", 1)
        check_settings(threshold, sensors, combine, backend, dtype)
        check_hold(hold)
        backend = resolve_backend(backend, model)
        if isinstance(debounce, bool) or not isinstance(debounce, (int, np.integer)) or not 1 <= debounce <= 1000:
            raise ConfigError(f"debounce must be a whole number of frames in 1..1000, got {debounce!r}")
        self.model = model.eval()
        self.model_name = model.model_name
        self.threshold, self.sensors, self.backend = float(threshold), int(sensors), backend
        self.debounce, self.dtype, self.hold = int(debounce), dtype, float(hold)

        #: the sensor the model was trained on (:class:`~slipsense.sensors.spec.SensorSpec`, from the checkpoint)
        self.sensor = sensor_of(info)
        self._stream = model.stream(sensors=self.sensors, info=info, backend=backend, dtype=dtype, onnx_dir=onnx_dir)
        #: True where each sensor gets its own probability (the model judges them apart)
        self.per_sensor = bool(self._stream.per_sensor)
        #: True where :meth:`heatmap` draws something (what: ``model.attention_map``)
        self.has_heatmap = bool(self._stream.has_attention)
        if combine is not None and not self.per_sensor and self.sensors > 1:
            self._stream.close()
            raise ConfigError(
                f"{self.model_name} fuses its {self.sensors} sensors inside the model: it gives one probability, "
                f"no per-sensor ones to combine (leave combine out)"
            )
        self.combine = combine or "max"
        self.gel_motion = bool(gel_motion)
        self._hold_ticks = hold_frames(self.hold, self.sensor.fps)  # the model's steps run at its sensor's rate
        self.reset()

    @classmethod
    def from_checkpoint(
        cls,
        path: str | Path,
        threshold: float | None = None,
        sensors: int | None = None,
        combine: str | None = None,
        backend: str = "auto",
        onnx_dir: str | Path | None = None,
        dtype: str = "float32",
        debounce: int | None = None,
        hold: float | None = None,
        loaded: tuple[Any, dict[str, Any]] | None = None,
        gel_motion: bool = True,
    ) -> "SlipDetector":
        """Load a checkpoint (:func:`slipsense.checkpoint.load_model`) into a detector (``loaded``:
        its ``(model, info)`` where the caller has read it already).

        ``threshold`` / ``debounce`` / ``hold`` default to the operating point stored in the
        checkpoint (chosen on its training objects only); a checkpoint without one gets 0.5 / 1 / 0 s
        and a warning.

        ``backend="auto"`` (default) runs on ONNX Runtime where it is installed, else on PyTorch;
        :attr:`backend` says which. On ONNX Runtime the parts are cached under ``onnx_dir`` (default
        ``<cache_root>/onnx/<hash of the checkpoint file>``), so only the first use pays the export.
        """
        model, info = loaded if loaded is not None else load_model(path)
        sensor_of(info, path)  # a malformed sensor spec is named with its file
        threshold, debounce = stored_operating_point(path, info, threshold, debounce)
        hold = stored_hold(info, hold)
        check_settings(threshold, 1 if sensors is None else sensors, combine, backend, dtype)
        backend = resolve_backend(backend, model)
        if backend == "onnx" and onnx_dir is None:
            onnx_dir = onnx_cache_dir(Path(path))
        settings = dict(
            threshold=threshold, sensors=sensors, combine=combine, dtype=dtype, debounce=debounce, hold=hold
        )
        settings["gel_motion"] = gel_motion
        try:
            return cls(model, backend=backend, info=info, onnx_dir=onnx_dir, **settings)
        except ConfigError as exc:  # name the checkpoint: it is what the user chose
            raise InputError(path, str(exc)) from None

    @classmethod
    def pretrained(
        cls, name: str | None = None, image_size: tuple[int, int] | None = None, **kwargs: Any
    ) -> "SlipDetector":
        """A shipped detector (:func:`slipsense.resources.shipped_models`): by default the one for the
        input (:func:`shipped_name`: the sensor's frame size ``image_size`` ``(h, w)`` and the number of
        sensors asked; ``sensors=2``, the default: ``"motionnet-gelsight"``, both fingers;
        ``sensors=1``: ``"motionnet-gelsight-1"``, one finger; a 480 x 640 GelSight:
        ``"shear-retention-gelsight-lift"``); ``"vivit-gelsight"`` is the paper's ViViT. ``kwargs`` as
        :meth:`from_checkpoint`."""
        name = name or shipped_name(kwargs.get("sensors"), image_size)
        if name not in shipped_models():
            raise ConfigError(f"no shipped detector {name!r}; shipped: {', '.join(shipped_models())}")
        return cls.from_checkpoint(shipped_model(name), **kwargs)

    @property
    def geometry(self) -> dict[str, Any]:
        """What the model takes: ``{"kind", "frames", "image_size" | "markers" | "gray_size", ...}``."""
        return self._stream.describe()

    @property
    def kind(self) -> str:
        return self.geometry["kind"]

    @property
    def frames(self) -> int:
        return self.geometry["frames"]

    def reset(self) -> None:
        """Forget the window and restart frame numbering (and the model's clock) at 0."""
        self._index = 0  # pushes
        self._ticks = 0  # steps of the model: one a push, or one a tick of its clock for stamped pushes
        self._above = 0  # consecutive steps at or above the threshold (debounce)
        self._since_alarm: int | None = None  # steps since the debounced rule last said alarm (hold)
        self._answer: tuple[float, tuple[float, ...]] | None = None  # the latest step's (combined, per sensor)
        self._clock = ModelClock(self.sensor.fps)
        self._stream.reset()
        self._gel: list | None = None  # one gel-motion stream per sensor, made at the first push

    def _gel_motion(self, frames: Sequence[Any], stamp: float | None) -> tuple[GelMotion | None, ...] | None:
        """Each sensor's :class:`GelMotion` for this push (None: the gel has no markers)."""
        if not self.gel_motion:
            return None
        if self._gel is None:
            startup = int(self.geometry.get("startup", 0))
            self._gel = [motion_stream(self.sensor, f, startup) for f in frames]
        if any(g is None for g in self._gel):
            return None
        return tuple(g.push(np.asarray(f), stamp) for g, f in zip(self._gel, frames))

    def push(self, *frames: Any, stamp: float | None = None) -> Reading:
        """Add one frame per sensor and classify the latest frames.

        Video and grasp models take uint8 ``(H, W, 3)`` BGR images (resized to the model's size when
        it differs); marker models take float ``(M, 3)`` marker positions in mm. Raises
        :class:`InputError` (naming the frame and sensor) for a wrong count, type, shape, dtype or
        a non-finite value; the window is left unchanged then.

        ``stamp``: when the frames were taken (seconds, the source's clock). With stamps the model
        runs on its own clock (:class:`~slipsense.streaming.clock.ModelClock`, its sensor's rate
        ``self.sensor.fps``): a source at another rate, with dropped frames or jitter, gives the model
        what it was trained on, and the reading is the model's latest answer. Without stamps every
        push is one step of the model, as if the source ran at the model's rate.
        """
        if len(frames) != self.sensors:
            raise InputError(
                None, f"frame {self._index}: push takes {self.sensors} frame(s), one per sensor, got {len(frames)}"
            )
        index = self._index
        for inputs in [frames] if stamp is None else self._clock.ticks(stamp, frames):
            self._step(inputs)
        self._index += 1
        gel = self._gel_motion(frames, stamp)
        unit = None if gel is None else self._gel[0].unit
        if self._answer is None:
            return Reading(index, None, None, False, gel, unit)
        p, per_sensor = self._answer
        alarm = self._since_alarm is not None and self._since_alarm <= self._hold_ticks
        return Reading(index, p, per_sensor if self.per_sensor else None, alarm, gel, unit)

    def _step(self, frames: Sequence[Any]) -> None:
        """One step of the model on its clock: its answer and the debounce count."""
        per_sensor = self._stream.push(frames, self._ticks)
        self._ticks += 1
        if per_sensor is None:
            return
        p = float(combine_probabilities(np.asarray(per_sensor), self.combine))
        # NaN must never read as "safe": a model answer that is not a number raises the alarm
        above = not (p < self.threshold)
        self._above = self._above + 1 if above else 0
        if self._above >= self.debounce:
            self._since_alarm = 0
        elif self._since_alarm is not None:
            self._since_alarm += 1
        self._answer = (p, tuple(float(v) for v in per_sensor))

    def replay(self, *streams: np.ndarray, stamps: np.ndarray | None = None) -> Trace:
        """Probabilities for whole recordings at once: the numbers pushing every frame would give.

        Args:
            streams: one per sensor, all N frames long: uint8 ``(N, H, W, 3)`` BGR videos (video
                and grasp models) or float ``(N, M, 3)`` marker clouds (marker models).
            stamps: ``(N,)`` seconds the frames were taken: the model runs on its own clock, as
                :meth:`push` with stamps does (None: every frame one step of the model).

        Returns:
            :class:`Trace`, one value per source frame. Does not touch the streaming state.
        """
        if len(streams) != self.sensors:
            raise InputError(None, f"replay takes {self.sensors} stream(s), one per sensor, got {len(streams)}")
        for i, s in enumerate(streams):
            if not isinstance(s, np.ndarray):
                raise InputError(None, f"sensor {i}: replay takes numpy arrays, got {type(s).__name__}")
        n = len(streams[0])
        if any(len(s) != n for s in streams):
            raise InputError(None, f"replay streams differ in length: {[len(s) for s in streams]}")
        return self._replayed(self._stream.replay, list(streams), stamps)

    @property
    def cache_product(self) -> str | None:
        """What of a video the model can be replayed from, as the frame cache names it
        (:func:`slipsense.recordings.frame_cache.video_products`, e.g. ``"gray:30x40"``), or None:
        replay the decoded video."""
        return getattr(self._stream, "cache_product", None)

    def replay_cached(self, frames: np.ndarray, stamps: np.ndarray | None = None) -> Trace:
        """:meth:`replay` from the frame cache's :attr:`cache_product` of every sensor, stacked:
        ``(S, N, ...)`` (grey frames uint8 ``(S, N, h, w)`` for a grasp model); ``stamps`` as there."""
        if self.cache_product is None:
            raise ConfigError(f"{self.model_name} is replayed from decoded videos: use replay()")
        if stamps is None:
            return self._trace(self._stream.replay_cached(frames))
        return self._replayed(lambda ticks: self._stream.replay_cached(np.stack(ticks)), list(frames), stamps)

    def replay_gray(self, gray: np.ndarray) -> Trace:
        """:meth:`replay_cached` of a grasp model: grey frames uint8 ``(S, N, h, w)`` at its size."""
        return self.replay_cached(gray)

    def _replayed(self, run, streams: list[np.ndarray], stamps: np.ndarray | None) -> Trace:
        """The trace of ``run(streams)``: on the model's clock (:func:`resample`) where ``stamps`` are given."""
        if stamps is None:
            return self._trace(run(streams))
        stamps = np.asarray(stamps, dtype=np.float64)
        ticks, last = resample(streams, stamps, self.sensor.fps)
        return self._trace(run(ticks)[last], stamps)

    def _trace(self, per_sensor: np.ndarray, stamps: np.ndarray | None = None) -> Trace:
        """The trace of per-sensor (or fused) answers, one row per source frame; the hold in frames
        of the source (at its median frame period where ``stamps`` are given, else the model's rate)."""
        fps = self.sensor.fps
        if stamps is not None and len(stamps) > 1:
            period = float(np.median(np.diff(stamps)))
            fps = 1.0 / period if period > 0 else fps
        prob = combine_probabilities(per_sensor, self.combine)
        return Trace(prob, per_sensor, self.threshold, self.debounce, hold_frames(self.hold, fps))

    def heatmap(self, sensor: int = 0) -> np.ndarray | None:
        """Where the model looks in the latest window of ``sensor`` (None until the window is full).

        ViViT: attention rollout of the latest frame (:meth:`ViViT.cls_attention_map`),
        ``(Hp, Wp)`` on the patch grid, sums to 1. STNet/TemNet: marker saliency
        (:meth:`STNet.marker_saliency`) ``(M,)``, max 1. 3D ResNet and grasp models: None (no
        attention to show: :attr:`has_heatmap` is False).
        """
        if not 0 <= sensor < self.sensors:
            return None
        return self._stream.attention(sensor)

    def close(self) -> None:
        self._stream.close()


@functools.lru_cache(maxsize=1)
def shipped_inputs() -> dict[str, tuple[tuple[int, int] | None, int | None]]:
    """``{name: (frame size (h, w) or None, sensors)}`` of every shipped detector, its metadata read
    once a process (the shipped files are part of the installed package: they do not change under it)."""
    out = {}
    for name in shipped_models():
        info = read_info(shipped_model(name))
        size = (info.get("sensor") or {}).get("image_size")
        out[name] = (tuple(size) if size else None, info["model_config"].get("sensors"))
    return out


def shipped_name(sensors: int | None = None, image_size: tuple[int, int] | None = None) -> str:
    """The shipped detector for an input: the one whose sensor has frames of ``image_size`` ``(h, w)``
    and that takes ``sensors`` sensors (default 2), else the GelSight Mini's for that many fingers."""
    if image_size is not None:
        for name, (size, takes) in shipped_inputs().items():
            if size == tuple(image_size) and takes == (sensors or 2):
                return name
    return default_model_name(sensors)


def stored_hold(info: Mapping[str, Any] | None, hold: float | None) -> float:
    """Seconds an alarm holds: the caller's where given, else the checkpoint's operating point's
    ``hold_s``, else 0 (checkpoints from before the hold)."""
    if hold is not None:
        return check_hold(hold)
    op = info.get("operating_point") if isinstance(info, Mapping) else None
    value = op.get("hold_s") if isinstance(op, Mapping) else None
    return check_hold(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else 0.0


def _in_range(value: Any, low: float, high: float) -> bool:
    try:
        return low <= float(value) <= high
    except (TypeError, ValueError):
        return False


def check_hold(hold: Any) -> float:
    """``hold`` as seconds in [0, MAX_HOLD_S], else ConfigError."""
    if not _in_range(hold, 0.0, MAX_HOLD_S):
        raise ConfigError(f"hold must be a number of seconds in [0, {MAX_HOLD_S:g}], got {hold!r}")
    return float(hold)


def stored_operating_point(
    path: str | Path, info: Mapping[str, Any], threshold: float | None, debounce: int | None
) -> tuple[float, int]:
    """The threshold and debounce to use: the caller's where given, else the checkpoint's operating
    point, else 0.5 / 1 with a warning naming the checkpoint."""
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


def check_settings(threshold: Any, sensors: Any, combine: str | None, backend: str, dtype: str = "float32") -> None:
    if not _in_range(threshold, 0.0, 1.0):
        raise ConfigError(f"threshold must be a number in [0, 1], got {threshold!r}")
    if isinstance(sensors, bool) or not isinstance(sensors, (int, np.integer)) or sensors < 1:
        raise ConfigError(f"sensors must be a positive integer, got {sensors!r}")
    if combine is not None and combine not in COMBINE:
        raise ConfigError(f"combine must be one of {COMBINE}, got {combine!r}")
    check_backend(backend, dtype)


__all__ = ["DEFAULT_CHECKPOINT", "Reading", "SlipDetector", "Trace", "combine_probabilities", "onnx_cache_dir"]
__all__ += ["shipped_name", "window_geometry", "stored_operating_point", "stored_hold", "check_hold"]
