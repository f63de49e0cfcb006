"""ViViT's streaming parts (what the live detector caches per frame) and its ONNX-friendly patch embedding.

The live detector (:mod:`slipsense.streaming.detector`) runs :class:`ViViTFramePart` once per pushed frame and
:class:`ViViTWindowPart` on the cached window; :mod:`slipsense.streaming.export` writes both as ONNX.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from slipsense.models.base import ModelPart


class ViViTFramePart(ModelPart):
    """One frame at every window slot: ``(N, 3, H, W)`` in [0, 1] -> ``(N, T, dim)`` spatial tokens.

    Row ``t`` of the output is the frame's ``encode_frames`` token when it sits in slot ``t``.
    """

    def forward(self, frames: Tensor) -> Tensor:
        tokens = self.model.embed_patches(frames)  # (N, P, dim), independent of the slot
        if self.model.positions == "factorised":  # the spatial token does not depend on the slot either
            return self.model.encode_patches(tokens.unsqueeze(1)).expand(-1, self.model.frames, -1)
        slots = tokens.unsqueeze(1).expand(-1, self.model.frames, -1, -1)  # (N, T, P, dim), a view
        return self.model.encode_patches(slots)  # slot t gets pos_embedding[t]


class ViViTWindowPart(ModelPart):
    """Temporal transformer and head: ``(B, T, dim)`` (frame of slot t at row t) -> ``(B, classes)`` logits."""

    def forward(self, tokens: Tensor) -> Tensor:
        return self.model.classify_frames(tokens)


def conv_embed_patches(model: nn.Module, frames: torch.Tensor) -> torch.Tensor:
    """ViViT's patch embedding written for ONNX Runtime: ``(N, C, H, W) -> (N, P, dim)``.

    The same function as ``ViViT.embed_patches`` (see ``ViViT._embed_fused``): the patch mean and
    variance are reductions over a 6-D *view* of the frames ``(N, C, Hp, ph, Wp, pw)`` (two-pass:
    centred first), and the projection of the centred frames is one convolution with kernel = stride
    = patch. The straightforward graph instead transposes
    every frame into patch order and normalises 4800-value rows: 1.1 ms against 0.7 ms per
    240 x 320 frame on ONNX Runtime (one thread).
    """
    # sizes from the config, not frames.shape: the tracer would make them dynamic and lose the rank
    c, (h, w), (ph, pw), (hp, wp) = model.channels, model.image_size, model.patch_size, model.grid
    kernel, _row_sum, bias = model.fused_patch_weights()  # rows in (c p1 p2) order, + a 1/n row
    weight = kernel[:-1].reshape(-1, c, ph, pw)  # (dim, C, ph, pw) = W diag(gamma)
    blocks = frames.reshape(-1, c, hp, ph, wp, pw)
    # the reductions run innermost axis first: ONNX Runtime reduces a contiguous trailing axis fast,
    # and strided axes (1, 3, 5) at once about 3x slower (measured: frame part 0.9 -> 0.5 ms)
    centred = blocks - blocks.mean(dim=5, keepdim=True).mean(dim=(1, 3), keepdim=True)
    var = (centred * centred).mean(dim=5).mean(dim=(1, 3))  # (N, Hp, Wp)
    z = F.conv2d(centred.reshape(-1, c, h, w), weight, stride=(ph, pw))  # (N, dim, Hp, Wp)
    z = z * torch.rsqrt(var + model.patch_norm.eps).unsqueeze(1) + bias[:, None, None]
    tokens = z.flatten(2).transpose(1, 2)  # (N, P, dim), patches row-major as in the model
    norm = model.dim_norm
    return F.layer_norm(tokens, norm.normalized_shape, norm.weight, norm.bias, norm.eps)
