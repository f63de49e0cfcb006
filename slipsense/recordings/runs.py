"""Whole grasps: every frame of both sensors of a run, small and grey, with its moment of slip.

Per-grasp training and evaluation replay runs from the first frame, the way a gripper sees them,
so they need whole recordings rather than clips. A 450-frame run of two 240 x 320 colour videos
is 207 MB decoded; the models that learn from motion look at grey frames a few times smaller, so
that is what is kept: ``gray`` uint8 ``(S, N, h, w)`` per run (S sensors, N frames), plus each
camera's contact signal (:func:`slipsense.recordings.contact.contact_signal`, used only to score
"alarms while the gel is at rest", never as model input).

:func:`~slipsense.recordings.video.gray_frames` is the one conversion used both here and by the live detector, so training
and streaming see the same pixels.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Iterable, Mapping, Sequence

import numpy as np

from ..errors import InputError
from ..progress import progress_bar
from .frame_cache import video_products
from .types import Recording, VideoLabel, by_run


@dataclass
class GraspRun:
    """One run (experiment) of one object, every frame, all sensors.

    ``moment_of_slip``: last frame before contact is lost (None: the run held, or no moment found
    and ``slipped`` is True). ``gray``: uint8 ``(S, N, h, w)``; ``contact``: float32 ``(S, N)``
    contact strength per camera (8-bit intensity units above the gel at rest).
    """

    object: str
    experiment: int
    slipped: bool
    moment_of_slip: int | None
    gray: np.ndarray
    contact: np.ndarray
    cameras: tuple[str, ...]
    whole: bool = False  # labelled as a whole (slipped or held, no moment): trained on as one bag of frames
    extra: bool = False  # another data set's grasp (``data.also``): trained on, never held out, judged or calibrated on

    @property
    def n_frames(self) -> int:
        return int(self.gray.shape[1])

    @property
    def key(self) -> tuple[str, int]:
        return (self.object, self.experiment)

    @property
    def usable(self) -> bool:
        """A run scored per grasp: it held, slipped at a known moment, or is labelled as a whole."""
        return not self.slipped or self.moment_of_slip is not None or self.whole


def load_runs(
    recordings: Iterable[Recording],
    labels: Mapping[tuple, VideoLabel],
    size: tuple[int, int],
    sensors: int = 2,
    progress: bool = True,
) -> list[GraspRun]:
    """Every run of ``recordings`` as a :class:`GraspRun` (decoded once, then cached, checksummed).

    Args:
        recordings: from :func:`~slipsense.recordings.folders.find_recordings`.
        labels: ``{(object, experiment, camera): VideoLabel}`` (with overrides applied); the run's
            moment of slip is its cameras' (they share it). A video labelled ``exclude`` (absent
            from ``labels``) leaves its run out.
        size: ``(h, w)`` of the grey frames kept.
        sensors: cameras a run must have; a run with another number is refused, naming its folder.
    """
    runs, product = [], f"gray:{size[0]}x{size[1]}"
    for (obj, experiment), recs in progress_bar(list(by_run(recordings).items()), progress, "loading runs"):
        if len(recs) != sensors:
            raise InputError(recs[0].path.parent, f"run has {len(recs)} camera video(s), expected {sensors}")
        if any(r.key not in labels for r in recs):
            continue  # excluded by an override
        products = [video_products(r.path, ["contact", product], min_frames=2) for r in recs]
        counts = {r.camera: len(p[product]) for r, p in zip(recs, products)}
        if len(set(counts.values())) != 1:
            raise InputError(recs[0].path.parent, f"the cameras of this run differ in frame count: {counts}")
        gray, contact = np.stack([p[product] for p in products]), np.stack([p["contact"] for p in products])
        labs = [labels[r.key] for r in recs]
        moment = next((l.moment_of_slip for l in labs if l.moment_of_slip is not None), None)
        slipped = any(l.slipped for l in labs)
        cameras, whole = tuple(r.camera for r in recs), any(r.per_grasp for r in recs)
        runs.append(GraspRun(obj, experiment, slipped, moment if slipped else None, gray, contact, cameras, whole))
    return runs


def per_sensor(runs: Sequence[GraspRun]) -> list[GraspRun]:
    """Each camera of each run as a grasp of its own (``gray (1, N, h, w)``): what a detector for one
    finger trains and is judged on. A run's cameras share its label (the grasp is lost for both)."""
    return [
        replace(r, gray=r.gray[s : s + 1], contact=r.contact[s : s + 1], cameras=(cam,))
        for r in runs
        for s, cam in enumerate(r.cameras)
    ]


def runs_summary(runs: Sequence[GraspRun]) -> dict[str, int]:
    """Counts a report states: runs, slip runs with a moment, slip runs without one, runs that held,
    and another data set's grasps trained on alongside (``also_runs``, counted apart from the rest)."""
    judged = [r for r in runs if not r.extra]
    return {
        "runs": len(judged),
        "slip_with_moment": sum(r.slipped and r.moment_of_slip is not None for r in judged),
        "slip_without_moment": sum(r.slipped and r.moment_of_slip is None for r in judged),
        "held": sum(not r.slipped for r in judged),
        **({"also_runs": len(runs) - len(judged)} if len(judged) < len(runs) else {}),
    }
