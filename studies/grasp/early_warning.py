"""The early-warning sweep: every run replayed through a detector and judged per grasp at a row of
alarm thresholds (slips warned in time, premature, missed; held grasps that alarmed), with the
trade-off plot. ``python -m studies grasp early-warning``."""

from __future__ import annotations

import csv
import io
import json
import math
import warnings
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

from slipsense import atomic
from slipsense.atomic import check_output_dir
from slipsense.checkpoint import read_info
from slipsense.paths import gelsight_recordings
from slipsense.errors import ConfigError, InputError
from slipsense.evaluation.judge import shipped_for
from slipsense.evaluation.replay import RunTrace, replay_recordings
from slipsense.plots import plot_tradeoff
from slipsense.measures import pergrasp
from slipsense.recordings.folders import camera_counts
from slipsense.recordings.recording_set import Recordings
from slipsense.recordings.label_csv import LABEL_COLUMNS, Key, _open_csv, _parse_int
from slipsense.recordings.types import VideoLabel
from slipsense.measures.registry import HORIZON_S, STARTUP_S, horizon_frames, startup_frames
from slipsense.sensors.spec import check_fps, sensor_of
from slipsense.streaming.detector import SlipDetector
from slipsense.watch import checkpoint_or_shipped

#: Default alarm thresholds of ``early-warning``.
DEFAULT_THRESHOLDS = "0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8,0.9"


def read_labels_csv(path: str | Path) -> dict[Key, VideoLabel]:
    """Read a file written by :func:`slipsense.recordings.label_csv.write_labels_csv` (``slipsense
    label``) back into ``{key: VideoLabel}``.

    Raises:
        InputError: naming the file and line, for missing columns or malformed values.
    """
    path = Path(path)
    header, rows = _open_csv(path)
    missing = [c for c in LABEL_COLUMNS if c not in header]
    if missing:
        raise InputError(path, f"line 1: missing column(s) {', '.join(missing)}")
    out: dict[Key, VideoLabel] = {}
    for line, row in rows:
        slipped = row["slipped"].lower()
        if slipped not in ("true", "false"):
            raise InputError(path, f"line {line}: slipped must be true or false, got {row['slipped']!r}")
        moment = row["moment_of_slip"]
        label = VideoLabel(
            object=row["object"],
            experiment=_parse_int(path, line, "experiment", row["experiment"]),
            camera=row["camera"],
            n_frames=_parse_int(path, line, "n_frames", row["n_frames"], lo=1),
            slipped=slipped == "true",
            moment_of_slip=None if moment == "" else _parse_int(path, line, "moment_of_slip", moment),
            contact_start=_parse_int(path, line, "contact_start", row["contact_start"]),
            contact_end=_parse_int(path, line, "contact_end", row["contact_end"]),
            source=row["source"] or "auto",
        )
        if label.key in out:
            raise InputError(path, f"line {line}: repeats {label.object} experiment {label.experiment} {label.camera}")
        out[label.key] = label
    return out


def parse_thresholds(text: str) -> list[float]:
    """``"0.1,0.5,0.9"`` -> ``[0.1, 0.5, 0.9]``; each in [0, 1], sorted, duplicates removed."""
    try:
        values = sorted({float(v) for v in text.split(",") if v.strip()})
    except ValueError:
        raise ConfigError(f"--thresholds must be comma-separated numbers in [0, 1], got {text!r}") from None
    if not values or any(not 0.0 <= v <= 1.0 for v in values):
        raise ConfigError(f"--thresholds must be comma-separated numbers in [0, 1], got {text!r}")
    return values


#: Columns of the early-warning CSV, in order.
EARLY_WARNING_COLUMNS = (
    "threshold",
    "debounce",
    "slip_runs",
    "warned",
    "premature",
    "missed",
    "warned_rate",
    "median_lead_frames",
    "median_lead_ms",
    "held_runs",
    "false_positive_grasps",
    "false_positive_rate",
    "held_alarm_fraction",
    "runs_alarming_at_rest",
    "score",
)


