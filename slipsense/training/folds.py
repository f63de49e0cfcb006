"""Leave-objects-out, judged per grasp: the headline measure of a slip detector.

``slipsense train --cross-validate`` splits the objects into folds, and for each fold trains a detector on the
other folds' objects, chooses its operating point on those training objects only (inner folds),
and replays every run of the fold's objects from the first frame. The per-grasp outcomes and the
paper's clip decisions are pooled over the folds (each fold at its own operating point), with the
always-wiggle baseline and balanced accuracy beside every accuracy.

Each finished fold is written at once (``fold<k>.json``, atomically); a rerun with the same
config skips the folds already done, so a killed run continues where it stopped.
"""

from __future__ import annotations

import hashlib
import json
import math
import platform
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from slipsense import atomic
from slipsense.errors import ConfigError, InputError
from slipsense.plots import plot_tradeoff
from slipsense.measures import MEASURES, cell, measure_all, measure_lines, pergrasp, ranked, ranked_columns
from slipsense.measures import operating_points
from slipsense.measures.clips import clip_metrics, scores
from slipsense.parallel import run_jobs
from slipsense.recordings.runs import GraspRun, runs_summary
from slipsense.training.grasp_detector import (
    pooled_runs,
    sensor_rate,
    chosen_part,
    finish_training,
    fit_job,
    held_out_result,
    inner_traces,
    job_weight,
    judged_indices,
    object_folds_of,
    plan_training,
    traces_json,
)
from slipsense.training.grasps import GraspTrainConfig


def pool_folds(folds: Sequence[dict[str, Any]], runs: Sequence[pergrasp.RunTrace], fps: float) -> dict[str, Any]:
    """Pool the folds: per-grasp outcomes and clip decisions, each fold at its own operating point; and,
    for the trade-off curve, every fold's held-out runs (:func:`pooled_runs`, taken at ``fps``) at shared
    thresholds."""
    outcomes = [
        pergrasp.GraspOutcome(r["outcome"], r["first_alarm"], r["lead"], 0.0, 0) for f in folds for r in f["runs"]
    ]
    per_grasp = pergrasp.summarise(outcomes, fps)
    per_grasp["runs_alarming_at_rest"] = sum(f["per_grasp"]["runs_alarming_at_rest"] for f in folds)
    per_grasp["held_alarm_fraction"] = float(np.mean([f["per_grasp"]["held_alarm_fraction"] for f in folds]))
    per_grasp["intervals"] = pergrasp.bootstrap_rates([o.outcome for o in outcomes])
    decisions = np.concatenate([np.asarray(f["clip_probability"]) >= f["operating_point"]["threshold"] for f in folds])
    y = np.concatenate([np.asarray(f["clip_label"], dtype=np.int64) for f in folds])
    p_all = np.concatenate([np.asarray(f["clip_probability"], dtype=np.float64) for f in folds])
    debounce = int(np.median([f["operating_point"]["debounce"] for f in folds]))
    traces, moments, rests = zip(*((r.probability, r.moment_of_slip, r.rest) for r in runs))
    return {
        "per_grasp": per_grasp,
        "clips": clip_metrics(decisions.astype(np.float64), y, 0.5),
        "clips_at_half": clip_metrics(p_all, y, 0.5),
        "operating_points": [f["operating_point"] for f in folds],
        "curve": operating_points.table(
            traces, moments, operating_points.THRESHOLDS, (debounce,), rests=rests, fps=fps, intervals=2000
        ),
    }


def pool(run_dirs: list[Path]) -> dict:
    """Pool the held-out evaluations of a clip model's folds (each run folder's ``evaluation.json``,
    written by ``slipsense train``) from the summed confusion matrices: every held-out clip counts once."""
    folds, total, keys = [], np.zeros((2, 2), np.int64), ("accuracy", "precision", "recall", "f1")
    for run in run_dirs:
        path = Path(run) / "evaluation.json"
        if not path.is_file():
            raise InputError(path, "no evaluation.json (did the run finish?)")
        m = json.loads(path.read_text())
        total += np.asarray(m["confusion"], np.int64)
        counts = {k: m[k] for k in (*keys, "n_clips", "n_slip", "n_wiggle")}
        folds.append({"run": Path(run).name, "test_objects": m.get("test_objects"), **counts})
    pooled = {
        **scores(total),
        "n_clips": int(total.sum()),
        "n_slip": int(total[1].sum()),
        "n_wiggle": int(total[0].sum()),
        "confusion": total.tolist(),
    }
    mean = {k: float(np.mean([f[k] for f in folds])) for k in keys}
    return {"folds": folds, "pooled": pooled, "mean_over_folds": mean}


