"""Checkpoints: one safetensors file holding the weights and, in its metadata, the full config.

A checkpoint rebuilds its model with no other file: ``load_model(path)``. Training state for
``--resume`` (optimizer, scheduler, RNG, epoch) lives beside it in ``resume.pt``: also a safetensors
file (tensors + JSON), never a pickle, so a run folder from elsewhere cannot run code when resumed.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn as nn
from safetensors import safe_open
from safetensors.torch import load_file

from slipsense import __version__
from slipsense.atomic import atomic_path
from slipsense.errors import ConfigError, InputError
from slipsense.models import build

META_KEY = "slipsense"


def _save(path: str | Path, tensors: dict[str, torch.Tensor], metadata: dict[str, str]) -> None:
    """A safetensors file written atomically."""
    from safetensors.torch import save_file  # looked up per call: tests/test_disk_full.py replaces it

    with atomic_path(Path(path)) as tmp:
        save_file(tensors, str(tmp), metadata=metadata)


def save_checkpoint(path: str | Path, model: nn.Module, info: dict[str, Any]) -> Path:
    """Write ``model``'s weights and ``info`` (must hold ``model`` and ``model_config``) atomically.

    ``info`` is stored as JSON in the safetensors metadata, together with the slipsense version.
    """
    model = getattr(model, "module", model)  # unwrap DistributedDataParallel
    info = {**info, "model": model.model_name, "model_config": model.config(), "slipsense_version": __version__}
    tensors = {k: v.detach().contiguous().cpu() for k, v in model.state_dict().items()}
    _save(path, tensors, {META_KEY: json.dumps(info)})
    return Path(path)


def _contents(fh: Any) -> tuple[dict[str, str], dict[str, torch.Tensor]]:
    """The metadata and tensors of an open safetensors file."""
    return dict(fh.metadata() or {}), {k: fh.get_tensor(k) for k in fh.keys()}


def update_info(path: str | Path, updates: dict[str, Any]) -> Path:
    """Rewrite a checkpoint's config with ``updates`` merged in (weights unchanged; atomic)."""
    path = Path(path)
    with safe_open(str(path), framework="pt") as fh:
        meta, tensors = _contents(fh)
    info = {**json.loads(meta[META_KEY]), **updates}
    meta[META_KEY] = json.dumps(info)
    _save(path, tensors, meta)
    return path


def _read(path: Path, problem: str, read: Any) -> Any:
    """``read(fh)`` of the safetensors file ``path``; InputError "``problem`` (the error)" where it fails."""
    try:
        with safe_open(str(path), framework="pt") as fh:
            return read(fh)
    except Exception as exc:  # safetensors raises several error types for a damaged file
        raise InputError(path, f"{problem} ({type(exc).__name__}: {exc})") from None


