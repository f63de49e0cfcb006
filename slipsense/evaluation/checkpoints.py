"""``slipsense evaluate``: a checkpoint judged the way its task is judged, the checkpoint opened once.

A grasp detector is replayed per grasp (:func:`slipsense.evaluation.judge.judge`: every run of the
recordings folder from its first frame, at the checkpoint's operating point) and every registered
measure (:mod:`slipsense.measures`) goes into the result; a clip or marker model is judged per clip on
the data its reader takes (:func:`slipsense.evaluation.predict.evaluate_clip_checkpoint`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

from slipsense.atomic import write_text
from slipsense.checkpoint import load_model
from slipsense.paths import portable_path
from slipsense.errors import ConfigError, InputError
from slipsense.evaluation.judge import judge
from slipsense.evaluation.predict import evaluate_clip_checkpoint


def evaluate_checkpoint(
    checkpoint: str | Path | None = None,
    recordings: str | Path | None = None,
    *,
    json_out: str | Path | None = None,
    echo: Callable[[str], Any] = lambda line: None,
    **options: Any,
) -> dict[str, Any]:
    """Judge ``checkpoint`` (default: the shipped detector for ``recordings``, named through ``echo``)
    and write every figure to ``json_out``. ``options``: those of
    :func:`~slipsense.evaluation.predict.evaluate_clip_checkpoint` (``split``, ``markers``, ``png``,
    ``noise_std``, ``on_error``, ``overrides``, ``progress``, ``dtype``, ``per_grasp``)."""
    if checkpoint is None:
        return _grasps(None, None, recordings, json_out=json_out, echo=echo, **options)
    loaded = load_model(checkpoint)  # a damaged checkpoint is refused before any data is read
    return JUDGES[loaded[0].training_task](checkpoint, loaded, recordings, json_out=json_out, **options)


def _grasps(
    checkpoint,
    loaded,
    recordings,
    *,
    json_out=None,
    echo: Callable[[str], Any] = lambda line: None,
    split=None,
    markers=None,
    on_error: str = "raise",
    overrides=None,
    progress: bool = True,
    dtype: str = "float32",
    png=None,
    noise_std: float = 0.0,
    per_grasp: bool = True,
    sensor=None,
) -> dict[str, Any]:
    """A grasp detector per grasp (``sensor``: the recordings' where they state none); the JSON holds every measure and each run's outcome (``png``,
    ``noise_std`` and ``per_grasp`` are for clip models and not used)."""
    if split is not None or markers is not None:
        raise InputError(
            split or markers,
            f"{checkpoint or 'the shipped detector'} holds a grasp detector (whole runs of both sensors): evaluate it "
            "on a recordings folder (--recordings; default: the shared recordings)",
        )
    if dtype != "float32":
        raise ConfigError(f"a grasp detector is evaluated in float32 (--dtype {dtype} is for clip and marker models)")

    ev = judge(
        checkpoint, recordings, overrides=overrides, progress=progress, on_error=on_error, loaded=loaded, sensor=sensor
    )
    if checkpoint is None:
        checkpoint = ev.checkpoint
        echo(f"evaluating the shipped detector {Path(checkpoint).stem}")
    doc = {
        "checkpoint": portable_path(checkpoint),
        "recordings": None if recordings is None else portable_path(recordings),
        **ev.to_dict(),
    }
    if json_out is not None:
        write_text(json_out, json.dumps(doc, indent=1, default=float))
    return doc


#: ``training_task`` (a model class attribute) -> how its checkpoint is judged
JUDGES: dict[str, Callable[..., dict[str, Any]]] = {"clips": evaluate_clip_checkpoint, "grasps": _grasps}

__all__ = ["evaluate_checkpoint"]
