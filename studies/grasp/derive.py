"""A user's own sensor, made from the shared recordings: every run's one camera, resized, at a lower
rate, as frame folders labelled per grasp (``slip.txt``) with a ``sensor.json`` stating its rate.
What ``slipsense adapt`` is measured on (``docs/new-sensor.md``): ``python -m studies grasp derive``.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2

from slipsense import atomic
from slipsense.progress import progress_bar
from slipsense.recordings.folders import find_recordings
from slipsense.recordings.frames import frame_files
from slipsense.recordings.video import read_video
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


def adapt_report(adapt_dir: Path, out: Path, commands: list[str], seconds: float) -> Path:
    """``README.md`` of a ``slipsense adapt`` run (its ``adapt.json``) into ``out``: every candidate and
    baseline judged on objects it never saw, what was kept and why, the commands and the time taken."""
    doc = json.loads((Path(adapt_dir) / "adapt.json").read_text())
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    text = (
        "# slipsense adapt on a derived sensor\n\n"
        + "Commands:\n\n"
        + "".join(f"    {c}\n" for c in commands)
        + f"\n{provenance()} `adapt` took {seconds:.0f} s.\n\n"
        "The sensor: the shared GelSight Mini recordings as a user's own sensor would give them (one camera, "
        "160 x 120 pixels, 12.5 frames/s, frame folders labelled per grasp). The shipped one-finger detector was "
        'trained on the same objects at 25 frames/s, so its row "as is" flatters it; the other rows choose their '
        "thresholds (and, fine-tuned, their weights) without the object judged. Baselines: thresholds chosen on "
        "the other objects.\n\n" + adapt_table(doc)
    )
    atomic.write_text(out / "README.md", text)
    atomic.write_text(out / "adapt.json", json.dumps(doc, indent=1))
    return out / "README.md"