def read_info(path: str | Path) -> dict[str, Any]:
    """The config stored in a checkpoint, without loading its weights."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "checkpoint not found")
    meta = _read(path, "not a readable safetensors checkpoint", lambda fh: fh.metadata() or {})
    if META_KEY not in meta:
        raise InputError(path, "safetensors file carries no slipsense config (not a slipsense checkpoint)")
    try:
        info = json.loads(meta[META_KEY])
    except json.JSONDecodeError as exc:
        raise InputError(path, f"checkpoint config is not valid JSON ({exc})") from None
    if not isinstance(info, dict):
        raise InputError(path, f"checkpoint config is a JSON {type(info).__name__}, not an object")
    for key in ("model", "model_config"):
        if key not in info:
            raise InputError(path, f"checkpoint config lacks {key!r}")
    if not isinstance(info["model"], str):
        raise InputError(path, f"checkpoint model name must be a string, got {type(info['model']).__name__}")
    if not isinstance(info["model_config"], dict):
        raise InputError(
            path, f"checkpoint model_config must be a mapping of settings, got a {type(info['model_config']).__name__}"
        )
    return info


#: A model setting may exceed this only when the weights in the file are as large.
CONFIG_FLOOR = 4096


def _check_config_bounds(path: Path, config: dict[str, Any], shapes: dict[str, tuple[int, ...]]) -> None:
    """Refuse, before anything is allocated, settings no model in this file can have.

    Every number in ``model_config`` (nested lists too) must be at most the largest of
    :data:`CONFIG_FLOOR`, the largest tensor dimension in the file and its number of tensors: a
    width of 1e9 needs a tensor that wide, a depth of 1e7 at least that many tensors.
    """
    limit = max([CONFIG_FLOOR, len(shapes)] + [d for shape in shapes.values() for d in shape])

    def walk(key: str, v: Any, depth: int = 0) -> None:
        if depth > 8:
            raise InputError(path, f"checkpoint setting {key} is nested too deeply")
        if isinstance(v, bool) or v is None or isinstance(v, str):
            return
        if isinstance(v, (int, float)):
            if not math.isfinite(v) or abs(v) > limit:
                raise InputError(
                    path,
                    f"checkpoint setting {key}={v!r} is out of range (at most {limit} for the weights this file holds)",
                )
            return
        if isinstance(v, (list, tuple)):
            if len(v) > limit:
                raise InputError(path, f"checkpoint setting {key} lists {len(v)} values")
            for i, item in enumerate(v):
                walk(f"{key}[{i}]", item, depth + 1)
            return
        if isinstance(v, dict):
            for k, item in v.items():
                walk(f"{key}.{k}", item, depth + 1)
            return
        raise InputError(path, f"checkpoint setting {key} has an unsupported type {type(v).__name__}")

    for k, v in config.items():
        walk(k, v)


def _check_fit(path: Path, name: str, expected: dict[str, tuple], got: dict[str, tuple]) -> None:
    """InputError unless the weights ``got`` (name -> shape) are the ones model ``name`` has."""
    missing, unexpected = sorted(set(expected) - set(got)), sorted(set(got) - set(expected))
    if missing or unexpected:
        raise InputError(path, f"weights do not fit model {name!r}: missing {missing[:3]}, unexpected {unexpected[:3]}")
    for key, shape in expected.items():
        if got[key] != shape:
            raise InputError(path, f"weight {key} has shape {got[key]}, model expects {shape}")


def load_model(path: str | Path, expect_model: str | None = None) -> tuple[nn.Module, dict[str, Any]]:
    """Rebuild the model a checkpoint describes and load its weights; returns ``(model, info)``.

    The model is in eval mode on the CPU. ``expect_model`` (e.g. ``"vivit"``) rejects a checkpoint
    of another network with a clear error.
    """
    path = Path(path)
    info = read_info(path)
    if expect_model is not None and info["model"] != expect_model:
        raise InputError(path, f"checkpoint holds a {info['model']!r} model, expected {expect_model!r}")
    # the tensor shapes the file's header states (no tensor is loaded)
    shapes = _read(
        path, "checkpoint weights are unreadable", lambda fh: {k: tuple(fh.get_slice(k).get_shape()) for k in fh.keys()}
    )
    _check_config_bounds(path, info["model_config"], shapes)
    try:  # on the meta device first (no memory): weights that do not fit it are refused before allocating
        with torch.device("meta"):
            meta = build(info["model"], **info["model_config"])
    except ConfigError as exc:
        raise InputError(path, f"checkpoint config cannot build its model: {exc}") from None
    except Exception:  # a model that cannot be built on the meta device is checked after building
        pass
    else:
        _check_fit(path, info["model"], {k: tuple(v.shape) for k, v in meta.state_dict().items()}, shapes)
    try:
        model = build(info["model"], **info["model_config"])
    except ConfigError as exc:
        raise InputError(path, f"checkpoint config cannot build its model: {exc}") from None
    try:
        state = load_file(str(path))
    except Exception as exc:
        raise InputError(path, f"checkpoint weights are unreadable ({type(exc).__name__}: {exc})") from None
    own = model.state_dict()
    _check_fit(
        path, info["model"], {k: tuple(v.shape) for k, v in own.items()}, {k: tuple(v.shape) for k, v in state.items()}
    )
    for key, ref in own.items():
        if state[key].is_floating_point() != ref.is_floating_point():
            # load_state_dict would cast int64 weights to float silently: nonsense predictions, no error
            raise InputError(path, f"weight {key} is stored as {state[key].dtype}, model expects {ref.dtype}")
        if state[key].is_floating_point() and not torch.isfinite(state[key]).all():
            raise InputError(path, f"weight {key} contains NaN or inf")
    model.load_state_dict(state)
    model.eval()
    return model, info


#: Metadata key of a resume state file, and the format tag stored under it.
RESUME_KEY = "slipsense-resume"
RESUME_FORMAT = 1


def _encode(obj: Any, tensors: dict[str, torch.Tensor]) -> Any:
    """``obj`` as JSON, its tensors moved to ``tensors`` (named ``t<k>``).

    Only plain data is accepted: None, bool, int, float, str, tuples, lists, dicts, torch tensors,
    numpy arrays and scalars. Reading it back builds nothing else, so a resume state cannot carry
    code the way a pickle can.
    """
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, int):
        return int(obj)
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else {"__float__": repr(obj)}
    if isinstance(obj, torch.Tensor):
        name = f"t{len(tensors)}"
        # a copy: safetensors refuses tensors sharing storage (tied weights)
        tensors[name] = obj.detach().cpu().contiguous().clone()
        return {"__tensor__": name}
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind not in "biuf":
            raise TypeError(f"resume state: numpy array of dtype {obj.dtype} cannot be stored")
        return {"__ndarray__": obj.tolist(), "dtype": obj.dtype.str, "shape": list(obj.shape)}
    if isinstance(obj, np.generic):
        return _encode(obj.item(), tensors)
    if isinstance(obj, tuple):
        return {"__tuple__": [_encode(v, tensors) for v in obj]}
    if isinstance(obj, list):
        return [_encode(v, tensors) for v in obj]
    if isinstance(obj, dict):
        if all(isinstance(k, str) and not k.startswith("__") for k in obj):
            return {k: _encode(v, tensors) for k, v in obj.items()}
        return {"__dict__": [[_encode(k, tensors), _encode(v, tensors)] for k, v in obj.items()]}
    raise TypeError(f"resume state: a {type(obj).__name__} cannot be stored (plain data only)")


_FLOATS = {"inf": math.inf, "-inf": -math.inf, "nan": math.nan}


def _decode(obj: Any, tensors: dict[str, torch.Tensor]) -> Any:
    """Inverse of :func:`_encode`; ValueError on anything it did not write."""
    if obj is None or isinstance(obj, (bool, str, int, float)):
        return obj
    if isinstance(obj, list):
        return [_decode(v, tensors) for v in obj]
    if not isinstance(obj, dict):
        raise ValueError(f"unexpected {type(obj).__name__} in the state")
    if "__tensor__" in obj:
        name = obj["__tensor__"]
        if not isinstance(name, str) or name not in tensors:
            raise ValueError(f"refers to a tensor {name!r} the file does not hold")
        return tensors[name]
    if "__float__" in obj:
        if obj["__float__"] not in _FLOATS:
            raise ValueError(f"unknown float {obj['__float__']!r}")
        return _FLOATS[obj["__float__"]]
    if "__ndarray__" in obj:
        dtype = np.dtype(str(obj.get("dtype")))
        if dtype.kind not in "biuf":
            raise ValueError(f"array of dtype {dtype} in the state")
        arr = np.array(obj["__ndarray__"], dtype=dtype)
        if list(arr.shape) != list(obj.get("shape", [])):
            raise ValueError("array shape does not match its data")
        return arr
    if "__tuple__" in obj:
        if not isinstance(obj["__tuple__"], list):
            raise ValueError("malformed tuple")
        return tuple(_decode(v, tensors) for v in obj["__tuple__"])
    if "__dict__" in obj:
        pairs = obj["__dict__"]
        if not isinstance(pairs, list) or not all(isinstance(p, list) and len(p) == 2 for p in pairs):
            raise ValueError("malformed mapping")
        out = {}
        for k, v in pairs:
            key = _decode(k, tensors)
            if not isinstance(key, (str, int, float, bool, type(None))):
                raise ValueError(f"mapping key of type {type(key).__name__}")
            out[key] = _decode(v, tensors)
        return out
    if any(k.startswith("__") for k in obj):
        raise ValueError(f"unknown entry {sorted(obj)[0]!r}")
    return {k: _decode(v, tensors) for k, v in obj.items()}


def save_resume_state(path: str | Path, state: dict[str, Any]) -> None:
    """Atomically write the training state needed by ``--resume``.

    The file is a safetensors file (whatever its name): the tensors (weights, optimizer moments,
    RNG state) as tensors, everything else as JSON in its metadata. Nothing in it is executable.
    """
    tensors: dict[str, torch.Tensor] = {}
    tree = _encode(state, tensors)
    meta = {
        RESUME_KEY: json.dumps({"format": RESUME_FORMAT, "state": tree}, allow_nan=False),
        "slipsense_version": __version__,
    }
    _save(path, tensors, meta)


#: What a resume state holds, and the type each entry must have.
RESUME_ENTRIES = dict(model=dict, optimizer=dict, scheduler=dict, rng=dict, history=list, best=(int, float), epoch=int)


def load_resume_state(path: str | Path) -> dict[str, Any]:
    """Read a state written by :func:`save_resume_state`; InputError naming ``path`` otherwise.

    Never unpickles: a ``resume.pt`` in torch's pickle format (written by an older slipsense, or put
    there by someone else) is refused, since loading it could run arbitrary code.
    """
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(9)
    except OSError as exc:
        raise InputError(path, f"resume state cannot be read ({exc.strerror or exc})") from None
    # safetensors: an 8-byte little-endian header length, then the JSON header
    is_safetensors = len(head) == 9 and head[8:9] == b"{" and int.from_bytes(head[:8], "little") < path.stat().st_size
    if not is_safetensors:
        if head[:4] == b"PK\x03\x04" or head[:1] == b"\x80":
            raise InputError(
                path,
                "resume state is a pickle (torch.save format), which is never loaded because "
                "unpickling can run code; delete it and train again without --resume",
            )
        raise InputError(path, "resume state is not a slipsense resume file (not safetensors)")
    meta, tensors = _read(path, "resume state is unreadable", _contents)
    if RESUME_KEY not in meta:
        raise InputError(path, "safetensors file holds no slipsense resume state")
    try:
        doc = json.loads(meta[RESUME_KEY])
        if not isinstance(doc, dict) or doc.get("format") != RESUME_FORMAT:
            raise ValueError(
                f"format {doc.get('format') if isinstance(doc, dict) else doc!r}, expected {RESUME_FORMAT}"
            )
        state = _decode(doc.get("state"), tensors)
    except (ValueError, TypeError, RecursionError) as exc:
        raise InputError(path, f"resume state is malformed ({exc})") from None
    if not isinstance(state, dict):
        raise InputError(path, "resume state is malformed (not a mapping)")
    for key, kind in RESUME_ENTRIES.items():
        if key not in state:
            raise InputError(path, f"resume state lacks {key!r}")
        if not isinstance(state[key], kind) or isinstance(state[key], bool):
            raise InputError(path, f"resume state entry {key!r} has type {type(state[key]).__name__}")
    if state["epoch"] < 0:
        raise InputError(path, f"resume state epoch is {state['epoch']}")
    if not all(isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state["model"].items()):
        raise InputError(path, "resume state model weights are not a mapping of names to tensors")
    return state
