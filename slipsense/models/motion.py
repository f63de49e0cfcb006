"""MotionNet: a small causal network that watches how both gels move over a whole grasp.

Beyond the papers. The ViViT learns from what a 5-frame clip *looks like*, which on objects it never
saw turns out to be the object and the session rather than slip. MotionNet sees only motion:

* input: every frame of every sensor, grey and small, ``(B, S, N, h, w)`` float in [0, 1]
  (:func:`slipsense.recordings.runs.gray_frames`), from the end of the camera start-up on;
* per frame and sensor, the differences to the frames ``lags`` back (default 1, 5, 25 and 100
  frames: fast motion, motion over 0.2 s, change over the last second, and the grasp as it was 4 s
  ago, which a slip leaves and a wiggle comes back to; before the first frame the first frame
  stands in), scaled and fed to a 3-layer strided CNN -> a feature vector;
* both sensors fused symmetrically (mean and max over sensors: the fingers are interchangeable,
  slip is a loss of the grasp, not of one pad);
* a causal temporal convolution (dilations 1, 2, 4, 8: 31 frames, 1.2 s of context) -> slip logits
  for *every* frame: ``(B, N, 2)``. Nothing looks ahead, so the same numbers come out streaming
  (:class:`MotionStream`; the first frame and feature stand in before the start).
"""

from __future__ import annotations

from collections import deque
from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from einops import rearrange
from torch import Tensor, nn

from slipsense.errors import ConfigError
from slipsense.models.base import GraspModel, ModelPart, OnnxPart, register
from slipsense.models.grasp_stream import GraspStream
from slipsense.models.streams import slip_probability

#: ``level`` scales each frame to this mean grey level, its mean taken as at least ``_DARK`` (a black
#: frame stays black).
_LEVEL, _DARK = 0.5, 1.0 / 255.0
#: Bounds on settings a checkpoint may carry (refused before anything is allocated).
_LIMITS = {"width": 256, "features": 512, "temporal": 512, "sensors": 8, "max_lag": 250, "pixels": 512 * 512}


def _conv(cin: int, cout: int, k: int, stride: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, k, stride, k // 2, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True)
    )


class MotionFrame(ModelPart):
    """The per-frame part of :class:`MotionNet`: differences ``(1, S, L, h, w)`` -> features ``(1, 2F)``."""

    def forward(self, diffs: Tensor) -> Tensor:
        return self.model.encode(diffs[:, :, None])[:, 0]


class MotionStep(ModelPart):
    """One step of :class:`MotionNet`'s causal temporal stack, its state passed in and out.

    Inputs: ``features (1, C0)``, ``fresh (1,)`` (1 on the first frame: every state is filled with
    that frame's input, the way the whole-run forward repeats the first feature), and per temporal
    layer ``state_i (1, C_i, 2 * dilation_i + 1)``, the inputs its newest output needs. Outputs:
    ``logits (1, 2)`` and the next states. The kernel-3 convolution of dilation ``d`` over ``2d + 1``
    inputs gives exactly the newest output.
    """

    def __init__(self, net: MotionNet):
        super().__init__(net)
        self.layers = list(getattr(net, "tcn", ()))
        self.feature_size = 2 * net.features if self.layers else len(net.lags)
        self.state_shapes = [(conv.in_channels, 2 * d + 1) for conv, d in zip(self.layers, net.dilations)]

    def forward(self, feat: Tensor, fresh: Tensor, *states: Tensor):
        x, nxt = feat, []
        first = fresh.reshape(1, 1, 1) > 0.5
        for i, (conv, buf) in enumerate(zip(self.layers, states)):
            col = x[:, :, None]
            buf = torch.where(first, col.expand_as(buf), torch.cat([buf[:, :, 1:], col], dim=2))
            nxt.append(buf)
            y = F.relu(conv(buf))[:, :, -1]
            x = y + x if i > 0 else y
        return (self.model.head(x), *nxt)


