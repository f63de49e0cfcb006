"""The shipped detector at other frame rates: every run of a recordings folder replayed as a sensor
at 15 or 12.5 frames/s, or one that drops 10% of its frame pairs, would have delivered it, judged per
grasp at the detector's operating point. Each condition twice: on the detector's clock (the frames
resampled to the rate it was trained at: what ``slipsense watch`` and ``evaluate`` do) and, as before
the clock, with every frame taken for one 40 ms step. ``python -m studies grasp rates``.
"""

from __future__ import annotations

import json
import re
import tempfile
import warnings
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from slipsense import atomic
from slipsense.checkpoint import read_info
from slipsense.paths import portable_path
from slipsense.evaluation.judge import judge
from slipsense.evaluation.replay import RunTrace
from slipsense.measures import pergrasp
from slipsense.measures import promise
from slipsense.progress import progress_bar
from slipsense.recordings.contact import rest_mask
from slipsense.recordings.recording_set import Recordings
from slipsense.recordings.frame_cache import video_products
from slipsense.recordings.types import by_run
from slipsense.streaming.clock import slower_camera_frames
from slipsense.streaming.detector import SlipDetector
from studies.grasp.derive import slower_frame_folders
from studies.pages import folds_table, lift_table
from studies.provenance import provenance


@dataclass(frozen=True)
class Condition:
    """How a slower or lossier sensor would have delivered a run recorded at ``recorded`` frames/s:
    ``frames(n, rng)`` gives the kept frames' indices and their stamps (s)."""

    name: str
    frames: Callable[[int, np.random.Generator], tuple[np.ndarray, np.ndarray]]
    fps: float


def at_rate(fps: float, recorded: float = 25.0) -> Condition:
    """Frames taken at ``fps``: the recorded frame at or just before each of the slower sensor's moments."""

    def frames(n, rng):
        taken = slower_camera_frames(n, fps / recorded)
        return taken, np.arange(len(taken)) / fps

    return Condition(f"frames taken at {fps:g} per second", frames, fps)


def dropped(fraction: float, recorded: float = 25.0) -> Condition:
    """Each frame pair (both cameras) lost with probability ``fraction``; the first and last kept."""

    def frames(n, rng):
        keep = rng.random(n) >= fraction
        keep[0] = keep[-1] = True
        idx = np.flatnonzero(keep)
        return idx, idx / recorded

    return Condition(f"{100 * fraction:g}% of frame pairs dropped at random", frames, recorded * (1 - fraction))


CONDITIONS = [at_rate(25.0), at_rate(15.0), at_rate(12.5), dropped(0.10)]
CONDITIONS[0] = Condition("as recorded (25 frames/s)", CONDITIONS[0].frames, 25.0)


def judged_runs(recs: list, labels: dict, sensors: int, progress: bool = True):
    """``(object, experiment, cameras, slipped, moment of slip)`` of every run of ``recs`` a per-grasp
    replay judges: labelled, with ``sensors`` cameras, and not a slip without a moment (nothing to warn of)."""
    for (obj, exp), cams in progress_bar(list(by_run(recs).items()), progress, "replaying runs"):
        labs = [labels[r.key] for r in cams if r.key in labels]
        if len(labs) != len(cams) or len(cams) != sensors:
            continue
        moment = next((lab.moment_of_slip for lab in labs if lab.moment_of_slip is not None), None)
        slipped = any(lab.slipped for lab in labs)
        if not (slipped and moment is None):
            yield obj, exp, cams, slipped, moment


def fold_detectors(folds: Path):
    """``(fold folder, held-out objects, detector)`` of each ``fold<k>/`` training of ``folds``
    (``slipsense train --fold k``: ``detector.safetensors``, ``held_out.json``), closed after use."""
    for fold in sorted(p for p in Path(folds).glob("fold*") if p.is_dir()):
        held = json.loads((fold / "held_out.json").read_text())["objects"]
        det = SlipDetector.from_checkpoint(fold / "detector.safetensors", backend="torch")
        try:
            yield fold, held, det
        finally:
            det.close()


