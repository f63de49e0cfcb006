"""The alarm operating point of a clip model: its training runs replayed per grasp.

A grasp model chooses its threshold and debounce on inner folds of its training objects
(:mod:`slipsense.training.grasp_detector`). A clip model (ViViT, 3D ResNet) costs too much to train
several times, so after training its last checkpoint is replayed over every run of its training
objects (both fingers, as :func:`slipsense.evaluation.judge.judge` replays), and the (threshold,
debounce) that best separates their slips from their held grasps is stored in the checkpoint
(:func:`slipsense.measures.operating_points.choose_operating_point`). Chosen on runs the model trained on,
it is optimistic, and says so (``chosen_on``); it never sees a held-out object.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any, Sequence

from slipsense.errors import ConfigError
from slipsense.evaluation.judge import judge
from slipsense.measures import operating_points
from slipsense.recordings.recording_set import Recordings


def choose_on_training_runs(
    checkpoint: str | Path,
    recordings: str | Path | Recordings,
    objects: Sequence[str],
    overrides=None,
    progress: bool = True,
) -> dict[str, Any]:
    """Replay the runs of ``objects`` under ``recordings`` through ``checkpoint`` (:func:`judge`); the
    operating point chosen on them (``{"threshold", "debounce", "horizon", "startup", ..., "chosen_on"}``)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # no threshold yet (that is what is chosen); trained on these objects
        ev = judge(
            checkpoint,
            recordings,
            overrides=overrides,
            objects=objects,
            on_error="skip",
            progress=progress,
            threshold=0.5,
            debounce=1,
        )
    runs = [r for r in ev.runs if not (r.slipped and r.moment_of_slip is None)]
    if not any(r.moment_of_slip is not None for r in runs):
        raise ConfigError("the training runs hold no slip with a known moment: no operating point can be chosen")
    rates = sorted({r.fps for r in runs})
    if len(rates) > 1:  # one horizon in frames would stand for different times
        raise ConfigError(f"the training runs were taken at different rates ({rates} frames/s): choose on one rate")
    traces, moments = [r.probability for r in runs], [r.moment_of_slip for r in runs]
    op = operating_points.choose_operating_point(traces, moments, fps=rates[0])
    op["chosen_on"] = f"the {len(runs)} training runs themselves, replayed per grasp (optimistic)"
    return op
