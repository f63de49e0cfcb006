"""The short Python API: fit a detector on recordings, judge it per grasp, run it live.

    >>> import slipsense
    >>> detector = slipsense.SlipDetector.pretrained(sensors=2)      # the shipped detector
    >>> reading = detector.push(frame_a, frame_b)                     # doctest: +SKIP
    >>> trained = slipsense.fit("my-recordings", "runs/mine", held_out=["mug"])   # doctest: +SKIP
    >>> trained.held_out["per_grasp"]["warned"]               # doctest: +SKIP
    >>> report = slipsense.evaluate(trained.checkpoint, "other-recordings")         # doctest: +SKIP
    >>> report.per_grasp()["warned"]                                # doctest: +SKIP

Recordings folders follow the GelSight layout ``<object>/exp_num_<N>/camera_*.avi`` (+ ``slip.txt``
in runs that slipped); see :mod:`slipsense.sensors.spec`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from slipsense.evaluation.judge import Evaluation, judge, recordings_folder
from slipsense.config_tree import DEFAULT_MODEL
from slipsense.recordings.recording_set import Recordings


@dataclass
class TrainedDetector:
    """What :func:`fit` returns.

    Attributes:
        checkpoint: the written ``detector.safetensors`` (weights, full config, operating point).
        operating_point: ``{"threshold", "debounce", ...}`` chosen on the training objects only.
        history: one row of training metrics per epoch.
        held_out: per-grasp outcomes (``"per_grasp"``) and clip metrics (``"clips"``) on the
            ``held_out`` objects, or None when none were held out.
    """

    checkpoint: Path
    operating_point: dict[str, Any]
    history: list[dict[str, Any]] = field(default_factory=list)
    held_out: dict[str, Any] | None = None

    def detector(self, sensors: int | None = None):
        """A live :class:`~slipsense.streaming.detector.SlipDetector` on the trained checkpoint."""
        from slipsense.streaming.detector import SlipDetector

        return SlipDetector.from_checkpoint(self.checkpoint, sensors=sensors)


def fit(
    recordings: str | Path | Recordings | None = None,
    out: str | Path = "runs/detector",
    *,
    model: str = DEFAULT_MODEL,
    held_out: Sequence[str] = (),
    overrides: str | Path | None | bool = None,
    seed: int = 0,
    progress: bool = True,
    **settings: Any,
) -> TrainedDetector:
    """Train a registered model on a recordings folder, as ``slipsense train`` does
    (:func:`slipsense.training.recipe.fit` of the :class:`~slipsense.training.settings.RunConfig` of
    its configuration tree: the same checks, sensor spec, one-finger split and resume).

    Args:
        recordings: the folder (default: the shared GelSight recordings, ``$SLIPSENSE_DATA``), or a
            :class:`~slipsense.recordings.recording_set.Recordings` read already.
        out: output folder (``detector.safetensors`` or ``last.safetensors``, ``metrics.csv``, ``curves.png``).
        model: a registered model: ``"motionnet"`` (the default detector), ``"motion-energy"`` (the
            non-learned baseline), or a clip model (``"vivit"``, ``"resnet3d50"``, ...).
        held_out: objects kept out of training and scored at the end (per grasp for a grasp detector).
        overrides: None (default) = the shipped hand labels for runs of the shared recordings
            (:mod:`~slipsense.recordings.labels`; True says the same); False = none; else a CSV.
        settings: the model's settings (e.g. ``width=8``) and training settings (e.g. ``epochs=5``),
            each by its name (:meth:`~slipsense.training.settings.RunConfig.from_tree` sorts them).
    """
    from slipsense.training.recipe import RunConfig, fit as fit_recipe

    tree = {
        "model": {"name": model, **settings},
        "data": {
            # a set read already travels as it is (nothing listed again), a folder as its path
            "recordings": recordings if isinstance(recordings, Recordings) else str(recordings_folder(recordings)),
            "overrides": None if overrides is True else overrides,  # None: the shipped hand labels
            "test_objects": list(held_out),
        },
        "train": {"seed": seed},
    }
    res = fit_recipe(RunConfig.from_tree(tree), out, progress=progress)
    held = {k: res[k] for k in ("per_grasp", "clips", "measures") if res.get(k) is not None} if held_out else None
    return TrainedDetector(Path(res["checkpoint"]), res.get("operating_point") or {}, res.get("history") or [], held)


#: ``slipsense.evaluate``: the judge (:func:`slipsense.evaluation.judge.judge`) under the name users
#: know; inside the package it is called by its own name.
evaluate = judge

__all__ = ["Evaluation", "TrainedDetector", "evaluate", "fit"]