def early_warning_table(
    runs: Sequence[RunTrace],
    thresholds: Sequence[float],
    debounce: int = 1,
    horizon: int | None = None,
    fps: float | None = None,
) -> list[dict[str, Any]]:
    """One row (:data:`EARLY_WARNING_COLUMNS`) per threshold, pooled over ``runs``; ``horizon``: frames
    at the detector's rate (None: :data:`~slipsense.measures.registry.HORIZON_S` at it); ``fps``: the rate
    the leads count at (None: each run's own)."""
    rates = fps if fps is not None else [r.fps for r in runs]
    return [
        {
            "threshold": float(th),
            "debounce": int(debounce),
            **pergrasp.summarise([r.outcome(th, debounce, horizon) for r in runs], rates),
        }
        for th in thresholds
    ]


def write_early_warning(
    runs: Sequence[RunTrace],
    thresholds: Sequence[float],
    out_dir: str | Path,
    debounce: int = 1,
    horizon: int | None = None,
    fps: float | None = None,
    meta: Mapping[str, Any] | None = None,
) -> dict[str, Path]:
    """Write ``early_warning.csv``, ``early_warning.json`` (table, definitions, every run's outcome
    per threshold and its trace) and ``early_warning.png`` (slips warned in time against grasps
    that held yet alarmed, one point per threshold) into ``out_dir``."""
    out_dir = Path(out_dir)
    rows = early_warning_table(runs, thresholds, debounce, horizon, fps)
    model_fps = runs[0].model_fps if runs else None  # the horizon and start-up count the detector's frames
    if horizon is None and model_fps:
        horizon = horizon_frames(model_fps)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=EARLY_WARNING_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
    paths = {
        "csv": out_dir / "early_warning.csv",
        "json": out_dir / "early_warning.json",
        "png": out_dir / "early_warning.png",
    }
    atomic.write_text(paths["csv"], buf.getvalue())
    doc = {
        **(dict(meta) if meta else {}),
        "fps": fps if fps is not None else (runs[0].fps if runs else None),
        "horizon_frames": horizon,
        "horizon_s": horizon / model_fps if horizon is not None and model_fps else None,
        "debounce": debounce,
        "startup_frames": startup_frames(model_fps) if model_fps else None,
        "startup_s": STARTUP_S,
        "thresholds": [float(t) for t in thresholds],
        "definitions": {
            "warned": "slip run whose first alarm after the start-up falls in moment-horizon..moment",
            "premature": "slip run whose first alarm comes before moment-horizon (a false alarm)",
            "missed": "slip run without an alarm up to the moment",
            "false_positive_grasps": "runs that held yet alarmed at any frame after the start-up",
            "runs_alarming_at_rest": "runs with an alarm while no gel was touched",
            "score": "warned_rate - false_positive_rate",
        },
        "table": [_json_safe(r) for r in rows],
        "runs": [
            {
                "object": r.object,
                "experiment": r.experiment,
                "slipped": r.slipped,
                "moment_of_slip": r.moment_of_slip,
                "n_frames": r.n_frames,
                "outcome": {f"{t:g}": r.outcome(t, debounce, horizon).outcome for t in thresholds},
                "first_alarm": {f"{t:g}": r.outcome(t, debounce, horizon).first_alarm for t in thresholds},
                "probability": [None if math.isnan(p) else round(float(p), 5) for p in r.probability],
            }
            for r in runs
        ],
    }
    atomic.write_text(paths["json"], json.dumps(doc, indent=1))
    plot_tradeoff(rows, paths["png"])
    return paths


def _json_safe(row: Mapping[str, Any]) -> dict[str, Any]:
    return {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()}


