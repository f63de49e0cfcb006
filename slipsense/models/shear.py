"""Shear retention: does the gel keep the shear that lifting the object put on it?

Beyond the papers; a physical detector for GelSight sensors whose gel carries markers. Lifting an
object shears the gel: the markers move with the gel's surface and stay moved while the grasp holds.
Where the object slides, the gel springs back and its markers give up much of the displacement they
had. Per frame and sensor:

* markers: how much darker each pixel is than its blurred surroundings, blurred a little
  (``(h, w)``; the gel's shading and the object's imprint vary slowly and drop out);
* the displacement of each ``patch`` x ``patch`` cell since the grasp's first frame: Lucas-Kanade
  with ``iterations`` warping steps (pixels at ``image_size``), ``C = (h / patch) (w / patch)`` cells;
* per cell, the largest displacement so far (its peak shear) and the share of it given up since;
* score: of the cells whose peak exceeds ``gate`` pixels, the share that gave up more than
  ``letgo`` of it (soft steps, so that the numbers can train by gradient; sharp with ``softness`` 0);
* slip logit ``slope * (score - bias)``, the largest over sensors.

Four numbers (``gate``, ``letgo``, ``slope``, ``bias``) can be learned by gradient through soft steps; for a
new sensor it is made without gradient training (:attr:`ShearRetention.recipe`: sharp steps, ``gate`` and
``letgo`` chosen on the user's grasps, then the threshold). Made so on the shared gelsight-lift grasps,
on objects it was not made on it is right on 93% of the grasps (AUC 0.985; learned by gradient: 86%, AUC
0.954; the fine-tuned network: 84%, AUC 0.945; docs/new-sensor.md). It needs markers: on a gel without them the cells barely move and it never alarms.
The first frame pushed is the reference: reset the stream at the start of each grasp.
"""

from __future__ import annotations

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
from slipsense.models.streams import slip_probability

#: Doublings of the running maximum's window: peaks are exact over up to 2**20 frames (13 h at 20 fps).
_DOUBLINGS = 20
#: Softness of the gate (pixels) and of the share given up: narrow enough to act as steps.
_GATE_SOFTNESS, _LETGO_SOFTNESS = 0.1, 0.05


def _gaussian(sigma: float) -> Tensor:
    radius = max(1, int(round(3 * sigma)))
    t = torch.arange(-radius, radius + 1, dtype=torch.float32)
    g = torch.exp(-(t**2) / (2 * sigma**2))
    return g / g.sum()


def running_max(x: Tensor, dim: int) -> Tensor:
    """Cumulative maximum along ``dim`` by doubling windows (exportable to ONNX, which has no CumMax)."""
    x = x.movedim(dim, 0)
    at = torch.arange(x.shape[0], device=x.device)
    for k in (2**i for i in range(_DOUBLINGS)):  # the first frame stands in before the start
        x = torch.maximum(x, x.index_select(0, (at - k).clamp(min=0)))
    return x.movedim(0, dim)


class _Frame(ModelPart):
    def forward(self, reference: Tensor, gray: Tensor):
        return self.model.frame_shift(reference, gray)


class _Step(ModelPart):
    def forward(self, shift: Tensor, fresh: Tensor, peak: Tensor):
        peak = torch.where(fresh.reshape(1, 1, 1) > 0.5, shift, torch.maximum(peak, shift))
        return self.model.logits_of(shift, peak), peak


class ShearStream(GraspStream):
    """Keeps the marker map of the grasp's first frame and every cell's peak displacement: each push
    runs the frame part once (the current frame against that map) and one step, the same numbers as
    :meth:`ShearRetention.forward` (the first frame runs the frame part twice: once for its map)."""

    def reset(self) -> None:
        super().reset()
        self._reference = None
        self._peak = np.zeros((1, self.sensors, self.model.cells), np.float32)

    def push_gray(self, gray: np.ndarray) -> float:
        frame = (gray.astype(np.float32) / np.float32(255.0))[None]
        fresh = self._reference is None
        if fresh:
            self._reference = self._run("frame", np.zeros_like(frame), frame)[1]
        shift = self._run("frame", self._reference, frame)[0]
        logits, self._peak = self._run("step", shift, np.array([float(fresh)], np.float32), self._peak)
        return float(slip_probability(logits)[0])


