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
