"""STNet/TemNet streaming parts: the per-frame layers the live detector caches, and the rest.

A window's frames pass the S codecs and the fusion layer one by one, so the live detector runs
:class:`MarkerFramePart` once per pushed frame and :class:`MarkerWindowPart` on the cached window
(:mod:`slipsense.streaming.export` writes both as ONNX). With relative input every frame is seen against its
window's first frame and nothing can be cached.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


class MarkerFramePart(nn.Module):
    """STNet/TemNet per-frame layers (S codecs, fusion): ``(N, M, 3)`` mm -> ``(N, d_model)``."""

    def __init__(self, model: nn.Module):
        super().__init__()
        self.model = model

    def forward(self, clouds: Tensor) -> Tensor:
        m = self.model
        x = clouds.to(m.pos_embedding.dtype).reshape(-1, 1, 3 * m.markers)  # (N, 1, 3M): each frame alone
        if m.codecs is not None:
            x = torch.cat((m.codecs(x), x), dim=-1)  # eq. 5 of the paper, as STNet._tokens
        return m.fuse(x)[:, 0]


class MarkerWindowPart(nn.Module):
    """Frame embedding, MSA blocks and head: ``(B, T, d_model)`` -> ``(B, classes)`` logits."""

    def __init__(self, model: nn.Module):
        super().__init__()
        self.model = model

    def forward(self, tokens: Tensor) -> Tensor:
        x = tokens + self.model.pos_embedding
        for block in self.model.blocks:
            x, _ = block(x)
        return self.model._head(x)
