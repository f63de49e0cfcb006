"""Find the recordings in a data folder laid out as ``<root>/<object>/exp_num_<N>/camera_*.avi``.

:func:`find_recordings` only looks at the folder structure, so it is instant; decoding problems
surface in :func:`validate_recordings` (a cheap probe of each video) or when the video is read.
Both take ``on_error``: ``"raise"`` stops at the first problem with an
:class:`~slipsense.errors.InputError`; ``"skip"`` emits a :class:`SkippedInputWarning` naming the
file and the problem and carries on without it.
"""

from __future__ import annotations

import re
import warnings
from collections import Counter
from pathlib import Path
from typing import Iterable, Literal, NamedTuple

from ..errors import ConfigError, InputError
from ..paths import missing_data_hint
from ..sensors.spec import SENSORS, STUDY_LAYOUT, SensorSpec
from .bags import bag_cameras
from .frame_folders import data_sensor, find_frame_recordings, is_frame_layout
from .listing import FolderError, FolderTree
from .types import Recording
from .video import probe_video

OnError = Literal["raise", "skip"]

#: Camera videos are named ``camera_<anything>.avi``; the stem becomes ``Recording.camera``.
CAMERA_GLOB = STUDY_LAYOUT["camera_glob"]


def state_sensor(option: str = "--sensor NAME") -> str:
    """What to do where no sensor can be found for a recordings folder, in words for its error;
    ``option``: how the command at hand names a registered sensor."""
    example = '{"name": "my-gelsight", "output": "video", "fps": 25}'
    return f"no sensor is stated for it: put a sensor.json in it ({example}) or name a registered one with {option}"


class Layout(NamedTuple):
    """How a sensor's camera videos are laid out in a recordings folder (:data:`STUDY_LAYOUT`'s keys),
    and the rate a ROS 2 bag's frames are written at (None: a bag cannot be read)."""

    experiment_pattern: str
    camera_glob: str
    slip_marker: str
    fps: float | None


class SkippedInputWarning(UserWarning):
    """A file or folder was left out because of the problem the message names (``on_error="skip"``)."""


class IncompleteRunWarning(UserWarning):
    """An experiment is used with fewer sensor videos than a run normally has (one camera)."""


def check_on_error(on_error: str) -> None:
    """Raise ConfigError unless ``on_error`` is ``"raise"`` or ``"skip"``."""
    if on_error not in ("raise", "skip"):
        raise ConfigError(f"on_error must be 'raise' or 'skip', got {on_error!r}")


def report(path: Path | str | None, problem: str, on_error: str) -> None:
    """Raise InputError(path, problem), or with ``on_error="skip"`` warn that ``path`` is skipped."""
    if on_error == "raise":
        raise InputError(path, problem)
    warnings.warn(f"{path}: {problem}; skipped", SkippedInputWarning, stacklevel=3)


def find_recordings(
    root: str | Path, on_error: OnError = "raise", sensor: SensorSpec | None = None, tree: FolderTree | None = None
) -> list[Recording]:
    """List every camera video under ``root``, sorted by (object, experiment, camera); or, where
    ``root`` holds grasps as folders of frames, every grasp folder
    (:mod:`~slipsense.recordings.frame_folders`, whatever ``sensor`` says).

    Args:
        root: folder holding one sub-folder per object, e.g. ``config.gelsight_recordings()``.
        sensor: whose folder layout to read (its ``experiment_pattern``, ``camera_glob`` and
            ``slip_marker``); None: the sensor the folder states (:func:`stated_sensor`). A sensor
            without a layout of its own is read with :data:`~slipsense.sensors.spec.STUDY_LAYOUT`
            (the names below).
        on_error: ``"raise"`` or ``"skip"`` for problems inside object folders: an experiment
            folder whose name does not match ``exp_num_<N>``, one without ``camera_*.avi``
            videos, an object folder without experiments, two folders naming the same experiment.
        tree: the folders listed already (:class:`~slipsense.recordings.listing.FolderTree`; a
            :class:`~slipsense.recordings.recording_set.Recordings` carries its own): nothing is
            listed twice.

    Returns:
        One :class:`Recording` per video; ``slipped`` is True when the experiment folder holds
        ``slip.txt``. Nothing is decoded here.

    Raises:
        InputError: ``root`` is missing or not a folder, holds no object folders, or (with either
            ``on_error``) nothing usable was found; with ``on_error="raise"`` also any problem above.
        ConfigError: ``on_error`` is neither value.
    """
    check_on_error(on_error)
    root, tree = Path(root), tree or FolderTree()
    if not root.exists():
        raise InputError(root, "recordings folder does not exist" + missing_data_hint(root))
    if not root.is_dir():
        raise InputError(root, "is not a folder (expected the recordings folder)")
    try:
        objects = tree.dirs(root)
    except PermissionError:
        raise InputError(root, "recordings folder is not readable (permission denied)") from None
    if not objects:
        raise InputError(root, f"no object folders (expected {_LAYOUTS})")

    if is_frame_layout(root, tree):
        found = find_frame_recordings(root, lambda path, problem: report(path, problem, on_error), tree)
    else:
        layout = _video_layout(sensor or stated_sensor(root, tree))
        listed = (r for obj in objects for r in _object_recordings(obj, on_error, layout, tree))
        found = sorted(listed, key=lambda r: r.key)
    if not found:
        raise InputError(root, "no usable recordings found")
    return found


