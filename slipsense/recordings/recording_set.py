"""One set of recordings, read once: the object every command builds from a folder and passes down.

``Recordings.open(folder)`` lists the folder tree once (:class:`~slipsense.recordings.listing.FolderTree`)
and keeps what it found: the layout (videos or frame folders), the sensor the data states
(``sensor.json``, or the ``gelsight-lift`` layout), its frame rate, every camera's recording. Judging,
labelling, training, calibrating and adapting take the object, so nothing below the command lists or
probes what it already read: a fold is :meth:`Recordings.without` some objects, a detector of another
sensor reads the same listing with its own file layout (:meth:`Recordings.read_with`), a worker process
receives the object pickled (names, never frames).

:class:`Labelled` is what judging and training take: the recordings that passed a probe, the
complete runs, each run's label and, through its set, one resolved sensor and each run's rate, made
once by :meth:`Recordings.labelled`. Judging, grasp and clip data, marker sequences, ``label`` and
``adapt`` take it as it is: nothing below them checks, labels or filters again.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Hashable, Iterable, Iterator, Mapping, Sequence, TypeVar

from ..errors import InputError
from ..sensors.spec import SensorSpec, check_fps, fps_problem
from .folders import (
    OnError,
    SkippedInputWarning,
    check_on_error,
    find_recordings,
    reads_alike,
    report,
    state_sensor,
    stated_sensor,
    validate_recordings,
)
from .frame_folders import is_frame_layout
from .frames import check_size
from .labels import label_runs, overrides_key
from .listing import FolderTree
from .types import Recording, by_run
from .video import probe_video

T = TypeVar("T")

#: How to give a folder of frames its rate (frames carry no time of their own).
STATE_FPS = 'state it in a sensor.json ({"fps": 25}) in the recordings folder, or name its sensor with --sensor NAME'


@dataclass(frozen=True)
class Recordings:
    """A recordings folder as one scan found it.

    Attributes:
        root: the folder.
        listed: every camera's :class:`~slipsense.recordings.types.Recording`, sorted by key (listed,
            not decoded; :meth:`checked` probes them).
        frames: grasps stored as folders of frames (else camera videos).
        stated: the sensor the data states (its ``sensor.json`` or a registered layout:
            :func:`~slipsense.recordings.folders.stated_sensor`), or the one its user stated; None where
            neither did (a detector's own sensor then applies).
        sensor: the one sensor the set is read as: the one asked for (a detector's), else the stated one.
        on_error: ``"raise"`` or ``"skip"`` for what a scan, probe or read finds wrong.
        named: the stated sensor is its user's (``--sensor``), not the data's own statement.
    """

    root: Path
    listed: tuple[Recording, ...]
    frames: bool
    stated: SensorSpec | None
    sensor: SensorSpec
    on_error: str = "raise"
    named: bool = False
    tree: FolderTree = field(default_factory=FolderTree, repr=False, compare=False)
    _probed: dict = field(default_factory=dict, repr=False, compare=False)
    _kept: dict = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def open(
        cls,
        root: str | Path,
        sensor: SensorSpec | None = None,
        on_error: OnError = "raise",
        *,
        stated: SensorSpec | None = None,
    ) -> "Recordings":
        """Scan ``root`` once (:func:`~slipsense.recordings.folders.find_recordings`: InputError for a
        missing folder or one without usable recordings; ``on_error`` for problems inside it), read as
        ``sensor`` (a detector's; its file layout) or, without one, as the sensor the data states
        (``sensor.json``, a registered layout) or ``stated`` (the user's ``--sensor``, which wins over
        the data's). No sensor is ever assumed: where none is found, an InputError says how to state one."""
        check_on_error(on_error)
        root, tree = Path(root), FolderTree()
        named, stated = stated is not None, stated or stated_sensor(root, tree)
        listed = find_recordings(root, on_error=on_error, sensor=sensor or stated, tree=tree)
        if (sensor or stated) is None:
            raise InputError(root, state_sensor())
        frames = is_frame_layout(root, tree)
        return cls(root, tuple(listed), frames, stated, sensor or stated, on_error, named, tree)

    @classmethod
    def of(
        cls,
        recordings: "str | Path | Recordings | Labelled",
        sensor: SensorSpec | None = None,
        on_error: OnError = "raise",
        *,
        stated: SensorSpec | None = None,
    ):
        """``recordings`` as a set read as ``sensor`` (None: the data's own): the given set itself where it
        is one (re-read from its listing where the layout differs; a labelled set's recordings), else a
        fresh :meth:`open` of the folder. ``stated``: the sensor its user states (:meth:`open`)."""
        if isinstance(recordings, Labelled):
            recordings = recordings.recordings
        if isinstance(recordings, Recordings):
            given = recordings if stated is None else replace(recordings, stated=stated, named=True)
            return given.read_with(sensor or given.sensor)
        return cls.open(recordings, sensor, on_error, stated=stated)

    def read_with(self, sensor: SensorSpec) -> "Recordings":
        """The set as ``sensor``'s file layout lists it: this one where both layouts read alike (frame
        folders always do), else listed again from the folders listed already (nothing opened twice)."""
        if reads_alike(self.root, sensor, self.sensor, self.tree):
            return self if sensor == self.sensor else replace(self, sensor=sensor)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the first listing said them
            listed = find_recordings(self.root, on_error=self.on_error, sensor=sensor, tree=self.tree)
        return replace(self, listed=tuple(listed), sensor=sensor, _probed={})

    # ---- what is in it
    @property
    def objects(self) -> list[str]:
        return sorted({r.object for r in self.listed})

    def __iter__(self) -> Iterator[Recording]:
        return iter(self.listed)

    def __len__(self) -> int:
        return len(self.listed)

    def runs(self) -> dict[tuple[str, int], list[Recording]]:
        """The recordings grouped by run ``(object, experiment)`` (:func:`~slipsense.recordings.types.by_run`)."""
        return by_run(self.listed)

    def subset(self, objects: Iterable[str]) -> "Recordings":
        """Only the recordings of ``objects`` (nothing listed again)."""
        keep = set(objects)
        return replace(self, listed=tuple(r for r in self.listed if r.object in keep))

    def without(self, objects: Iterable[str]) -> "Recordings":
        """Every recording but those of ``objects``: a fold's training set (nothing listed again)."""
        drop = set(objects)
        return replace(self, listed=tuple(r for r in self.listed if r.object not in drop))

    def only(self, recordings: Sequence[Recording]) -> "Recordings":
        """The set holding just ``recordings`` (some of its own), in its order."""
        keep = {r.key for r in recordings}
        return replace(self, listed=tuple(r for r in self.listed if r.key in keep))

    # ---- checks and facts read once
    def kept(self, what: Hashable, make: Callable[[], T]) -> T:
        """``make()``, made once for this listing and kept with the set (and the folds and copies made
        from it in this process; a pickled copy leaves it behind): what commands read of the set again
        and again is read once (``adapt`` trains 26 detectors on the same labelled grasps). ``what``
        names it; the recordings listed and their sensor are part of the name."""
        key = (what, repr(self.sensor), tuple(str(r.path) for r in self.listed))
        if key not in self._kept:
            self._kept[key] = make()
        return self._kept[key]

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_kept": {}}

    def checked(self, on_error: str | None = None, expected_size: tuple[int, int] | None = None) -> list[Recording]:
        """The recordings whose videos (or frame folders) pass a probe
        (:func:`~slipsense.recordings.folders.validate_recordings`), each probed once for the set's life:
        a fold or a second judge of the same set reads the verdicts. With ``on_error="raise"`` a recording
        an earlier ``"skip"`` left out is probed again, so that it raises its error rather than go missing."""
        on_error = on_error or self.on_error
        todo = [r for r in self.listed if r.key not in self._probed]
        if on_error == "raise":
            todo += [r for r in self.listed if r.key in self._probed and self._probed[r.key] is None]
        if todo:
            infos: dict = {}
            validate_recordings(todo, on_error=on_error, expected_size=None, probed=infos)
            self._probed.update({r.key: infos.get(r.key) for r in todo})
        good = [r for r in self.listed if self._probed[r.key] is not None]
        return good if expected_size is None else self._sized(good, expected_size, on_error)

    def _sized(self, recs: list[Recording], expected_size: tuple[int, int], on_error: str) -> list[Recording]:
        """``recs`` whose frames are ``expected_size`` ``(h, w)``; the others refused as a probe refuses them."""
        kept = []
        for r in recs:
            info = self._probed[r.key]
            try:
                check_size(r.path, info.height, info.width, expected_size)
            except InputError as exc:
                report(exc.path, exc.problem, on_error)  # raised, or warned and left out
                continue
            kept.append(r)
        return kept

    def complete_runs(self, kept: Sequence[Recording]) -> list[Recording]:
        """``kept`` (some of this set's recordings) without the runs that lost a camera (a video skipped
        with ``on_error="skip"``), each named in a :class:`~slipsense.recordings.folders.SkippedInputWarning`:
        a detector on both fingers cannot judge a grasp from one."""
        have = {r.key for r in kept}
        broken: dict[tuple[str, int], tuple[Path, str]] = {}
        for r in self.listed:
            if r.key not in have:
                broken.setdefault((r.object, r.experiment), (r.path.parent, r.path.name))
        for folder, name in broken.values():
            warnings.warn(
                f"{folder}: run left out, its video {name} was skipped and the detector needs every camera of a run",
                SkippedInputWarning,
                stacklevel=3,
            )
        return [r for r in kept if (r.object, r.experiment) not in broken]

    def labelled(
        self,
        overrides=None,
        *,
        whole_runs: bool = True,
        progress: bool = True,
        on_error: str | None = None,
        expected_size: tuple[int, int] | None = None,
    ) -> Labelled:
        """The set as judging and training take it, made once for its life (:meth:`kept`): the
        recordings that pass a probe (:meth:`checked`), without the runs that lost a camera where
        ``whole_runs``, each run labelled (:func:`~slipsense.recordings.labels.label_runs`;
        ``overrides`` as it takes them), the runs that could not be labelled left out. InputError where
        nothing is left. ``expected_size`` ``(h, w)``: frames of another size are refused (None: any)."""
        on_error = on_error or self.on_error
        what = ("labelled", overrides_key(overrides), whole_runs, on_error, expected_size)
        return self.kept(what, lambda: self._labelled(overrides, whole_runs, progress, on_error, expected_size))

    def _labelled(self, overrides, whole_runs: bool, progress: bool, on_error: str, expected_size) -> Labelled:
        recs = self.checked(on_error, expected_size)
        if whole_runs:  # a run replayed or trained on with all its cameras is left out whole where one was skipped
            recs = self.complete_runs(recs)
        if not recs:
            raise InputError(self.root, "no usable recordings (every one was skipped)")
        labels = label_runs(recs, overrides, on_error=on_error, progress=progress)
        kept = self.only([r for r in recs if r.key in labels])  # runs that could not be labelled are left out
        if not kept.listed:
            raise InputError(self.root, "no usable recordings (no run could be labelled)")
        return Labelled(kept, dict(labels))

    def rate(self, recording: Recording) -> tuple[float, str]:
        """The rate a recording was taken at and where it was read: a frame folder's from the data's
        ``sensor.json`` or layout (or its user's ``--sensor``), a video's from its container (read by
        the probe). InputError where none can be known, saying to state it in a sensor.json."""
        if not self.frames:
            info = self._probed.get(recording.key) or probe_video(recording.path, expected_size=None, min_frames=1)
            problem = fps_problem(info.fps)
            if problem is not None:
                raise InputError(recording.path, f"the video states no usable frame rate ({problem}): {STATE_FPS}")
            return float(info.fps), "the video's stated rate"
        if self.stated is None:  # a detector's rate is its training's, not the data's
            raise InputError(recording.path, f"a folder of frames states no frame rate: {STATE_FPS}")
        where = self.root / "sensor.json"
        fps = check_fps(self.stated.fps, str(where))
        if self.named:
            return fps, f"the {self.stated.name} sensor (--sensor)"
        return fps, str(where) if self.tree.is_file(where) else f"the {self.stated.name} layout"


@dataclass(frozen=True)
class Labelled:
    """Labelled runs of one set.

    Attributes:
        recordings: the :class:`~slipsense.recordings.recording_set.Recordings` holding just the
            labelled recordings (each camera's video or frame folder), sorted by key.
        labels: ``{Recording.key: VideoLabel}`` of every one of them.
    """

    recordings: Recordings
    labels: Mapping[tuple, object]

    @property
    def root(self) -> Path:
        return self.recordings.root

    @property
    def sensor(self) -> SensorSpec:
        """The one sensor the set is read as (:attr:`Recordings.sensor`)."""
        return self.recordings.sensor

    @property
    def objects(self) -> list[str]:
        return self.recordings.objects

    def __iter__(self) -> Iterator[Recording]:
        return iter(self.recordings.listed)

    def __len__(self) -> int:
        return len(self.recordings.listed)

    def runs(self) -> dict[tuple[str, int], list[Recording]]:
        """The recordings grouped by run ``(object, experiment)``."""
        return by_run(self.recordings.listed)

    def rate(self, recording: Recording) -> tuple[float, str]:
        """The rate ``recording`` was taken at and where it was read (:meth:`Recordings.rate`)."""
        return self.recordings.rate(recording)

    def only(self, objects: Iterable[str]) -> "Labelled":
        """The runs of ``objects`` alone (nothing listed or labelled again)."""
        return self._keeping(self.recordings.subset(objects))

    def without(self, objects: Iterable[str]) -> "Labelled":
        """Every run but those of ``objects``: a fold's training set (nothing listed or labelled again)."""
        return self._keeping(self.recordings.without(objects))

    def _keeping(self, recordings: Recordings) -> "Labelled":
        keys = {r.key for r in recordings.listed}
        return Labelled(recordings, {k: v for k, v in self.labels.items() if k in keys})


def labelled_set(
    recordings: "str | Path | Recordings | Labelled",
    overrides=None,
    sensor: SensorSpec | None = None,
    on_error: OnError = "raise",
    *,
    whole_runs: bool = True,
    progress: bool = True,
    stated: SensorSpec | None = None,
) -> Labelled:
    """``recordings`` as a labelled set: a :class:`~slipsense.recordings.recording_set.Labelled` as it is;
    a set or its folder read as ``sensor`` (:meth:`Recordings.of`) and labelled once
    (:meth:`Recordings.labelled`). Where a command turns what its user named into the set it judges or
    trains on. ``stated``: the sensor its user states (:meth:`Recordings.open`)."""
    if isinstance(recordings, Labelled):
        return recordings
    read = Recordings.of(recordings, sensor, on_error, stated=stated)
    return read.labelled(overrides, whole_runs=whole_runs, progress=progress, on_error=on_error)
