"""ViViT, factorised encoder: a spatial transformer per frame, then a temporal transformer.

The network of the GelSight incipient-slip study (Parag, Adelson, Misimi): the study built it with
vit-pytorch's ``ViViT`` at 240 x 320 input, 40 x 40 patches, ``dim=8``, 2 spatial + 2 temporal layers,
2 heads, ``mlp_dim=8`` ("8 neurons in the hidden layers"; the study's ``train.py`` passes
``mlp_dim=8``), the vit-pytorch defaults ``dim_head=64``, ``pool="cls"``, no dropout, 2 classes.
This file computes the same function as vit-pytorch 1.26's ``ViViT(variant="factorized_encoder",
frame_patch_size=1)`` (uniform frame sampling: one token sequence per frame), written for speed on a
CPU at batch 1::

    video (B, T, 3, H, W)
      -> patches of every frame               (B*T, P, 3*ph*pw)          P = (H/ph) * (W/pw)
      -> LayerNorm(3*ph*pw) -> Linear -> LayerNorm(dim)                  (B*T, P, dim)
      -> + pos_embedding[t]                   per frame slot t and patch (positions="factorised": per patch)
      -> [spatial CLS] + tokens -> spatial transformer -> CLS (or mean)  (B, T, dim)    encode_frames
      -> (+ temporal_pos_embedding[t], positions="factorised" only)
      -> [temporal CLS] + frames -> temporal transformer -> CLS (or mean)
      -> Linear(dim, num_classes)                                        (B, num_classes) classify_frames

Speed (CPU inference). vit-pytorch cuts the patches out with a rearrange that gathers every
channel-last ``(p1 p2 c)`` value one float at a time, then runs LayerNorm over 4800-value rows and a
Linear: about 80 % of its time at the paper size.
Here (:meth:`ViViT._embed_fused`) the patches are copied in ``(c p1 p2)`` order and projected by one
matrix product with the patch LayerNorm folded in, as accurate as ``F.layer_norm`` (measured: closer
to a float64 reference than vit-pytorch's own float32 path). In eval mode without autograd the
attention folds ``dim_head`` away (see :class:`Attention`) and the last layer of each transformer
computes only the CLS row; training runs vit-pytorch's attention.
The parameters stay an ordinary ``LayerNorm`` + ``Linear`` (same shapes and ``(p1 p2 c)`` layout as
vit-pytorch), so training, weight decay and checkpoints are normal; ``fused=False`` runs the
straightforward patch embedding instead.
``bench/bench_vivit.py`` measures both against vit-pytorch. ONNX export (legacy and dynamo) works:
caches and scratch buffers are used only in eager inference.

Differences from vit-pytorch (all outside the paper configuration's inference path): attention
dropout is applied only in training mode (vit-pytorch passes it to ``scaled_dot_product_attention``
even in eval); no tubelets (``frame_patch_size`` is always 1); no temporal mask; the clip must have
exactly ``frames`` frames of exactly ``image_size``. Input is ``(B, T, C, H, W)``, vit-pytorch's is
``(B, C, T, H, W)``.

Streaming. With the paper's (vit-pytorch's) position embedding, ``positions="slot"``, the
embedding depends on the frame's *slot* in the clip, so a frame's ``encode_frames`` token is only
reusable while the frame stays in the same slot. What can be cached per frame regardless of slot is
:meth:`ViViT.embed_patches` (the patch tokens before the position embedding);
:meth:`ViViT.encode_patches` then finishes a clip. ``positions="factorised"`` (beyond the paper)
splits the embedding in two: one spatial embedding per patch, shared by every frame, and one
temporal embedding per slot added to the frame tokens before the temporal transformer. A frame's
spatial token is then the same in every slot, so a streaming detector encodes each frame once
(patch embedding *and* spatial transformer) and reruns only the temporal transformer per window.
"""

from __future__ import annotations

import copy
import threading
import types
from typing import Any, Sequence

import torch
import torch.nn.functional as F
from einops import rearrange, repeat
from torch import Tensor, nn

from slipsense.errors import ConfigError, InputError
from slipsense.models.base import VideoModel, register
from slipsense.models.vivit_layers import Transformer, cached, eager_inference
from slipsense.models.vivit_parts import ViViTFramePart, ViViTWindowPart, conv_embed_patches


def pair(value: int | Sequence[int]) -> tuple[int, int]:
    """``8 -> (8, 8)``; ``(240, 320) -> (240, 320)`` (lists too, as configs come back from JSON)."""
    if isinstance(value, int):
        return (value, value)
    a, b = value
    return (int(a), int(b))


