"""A user's own sensor, made from the shared recordings: every run's one camera, resized, at a lower
rate, as frame folders labelled per grasp (``slip.txt``) with a ``sensor.json`` stating its rate.
What ``slipsense adapt`` is measured on (``docs/new-sensor.md``): ``python -m studies grasp derive``.
:func:`two_finger_frame_folders`: a few objects' runs as a two-finger user's frame folders, both
cameras as recorded.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Sequence

import cv2

from slipsense import atomic
from slipsense.errors import InputError
from slipsense.progress import progress_bar
from slipsense.recordings.folders import find_recordings
from slipsense.recordings.frames import frame_files
from slipsense.recordings.types import by_run
from slipsense.recordings.video import probe_video, read_video
from studies.pages import adapt_table
from studies.provenance import provenance


def derive_sensor(
    recordings: Path,
    out: Path,
    size: tuple[int, int] = (120, 160),
    every: int = 2,
    camera: str = "camera_0",
    recorded_fps: float = 25.0,
    progress: bool = True,
) -> int:
    """Write ``out/<object>/exp_num_<N>/<k>.jpg`` (``size``: height, width; every ``every``-th frame of
    ``camera``'s video), ``slip.txt`` where the run slipped, and ``out/sensor.json``; returns the grasps
    written. A grasp folder is written whole under a hidden name and renamed into place, so a killed
    run is redone, not half-read."""
    out = Path(out)
    recs = [r for r in find_recordings(recordings, on_error="skip") if r.camera == camera]
    h, w = size
    for rec in progress_bar(recs, progress, "deriving grasps"):
        folder = out / rec.object / f"exp_num_{rec.experiment}"
        if folder.is_dir():
            continue
        partial = folder.with_name(f".{folder.name}.partial")
        partial.mkdir(parents=True, exist_ok=True)
        frames = read_video(rec.path, expected_size=None)[::every]
        for k, f in enumerate(frames):
            cv2.imwrite(str(partial / f"{k:05d}.jpg"), cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA))
        if rec.slipped:
            (partial / "slip.txt").write_text("")
        partial.rename(folder)
    sensor = {"name": "derived-gelsight", "output": "video", "fps": recorded_fps / every, "image_size": [h, w]}
    atomic.write_text(out / "sensor.json", json.dumps(sensor))
    return len(recs)


def two_finger_frame_folders(
    recordings: Path, out: Path, objects: Sequence[str] | None = None, suffix: str = ".png", progress: bool = False
) -> int:
    """The runs of ``objects`` (default: all) of a video recordings folder (the shared wiggle grasps,
    ``gelsight-slip``) as a two-finger user's frame folders: ``out/<object>/exp_num_<N>/camera_<i>/<k>.png``
    (every frame of each camera's video at its recorded size), ``slip.txt`` where the run slipped and
    ``out/sensor.json`` (the videos' stated rate and frame size: 25 frames/s, 240 x 320). PNG keeps every
    pixel, so a detector replays the same frames as from the videos (``suffix=".jpg"`` does not).
    Returns the grasps written. A grasp folder is written whole under a hidden name and renamed into
    place; one already there is kept."""
    recordings, out = Path(recordings), Path(out)
    recs = find_recordings(recordings)
    if objects is not None:
        missing = sorted(set(objects) - {r.object for r in recs})
        if missing:
            raise InputError(recordings, f"holds no runs of {', '.join(missing)}")
        recs = [r for r in recs if r.object in set(objects)]
    runs = by_run(recs)
    first = probe_video(recs[0].path, expected_size=None)
    for (obj, experiment), cams in progress_bar(list(runs.items()), progress, "two-finger frame folders"):
        folder = out / obj / f"exp_num_{experiment}"
        if folder.is_dir():
            continue
        partial = folder.with_name(f".{folder.name}.partial")
        if partial.exists():
            shutil.rmtree(partial)
        for rec in cams:
            (partial / rec.camera).mkdir(parents=True)
            for k, frame in enumerate(read_video(rec.path, expected_size=None)):
                if not cv2.imwrite(str(partial / rec.camera / f"{k:05d}{suffix}"), frame):
                    raise InputError(partial / rec.camera, f"frame {k} could not be written as {suffix}")
        if cams[0].slipped:
            (partial / "slip.txt").write_text("")
        partial.rename(folder)
    sensor = {"name": "gelsight-mini-frames", "output": "video", "fps": float(first.fps)}
    atomic.write_text(out / "sensor.json", json.dumps({**sensor, "image_size": [first.height, first.width]}))
    return len(runs)


def slower_frame_folders(recordings: Path, out: Path, every: int = 2, fps: float = 30.0) -> int:
    """A frame-folder data set (the ``gelsight-lift`` layout: ``<object>/<grasp>/`` frames and
    ``<object>_result.dat``) as a sensor ``every`` times slower would have taken it: every ``every``-th
    frame, numbered again without gaps, the label files copied, ``sensor.json`` stating the rate
    (``fps / every``). Returns the grasps written."""
    recordings, out = Path(recordings), Path(out)
    grasps = 0
    for labels in sorted(recordings.glob("*_result.dat")):
        obj = labels.name[: -len("_result.dat")]
        for grasp in sorted(p for p in (recordings / obj).iterdir() if p.is_dir()):
            target = out / obj / grasp.name
            target.mkdir(parents=True, exist_ok=True)
            for k, frame in enumerate(frame_files(grasp)[::every]):
                shutil.copyfile(frame, target / f"{k:05d}{frame.suffix}")
            grasps += 1
        shutil.copyfile(labels, out / labels.name)
    spec = {"name": "gelsight-lift", "output": "video", "fps": fps / every, "image_size": [480, 640]}
    atomic.write_text(out / "sensor.json", json.dumps({**spec, "camera_glob": "*.jpg"}))
    return grasps


def resized_frame_folders(
    recordings: Path,
    out: Path,
    size: tuple[int, int] = (300, 400),
    fps: float = 30.0,
    suffix: str = ".jpg",
    progress: bool = False,
) -> int:
    """A frame-folder data set (the ``gelsight-lift`` layout, or any grasps labelled as a whole) as a
    user's sensor of another frame size would give it: every frame resized to ``size`` (height, width;
    area interpolation), ``out/<object>/<grasp>/<k><suffix>`` numbered without gaps, ``slip.txt`` in
    each grasp that slipped (no result files), ``out/sensor.json`` stating ``fps`` and the size.
    Returns the grasps written. A grasp folder is written whole under a hidden name and renamed into
    place; one already there is kept."""
    recordings, out = Path(recordings), Path(out)
    recs = find_recordings(recordings)
    if not all(r.per_grasp for r in recs):
        raise InputError(recordings, "holds runs of videos, not grasps as folders of frames")
    h, w = size
    for rec in progress_bar(recs, progress, "resized frame folders"):
        folder = out / rec.object / rec.path.name
        if folder.is_dir():
            continue
        partial = folder.with_name(f".{folder.name}.partial")
        if partial.exists():
            shutil.rmtree(partial)
        partial.mkdir(parents=True)
        for k, frame in enumerate(frame_files(rec.path)):
            image = cv2.imread(str(frame), cv2.IMREAD_COLOR)
            if image is None:
                raise InputError(frame, "frame does not decode")
            resized = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)
            if not cv2.imwrite(str(partial / f"{k:05d}{suffix}"), resized):
                raise InputError(partial, f"frame {k} could not be written as {suffix}")
        if rec.slipped:
            (partial / "slip.txt").write_text("")
        partial.rename(folder)
    sensor = {"name": f"{recordings.name}-{h}x{w}", "output": "video", "fps": float(fps), "image_size": [h, w]}
    atomic.write_text(out / "sensor.json", json.dumps(sensor))
    return len(recs)


def adapt_report(adapt_dir: Path, out: Path, commands: list[str], seconds: float, sensor: Path) -> Path:
    """``README.md`` of a ``slipsense adapt`` run (its ``adapt.json``) into ``out``: every candidate and
    baseline judged on objects it never saw, what was kept, the figure to expect of it and why, the
    commands and the time taken."""
    doc = json.loads((Path(adapt_dir) / "adapt.json").read_text())
    spec = json.loads((Path(sensor) / "sensor.json").read_text())
    h, w = spec.get("image_size") or (None, None)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    text = (
        "# slipsense adapt on a derived sensor\n\n"
        + "Commands:\n\n"
        + "".join(f"    {c}\n" for c in commands)
        + f"\n{provenance()} `adapt` took {seconds:.0f} s.\n\n"
        f"The sensor (`{spec.get('name')}`): {w} x {h} pixels, {spec.get('fps'):g} frames/s, frame folders labelled "
        "per grasp, made from the shared recordings as a user's own sensor would give them. Every row chooses its "
        "threshold (and, where it learns, its weights) without the object judged; where the shipped detector was "
        'trained on these objects (the wiggle grasps), its rows "as is" and "recalibrated" flatter it. The last row '
        "is the figure of what adapt keeps: the choice among the candidates made again without each object, on the "
        "other objects' grasps only. Baselines: thresholds chosen on the other objects.\n\n" + adapt_table(doc)
    )
    atomic.write_text(out / "README.md", text)
    atomic.write_text(out / "adapt.json", json.dumps(doc, indent=1))
    return out / "README.md"
