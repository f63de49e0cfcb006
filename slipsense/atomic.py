"""Atomic file writes: a reader sees the old file or the whole new one, never half of one.

Checkpoints, caches and reports all go through here, so a run killed at any moment leaves every
file it had written before intact.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import tempfile
from pathlib import Path
from typing import Callable, Iterator

from safetensors import SafetensorError

from slipsense.errors import OutputError


def _why(exc: BaseException) -> str:
    """What went wrong, in the system's words: ``No space left on device``."""
    if isinstance(exc, OSError):
        return exc.strerror or str(exc)
    text = str(exc)
    # safetensors reports an I/O error inside its own message: 'Error while serializing: I/O error:
    # No space left on device (os error 28) at path ...' (0.5 and later) or '... IoError(Os { code:
    # 28, kind: StorageFull, message: "No space left on device" })' (before)
    for pattern in (r"I/O error: (.+?) \(os error \d+\)", r'IoError\(Os \{.*?message: "(.+?)"'):
        found = re.search(pattern, text)
        if found:
            return found.group(1)
    return text


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it is fsynced and renamed onto ``path``.

    The temporary file keeps the final suffix so libraries that look at the extension
    (numpy, matplotlib, safetensors) behave. On error the temporary file is removed. A place that
    cannot be written (a folder in the way, a read-only folder, a full disk) raises
    :class:`~slipsense.errors.OutputError` naming ``path`` (an OSError too), whether the write
    failed with an OSError or with a writer's own error (safetensors' SafetensorError).
    """
    path = Path(path)
    if path.is_dir():
        raise OutputError(path, "is a folder; expected a file path")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    except OSError as exc:
        raise OutputError(path, f"cannot be written ({_why(exc)})") from None
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        try:
            yield tmp_path
        except OSError as exc:
            if exc.filename is None or str(exc.filename) == str(tmp_path):
                raise OutputError(path, f"cannot be written ({_why(exc)})") from None
            raise
        except SafetensorError as exc:  # a full disk while safetensors writes the temporary file
            raise OutputError(path, f"cannot be written ({_why(exc)})") from None
        try:
            with open(tmp_path, "rb+") as fh:
                os.fsync(fh.fileno())
            # mkstemp creates 0600 (and some writers replace the file): give the result the mode a
            # plain open() would, 0666 less the umask.
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp_path, 0o666 & ~umask)
            os.replace(tmp_path, path)
        except OSError as exc:
            raise OutputError(path, f"cannot be written ({_why(exc)})") from None
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def _existing_ancestor(path: Path) -> Path:
    p = path.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _can_create_in(folder: Path) -> bool:
    """Whether a file can be created in ``folder`` (tried, then removed: permission bits do not
    tell for root, read-only mounts or full disks)."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=".slipsense-probe.", dir=folder)
    except OSError:
        return False
    os.close(fd)
    os.unlink(tmp)
    return True


def check_output_file(path: str | Path | None, option: str = "output") -> None:
    """Before any work: OutputError unless ``path`` can be written as a file (not a folder, inside
    a folder that exists or can be made, and that takes new files)."""
    if path is None:
        return
    path = Path(path)
    if path.is_dir():
        raise OutputError(path, f"is a folder; {option} takes a file path")
    base = _existing_ancestor(path.parent)
    if not base.is_dir():
        raise OutputError(path, f"cannot be written: {base} is a file, not a folder")
    if not _can_create_in(base):
        raise OutputError(path, f"cannot be written: {base} does not take new files (read-only or no permission)")


def check_output_dir(path: str | Path | None, option: str = "output folder") -> None:
    """Before any work: OutputError unless ``path`` is, or can be made, a folder that takes files."""
    if path is None:
        return
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(path, f"is a file; {option} takes a folder")
    base = _existing_ancestor(path)
    if not base.is_dir():
        raise OutputError(path, f"cannot be made: {base} is a file, not a folder")
    if not _can_create_in(base):
        raise OutputError(path, f"cannot be written: {base} does not take new files (read-only or no permission)")


def file_sha256(path: str | Path) -> str:
    """The sha256 of a file's bytes (hex), read in 1 MB blocks: what cache sidecars and manifests keep."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text(path: str | Path, text: str) -> None:
    write_bytes(path, text.encode("utf-8"))


def write_with(path: str | Path, writer: Callable[[Path], None]) -> None:
    """Call ``writer(tmp_path)`` and atomically move the result onto ``path``."""
    with atomic_path(path) as tmp:
        writer(tmp)
