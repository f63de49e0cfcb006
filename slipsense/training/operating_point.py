"""The alarm operating point of a clip model: its training runs replayed per grasp.

A grasp model chooses its threshold and debounce on inner folds of its training objects
(:mod:`slipsense.training.grasp_detector`). A clip model (ViViT, 3D ResNet) costs too much to train
several times, so after training its last checkpoint is replayed over every run of its training
objects (both fingers, as :func:`slipsense.evaluate` replays), and the (threshold, debounce) that
best separates their slips from their held grasps is stored in the checkpoint
(:func:`slipsense.evaluation.pergrasp.choose_operating_point`). Chosen on runs the model trained on,
it is optimistic, and says so (``chosen_on``); it never sees a held-out object.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence


def choose_on_training_runs(
    checkpoint: str | Path,
    recordings: str | Path,
    objects: Sequence[str],
    overrides=None,
    progress: bool = True,
) -> dict[str, Any]:
    """Replay the runs of ``objects`` under ``recordings`` through ``checkpoint``; the operating point
    chosen on them (``{"threshold", "debounce", "horizon", "startup", ..., "chosen_on"}``)."""
    import warnings

    from slipsense.data import label_runs
    from slipsense.errors import ConfigError
    from slipsense.evaluation import pergrasp
    from slipsense.evaluation.early_warning import replay_recordings
    from slipsense.recordings.folders import camera_counts, find_recordings, validate_recordings
    from slipsense.sensors.spec import sensor_of
    from slipsense.checkpoint import read_info
    from slipsense.streaming.detector import SlipDetector

    sensor = sensor_of(read_info(checkpoint), checkpoint)
    found = find_recordings(recordings, on_error="skip", sensor=sensor)
    recs = [r for r in validate_recordings(found, on_error="skip", expected_size=None) if r.object in set(objects)]
    counts = camera_counts(recs)
    if not counts:
        raise ConfigError(f"no recordings of the training objects under {recordings}")
    if len(counts) != 1:
        raise ConfigError(f"runs under {recordings} hold different numbers of cameras ({counts})")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the checkpoint has no threshold yet: that is what is chosen
        det = SlipDetector.from_checkpoint(checkpoint, sensors=counts[0], threshold=0.5, debounce=1, backend="torch")
    labels = label_runs(recs, overrides, on_error="skip", progress=progress)
    runs = replay_recordings(det, [r for r in recs if r.key in labels], labels, progress=progress)
    if not any(r.moment_of_slip is not None for r in runs):
        raise ConfigError("the training runs hold no slip with a known moment: no operating point can be chosen")
    op = pergrasp.choose_operating_point([r.probability for r in runs], [r.moment_of_slip for r in runs])
    op["chosen_on"] = f"the {len(runs)} training runs themselves, replayed per grasp (optimistic)"
    return op