def _replayed(det: SlipDetector, recs: list, labels: dict, rng_for, modes=("clock", "plain"), progress=True):
    """``{condition: {mode: [GraspOutcome]}}`` of ``det`` on the runs of ``recs`` it judges
    (:func:`judged_runs`) under each of :data:`CONDITIONS`, ``rng_for(object, experiment)`` drawing the
    dropped frames."""
    product = det.cache_product
    outcomes: dict[str, dict[str, list]] = {c.name: {m: [] for m in modes} for c in CONDITIONS}
    for obj, exp, cams, slipped, moment in judged_runs(recs, labels, det.sensors, progress):
        cached = [video_products(r.path, ["contact", product]) for r in cams]
        gray, contact = np.stack([c[product] for c in cached]), np.stack([c["contact"] for c in cached])
        for cond in CONDITIONS:
            idx, stamps = cond.frames(gray.shape[1], rng_for(obj, exp))
            sub_moment = None if moment is None else int(np.searchsorted(idx, moment, side="right")) - 1
            rest = rest_mask(contact[:, idx])
            for mode in modes:
                trace = det.replay_cached(gray[:, idx], stamps=stamps if mode == "clock" else None)
                run = RunTrace(
                    obj, exp, slipped, sub_moment, len(idx), trace.probability, rest, (), cond.fps, det.sensor.fps
                )
                outcomes[cond.name][mode].append(run.outcome(det.threshold, det.debounce))
    return outcomes


def _counts(outs: list, fps: float) -> dict[str, Any]:
    s = pergrasp.summarise(outs, fps)
    row = {k: s[k] for k in ("slip_runs", "warned", "premature", "missed", "held_runs", "false_positive_grasps")}
    row["warned_interval"] = promise.wilson(row["warned"], row["slip_runs"])
    row["false_positive_interval"] = promise.wilson(row["false_positive_grasps"], row["held_runs"])
    return row


def rates_study(recordings: Path, checkpoint: Path, seed: int = 0, progress: bool = True) -> dict[str, Any]:
    """Per-grasp outcomes of ``checkpoint`` on every run of ``recordings`` under each condition, on the
    detector's clock and without it."""
    det = SlipDetector.from_checkpoint(checkpoint, backend="torch")
    data = Recordings.open(recordings, on_error="skip").labelled(whole_runs=False, progress=progress)
    recs, labels = list(data), dict(data.labels)
    rng = np.random.default_rng(seed)
    outcomes = _replayed(det, recs, labels, lambda o, e: rng, progress=progress)
    det.close()
    rows = [{"condition": c.name, **{m: _counts(o, c.fps) for m, o in outcomes[c.name].items()}} for c in CONDITIONS]
    return {
        "checkpoint": Path(checkpoint).name,
        "recordings": portable_path(recordings),
        "operating_point": {"threshold": det.threshold, "debounce": det.debounce},
        "seed": seed,
        "rows": rows,
    }


def folds_study(
    recordings: Path, detectors: Path, baselines: Path | None = None, seed: int = 0, progress: bool = True
) -> dict[str, Any]:
    """Leave objects out: each fold's detector (``<detectors>/fold<k>/detector.safetensors``, trained by
    ``slipsense train --fold k``) replays only its held-out objects (``held_out.json``) under each
    condition on its clock, at its own operating point; the outcomes are pooled over folds. The
    non-learned baseline's folds (``baselines``, e.g. ``motion-energy``) the same way beside it."""
    data = Recordings.open(recordings, on_error="skip").labelled(whole_runs=False, progress=progress)
    recs, labels = list(data), dict(data.labels)

    def rng_for(obj: str, exp: int) -> np.random.Generator:  # the same frames dropped for every model
        return np.random.default_rng([seed, zlib.crc32(obj.encode()), exp])

    pooled: dict[str, dict[str, list]] = {c.name: {} for c in CONDITIONS}
    folds = []
    for name, root in (("detector", detectors), ("baseline", baselines)):
        for fold, held, det in fold_detectors(root) if root is not None else ():
            mine = [r for r in recs if r.object in held]
            outs = _replayed(det, mine, labels, rng_for, modes=("clock",), progress=progress)
            for cond in CONDITIONS:
                pooled[cond.name].setdefault(name, []).extend(outs[cond.name]["clock"])
            folds.append({"model": name, "fold": fold.name, "objects": held, "threshold": det.threshold})
    rows = [{"condition": c.name, **{m: _counts(o, c.fps) for m, o in pooled[c.name].items()}} for c in CONDITIONS]
    trained_by = [trained_by_command(root) for root in (detectors, baselines) if root is not None]
    return {
        "recordings": portable_path(recordings),
        "seed": seed,
        "folds": folds,
        "rows": rows,
        "trained_by": trained_by,
    }


def trained_by_command(folds: Path) -> str:
    """The command that trained fold ``k`` of ``folds`` (as its first fold's checkpoint keeps it), for any k."""
    command = read_info(sorted(p for p in Path(folds).glob("fold*") if p.is_dir())[0] / "detector.safetensors")
    command = (command.get("data") or {}).get("command") or "?"
    command = re.sub(r"--fold \d+", "--fold K", command)
    return re.sub(r"--out \S+", f"--out {portable_path(folds)}/foldK", command)


