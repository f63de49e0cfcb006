"""Where the experiments' data come from: :class:`DataSource` and the held-out objects.

Video experiments use the GelSight recordings, labelled and cut as ``slipsense train`` does
(:func:`slipsense.recordings.labels.label_runs`, cached clips), with the shipped hand-label overrides
(:func:`default_overrides`) when present. Held-out objects are fixed for every condition of an
experiment: fold ``fold`` of ``folds`` object folds (:class:`slipsense.recordings.splits.ObjectFolds`,
seeded by ``data_seed``) of the objects that give clips at 5 frames, horizon 0 — the same objects
``slipsense train --fold 0`` holds out (with its default ``--seed 0``, which seeds its folds).
``data_seed`` also seeds the wiggle windows and the random clip split; ``seed`` seeds model
initialisation, batch order and augmentation. Models are scored at their last epoch (nothing is
selected on held-out data).

Data come from a :class:`DataSource`; tests hand in an in-memory one (any object with ``objects``,
``clips``, ``markers`` and optionally ``describe`` and ``replay``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from slipsense.errors import ConfigError, InputError
from studies.experiments.settings import Settings


def default_overrides() -> Path | None:
    """The shipped hand-label overrides (:func:`slipsense.resources.shipped_overrides`, package data;
    ``configs/gelsight-label-overrides.csv`` of the checkout links to it), None when it is missing."""
    from slipsense.resources import shipped_overrides

    path = shipped_overrides()
    return path if path.is_file() else None


# =============================================================================== data


class DataSource:
    """GelSight recordings -> clips, objects and real marker sequences (the experiments' only data door).

    Args:
        recordings: the recordings folder (default ``$SLIPSENSE_DATA/gelsight-slip``).
        overrides: hand-label CSV; ``"default"`` = the shipped one when present, None = none.
        on_error: ``raise`` or ``skip`` bad videos and runs that cannot be labelled (as ``slipsense train``).
    """

    def __init__(
        self,
        recordings: str | Path | None = None,
        overrides: str | Path | None = "default",
        on_error: str = "raise",
        progress: bool = True,
    ):
        from slipsense.paths import gelsight_recordings

        self.root = Path(recordings) if recordings is not None else gelsight_recordings()
        self.overrides = default_overrides() if overrides == "default" else (Path(overrides) if overrides else None)
        self.on_error = on_error
        self.progress = progress
        self._labelled = None
        self._set = None

    def describe(self) -> dict[str, Any]:
        from slipsense.paths import portable_path

        return {
            "recordings": portable_path(self.root),
            "overrides": portable_path(self.overrides) if self.overrides else None,
            "on_error": self.on_error,
        }

    def recordings_set(self):
        """The recordings folder as one :class:`~slipsense.recordings.recording_set.Recordings` (listed once)."""
        if self._set is None:
            from slipsense.recordings.recording_set import Recordings

            self._set = Recordings.open(self.root, on_error=self.on_error)
        return self._set

    def labelled(self):
        """The recordings as one labelled set (:meth:`Recordings.labelled`: probed, labelled as
        ``slipsense train`` labels them, with the label cache and the hand labels; with
        ``on_error="skip"`` a run that cannot be labelled is left out with a warning), made once."""
        if self._labelled is None:
            self._labelled = self.recordings_set().labelled(
                self.label_overrides(), whole_runs=False, progress=self.progress
            )
        return self._labelled

    @property
    def fps(self) -> float:
        """The frame rate of the sensor the recordings state (what a clip's frames last)."""
        return self.labelled().sensor.fps

    def recordings(self):
        """The labelled recordings (listed, probed and labelled once)."""
        return list(self.labelled())

    def label_overrides(self):
        """The hand labels, as :func:`slipsense.recordings.labels.label_runs` takes them. A user's file is passed as
        its path (read against the recordings: it must fit them exactly, errors name its line); the
        shipped file is None, which label_runs turns into its rows for the runs of the shared
        recordings (:func:`slipsense.recordings.labels.shipped_overrides_for`)."""
        if self.overrides is None:
            return False  # --no-overrides: automatic labels only, not even the shipped ones
        return None if self.overrides == default_overrides() else self.overrides

    def labels(self):
        """``{key: VideoLabel}`` of the recordings (:meth:`labelled`)."""
        return dict(self.labelled().labels)

    def clips(self, spec):
        """Labelled clips (ClipSet) cut with ``spec`` (cached on disk, as ``slipsense train`` caches them)."""
        from slipsense.recordings.clips import load_or_build_clips

        data = self.labelled()
        clips = load_or_build_clips(list(data), data.labels, spec, progress=self.progress)
        if len(clips) == 0:
            raise InputError(self.root, "no clips could be made (no slip moments and no contact phases found)")
        return clips

    def objects(self, spec) -> list[str]:
        """Objects that give at least one clip with ``spec`` (from the labels; no decoding)."""
        from slipsense.recordings.clips import plan_windows

        return sorted({lab.object for lab in self.labels().values() if plan_windows(lab, spec)})

    def markers(
        self,
        frames: int,
        n_markers: str | int,
        horizon: int = 0,
        wiggle_per_video: int = 2,
        seed: int = 0,
    ) -> dict[str, np.ndarray]:
        """Real marker windows (:func:`slipsense.marker_sequences.real_marker_dataset`; ``n_markers`` a
        layout: N markers nearest the image centre, or ``"ROWSxCOLS"``, every marker on that grid),
        labelled as :meth:`labels` labels them (the same hand labels)."""
        from slipsense.marker_sequences import real_marker_dataset

        arrays = real_marker_dataset(
            self.labelled(),
            frames=frames,
            n_markers=n_markers,
            horizon=horizon,
            wiggle_per_video=wiggle_per_video,
            seed=seed,
            on_error=self.on_error,
            progress=self.progress,
            overrides=self.label_overrides(),
        )
        return arrays

    def replay(self, detector, objects: Sequence[str]):
        """Every labelled run of ``objects`` replayed through ``detector`` as it runs live, all
        cameras from the first frame (:func:`slipsense.evaluation.replay.replay_recordings`):
        one :class:`~slipsense.evaluation.replay.RunTrace` per run (slips without a moment left out)."""
        from slipsense.evaluation.replay import replay_recordings

        data = self.labelled().only(objects)
        return replay_recordings(detector, data.recordings, data.labels, progress=self.progress)


def clip_spec(settings: Settings, frames: int = 5, horizon: int = 0, size: tuple[int, int] | None = None):
    from slipsense.recordings.clips import ClipSpec

    return ClipSpec(
        frames=frames,
        horizon=horizon,
        wiggle_per_video=settings.wiggle_per_video,
        size=size or settings.video_size,
        seed=settings.data_seed,
    )


def held_out_objects(source, settings: Settings) -> list[str]:
    """The fixed held-out objects: ``settings.test_objects``, else fold ``fold`` of the objects that
    give clips at 5 frames / horizon 0 (what ``slipsense train --fold`` holds out)."""
    from slipsense.recordings.splits import ObjectFolds

    objects = source.objects(clip_spec(settings))
    if settings.test_objects:
        unknown = sorted(set(settings.test_objects) - set(objects))
        if unknown:
            raise ConfigError(f"--test-objects without clips: {', '.join(unknown)}")
        return sorted(settings.test_objects)
    if len(objects) < settings.folds:
        raise ConfigError(f"{len(objects)} objects cannot make {settings.folds} folds; lower --folds")
    return ObjectFolds(settings.folds, settings.data_seed).test_objects(objects)[settings.fold]


def object_split(clips, test_objects: Sequence[str]) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Indices of the training and held-out clips; the held-out objects present in ``clips``."""
    from slipsense.recordings.clips import split_by_object

    present = sorted(set(test_objects) & set(clips.objects))
    if not present:
        raise ConfigError(f"none of the held-out objects {list(test_objects)} has clips here")
    tr, te = split_by_object(clips, present)
    if len(tr) == 0:
        raise ConfigError("no training clips left after holding objects out")
    return tr, te, present