def run_early_warning(
    checkpoint: Optional[Path],
    recordings: Optional[Path],
    out: Path,
    thresholds: str | Sequence[float] = DEFAULT_THRESHOLDS,
    labels: Optional[Path] = None,
    combine: str | None = None,
    backend: str = "torch",
    limit: Optional[int] = None,
    fps: float | None = None,
    on_error: str = "raise",
    progress: bool = True,
    dtype: str = "float32",
    horizon: float = HORIZON_S,
    debounce: Optional[int] = None,
    overrides: Optional[Path] = None,
) -> str:
    """The ``early-warning`` command as a function; returns the summary text it prints."""
    ths = parse_thresholds(thresholds) if isinstance(thresholds, str) else [float(t) for t in thresholds]
    if limit is not None and limit < 1:
        raise ConfigError(f"--limit must be a positive integer, got {limit}")
    if fps is not None:
        check_fps(fps, "--fps")
    if isinstance(horizon, bool) or not isinstance(horizon, (int, float)) or not 0 < horizon <= 3600:
        raise ConfigError(f"--horizon must be a time in seconds, above 0 and at most 3600, got {horizon!r}")
    check_output_dir(out, "--out")
    root = Path(recordings) if recordings else gelsight_recordings()
    if checkpoint is None:
        checkpoint = shipped_for(root)  # one camera per grasp: the one-finger detector
    ckpt = checkpoint_or_shipped(checkpoint)
    info = read_info(ckpt)
    data = Recordings.open(root, sensor_of(info, ckpt), on_error)
    recs = data.listed
    if all(r.per_grasp for r in recs):
        raise InputError(
            root, "grasps labelled as a whole have no moment of slip to warn before: judge them with slipsense evaluate"
        )
    counts = camera_counts(recs)
    if len(counts) != 1:
        raise InputError(root, f"runs hold different numbers of camera videos ({counts}); early warning needs the same")
    if labels is not None:
        lab = read_labels_csv(labels)
    else:
        first = sorted({(r.object, r.experiment) for r in recs})[:limit] if limit is not None else None
        todo = [r for r in recs if first is None or (r.object, r.experiment) in first]
        lab = data.only(todo).labelled(overrides, whole_runs=False, progress=progress).labels
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a checkpoint without a threshold: the table covers thresholds anyway
        fixed = info["model_config"].get("sensors")  # a model trained on so many fingers
        det = SlipDetector.from_checkpoint(
            ckpt, sensors=fixed or counts[0], combine=combine, backend=backend, dtype=dtype, debounce=debounce
        )
    if det.threshold not in ths:
        ths = sorted(ths + [det.threshold])
    try:
        runs = replay_recordings(det, data, lab, progress=progress, limit=limit)
    finally:
        det.close()
    meta = {
        "checkpoint": str(ckpt),
        "model": det.model_name,
        "recordings": str(root),
        "combine": det.combine if det.per_sensor else None,
        "backend": backend,
        "dtype": dtype,
        "sensors": det.sensors,
        "operating_point": {"threshold": det.threshold, "debounce": det.debounce},
    }
    seconds, horizon = horizon, horizon_frames(det.sensor.fps, horizon)  # the detector's frames
    paths = write_early_warning(runs, ths, out, debounce=det.debounce, horizon=horizon, fps=fps, meta=meta)
    rows = early_warning_table(runs, ths, det.debounce, horizon, fps)
    slips = sum(r.slipped for r in runs)
    lines = [
        f"{slips} slip runs, {len(runs) - slips} runs that held; horizon {seconds:g} s ({horizon} frames at "
        f"{det.sensor.fps:g} frames/s), debounce {det.debounce}",
        "threshold  warned in time  premature  missed  median lead (ms)  false-positive grasps  alarm at rest",
    ]
    for row in rows:
        mark = "  <- checkpoint's operating point" if row["threshold"] == det.threshold else ""
        lines.append(
            f"{row['threshold']:9.3g}  {row['warned']:>6d}/{row['slip_runs']:<7d} {row['premature']:>9d}  "
            f"{row['missed']:>6d}  {row['median_lead_ms']:16.0f}  {row['false_positive_grasps']:>11d}/"
            f"{row['held_runs']:<9d} {row['runs_alarming_at_rest']:>13d}{mark}"
        )
    lines.append("-> " + ", ".join(str(p) for p in paths.values()))
    return "\n".join(lines)