def table(doc: dict[str, Any]) -> str:
    """The study as a Markdown table: slips warned in time and held grasps alarming, with and without
    the detector's clock."""
    lines = [
        "| the same runs | slips warned in time, detector's clock | held grasps alarming | "
        "slips warned in time, every frame one 40 ms step | held grasps alarming |",
        "|---|---:|---:|---:|---:|",
    ]
    for r in doc["rows"]:
        c, p = r["clock"], r["plain"]
        lines.append(
            f"| {r['condition']} | {c['warned']} of {c['slip_runs']} | {c['false_positive_grasps']} of "
            f"{c['held_runs']} | {p['warned']} of {p['slip_runs']} | {p['false_positive_grasps']} of {p['held_runs']} |"
        )
    return "\n".join(lines) + "\n"


def lift_study(lift: Path, progress: bool = True) -> list[dict[str, Any]]:
    """The shipped ``gelsight-lift`` detector on that data set as recorded (30 frames/s) and as a
    sensor at half its rate would have taken it (:func:`studies.grasp.derive.slower_frame_folders`),
    judged per grasp: slipped grasps caught and held grasps alarming at its operating point, and the
    accuracy with each object's threshold chosen on the other objects (95% range over objects)."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        half = Path(tmp) / "half"
        slower_frame_folders(lift, half, every=2)
        for name, root in (("as recorded (30 frames/s)", lift), ("frames taken at 15 per second", half)):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the detector's own objects: said in the report's text
                ev = judge(None, root, progress=progress)
            m = ev.grasp_measure()["detector"]
            slipped = np.array([r.slipped for r in ev.runs], bool)
            alarmed = ev.peak_scores() >= ev.threshold
            rows.append(
                {
                    "condition": name,
                    "slipped": int(slipped.sum()),
                    "caught": int(alarmed[slipped].sum()),
                    "held": int((~slipped).sum()),
                    "held_alarming": int(alarmed[~slipped].sum()),
                    "leave_objects_out_accuracy": m["leave_objects_out"]["accuracy"],
                }
            )
    return rows


def write(doc: dict[str, Any], out: Path, command: str) -> list[Path]:
    """``rates.json`` and ``README.md`` (the table, the command) into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    doc = {**doc, "command": command}
    atomic.write_text(out / "rates.json", json.dumps(doc, indent=1))
    text = (
        "# The shipped detector at other frame rates\n\n"
        f"Command: `{command}`  \n{provenance()}\n\n"
        f"Detector `{doc['checkpoint']}` at its operating point (threshold "
        f"{doc['operating_point']['threshold']:g}, debounce {doc['operating_point']['debounce']}), every run of "
        f"`{doc['recordings']}` replayed from its first frame, judged per grasp (in time: the first alarm at most "
        "2 s before the moment of slip). The detector was trained on these runs: the change between rows is what "
        "counts, not the level.\n\n" + table(doc)
    )
    atomic.write_text(out / "README.md", text)
    return [out / "rates.json", out / "README.md"]


def write_folds(doc: dict[str, Any], out: Path, command: str) -> list[Path]:
    """``rates.json`` and ``README.md`` (the leave-objects-out table, the command) into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    doc = {**doc, "command": command}
    atomic.write_text(out / "rates.json", json.dumps(doc, indent=1))
    thresholds = ", ".join(f"{f['threshold']:g}" for f in doc["folds"] if f["model"] == "detector")
    text = (
        "# The detector's recipe at other frame rates, on objects it never saw\n\n"
        f"Command: `{command}`  \n{provenance()}\n\n"
        + "".join(f"Folds trained by `{c}` for K = 0..4.  \n" for c in doc.get("trained_by", ()))
        + f"\nEach fold's detector (thresholds {thresholds}, chosen on its training objects) replays the runs of its "
        f"held-out objects of `{doc['recordings']}` from their first frame on its own clock (frames taken at "
        "another rate resampled to 25 frames/s), judged per grasp (in time: the first alarm at most 2 s before the "
        "moment of slip), pooled over the folds; the non-learned baseline's folds the same way. 95% Wilson "
        "intervals over runs. The last column: within 2 slips warned and 2 held grasps alarming of the 25 "
        "frames/s row.\n\n" + folds_table(doc)
    )
    if doc.get("lift"):
        text += (
            "\nThe shipped `gelsight-lift` detector (shear retention: a gate, a let-go time and a threshold, no "
            "learned filters; fitted on all of these objects, so only the thresholds of the last column are chosen "
            "without the object judged) on that data set and at half its rate:\n\n" + lift_table(doc["lift"])
        )
    atomic.write_text(out / "README.md", text)
    return [out / "rates.json", out / "README.md"]
