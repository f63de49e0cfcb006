"""ONNX export of slipsense models, and of the two streaming parts the live detector runs.

    >>> from slipsense.streaming.export import export_onnx
    >>> result = export_onnx("models/vivit-gelsight.safetensors", "vivit.onnx")   # doctest: +SKIP
    >>> result.paths      # {"model": vivit.onnx, "frame": vivit.frame.onnx, "window": vivit.window.onnx}

Files (inputs float32; ``B``/``N`` is the batch axis, dynamic unless ``batch`` is given):

* ``model``  — the whole network: ``video`` ``(B, T, 3, H, W)`` in [0, 1], BGR (ViViT, 3D ResNet) or
  ``markers`` ``(B, T, M, 3)`` mm (STNet, TemNet) -> ``logits`` ``(B, 2)``.
* ``frame``  — streaming frame part (see :mod:`slipsense.streaming.detector`): ViViT ``frames`` ``(N, 3, H, W)`` ->
  ``tokens`` ``(N, T, dim)`` (the frame encoded at every window slot); STNet/TemNet ``clouds``
  ``(N, M, 3)`` -> ``tokens`` ``(N, d_model)``.
* ``window`` — streaming window part: ``tokens`` ``(B, T, dim | d_model)`` -> ``logits`` ``(B, 2)``.

The 3D ResNet has no frame part (nothing carries between windows); its window part is the model.

Which exporter (torch 2.13, onnx 1.23, onnxruntime 1.31)
---------------------------------------------------------
``torch.onnx.export(..., dynamo=False)`` (the TorchScript-based exporter, deprecated but still
shipped) is tried first: it takes about a second per file. It exports ViViT, TemNet and the 3D
ResNet. (ViViT's fused patch embedding does not export — ``addmv`` has no ONNX symbolic — and the
straightforward one is slow on ONNX Runtime, so ViViT is exported with
:func:`slipsense.models.vivit_parts.conv_embed_patches`,
the same function to ~1e-5.) It fails on STNet's S codecs
(``adaptive_avg_pool1d`` whose length it cannot see with a dynamic batch), so those fall back to
``dynamo=True`` (``torch.export`` + onnxscript, 3-12 s per file), which handles every model here. On
the shared GelSight clips ONNX Runtime matches PyTorch to ~1e-6 (tests require <= 1e-4).
Shapes other than the batch (frames, image size, markers) are fixed at export.

Every file carries, in its ONNX ``metadata_props`` (keys ``slipsense.*``, values JSON), what a program
running it without slipsense needs: ``model``, ``config`` (the model's settings), ``sensor`` and
``fps``, ``operating_point`` (``threshold``, ``debounce`` frames, ``hold_s``, ``startup`` frames), its
``promise``, and the file's ``part``, ``inputs`` and ``outputs``
(:func:`slipsense.models.onnx.onnx_metadata` reads them back; so does any ONNX Runtime).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from torch import nn

from slipsense.checkpoint import load_model
from slipsense.errors import InputError
from slipsense.models.base import window_geometry
from slipsense.models.onnx import ExportResult, export_parts, streaming_names


def export_onnx(
    checkpoint_or_model: str | Path | nn.Module,
    out_path: str | Path,
    batch: int | None = None,
    *,
    streaming: bool = True,
    verify: bool = True,
    info: Mapping[str, Any] | None = None,
) -> ExportResult:
    """Export a checkpoint (or a model) to ONNX: the whole model at ``out_path`` and, with
    ``streaming``, the modules the live detector runs beside it as ``<stem>.<name>.onnx`` (ViViT,
    STNet, TemNet: ``frame`` and ``window``; MotionNet: ``frame`` and ``step``; a 3D ResNet has none).

    Args:
        checkpoint_or_model: a ``.safetensors`` checkpoint path or a slipsense model.
        out_path: the ``.onnx`` file for the whole model.
        batch: None (default) for a dynamic batch axis, or a fixed batch size.
        streaming: also export the streaming parts.
        verify: run each file on ONNX Runtime against PyTorch on a random example input and record
            the max abs difference in the result.
        info: checkpoint config for a bare model (window length / frame size of a 3D ResNet).

    Raises:
        InputError: unreadable checkpoint, or neither exporter could export the model.
    """
    source = checkpoint_or_model
    model, ck_info = (source, {}) if isinstance(source, nn.Module) else load_model(source)
    geometry = window_geometry(model, info or ck_info)
    out_path = Path(out_path)
    if batch is not None and (isinstance(batch, bool) or not isinstance(batch, int) or batch < 1):
        raise InputError(None, f"batch must be a positive integer or None (dynamic), got {batch!r}")
    stem = out_path.name[: -len(".onnx")] if out_path.name.endswith(".onnx") else out_path.name
    paths, names = {"model": out_path}, streaming_names(model, geometry)
    if streaming and names != ["window"]:  # a lone window part is the whole model again
        paths.update({n: out_path.parent / f"{stem}.{n}.onnx" for n in names})
    return export_parts(model, paths, geometry=geometry, batch=batch, verify=verify, metadata=_metadata(model, ck_info))


def _metadata(model: nn.Module, info: Mapping[str, Any]) -> dict[str, Any]:
    """What a program running the ONNX files alone needs besides them: the model and its settings, the
    sensor (its frame rate), and the operating point the detector alarms at (threshold, debounce
    frames, hold seconds, start-up frames), with its promise; ``null`` where the checkpoint has none."""
    from slipsense.measures.promise import promise_text

    op = info.get("operating_point")
    keys = ("threshold", "debounce", "hold_s", "startup", "horizon", "chosen_on", "rule")
    sensor = info.get("sensor") or {}
    return {
        "model": getattr(model, "model_name", type(model).__name__),
        "config": model.config() if hasattr(model, "config") else {},
        "sensor": sensor,
        "fps": sensor.get("fps"),
        "operating_point": {k: op[k] for k in keys if k in op} if isinstance(op, dict) else None,
        "promise": promise_text(op),
    }
