"""Grasps stored as folders of frames and labelled as a whole (slipped or held), one finger or two.

Layout (the shared ``gelsight-lift`` data is the first instance; lay out your own the same way)::

    <root>/<object>/<grasp>/<frames>       the frames of one grasp: .jpg/.png/.bmp files numbered
                                           without gaps (see :mod:`slipsense.recordings.frames`)
      or <root>/<object>/<grasp>/camera_<i>/<frames>
                                           one folder of frames per camera (finger) of the grasp,
                                           named as the video layout names its videos (camera_0,
                                           camera_2), each with the same number of frames
    <root>/<object>_result.dat             one line per grasp, naming its folder and outcome; or,
                                           without it, <grasp>/slip.txt when the object slipped
    <root>/sensor.json                     optional: the sensor (name, fps, image_size, ...), e.g.
                                           {"name": "my-gelsight", "output": "video", "fps": 30}

A grasp with frames in its own folder is one camera, ``Recording.camera`` :data:`CAMERA`; a grasp of
``camera_*`` folders is a run of that many cameras, ``Recording.camera`` the folder's name (as
``camera_0.avi`` gives ``camera_0``), so two fingers' frames read as two-camera runs, as their videos
would. Every grasp of a data set must hold the same cameras; a grasp whose cameras differ in frame
count, that holds frames beside its camera folders, or a camera folder without frames is an
:class:`~slipsense.errors.InputError` naming the folder.

A line of ``<object>_result.dat`` (Li, Dong and Adelson's format, space-separated), e.g.
``68 fail 0 160 450 398 068_00 _s09_``: column 2 is the outcome (``fail`` or ``slip``: the object
slipped; ``ok`` or ``success``: it held), column 3 says the same as 0 or 1, column 7 names the grasp's
folder (``068_00`` for the folder ``068_00_mm``); the other columns are not read. A grasp's number
(``Recording.experiment``) is the digits of its folder's name: ``068_00_mm`` is grasp 6800.

Every grasp folder must be named by exactly one line of its object's file and every line must name a
folder; anything else is an :class:`~slipsense.errors.InputError` naming the file (``on_error="skip"``:
a warning, the grasp left out).
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Callable

from ..errors import InputError
from ..sensors.spec import GELSIGHT_LIFT, SensorSpec
from .frames import FRAME_SUFFIXES, frame_files
from .listing import FolderTree
from .types import Recording, by_run

Report = Callable[[Path, str], None]

RESULT_SUFFIX = "_result.dat"
#: The camera name of a frame folder's recording (one finger per grasp).
CAMERA = "gelsight"
#: Per-camera frame folders of a grasp are named as the video layout's videos: ``camera_0``, ``camera_2``.
CAMERA_FOLDER_PREFIX = "camera_"
SLIPPED_WORDS = ("fail", "slip")
HELD_WORDS = ("ok", "success")


def camera_folders(grasp: str | Path, tree: FolderTree | None = None) -> list[Path]:
    """The per-camera frame folders of a grasp folder (its ``camera_*`` sub-folders), by name; empty
    for a grasp of one camera whose frames lie in the grasp folder itself (or for a run of videos)."""
    return [p for p in (tree or FolderTree()).dirs(grasp) if p.name.startswith(CAMERA_FOLDER_PREFIX)]


def is_frame_layout(root: str | Path, tree: FolderTree | None = None) -> bool:
    """Whether ``root`` holds grasps as frame folders: it has ``*_result.dat`` files, or its first
    object's first grasp folder holds image files or ``camera_*`` folders of them (not
    ``camera_*`` videos). ``tree``: where ``root`` was listed already."""
    root, tree = Path(root), tree or FolderTree()
    if not root.is_dir():
        return False
    if tree.names(root, f"*{RESULT_SUFFIX}"):
        return True
    objects = tree.dirs(root)
    grasps = tree.dirs(objects[0]) if objects else []
    if not grasps or tree.files(grasps[0], f"{CAMERA_FOLDER_PREFIX}*"):
        return False
    first = grasps[0]
    return bool(frame_files(first, tree)) or any(frame_files(c, tree) for c in camera_folders(first, tree))


def grasp_cameras(folder: Path, tree: FolderTree | None = None) -> list[tuple[str, Path]]:
    """``[(camera, frame folder)]`` of one grasp folder: its ``camera_*`` folders by name, or the grasp
    folder itself as :data:`CAMERA`. InputError naming the folder where it holds frames beside camera
    folders, a camera folder holds no frames, or the cameras differ in frame count (listed, not
    decoded: a gap or an undecodable frame is found when the frames are read)."""
    tree = tree or FolderTree()
    cameras = camera_folders(folder, tree)
    if not cameras:
        return [(CAMERA, folder)]
    if frame_files(folder, tree):
        raise InputError(folder, "holds frames beside its camera_* folders: put every frame into its camera's folder")
    counts = {}
    for cam in cameras:
        counts[cam.name] = len(frame_files(cam, tree))
        if not counts[cam.name]:
            raise InputError(cam, f"camera folder holds no image files ({', '.join(FRAME_SUFFIXES)})")
    if len(set(counts.values())) != 1:
        listed = ", ".join(f"{name} {n}" for name, n in counts.items())
        raise InputError(
            folder, f"the cameras of this grasp differ in frame count ({listed}): each camera needs every frame"
        )
    return [(cam.name, cam) for cam in cameras]


def _grasp_folder(rec: Recording) -> Path:
    return rec.path if rec.camera == CAMERA else rec.path.parent


def _cameras_words(cameras: tuple[str, ...]) -> str:
    return "its frames in itself (one camera)" if cameras == (CAMERA,) else " and ".join(cameras)


def data_sensor(root: str | Path, tree: FolderTree | None = None) -> SensorSpec | None:
    """The sensor a frame-folder data set states: its ``sensor.json``, else the GelSight of the
    ``gelsight-lift`` data where the folder is laid out as that data is (``*_result.dat``), else
    None (a video data set: the detector's own sensor applies). ``tree``: where ``root`` was listed."""
    root, tree = Path(root), tree or FolderTree()
    path = root / "sensor.json"
    try:
        stated, results = tree.is_file(path), tree.names(root, f"*{RESULT_SUFFIX}")
    except OSError:  # no folder to read (the scan names the problem)
        return None
    if stated:
        try:
            return SensorSpec.from_dict(json.loads(path.read_text(encoding="utf-8")))
        except (ValueError, UnicodeDecodeError) as exc:
            raise InputError(path, f"not a sensor spec ({exc})") from None
    return GELSIGHT_LIFT if results else None


def read_result_file(path: Path) -> dict[str, bool]:
    """``{folder name as the line writes it: slipped}`` of one ``<object>_result.dat``."""
    out: dict[str, bool] = {}
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot be read ({exc})") from None
    for number, line in enumerate(lines, 1):
        cols = line.split()
        if not cols:
            continue
        if len(cols) < 7:
            raise InputError(path, f"line {number} has {len(cols)} columns, expected at least 7")
        word, flag, name = cols[1].lower(), cols[2], cols[6]
        if word not in SLIPPED_WORDS + HELD_WORDS:
            raise InputError(
                path, f"line {number}: outcome {cols[1]!r} is none of {', '.join(SLIPPED_WORDS + HELD_WORDS)}"
            )
        slipped = word in SLIPPED_WORDS
        if flag not in ("0", "1") or (flag == "0") != slipped:
            raise InputError(path, f"line {number}: column 3 ({flag!r}) does not agree with the outcome {cols[1]!r}")
        if name in out:
            raise InputError(path, f"line {number} names grasp {name} a second time")
        out[name] = slipped
    return out


def _object_grasps(root: Path, obj: Path, report: Report, with_results: bool, tree: FolderTree) -> list[Recording]:
    result = root / f"{obj.name}{RESULT_SUFFIX}"
    if with_results and not tree.is_file(result):  # its grasps would all read as held
        report(obj, f"no {result.name} beside it, where the other objects have theirs")
        return []
    outcomes = read_result_file(result) if tree.is_file(result) else None
    folders = {g.name: g for g in tree.dirs(obj)}
    found: list[Recording] = []
    named: set[str] = set()
    if outcomes is not None:
        for name in outcomes:
            folder = next((folders[n] for n in (name, f"{name}_mm") if n in folders), None)
            if folder is None:
                report(result, f"names grasp folder {name}, which {obj} does not hold")
                continue
            named.add(folder.name)
    seen: dict[int, Path] = {}
    for folder in folders.values():
        if outcomes is not None and folder.name not in named:
            report(folder, f"no line of {result} names this grasp folder")
            continue
        digits = "".join(re.findall(r"\d", folder.name))
        if not digits:
            report(folder, "grasp folder name holds no number (its digits number the grasp)")
            continue
        number = int(digits)
        if number in seen:
            report(folder, f"grasp {number} also found as {seen[number].name}")
            continue
        try:
            cameras = grasp_cameras(folder, tree)
        except InputError as exc:
            report(exc.path, exc.problem)
            continue
        seen[number] = folder
        if outcomes is not None:
            slipped = outcomes.get(folder.name, outcomes.get(folder.name.removesuffix("_mm")))
        else:
            slipped = tree.exists(folder / "slip.txt")
        found.extend(Recording(obj.name, number, cam, path, bool(slipped), per_grasp=True) for cam, path in cameras)
    if not folders:
        report(obj, f"object folder holds no grasp folders of frames ({', '.join(FRAME_SUFFIXES)})")
    return found


def find_frame_recordings(root: str | Path, report: Report, tree: FolderTree | None = None) -> list[Recording]:
    """One :class:`Recording` per grasp folder under ``root`` (``path``: the folder; ``per_grasp``
    True), sorted by key. Frames are not read here (see
    :func:`~slipsense.recordings.folders.validate_recordings`). ``report(path, problem)`` raises or
    warns (:func:`slipsense.recordings.folders.find_recordings` passes its ``on_error`` rule).
    ``tree``: where ``root`` was listed already."""
    root, tree = Path(root), tree or FolderTree()
    results = tree.names(root, f"*{RESULT_SUFFIX}")
    objects = tree.dirs(root)
    for result in results:
        name = result.name.removesuffix(RESULT_SUFFIX)
        if root / name not in objects:
            report(result, f"names object {name}, which has no folder")
    found = [r for obj in objects for r in _object_grasps(root, obj, report, bool(results), tree)]
    return _same_cameras(sorted(found, key=lambda r: r.key), report)


def _same_cameras(found: list[Recording], report: Report) -> list[Recording]:
    """``found`` without the grasps whose cameras are not the first grasp's, each reported: a data
    set is one camera per grasp or the same ``camera_*`` folders in every grasp."""
    runs = by_run(found)
    if not runs:
        return found
    first = next(iter(runs.values()))
    expected = tuple(r.camera for r in first)
    kept: list[Recording] = []
    for recs in runs.values():
        cameras = tuple(r.camera for r in recs)
        if cameras != expected:
            report(
                _grasp_folder(recs[0]),
                f"holds {_cameras_words(cameras)}, where {_grasp_folder(first[0])} holds "
                f"{_cameras_words(expected)}: every grasp needs the same cameras",
            )
            continue
        kept.extend(recs)
    return sorted(kept, key=lambda r: r.key)
