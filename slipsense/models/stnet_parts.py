"""STNet/TemNet streaming parts: the per-frame layers the live detector caches (S codecs, fusion:
each frame alone), and the rest; and the marker saliency behind their heat maps.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from slipsense.errors import ConfigError
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


def marker_saliency(model: nn.Module, x: Tensor, target: int = 1, baseline="first") -> Tensor:
    """:meth:`slipsense.models.stnet.STNet.marker_saliency` (see there), for a checked input ``x``."""
    if getattr(model, "inference_only", False):
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
        x0 = model.reference.expand_as(x) if getattr(model, "centred", False) else x[:, :1].expand_as(x)
    else:
        raise ConfigError(f"marker_saliency: baseline must be 'first', 'rest', 'zero' or a tensor, got {baseline!r}")
    was_training = model.training
    model.eval()
    try:
        with torch.enable_grad():
            xg = x.detach().float().requires_grad_(True)
            logits = model(xg)
            (grad,) = torch.autograd.grad(logits[:, target].sum(), xg)
    finally:
        model.train(was_training)
    rel = (grad * (xg.detach() - x0.float())).sum(dim=(1, 3)).abs()  # (b, m)
    return rel / rel.amax(dim=1, keepdim=True).clamp_min(torch.finfo(rel.dtype).tiny)