#: The two layouts a recordings folder may have, in words for the errors that find neither.
_LAYOUTS = (
    "videos as <object>/exp_num_<N>/camera_*.avi, or grasps as frame folders: "
    "<object>/<grasp>/ holding .jpg/.png/.bmp frames; see docs/new-sensor.md"
)


def _has_layout(sensor: SensorSpec | None) -> bool:
    return sensor is not None and bool(sensor.experiment_pattern and sensor.camera_glob and sensor.slip_marker)


def _video_layout(sensor: SensorSpec | None) -> Layout:
    """The layout a scan of videos reads: the sensor's own; for a sensor of frame folders (a detector
    calibrated to one), or none, the study's (:data:`~slipsense.sensors.spec.STUDY_LAYOUT`)."""
    if _has_layout(sensor):
        return Layout(sensor.experiment_pattern, sensor.camera_glob, sensor.slip_marker, sensor.fps)
    return Layout(**STUDY_LAYOUT, fps=sensor.fps if sensor is not None else None)


def layout_sensor(root: str | Path, tree: FolderTree | None = None) -> SensorSpec | None:
    """The registered sensor whose video layout ``root`` holds: an object folder with an experiment
    folder named as the sensor names them, holding its camera videos (or a ROS 2 bag). None where no
    registered sensor's layout is found, or where two different ones are (which one is then stated)."""
    root, tree = Path(root), tree or FolderTree()
    found: dict[tuple, SensorSpec] = {}
    for sensor in filter(_has_layout, SENSORS.values()):
        layout = _video_layout(sensor)
        if layout[:3] not in found and _holds_layout(root, layout, tree):
            found[layout[:3]] = sensor
    return next(iter(found.values())) if len(found) == 1 else None


def _holds_layout(root: Path, layout: Layout, tree: FolderTree) -> bool:
    pattern = re.compile(layout.experiment_pattern)
    try:
        for obj in tree.dirs(root):
            for exp in tree.dirs(obj):
                if pattern.match(exp.name) and (
                    tree.files(exp, layout.camera_glob) or tree.is_file(exp / "metadata.yaml")
                ):
                    return True
    except OSError:  # an unreadable folder: the scan names it
        return False
    return False


def stated_sensor(root: str | Path, tree: FolderTree | None = None) -> SensorSpec | None:
    """The sensor a recordings folder states: its ``sensor.json`` or a registered layout (the
    ``gelsight-lift`` data's ``*_result.dat`` files, a registered sensor's videos: :func:`layout_sensor`);
    None where it states none."""
    tree = tree or FolderTree()
    return data_sensor(root, tree) or layout_sensor(root, tree)


def reads_alike(root: str | Path, a: SensorSpec, b: SensorSpec, tree: FolderTree | None = None) -> bool:
    """Whether :func:`find_recordings` of ``root`` finds the same recordings with sensor ``a`` as with
    ``b``: grasps as frame folders whatever the sensor, videos where both read the same folder layout."""
    return _video_layout(a)[:3] == _video_layout(b)[:3] or is_frame_layout(root, tree)


def camera_counts(recordings: Iterable[Recording]) -> list[int]:
    """The distinct numbers of camera videos per run (object, experiment), sorted: ``[2]`` when every
    run has both fingers."""
    per_run = Counter((r.object, r.experiment) for r in recordings)
    return sorted(set(per_run.values()))


def _hint(pattern: str) -> str:
    """An experiment-folder pattern as people write it: ``^exp_num_(\\d+)$`` -> ``exp_num_<N>``."""
    return pattern.lstrip("^").rstrip("$").replace(r"(\d+)", "<N>")


