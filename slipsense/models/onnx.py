"""ONNX export of a slipsense model's parts, the ONNX Runtime session, and the verified cache of the
streaming parts a live stream runs on ONNX Runtime (:mod:`slipsense.models.runners`).

Which exporter, which files: :mod:`slipsense.streaming.export` (the user-facing export of a checkpoint).
"""

from __future__ import annotations

import contextlib
import hashlib
import inspect
import io
import logging
import os
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np
import torch
from torch import nn

from slipsense import __version__
from slipsense.atomic import atomic_path
from slipsense.cache import Entry
from slipsense.errors import InputError

#: Opset for the TorchScript exporter (its newest well-tested one); the dynamo exporter picks its own.
TORCHSCRIPT_OPSET = 17


@dataclass
class ExportResult:
    """What :func:`export_onnx` wrote.

    ``paths``: ``{"model" | "frame" | "window": file}``; ``exporter``: per file, ``"torchscript"``
    or ``"dynamo"``; ``max_abs_diff``: per file, ONNX Runtime vs PyTorch on the example input
    (only when verified).
    """

    paths: dict[str, Path] = field(default_factory=dict)
    exporter: dict[str, str] = field(default_factory=dict)
    max_abs_diff: dict[str, float] = field(default_factory=dict)


def exportable(model: nn.Module) -> nn.Module:
    """An eval-mode copy of ``model`` set up for tracing (each model says how: ``SlipModel.exportable``)."""
    if not callable(getattr(model, "onnx_parts", None)):  # not isinstance: models.base reaches here through its streams
        raise InputError(None, f"{type(model).__name__} is not a slipsense model (see slipsense.models.base)")
    return model.exportable()


def export_module(
    module: nn.Module,
    examples: tuple[torch.Tensor, ...],
    path: str | Path,
    inputs: list[str],
    outputs: list[str],
    dynamic: Mapping[str, Mapping[int, str]],
) -> str:
    """Export ``module(*examples)`` to ``path`` (atomically); returns the exporter that worked.

    ``dynamic`` names the free axes per input/output name (``{}``: every axis fixed to the example's).
    Tries the TorchScript exporter, then the dynamo exporter; raises InputError with both reasons.
    """
    path = Path(path)
    module = module.eval()
    errors, names = [], dict(input_names=inputs, output_names=outputs)
    for exporter in ("torchscript", "dynamo"):
        try:
            with atomic_path(path) as tmp, torch.no_grad(), _quiet():
                if exporter == "torchscript":
                    axes = {k: dict(v) for k, v in dynamic.items()} or None
                    settings = dict(opset_version=TORCHSCRIPT_OPSET, do_constant_folding=True, dynamic_axes=axes)
                    torch.onnx.export(module, examples, str(tmp), dynamo=False, **names, **settings)
                else:
                    dims: dict[str, Any] = {}
                    shapes = tuple(
                        {
                            axis: dims.setdefault(label, torch.export.Dim(label, min=1, max=65536))
                            for axis, label in dynamic.get(name, {}).items()
                        }
                        or None
                        for name in inputs
                    )
                    settings = dict(dynamic_shapes=shapes if any(shapes) else None, optimize=True, verbose=False)
                    program = torch.onnx.export(module, examples, dynamo=True, **names, **settings)
                    program.save(str(tmp), external_data=False)
            return exporter
        except Exception as exc:  # each exporter raises its own zoo of error types
            errors.append(f"{exporter}: {type(exc).__name__}: {' '.join(str(exc).split())[:300]}")
    raise InputError(path, "ONNX export failed (" + "; ".join(errors) + ")")


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """Silence the exporters: deprecation/tracer warnings, progress lines and IR dumps on stdout, and
    torch.onnx's logger (which reports e.g. missing torchvision ops). Errors still propagate."""
    # torch.onnx's logger, and the root logger onnxruntime.quantization writes its advice to
    loggers = [logging.getLogger("torch.onnx"), logging.getLogger()]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.ERROR)
    sys.stdout.flush()
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    # The TorchScript exporter switches its C++ log on whatever `verbose` says (torch 2.13) and dumps
    # the whole IR graph to file descriptor 1 when an export fails: redirect the descriptor itself.
    os.dup2(devnull, 1)
    try:
        with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
            warnings.simplefilter("ignore")
            yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def quantize_int8(src: str | Path, dst: str | Path) -> Path:
    """Dynamically quantize an ONNX file's MatMul/Gemm weights to int8 (``onnxruntime.quantization``).

    Activations are quantized on the fly per batch; ONNX Runtime runs the products as int8. For
    weight-bound models (the paper-size STNet streams 0.5 GB of float32 weights per window) this
    cuts the per-frame time about 3x; results differ from float32 by quantization error.
    """
    try:
        from onnxruntime.quantization import QuantType, quantize_dynamic
    except ModuleNotFoundError:
        raise InputError(src, "onnxruntime is not installed (pip install 'slipsense[export]')") from None
    dst = Path(dst)
    with atomic_path(dst) as tmp, _quiet():
        quantize_dynamic(str(src), str(tmp), weight_type=QuantType.QInt8, op_types_to_quantize=["MatMul", "Gemm"])
    return dst


def onnx_session(path: str | Path, threads: int | None = None):
    """An ONNX Runtime CPU session for ``path``.

    ``threads``: intra-op threads; default ``torch.get_num_threads()``, so that both backends of the
    live detector use the same cores (ONNX Runtime's own default, one spinning thread per physical
    core, fights other processes on a shared machine).
    """
    try:
        import onnxruntime as ort
    except ModuleNotFoundError:
        raise InputError(path, "onnxruntime is not installed (pip install 'slipsense[export]')") from None
    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    opts.intra_op_num_threads = int(threads if threads is not None else torch.get_num_threads())
    try:
        return ort.InferenceSession(str(path), sess_options=opts, providers=["CPUExecutionProvider"])
    except Exception as exc:
        raise InputError(
            path, f"ONNX Runtime cannot load it ({type(exc).__name__}: {' '.join(str(exc).split())[:200]})"
        ) from None


