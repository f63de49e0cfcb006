"""The shipped detector at other frame rates: every run of a recordings folder replayed as a sensor
at 15 or 12.5 frames/s, or one that drops 10% of its frame pairs, would have delivered it, judged per
grasp at the detector's operating point. Each condition twice: on the detector's clock (the frames
resampled to the rate it was trained at: what ``slipsense watch`` and ``evaluate`` do) and, as before
the clock, with every frame taken for one 40 ms step. ``python -m studies grasp rates``.
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

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
from slipsense.streaming.detector import SlipDetector


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
        k = np.arange(int(np.floor((n - 1) * fps / recorded)) + 1)
        return np.floor(k * recorded / fps + 1e-9).astype(np.int64), k / fps

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


def rates_study(recordings: Path, checkpoint: Path, seed: int = 0, progress: bool = True) -> dict[str, Any]:
    """Per-grasp outcomes of ``checkpoint`` on every run of ``recordings`` under each condition, on the
    detector's clock and without it. Slips without a moment of slip are left out (nothing to warn of)."""
    det = SlipDetector.from_checkpoint(checkpoint, backend="torch")
    product = det.cache_product
    recs = find_recordings(recordings, on_error="skip")
    labels = label_runs(recs, progress=progress)
    rng = np.random.default_rng(seed)
    outcomes: dict[str, dict[str, list]] = {c.name: {"clock": [], "plain": []} for c in CONDITIONS}
    for (obj, exp), cams in progress_bar(list(by_run(recs).items()), progress, "replaying runs"):
        labs = [labels[r.key] for r in cams if r.key in labels]
        if len(labs) != len(cams) or len(cams) != det.sensors:
            continue
        moment = next((lab.moment_of_slip for lab in labs if lab.moment_of_slip is not None), None)
        slipped = any(lab.slipped for lab in labs)
        if slipped and moment is None:
            continue
        cached = [video_products(r.path, ["contact", product]) for r in cams]
        gray, contact = np.stack([c[product] for c in cached]), np.stack([c["contact"] for c in cached])
        for cond in CONDITIONS:
            idx, stamps = cond.frames(gray.shape[1], rng)
            sub_moment = None if moment is None else int(np.searchsorted(idx, moment, side="right")) - 1
            rest = pergrasp.rest_mask(contact[:, idx])
            for mode, trace in (
                ("clock", det.replay_cached(gray[:, idx], stamps=stamps)),
                ("plain", det.replay_cached(gray[:, idx])),
            ):
                run = RunTrace(obj, exp, slipped, sub_moment, len(idx), trace.probability, rest, (), cond.fps)
                outcomes[cond.name][mode].append(run.outcome(det.threshold, det.debounce))
    det.close()
    rows = []
    for cond in CONDITIONS:
        row: dict[str, Any] = {"condition": cond.name}
        for mode, outs in outcomes[cond.name].items():
            s = pergrasp.summarise(outs)
            row[mode] = {k: s[k] for k in ("slip_runs", "warned", "premature", "missed", "held_runs")}
            row[mode]["false_positive_grasps"] = s["false_positive_grasps"]
        rows.append(row)
    return {
        "checkpoint": Path(checkpoint).name,
        "recordings": portable_path(recordings),
        "operating_point": {"threshold": det.threshold, "debounce": det.debounce},
        "seed": seed,
        "rows": rows,
    }


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


def provenance() -> str:
    """Commit, machine and date of a report, in one line."""
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    except OSError:
        commit = ""
    machine = f"{platform.system()} {platform.machine()}, {os.cpu_count()} cores"
    return f"Commit {commit or 'unknown'}, {machine}, {datetime.date.today().isoformat()}."


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
