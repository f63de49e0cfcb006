"""Plain records shared by the recordings pipeline: what a video is, and what we know about it."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable


@dataclass(frozen=True)
class Recording:
    """One sensor video of one experiment: ``<root>/<object>/exp_num_<experiment>/<camera>.avi``,
    or a folder of its frames (:mod:`slipsense.recordings.frame_folders`).

    ``per_grasp``: the data labels the grasp as a whole (slipped or held, no moment of slip to find).
    """

    object: str
    experiment: int
    camera: str  # file stem, e.g. "camera_0" (a camera's folder of frames: its name)
    path: Path
    slipped: bool  # slip.txt present in the experiment folder
    per_grasp: bool = False

    @property
    def key(self) -> tuple[str, int, str]:
        return (self.object, self.experiment, self.camera)


@dataclass(frozen=True)
class VideoLabel:
    """What the labeller found in one video (frame indices into the decoded video, 0-based).

    ``moment_of_slip``: the last frame before the object loses contact with either sensor
    (``None`` when the run did not slip). ``contact_start``/``contact_end``: the first and last
    frame of the contact phase (inclusive), used to draw wiggle windows from runs that did not slip.
    """

    object: str
    experiment: int
    camera: str
    n_frames: int
    slipped: bool
    moment_of_slip: int | None
    contact_start: int
    contact_end: int
    source: str = "auto"  # "auto" or "override"

    @property
    def key(self) -> tuple[str, int, str]:
        return (self.object, self.experiment, self.camera)


def by_run(recordings: Iterable[Recording]) -> dict[tuple[str, int], list[Recording]]:
    """The recordings grouped by run, ``(object, experiment)``: runs in key order, cameras by name."""
    runs: dict[tuple[str, int], list[Recording]] = {}
    for r in recordings:
        runs.setdefault((r.object, r.experiment), []).append(r)
    return {key: sorted(runs[key], key=lambda r: r.camera) for key in sorted(runs)}
