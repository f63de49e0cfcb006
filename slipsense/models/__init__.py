"""The model zoo: every network is built by name from a plain config dict.

    >>> from slipsense.models import build, available
    >>> model = build("vivit", frames=5)            # doctest: +SKIP

Each model class declares

* ``input_kind``: ``"video"`` — input ``(B, T, 3, H, W)`` float32 in [0, 1], BGR channel order as
  OpenCV decodes — or ``"markers"`` — input ``(B, T, N, 3)`` float32 marker positions;
* ``config()``: the keyword arguments that rebuild it (stored in every checkpoint);
* ``forward(x) -> (B, 2)`` logits, class 1 = slip (onset of slip), class 0 = no slip (wiggle);
* ``check_input(x)``: raises :class:`slipsense.errors.InputError` on a wrong shape or non-finite values.
"""
from __future__ import annotations

import importlib
from typing import Any, Callable

import torch.nn as nn

from slipsense.errors import ConfigError

_REGISTRY: dict[str, Callable[..., nn.Module]] = {}
# Modules that register models on import; imported lazily so `import slipsense` stays fast.
_MODULES = ("slipsense.models.vivit", "slipsense.models.resnet3d", "slipsense.models.stnet", "slipsense.models.motion")


def register(name: str):
    """Class decorator: make ``build(name, **config)`` construct this class."""

    def deco(cls):
        _REGISTRY[name] = cls
        cls.model_name = name
        return cls

    return deco


def _load_all() -> None:
    for mod in _MODULES:
        try:
            importlib.import_module(mod)
        except ModuleNotFoundError as exc:  # a model file not written yet must not break the others
            if exc.name != mod:
                raise


def available() -> list[str]:
    """Names of all registered models."""
    _load_all()
    return sorted(_REGISTRY)


#: No setting of any model is an integer this large (widths, depths, heads, frames, pixels).
MAX_SETTING = 100_000
#: Models with more parameters are refused before their weights are allocated.
MAX_PARAMETERS = 1_000_000_000


def _check_sizes(name: str, config: dict[str, Any]) -> None:
    def walk(key, v):
        if isinstance(v, bool):
            return
        if isinstance(v, (int, float)) and abs(v) > MAX_SETTING and key not in ("lr", "eps"):
            raise ConfigError(f"model {name!r}: setting {key}={v!r} is beyond {MAX_SETTING:,}")
        if isinstance(v, (list, tuple)):
            for x in v:
                walk(key, x)

    for key, value in config.items():
        walk(key, value)


def build(name: str, **config: Any) -> nn.Module:
    """Build model ``name`` with keyword ``config``; unknown names or keys, settings beyond
    :data:`MAX_SETTING` and models beyond :data:`MAX_PARAMETERS` raise ConfigError (the size is
    checked on the meta device, before any weight is allocated)."""
    import torch

    _load_all()
    if name not in _REGISTRY:
        raise ConfigError(f"unknown model {name!r}; available: {', '.join(sorted(_REGISTRY))}")
    _check_sizes(name, config)
    cls = _REGISTRY[name]
    try:
        if torch.empty(0).device.type == "meta":  # already building without memory (checkpoint checks)
            return cls(**config)
        with torch.device("meta"):
            n = sum(p.numel() for p in cls(**config).parameters())
        if n > MAX_PARAMETERS:
            raise ConfigError(f"model {name!r}: {n:,} parameters is beyond {MAX_PARAMETERS:,}")
        return cls(**config)
    except TypeError as exc:
        raise ConfigError(f"model {name!r}: {exc}") from None


def check_video_values(x) -> None:
    """Raise InputError unless the video tensor ``x`` is float and finite (shape checked by the model)."""
    import torch

    from slipsense.errors import InputError

    if not x.dtype.is_floating_point:
        raise InputError(None, f"video must be a float tensor in [0, 1], got dtype {x.dtype}")
    if not bool(torch.isfinite(x).all()):
        raise InputError(None, "video contains NaN or infinite values")


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


#: inference precisions :func:`with_precision` offers
PRECISIONS = ("float32", "bfloat16", "int8")


def with_precision(model: nn.Module, precision: str = "float32") -> nn.Module:
    """``model`` for CPU inference at ``precision``: "float32" (unchanged), "int8" (a copy with every
    nn.Linear dynamically quantized: int8 weights, activations quantized per batch) or "bfloat16"
    (a copy with bf16 weights packed for oneDNN, float32 in and out). Reduced precision is offered for
    STNet and TemNet, whose time goes to streaming ~0.5 GB of Linear weights; ViViT (67 k parameters)
    and the 3D ResNet-50 (convolutions) gain nothing from it. The copies are inference-only: call
    them under ``torch.inference_mode()``."""
    if precision not in PRECISIONS:
        raise ConfigError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if precision == "float32":
        return model
    import torch

    from slipsense.models.stnet import STNet, optimize_for_inference, quantize_dynamic_int8

    if not isinstance(model, STNet):
        raise ConfigError(f"{precision} inference is implemented for STNet and TemNet, not {type(model).__name__}")
    return quantize_dynamic_int8(model) if precision == "int8" else optimize_for_inference(model, torch.bfloat16)