def _object_recordings(obj_dir: Path, on_error: str, layout: Layout, tree: FolderTree) -> list[Recording]:
    experiment_re = re.compile(layout.experiment_pattern)
    camera_glob, slip_marker = layout.camera_glob, layout.slip_marker
    camera_prefix = camera_glob.split("*")[0].lower()
    try:
        exp_dirs = tree.dirs(obj_dir)
    except FolderError as exc:  # unreadable, or a link that loops or points nowhere
        why = "object folder is not readable (permission denied)" if isinstance(exc, PermissionError) else exc.problem
        report(obj_dir, why, on_error)
        return []
    if not exp_dirs:
        report(obj_dir, f"object folder holds no {_hint(layout.experiment_pattern)} experiment folders", on_error)
        return []
    out: list[Recording] = []
    seen: dict[int, Path] = {}
    for exp_dir in exp_dirs:
        m = experiment_re.match(exp_dir.name)
        if m is None:
            named = any(experiment_re.match(d.name) for d in exp_dirs)
            if not named and not tree.entries(exp_dir):  # no layout to go by: say what a grasp folder holds
                report(exp_dir, f"grasp folder is empty (expected {_LAYOUTS})", on_error)
            else:
                report(exp_dir, f"folder name does not match {_hint(layout.experiment_pattern)}", on_error)
            continue
        number = int(m.group(1))
        if number in seen:
            # exp_num_1 and exp_num_01 would give two recordings with one key.
            report(exp_dir, f"experiment {number} also found as {seen[number].name}", on_error)
            continue
        try:
            cameras = tree.files(exp_dir, camera_glob)
        except FolderError as exc:
            perm = isinstance(exc, PermissionError)
            report(exp_dir, "experiment folder is not readable (permission denied)" if perm else exc.problem, on_error)
            continue
        if not cameras and tree.is_file(exp_dir / "metadata.yaml"):  # a ROS 2 bag as the experiment
            if layout.fps is None:
                report(
                    exp_dir, f"a ROS 2 bag is written into videos at its sensor's rate, and {state_sensor()}", on_error
                )
                continue
            try:
                cameras = bag_cameras(exp_dir, layout.fps)
            except InputError as exc:
                report(exp_dir, exc.problem, on_error)
                continue
        # camera_2.AVI, Camera_0.avi, camera_0.mp4: look like sensor videos but are not read;
        # say so rather than label the run from the other camera alone without a word.
        for p in tree.files(exp_dir):
            if camera_prefix and p.name.lower().startswith(camera_prefix) and p not in cameras:
                why = f"not used (sensor videos are read from files named {camera_glob}, lower case)"
                warnings.warn(f"{p}: {why}", SkippedInputWarning, stacklevel=3)
        if not cameras:
            report(exp_dir, f"experiment folder holds no {camera_glob} video", on_error)
            continue
        if len(cameras) == 1:
            why = f"only one sensor video ({cameras[0].name}); the run is labelled from it alone"
            warnings.warn(f"{exp_dir}: {why}", IncompleteRunWarning, stacklevel=3)
        seen[number] = exp_dir
        slipped = tree.exists(exp_dir / slip_marker)
        out.extend(Recording(obj_dir.name, number, cam.stem, cam, slipped) for cam in cameras)
    return out


def validate_recordings(
    recordings: Iterable[Recording],
    on_error: OnError = "raise",
    expected_size: tuple[int, int] | None = None,
    probed: dict | None = None,
) -> list[Recording]:
    """The ``recordings`` (from :func:`find_recordings`) whose videos pass a probe
    (:func:`~slipsense.recordings.video.probe_video`, a few ms each; at least 2 frames, and
    ``expected_size`` ``(height, width)`` in pixels unless None), in the given order; ``on_error`` as
    the module notes say (``"skip"``: a video that fails is named in a warning and dropped).
    ``probed``: where given, each good recording's :class:`~slipsense.recordings.video.VideoInfo` goes
    there under its key."""
    check_on_error(on_error)
    good: list[Recording] = []
    for rec in recordings:
        try:
            info = probe_video(rec.path, expected_size=expected_size, min_frames=2)
            if probed is not None:
                probed[rec.key] = info
        except InputError as exc:
            if on_error == "raise":
                raise
            warnings.warn(f"{exc}; skipped", SkippedInputWarning, stacklevel=2)
            continue
        good.append(rec)
    return good
