"""Tracked marker shifts, looked up where the same frames were tracked before.

Shear retention and slip velocity follow the gel's markers cell by cell (Lucas-Kanade): most of their
time. What tracking gives depends on the frames and the tracking settings only, not on the numbers a
recipe chooses (``gate``, ``letgo``, ``floor``, ``window``) or learns, so each grasp is tracked once:

* in this process, the last :data:`IN_MEMORY` grasps' results are kept;
* on disk, under ``<cache root>/tracked`` (:mod:`slipsense.cache`: verified entries, safetensors), so
  that the worker processes of a training (its candidates and inner folds side by side) and the next
  training on the same grasps (``slipsense adapt``: every object fold and the final detector) read what
  one of them tracked. Measured on the lift grasps made into a 300 x 400 sensor: each fold of the
  slip-velocity family tracked all 44 grasps in each of its 2 workers, 8 s of a 6.4 s fold's 2 cores.

Never while an export traces the model: a looked-up result would be baked into the graph as a
constant of that input's frame count.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Callable, Sequence

import torch
from safetensors.torch import load_file, save_file
from torch import Tensor

from slipsense.cache import Entry
from slipsense.paths import cache_root

#: Grasps whose tracked shifts a process keeps in memory (a grasp of 200 frames: about 150 KB).
IN_MEMORY = 512
#: Bumped when what tracking computes changes: entries made before are not read.
VERSION = 1

_MEMO: dict[tuple, tuple[Tensor, ...]] = {}


def frames_digest(gray: Tensor) -> list:
    """``gray``'s shape, dtype and a digest of its values: what names its tracking."""
    data = gray.detach().contiguous().cpu().numpy()
    return [list(data.shape), str(data.dtype), hashlib.blake2b(data.tobytes(), digest_size=16).hexdigest()]


def tracked(
    kind: str, gray: Tensor, settings: Sequence, track: Callable[[Tensor], tuple[Tensor, ...]], on_disk: bool = True
):
    """``track(gray)`` (a tuple of tensors) of these frames under ``kind``'s tracking ``settings``, from
    memory, else from the disk cache, else computed and kept in both (in memory only without
    ``on_disk``: a model training by gradient sees each run flipped and at another gain every epoch,
    frames no other process will ask for)."""
    if torch.jit.is_tracing() or torch.onnx.is_in_onnx_export():
        return track(gray)
    inputs = {"kind": kind, "frames": frames_digest(gray), "settings": list(settings), "version": VERSION}
    memo_key = repr(inputs)
    found = _MEMO.get(memo_key)
    if found is None:
        if on_disk:
            entry = Entry(cache_root() / "tracked", inputs, "tracked markers", suffix=".safetensors")
            found = entry.get(_read, lambda: tuple(track(gray)), _write)
        else:
            found = tuple(track(gray))
        _MEMO[memo_key] = found
        while len(_MEMO) > IN_MEMORY:
            _MEMO.pop(next(iter(_MEMO)))  # the oldest first
    return found


def _read(path: Path) -> tuple[Tensor, ...]:
    tensors = load_file(str(path))
    return tuple(tensors[str(k)] for k in range(len(tensors)))


def _write(path: Path, value: tuple[Tensor, ...]) -> None:
    save_file({str(k): t.detach().contiguous() for k, t in enumerate(value)}, str(path))
