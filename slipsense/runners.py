"""Where the live detector's two streaming parts run: PyTorch, or ONNX Runtime with the parts
exported once and cached (numpy in, numpy out either way)."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import torch
from torch import nn


class TorchRunner:
    # no_grad, not inference_mode: tensors a model caches during an inference-mode call (ViViT keeps
    # scratch buffers) could not be updated in place by a later ordinary call on the same model.
    def __init__(self, frame_part: nn.Module | None, window_part: nn.Module):
        self.frame_part, self.window_part = frame_part, window_part

    def frame(self, x: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return self.frame_part(torch.from_numpy(x)).numpy()

    def window(self, x: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return self.window_part(torch.from_numpy(x)).float().numpy()


class OnnxRunner:
    def __init__(self, frame_path: Path | None, window_path: Path):
        from slipsense.export import onnx_session

        self.frame_sess = None if frame_path is None else onnx_session(frame_path)
        self.window_sess = onnx_session(window_path)
        self._frame_in = None if self.frame_sess is None else self.frame_sess.get_inputs()[0].name
        self._window_in = self.window_sess.get_inputs()[0].name

    def frame(self, x: np.ndarray) -> np.ndarray:
        return self.frame_sess.run(None, {self._frame_in: x})[0]

    def window(self, x: np.ndarray) -> np.ndarray:
        return self.window_sess.run(None, {self._window_in: x})[0]


def onnx_cache_dir(checkpoint: Path) -> Path:
    """``<cache_root>/onnx/<hash>``: keyed by the checkpoint's bytes and the library versions."""
    from slipsense import __version__
    from slipsense.config import cache_root

    h = hashlib.sha256()
    with open(checkpoint, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    # parts-2: the ViViT frame part's patch statistics are reduced innermost axis first (faster graph)
    h.update(f"{__version__} {torch.__version__} parts-2".encode())
    return cache_root() / "onnx" / h.hexdigest()[:24]


def exported_parts(
    model: nn.Module, geometry: Mapping[str, Any], folder: Path, dtype: str = "float32"
) -> tuple[Path | None, Path]:
    """The model's streaming parts as ONNX files in ``folder``, exported unless a verified copy is
    there (:func:`slipsense.export.cached_streaming_parts`); ``dtype="int8"``: their dynamically
    quantized copies."""
    from slipsense.export import cached_streaming_parts

    return cached_streaming_parts(model, folder, geometry, dtype)
