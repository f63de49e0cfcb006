"""One set of recordings, read once: the object every command builds from a folder and passes down.

``Recordings.open(folder)`` lists the folder tree once (:class:`~slipsense.recordings.listing.FolderTree`)
and keeps what it found: the layout (videos or frame folders), the sensor the data states
(``sensor.json``, or the ``gelsight-lift`` layout), its frame rate, every camera's recording. Judging,
labelling, training, calibrating and adapting take the object, so nothing below the command lists or
probes what it already read: a fold is :meth:`Recordings.without` some objects, a detector of another
sensor reads the same listing with its own file layout (:meth:`Recordings.read_with`), a worker process
receives the object pickled (names, never frames).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Hashable, Iterable, Iterator, Sequence, TypeVar

from ..errors import InputError
from ..sensors.spec import GELSIGHT_MINI, SensorSpec, check_fps, fps_problem
from .folders import OnError, SkippedInputWarning, check_on_error, find_recordings, reads_alike, validate_recordings
from .frame_folders import data_sensor, is_frame_layout
from .listing import FolderTree
from .types import Recording, by_run
from .video import probe_video

T = TypeVar("T")

#: How to give a folder of frames its rate (frames carry no time of their own).
STATE_FPS = 'state it in a sensor.json ({"fps": 25}) in the recordings folder'


@dataclass(frozen=True)
class Recordings:
    """A recordings folder as one scan found it.

    Attributes:
        root: the folder.
        listed: every camera's :class:`~slipsense.recordings.types.Recording`, sorted by key (listed,
            not decoded; :meth:`checked` probes them).
        frames: grasps stored as folders of frames (else camera videos).
        stated: the sensor the data states (its ``sensor.json`` or layout); None for videos, whose
            detector's own sensor applies.
        layout: the sensor whose file layout the videos were listed with (GelSight Mini by default).
        on_error: ``"raise"`` or ``"skip"`` for what a scan, probe or read finds wrong.
    """

    root: Path
    listed: tuple[Recording, ...]
    frames: bool
    stated: SensorSpec | None
    layout: SensorSpec
    on_error: str = "raise"
    tree: FolderTree = field(default_factory=FolderTree, repr=False, compare=False)
    _probed: dict = field(default_factory=dict, repr=False, compare=False)
    _kept: dict = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def open(
        cls, root: str | Path, sensor: SensorSpec | None = GELSIGHT_MINI, on_error: OnError = "raise"
    ) -> "Recordings":
        """Scan ``root`` once (:func:`~slipsense.recordings.folders.find_recordings`: InputError for a
        missing folder or one without usable recordings; ``on_error`` for problems inside it) with
        ``sensor``'s file layout (None: the sensor the data states, else the GelSight Mini's)."""
        check_on_error(on_error)
        root, tree = Path(root), FolderTree()
        stated = data_sensor(root, tree)
        sensor = sensor or stated or GELSIGHT_MINI
        listed = find_recordings(root, on_error=on_error, sensor=sensor, tree=tree)
        return cls(root, tuple(listed), is_frame_layout(root, tree), stated, sensor, on_error, tree)

    @classmethod
    def of(
        cls,
        recordings: "str | Path | Recordings",
        sensor: SensorSpec | None = GELSIGHT_MINI,
        on_error: OnError = "raise",
    ):
        """``recordings`` as a set read with ``sensor``'s file layout (None: the data's own, else the
        GelSight Mini's): the given set itself where it is one (re-read from its listing where the
        layout differs), else a fresh :meth:`open` of the folder."""
        if isinstance(recordings, Recordings):
            return recordings.read_with(sensor or recordings.stated or GELSIGHT_MINI)
        return cls.open(recordings, sensor, on_error)

    def read_with(self, sensor: SensorSpec) -> "Recordings":
        """The set as ``sensor``'s file layout lists it: this one where both layouts read alike (frame
        folders always do), else listed again from the folders listed already (nothing opened twice)."""
        if reads_alike(self.root, sensor, self.layout, self.tree):
            return self if sensor == self.layout else replace(self, layout=sensor)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the first listing said them
            listed = find_recordings(self.root, on_error=self.on_error, sensor=sensor, tree=self.tree)
        return replace(self, listed=tuple(listed), layout=sensor, _probed={})

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
        names it; the recordings listed and their layout are part of the name."""
        key = (what, repr(self.layout), tuple(str(r.path) for r in self.listed))
        if key not in self._kept:
            self._kept[key] = make()
        return self._kept[key]

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_kept": {}}

    def checked(self, on_error: str | None = None) -> list[Recording]:
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
        return [r for r in self.listed if self._probed[r.key] is not None]

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

    def rate(self, recording: Recording) -> tuple[float, str]:
        """The rate a recording was taken at and where it was read: a frame folder's from the data's
        ``sensor.json`` or layout, a video's from its container (read by the probe). InputError where
        none can be known, saying to state it in a sensor.json."""
        if not self.frames:
            info = self._probed.get(recording.key) or probe_video(recording.path, expected_size=None, min_frames=1)
            problem = fps_problem(info.fps)
            if problem is not None:
                raise InputError(recording.path, f"the video states no usable frame rate ({problem}): {STATE_FPS}")
            return float(info.fps), "the video's stated rate"
        if self.stated is None:
            raise InputError(recording.path, f"a folder of frames states no frame rate: {STATE_FPS}")
        where = self.root / "sensor.json"
        stated = self.tree.is_file(where)
        return check_fps(self.stated.fps, str(where)), str(where) if stated else f"the {self.stated.name} layout"
