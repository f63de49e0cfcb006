"""Where the data lives: the ``SLIPSENSE_DATA`` environment variable, else a ``shared/data`` folder found
beside the checkout or the working directory (:func:`data_candidates`)."""

from __future__ import annotations

import os
from pathlib import Path

#: Environment variable naming the data folder (the one holding ``gelsight-slip/``).
DATA_ENV = "SLIPSENSE_DATA"


def data_candidates() -> list[Path]:
    """Where the data folder is looked for, in order: ``$SLIPSENSE_DATA`` alone where it is set; else
    ``shared/data`` beside the checkout the package runs from (an editable install or the source
    tree), then ``shared/data`` in the working directory and beside it."""
    env = os.environ.get(DATA_ENV)
    if env:
        return [Path(env).expanduser()]
    checkout = Path(__file__).resolve().parent.parent
    found = [checkout.parent / "shared" / "data"] if (checkout / "pyproject.toml").is_file() else []
    cwd = Path.cwd()
    return [*found, cwd / "shared" / "data", cwd.parent / "shared" / "data"]


def data_root() -> Path:
    """The data folder: the first of :func:`data_candidates` that exists (the first of them where none
    does, so that a message can name it)."""
    candidates = data_candidates()
    return next((c.resolve() for c in candidates if c.is_dir()), candidates[0].resolve())


def missing_data_hint(path: str | Path) -> str:
    """For a missing ``path``: how to point at the data where ``path`` lies in a data folder that does
    not exist (the default one found nowhere); else nothing."""
    root = data_root()
    if root.is_dir() or not Path(path).resolve().is_relative_to(root):
        return ""
    looked = ", ".join(str(c) for c in data_candidates())
    return f"; no data folder was found (looked in: {looked}): set {DATA_ENV} to the folder holding gelsight-slip/"


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
