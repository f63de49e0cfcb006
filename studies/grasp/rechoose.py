"""Research tools over finished leave-objects-out reports (``slipsense train --cross-validate``):
choose every fold's operating point again by another rule without training (:func:`rechoose`), and
put reports side by side with their intervals (:func:`compare_markdown`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from slipsense.errors import ConfigError, InputError
from slipsense.measures.clips import clip_metrics
from slipsense.measures.registry import startup_frames
from slipsense.training.grasp_detector import sensor_rate, stored_trace
from slipsense.measures import pergrasp
from slipsense.measures import promise
from slipsense.measures import operating_points
from slipsense.training.folds import _echo_fold, _pct, _rule, _write_report


def fold_at(fold: dict[str, Any], op: dict[str, Any], horizon: int, fps: float) -> dict[str, Any]:
    """A fold written by :func:`slipsense.training.folds.run_folds` (its runs taken at ``fps``; ``horizon`` in
    frames at it) scored again at another operating point ``op``, from
    the held-out traces and clip probabilities it keeps (6 decimals; fold files written before kept 4,
    where a threshold near 0.9999 can decide differently than the full-precision trace would)."""
    runs, outs = [], []
    for r in fold["runs"]:
        p = stored_trace(r)
        rest = np.zeros(len(p), dtype=bool)
        rest[r["rest"]] = True
        startup = int(op.get("startup", startup_frames(fps)))
        o = pergrasp.trace_outcome(
            p, op["threshold"], op["debounce"], r["moment_of_slip"], bool(r.get("slipped")), horizon, startup, rest
        )
        outs.append(o)
        runs.append({**r, "outcome": o.outcome, "first_alarm": o.first_alarm, "lead": o.lead})
    p = np.asarray(fold["clip_probability"], dtype=np.float64)
    y = np.asarray(fold["clip_label"], dtype=np.int64)
    return {
        **fold,
        "operating_point": op,
        "per_grasp": pergrasp.summarise(outs, fps),
        "clips": clip_metrics(p, y, op["threshold"]),
        "runs": runs,
    }


def rechoose(src, out, max_held_alarm: float | None, command: str = "", echo=print) -> dict[str, Any]:
    """The folds of ``src`` (a ``slipsense train --cross-validate`` report) with every fold's operating point
    chosen again by another rule, on the inner folds' traces its fold file keeps (training objects
    only), each fold scored again on its held-out traces, pooled, written into ``out`` (README.md,
    folds.json, tradeoff.png). No training: a rule is compared with another in seconds."""

    src, out = Path(src), Path(out)
    try:
        report = json.loads((src / "folds.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(src / "folds.json", f"is not a folds report ({exc})") from None
    cfg = {**report["train_config"], "max_held_alarm": max_held_alarm}
    fps = sensor_rate(report, f"{src / 'folds.json'}")
    folds, keys = [], set()
    for k in range(int(report["folds"])):
        path = src / f"fold{k}.json"
        fold = _read_fold(path)
        keys.add(fold.get("config_key"))
        if len(keys) > 1:  # a later run with other settings wrote some of the report's folds
            raise InputError(
                path, f"was written with other settings than the folds before it (config keys {sorted(map(str, keys))})"
            )
        probs = [stored_trace(r) for r in fold["inner"]]
        op = operating_points.choose_operating_point(
            probs,
            [r["moment_of_slip"] for r in fold["inner"]],
            horizon=cfg["horizon"],
            max_held_alarm=max_held_alarm,
            fps=fps,
        )
        op["chosen_on"] = f"{cfg['inner_folds']} inner folds of the training objects (kept traces)"
        folds.append(fold_at(fold, op, cfg["horizon"], fps))
        _echo_fold(echo, k, fold["objects"], folds[-1])
    head = {
        **{k: v for k, v in report.items() if k not in ("pooled", "curve", "per_fold")},
        "command": command or report.get("command", ""),
        "rechosen_from": str(src),
        "train_config": cfg,
    }
    out.mkdir(parents=True, exist_ok=True)
    return _write_report(out, head, folds, f"{cfg['model']}: folds pooled, {_rule(head)}")


def _read_fold(path: Path) -> dict[str, Any]:

    try:
        fold = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(path, f"cannot be read ({exc})") from None
    if not fold.get("inner"):
        raise InputError(path, "keeps no inner-fold traces (written before they were kept, or inner_folds=0)")
    return fold


def _count(n: int, of: int) -> str:
    """``n/of (low-high)``: a count with its 95% Wilson interval."""

    low, high = promise.wilson(n, of)
    return f"{n}/{of} ({_pct(low)}-{_pct(high)})"


def compare_markdown(reports: Sequence[str | Path], labels: Sequence[str] = (), command: str = "") -> str:
    """One row per ``slipsense train --cross-validate`` report (its pooled per-grasp outcome and clip F1 at 0.5),
    so that detectors judged the same way sit side by side; ``labels`` name the rows (default: the
    model, its operating-point rule and the report's folder)."""

    if labels and len(labels) != len(reports):
        raise ConfigError(f"{len(labels)} label(s) for {len(reports)} report(s): give one per report or none")
    lines = [
        "# Detectors side by side",
        "",
        *([f"Command: `{command}`", ""] if command else []),
        "## Per grasp, leave-objects-out",
        "",
        "Pooled over folds, each fold at the operating point chosen on its training objects only; 95% Wilson"
        " intervals over runs.",
        "",
        "| detector | rule | slips warned in time | premature | missed | false-positive grasps | median lead "
        "| runs alarming at rest | clip F1 at 0.5 | report |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for k, folder in enumerate(map(Path, reports)):
        try:
            report = json.loads((folder / "folds.json").read_text(encoding="utf-8"))
            g, cfg = report["pooled"]["per_grasp"], report["train_config"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise InputError(folder / "folds.json", f"is not a folds report ({exc})") from None

        one_finger = ", one finger" if report.get("sensors_per_grasp") == 1 else ""
        label = labels[k] if labels else f"`{cfg['model']}`{one_finger}"
        clips = (report["pooled"].get("clips_at_half") or {}).get("f1")
        lead = g.get("median_lead_frames")
        lines.append(
            f"| {label} | {_rule(report)} ({cfg['inner_folds']} inner folds) "
            f"| {_count(g['warned'], g['slip_runs'])} | {g['premature']} | {g['missed']} "
            f"| {_count(g['false_positive_grasps'], g['held_runs'])} "
            f"| {'-' if lead is None else f'{lead:g} frames'} | {g.get('runs_alarming_at_rest', '-')} | {_pct(clips)} "
            f"| `{folder.as_posix()}` |"
        )
    return "\n".join(lines) + "\n"