POSITIONS = ("slot", "factorised")


@register("vivit")
class ViViT(VideoModel):
    """Factorised-encoder ViViT for ``(B, T, 3, H, W)`` clips; logits ``(B, num_classes)``, class 1 = slip.

    Keyword config (defaults: the paper's model): ``image_size=(240, 320)``, ``patch_size=(40, 40)``,
    ``frames=5``, ``dim=8``, ``spatial_depth=2``, ``temporal_depth=2``, ``heads=2``, ``dim_head=64``,
    ``mlp_dim=8``, ``pool="cls"`` (or ``"mean"``), ``dropout=0.0``, ``emb_dropout=0.0``,
    ``channels=3``, ``num_classes=2``, ``positions="slot"`` (vit-pytorch's ``(frames, P, dim)``
    position embedding) or ``"factorised"`` (a ``(P, dim)`` spatial and a ``(frames, dim)`` temporal
    embedding: every frame encodes to the same spatial token in every slot, see the module notes).

    ``fused`` (attribute, not config): True (default) embeds patches with the folded fast path;
    False with the straightforward rearrange + LayerNorm + Linear.
    """

    slot_tokens = True  # the slot position embedding: a frame's spatial token depends on its slot
    paper_training = dict(epochs=75, batch_size=16, lr=3e-4, weight_decay=1e-4, step_size=30, gamma=0.1)

    def __init__(
        self,
        *,
        image_size: int | Sequence[int] = (240, 320),
        patch_size: int | Sequence[int] = (40, 40),
        frames: int = 5,
        dim: int = 8,
        spatial_depth: int = 2,
        temporal_depth: int = 2,
        heads: int = 2,
        dim_head: int = 64,
        mlp_dim: int = 8,
        pool: str = "cls",
        dropout: float = 0.0,
        emb_dropout: float = 0.0,
        channels: int = 3,
        num_classes: int = 2,
        positions: str = "slot",
    ):
        super().__init__()
        image_h, image_w = pair(image_size)
        patch_h, patch_w = pair(patch_size)
        counts = dict(image_h=image_h, image_w=image_w, patch_h=patch_h, patch_w=patch_w, frames=frames, dim=dim)
        counts.update(heads=heads, dim_head=dim_head, mlp_dim=mlp_dim, channels=channels, num_classes=num_classes)
        counts.update(spatial_depth=spatial_depth, temporal_depth=temporal_depth)  # these may be 0
        for key, value in counts.items():
            if not isinstance(value, int) or value < (0 if key.endswith("_depth") else 1):
                kind = "non-negative" if key.endswith("_depth") else "positive"
                raise ConfigError(f"vivit: {key} must be a {kind} integer, got {value!r}")
        if image_h % patch_h or image_w % patch_w:
            raise ConfigError(
                f"vivit: image_size {(image_h, image_w)} is not divisible by patch_size {(patch_h, patch_w)}"
            )
        if pool not in ("cls", "mean"):
            raise ConfigError(f"vivit: pool must be 'cls' or 'mean', got {pool!r}")
        if positions not in POSITIONS:
            raise ConfigError(f"vivit: positions must be one of {', '.join(map(repr, POSITIONS))}, got {positions!r}")
        for key, value in dict(dropout=dropout, emb_dropout=emb_dropout).items():
            if not 0.0 <= float(value) < 1.0:
                raise ConfigError(f"vivit: {key} must be in [0, 1), got {value!r}")

        self.image_size = (image_h, image_w)
        self.patch_size = (patch_h, patch_w)
        self.grid = (image_h // patch_h, image_w // patch_w)  # (Hp, Wp)
        self.frames, self.channels, self.pool = frames, channels, pool
        self._config = dict(image_size=[image_h, image_w], patch_size=[patch_h, patch_w], frames=frames, dim=dim)
        self._config.update(spatial_depth=spatial_depth, temporal_depth=temporal_depth, heads=heads, dim_head=dim_head)
        self._config.update(mlp_dim=mlp_dim, pool=pool, dropout=float(dropout), emb_dropout=float(emb_dropout))
        self._config.update(channels=channels, num_classes=num_classes)
        if positions != "slot":  # only when set: checkpoints of the paper model keep their config unchanged
            self._config["positions"] = positions
        self.positions = positions
        self.fused = True
        self.embed_chunk = 5  # frames per fused patch-embedding step (cache-sized working set)
        self._fused_cache: tuple | None = None
        self._scratch: dict[tuple, Tensor] = {}  # per-thread patch buffers for inference, see _cut_patches

        num_patches = self.grid[0] * self.grid[1]
        patch_dim = channels * patch_h * patch_w

        # patch embedding: LayerNorm over each (p1 p2 c)-ordered patch, Linear, LayerNorm (vit-pytorch's layout)
        self.patch_norm = nn.LayerNorm(patch_dim)
        self.patch_to_dim = nn.Linear(patch_dim, dim)
        self.dim_norm = nn.LayerNorm(dim)

        # "slot": per frame slot and patch; "factorised": per patch, any slot, and per frame slot
        slot = positions == "slot"
        self.pos_embedding = nn.Parameter(torch.randn(1, frames if slot else 1, num_patches, dim))
        self.temporal_pos_embedding = None if slot else nn.Parameter(torch.randn(1, frames, dim))
        self.emb_dropout = nn.Dropout(emb_dropout)
        self.spatial_cls = nn.Parameter(torch.randn(1, 1, dim)) if pool == "cls" else None
        self.temporal_cls = nn.Parameter(torch.randn(1, 1, dim)) if pool == "cls" else None

        self.spatial_transformer = Transformer(dim, spatial_depth, heads, dim_head, mlp_dim, dropout)
        self.temporal_transformer = Transformer(dim, temporal_depth, heads, dim_head, mlp_dim, dropout)
        self.head = nn.Linear(dim, num_classes)

    def _check_shape(self, x: Any) -> None:
        if not isinstance(x, Tensor):
            raise InputError(None, f"video must be a torch.Tensor, got {type(x).__name__}")
        expected = (self.frames, self.channels, *self.image_size)
        if x.dim() != 5 or x.shape[0] < 1 or tuple(x.shape[1:]) != expected:
            shown = ", ".join(map(str, expected))
            raise InputError(
                None,
                f"video must have shape (B, {shown}) (batch, frames, channels, height, width), got {tuple(x.shape)}",
            )

    def embed_patches(self, frames: Tensor) -> Tensor:
        """Patch tokens of single frames, before the position embedding: (N, C, H, W) -> (N, P, dim).

        Independent of the frame's slot in a clip, so a streaming detector can cache it per frame.
        The fused path runs ``embed_chunk`` frames at a time so that its working set stays in the
        CPU cache (it is memory-bound: at batch 16 whole-batch passes run at DRAM speed).
        """
        if not self.fused:
            return self._embed_plain(frames)
        if frames.shape[0] <= self.embed_chunk:
            return self._embed_fused(frames)
        return torch.cat([self._embed_fused(chunk) for chunk in frames.split(self.embed_chunk)])

    def _embed_plain(self, frames: Tensor) -> Tensor:
        """vit-pytorch's way: copy patches into (p1 p2 c) rows, LayerNorm(patch_dim), Linear, LayerNorm."""
        ph, pw = self.patch_size
        patches = rearrange(frames, "n c (h p1) (w p2) -> n (h w) (p1 p2 c)", p1=ph, p2=pw)
        return self.dim_norm(self.patch_to_dim(self.patch_norm(patches)))

    def fused_patch_weights(self) -> tuple[Tensor, Tensor, Tensor]:
        """The patch LayerNorm's affine folded into the projection, for patches in ``(c p1 p2)`` order.

        Returns ``kernel`` (dim + 1, patch_dim) = ``[W diag(gamma); 1/patch_dim]``, ``row_sum``
        (dim,) = ``W diag(gamma) 1`` and ``bias`` (dim,) = ``W beta + b``.
        """
        ph, pw = self.patch_size
        norm, proj = self.patch_norm, self.patch_to_dim
        patch_dim = norm.normalized_shape[0]
        kernel = rearrange(proj.weight * norm.weight, "d (p1 p2 c) -> d (c p1 p2)", p1=ph, p2=pw)
        row_sum = kernel.sum(dim=1)
        kernel = torch.cat((kernel, kernel.new_full((1, patch_dim), 1.0 / patch_dim)))
        return kernel, row_sum, proj.weight @ norm.bias + proj.bias

    def _cut_patches(self, frames: Tensor) -> Tensor:
        """(n, C, H, W) -> a new (n P, C ph pw) tensor of patches in ``(c p1 p2)`` order.

        Under eager inference (no autograd, no tracing) it is written into a scratch buffer kept per
        thread, dtype and device: a fresh 4.6 MB allocation per clip costs more in page faults than the copy.
        """
        ph, pw = self.patch_size
        hp, wp = self.grid
        n, c = frames.shape[:2]
        patches = frames.reshape(n, c, hp, ph, wp, pw).permute(0, 2, 4, 1, 3, 5)  # a view: (n, hp, wp, c, ph, pw)
        if not eager_inference():
            return patches.reshape(n * hp * wp, c * ph * pw)
        # Inference tensors cannot be written outside inference mode: one buffer per mode.
        key = (threading.get_ident(), frames.dtype, frames.device, torch.is_inference_mode_enabled())
        buffer = self._scratch.get(key)
        if buffer is None or buffer.shape[0] < n * hp * wp:
            buffer = self._scratch[key] = frames.new_empty(n * hp * wp, c * ph * pw)
        rows = buffer[: n * hp * wp]
        rows.view(n, hp, wp, c, ph, pw).copy_(patches)
        return rows

    def __getstate__(self) -> dict[str, Any]:  # pickling / deepcopy: leave the scratch buffers and caches behind
        state = self.__dict__.copy()
        state["_scratch"], state["_fused_cache"] = {}, None
        return state

    def _embed_fused(self, frames: Tensor) -> Tensor:
        """Same function as :meth:`_embed_plain`, several times faster on a CPU: (n, C, H, W) -> (n, P, dim).

        ``Linear(LayerNorm(p)) = (W diag(gamma)) (p - mu) / sqrt(var + eps) + (W beta + b)`` for a
        patch ``p`` with mean ``mu`` and variance ``var``: the patches, cut out in ``(c p1 p2)`` order
        (runs of ``pw`` contiguous pixels), are centred in place and projected by one matrix product
        (:meth:`fused_patch_weights`). Numerics: the corrected two-pass algorithm (the kernel's
        all-``1/n`` row gives the residual mean of the centred patches), as accurate as ``F.layer_norm``.
        """
        params = (self.patch_norm.weight, self.patch_norm.bias, self.patch_to_dim.weight, self.patch_to_dim.bias)
        kernel, row_sum, bias = cached(self, "_fused_cache", params, self.fused_patch_weights)  # until a weight changes

        rows = self._cut_patches(frames)  # (n P, patch_dim)
        mean = rows.mean(dim=1, keepdim=True)
        centred = rows.sub_(mean) if eager_inference() else rows - mean  # in place: the scratch buffer
        sum_sq = torch.linalg.vector_norm(centred, dim=1).square()  # (n P,)
        z = kernel @ centred.t()  # (dim + 1, n P)
        z, resid = z[:-1], z[-1]
        var = sum_sq / self.patch_norm.normalized_shape[0] - resid * resid
        z = torch.addcmul(bias[:, None], z - resid * row_sum[:, None], torch.rsqrt(var + self.patch_norm.eps))
        tokens = rearrange(z, "d (n p) -> n p d", p=self.grid[0] * self.grid[1])
        return F.layer_norm(
            tokens, self.dim_norm.normalized_shape, self.dim_norm.weight, self.dim_norm.bias, self.dim_norm.eps
        )

    def encode_patches(self, tokens: Tensor, attn_store: list[Tensor] | None = None) -> Tensor:
        """Spatial transformer over each frame's patch tokens: (B, T, P, dim) -> (B, T, dim).

        Frame slot ``t`` gets ``pos_embedding[t]`` (``positions="slot"``; T may be less than
        ``frames``: the first slots) or the one shared spatial embedding (``"factorised"``: any T).
        """
        b, t = tokens.shape[:2]
        x = tokens + (self.pos_embedding[:, :t] if self.positions == "slot" else self.pos_embedding)
        if self.spatial_cls is not None:
            x = torch.cat((repeat(self.spatial_cls, "1 1 d -> b t 1 d", b=b, t=t), x), dim=2)  # (B, T, 1+P, dim)
        x = self.emb_dropout(x)
        cls_only = self.spatial_cls is not None and attn_store is None
        x = self.spatial_transformer(rearrange(x, "b t n d -> (b t) n d"), attn_store, first_only=cls_only)
        x = x[:, 0] if self.spatial_cls is not None else x.mean(dim=1)  # (B*T, dim)
        return rearrange(x, "(b t) d -> b t d", b=b)

    def encode_frames(self, x: Tensor, attn_store: list[Tensor] | None = None) -> Tensor:
        """Per-frame tokens: (B, T, C, H, W) -> (B, T, dim); frames are independent given their slot."""
        b = x.shape[0]
        tokens = self.embed_patches(rearrange(x, "b t c h w -> (b t) c h w"))
        return self.encode_patches(rearrange(tokens, "(b t) p d -> b t p d", b=b), attn_store)

    def classify_frames(self, tokens: Tensor, attn_store: list[Tensor] | None = None) -> Tensor:
        """Temporal transformer and head: (B, T, dim) -> (B, num_classes) logits."""
        x = tokens
        if self.temporal_pos_embedding is not None:
            x = x + self.temporal_pos_embedding[:, : x.shape[1]]
        if self.temporal_cls is not None:
            x = torch.cat((repeat(self.temporal_cls, "1 1 d -> b 1 d", b=x.shape[0]), x), dim=1)  # (B, 1+T, dim)
        cls_only = self.temporal_cls is not None and attn_store is None
        x = self.temporal_transformer(x, attn_store, first_only=cls_only)
        x = x[:, 0] if self.temporal_cls is not None else x.mean(dim=1)
        return self.head(x)

    def forward(self, x: Tensor, return_attention: bool = False):
        """(B, T, C, H, W) in [0, 1] -> logits (B, num_classes).

        Checks the shape only (cheap); call :meth:`check_input` for dtype and finiteness.
        ``return_attention=True`` returns ``(logits, attention)`` with ``attention`` as in
        :meth:`attention_maps`.
        """
        self._check_shape(x)
        if not return_attention:
            return self.classify_frames(self.encode_frames(x))
        spatial: list[Tensor] = []
        temporal: list[Tensor] = []
        logits = self.classify_frames(self.encode_frames(x, spatial), temporal)
        b, t = x.shape[:2]
        if spatial:
            spatial_maps = rearrange(torch.stack(spatial, 1), "(b t) l h i j -> b t l h i j", b=b, t=t)
        else:
            spatial_maps = x.new_zeros(b, t, 0, 0, 0, 0)
        temporal_maps = torch.stack(temporal, 1) if temporal else x.new_zeros(b, 0, 0, 0, 0)
        return logits, {"spatial": spatial_maps, "temporal": temporal_maps}

    @classmethod
    def small_config(cls) -> dict:
        return {"image_size": [48, 64], "patch_size": [16, 16], "frames": 3}

    def streaming_parts(self) -> tuple[nn.Module, nn.Module]:
        return ViViTFramePart(self), ViViTWindowPart(self)

    def exportable(self) -> nn.Module:
        """A copy whose patch embedding is :func:`~slipsense.models.vivit_parts.conv_embed_patches`
        (the fused path does not trace; the plain one is slow on ONNX Runtime)."""
        m = copy.deepcopy(self).eval()
        m.fused = False
        # an instance attribute shadows the method: encode_frames and the streaming frame part use it
        m.embed_patches = types.MethodType(conv_embed_patches, m)
        return m

    attention_map = "attention rollout of the latest frame"

    def attention(self, window: Tensor):
        """Attention rollout of the window's latest frame on the patch grid, ``(Hp, Wp)``, sums to 1."""
        return self.cls_attention_map(window)[0, -1].numpy()

    @torch.no_grad()
    def attention_maps(self, x: Tensor) -> dict[str, Tensor]:
        """All attention weights (rows = queries, columns = keys, token 0 = CLS when ``pool="cls"``).

        ``spatial``: (B, T, spatial_depth, heads, n, n) with n = 1 + P (P = Hp * Wp patches, row-major);
        ``temporal``: (B, temporal_depth, heads, m, m) with m = 1 + T. Without CLS tokens n = P, m = T.
        """
        return self(x, return_attention=True)[1]

    @torch.no_grad()
    def cls_attention_map(self, x: Tensor) -> Tensor:
        """Per-frame spatial attention on the patch grid, for heat maps: (B, T, Hp, Wp), each map sums to 1.

        Attention rollout (Abnar & Zuidema 2020) through all spatial layers: each layer's
        head-averaged attention plus the identity (the residual), rows renormalised, multiplied from
        the first layer to the last; the CLS row. With ``pool="mean"`` (no CLS) the attention each
        patch receives is averaged over all query tokens instead of the CLS row.
        """
        spatial = self.attention_maps(x)["spatial"].mean(dim=3)  # (B, T, L, n, n)
        if spatial.shape[2] == 0:
            raise ConfigError("cls_attention_map: the model has no spatial layers")
        eye = torch.eye(spatial.shape[-1], dtype=spatial.dtype, device=spatial.device)
        joint = eye.expand_as(spatial[:, :, 0])
        for layer in spatial.unbind(dim=2):
            a = layer + eye
            joint = (a / a.sum(dim=-1, keepdim=True)) @ joint
        has_cls = self.spatial_cls is not None
        received = joint[..., 0, 1:] if has_cls else joint.mean(dim=-2)  # (B, T, P)
        received = received / received.sum(dim=-1, keepdim=True)
        return rearrange(received, "b t (hp wp) -> b t hp wp", hp=self.grid[0], wp=self.grid[1])
