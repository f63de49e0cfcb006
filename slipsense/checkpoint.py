"""Checkpoints: one safetensors file holding the weights and, in its metadata, the full config.

A checkpoint rebuilds its model with no other file: ``load_model(path)``. Training state for
``--resume`` (optimizer, scheduler, RNG, epoch) lives beside it in ``resume.pt``.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import torch
import torch.nn as nn

from slipsense import __version__
from slipsense.atomic import atomic_path
from slipsense.errors import ConfigError, InputError

META_KEY = "slipsense"


def save_checkpoint(path: str | Path, model: nn.Module, info: dict[str, Any]) -> Path:
    """Write ``model``'s weights and ``info`` (must hold ``model`` and ``model_config``) atomically.

    ``info`` is stored as JSON in the safetensors metadata, together with the slipsense version.
    """
    from safetensors.torch import save_file

    model = getattr(model, "module", model)  # unwrap DistributedDataParallel
    info = {**info, "model": model.model_name, "model_config": model.config(), "slipsense_version": __version__}
    tensors = {k: v.detach().contiguous().cpu() for k, v in model.state_dict().items()}
    path = Path(path)
    with atomic_path(path) as tmp:
        save_file(tensors, str(tmp), metadata={META_KEY: json.dumps(info)})
    return path


def read_info(path: str | Path) -> dict[str, Any]:
    """The config stored in a checkpoint, without loading its weights."""
    from safetensors import safe_open

    path = Path(path)
    if not path.is_file():
        raise InputError(path, "checkpoint not found")
    try:
        with safe_open(str(path), framework="pt") as fh:
            meta = fh.metadata() or {}
    except Exception as exc:  # safetensors raises several error types for a damaged header
        raise InputError(path, f"not a readable safetensors checkpoint ({type(exc).__name__}: {exc})") from None
    if META_KEY not in meta:
        raise InputError(path, "safetensors file carries no slipsense config (not a slipsense checkpoint)")
    try:
        info = json.loads(meta[META_KEY])
    except json.JSONDecodeError as exc:
        raise InputError(path, f"checkpoint config is not valid JSON ({exc})") from None
    for key in ("model", "model_config"):
        if key not in info:
            raise InputError(path, f"checkpoint config lacks {key!r}")
    return info


def load_model(path: str | Path, expect_model: str | None = None) -> tuple[nn.Module, dict[str, Any]]:
    """Rebuild the model a checkpoint describes and load its weights; returns ``(model, info)``.

    The model is in eval mode on the CPU. ``expect_model`` (e.g. ``"vivit"``) rejects a checkpoint
    of another network with a clear error.
    """
    from safetensors.torch import load_file

    from slipsense.models import build

    path = Path(path)
    info = read_info(path)
    if expect_model is not None and info["model"] != expect_model:
        raise InputError(path, f"checkpoint holds a {info['model']!r} model, expected {expect_model!r}")
    try:
        model = build(info["model"], **info["model_config"])
    except ConfigError as exc:
        raise InputError(path, f"checkpoint config cannot build its model: {exc}") from None
    try:
        state = load_file(str(path))
    except Exception as exc:
        raise InputError(path, f"checkpoint weights are unreadable ({type(exc).__name__}: {exc})") from None
    missing, unexpected = _diff_keys(model.state_dict(), state)
    if missing or unexpected:
        raise InputError(path, f"weights do not fit model {info['model']!r}: missing {missing[:3]}, unexpected {unexpected[:3]}")
    for key, ref in model.state_dict().items():
        if state[key].shape != ref.shape:
            raise InputError(path, f"weight {key} has shape {tuple(state[key].shape)}, model expects {tuple(ref.shape)}")
        if state[key].is_floating_point() and not torch.isfinite(state[key]).all():
            raise InputError(path, f"weight {key} contains NaN or inf")
    model.load_state_dict(state)
    model.eval()
    return model, info


def _diff_keys(expected: dict, got: dict) -> tuple[list[str], list[str]]:
    return sorted(set(expected) - set(got)), sorted(set(got) - set(expected))


def save_resume_state(path: str | Path, state: dict[str, Any]) -> None:
    """Atomically write the training state needed by ``--resume``."""
    with atomic_path(path) as tmp:
        torch.save(state, tmp)


def load_resume_state(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    try:
        return torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:
        raise InputError(path, f"resume state is unreadable ({type(exc).__name__}: {exc})") from None
