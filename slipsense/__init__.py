"""slipsense: slip detection and prediction from vision-based tactile sensors.

    >>> import slipsense
    >>> detector = slipsense.SlipDetector.pretrained(sensors=2)   # the shipped grasp detector
    >>> reading = detector.push(left_frame, right_frame)          # doctest: +SKIP
    >>> reading.alarm                                             # doctest: +SKIP

The names below are imported on first use, so ``import slipsense`` stays fast (no torch until needed).
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

#: public name -> module that defines it
_EXPORTS = dict.fromkeys(["SlipDetector", "Reading", "Trace"], "slipsense.streaming.detector")
_EXPORTS |= dict.fromkeys(["fit", "evaluate", "TrainedDetector", "Evaluation"], "slipsense.api")
_EXPORTS |= {"read_video": "slipsense.recordings.video", "find_recordings": "slipsense.recordings.folders"}
_EXPORTS |= dict.fromkeys(["build_model", "available_models"], "slipsense.models")
_EXPORTS |= {"shipped_model": "slipsense.resources", "SensorSpec": "slipsense.sensors.spec"}
_EXPORTS["GELSIGHT_MINI"] = "slipsense.sensors.spec"
_ALIASES = {"build_model": "build", "available_models": "available"}


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'slipsense' has no attribute {name!r}")
    value = getattr(importlib.import_module(_EXPORTS[name]), _ALIASES.get(name, name))
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])


__all__ = sorted(_EXPORTS)
