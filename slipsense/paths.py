"""Where the data lives: one setting, the ``SLIPSENSE_DATA`` environment variable."""

from __future__ import annotations

import os
from pathlib import Path

#: Environment variable naming the data folder (the one holding ``gelsight-slip/``).
DATA_ENV = "SLIPSENSE_DATA"


def data_root() -> Path:
    """The data folder: ``$SLIPSENSE_DATA``, else ``../shared/data`` beside the checkout."""
    env = os.environ.get(DATA_ENV)
    if env:
        return Path(env).expanduser()
    checkout = Path(__file__).resolve().parent.parent
    return (checkout.parent / "shared" / "data").resolve()


def gelsight_recordings() -> Path:
    """The shared GelSight recordings folder (``<data_root>/gelsight-slip``)."""
    return data_root() / "gelsight-slip"


def cache_root() -> Path:
    """Where preprocessed clips are cached: ``$SLIPSENSE_CACHE`` or ``~/.cache/slipsense``."""
    env = os.environ.get("SLIPSENSE_CACHE")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "slipsense"


def portable_path(path: str | Path) -> str:
    """``path`` as stored in checkpoints and reports: under the data folder it is written
    ``$SLIPSENSE_DATA/...``, under the working directory relative to it, so files written on one
    machine name no folder of that machine."""
    p = Path(path).resolve()
    for base, prefix in ((data_root().resolve(), f"${DATA_ENV}"), (Path.cwd().resolve(), None)):
        try:
            rel = p.relative_to(base)
        except ValueError:
            continue
        return f"{prefix}/{rel.as_posix()}" if prefix else rel.as_posix()
    return str(path)


def resolve_path(stored: str | Path) -> Path:
    """The inverse of :func:`portable_path` on this machine."""
    s = str(stored)
    prefix = f"${DATA_ENV}/"
    if s.startswith(prefix):
        return data_root() / s[len(prefix) :]
    return Path(s)
