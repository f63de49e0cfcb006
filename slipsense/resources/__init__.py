"""Files shipped inside the package: the trained detectors and the default label overrides.

Found through :mod:`importlib.resources`, so they travel with ``pip install .`` and are found from
any working folder::

    >>> from slipsense.resources import shipped_model, shipped_overrides
    >>> shipped_model().name
    'motionnet-gelsight.safetensors'
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

#: The default detector: motionnet trained on every shared run with a known outcome (see docs/models.md).
DEFAULT_DETECTOR = "motionnet-gelsight"
#: The default for one finger: the same recipe trained on each camera alone (configs/motionnet-1sensor.yaml).
ONE_SENSOR_DETECTOR = "motionnet-gelsight-1"


def _path(*parts: str) -> Path:
    # the package is installed as plain files (setuptools, not a zip), so this is a real path
    return Path(str(files(__name__).joinpath(*parts)))


def shipped_model(name: str = DEFAULT_DETECTOR) -> Path:
    """Path of a shipped checkpoint (:func:`shipped_models`; ``"motionnet-gelsight"`` by default)."""
    return _path("models", f"{name}.safetensors")


def default_model_name(sensors: int | None = None) -> str:
    """The shipped detector for ``sensors`` sensors per push: one finger or both (the default)."""
    return ONE_SENSOR_DETECTOR if sensors == 1 else DEFAULT_DETECTOR


def shipped_models() -> list[str]:
    """Names of the shipped checkpoints."""
    return sorted(p.name[: -len(".safetensors")] for p in _path("models").glob("*.safetensors"))


def shipped_overrides() -> Path:
    """The hand-checked moments of slip of the shared GelSight recordings (an overrides CSV)."""
    return _path("gelsight-label-overrides.csv")


__all__ = [
    "DEFAULT_DETECTOR",
    "ONE_SENSOR_DETECTOR",
    "default_model_name",
    "shipped_model",
    "shipped_models",
    "shipped_overrides",
]
