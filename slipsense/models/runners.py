"""Where a stream's named modules run: PyTorch, or ONNX Runtime with the modules exported once and
cached (numpy in, numpy out either way). A stream calls ``runner(name, *arrays) -> list of arrays``
and never knows which."""

from __future__ import annotations

import hashlib
import importlib.util
import tempfile
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import torch
from torch import nn

from slipsense import __version__
from slipsense.paths import cache_root
from slipsense.errors import ConfigError
from slipsense.models.onnx import cached_streaming_parts, onnx_session

#: "auto": ONNX Runtime where it is installed (several times faster for the small streaming models),
#: else PyTorch (:func:`resolve_backend`).
BACKENDS = ("auto", "torch", "onnx")
DTYPES = ("float32", "int8")


def resolve_backend(backend: str, model: nn.Module | None = None) -> str:
    """``"torch"`` or ``"onnx"``: ``"auto"`` is ONNX Runtime where it and the ONNX exporter are installed,
    unless ``model`` streams faster on PyTorch (its ``auto_backend``)."""
    if backend != "auto":
        return backend
    if getattr(model, "auto_backend", "onnx") == "torch":
        return "torch"
    return "onnx" if all(importlib.util.find_spec(m) is not None for m in ("onnxruntime", "onnx")) else "torch"


def check_backend(backend: str, dtype: str, model: nn.Module | None = None) -> str:
    """:func:`resolve_backend`, after ConfigError for an unknown backend or dtype, or int8 off ONNX Runtime."""
    if backend not in BACKENDS:
        raise ConfigError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if dtype not in DTYPES:
        raise ConfigError(f"dtype must be one of {DTYPES}, got {dtype!r}")
    backend = resolve_backend(backend, model)
    if dtype != "float32" and backend != "onnx":
        raise ConfigError("dtype 'int8' needs backend 'onnx' (ONNX Runtime dynamic quantization)")
    return backend


class TorchRunner:
    # no_grad, not inference_mode: tensors a model caches during an inference-mode call (ViViT keeps
    # scratch buffers) could not be updated in place by a later ordinary call on the same model.
    def __init__(self, modules: Mapping[str, nn.Module]):
        self.modules = dict(modules)

    def __call__(self, name: str, *arrays: np.ndarray) -> list[np.ndarray]:
        with torch.no_grad():
            out = self.modules[name](*(torch.from_numpy(a) for a in arrays))
        outs = out if isinstance(out, (tuple, list)) else (out,)
        return [o.float().numpy() for o in outs]


class OnnxRunner:
    """``inputs``: per file, the names of the arrays a call passes, in order (the part's
    :class:`~slipsense.models.base.OnnxPart` inputs)."""

    def __init__(self, paths: Mapping[str, Path], inputs: Mapping[str, list[str]]):
        self.sessions = {name: onnx_session(path) for name, path in paths.items()}
        self._declared = {name: list(inputs[name]) for name in paths}
        self._kept = {name: {i.name for i in s.get_inputs()} for name, s in self.sessions.items()}

    def __call__(self, name: str, *arrays: np.ndarray) -> list[np.ndarray]:
        # fed by name: an exporter may drop an input the graph does not use, wherever it stands
        feed = {n: a for n, a in zip(self._declared[name], arrays) if n in self._kept[name]}
        return self.sessions[name].run(None, feed)


def onnx_cache_dir(checkpoint: Path) -> Path:
    """``<cache_root>/onnx/<hash>``: keyed by the checkpoint's bytes and the library versions."""
    h = hashlib.sha256()
    with open(checkpoint, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    # parts-2: the ViViT frame part's patch statistics are reduced innermost axis first (faster graph)
    h.update(f"{__version__} {torch.__version__} parts-2".encode())
    return cache_root() / "onnx" / h.hexdigest()[:24]


def make_runner(
    model: nn.Module, geometry: Mapping[str, Any], backend: str, dtype: str = "float32", onnx_dir: Any = None
) -> tuple[TorchRunner | OnnxRunner, Any]:
    """The runner of ``model``'s streaming modules on ``backend``; returns ``(runner, tmpdir)``,
    ``tmpdir`` a :class:`tempfile.TemporaryDirectory` to clean up when no ``onnx_dir`` was given for
    ONNX (else None). ONNX parts already in ``onnx_dir`` are reused when their manifest matches."""
    if check_backend(backend, dtype, model) == "torch":
        return TorchRunner(model.streaming_modules(geometry)), None
    tmpdir = None
    if onnx_dir is None:
        tmpdir = tempfile.TemporaryDirectory(prefix="slipsense-onnx-")
        onnx_dir = tmpdir.name
    paths = cached_streaming_parts(model, Path(onnx_dir), geometry, dtype)
    inputs = {k: part.inputs for k, part in model.exportable().onnx_parts(geometry).items() if k in paths}
    return OnnxRunner(paths, inputs), tmpdir
