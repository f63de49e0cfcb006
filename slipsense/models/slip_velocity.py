"""Slip velocity: slip as the object's footprint sliding over the gel's material.

Beyond the papers; a physical detector for GelSight sensors whose gel carries markers, in a form that
trains, judges and exports like every model. It is the footprint's speed over the gel's material that
the readings reported before they measured the object's motion against the gel
(:mod:`slipsense.sensors.gel_motion`); it cannot see a turn. Per frame and sensor:

* the gel's shading without its markers (a grey closing of ``close`` pixels) and, per ``patch`` x ``patch`` cell, how much it changed since the grasp's first frame,
  above ``floor`` (grey levels in [0, 1]): where the object presses the gel;
* each cell's shift since the first frame (Lucas-Kanade on the marker map, as shear retention):
  the cell's pixels came from ``centre - shift`` of the gel's material;
* the footprint's centroid over the material, weighted by the change; a sensor is in contact where at
  least :data:`MIN_CELLS` cells changed;
* the slip speed: the length of the centroid's least-squares slope over the last ``window`` frames
  (pixels at ``image_size`` per frame), 0 unless every one of those frames was in contact;
* slip logit ``slope * (log(speed + 0.1) - log(bias))``, the largest over sensors.

Nothing is learned by gradient: ``floor`` and ``window`` are chosen on the user's grasps, then the
threshold (:attr:`SlipVelocity.recipe`). The first frame pushed is the reference: reset the stream
at the start of each grasp, before contact.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from einops import rearrange
from torch import Tensor, nn

from slipsense.errors import ConfigError
from slipsense.models import tracking
from slipsense.models.base import GraspModel, ModelPart, OnnxPart, register
from slipsense.models.grasp_stream import GraspStream
from slipsense.models.shear import ShearRetention
from slipsense.models.streams import slip_probability

#: Fewest changed cells for a sensor to count as in contact.
MIN_CELLS = 3


class _Frame(ModelPart):
    def forward(self, ref_markers: Tensor, ref_shade: Tensor, gray: Tensor):
        return self.model.frame_state(ref_markers, ref_shade, gray)


class _Step(ModelPart):
    def forward(self, state: Tensor, fresh: Tensor, history: Tensor):
        k = self.model.window
        filled = state[:, None].expand(-1, k, -1, -1)
        history = torch.where(fresh.reshape(1, 1, 1, 1) > 0.5, filled, torch.cat([history[:, 1:], state[:, None]], 1))
        return self.model.logits_of(history), history


class VelocityStream(GraspStream):
    """Keeps the first frame's marker map and shading, and the last ``window`` frames' footprints: each
    push runs the frame part once (twice for the first frame: once for its maps) and one step."""

    def reset(self) -> None:
        super().reset()
        self._reference = None
        self._history = np.zeros((1, self.model.window, self.sensors, 3), np.float32)

    def push_gray(self, gray: np.ndarray) -> float:
        frame = (gray.astype(np.float32) / np.float32(255.0))[None]
        fresh = self._reference is None
        if fresh:
            zeros = np.zeros_like(frame)
            self._reference = self._run("frame", zeros, zeros, frame)[1:]
        state = self._run("frame", *self._reference, frame)[0]
        logits, self._history = self._run("step", state, np.array([float(fresh)], np.float32), self._history)
        return float(slip_probability(logits)[0])


@register("slip-velocity")
class SlipVelocity(GraspModel):
    """Slip as the footprint's speed over the gel's material: see the module notes.

    Args:
        sensors: sensors per frame (2: both fingers; a slip on either is the grasp's).
        image_size: ``(h, w)`` of the grey frames; both divisible by ``patch``.
        patch: cell size in pixels (about one marker spacing).
        blur: sigma in pixels of the marker map's smoothing.
        close: side in pixels of the closing that removes the markers from the shading (odd, > a marker).
        iterations: Lucas-Kanade warping steps (each moves a cell at most a pixel).
        floor: change of the shading (grey levels in [0, 1]) a cell must exceed to be in the footprint.
        window: frames the centroid's slope is fitted over.
        slope, bias: the logit ``slope * (log(speed + 0.1) - log(bias))``, speed and bias in pixels a
            frame (bias > 0).
    """

    auto_backend = "torch"
    stream_class = VelocityStream
    #: How it is made: no gradient training; ``floor`` and ``window`` chosen among these on the user's
    #: grasps, then the threshold.
    recipe = {"epochs": 0, "inner_folds": 0, "choose": {"floor": [0.01, 0.02, 0.04], "window": [5, 10]}}

    adapt_cost = 10.0
    adapt_words = "slip velocity: how fast the object's footprint slides over the gel (settings chosen on your grasps)"

    @classmethod
    def adapt_reason(cls, grasps) -> str | None:
        return ShearRetention.adapt_reason(grasps)  # the same markers to follow

    def __init__(
        self,
        sensors: int = 2,
        image_size: Sequence[int] = (120, 160),
        patch: int = 10,
        blur: float = 1.0,
        close: int = 7,
        iterations: int = 5,
        floor: float = 0.02,
        window: int = 10,
        slope: float = 2.0,
        bias: float = 0.5,
    ):
        super().__init__()
        # the cells' shifts are shear retention's, with its checks of size, patch, blur and iterations
        self.shift = ShearRetention(sensors, image_size, patch, blur, iterations)
        close, window = int(close), int(window)
        if close % 2 == 0 or not 3 <= close <= 31 or not 2 <= window <= 100:
            raise ConfigError(
                f"slip-velocity: close an odd 3..31 pixels and window 2..100 frames, got {close}, {window}"
            )
        numbers = {"floor": floor, "slope": slope, "bias": bias}
        if not all(np.isfinite(float(v)) for v in numbers.values()) or not 0 <= float(floor) < 1 or float(bias) <= 0:
            raise ConfigError(f"slip-velocity: floor in [0, 1), a finite slope and a bias above 0, got {numbers}")
        self.sensors, self.image_size, self.patch = self.shift.sensors, self.shift.image_size, self.shift.patch
        self.blur, self.iterations, self.close, self.window = self.shift.blur, self.shift.iterations, close, window
        self.floor = float(floor)
        self._init = {"slope": float(slope), "bias": float(bias)}
        # the logit's two numbers can be learned by gradient (``slipsense train --set train.epochs=N``);
        # the recipe learns none. The bias is kept as its log: it stays above 0.
        self.slope = nn.Parameter(torch.tensor(float(slope)))
        self.log_bias = nn.Parameter(torch.tensor(math.log(float(bias))))
        for p in self.shift.parameters():  # shear retention's own logit numbers: not used here
            p.requires_grad_(False)
        h, w, p = *self.image_size, self.patch
        ys, xs = torch.meshgrid(
            torch.arange(h // p) * p + (p - 1) / 2, torch.arange(w // p) * p + (p - 1) / 2, indexing="ij"
        )
        self.register_buffer("_centres", torch.stack([xs, ys], -1).reshape(-1, 2).float(), persistent=False)  # (C, 2)
        t = torch.arange(window, dtype=torch.float32)
        t = t - t.mean()
        self.register_buffer("_slope_weights", t / (t * t).sum(), persistent=False)  # (K,)

    @classmethod
    def small_config(cls) -> dict:
        return {"image_size": [40, 60], "window": 4}

    def config(self) -> dict:
        out = {"sensors": self.sensors, "image_size": list(self.image_size), "patch": self.patch, "blur": self.blur}
        out.update(close=self.close, iterations=self.iterations, floor=self.floor, window=self.window)
        return {**out, **self._init}

    def shading(self, gray: Tensor) -> Tensor:
        """``(B, 1, h, w)`` grey -> the gel's shading without its dark markers: a closing (the cells'
        averages smooth it further)."""
        k, r = self.close, self.close // 2
        return -F.max_pool2d(-F.max_pool2d(gray, k, 1, r), k, 1, r)  # dilation, then erosion

    def footprint(self, fx: Tensor, fy: Tensor, change: Tensor) -> Tensor:
        """Cell shifts ``(R, n, h/p, w/p)`` each and shading changes ``(R, n, C)`` -> per frame the
        footprint's centroid over the material and whether it is in contact, ``(R, n, 3)``."""
        weight = F.relu(change - self.floor)
        material = self._centres - torch.stack([fx.flatten(2), fy.flatten(2)], -1)  # (R, n, C, 2)
        total = weight.sum(-1, keepdim=True)
        centroid = (weight[..., None] * material).sum(-2) / (total + 1e-9)
        touching = ((weight > 0).to(weight.dtype).sum(-1, keepdim=True) >= MIN_CELLS).to(weight.dtype)
        return torch.cat([centroid, touching], -1)

    def frame_state(self, ref_markers: Tensor, ref_shade: Tensor, gray: Tensor):
        """The frame part: the first frame's marker map and shading ``(B, S, h, w)`` each, a grey frame
        ``(B, S, h, w)`` -> (footprint ``(B, S, 3)``, the frame's marker map, its shading)."""
        b = gray.shape[0]
        flat = rearrange(gray, "b s h w -> (b s) 1 h w")
        markers, shade = self.shift.markers(flat), self.shading(flat)
        fx, fy = self.shift.cell_shifts(rearrange(ref_markers, "b s h w -> (b s) 1 h w"), markers)
        change = F.avg_pool2d((shade - rearrange(ref_shade, "b s h w -> (b s) 1 h w")).abs(), self.patch).flatten(2)
        state = rearrange(self.footprint(fx, fy, change), "(b s) 1 k -> b s k", b=b)
        unflat = lambda x: rearrange(x, "(b s) 1 h w -> b s h w", b=b)  # noqa: E731
        return state, unflat(markers), unflat(shade)

    def logits_of(self, windows: Tensor) -> Tensor:
        """Footprints of the last ``window`` frames ``(..., K, S, 3)`` -> logits ``(..., 2)``."""
        v = torch.einsum("k,...ksc->...sc", self._slope_weights, windows[..., :2])
        touching = windows[..., 2].amin(dim=-2)  # every frame of the window in contact
        speed = (v.square().sum(-1) + 1e-12).sqrt() * touching
        # on the log of the speed: a slow slip and a fast one both stay short of probability 1 (a float
        # at 1.0 leaves no threshold between them)
        logit = (self.slope * (torch.log(speed + 0.1) - self.log_bias)).amax(dim=-1)
        return torch.stack([torch.zeros_like(logit), logit], dim=-1)

    def forward(self, gray: Tensor) -> Tensor:
        """``(B, S, N, h, w)`` grey frames in [0, 1] -> ``(B, N, 2)`` slip logits at every frame."""
        self.check_input(gray)
        b, n = gray.shape[0], gray.shape[2]
        fx, fy, change = self.tracked(gray)
        state = rearrange(self.footprint(fx, fy, change), "(b s) n k -> b n s k", b=b)  # (B, N, S, 3)
        # the first frame stands in before the start, as the stream's history is filled with it
        padded = torch.cat([state[:, :1].expand(-1, self.window - 1, -1, -1), state], 1)
        windows = torch.stack([padded[:, k : k + n] for k in range(self.window)], 2)  # (B, N, K, S, 3)
        return self.logits_of(windows)

    def tracked(self, gray: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """``(B, S, N, h, w)`` -> every cell's shift from the first frame, x and y ``(B S, N, h/p, w/p)``,
        and its shading change ``(B S, N, C)``. Frames tracked before are looked up
        (:mod:`slipsense.models.tracking`): these depend on the frames and the tracking settings only,
        not on ``floor`` or ``window``, so choosing those tracks each grasp once."""
        settings = (self.patch, self.blur, self.iterations, self.close, list(self.image_size))
        return tracking.tracked("slip-velocity", gray, settings, self._track, not self.training)

    def _track(self, gray: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        n = gray.shape[2]
        flat = rearrange(gray, "b s n h w -> (b s n) 1 h w")
        markers = rearrange(self.shift.markers(flat), "(r n) 1 h w -> r n h w", n=n)
        shade = rearrange(self.shading(flat), "(r n) 1 h w -> r n h w", n=n)
        fx, fy = self.shift.cell_shifts(markers[:, :1], markers)
        return fx, fy, F.avg_pool2d((shade - shade[:, :1]).abs(), self.patch).flatten(2)

    def chunk_logits(self, runs: Sequence[tuple[Tensor, Sequence[int]]], n_out: int) -> Tensor:
        """Logits of chunks of whole runs (each run's frames computed once); see
        :meth:`GraspModel.chunk_logits`."""
        out = []
        for gray, ends in runs:
            rows = self.chunk_rows(gray, ends, n_out)
            out.append(self(gray[None])[0][rows])
        return torch.cat(out)

    def streaming_modules(self, geometry=None) -> dict[str, nn.Module]:
        """``frame``: the first frame's marker map and shading and the current frame -> footprint
        ``(1, S, 3)``, the frame's marker map and shading; ``step``: the footprint, ``fresh (1,)`` and
        the last ``window`` footprints -> logits ``(1, 2)``, the new history."""
        return {"frame": _Frame(self), "step": _Step(self)}

    def onnx_parts(self, geometry=None, batch: int | None = None) -> dict:
        g = torch.Generator().manual_seed(0)
        b = batch or 1
        gray = torch.rand(b, self.sensors, 6, *self.image_size, generator=g)
        frame = torch.rand(1, self.sensors, *self.image_size, generator=g)
        state = torch.rand(1, self.sensors, 3, generator=g)
        history = torch.rand(1, self.window, self.sensors, 3, generator=g)
        free = {} if batch is not None else {0: "batch"}
        return {
            "model": OnnxPart(
                self, (gray,), ["gray"], ["logits"], {"gray": {**free, 2: "frames"}, "logits": {**free, 1: "frames"}}
            ),
            "frame": OnnxPart(
                _Frame(self),
                (frame, frame.flip(-1), frame.flip(-2)),
                ["ref_markers", "ref_shade", "gray"],
                ["footprint", "markers", "shade"],
                {},
            ),
            "step": OnnxPart(
                _Step(self),
                (state, torch.zeros(1), history),
                ["footprint", "fresh", "history"],
                ["logits", "history_next"],
                {},
            ),
        }