class MotionStream(GraspStream):
    """Push one frame per sensor, get the slip probability of that frame (fused over sensors).

    Keeps the last ``max_lag + 1`` grey frames and the temporal stack's state, so each push encodes
    one frame per sensor and computes one output per layer: the same numbers as
    :meth:`MotionNet.forward` over the whole sequence (repeating the first input to the left of every
    layer equals repeating the first feature to the left of the stack). The frame encoder and the
    step run on PyTorch or ONNX Runtime (:class:`~slipsense.models.grasp_stream.GraspStream`).
    """

    def reset(self) -> None:
        super().reset()
        self._frames: deque[np.ndarray] = deque(maxlen=self.model.max_lag + 1)
        self._states = [np.zeros((1, *shape), np.float32) for shape in MotionStep(self.model).state_shapes]

    def push_gray(self, gray: np.ndarray) -> float:
        """``gray``: uint8 ``(S, h, w)``, one frame per sensor at the model's size. Returns P(slip)."""
        m = self.model
        frame = gray.astype(np.float32) / np.float32(255.0)
        if m.level:  # as MotionNet.levelled
            frame *= np.float32(_LEVEL) / np.maximum(frame.mean(axis=(1, 2), keepdims=True, dtype=np.float32), _DARK)
        fresh = not self._frames
        if fresh:
            self._frames.extend([frame] * (m.max_lag + 1))
            self._first = frame
        else:
            self._frames.append(frame)
        diffs = np.empty((1, gray.shape[0], len(m.lags), *gray.shape[1:]), np.float32)
        for i, lag in enumerate(m.lags):
            np.subtract(frame, self._first if lag == 0 else self._frames[-1 - lag], out=diffs[0, :, i])
        diffs *= np.float32(m.diff_scale)
        feat = self._run("frame", diffs)[0]
        logits, *self._states = self._run("step", feat, np.array([float(fresh)], np.float32), *self._states)
        return float(slip_probability(logits)[0])


