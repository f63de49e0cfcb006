"""Which slips leave a trace before contact is lost: the precursor report (``python -m studies grasp precursors``).

A detector can only warn of a slip that shows in the frames before it. For every slip run with a
moment of slip ``m`` this measures simple signals of the gels (no model) in the ``window`` frames up
to ``m`` and asks two questions:

* **against its own grasp**: is the value above what the same run showed while it was wiggled and
  held (every ``window``-frame mean from ``grasp start + 25`` to ``m - 50``)? ``own_percentile`` is
  the fraction of those below it;
* **against grasps that held**: how many held runs show a value at least as large over the same
  frames (``held_fraction``)? A precursor no held grasp matches is one a detector could alarm on
  without false alarms.

A slip *stands out* on a signal when ``held_fraction <= 0.10`` and ``own_percentile >= 0.95`` (or
the slip came before any wiggle, leaving the held grasps as the only reference). The
signals, per frame, largest over the sensors (grey frames at the training size, contact strength
from the frame cache): ``motion`` (mean absolute change from the previous frame), ``change_1s``
(from 25 frames back), ``contact_fading`` (drop of contact strength over the last 10 frames,
relative to the run's strongest contact).
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from slipsense.measures import pergrasp
from slipsense.recordings.contact import rest_mask
from slipsense.recordings.runs import GraspRun

SIGNALS = ("motion", "change_1s", "contact_fading")
#: own-grasp percentile and held fraction a precursor must pass
OWN_PERCENTILE, HELD_FRACTION = 0.95, 0.10


def signals(run: GraspRun) -> dict[str, np.ndarray]:
    """``{name: (N,) float}`` per frame, largest over the run's sensors (NaN where undefined)."""
    g = run.gray.astype(np.float32)
    n = g.shape[1]

    def lagged(lag: int) -> np.ndarray:
        d = np.full(n, np.nan)
        if n > lag:
            d[lag:] = np.abs(g[:, lag:] - g[:, :-lag]).mean(axis=(2, 3)).max(axis=0)
        return d

    c = run.contact.astype(np.float64)
    peak = np.maximum(c.max(axis=1, keepdims=True), 1e-6)
    fading = np.full(n, np.nan)
    if n > 10:
        fading[10:] = ((c[:, :-10] - c[:, 10:]) / peak).max(axis=0)
    return {"motion": lagged(1), "change_1s": lagged(25), "contact_fading": fading}


def _window_mean(x: np.ndarray, end: int, window: int) -> float:
    part = x[max(0, end - window + 1) : end + 1]
    return float(np.nanmean(part)) if part.size and np.isfinite(part).any() else math.nan


def _grasp_start(run: GraspRun) -> int:
    touched = np.flatnonzero(~rest_mask(run.contact))
    touched = touched[touched >= pergrasp.STARTUP]
    return int(touched[0]) if touched.size else pergrasp.STARTUP


def precursor_table(runs: Sequence[GraspRun], window: int = 10) -> list[dict[str, Any]]:
    """One row per slip run with a moment: per signal its value before the loss, its percentile in
    the run's own grasp, the fraction of held runs as loud at the same frames, and whether it
    stands out (module notes)."""
    sig = {id(r): signals(r) for r in runs}
    held = [r for r in runs if not r.slipped]
    rows = []
    for r in runs:
        m = r.moment_of_slip
        if not r.slipped or m is None:
            continue
        start = _grasp_start(r)
        row: dict[str, Any] = {"object": r.object, "experiment": r.experiment, "moment_of_slip": m}
        row["wiggle_frames"] = max(0, m - 50 - (start + 25 + window))
        for name in SIGNALS:
            x = sig[id(r)][name]
            pre = _window_mean(x, m, window)
            own = [_window_mean(x, e, window) for e in range(start + 25 + window, m - 50)]
            own = [v for v in own if not math.isnan(v)]
            same = [_window_mean(sig[id(h)][name], m, window) for h in held if h.n_frames > m]
            same = [v for v in same if not math.isnan(v)]
            own_pct = float(np.mean([v < pre for v in own])) if own and not math.isnan(pre) else math.nan
            held_frac = float(np.mean([v >= pre for v in same])) if same and not math.isnan(pre) else math.nan
            row[name] = {
                "before_loss": pre,
                "own_percentile": own_pct,
                "held_fraction": held_frac,
                # a slip before any wiggle has only the held grasps to be compared with
                "stands_out": bool((math.isnan(own_pct) or own_pct >= OWN_PERCENTILE) and held_frac <= HELD_FRACTION),
            }
        row["any"] = any(row[name]["stands_out"] for name in SIGNALS)
        rows.append(row)
    return rows


