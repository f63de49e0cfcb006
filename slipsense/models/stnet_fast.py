"""STNet/TemNet for fast CPU inference: oneDNN-packed Linear weights, a frame-split classifier,
bf16 weights, int8 dynamic quantization (``SlipModel.reduced_precision``, ``bench/bench_stnet.py``).

The paper-size STNet streams ~0.5 GB of Linear weights per sample; these copies cut what is read
(int8, bf16) or read it faster (pre-packed blocked layout, both cores on the classifier).
"""

from __future__ import annotations

import copy
import warnings

import torch
from einops import rearrange
from torch import nn
from torch.ao.quantization import quantize_dynamic

from slipsense.errors import ConfigError

_PACKING: dict[torch.dtype, bool] = {}


def onednn_packing_available(dtype: torch.dtype = torch.float32) -> bool:
    """Whether this build and this CPU can pre-pack ``dtype`` Linear weights for oneDNN (bf16
    packing needs AVX512-BF16/AVX-NE-CONVERT or AVX512BW/VL/DQ; plain AVX2 machines lack it)."""
    if dtype not in _PACKING:
        ops = ("_reorder_linear_weight", "_linear_pointwise")
        ok = torch.backends.mkldnn.is_available() and all(hasattr(torch.ops.mkldnn, op) for op in ops)
        if ok:
            try:
                w = torch.ops.mkldnn._reorder_linear_weight(torch.zeros(8, 8, dtype=dtype), 1)
                torch.ops.mkldnn._linear_pointwise(torch.zeros(1, 8, dtype=dtype), w, None, "none", [], "")
            except RuntimeError:
                ok = False
        _PACKING[dtype] = ok
    return _PACKING[dtype]


class PackedLinear(nn.Module):
    """Inference-only ``nn.Linear`` with its weight pre-packed in oneDNN's blocked layout.

    The packed weight is an opaque oneDNN tensor (no gradients, no state_dict, no ``.to()``);
    keep the original model for training and checkpoints.
    """

    def __init__(self, linear: nn.Linear, dtype: torch.dtype = torch.float32, activation: str = "none"):
        super().__init__()
        self.in_features, self.out_features = linear.in_features, linear.out_features
        self.activation = activation  # "none" or "relu", fused into the matmul
        w = linear.weight.detach().to(dtype).contiguous()
        self.packed = torch.ops.mkldnn._reorder_linear_weight(w, 12)  # batch hint: a window's 12 frames
        self.bias = None if linear.bias is None else linear.bias.detach().to(dtype).clone()

    def forward(self, x):
        return torch.ops.mkldnn._linear_pointwise(x, self.packed, self.bias, self.activation, [], "")

    def extra_repr(self):
        return f"in_features={self.in_features}, out_features={self.out_features}, packed=oneDNN" + (
            f", activation={self.activation}" if self.activation != "none" else ""
        )


class FrameSumLinear(nn.Module):
    """Inference-only ``nn.Linear`` over a flattened (frames x d) input, as ``b + sum_t W_t x_t``:
    one batched matmul over frames. At batch 1 the flattened product is a matrix-vector product
    (1 x 19872 by 19872 x 1656, 132 MB of weights for 66 MFLOP) that BLAS and oneDNN run on one
    core, at half the machine's memory bandwidth; split by frame, both cores stream."""

    def __init__(self, linear: nn.Linear, frames: int, dtype: torch.dtype = torch.float32):
        super().__init__()
        self.frames = frames
        self.weight = rearrange(linear.weight.detach(), "o (t d) -> t o d", t=frames).to(dtype).contiguous()
        self.bias = linear.bias.detach().to(dtype).clone()

    def forward(self, x):  # (b, t * d) -> (b, o)
        x = rearrange(x, "b (t d) -> t d b", t=self.frames)
        return torch.bmm(self.weight, x).sum(0).t() + self.bias


def optimize_for_inference(model: nn.Module, dtype: torch.dtype = torch.float32) -> nn.Module:
    """A copy of ``model`` for fast CPU inference: eval mode, ``dtype`` weights (float32 or
    bfloat16), every nn.Linear pre-packed for oneDNN (:class:`PackedLinear`), a big classifier
    layer over the flattened frames split by frame (:class:`FrameSumLinear`). Inputs stay float32
    (cast inside), logits come out float32. Falls back to plain (cast) Linears where this PyTorch
    build or this CPU lacks oneDNN packing for ``dtype``. Run it under ``torch.inference_mode()``;
    inference only (the packed weights have no gradients and no state_dict - keep ``model`` for that).

    Tip: ``THP_MEM_ALLOC_ENABLE=1`` in the environment (before torch is imported) backs the weights
    with huge pages, which helps batch-1 inference stream them from memory.
    """
    if dtype not in (torch.float32, torch.bfloat16):
        raise ConfigError(f"optimize_for_inference: dtype must be float32 or bfloat16, got {dtype}")
    fast = copy.deepcopy(model).eval().to(dtype)
    fast.inference_only = True
    if getattr(fast, "pool", None) == "flatten":
        first = fast.to_logits[0] if isinstance(fast.to_logits, nn.Sequential) else fast.to_logits
        if first.out_features >= 64:  # worth it only for a wide layer
            head = FrameSumLinear(first, fast.frames, dtype)
            if isinstance(fast.to_logits, nn.Sequential):
                fast.to_logits[0] = head
            else:
                fast.to_logits = head
    if not onednn_packing_available(dtype):
        return fast
    for block in getattr(fast, "blocks", ()):  # STNet's MSA blocks: ReLU fused into the first ff product
        if isinstance(block.ff[1], nn.ReLU):
            block.ff[0] = PackedLinear(block.ff[0], dtype, activation="relu")
            block.ff[1] = nn.Identity()
    for parent in list(fast.modules()):
        for name, child in list(parent.named_children()):
            if type(child) is nn.Linear:
                setattr(parent, name, PackedLinear(child, dtype))
    return fast


def quantize_dynamic_int8(model: nn.Module) -> nn.Module:
    """A copy of ``model`` with every nn.Linear dynamically quantized to int8 (weights int8 per
    tensor, activations quantized on the fly), for CPU inference."""
    engines = torch.backends.quantized.supported_engines
    for engine in ("x86", "fbgemm", "onednn", "qnnpack"):
        if engine in engines:
            torch.backends.quantized.engine = engine
            break
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # torch.ao.quantization deprecation notice
        return quantize_dynamic(copy.deepcopy(model).eval().float(), {nn.Linear}, dtype=torch.qint8)
