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
from slipsense.config import portable_path
from slipsense.data import label_runs
from slipsense.evaluation import pergrasp
from slipsense.evaluation.early_warning import RunTrace
from slipsense.progress import progress_bar
from slipsense.recordings.folders import find_recordings
from slipsense.recordings.frame_cache import video_products
from slipsense.recordings.types import by_run
from slipsense.recordings.video import read_video
from slipsense.streaming.detector import SlipDetector
from studies.provenance import provenance


def _exposure(gain: float) -> Callable[[np.ndarray], np.ndarray]:
    return lambda v: np.clip(v.astype(np.float32) * gain, 0, 255).astype(np.uint8)


def _tint(v: np.ndarray) -> np.ndarray:  # BGR: blue -20, red +25
    return np.clip(v.astype(np.int16) + np.array([-20, 0, 25], np.int16), 0, 255).astype(np.uint8)


def _blur(v: np.ndarray) -> np.ndarray:
    return np.stack([cv2.GaussianBlur(f, (5, 5), 1.5) for f in v])


#: name -> what it does to a video (uint8 (N, H, W, 3) BGR)
LOOKS: dict[str, Callable[[np.ndarray], np.ndarray] | None] = {
    "as recorded": None,
    "exposure x0.7": _exposure(0.7),
    "exposure x1.3": _exposure(1.3),
    "Gaussian blur (5 px, sigma 1.5)": _blur,
    "LED tint (B -20, R +25)": _tint,
}


def looks_study(recordings: Path, checkpoint: Path, progress: bool = True) -> dict[str, Any]:
    """Per-grasp outcomes of ``checkpoint`` on every run of ``recordings`` under each look."""
    det = SlipDetector.from_checkpoint(checkpoint, backend="torch")
    recs = find_recordings(recordings, on_error="skip")
    labels = label_runs(recs, progress=progress)
    outcomes: dict[str, list] = {name: [] for name in LOOKS}
    for (obj, exp), cams in progress_bar(list(by_run(recs).items()), progress, "replaying runs"):
        labs = [labels[r.key] for r in cams if r.key in labels]
        if len(labs) != len(cams) or len(cams) != det.sensors:
            continue
        moment = next((lab.moment_of_slip for lab in labs if lab.moment_of_slip is not None), None)
        slipped = any(lab.slipped for lab in labs)
        if slipped and moment is None:
            continue
        videos = [read_video(r.path, expected_size=None) for r in cams]
        rest = pergrasp.rest_mask(np.stack([video_products(r.path, ["contact"])["contact"] for r in cams]))
        for name, change in LOOKS.items():
            trace = det.replay(*[v if change is None else change(v) for v in videos])
            run = RunTrace(obj, exp, slipped, moment, len(videos[0]), trace.probability, rest)
            outcomes[name].append(run.outcome(det.threshold, det.debounce))
    det.close()
    rows = []
    for name, outs in outcomes.items():
        s = pergrasp.summarise(outs)
        rows.append({"look": name, **{k: s[k] for k in ("slip_runs", "warned", "premature", "held_runs")}})
        rows[-1]["false_positive_grasps"] = s["false_positive_grasps"]
    return {
        "checkpoint": Path(checkpoint).name,
        "recordings": portable_path(recordings),
        "operating_point": {"threshold": det.threshold, "debounce": det.debounce},
        "rows": rows,
    }


def table(doc: dict[str, Any]) -> str:
    lines = [
        "| the same runs, as another unit sees them | slips warned in time | held grasps alarming |",
        "|---|---:|---:|",
    ]
    for r in doc["rows"]:
        lines.append(
            f"| {r['look']} | {r['warned']} of {r['slip_runs']} | {r['false_positive_grasps']} of {r['held_runs']} |"
        )
    return "\n".join(lines) + "\n"


def write(doc: dict[str, Any], out: Path, command: str) -> list[Path]:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    doc = {**doc, "command": command}
    atomic.write_text(out / "looks.json", json.dumps(doc, indent=1))
    text = (
        "# The shipped detector as another unit of the sensor sees the runs\n\n"
        f"Command: `{command}`  \n{provenance()}\n\n"
        f"Detector `{doc['checkpoint']}` at its operating point (threshold {doc['operating_point']['threshold']:g}, "
        f"debounce {doc['operating_point']['debounce']}), every run of `{doc['recordings']}` replayed from its "
        "first frame with the change applied to both cameras' frames, judged per grasp. The detector was trained "
        "on these runs: the change between rows is what counts, not the level.\n\n" + table(doc)
    )
    atomic.write_text(out / "README.md", text)
    return [out / "looks.json", out / "README.md"]