def _config_key(cfg: GraspTrainConfig, folds: int, runs: Sequence[GraspRun]) -> str:
    """What a finished fold depends on: the settings, the folds, every run's label and the code (a fold
    finished by other code is trained again, never reused)."""
    from slipsense.provenance import code_digest

    labels = sorted((r.object, r.experiment, r.slipped, r.moment_of_slip) for r in runs)
    cfg_text = {"cfg": cfg.to_dict(), "folds": folds, "labels": labels, "code": code_digest()}
    text = json.dumps(cfg_text, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def run_folds(
    runs: Sequence[GraspRun],
    labels: dict,
    cfg: GraspTrainConfig,
    out,
    folds: int = 5,
    meta: dict[str, Any] | None = None,
    progress: bool = True,
    echo=print,
    workers: int | None = None,
) -> dict[str, Any]:
    """Run (or resume) the leave-objects-out evaluation into ``out``; returns the pooled report.

    Every training of the folds not yet done (each fold's detector and its inner folds') goes to
    one pool of ``workers`` processes (default one per core, :mod:`slipsense.parallel`); a fold is
    written as soon as its trainings are finished. ``meta`` names the runs' ``sensor``: every time
    judged (the warning horizon, the leads) is read at its rate."""
    out = Path(out)
    fps = sensor_rate(meta, "the cross-validation's data")
    usable = [r for r in runs if r.usable]
    if any(r.whole and not r.extra for r in usable):
        raise ConfigError(
            "these grasps are labelled as a whole (no moment of slip): their leave-objects-out figures are "
            "`python -m studies grasp adaptation --recordings DIR` (slipped against held, intervals over objects)"
        )
    split = object_folds_of(usable, folds, cfg.folds_seed)
    key = _config_key(cfg, folds, usable)
    done: dict[int, dict[str, Any]] = {}
    for k in range(len(split)):
        prior = _load_fold(out / f"fold{k}.json", key)
        if prior is not None:
            done[k] = prior
            _echo_fold(echo, k, split[k], prior, resumed=True)
    plans = {k: plan_training(usable, held, cfg) for k, held in enumerate(split) if k not in done}
    jobs = [(k, j) for k, plan in plans.items() for j in plan]
    results: dict[int, dict[int, Any]] = {k: {} for k in plans}
    t0 = time.perf_counter()

    def finished(index: int, result: dict[str, Any]) -> None:
        k, _ = jobs[index]
        results[k][index] = result
        if len(results[k]) < len(plans[k]):
            return
        ordered = [results[k][i] for i in sorted(results[k])]
        _, history, op, probs = finish_training(usable, plans[k], ordered, cfg, fps=fps)
        jobs_kept, results_kept = chosen_part(plans[k], ordered, op)  # of the settings train.choose kept
        test = [usable[i] for i in plans[k][0].predict]
        inner = [usable[i] for i in judged_indices(usable, jobs_kept)] if len(jobs_kept) > 1 else []
        done[k] = {
            "config_key": key,
            "fold": k,
            "objects": sorted(split[k]),
            "operating_point": op,
            "history": history,
            **held_out_result(test, probs, op, labels, cfg.horizon, fps),
            # what chose the operating point, kept so another rule can be chosen on it later
            "inner": traces_json(inner, inner_traces(usable, jobs_kept, results_kept) if inner else []),
            "seconds": round(time.perf_counter() - t0, 1),  # since the pool started: folds share it
        }
        atomic.write_text(out / f"fold{k}.json", json.dumps(done[k]))
        _echo_fold(echo, k, split[k], done[k])

    run_jobs(
        fit_job,
        [j for _, j in jobs],
        (usable, cfg),
        workers,
        [job_weight(j, cfg) for _, j in jobs],
        on_done=finished,
        progress=progress,
        desc=f"{len(plans)} fold(s)",
        groups=[f"fold {k}" for k, _ in jobs],
    )
    results = [done[k] for k in range(len(split))]
    head = {
        **(meta or {}),  # the command and its whole configuration tree ("config")
        "train_config": cfg.to_dict(),
        "folds": folds,
        "data": runs_summary(runs),
        "machine": {"cpu": platform.processor() or platform.machine(), "python": platform.python_version()},
    }
    return _write_report(out, head, results, f"{cfg.model}: {folds} folds by object, pooled (labels: thresholds)")


def _write_report(out: Path, head: dict[str, Any], folds: list[dict[str, Any]], title: str) -> dict[str, Any]:
    """``head`` with the ``folds`` pooled, written into ``out`` as folds.json, README.md and
    tradeoff.png; returns the report."""
    fps = sensor_rate(head, "the cross-validation's data")
    horizon = head["train_config"]["horizon"]
    judged = pooled_runs(folds, fps, horizon)
    pooled = {**pool_folds(folds, judged.runs, fps), **measure_all(judged, pooled_measures())}
    report = {
        **head,
        "pooled": {k: v for k, v in pooled.items() if k != "curve"},
        "curve": pooled["curve"],
        "per_fold": [
            {
                **{k: f[k] for k in ("fold", "objects", "operating_point", "per_grasp", "clips", "seconds")},
                # every registered measure that ranks, on the fold's own held-out runs (the registry's value)
                "measures": ranked(measure_all(pooled_runs([f], fps, horizon))),
            }
            for f in folds
        ],
    }
    atomic.write_text(out / "folds.json", json.dumps(_json_safe(report), indent=1))
    atomic.write_text(out / "README.md", summary_markdown(report))
    plot_tradeoff(pooled["curve"], out / "tradeoff.png", title=title)
    return report


def pooled_measures() -> list[str]:
    """The registered measures a cross-validation report computes on its folds pooled."""
    return [k for k, m in MEASURES.items() if m.pools]


def _echo_fold(echo, k: int, held: Sequence[str], done: dict[str, Any], resumed: bool = False) -> None:
    g, c = done["per_grasp"], done["clips"]
    echo(
        f"fold {k} ({', '.join(held)}){' (done before)' if resumed else ''}: warned {g['warned']}/{g['slip_runs']}, "
        f"false-positive grasps {g['false_positive_grasps']}/{g['held_runs']}, clip F1 {c['f1']:.3f} at threshold "
        f"{done['operating_point']['threshold']:g} x{done['operating_point']['debounce']}, {done['seconds']} s"
    )


def _load_fold(path: Path, key: str) -> dict[str, Any] | None:
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and doc.get("config_key") == key else None


def _json_safe(x):
    if isinstance(x, float) and math.isnan(x):
        return None
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_json_safe(v) for v in x]
    return x


