"""STNet/TemNet streaming parts: the per-frame layers the live detector caches (S codecs, fusion:
each frame alone), and the rest.
"""

from __future__ import annotations

import torch
from torch import Tensor

from slipsense.models.base import ModelPart


class MarkerFramePart(ModelPart):
    """STNet/TemNet per-frame layers (S codecs, fusion): ``(N, M, 3)`` mm -> ``(N, d_model)``."""

    def forward(self, clouds: Tensor) -> Tensor:
        m = self.model
        x = clouds.to(m.pos_embedding.dtype)
        if m.centred:
            x = x - m.reference
        x = x.reshape(-1, 1, 3 * m.markers)  # (N, 1, 3M): each frame alone
        if m.codecs is not None:
            x = torch.cat((m.codecs(x), x), dim=-1)  # eq. 5 of the paper, as STNet._tokens
        return m.fuse(x)[:, 0]


class MarkerWindowPart(ModelPart):
    """Frame embedding, MSA blocks and head: ``(B, T, d_model)`` -> ``(B, classes)`` logits."""

    def forward(self, tokens: Tensor) -> Tensor:
        x = tokens + self.model.pos_embedding
        for block in self.model.blocks:
            x = block(x)
        return self.model._head(x)
