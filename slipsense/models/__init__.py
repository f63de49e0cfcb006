"""The model zoo: every network is built by name from a plain config dict.

    >>> from slipsense.models import build, available
    >>> model = build("vivit", frames=5)            # doctest: +SKIP

Every model subclasses a kind of :mod:`slipsense.models.base`, whose contract is all the rest of
slipsense knows of it: nothing outside this package names a model.
"""

from __future__ import annotations

import importlib
from typing import Any

import torch.nn as nn

from slipsense.errors import ConfigError

# re-exported: the public face of the registry
from slipsense.models.base import MarkerModel, SlipModel, build_registered, register  # noqa: F401
from slipsense.models.base import registered, settings_of, window_geometry  # noqa: F401

# Modules that register models on import; imported lazily so `import slipsense` stays fast.
_MODULES = tuple(f"slipsense.models.{m}" for m in ("vivit", "resnet3d", "stnet", "motion", "shear", "slip_velocity"))


def _load_all() -> None:
    for mod in _MODULES:
        importlib.import_module(mod)


def available() -> list[str]:
    """Names of all registered models."""
    _load_all()
    return sorted(registered())


def model_class(name: str) -> type:
    """The class registered as ``name`` (ConfigError naming the available ones otherwise)."""
    _load_all()
    classes = registered()
    if name not in classes:
        raise ConfigError(f"unknown model {name!r}; available: {', '.join(sorted(classes))}")
    return classes[name]


def build(name: str, **config: Any) -> SlipModel:
    """Build model ``name`` with keyword ``config``; unknown names or keys, settings beyond
    :data:`~slipsense.models.base.MAX_SETTING` and models beyond
    :data:`~slipsense.models.base.MAX_PARAMETERS` raise ConfigError (the size is checked on the meta
    device, before any weight is allocated)."""
    _load_all()
    return build_registered(name, **config)


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


#: number formats :func:`at_dtype` offers for inference
DTYPES = ("float32", "bfloat16", "int8")


def at_dtype(model: nn.Module, dtype: str = "float32") -> nn.Module:
    """``model`` for CPU inference with ``dtype`` weights: "float32" (unchanged), "int8" (a copy with every
    nn.Linear dynamically quantized: int8 weights, activations quantized per batch) or "bfloat16"
    (a copy with bf16 weights packed for oneDNN, float32 in and out). Reduced precision is offered for
    STNet and TemNet, whose time goes to streaming ~0.5 GB of Linear weights; ViViT (67 k parameters)
    and the 3D ResNet-50 (convolutions) gain nothing from it. The copies are inference-only: call
    them under ``torch.inference_mode()``."""
    if dtype not in DTYPES:
        raise ConfigError(f"dtype must be one of {', '.join(DTYPES)}, got {dtype!r}")
    if dtype == "float32":
        return model
    if not isinstance(model, SlipModel):
        raise ConfigError(f"{dtype} inference is implemented for STNet and TemNet, not {type(model).__name__}")
    return model.reduced_precision(dtype)