def _pct(v) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{100 * v:.1f}%"


def _rule(report: dict[str, Any]) -> str:
    k = report["train_config"].get("max_held_alarm")
    return "best score" if k is None else f"at most {100 * k:g}% of held grasps alarming"


def _interval_lines(g: dict[str, Any]) -> list[str]:
    ci = g.get("intervals")
    if not ci:
        return []

    def wilson(name: str) -> str:
        w = ci.get(f"{name}_wilson")
        return f" (Wilson {_pct(w[0])}-{_pct(w[1])})" if w else ""

    return [
        "",
        f"95% bootstrap intervals over runs ({ci['samples']} resamples): warned in time "
        f"{_pct(ci['warned_low'])}-{_pct(ci['warned_high'])}{wilson('warned')}, false-positive grasps "
        f"{_pct(ci['fp_low'])}-{_pct(ci['fp_high'])}{wilson('fp')}.",
    ]


def summary_markdown(report: dict[str, Any]) -> str:
    """The report as a short Markdown page: per-grasp and clip tables, per fold and pooled."""
    g, c = report["pooled"]["per_grasp"], report["pooled"]["clips"]
    cfg, d = report["train_config"], report["data"]
    fps = sensor_rate(report, "the cross-validation report")
    pooled = {k: v for k, v in report["pooled"].items() if k in pooled_measures()}
    others = measure_lines(pooled, {"horizon": cfg["horizon"], "fps": fps})
    one = "One finger: each camera of a run is a grasp of its own (a run's two cameras count twice)."
    also = "Every fold also trained on {} grasps of another data set (`data.also`: never held out or judged)."
    lines = [
        f"# {cfg['model']}: leave-objects-out, {report['folds']} folds, judged per grasp",
        "",
        f"Command: `{report.get('command', 'slipsense train --cross-validate')}`",
        "",
        f"Runs: {d['runs']}: {d['slip_with_moment']} slips with a moment of slip, {d['slip_without_moment']} slips "
        f"without one (left out; for the shared recordings reports/labels says why), {d['held']} that held. Horizon {cfg['horizon']} frames ({cfg['horizon'] / fps:g} s at {fps:g} frames/s); operating point "
        f"chosen per fold on its training objects only ({cfg['inner_folds']} inner folds; 0 = on the training "
        f"runs themselves; rule: {_rule(report)}).",
        *([also.format(d["also_runs"])] if d.get("also_runs") else []),
        *(["", one] if report.get("sensors_per_grasp") == 1 else []),
        "",
        "## Per grasp (pooled over folds, each fold at its own operating point)",
        "",
        "| slip runs | warned in time | premature | missed | median lead | runs that held | false-positive grasps "
        "| runs alarming at rest |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
        f"| {g['slip_runs']} | {g['warned']} ({_pct(g['warned_rate'])}) | {g['premature']} | {g['missed']} | "
        f"{g['median_lead_frames'] if g['median_lead_frames'] is not None else '-'} frames | {g['held_runs']} | "
        f"{g['false_positive_grasps']} ({_pct(g['false_positive_rate'])}) | {g['runs_alarming_at_rest']} |",
        *_interval_lines(g),
        "",
        "## Per clip (the paper's 5-frame clips, scored at their last frame)",
        "",
        "| threshold | clips | slip clips | accuracy | balanced accuracy | always-wiggle accuracy | precision | recall "
        "| F1 |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
        *[
            f"| {name} | {c['clips']} | {c['slip_clips']} | {_pct(c['accuracy'])} | {_pct(c['balanced_accuracy'])} | "
            f"{_pct(c['always_wiggle_accuracy'])} | {_pct(c['precision'])} | {_pct(c['recall'])} | {_pct(c['f1'])} |"
            for name, c in (("each fold's operating point", c), ("0.5", report["pooled"].get("clips_at_half")))
            if c is not None
        ],
        "",
        *(["## Pooled over folds, each at its own operating point", "", *others, ""] if others else []),
        "## Folds",
        "",
        "| fold | objects | threshold x debounce | warned | false-positive grasps | clip F1 | done after (s) |",
        "|---:|---|---:|---:|---:|---:|---:|",
    ]
    for f in report["per_fold"]:
        fg, op = f["per_grasp"], f["operating_point"]
        lines.append(
            f"| {f['fold']} | {', '.join(f['objects'])} | {op['threshold']:g} x{op['debounce']} | "
            f"{fg['warned']}/{fg['slip_runs']} | {fg['false_positive_grasps']}/{fg['held_runs']} | "
            f"{_pct(f['clips']['f1'])} | {f['seconds']} |"
        )
    lines += ["", *_measures_table(report), "![trade-off](tradeoff.png)", ""]
    return "\n".join(lines)


def _measures_table(report: dict[str, Any]) -> list[str]:
    """Every registered measure that ranks (:data:`~slipsense.measures.MEASURES`), fold by fold: the
    value each ranks detectors by, on the fold's held-out runs at its own operating point."""
    rows = [f.get("measures") or {} for f in report["per_fold"]]
    keys = ranked_columns(rows)
    if not keys:
        return []
    head = " | ".join(MEASURES[k].label + (" (lower is better)" if MEASURES[k].lower_is_better else "") for k in keys)
    lines = ["## Every registered measure, fold by fold", "", f"| fold | {head} |", "|---:|" + "---:|" * len(keys)]
    for f, row in zip(report["per_fold"], rows):
        lines.append(f"| {f['fold']} | " + " | ".join(cell(k, row.get(k, math.nan)) for k in keys) + " |")
    return [*lines, ""]
