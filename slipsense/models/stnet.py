"""STNet and TemNet: slip detection from marker point clouds (paper: STNet, section II.B).

Input ``(B, T, M, 3)``: the 3-D positions (mm) of ``M`` markers over ``T`` frames; the paper uses
T = 12 frames of M = 552 markers (23 x 24), flattened per frame to ``12 x 1656``.

    x (B, T, M, 3) --flatten--> x_i (B, T, 1656)
      |- S codecs (per frame, Conv1d) --> S_i (B, T, 1656)       [STNet only]
      a_i = FC(Concat(S_i, x_i))  (eq. 5, "fusion")             [TemNet: a_i = x_i]
      a_i + learned frame embedding
      m x MSA block (8 heads, dropout, feed-forward)  --> [b] (B, T, d)
      classifier on the flattened [b] --> (B, 2) logits, class 1 = slip

Reading of the paper and the choices it leaves open
---------------------------------------------------
* S codecs (Fig. 3): the encoder is 4 Conv1d(stride 2) + LeakyReLU(k=0.01) layers, so the 1656
  values of a frame shrink to 1/16 of their length (1656 -> 828 -> 414 -> 207 -> 104) with
  ``codec_channels`` channels; the decoder is upsampling (x16) -> Conv1d -> pooling (adaptive
  average pooling back to exactly 1656) -> LeakyReLU. Each frame is coded on its own ("single
  sample features"), frames ride in the batch axis.
* Fusion: Concat(S_i, x_i) (2 x 1656) -> one fully connected layer to ``d_model``. TemNet has no
  codecs and no fusion layer ("inputs the original sequence directly into the MSA"); it only gets a
  projection when a compact ``d_model != markers * 3`` is asked for.
* "The input [a] passes through the embedding layer": read as a learned embedding of the frame
  index added to a_i (self-attention is otherwise blind to frame order, and slip is a process in
  time). 12 x 1656 parameters.
* MSA block: 8 heads, dropout, and a feed-forward layer, post-norm - what
  ``nn.TransformerEncoderLayer(d_model, 8)`` builds, the layer a PyTorch port of the paper uses.
* Head: "[b] is fed into the fully connected layer for binary classification": the whole (T x d)
  output, flattened (``pool="flatten"``), goes to the classifier. ``pool="mean"`` (mean over
  frames) and ``"last"`` (last frame) are offered for compact models.
* Sizes the paper does not give. A direct port of the authors' network had ~129 M parameters, which
  pins the feed-forward width and the classifier. Per block, attention costs 4d^2 + 4d = 10.98 M
  (d = 1656), a feed-forward of width f costs 2df + f + d; the fusion layer costs 5.49 M:

  ====================================================  ==========  =============
  candidate (5 blocks, d = 1656)                         parameters  GFLOP/sample
  ====================================================  ==========  =============
  f = 2048 (PyTorch default), FC 19872 -> 2                94.4 M       2.28
  f = 2048, classifier FC 19872 -> 1656 -> 2  ("paper")   127.3 M       2.35
  f = 4096, FC 19872 -> 2  ("paper-ff4096")               128.3 M       3.10
  f = 4d = 6624, FC 19872 -> 2                            170.2 M       4.10
  ====================================================  ==========  =============

  Two readings reach ~129 M. "paper" takes f = 2048 and a two-layer classifier: it keeps the
  encoder layer's default width (what a port that sets only d_model and 8 heads gets) and puts the
  remaining 33 M in a classifier that compresses the flattened sequence back to d_model. It is also
  the one consistent with the speed the direct port was measured at on this machine (batch 64 at
  >= 82 samples/s x 2.35 GFLOP = the ~190 GFLOP/s this CPU's matmul reaches; 3.1 GFLOP/sample would
  need 250+, above its peak). The other reading (one FC head as the text says, f = 4096) is the
  "paper-ff4096" preset. ``studies/stnet/size.py`` gives the exact count of any configuration.
* Xavier-normal init of every Linear and Conv1d weight, zero biases (paper, section III.B). The
  paper's training setup (Adam, lr 1e-5, batch 64, cross-entropy, 80/20 split) is the trainer's.

Speed (CPU inference)
---------------------
Training uses the plain modules below; inference copies with oneDNN-packed, bf16 or int8 weights are
made by :mod:`slipsense.models.stnet_fast` (at batch 1 the packed oneDNN kernel reaches ~3/4 of the
machine's matmul speed on the network's 12 rows x ~94 M weights, the default BLAS call ~1/3).
Attention is one fused qkv Linear + ``F.scaled_dot_product_attention``; the S-codec decoder's
one-channel convolution over the upsampled signal is computed on the short signal
(:class:`UpsampleConv1d`). Measurements: ``bench/bench_stnet.py``.

Heat maps
---------
The MSA attends over the T frames, not over the sensor surface, so a heat map over the surface needs
an attribution to markers: :meth:`STNet.marker_saliency` is gradient x input-displacement (see its
docstring).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from einops import rearrange, repeat
from einops.layers.torch import Rearrange

from slipsense.errors import ConfigError, InputError
from slipsense.models.base import MarkerModel, register
from slipsense.models.stnet_fast import optimize_for_inference, quantize_dynamic_int8
from slipsense.models.stnet_parts import MarkerFramePart, MarkerWindowPart
from slipsense.sensors.marker_grid import rest_estimate

POOLS = ("flatten", "mean", "last")
ACTIVATIONS = {"relu": nn.ReLU, "gelu": nn.GELU}
#: Settings that count something: positive integers.
_COUNTS = "frames markers d_model heads blocks ff_dim codec_channels codec_kernel codec_layers num_classes".split()

#: Named configurations. "paper": every layer as section II.B describes, sizes it leaves open
#: chosen to match the direct port's ~129 M parameters (127,268,027 for STNet; see the module
#: docstring); "paper-ff4096": the other reading that reaches ~129 M (128,319,891); "compact":
#: trains in minutes on 2 CPU cores (~0.7 M parameters, most in the fusion layer that reads the
#: raw 1656 values; beyond the paper, it reads positions against the gel at rest, ``centred``).
_PAPER: dict[str, Any] = dict(frames=12, markers=552, d_model=1656, heads=8, blocks=5, ff_dim=2048, head_hidden=1656)
_PAPER.update(dropout=0.1, codec_channels=16, codec_kernel=3, codec_layers=4, pool="flatten", activation="relu")
_COMPACT = dict(_PAPER, d_model=128, heads=4, blocks=2, ff_dim=256, head_hidden=0, codec_channels=8, centred=True)
PRESETS: dict[str, dict[str, Any]] = {"paper": _PAPER, "paper-ff4096": {**_PAPER, "ff_dim": 4096, "head_hidden": 0}}
PRESETS["compact"] = _COMPACT


class UpsampleConv1d(nn.Module):
    """``nn.Upsample(scale)`` then ``nn.Conv1d(channels, 1, kernel, padding=kernel // 2)``: same
    parameters, same result, computed cheaply. Mixing the channels commutes with nearest
    upsampling, so each of the ``kernel`` taps is mixed on the short signal, upsampled, and the taps
    are added shifted. (oneDNN runs a one-output-channel convolution over the long signal several
    times slower than all of this.)"""

    def __init__(self, channels, scale, kernel):
        super().__init__()
        self.scale, self.kernel = scale, kernel
        self.weight = nn.Parameter(torch.empty(1, channels, kernel))
        self.bias = nn.Parameter(torch.zeros(1))

    def forward(self, z):  # (n, c, l) -> (n, 1, l * scale)
        taps = torch.einsum("ncl,ck->nkl", z, self.weight[0])
        taps = repeat(taps, "n k l -> n k (l s)", s=self.scale)
        pad = self.kernel // 2
        taps = F.pad(taps, (pad, pad))
        length = taps.shape[-1] - 2 * pad
        out = sum(taps[:, j, j : j + length] for j in range(self.kernel))
        return rearrange(out + self.bias, "n l -> n 1 l")


class SCodecs(nn.Module):
    def __init__(self, length, channels=16, kernel=3, layers=4):
        super().__init__()
        pad = kernel // 2
        enc = []
        for i in range(layers):
            enc += [nn.Conv1d(1 if i == 0 else channels, channels, kernel, stride=2, padding=pad), nn.LeakyReLU(0.01)]
        self.encoder = nn.Sequential(*enc)  # length L -> ceil(L / 2**layers)
        self.decoder = nn.Sequential(
            UpsampleConv1d(channels, 2**layers, kernel),  # upsampling + Conv1d, back to >= L
            nn.AdaptiveAvgPool1d(length),  # pooling: exactly L
            nn.LeakyReLU(0.01),
        )

    def forward(self, x):  # (b, t, d)
        b = x.shape[0]
        x = rearrange(x, "b t d -> (b t) 1 d")
        x = self.decoder(self.encoder(x))
        return rearrange(x, "(b t) 1 d -> b t d", b=b)


class Attention(nn.Module):
    def __init__(self, dim, heads=8, dropout=0.0):
        super().__init__()
        self.heads = heads
        self.dropout = dropout
        self.to_qkv = nn.Linear(dim, dim * 3)  # W^Q, W^K, W^V in one matmul (eq. 6a)
        self.to_out = nn.Linear(dim, dim)

    def forward(self, x):  # (b, n, d)
        qkv = self.to_qkv(x)
        q, k, v = rearrange(qkv, "b n (three h d) -> three b h n d", three=3, h=self.heads)
        # softmax(QK^T / sqrt(d_k)) V, eq. 6b
        out = F.scaled_dot_product_attention(q, k, v, dropout_p=self.dropout if self.training else 0.0)
        return self.to_out(rearrange(out, "b h n d -> b n (h d)"))


class Block(nn.Module):
    """Post-norm transformer encoder layer (as nn.TransformerEncoderLayer, same parameters)."""

    def __init__(self, dim, heads, ff_dim, dropout, activation="relu"):
        super().__init__()
        self.attn = Attention(dim, heads, dropout)
        self.norm1 = nn.LayerNorm(dim)
        self.ff = nn.Sequential(
            nn.Linear(dim, ff_dim), ACTIVATIONS[activation](), nn.Dropout(dropout), nn.Linear(ff_dim, dim)
        )
        self.norm2 = nn.LayerNorm(dim)
        self.drop = nn.Dropout(dropout)

    def forward(self, x):
        x = self.norm1(x + self.drop(self.attn(x)))
        return self.norm2(x + self.drop(self.ff(x)))


@register("stnet")
class STNet(MarkerModel):
    """STNet (``use_codecs=True``) / TemNet (``use_codecs=False``): see the module docstring."""

    paper_training = dict(epochs=100, batch_size=64, lr=1e-5, weight_decay=0.0, step_size=1000, gamma=1.0)
    #: the compact network learns at ten times the paper's rate, and in few epochs over the moved
    #: copies of its windows (studies/docs/simulator.md)
    preset_training = {"compact": dict(epochs=5, batch_size=32, lr=1e-4)}
    presets = PRESETS

    def __init__(
        self,
        frames=12,
        markers=552,
        d_model=None,
        heads=8,
        blocks=5,
        ff_dim=2048,
        head_hidden=None,
        dropout=0.1,
        codec_channels=16,
        codec_kernel=3,
        codec_layers=4,
        pool="flatten",
        activation="relu",
        num_classes=2,
        use_codecs=True,
        relative=False,
        centred=False,
    ):
        super().__init__()
        d_in = markers * 3
        d_model = d_in if d_model is None else d_model
        head_hidden = d_model if head_hidden is None else head_hidden
        c = self._config = dict(frames=frames, markers=markers, d_model=d_model, heads=heads, blocks=blocks)
        c.update(ff_dim=ff_dim, head_hidden=head_hidden, dropout=dropout, codec_channels=codec_channels)
        c.update(codec_kernel=codec_kernel, codec_layers=codec_layers, pool=pool, activation=activation)
        c.update(num_classes=num_classes, use_codecs=use_codecs)
        for key in _COUNTS:
            if not isinstance(c[key], int) or isinstance(c[key], bool) or c[key] < 1:
                raise ConfigError(f"{key} must be a positive integer, got {c[key]!r}")
        if not isinstance(c["head_hidden"], int) or isinstance(c["head_hidden"], bool) or c["head_hidden"] < 0:
            raise ConfigError(f"head_hidden must be an integer >= 0 (0: one FC layer), got {c['head_hidden']!r}")
        if c["d_model"] % c["heads"]:
            raise ConfigError(f"d_model ({c['d_model']}) must be divisible by heads ({c['heads']})")
        if c["codec_kernel"] % 2 == 0:
            raise ConfigError(f"codec_kernel must be odd, got {c['codec_kernel']}")
        if c["num_classes"] < 2:
            raise ConfigError(f"num_classes must be >= 2, got {c['num_classes']}")
        if not 0 <= c["dropout"] < 1:
            raise ConfigError(f"dropout must be in [0, 1), got {c['dropout']!r}")
        if c["pool"] not in POOLS:
            raise ConfigError(f"pool must be one of {POOLS}, got {c['pool']!r}")
        if c["activation"] not in ACTIVATIONS:
            raise ConfigError(f"activation must be one of {tuple(ACTIVATIONS)}, got {c['activation']!r}")
        if relative:  # only stored when set, so checkpoints of the paper's network keep their config
            self._config["relative"] = True
        if centred and relative:
            raise ConfigError(
                "stnet: centred and relative are two references; choose one (the compact preset sets "
                "centred=true: add --set centred=false for relative input)"
            )
        if centred:  # beyond the paper: positions against a reference fitted on the training windows
            self._config["centred"] = True
            self.register_buffer("reference", torch.zeros(markers, 3))
        self.centred = bool(centred)
        self.frames, self.markers, self.pool, self.use_codecs = frames, markers, pool, use_codecs
        # Beyond the paper: feed each frame's displacement from the window's first frame instead of
        # absolute positions. Slip shows as 0.1-1 mm motions on a +-11 mm grid; relative input puts
        # them at the scale the first layers see.
        self.relative = bool(relative)

        self.to_frames = Rearrange("b t m c -> b t (m c)")  # x_i: (b, t, 1656), a view
        if use_codecs:
            self.codecs = SCodecs(d_in, codec_channels, codec_kernel, codec_layers)
            self.fuse = nn.Linear(2 * d_in, d_model)  # a_i = FC(Concat(S_i, x_i))
        else:
            self.codecs = None
            self.fuse = nn.Linear(d_in, d_model) if d_model != d_in else nn.Identity()
        self.pos_embedding = nn.Parameter(torch.empty(1, frames, d_model))
        self.blocks = nn.ModuleList([Block(d_model, heads, ff_dim, dropout, activation) for _ in range(blocks)])
        head_in = frames * d_model if pool == "flatten" else d_model
        if head_hidden:  # FC -> ReLU -> dropout -> FC
            self.to_logits = nn.Sequential(
                nn.Linear(head_in, head_hidden), nn.ReLU(), nn.Dropout(dropout), nn.Linear(head_hidden, num_classes)
            )
        else:
            self.to_logits = nn.Linear(head_in, num_classes)
        self.reset_parameters()

    def reset_parameters(self):
        """Xavier-normal weights, zero biases (paper); frame embedding N(0, 0.02)."""
        for m in self.modules():
            if isinstance(m, (nn.Linear, nn.Conv1d, UpsampleConv1d)):
                nn.init.xavier_normal_(m.weight)
                if m.bias is not None:
                    nn.init.zeros_(m.bias)
        nn.init.normal_(self.pos_embedding, std=0.02)

    def check_input(self, x) -> None:
        """Raise InputError unless ``x`` is a finite float tensor (B, frames, markers, 3)."""
        want = f"(B, {self.frames}, {self.markers}, 3)"
        if not isinstance(x, torch.Tensor):
            raise InputError(None, f"expected a torch.Tensor {want}, got {type(x).__name__}")
        if x.ndim != 4:
            raise InputError(None, f"expected marker positions {want}, got {x.ndim}-D shape {tuple(x.shape)}")
        b, t, m, c = x.shape
        if b < 1 or t != self.frames or m != self.markers or c != 3:
            raise InputError(None, f"expected marker positions {want}, got shape {tuple(x.shape)}")
        if not x.is_floating_point():
            raise InputError(None, f"expected float marker positions, got dtype {x.dtype}")
        bad = ~torch.isfinite(x)
        if bad.any():
            i, f, k, _ = (int(v) for v in bad.nonzero()[0])
            value = x[i, f, k][bad[i, f, k]][0].item()
            raise InputError(None, f"non-finite marker position ({value}) at sample {i}, frame {f}, marker {k}")

    def _tokens(self, x):  # (b, t, m, 3) -> a: (b, t, d)
        x = x.to(self.pos_embedding.dtype)
        if self.relative:
            x = x - x[:, :1]
        if self.centred:
            x = x - self.reference
        x = self.to_frames(x)
        if self.codecs is not None:
            x = torch.cat((self.codecs(x), x), dim=-1)  # eq. 5
        return self.fuse(x) + self.pos_embedding

    def _head(self, x):  # [b]: (b, t, d) -> (b, classes)
        if self.pool == "flatten":
            x = rearrange(x, "b t d -> b (t d)")
        elif self.pool == "mean":
            x = x.mean(dim=1)
        else:
            x = x[:, -1]
        return self.to_logits(x).float()

    def forward(self, x):
        x = self._tokens(x)
        for block in self.blocks:
            x = block(x)
        return self._head(x)

    @classmethod
    def small_config(cls) -> dict:
        return dict(PRESETS["compact"], frames=4, markers=24)

    @torch.no_grad()
    def prepare(self, train_data) -> None:
        """With ``centred``: the reference is the gel at rest estimated from the training windows'
        first frames (up to 2048 of them; :func:`~slipsense.sensors.marker_grid.rest_estimate`). The standing shear of a steadily
        sliding contact then shows as an offset from it (studies/docs/simulator.md: the within-window motion
        alone stops when sliding is steady)."""
        n = getattr(train_data, "windows", len(train_data))  # the originals, not a dataset's moved copies
        if not self.centred or n == 0:
            return
        take = np.linspace(0, n - 1, min(n, 2048)).round().astype(int)
        first = np.stack([np.asarray(train_data[int(i)][0], dtype=np.float32)[0] for i in np.unique(take)])
        self.reference.copy_(torch.from_numpy(rest_estimate(first)))

    def streaming_parts(self) -> tuple[nn.Module | None, nn.Module]:
        if self.relative:  # every frame is seen relative to its window's first one: nothing to cache
            return None, self
        return MarkerFramePart(self), MarkerWindowPart(self)

    attention_map = "marker saliency against the gel at rest"

    def attention(self, window: torch.Tensor):
        """Marker saliency of the window against the gel at rest, ``(M,)``, max 1 (:meth:`marker_saliency`)."""
        return self.marker_saliency(window, baseline="rest")[0].detach().numpy()

    def reduced_precision(self, precision: str) -> nn.Module:
        if precision == "int8":
            return quantize_dynamic_int8(self)
        if precision == "bfloat16":
            return optimize_for_inference(self, torch.bfloat16)
        return super().reduced_precision(precision)

    def marker_saliency(self, x, target: int = 1, baseline: str | torch.Tensor = "first") -> torch.Tensor:
        """Relevance of each marker for class ``target`` (default 1 = slip): a (B, M) heat map.

        Method: gradient x input relative to a baseline, the first-order term of integrated gradients,

            R[b, m] = | sum_{t, c} dlogit_target / dx[b, t, m, c] * (x[b, t, m, c] - x0[b, t, m, c]) |

        with baseline ``x0`` = the first frame held still (``"first"``, default; so R measures how
        the displacement of marker m since frame 1 moves the slip logit), the gel at rest of a
        ``centred`` model (``"rest"``: its displacement from rest, which shows a steady slide's
        standing shear; the first frame for other models), ``"zero"``, or a tensor broadcastable
        to ``x``. Absolute positions in mm are not a meaningful "input" to attribute
        (a marker 20 mm off the origin is not 20x as relevant), displacements are. Each sample's
        map is scaled to max 1 (all zeros stays zeros). Runs in eval mode with gradients; not
        available on a model made by :func:`optimize_for_inference`. Reshape to (23, 24) for the
        paper's sensor grid.
        """
        self.check_input(x)
        if getattr(self, "inference_only", False):
            raise ConfigError(
                "marker_saliency needs gradients: call it on the trainable model, "
                "not on the copy optimize_for_inference made"
            )
        if isinstance(baseline, torch.Tensor):
            x0 = baseline.to(x)
        elif baseline == "first":
            x0 = x[:, :1].expand_as(x)
        elif baseline == "zero":
            x0 = torch.zeros_like(x)
        elif baseline == "rest":  # the gel at rest a centred model reads against, else the first frame
            x0 = self.reference.expand_as(x) if self.centred else x[:, :1].expand_as(x)
        else:
            raise ConfigError(
                f"marker_saliency: baseline must be 'first', 'rest', 'zero' or a tensor, got {baseline!r}"
            )
        was_training = self.training
        self.eval()
        try:
            with torch.enable_grad():
                xg = x.detach().float().requires_grad_(True)
                logits = self(xg)
                (grad,) = torch.autograd.grad(logits[:, target].sum(), xg)
        finally:
            self.train(was_training)
        rel = (grad * (xg.detach() - x0.float())).sum(dim=(1, 3)).abs()  # (b, m)
        return rel / rel.amax(dim=1, keepdim=True).clamp_min(torch.finfo(rel.dtype).tiny)


@register("temnet")
class TemNet(STNet):
    """The paper's ablation: STNet without the S codecs (and so without the fusion layer)."""

    def __init__(self, **kwargs):
        if "use_codecs" in kwargs:
            raise TypeError("TemNet has no S codecs; use_codecs is not a TemNet setting")
        super().__init__(use_codecs=False, **kwargs)
        del self._config["use_codecs"]
