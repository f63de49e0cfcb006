"""Another unit of the same sensor looks different: the shipped detector on every run of the shared
recordings as a dimmer or brighter unit, one with another LED tint or a softer focus would have seen
them, judged per grasp at its operating point. ``python -m studies grasp looks``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np

from slipsense import atomic
from slipsense.paths import portable_path
from slipsense.errors import InputError
from slipsense.evaluation.replay import RunTrace
from slipsense.measures import pergrasp
from slipsense.recordings.contact import STARTUP_FRAMES, rest_mask
from slipsense.recordings.recording_set import Recordings
from slipsense.recordings.frame_cache import video_products
from slipsense.recordings.video import read_video
from slipsense.sensors.marker_detection import detect_markers
from slipsense.streaming.detector import SlipDetector
from studies.grasp.rates import fold_detectors, judged_runs, trained_by_command
from studies.pages import looks_table
from studies.provenance import provenance


def _exposure(gain: float) -> Callable[[np.ndarray], np.ndarray]:
    return lambda v: np.clip(v.astype(np.float32) * gain, 0, 255).astype(np.uint8)


def _tint(v: np.ndarray) -> np.ndarray:  # BGR: blue -20, red +25
    return np.clip(v.astype(np.int16) + np.array([-20, 0, 25], np.int16), 0, 255).astype(np.uint8)


def _blur(v: np.ndarray) -> np.ndarray:
    return np.stack([cv2.GaussianBlur(f, (5, 5), 1.5) for f in v])


def _markers_gone(v: np.ndarray, fraction: float = 0.1, seed: int = 0) -> np.ndarray:
    """``fraction`` of the gel's markers (found on a frame after the camera start-up) painted over with
    the gel around them in every frame, as on a worn gel; a video with too few markers is left as is."""
    try:
        centres = detect_markers(v[min(STARTUP_FRAMES, len(v) - 1)])
    except InputError:
        return v
    rng = np.random.default_rng([seed, len(centres)])
    gone = centres[rng.choice(len(centres), max(1, round(fraction * len(centres))), replace=False)]
    out = v.copy()
    h, w = v.shape[1:3]
    for x, y in gone:  # each painted over with the mean of the unpainted gel around it (smooth shading)
        cx, cy = int(round(x)), int(round(y))
        y0, y1, x0, x1 = max(0, cy - 30), min(h, cy + 31), max(0, cx - 30), min(w, cx + 31)
        mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.circle(mask, (cx - x0, cy - y0), 14, 1, -1)  # markers of the shared gels: 11-22 px wide, and their shift
        keep = (1 - mask).astype(np.float32)
        weight = np.maximum(cv2.blur(keep, (31, 31)), 1e-6)[..., None]
        for f in out[:, y0:y1, x0:x1]:
            fill = cv2.blur(f.astype(np.float32) * keep[..., None], (31, 31)) / weight
            f[mask == 1] = np.clip(np.rint(fill[mask == 1]), 0, 255).astype(np.uint8)
    return out


#: name -> what it does to a video (uint8 (N, H, W, 3) BGR)
LOOKS: dict[str, Callable[[np.ndarray], np.ndarray] | None] = {
    "as recorded": None,
    "exposure x0.7": _exposure(0.7),
    "exposure x1.3": _exposure(1.3),
    "Gaussian blur (5 px, sigma 1.5)": _blur,
    "LED tint (B -20, R +25)": _tint,
    "10% of the gel's markers gone": _markers_gone,
}


def _replayed(det: SlipDetector, recs: list, labels: dict, looks: dict, progress: bool) -> dict[str, list]:
    """``{look: [GraspOutcome]}`` of ``det`` on every run of ``recs`` under each look (slips without a
    moment of slip left out: nothing to warn of)."""
    outcomes: dict[str, list] = {name: [] for name in looks}
    for obj, exp, cams, slipped, moment in judged_runs(recs, labels, det.sensors, progress):
        videos = [read_video(r.path, expected_size=None) for r in cams]
        rest = rest_mask(np.stack([video_products(r.path, ["contact"])["contact"] for r in cams]))
        for name, change in looks.items():
            trace = det.replay(*[v if change is None else change(v) for v in videos])
            run = RunTrace(obj, exp, slipped, moment, len(videos[0]), trace.probability, rest, fps=det.sensor.fps)
            outcomes[name].append(run.outcome(det.threshold, det.debounce))
    return outcomes


def _row(name: str, outs: list, fps: float) -> dict[str, Any]:
    s = pergrasp.summarise(outs, fps)
    row = {"look": name, **{k: s[k] for k in ("slip_runs", "warned", "premature", "held_runs")}}
    row["false_positive_grasps"] = s["false_positive_grasps"]
    return row


def looks_study(recordings: Path, checkpoint: Path, progress: bool = True) -> dict[str, Any]:
    """Per-grasp outcomes of ``checkpoint`` on every run of ``recordings`` under each look."""
    det = SlipDetector.from_checkpoint(checkpoint, backend="torch")
    data = Recordings.open(recordings, on_error="skip").labelled(whole_runs=False, progress=progress)
    outcomes = _replayed(det, list(data), dict(data.labels), LOOKS, progress)
    det.close()
    return {
        "checkpoint": Path(checkpoint).name,
        "recordings": portable_path(recordings),
        "operating_point": {"threshold": det.threshold, "debounce": det.debounce},
        "rows": [_row(name, outs, det.sensor.fps) for name, outs in outcomes.items()],
    }


def looks_folds_study(recordings: Path, detectors: Path, progress: bool = True) -> dict[str, Any]:
    """Leave objects out: each fold's detector (``<detectors>/fold<k>/``, ``slipsense train --fold k``)
    on its held-out objects (``held_out.json``) under each look, pooled over the folds."""
    data = Recordings.open(recordings, on_error="skip").labelled(whole_runs=False, progress=progress)
    recs, labels = list(data), dict(data.labels)
    pooled: dict[str, list] = {name: [] for name in LOOKS}
    fps = None  # the folds' detectors share their sensor's rate (each replay runs on its clock)
    for _, held, det in fold_detectors(detectors):
        fps = det.sensor.fps
        mine = [r for r in recs if r.object in held]
        for name, outs in _replayed(det, mine, labels, LOOKS, progress).items():
            pooled[name].extend(outs)
    return {
        "checkpoint": f"the folds of {portable_path(detectors)}, each on its held-out objects",
        "trained_by": trained_by_command(detectors),
        "recordings": portable_path(recordings),
        "rows": [_row(name, outs, fps) for name, outs in pooled.items()],
    }


def table(doc: dict[str, Any]) -> str:
    return looks_table(doc["rows"], bound="operating_point" not in doc)


def write(doc: dict[str, Any], out: Path, command: str) -> list[Path]:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    doc = {**doc, "command": command}
    atomic.write_text(out / "looks.json", json.dumps(doc, indent=1))
    if "operating_point" in doc:
        title, how = (
            "The shipped detector as another unit of the sensor sees the runs",
            f"Detector `{doc['checkpoint']}` at its operating point (threshold {doc['operating_point']['threshold']:g}, "
            f"debounce {doc['operating_point']['debounce']}), every run of `{doc['recordings']}` replayed from its "
            "first frame with the change applied to both cameras' frames, judged per grasp. The detector was trained "
            "on these runs: the change between rows is what counts, not the level.",
        )
    else:
        title, how = (
            "The detector's recipe as another unit of the sensor sees the runs, on objects it never saw",
            f"Detectors: {doc['checkpoint']}, at their own operating points; every run of `{doc['recordings']}` "
            "replayed from its first frame with the change applied to both cameras' frames, judged per grasp, "
            "pooled over the folds.",
        )
    trained = f"Folds trained by `{doc['trained_by']}` for K = 0..4.\n\n" if doc.get("trained_by") else ""
    text = f"# {title}\n\nCommand: `{command}`  \n{provenance()}\n\n{trained}{how}\n\n" + table(doc)
    atomic.write_text(out / "README.md", text)
    return [out / "looks.json", out / "README.md"]
