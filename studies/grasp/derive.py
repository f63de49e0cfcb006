"""A user's own sensor, made from the shared recordings: every run's one camera, resized, at a lower
rate, as frame folders labelled per grasp (``slip.txt``) with a ``sensor.json`` stating its rate.
What ``slipsense adapt`` is measured on (``docs/new-sensor.md``): ``python -m studies grasp derive``.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2

from slipsense import atomic
from slipsense.progress import progress_bar
from slipsense.recordings.folders import find_recordings
from slipsense.recordings.video import read_video


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