@register("motionnet")
class MotionNet(GraspModel):
    """Causal slip detector over grey frame differences of all sensors.

    Args:
        sensors: sensors per frame (2: both fingers).
        image_size: ``(h, w)`` of the grey frames.
        lags: frame differences taken, in frames back; 0 is the first frame of the grasp (what the
            gel looked like before it: the difference is the imprint so far).
        width: channels of the first convolution (then 2x, 2x).
        features: per-sensor feature size.
        temporal: channels of the temporal convolutions.
        dilations: of the causal temporal convolutions (kernel 3 each).
        dropout: before the classifier.
        diff_scale: differences are multiplied by this (grey levels in [0, 1]; motion is a few %).
        level: each frame of each sensor is scaled to a mean grey level of 0.5 before the differences
            are taken, so a unit of brighter or dimmer exposure gives the same differences (False:
            the grey levels as the camera gives them, as detectors trained before it).
    """

    stream_class = MotionStream
    adapt_cost = 50.0
    adapt_settings = {"epochs": 10}  # as the shipped weights are fine-tuned: a few minutes, not an hour
    adapt_words = "MotionNet trained from scratch on your grasps (grey frame differences, causal convolution)"
    #: the fewest grasps and objects it is trained from scratch on (fewer: the fine-tuned shipped weights)
    adapt_min_grasps, adapt_min_objects = 40, 5

    @classmethod
    def adapt_reason(cls, grasps) -> str | None:
        if grasps.count < cls.adapt_min_grasps or len(grasps.objects) < cls.adapt_min_objects:
            return (
                f"trained from scratch only on {cls.adapt_min_grasps}+ grasps of {cls.adapt_min_objects}+ objects "
                f"(you have {grasps.count} of {len(grasps.objects)}); the shipped weights fine-tuned stand in"
            )
        return None

    def __init__(
        self,
        sensors: int = 2,
        image_size: Sequence[int] = (30, 40),
        lags: Sequence[int] = (1, 5, 25, 100),
        width: int = 8,
        features: int = 32,
        temporal: int = 32,
        dilations: Sequence[int] = (1, 2, 4, 8),
        dropout: float = 0.1,
        diff_scale: float = 10.0,
        level: bool = False,
    ):
        super().__init__()
        image_size = tuple(int(v) for v in image_size)
        lags, dilations = tuple(int(v) for v in lags), tuple(int(v) for v in dilations)
        if len(image_size) != 2 or min(image_size) < 8 or image_size[0] * image_size[1] > _LIMITS["pixels"]:
            raise ConfigError(
                f"motionnet: image_size must be (h, w) with 8 <= h, w and h*w <= {_LIMITS['pixels']}, got {image_size}"
            )
        if not lags or min(lags) < 0 or max(lags) > _LIMITS["max_lag"] or lags.count(0) > 1 or lags == (0,):
            raise ConfigError(
                f"motionnet: lags must be 1..{_LIMITS['max_lag']} frames (0: the first frame of the grasp), got {lags}"
            )
        if not dilations or min(dilations) < 1 or sum(dilations) > 256:
            raise ConfigError(f"motionnet: dilations must be >= 1 with a sum <= 256, got {dilations}")
        for key, v in (("sensors", sensors), ("width", width), ("features", features), ("temporal", temporal)):
            if not 1 <= int(v) <= _LIMITS[key]:
                raise ConfigError(f"motionnet: {key} must be 1..{_LIMITS[key]}, got {v}")
        if not 0.0 <= float(dropout) < 1.0:
            raise ConfigError(f"motionnet: dropout must be in [0, 1), got {dropout}")
        self.sensors, self.image_size, self.lags = int(sensors), image_size, lags
        self.width, self.features, self.temporal = int(width), int(features), int(temporal)
        self.dilations, self.dropout_p, self.diff_scale = dilations, float(dropout), float(diff_scale)
        if not isinstance(level, bool):
            raise ConfigError(f"motionnet: level must be true or false, got {level!r}")
        self.level = level
        self._in_place = True  # differences written in place (False in the copy ONNX export traces)
        w = self.width
        self.encoder = nn.Sequential(_conv(len(lags), w, 5, 2), _conv(w, 2 * w, 3, 2), _conv(2 * w, 2 * w, 3, 2))
        self.project = nn.Linear(4 * w, self.features)
        chans = [2 * self.features] + [self.temporal] * len(dilations)
        self.tcn = nn.ModuleList(nn.Conv1d(a, b, 3, dilation=d) for a, b, d in zip(chans, chans[1:], dilations))
        self.dropout = nn.Dropout(self.dropout_p)
        self.head = nn.Linear(self.temporal, 2)

    def config(self) -> dict:
        names = ("sensors", "image_size", "lags", "width", "features", "temporal", "dilations")
        out = {k: getattr(self, k) for k in names}
        out = {k: list(v) if isinstance(v, tuple) else v for k, v in out.items()}  # JSON-ready
        return {**out, "dropout": self.dropout_p, "diff_scale": self.diff_scale, "level": self.level}

    @property
    def receptive_field(self) -> int:
        """Frames of features the temporal stack sees (kernel 3 per dilation)."""
        return 1 + 2 * sum(self.dilations)

    @property
    def max_lag(self) -> int:
        """Frames back the differences reach (lag 0, the first frame of the grasp, is kept apart)."""
        return max(lag for lag in self.lags if lag > 0)

    def levelled(self, gray: Tensor) -> Tensor:
        """``(..., h, w)`` grey frames scaled to a mean of 0.5 each when ``level`` is set (exposure is a
        gain on the grey levels; dividing by the frame's own mean takes it out, frame by frame, so
        streaming needs no state for it). Unchanged otherwise."""
        if not self.level:
            return gray
        return gray * (_LEVEL / gray.mean(dim=(-2, -1), keepdim=True).clamp(min=_DARK))

    def differences(self, gray: Tensor) -> Tensor:
        """``(B, S, N, h, w)`` -> ``(B, S, N, L, h, w)``: frame minus the frame ``lag`` back (the first
        frame standing in before the start), scaled."""
        at = torch.arange(gray.shape[2], device=gray.device)
        gray = self.levelled(gray)
        return self._lagged(gray, at, self._pasts(at), dim=2).movedim(5, 3)  # positive axes: ONNX Transpose

    def _pasts(self, at: Tensor) -> list[Tensor]:
        """Per lag, the frame indices ``lag`` before ``at`` (the first frame standing in before 0)."""
        # lag 0 is the anchor: the first frame of the grasp, what the gel looked like before it
        return [torch.zeros_like(at) if lag == 0 else (at - lag).clamp(min=0) for lag in self.lags]

    def _lagged(self, gray: Tensor, now: Tensor, pasts: Sequence[Tensor], dim: int) -> Tensor:
        """Scaled differences of the frames ``now`` and, per lag, ``pasts`` along ``dim`` of ``gray``,
        lags last: ``(..., h, w, L)``. Moved to after the frame axis this is a channels-last view of
        the images, on which the strided convolutions run about a third faster than on planar ones."""
        cur = gray.index_select(dim, now)
        if not self._in_place:  # the ONNX tracer does not follow writes into views of a new tensor
            return torch.stack([cur - gray.index_select(dim, p) for p in pasts], dim=-1) * self.diff_scale
        out = cur.new_empty((*cur.shape, len(pasts)))
        for i, p in enumerate(pasts):  # written in place: no stacked copy
            torch.sub(cur, gray.index_select(dim, p), out=out[..., i])
        return out.mul_(self.diff_scale)

    def encode(self, diffs: Tensor) -> Tensor:
        """``(B, S, N, L, h, w)`` differences -> ``(B, N, 2F)`` fused per-frame features."""
        b, s = diffs.shape[:2]
        x = rearrange(diffs, "b s n l h w -> (b s n) l h w")
        x = self.encoder(x)
        x = torch.cat([x.mean(dim=(2, 3)), x.amax(dim=(2, 3))], dim=1)
        f = rearrange(self.project(x), "(b s n) f -> b s n f", b=b, s=s)
        return torch.cat([f.mean(dim=1), f.amax(dim=1)], dim=-1)

    def classify(self, feats: Tensor) -> Tensor:
        """``(B, N, 2F)`` features -> ``(B, N', 2)`` logits, ``N' = N - receptive_field + 1`` (valid
        causal convolution: pad the left edge yourself)."""
        x = rearrange(feats, "b n f -> b f n")
        for i, conv in enumerate(self.tcn):
            y = F.relu(conv(x))
            x = y + x[:, :, -y.shape[2] :] if i > 0 else y
        x = self.dropout(rearrange(x, "b f n -> b n f"))
        return self.head(x)

    def forward(self, gray: Tensor) -> Tensor:
        """``(B, S, N, h, w)`` grey frames in [0, 1] -> ``(B, N, 2)`` slip logits at every frame."""
        self.check_input(gray)
        feats = self.encode(self.differences(gray))
        if self.receptive_field > 1:
            feats = torch.cat([feats[:, :1].expand(-1, self.receptive_field - 1, -1), feats], dim=1)
        return self.classify(feats)

    def chunk_logits(self, runs: Sequence[tuple[Tensor, Sequence[int]]], n_out: int) -> Tensor:
        """Logits of chunks of whole runs, each frame encoded once however many chunks share it.

        Args:
            runs: ``(gray, ends)`` pairs: a run's float frames ``(S, N, h, w)`` and the last frame
                index of each of its chunks.
            n_out: frames scored per chunk.

        Returns:
            ``(C, n_out, 2)``, chunks in the order given; the logits of frames ``end - n_out + 1 ..
            end`` as ``forward(run)`` gives them (frame indices below 0 repeat frame 0, the way the
            whole-run forward pads the start). In training mode, batch norm sees each distinct frame
            once, where one chunk at a time would count shared frames again.
        """
        need = n_out + self.receptive_field - 1
        grays, now, pasts, gathers = [], [], [], []
        frames = distinct = 0  # frames of the runs so far, distinct frames so far
        for gray, ends in runs:
            rows = self.chunk_rows(gray, ends, need)
            at, where = torch.unique(rows, return_inverse=True)  # the distinct frames, and each chunk slot's
            grays.append(gray)
            now.append(at + frames)
            pasts.append([p + frames for p in self._pasts(at)])
            gathers.append(where + distinct)
            frames, distinct = frames + gray.shape[1], distinct + len(at)
        gray = torch.cat(grays, dim=1) if len(grays) > 1 else grays[0]  # the runs' frames one after another
        gray = self.levelled(gray)
        by_lag = [torch.cat(p) for p in zip(*pasts)]
        diffs = self._lagged(gray, torch.cat(now), by_lag, dim=1)  # (S, U, h, w, L)
        feats = self.encode(diffs.movedim(-1, 2)[None])[0]  # (U, 2F)
        return self.classify(feats[torch.cat(gathers)])

    def exportable(self) -> nn.Module:
        copy = super().exportable()
        copy._in_place = False
        return copy

    def streaming_modules(self, geometry=None) -> dict[str, nn.Module]:
        """``frame``: differences ``(1, S, L, h, w)`` -> fused features ``(1, 2F)``; ``step``: one
        temporal step, its state as inputs and outputs (:class:`MotionStep`)."""
        return {"frame": MotionFrame(self), "step": MotionStep(self)}

    def onnx_parts(self, geometry=None, batch: int | None = None) -> dict:
        """``model``: ``gray (B, S, N, h, w)`` -> ``logits (B, N, 2)`` (batch and frames free);
        ``frame`` and ``step`` as :meth:`streaming_modules` (one frame at a time, no free axis)."""
        g = torch.Generator().manual_seed(0)
        b = batch or 1
        gray = torch.rand(b, self.sensors, max(8, self.max_lag // 4), *self.image_size, generator=g)
        diffs = torch.randn(1, self.sensors, len(self.lags), *self.image_size, generator=g) * 0.1
        step = MotionStep(self)
        states = [torch.randn(1, *shape, generator=g) for shape in step.state_shapes]
        feat = torch.randn(1, step.feature_size, generator=g)
        free = {} if batch is not None else {0: "batch"}
        state_in = [f"state{i}" for i in range(len(states))]
        state_out = ["logits", *(f"{n}_next" for n in state_in)]
        return {
            "model": OnnxPart(
                self, (gray,), ["gray"], ["logits"], {"gray": {**free, 2: "frames"}, "logits": {**free, 1: "frames"}}
            ),
            "frame": OnnxPart(MotionFrame(self), (diffs,), ["differences"], ["features"], {}),
            "step": OnnxPart(step, (feat, torch.ones(1), *states), ["features", "fresh", *state_in], state_out, {}),
        }


@register("motion-energy")
class MotionEnergy(MotionNet):
    """The non-learned baseline: how much the gels move, with a fitted threshold.

    Per frame, the mean absolute grey-level change over each lag (1, 5, 25 frames) on each sensor,
    the largest over sensors, ``log1p`` -> a logistic regression (``len(lags) + 1`` numbers fitted).
    No appearance, no learned filters: what frame-difference slip detectors threshold, so users see
    what the network adds. Streams and trains like :class:`MotionNet`.
    """

    adapt_cost = 5.0
    adapt_settings: dict = {}  # its own training: a few numbers fitted
    adapt_words = "motion energy: how much the gels move, a threshold fitted on your grasps (non-learned)"

    @classmethod
    def adapt_reason(cls, grasps) -> str | None:
        return None  # a few numbers fitted: any grasps that can be judged can fit it

    def __init__(
        self,
        sensors: int = 2,
        image_size: Sequence[int] = (30, 40),
        lags: Sequence[int] = (1, 5, 25),
        diff_scale: float = 10.0,
    ):
        # a MotionNet of the smallest settings (width, features, temporal 1, one dilation, no dropout), then unmade
        super().__init__(sensors, image_size, lags, 1, 1, 1, (1,), 0.0, diff_scale)
        del self.encoder, self.project, self.tcn, self.head
        self.head = nn.Linear(len(self.lags), 2)
        self.dilations = ()

    def config(self) -> dict:
        return {k: v for k, v in super().config().items() if k in ("sensors", "image_size", "lags", "diff_scale")}

    def encode(self, diffs: Tensor) -> Tensor:
        """``(B, S, N, L, h, w)`` -> ``(B, N, L)``: log1p of the mean absolute change, max over sensors."""
        return torch.log1p(diffs.abs().mean(dim=(4, 5)).amax(dim=1))

    def classify(self, feats: Tensor) -> Tensor:
        return self.head(feats)