@register("shear-retention")
class ShearRetention(GraspModel):
    """Slip as shear given up: see the module notes.

    It streams on PyTorch by default: its ONNX Runtime parts were slower (p50 7.8 against 6.1 ms per
    push of a 480 x 640 frame, one thread; ``python bench/bench_detector.py --threads 1``).

    Args:
        sensors: sensors per frame (2: both fingers; a slip on either is the grasp's).
        image_size: ``(h, w)`` of the grey frames; both divisible by ``patch``.
        patch: cell size in pixels (about one marker spacing).
        blur: sigma in pixels of the marker map's smoothing (the surroundings: 4x it).
        iterations: Lucas-Kanade warping steps (each moves a cell at most a pixel).
        gate: initial peak displacement, pixels, for a cell to count.
        letgo: initial share of its peak a cell must give up to count as let go.
        slope, bias: initial logit ``slope * (score - bias)``.
        softness: width of the gate's and the let-go share's steps, as a multiple of theirs for
            gradient training (1); 0: sharp steps, for a model whose numbers are chosen, not learned.
    """

    auto_backend = "torch"
    stream_class = ShearStream
    #: How it is made for a new sensor (training settings, ``slipsense train --set train.KEY``):
    #: no gradient training; ``gate`` and ``letgo`` are chosen among these on the user's grasps, then
    #: the threshold. Learning the four numbers by gradient on the 36 grasps of four objects ranked
    #: the held-out objects' grasps worse (ROC AUC 0.954, docs/new-sensor.md).
    recipe = {
        "epochs": 0,
        "inner_folds": 0,
        "model.softness": 0.0,
        "choose": {"gate": [0.3, 0.5, 1.0, 1.5], "letgo": [0.2, 0.3, 0.4, 0.6]},
    }

    adapt_cost = 10.0
    adapt_words = "shear retention: the shear the gel's markers give up (settings chosen on your grasps)"

    @classmethod
    def adapt_reason(cls, grasps) -> str | None:
        found, evidence = grasps.markers()
        return None if found else f"needs a gel with markers: {evidence}"

    def __init__(
        self,
        sensors: int = 2,
        image_size: Sequence[int] = (120, 160),
        patch: int = 10,
        blur: float = 1.0,
        iterations: int = 5,
        gate: float = 0.5,
        letgo: float = 0.4,
        slope: float = 20.0,
        bias: float = 0.15,
        softness: float = 1.0,
    ):
        super().__init__()
        image_size = tuple(int(v) for v in image_size)
        patch, iterations = int(patch), int(iterations)
        if len(image_size) != 2 or not 2 <= patch <= 64 or any(v % patch or v // patch < 2 for v in image_size):
            raise ConfigError(
                f"shear-retention: image_size must be (h, w), each at least 2 cells of patch 2..64 pixels "
                f"and divisible by it, got {image_size} and patch {patch}"
            )
        if image_size[0] * image_size[1] > 512 * 512:
            raise ConfigError(f"shear-retention: image_size {image_size} is over 512 x 512 pixels")
        if not 1 <= int(sensors) <= 8 or not 1 <= iterations <= 20 or not 0.3 <= float(blur) <= 8:
            raise ConfigError(
                f"shear-retention: sensors 1..8, iterations 1..20 and blur 0.3..8 pixels, "
                f"got {sensors}, {iterations}, {blur}"
            )
        numbers = {"blur": blur, "gate": gate, "letgo": letgo, "slope": slope, "bias": bias, "softness": softness}
        if not all(np.isfinite(float(v)) for v in numbers.values()):
            raise ConfigError(f"shear-retention: {', '.join(numbers)} must be finite numbers, got {numbers}")
        self.sensors, self.image_size, self.patch = int(sensors), image_size, patch
        if not 0 <= float(softness) <= 10:
            raise ConfigError(f"shear-retention: softness must be in 0..10, got {softness}")
        self.blur, self.iterations, self.softness = float(blur), iterations, float(softness)
        self._init = {"gate": float(gate), "letgo": float(letgo), "slope": float(slope), "bias": float(bias)}
        for name, value in self._init.items():  # the four numbers gradient training can learn
            setattr(self, name, nn.Parameter(torch.tensor(value)))
        self.register_buffer("_fine", _gaussian(self.blur), persistent=False)
        self.register_buffer("_coarse", _gaussian(4 * self.blur), persistent=False)
        h, w = image_size
        ys, xs = torch.meshgrid(torch.linspace(-1, 1, h), torch.linspace(-1, 1, w), indexing="ij")
        self.register_buffer("_grid", torch.stack([xs, ys], dim=-1)[None], persistent=False)  # (1, h, w, 2)
        # a displacement of one pixel, in grid_sample's [-1, 1] coordinates
        self.register_buffer("_pixel", torch.tensor([2.0 / (w - 1), 2.0 / (h - 1)]), persistent=False)

    @classmethod
    def small_config(cls) -> dict:
        return {"image_size": [40, 60]}

    def config(self) -> dict:
        out = {"sensors": self.sensors, "image_size": list(self.image_size), "patch": self.patch, "blur": self.blur}
        return {**out, "iterations": self.iterations, "softness": self.softness, **self._init}

    @property
    def cells(self) -> int:
        return (self.image_size[0] // self.patch) * (self.image_size[1] // self.patch)

    def _smooth(self, x: Tensor, kernel: Tensor) -> Tensor:
        r = kernel.shape[0] // 2
        x = F.conv2d(F.pad(x, (r, r, 0, 0), mode="replicate"), kernel.view(1, 1, 1, -1))
        return F.conv2d(F.pad(x, (0, 0, r, r), mode="replicate"), kernel.view(1, 1, -1, 1))

    def markers(self, gray: Tensor) -> Tensor:
        """``(B, 1, h, w)`` grey in [0, 1] -> marker map ``(B, 1, h, w)``: darker than the surroundings."""
        return self._smooth(F.relu(self._smooth(gray, self._coarse) - gray), self._fine)

    def displacements(self, ref: Tensor, cur: Tensor) -> Tensor:
        """Marker maps of reference frames ``(R, 1, h, w)`` and of ``n`` frames each ``(R, n, h, w)``
        -> per frame and cell the length of its shift from the reference, pixels, ``(R, n, C)``."""
        fx, fy = self.cell_shifts(ref, cur)
        return (fx.square() + fy.square()).add(1e-12).sqrt().flatten(2)

    def cell_shifts(self, ref: Tensor, cur: Tensor) -> tuple[Tensor, Tensor]:
        """As :meth:`displacements`, the shift itself: x and y, pixels, each ``(R, n, h / patch, w / patch)``."""
        p, (h, w) = self.patch, self.image_size
        pad_x, pad_y = F.pad(ref, (1, 1, 0, 0), mode="replicate"), F.pad(ref, (0, 0, 1, 1), mode="replicate")
        gx, gy = (pad_x[..., 2:] - pad_x[..., :-2]) / 2, (pad_y[..., 2:, :] - pad_y[..., :-2, :]) / 2
        a, b, c = F.avg_pool2d(gx * gx, p), F.avg_pool2d(gx * gy, p), F.avg_pool2d(gy * gy, p)  # (R, 1, h/p, w/p)
        det = a * c - b * b + 1e-9
        fx = F.avg_pool2d(cur, p) * 0.0  # the cells' shift (R, n, h/p, w/p), pixels
        fy = fx
        for _ in range(self.iterations):
            dense = torch.stack(
                [F.interpolate(fx, scale_factor=float(p)), F.interpolate(fy, scale_factor=float(p))], -1
            )
            grid = (self._grid + dense * self._pixel).reshape(-1, h, w, 2)  # (R n, h, w, 2)
            warped = F.grid_sample(cur.reshape(-1, 1, h, w), grid, padding_mode="border", align_corners=True)
            diff = warped.reshape(cur.shape) - ref
            bx, by = F.avg_pool2d(gx * diff, p), F.avg_pool2d(gy * diff, p)
            fx = fx + ((b * by - c * bx) / det).clamp(-1.0, 1.0)
            fy = fy + ((b * bx - a * by) / det).clamp(-1.0, 1.0)
        return fx, fy

    def frame_shift(self, reference: Tensor, gray: Tensor) -> tuple[Tensor, Tensor]:
        """The frame part: the marker map of the grasp's first frame ``(B, S, h, w)`` (kept by the
        stream) and a grey frame ``(B, S, h, w)`` -> (cell displacements ``(B, S, C)``, the frame's
        marker map ``(B, S, h, w)``)."""
        b = gray.shape[0]
        cur = self.markers(rearrange(gray, "b s h w -> (b s) 1 h w"))
        shift = self.displacements(rearrange(reference, "b s h w -> (b s) 1 h w"), cur)
        return rearrange(shift, "(b s) 1 c -> b s c", b=b), rearrange(cur, "(b s) 1 h w -> b s h w", b=b)

    def logits_of(self, shift: Tensor, peak: Tensor) -> Tensor:
        """Cell displacements and their peaks so far ``(..., S, C)`` -> logits ``(..., 2)``."""
        moved = self._step(peak - self.gate, _GATE_SOFTNESS)
        given_up = F.relu(peak - shift) / (peak + 0.05)
        let_go = self._step(given_up - self.letgo, _LETGO_SOFTNESS)
        score = (moved * let_go).sum(dim=-1) / (moved.sum(dim=-1) + 1.0)  # one cell's worth: no motion, no alarm
        logit = (self.slope * (score - self.bias)).amax(dim=-1)
        return torch.stack([torch.zeros_like(logit), logit], dim=-1)

    def _step(self, x: Tensor, width: float) -> Tensor:
        """0 below 0, 1 above: a sigmoid ``width * softness`` wide, or sharp (softness 0)."""
        return torch.sigmoid(x / (width * self.softness)) if self.softness > 0 else (x > 0).to(x.dtype)

    def forward(self, gray: Tensor) -> Tensor:
        """``(B, S, N, h, w)`` grey frames in [0, 1] -> ``(B, N, 2)`` slip logits at every frame."""
        self.check_input(gray)
        shift = self.tracked(gray)
        return self.logits_of(shift, running_max(shift, dim=1))

    def tracked(self, gray: Tensor) -> Tensor:
        """``(B, S, N, h, w)`` -> every cell's shift from the first frame ``(B, N, S, C)``, pixels.

        Frames tracked before are looked up (:mod:`slipsense.models.tracking`): the shifts depend on the
        frames and the tracking settings only, not on ``gate``, ``letgo`` or the logit (no gradient flows
        into them), so choosing those on a user's grasps (``recipe["choose"]``: 16 pairs) tracks each
        grasp once, not 16 times, and gradient training tracks each run once, not once per epoch."""
        settings = (self.patch, self.blur, self.iterations, list(self.image_size))
        return tracking.tracked("shear-retention", gray, settings, lambda g: (self._track(g),), not self.training)[0]

    def _track(self, gray: Tensor) -> Tensor:
        b, s = gray.shape[:2]
        ref = self.markers(rearrange(gray[:, :, 0], "b s h w -> (b s) 1 h w"))
        cur = self.markers(rearrange(gray, "b s n h w -> (b s n) 1 h w"))
        shift = self.displacements(ref, rearrange(cur, "(r n) 1 h w -> r n h w", r=b * s))
        return rearrange(shift, "(b s) n c -> b n s c", b=b)

    def chunk_logits(self, runs: Sequence[tuple[Tensor, Sequence[int]]], n_out: int) -> Tensor:
        """Logits of chunks of whole runs (each run's frames computed once); see
        :meth:`GraspModel.chunk_logits`."""
        out = []
        for gray, ends in runs:
            rows = self.chunk_rows(gray, ends, n_out)
            out.append(self(gray[None])[0][rows])
        return torch.cat(out)

    def streaming_modules(self, geometry=None) -> dict[str, nn.Module]:
        """``frame``: the first frame's marker map and the current frame ``(1, S, h, w)`` -> cell
        displacements ``(1, S, C)`` and the frame's marker map;
        ``step``: the displacements, ``fresh (1,)`` and the peaks so far -> logits ``(1, 2)``, new peaks."""
        return {"frame": _Frame(self), "step": _Step(self)}

    def onnx_parts(self, geometry=None, batch: int | None = None) -> dict:
        g = torch.Generator().manual_seed(0)
        b = batch or 1
        gray = torch.rand(b, self.sensors, 6, *self.image_size, generator=g)
        frame = torch.rand(1, self.sensors, *self.image_size, generator=g)
        shift = torch.rand(1, self.sensors, self.cells, generator=g)
        free = {} if batch is not None else {0: "batch"}
        return {
            "model": OnnxPart(
                self, (gray,), ["gray"], ["logits"], {"gray": {**free, 2: "frames"}, "logits": {**free, 1: "frames"}}
            ),
            "frame": OnnxPart(_Frame(self), (frame, frame.flip(-1)), ["reference", "gray"], ["shift", "markers"], {}),
            "step": OnnxPart(
                _Step(self), (shift, torch.zeros(1), shift * 2), ["shift", "fresh", "peak"], ["logits", "peak_next"], {}
            ),
        }
