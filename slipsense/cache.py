"""Verified on-disk cache entries: every cache of slipsense keeps its entries through :class:`Entry`.

An entry is named by :func:`key`, a hash of what it is made from (its ``inputs``: versions,
settings, each source file's path, size and modification time), and is one file ``<key><suffix>``
with ``<key><suffix>.check`` beside it, or a folder of named files with ``check.json`` inside. The
files are written atomically and the check file last; it records the inputs and each file's
sha256. An entry is used only when its check file records the same inputs, every file has its
sha256 and the reader accepts what it holds; otherwise (damaged, made from other inputs, check file
garbled) it is rebuilt with a :class:`~slipsense.errors.CacheWarning`, or, with no check file (an
entry whose writing never finished), rebuilt without one.
"""

from __future__ import annotations

import hashlib
import json
import warnings
import zipfile
from pathlib import Path
from typing import Any, Callable, Sequence, TypeVar

from slipsense.atomic import atomic_path, file_sha256, write_text
from slipsense.errors import CacheWarning, InputError

T = TypeVar("T")
#: What a reader may raise on an entry it cannot use (its own checks raise ValueError).
UNUSABLE = (OSError, ValueError, KeyError, TypeError, IndexError, EOFError, zipfile.BadZipFile, InputError)


def key(inputs: Any) -> str:
    """32 hex digits of the sha256 of ``inputs`` as canonical JSON (values JSON lacks by ``str``)."""
    return hashlib.sha256(json.dumps(inputs, sort_keys=True, default=str).encode()).hexdigest()[:32]


class Entry:
    """The entry of the cache ``folder`` made from ``inputs``; ``what`` names the cache in warnings.

    ``Entry(folder, inputs, what, suffix=".npy")`` is the file ``folder/<prefix><key>.npy``;
    ``Entry(folder, inputs, what, names=[...])`` the files ``names`` in the folder
    ``folder/<prefix><key>``, or in ``folder`` itself with ``keyed=False`` (a folder its caller names).
    """

    def __init__(
        self,
        folder: str | Path,
        inputs: Any,
        what: str,
        *,
        suffix: str = "",
        prefix: str = "",
        names: Sequence[str] | None = None,
        keyed: bool = True,
    ):
        self.inputs = json.loads(json.dumps(inputs, sort_keys=True, default=str))  # as the check file holds them
        self.what = what
        self.path = Path(folder) / f"{prefix}{key(inputs)}{suffix}" if keyed else Path(folder)
        self.is_folder = names is not None
        self.files = [self.path / n for n in names] if names is not None else [self.path]
        self.check = self.path / "check.json" if self.is_folder else self.path.with_name(self.path.name + ".check")

    def load(self, read: Callable[..., T]) -> T | None:
        """``read(*files)`` of the entry when it passes its checks (``read`` raises ValueError on
        contents it refuses); else None: silently when there is no check file (no entry, or one
        whose writing never finished), with a warning when the check file is there."""
        if not self.check.is_file():
            return None
        try:
            info = json.loads(self.check.read_text(encoding="utf-8"))
            if not isinstance(info, dict) or info.get("inputs") != self.inputs:
                raise ValueError("made from other inputs")
            for f in self.files:
                if not isinstance(info.get("sha256"), dict) or info["sha256"].get(f.name) != file_sha256(f):
                    raise ValueError(f"{f.name}: checksum mismatch")
            return read(*self.files)
        except UNUSABLE as exc:
            warnings.warn(f"{self.path}: {self.what} entry failed its checks ({exc}); rebuilding", CacheWarning, 3)
            return None

    def save(self, write: Callable[[Path], Any]) -> bool:
        """Write the entry, then its check file: ``write(path)`` writes the file at ``path`` (a
        temporary file moved onto the entry's), or a folder entry's files into the folder ``path``
        (each atomically). A file entry that cannot be written is only warned about (False: its
        value is in hand); a folder entry's files are the value itself, so that raises."""
        try:
            self.check.unlink(missing_ok=True)
            if self.is_folder:
                self.path.mkdir(parents=True, exist_ok=True)
                write(self.path)
            else:
                with atomic_path(self.path) as tmp:
                    write(tmp)
            sums = {f.name: file_sha256(f) for f in self.files}
            write_text(self.check, json.dumps({"inputs": self.inputs, "sha256": sums}, indent=1))
        except OSError as exc:
            if self.is_folder:
                raise
            warnings.warn(f"{self.path}: cannot write the {self.what} ({exc}); continuing without it", CacheWarning, 3)
            return False
        return True

    def get(self, read: Callable[..., T], build: Callable[[], T], write: Callable[[Path, T], Any]) -> T:
        """The entry as ``read(*files)`` gives it, or else ``build()``, stored by ``write(path, value)``."""
        value = self.load(read)
        if value is None:
            value = build()
            self.save(lambda path: write(path, value))
        return value
