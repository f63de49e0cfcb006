"""STNet's and TemNet's size without building them: exact parameter counts and the multiply-adds of
one forward pass, from a configuration (the paper's 129 M-parameter network need not be allocated to
be counted)."""

from __future__ import annotations

import inspect
from typing import Any

from slipsense.models.stnet import STNet


def _full_config(config: dict[str, Any] | None, model: str) -> dict[str, Any]:
    """``config`` with STNet's own defaults filled in (what the analytic counts below need)."""
    defaults = {k: p.default for k, p in inspect.signature(STNet.__init__).parameters.items() if k != "self"}
    return {**defaults, "use_codecs": model == "stnet", **(config or {})}


def count_parameters_for(config: dict[str, Any] | None = None, model: str = "stnet") -> int:
    """Exact parameter count of ``model`` ("stnet"/"temnet") for ``config`` (defaults filled in),
    computed analytically - no need to build a 129 M network to know its size."""
    c = _full_config(config, model)
    d_in = 3 * c["markers"]
    d = d_in if c["d_model"] is None else c["d_model"]
    f, t, k, ch = c["ff_dim"], c["frames"], c["codec_kernel"], c["codec_channels"]
    n = 0
    if c["use_codecs"]:
        n += (k * ch + ch) + (c["codec_layers"] - 1) * (ch * ch * k + ch) + (ch * k + 1)  # S codecs
        n += 2 * d_in * d + d  # fusion FC
    elif d != d_in:
        n += d_in * d + d  # projection
    n += t * d  # frame embedding
    n += c["blocks"] * ((3 * d * d + 3 * d) + (d * d + d) + (d * f + f) + (f * d + d) + 4 * d)
    head_in = t * d if c["pool"] == "flatten" else d
    hid = d if c["head_hidden"] is None else c["head_hidden"]
    nc = c["num_classes"]
    n += (head_in * hid + hid + hid * nc + nc) if hid else (head_in * nc + nc)
    return n


def flops_per_sample(config: dict[str, Any] | None = None, model: str = "stnet") -> int:
    """Multiply-adds x 2 of one forward pass (matmuls, convolutions, attention; no elementwise)."""
    c = _full_config(config, model)
    d_in = 3 * c["markers"]
    d = d_in if c["d_model"] is None else c["d_model"]
    f, t, k, ch = c["ff_dim"], c["frames"], c["codec_kernel"], c["codec_channels"]
    macs = 0
    if c["use_codecs"]:
        length, cin = d_in, 1
        for _ in range(c["codec_layers"]):
            length = (length + 1) // 2
            macs += length * ch * cin * k
            cin = ch
        macs += length * 2 ** c["codec_layers"] * ch * k  # decoder conv
        macs += 2 * d_in * d  # fusion
    elif d != d_in:
        macs += d_in * d
    macs *= t
    macs += c["blocks"] * (t * (4 * d * d + 2 * d * f) + 2 * t * t * d)  # linears + QK^T, AV
    hid = d if c["head_hidden"] is None else c["head_hidden"]
    head_in = t * d if c["pool"] == "flatten" else d
    macs += (head_in * hid + hid * c["num_classes"]) if hid else head_in * c["num_classes"]
    return 2 * macs