def max_abs_diff(path: str | Path, module: nn.Module, x: torch.Tensor | tuple[torch.Tensor, ...]) -> float:
    """Largest |ONNX Runtime - PyTorch| over every output of ``module`` exported at ``path``, on ``x``."""
    xs = x if isinstance(x, tuple) else (x,)
    with torch.no_grad():
        ref = module.eval()(*xs)
    refs = ref if isinstance(ref, (tuple, list)) else (ref,)
    session = onnx_session(path)
    feed = {i.name: v.numpy() for i, v in zip(session.get_inputs(), xs)}
    got = session.run(None, feed)
    return max(float(np.abs(g - r.float().numpy()).max()) for g, r in zip(got, refs))


def streaming_names(model: nn.Module, geometry: Mapping[str, Any]) -> list[str]:
    return list(model.streaming_modules(geometry))


#: The prefix of the metadata keys slipsense writes into every ONNX file it exports.
META = "slipsense."


def write_metadata(path: str | Path, metadata: Mapping[str, Any]) -> None:
    """Store ``metadata`` in the ONNX file's ``metadata_props`` as ``slipsense.<key>``, each value as
    JSON (strings too: every value reads back with one JSON parse); the file is rewritten atomically."""
    import json

    import onnx

    proto = onnx.load(str(path))
    keep = [p for p in proto.metadata_props if not p.key.startswith(META)]
    del proto.metadata_props[:]
    proto.metadata_props.extend(keep)
    for key, value in metadata.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = META + key, json.dumps(value, sort_keys=True)
    with atomic_path(path) as tmp:
        onnx.save(proto, str(tmp))


def onnx_metadata(path: str | Path) -> dict[str, Any]:
    """What :func:`write_metadata` stored in an ONNX file, read with ONNX Runtime alone (as a user's
    program without slipsense would): ``{key: value}``, JSON values decoded, without the prefix."""
    import json

    meta = onnx_session(path, threads=1).get_modelmeta().custom_metadata_map
    return {key[len(META) :]: json.loads(value) for key, value in meta.items() if key.startswith(META)}


def export_parts(
    model: nn.Module,
    paths: Mapping[str, Path],
    *,
    geometry: Mapping[str, Any],
    batch: int | None = None,
    verify=True,
    metadata: Mapping[str, Any] | None = None,
) -> ExportResult:
    """Write the model's ONNX files (:meth:`SlipModel.onnx_parts`) ``{name: path}``, in that order, each
    verified against the model as it runs in PyTorch; ``metadata`` (the operating point, the sensor,
    the model's settings) goes into every file with its ``part`` name (:func:`write_metadata`)."""
    parts = exportable(model).onnx_parts(geometry, batch)
    ref = {"model": model.eval(), **model.eval().streaming_modules(geometry)}
    result = ExportResult()
    for key, path in paths.items():
        part = parts[key]
        result.exporter[key] = export_module(part.module, part.example, path, part.inputs, part.outputs, part.dynamic)
        if metadata is not None:
            write_metadata(path, {**metadata, "part": key, "inputs": part.inputs, "outputs": part.outputs})
        result.paths[key] = path
        if verify:
            result.max_abs_diff[key] = max_abs_diff(path, ref[key], part.example)
    return result


def _parts_key(model: nn.Module, geometry: Mapping[str, Any], dtype: str) -> dict[str, Any]:
    config = model.config() if hasattr(model, "config") else {}
    # the model's own code: parts exported before a change to it (their inputs, their maths) are stale
    code = hashlib.sha256(Path(inspect.getfile(type(model))).read_bytes()).hexdigest()[:16]
    key = dict(model=getattr(model, "model_name", type(model).__name__), config=config, geometry=dict(geometry))
    return {**key, "dtype": dtype, "slipsense": __version__, "torch": torch.__version__, "code": code}


def cached_streaming_parts(
    model: nn.Module, folder: str | Path, geometry: Mapping[str, Any], dtype: str = "float32"
) -> dict[str, Path]:
    """The model's streaming modules as ONNX files in ``folder``, exported unless a verified copy is
    there: ``{name: path}`` (``frame.onnx``, ``window.onnx`` / ``step.onnx``), their ``*.int8.onnx``
    copies for ``dtype="int8"``.

    The folder is a verified cache entry (:mod:`slipsense.cache`): ``folder/check.json`` (written
    last) records the model's name, config, code, geometry, dtype, the library versions and each
    file's sha256; files that do not match it (damaged, half written, from another checkpoint) are
    exported again with a :class:`~slipsense.errors.CacheWarning`.
    """
    parts = streaming_names(model, geometry)
    names = [p + (".int8.onnx" if dtype == "int8" else ".onnx") for p in parts]
    entry = Entry(folder, _parts_key(model, geometry, dtype), "ONNX parts", names=names, keyed=False)

    def export(folder: Path) -> None:
        export_parts(model, {p: folder / f"{p}.onnx" for p in parts}, geometry=geometry, verify=False)
        for p in parts if dtype == "int8" else []:
            quantize_int8(folder / f"{p}.onnx", folder / f"{p}.int8.onnx")

    if entry.load(lambda *files: files) is None:
        entry.save(export)
    return dict(zip(parts, entry.files))