def aligned_means(runs: Sequence[GraspRun], before: int = 60, after: int = 5) -> dict[str, Any]:
    """Each signal averaged over slip runs aligned at their moment (frames ``-before..after``), and
    over held runs at the same frames: ``{"frames", name: {"slip", "held"}}``."""
    offsets = np.arange(-before, after + 1)
    sig = {id(r): signals(r) for r in runs}
    slips = [r for r in runs if r.slipped and r.moment_of_slip is not None]
    held = [r for r in runs if not r.slipped]
    out: dict[str, Any] = {"frames": offsets.tolist()}
    for name in SIGNALS:
        s_rows, h_rows = [], []
        for r in slips:
            at = r.moment_of_slip + offsets
            x = sig[id(r)][name]
            s_rows.append(np.where((at >= 0) & (at < len(x)), x[np.clip(at, 0, len(x) - 1)], np.nan))
            for h in held:
                y = sig[id(h)][name]
                h_rows.append(np.where((at >= 0) & (at < len(y)), y[np.clip(at, 0, len(y) - 1)], np.nan))

        def mean(rows):
            if not rows:
                return []
            a = np.array(rows)
            ok = np.isfinite(a)
            return (np.where(ok, a, 0).sum(axis=0) / np.maximum(ok.sum(axis=0), 1)).tolist()

        out[name] = {"slip": mean(s_rows), "held": mean(h_rows)}
    return out


def summary(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """How many slips stand out on each signal, and on any; and the same among the slips that had a
    wiggle of their own before (compared with both references)."""
    own = [r for r in rows if r["wiggle_frames"] > 0]
    return {
        "slip_runs": len(rows),
        **{name: sum(r[name]["stands_out"] for r in rows) for name in SIGNALS},
        "any": sum(r["any"] for r in rows),
        "with_own_grasp": len(own),
        "any_with_own_grasp": sum(r["any"] for r in own),
    }


def write_report(rows, aligned, out, command: str = "", window: int = 10) -> None:
    """``precursors.json``, ``precursors.csv``, ``README.md`` and ``precursors.png`` into ``out``."""
    import csv
    import io
    import json
    from pathlib import Path

    from slipsense import atomic
    from slipsense.plots import _plt, save_figure

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    s = summary(rows)
    atomic.write_text(
        out / "precursors.json",
        json.dumps(
            {"command": command, "window": window, "summary": s, "runs": rows, "aligned": aligned},
            indent=1,
            default=float,
        ),
    )
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(
        ["object", "experiment", "moment_of_slip", "wiggle_frames"]
        + [f"{n}_{k}" for n in SIGNALS for k in ("own_percentile", "held_fraction", "stands_out")]
        + ["any"]
    )
    for r in rows:
        w.writerow(
            [r["object"], r["experiment"], r["moment_of_slip"], r["wiggle_frames"]]
            + [
                round(r[n][k], 3) if isinstance(r[n][k], float) else r[n][k]
                for n in SIGNALS
                for k in ("own_percentile", "held_fraction", "stands_out")
            ]
            + [r["any"]]
        )
    atomic.write_text(out / "precursors.csv", buf.getvalue())

    def cell(v):
        return "-" if isinstance(v, float) and math.isnan(v) else f"{v:.2f}"

    lines = [
        "# What precedes a slip: precursors in the frames before contact is lost",
        "",
        f"Command: `{command}`" if command else "",
        "",
        f"Per slip run, each signal's mean over the {window} frames up to the moment of slip, against the same run's "
        f"own grasp (percentile) and against the runs that held at the same frames (fraction as loud). A slip stands "
        f"out when at most {100 * HELD_FRACTION:g}% of held runs are as loud and its own percentile is >= "
        f"{OWN_PERCENTILE} (`-`: the slip came before any wiggle, the held runs are the only reference; "
        "`slipsense/evaluation/precursors.py`).",
        "",
        f"Slips standing out: motion {s['motion']}, change over 1 s {s['change_1s']}, contact fading "
        f"{s['contact_fading']}; on any signal **{s['any']} of {s['slip_runs']}**. Of the {s['with_own_grasp']} slips "
        f"that came after a wiggle of their own (compared with both references), {s['any_with_own_grasp']} stand out.",
        "",
        "| object | exp | moment | " + " | ".join(f"{n}: own pct / held frac" for n in SIGNALS) + " | stands out |",
        "|---|---:|---:|" + "---|" * len(SIGNALS) + "---|",
    ]
    for r in rows:
        cells = [
            f"{cell(r[n]['own_percentile'])} / {cell(r[n]['held_fraction'])}{' *' if r[n]['stands_out'] else ''}"
            for n in SIGNALS
        ]
        lines.append(
            f"| {r['object']} | {r['experiment']} | {r['moment_of_slip']} | "
            + " | ".join(cells)
            + f" | {'yes' if r['any'] else ''} |"
        )
    lines += ["", "![aligned signals](precursors.png)", ""]
    atomic.write_text(out / "README.md", "\n".join(lines))

    plt = _plt()
    fig, axes = plt.subplots(1, len(SIGNALS), figsize=(4 * len(SIGNALS), 3.2))
    for ax, name in zip(axes, SIGNALS):
        ax.plot(aligned["frames"], aligned[name]["slip"], label="slip runs, aligned at the moment")
        ax.plot(aligned["frames"], aligned[name]["held"], label="held runs, same frames")
        ax.axvline(0, color="gray", lw=0.8, ls=":")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("frames from the moment of slip")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    save_figure(fig, out / "precursors.png")
