"""One configuration tree for every training command: ``model``, ``data`` and ``train`` sections.

A run is described by a tree like ``configs/vivit-paper.yaml``::

    model: {name: vivit, patch_size: [40, 40]}   # the model's name, preset and settings
    data:  {frames: 5, size: [240, 320], split: objects, fold: 0}
    train: {epochs: 75, batch_size: 16, lr: 3.0e-4, seed: 0}

and built in layers, later ones winning: the command's defaults < the model's recipe and what the
recordings are (:meth:`slipsense.models.base.SlipModel.training_defaults`, applied by
:meth:`~slipsense.training.settings.RunConfig.from_tree`) < ``--config FILE`` < the command's own
options (``--epochs 3``) < ``--set section.key=value`` (a bare ``key=value`` goes to ``model``). A
tree is checked once, into the frozen run that training reads
(:class:`slipsense.training.settings.RunConfig`); the run's resolved tree is stored whole in every
checkpoint (``info["config"]``) and written as ``config.yaml`` beside it, so ``--config
RUN/config.yaml`` repeats a run. This module is the torch-free part (``slipsense --help`` reads it).
"""

from __future__ import annotations

import json
from dataclasses import MISSING, fields
from pathlib import Path
from typing import Any, Iterable, Mapping

import yaml

from slipsense.errors import ConfigError, InputError

SECTIONS = ("model", "data", "train")
#: The model trained where none is named: the slip detector over whole grasps (here, below torch, so
#: that ``slipsense --help`` can show it without starting torch).
DEFAULT_MODEL = "motionnet"
#: largest configuration file read (a tree is a few hundred bytes)
MAX_BYTES = 1_000_000


def empty_tree() -> dict[str, dict[str, Any]]:
    return {s: {} for s in SECTIONS}


def load_tree(path: str | Path) -> dict[str, dict[str, Any]]:
    """Read a YAML (or JSON) tree; InputError naming the file on anything but ``section: {key: value}``."""
    path = Path(path)
    try:
        if path.stat().st_size > MAX_BYTES:
            raise InputError(path, f"configuration file is over {MAX_BYTES:,} bytes")
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(path, "configuration file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"configuration file cannot be read: {exc}") from None
    try:
        doc = yaml.safe_load(text)  # safe_load: plain data only, never objects
    except yaml.YAMLError as exc:
        raise InputError(path, f"not valid YAML: {str(exc).splitlines()[0]}") from None
    if doc is None:
        doc = {}
    if not isinstance(doc, dict):
        raise InputError(path, f"expected sections {', '.join(SECTIONS)} at the top, got a {type(doc).__name__}")
    tree = empty_tree()
    for section, values in doc.items():
        if section not in SECTIONS:
            raise InputError(path, f"unknown section {section!r}; sections: {', '.join(SECTIONS)}")
        if values is None:
            continue
        if not isinstance(values, dict) or not all(isinstance(k, str) for k in values):
            raise InputError(path, f"section {section!r} must map names to values")
        tree[section].update(values)
    return tree


def merge(tree: Mapping[str, Mapping[str, Any]], *layers: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """``tree`` with each layer's values written over it (section by section, key by key); a None
    value in a layer is written too (``--set data.fold=null`` clears a fold)."""
    out = {s: dict(tree.get(s) or {}) for s in SECTIONS}
    for layer in layers:
        for section, values in layer.items():
            out.setdefault(section, {}).update(values)
    return out


def given(options: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """A command's options as a tree layer: the ones given (None means "not given" there)."""
    return {s: {k: v for k, v in values.items() if v is not None} for s, values in options.items()}


def parse_sets(sets: Iterable[str] | None) -> dict[str, dict[str, Any]]:
    """``--set section.key=value`` pairs as a tree layer; values are JSON where they parse (numbers,
    lists, true/false), else strings. A key without a known section goes to ``model``."""
    layer: dict[str, dict[str, Any]] = {}
    for item in sets or []:
        if "=" not in item:
            raise ConfigError(f"--set expects section.key=value, got {item!r}")
        key, raw = item.split("=", 1)
        key = key.strip()
        section, _, name = key.partition(".")
        if section not in SECTIONS or not name:
            section, name = "model", key
        if not name:
            raise ConfigError(f"--set expects section.key=value, got {item!r}")
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw
        layer.setdefault(section, {})[name] = value
    return layer


def check_keys(
    tree: Mapping[str, Mapping[str, Any]], allowed: Mapping[str, Iterable[str]], where: str = "configuration"
) -> None:
    """ConfigError naming the first key of a section of ``tree`` that ``allowed`` does not name."""
    for section, values in tree.items():
        known = allowed[section]
        unknown = sorted(set(values) - set(known))
        if unknown:
            raise ConfigError(
                f"{where}: {section}.{unknown[0]} is not a setting; {section} settings: {', '.join(sorted(known))}"
            )


def typed(cls: type, values: Mapping[str, Any], where: str) -> dict[str, Any]:
    """``values`` for dataclass ``cls`` with each value checked against its field's default type: a
    float field takes numbers and numeric strings (YAML reads ``3e-4`` as a string); an int field
    whole numbers; a bool field true/false; None keeps the default where the default is not None.
    ConfigError names the key otherwise."""
    defaults = {f.name: f.default for f in fields(cls) if f.default is not MISSING}
    out: dict[str, Any] = {}
    for key, value in values.items():
        default = defaults.get(key)
        if value is None and default is not None:
            continue
        kind = type(default)
        out[key] = value
        if value is None or default is None:
            continue
        if kind is bool and not isinstance(value, bool):
            raise ConfigError(f"{where}: {key} must be true or false, got {value!r}")
        if kind is int and (isinstance(value, bool) or not isinstance(value, int)):
            raise ConfigError(f"{where}: {key} must be a whole number, got {value!r}")
        if kind is float:
            try:
                if isinstance(value, bool):
                    raise ValueError
                out[key] = float(value)
            except (TypeError, ValueError):
                raise ConfigError(f"{where}: {key} must be a number, got {value!r}") from None
    return out


def to_plain(tree: Mapping[str, Any]) -> dict[str, Any]:
    """A JSON/YAML-safe deep copy (paths and tuples become strings and lists)."""
    return json.loads(json.dumps(dict(tree), default=str))


def dump_tree(tree: Mapping[str, Any]) -> str:
    return yaml.safe_dump(to_plain(tree), sort_keys=False, default_flow_style=None)


#: Seeds are unsigned 32-bit integers (what NumPy's legacy generator takes, and every seed here fits).
MAX_SEED = 2**32 - 1


def check_seed(seed: int, option: str = "--seed") -> int:
    """``seed`` if it is in 0..2**32-1, else ConfigError (a negative seed breaks NumPy's generators)."""
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise ConfigError(f"{option} must be an integer in 0..{MAX_SEED}, got {seed!r}")
    return seed
