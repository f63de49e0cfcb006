"""ViViT's building blocks: vit-pytorch's pre-norm attention, feed-forward and transformer, with an
eval-mode fast path (``dim_head`` folded away, cached while the weights do not change)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from einops import rearrange
from torch import Tensor, nn


class FeedForward(nn.Module):
    """``x -> Linear(GELU(Linear(LayerNorm(x))))``: (N, n, dim) -> (N, n, dim)."""

    def __init__(self, dim: int, hidden_dim: int, dropout: float = 0.0):
        super().__init__()
        self.norm = nn.LayerNorm(dim)
        self.fc1 = nn.Linear(dim, hidden_dim)
        self.fc2 = nn.Linear(hidden_dim, dim)
        self.dropout = nn.Dropout(dropout)

    def forward(self, x: Tensor) -> Tensor:
        x = F.gelu(self.fc1(self.norm(x)))
        if self.training and self.dropout.p > 0:
            return self.dropout(self.fc2(self.dropout(x)))
        return self.fc2(x)


def eager_inference() -> bool:
    """True in plain eager inference: no autograd, no tracing (jit / legacy ONNX export) or compiling
    (torch.compile / torch.export / dynamo ONNX export). Only then are caches and scratch buffers safe."""
    return not (torch.is_grad_enabled() or torch.jit.is_tracing() or torch.compiler.is_compiling())


def cached(owner: nn.Module, attr: str, tensors, compute):
    """``compute()``, kept in ``owner.<attr>`` in eager inference until one of ``tensors`` changes
    (its storage, shape or in-place version)."""
    if not eager_inference():
        return compute()
    try:
        key = tuple((t.data_ptr(), t._version, t.shape, t.dtype, t.device) for t in tensors)
    except RuntimeError:  # inference tensors carry no version counter: do not cache
        key = None
    cache = getattr(owner, attr)
    if key is None or cache is None or cache[0] != key:
        cache = (key, compute())
        setattr(owner, attr, cache)
    return cache[1]


class Attention(nn.Module):
    """Pre-norm multi-head self-attention: (N, n, dim) -> (N, n, dim).

    ``attn_store``: a list to append the attention weights ``(N, heads, n, n)`` to; then the
    weights are computed explicitly (softmax of scaled dot products) instead of by the fused
    ``scaled_dot_product_attention`` kernel — the same numbers to float rounding.

    Inference (eval mode, no autograd) takes a folded path: with ``dim_head`` (64) far above ``dim``
    (8), the per-head products ``scale * Wq_h^T Wk_h`` and ``Wv_h^T Wo_h^T`` are ``dim x dim``
    matrices, so scores ``y A_h y^T`` and outputs ``sum_h P_h (y M_h) + b_o`` need 8-wide instead of
    64-wide matmuls. Exactly the same function (matrix products regrouped); the folded matrices are
    cached until a weight changes.
    """

    def __init__(self, dim: int, heads: int, dim_head: int, dropout: float = 0.0):
        super().__init__()
        inner_dim = heads * dim_head
        self.heads = heads
        self.scale = dim_head**-0.5
        self.dropout_p = dropout
        self.norm = nn.LayerNorm(dim)
        self.to_qkv = nn.Linear(dim, inner_dim * 3, bias=False)
        project_out = not (heads == 1 and dim_head == dim)  # as vit-pytorch: no projection then
        self.to_out = nn.Linear(inner_dim, dim) if project_out else nn.Identity()
        self.dropout = nn.Dropout(dropout)
        self._folded: tuple | None = None

    def forward(self, x: Tensor, attn_store: list[Tensor] | None = None, first_only: bool = False) -> Tensor:
        """``first_only``: return only token 0's output, (N, 1, dim)."""
        y = self.norm(x)
        if not self.training and not torch.is_grad_enabled():
            return self._forward_folded(y, attn_store, first_only)
        q, k, v = rearrange(self.to_qkv(y), "b n (qkv h d) -> qkv b h n d", qkv=3, h=self.heads)
        dropout_p = self.dropout_p if self.training else 0.0
        if attn_store is None:
            out = F.scaled_dot_product_attention(q, k, v, dropout_p=dropout_p, scale=self.scale)
        else:
            attn = (q @ k.transpose(-1, -2) * self.scale).softmax(dim=-1)  # (b, h, n, n)
            attn_store.append(attn)
            out = F.dropout(attn, dropout_p, self.training) @ v
        out = rearrange(out[:, :, :1] if first_only else out, "b h n d -> b n (h d)")
        return self.dropout(self.to_out(out))

    def folded_weights(self) -> tuple[Tensor, Tensor, Tensor]:
        """``(A, M, b_o)``: A = [A_1 .. A_h], M = [M_1 .. M_h] as (dim, heads * dim) and the output bias (dim,)."""
        wq, wk, wv = rearrange(self.to_qkv.weight, "(qkv h d) c -> qkv h d c", qkv=3, h=self.heads)
        dim = wq.shape[-1]
        if isinstance(self.to_out, nn.Linear):
            wo, bias = rearrange(self.to_out.weight, "c (h d) -> h c d", h=self.heads), self.to_out.bias
        else:  # heads == 1 and dim_head == dim: no output projection
            wo, bias = torch.eye(dim, dtype=wq.dtype, device=wq.device)[None], wq.new_zeros(dim)
        a = torch.einsum("hdi,hdj->ihj", wq, wk) * self.scale  # A_h[i, j] = scale sum_d Wq_h[d, i] Wk_h[d, j]
        m = torch.einsum("hdi,hcd->ihc", wv, wo)  # M_h[i, c] = sum_d Wv_h[d, i] Wo_h[c, d]
        return a.reshape(dim, -1), m.reshape(dim, -1), bias

    def _forward_folded(self, y: Tensor, attn_store: list[Tensor] | None, first_only: bool) -> Tensor:
        a, m, bias = cached(self, "_folded", (self.to_qkv.weight, *self.to_out.parameters()), self.folded_weights)
        b, n, dim = y.shape
        h = self.heads
        queries = y[:, :1] if first_only else y  # (b, q, dim)
        q = queries.shape[1]
        scores = torch.bmm((queries @ a).view(b, q * h, dim), y.transpose(1, 2))  # rows (query, head): (b, q h, n)
        attn = scores.softmax(dim=-1).view(b, q, h * n)
        if attn_store is not None:
            attn_store.append(rearrange(attn, "b q (h n) -> b h q n", h=h))
        values = rearrange(y @ m, "b n (h c) -> b (h n) c", h=h)  # y M_h for every head: (b, h n, dim)
        return torch.baddbmm(bias, attn, values)  # sum over heads and keys: (b, q, dim)


class Transformer(nn.Module):
    """``depth`` pre-norm residual layers (attention, feed-forward), then a LayerNorm."""

    def __init__(self, dim: int, depth: int, heads: int, dim_head: int, mlp_dim: int, dropout: float):
        super().__init__()
        self.layers = nn.ModuleList(
            nn.ModuleList([Attention(dim, heads, dim_head, dropout), FeedForward(dim, mlp_dim, dropout)])
            for _ in range(depth)
        )
        self.norm = nn.LayerNorm(dim)

    def forward(self, x: Tensor, attn_store: list[Tensor] | None = None, first_only: bool = False) -> Tensor:
        """(N, n, dim) -> (N, n, dim); appends each layer's ``(N, heads, n, n)`` to ``attn_store``.

        ``first_only``: return only token 0 (the CLS token), (N, 1, dim); the last layer then
        computes only that token's row (the others cannot reach it any more).
        """
        if first_only and not self.layers:
            x = x[:, :1]
        for i, (attn, ff) in enumerate(self.layers):
            if first_only and i == len(self.layers) - 1:
                x = attn(x, attn_store, first_only=True) + x[:, :1]
            else:
                x = attn(x, attn_store) + x
            x = ff(x) + x
        return self.norm(x)
