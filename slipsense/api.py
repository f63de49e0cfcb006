"""The short Python API: fit a detector on recordings, judge it per grasp, run it live.

    >>> import slipsense
    >>> detector = slipsense.SlipDetector.pretrained(sensors=2)      # the shipped detector
    >>> reading = detector.push(frame_a, frame_b)                     # doctest: +SKIP
    >>> trained = slipsense.fit("my-recordings", "runs/mine", held_out=["mug"])   # doctest: +SKIP
    >>> trained.held_out["per_grasp"]["warned"]               # doctest: +SKIP
    >>> report = slipsense.evaluate(trained.checkpoint, "other-recordings")         # doctest: +SKIP
    >>> report.summary()                                              # doctest: +SKIP

Recordings folders follow the GelSight layout ``<object>/exp_num_<N>/camera_*.avi`` (+ ``slip.txt``
in runs that slipped); see :mod:`slipsense.sensors.spec`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from slipsense.evaluation.replay import Evaluation, evaluate, label_overrides, recordings_folder


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
    recordings: str | Path | None = None,
    out: str | Path = "runs/detector",
    *,
    model: str = "motionnet",
    held_out: Sequence[str] = (),
    overrides: str | Path | None | bool = True,
    seed: int = 0,
    progress: bool = True,
    **settings: Any,
) -> TrainedDetector:
    """Train a grasp detector (both sensors, every frame) on a recordings folder.

    Args:
        recordings: the folder (default: the shared GelSight recordings, ``$SLIPSENSE_DATA``).
        out: output folder (``detector.safetensors``, ``metrics.csv``, ``curves.png``).
        model: a registered grasp model (``"motionnet"``, or ``"motion-energy"`` for the baseline).
        held_out: objects kept out of training and scored per grasp at the end.
        overrides: label overrides CSV; True = the shipped hand labels for runs of the shared
            recordings; False = none.
        settings: training or model settings, e.g. ``epochs=5``, ``width=8``
            (:class:`slipsense.training.grasps.GraspTrainConfig`).
    """
    from slipsense.training.grasp_detector import train_detector
    from slipsense.training.grasps import load_grasp_data, make_config

    root = recordings_folder(recordings)
    cfg = make_config(model, {**settings, "seed": seed})
    from slipsense.models import build

    image_size = tuple(cfg.model_config.get("image_size") or build(model).image_size)
    runs, labels = load_grasp_data(root, label_overrides(overrides), image_size, progress=progress)
    result = train_detector(runs, labels, cfg, out, held=list(held_out), progress=progress)
    held = {k: result[k] for k in ("per_grasp", "clips") if k in result} or None
    return TrainedDetector(Path(result["checkpoint"]), result["operating_point"], result["history"], held)


__all__ = ["Evaluation", "TrainedDetector", "evaluate", "fit"]
