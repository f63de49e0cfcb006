"""``python -m studies.pages``: the measured figures of README.md and docs/*.md, written from the reports.

A page marks each generated block::

    <!-- figures:NAME -->
    ...written by this module from the report files named in FIGURES[NAME]...
    <!-- /figures:NAME -->

``python -m studies.pages`` rewrites every block from its reports; ``python -m studies.pages --check``
changes nothing and exits 1 listing each page and figure whose text disagrees with its reports (or
names a figure this module does not know, or whose report is missing). ``tests/test_pages.py`` runs
the check, so a page cannot drift from its report unnoticed.

The reports are JSON (``folds.json``, ``adaptation.json``, ``precursors.json``, ``provenance.json``)
and CSV (the experiments' tables), the pipeline YAML (``dvc.yaml``, read with PyYAML); nothing here
imports slipsense, so the check runs anywhere the project's dependencies are installed.
Paths are relative to the project root (the folder holding README.md).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

ROOT = Path(__file__).resolve().parent.parent

_BLOCK = re.compile(r"<!-- figures:(?P<name>[\w.-]+) -->\n(?P<body>.*?)<!-- /figures:(?P=name) -->", re.S)
_OPEN = re.compile(r"<!-- figures:([\w.-]+) -->")


# ---------------------------------------------------------------------------------------- reading


def _json(root: Path, path: str) -> dict:
    return json.loads((root / path).read_text(encoding="utf-8"))


def _csv(root: Path, path: str) -> list[dict]:
    with open(root / path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def wilson(k: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """95% Wilson score interval of k successes in n trials."""
    if n == 0:
        return 0.0, 1.0
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def _pct(x: float) -> str:
    return f"{100 * x:.1f}%"


def _count(k: int, n: int) -> str:
    low, high = wilson(k, n)
    return f"{k}/{n} ({_pct(low)}-{_pct(high)})"


def _table(header: list[str], rows: list[list[str]], align: list[str]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(a for a in align) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------- figures


@dataclass(frozen=True)
class Figure:
    """One generated block: the report files it reads and the function writing its Markdown."""

    reports: tuple[str, ...]
    write: Callable[[Path], str]
    #: its writer says of each row whose report is missing that it is still to be made
    rows_pending: bool = False


_GRASP_ROWS = (
    ("`motionnet` (shipped), both fingers", "reports/grasp-motionnet-k5"),
    ("`motionnet-gelsight-1` recipe, one finger (each camera a grasp)", "reports/grasp-motionnet-1sensor-k5"),
    ("`motion-energy` (non-learned baseline)", "reports/grasp-motion-energy"),
    ("`slip-velocity` (the footprint's speed over the gel)", "reports/grasp-slip-velocity"),
)

_SEED_ROWS = (
    ("seed 0", "reports/grasp-motionnet-k5"),
    ("seed 1", "reports/grasp-motionnet-seed1"),
    ("seed 2", "reports/grasp-motionnet-seed2"),
)


def _pooled(root: Path, report: str) -> dict:
    data = _json(root, f"{report}/folds.json")
    pooled = data["pooled"]
    return {
        "grasp": pooled["per_grasp"],
        # reports written before the rule was recorded chose by the best score, the only rule then
        "rule": pooled["operating_points"][0].get("rule", "best score"),
        "inner": data["train_config"].get("inner_folds"),
        "f1": pooled["clips_at_half"]["f1"],
        "folds": data.get("folds"),
        "per_hour": pooled.get("false_alarms_per_hour"),  # reports pooled before that measure have none
    }


def _per_hour(p: dict, sentence: bool = False) -> str:
    """False alarms per hour of holding with its 95% range (``slipsense.measures.holding``)."""
    h = p.get("per_hour")
    if not h:
        return "" if sentence else "-"
    v, (lo, hi) = h["per_hour"]["value"], h["per_hour"]["interval"]
    text = f"{v:.0f} ({lo:.0f}-{hi:.0f})" if lo is not None else f"{v:.0f}"
    if not h.get("enough", True):  # the measure's own rule: no rate over seconds of contact
        minutes, least = 60 * h["hours"], h["minimum_minutes"]
        text = f"not stated ({h['false_alarms']} in {minutes:.1f} minutes of contact, under {least:g})"
    return f"; false alarms per hour of holding: {text}" if sentence else text


def _holding(p: dict) -> str:
    """False alarms per hour of holding in a sentence, with the contact it rests on."""
    h = p["per_hour"]
    if not h:
        return "false alarms per hour of holding: not in this report (made before that measure)"
    return (
        f"false alarms per hour of holding: {_per_hour(p)}, {h['false_alarms']} in "
        f"{60 * h['hours']:.1f} minutes of contact"
    )


def _rule(p: dict) -> str:
    rule = "best score" if p["rule"].startswith("best") else p["rule"]
    return f"{rule} ({p['inner']} inner folds)"


def _lead(g: dict) -> str:
    return "-" if g.get("median_lead_ms") is None else f"{g['median_lead_ms']:.0f} ms"


def per_grasp(root: Path) -> str:
    rows = []
    for label, report in _GRASP_ROWS:
        p = _pooled(root, report)
        g = p["grasp"]
        rows.append(
            [
                label,
                _rule(p),
                _count(g["warned"], g["slip_runs"]),
                str(g["premature"]),
                str(g["missed"]),
                _count(g["false_positive_grasps"], g["held_runs"]),
                _lead(g),
                _per_hour(p),
                _pct(p["f1"]),
                f"`{report}`",
            ]
        )
    header = [
        "detector",
        "alarm rule",
        "slips warned in time",
        "premature",
        "missed",
        "false-positive grasps",
        "median lead",
        "false alarms per hour of holding",
        "clip F1 at 0.5",
        "report",
    ]
    note = (
        "Leave-objects-out, 5 folds by object, pooled; every run replayed from its first frame; each "
        "fold's alarm point chosen on its training objects only; 95% Wilson intervals over runs.\n\n"
    )
    return note + _table(header, rows, ["---", "---", "---:", "---:", "---:", "---:", "---:", "---:", "---:", "---"])


def seed_spread(root: Path) -> str:
    rows = []
    for label, report in _SEED_ROWS:
        if not (root / report).exists():
            rows.append([label, _NOT_YET, "", "", f"`{report}`"])
            continue
        g = _pooled(root, report)["grasp"]
        rows.append(
            [
                label,
                _count(g["warned"], g["slip_runs"]),
                str(g["premature"]),
                _count(g["false_positive_grasps"], g["held_runs"]),
                f"`{report}`",
            ]
        )
    header = ["training seed", "slips warned in time", "premature", "false-positive grasps", "report"]
    return _table(header, rows, ["---", "---:", "---:", "---:", "---"])


def precursors(root: Path) -> str:
    s = _json(root, "reports/precursors/precursors.json")["summary"]
    rows = [
        ["any of the three signals", f"{s['any']} of {s['slip_runs']}"],
        ["motion (frame to frame)", f"{s['motion']} of {s['slip_runs']}"],
        ["change over 1 s", f"{s['change_1s']} of {s['slip_runs']}"],
        ["contact fading", f"{s['contact_fading']} of {s['slip_runs']}"],
        ["against held grasps and the run's own wiggle", f"{s['any_with_own_grasp']} of {s['with_own_grasp']}"],
    ]
    return _table(["slips that stand out in the 10 frames before contact is lost, on", "runs"], rows, ["---", "---:"])


_ADAPTATION_ROWS = (
    ("shipped one-finger detector, as is", "as is"),
    ("the same, recalibrated on the other objects (`slipsense calibrate`)", "recalibrated"),
    ("the same, fine-tuned on all the other objects' grasps", "fine-tuned, all grasps"),
    ("shear retention (`shear-retention-gelsight-lift`)", "shear retention"),
    ("slip velocity (`slip-velocity`: the footprint's speed over the gel)", "slip velocity"),
    ("best non-learned baseline (difference to the first frame in contact)", "baseline: difference_to_contact"),
)


def _interval(v: dict, percent: bool = True) -> str:
    low, high = v["interval"]
    if percent:
        return f"{_pct(v['value'])} [{_pct(low)}-{_pct(high)}]"
    return f"{v['value']:.3f} [{low:.2f}-{high:.2f}]"


def adaptation(root: Path) -> str:
    data = _json(root, "reports/adaptation/adaptation.json")
    by_name = {r["row"]: r for r in data["rows"]}
    rows = []
    for label, prefix in _ADAPTATION_ROWS:
        r = next(v for k, v in by_name.items() if k.startswith(prefix))
        held = r["held_alarming"]
        rows.append(
            [
                label,
                _interval(r["operating_point"]["accuracy"]),
                _interval(r["roc_auc"], percent=False),
                f"{held} of {r['grasps'] - r['slipped']}",
            ]
        )
    note = (
        f"`gelsight-lift`: {data['grasps']} grasps of {len(data['objects'])} objects, each object held out "
        "in turn; 95% intervals over objects; report `reports/adaptation`.\n\n"
    )
    return note + _table(
        ["detector", "accuracy", "ROC AUC", "held grasps alarming"], rows, ["---", "---:", "---:", "---:"]
    )


_STNET_SIM = (
    ("seed 0", "reports/stnet-sim-seed0"),
    ("seed 1", "reports/stnet-sim-seed1"),
    ("seed 2", "reports/stnet-sim-seed2"),
)


def stnet_sim(root: Path) -> str:
    rows = []
    for label, report in _STNET_SIM:
        if not (root / report).exists():
            rows.append([label, "", _NOT_YET, "", "", f"`{report}`"])
            continue
        for r in _csv(root, f"{report}/stnet.csv"):
            rows.append(
                [
                    label,
                    r["model"],
                    _pct(float(r["precision"])),
                    _pct(float(r["recall"])),
                    _pct(float(r["f1"])),
                    f"`{report}`",
                ]
            )
    return _table(
        ["seeds", "model", "precision", "recall", "F1", "report"], rows, ["---", "---", "---:", "---:", "---:", "---"]
    )


def _frac(text: str) -> tuple[int, int]:
    k, n = text.split("/")
    return int(k), int(n)


def stnet_real(root: Path) -> str:
    totals: dict[str, list[int]] = {}
    for k in range(5):
        for r in _csv(root, f"reports/stnet-real/fold{k}/stnet.csv"):
            w, ws = _frac(r["warned_in_time"])
            f, fs = _frac(r["false_positive_grasps"])
            t = totals.setdefault(r["model"], [0, 0, 0, 0, 0])
            for i, v in enumerate((w, ws, int(r["premature"]), f, fs)):
                t[i] += v
    rows = [[m, _count(t[0], t[1]), str(t[2]), _count(t[3], t[4])] for m, t in totals.items()]
    note = (
        "Every tracked marker on a 7 x 9 grid, 5 folds by object, per grasp; reports `reports/stnet-real/fold0..4`.\n\n"
    )
    return note + _table(
        ["model", "slips warned in time", "premature", "false-positive grasps"], rows, ["---", "---:", "---:", "---:"]
    )


def _promise(name: str) -> str:
    """A shipped detector's promise about held grasps, as every command prints it: read from the
    checkpoint (its one source), in the one wording of :func:`slipsense.measures.promise.promise_text`."""
    from slipsense.checkpoint import read_info
    from slipsense.measures.promise import promise_text
    from slipsense.resources import shipped_model

    return promise_text(read_info(shipped_model(name)).get("operating_point"))


#: a table cell whose report today's code has not made yet
_NOT_YET = "not measured by today's code yet: `dvc repro` (dvc.yaml) writes it"


def _readme_motionnet(root: Path) -> list[str]:
    p = _pooled(root, "reports/grasp-motionnet-k5")
    g = p["grasp"]
    return [
        "GelSight Mini, both fingers, unseen objects",
        "`motionnet` (shipped)",
        f"warns of {_count(g['warned'], g['slip_runs'])} slips in time (median lead {_lead(g)}), "
        f"{g['premature']} too early; {_holding(p)}. Its promise: {_promise('motionnet-gelsight')}",
    ]


def _readme_one_finger(root: Path) -> list[str]:
    p = _pooled(root, "reports/grasp-motionnet-1sensor-k5")
    g = p["grasp"]
    return [
        "GelSight Mini, one finger, unseen objects",
        "`motionnet-gelsight-1` (shipped)",
        f"{_count(g['warned'], g['slip_runs'])} camera-slips in time, {g['premature']} too early"
        f"{_per_hour(p, True)}. Its promise: {_promise('motionnet-gelsight-1')}",
    ]


def _readme_baseline(root: Path) -> list[str]:
    p = _pooled(root, "reports/grasp-motion-energy")
    g = p["grasp"]
    return [
        "the same, non-learned baseline",
        "`motion-energy`",
        f"{_count(g['warned'], g['slip_runs'])} in time, {g['premature']} too early; "
        f"{_count(g['false_positive_grasps'], g['held_runs'])} held grasps alarm{_per_hour(p, True)}",
    ]


def _readme_lift(root: Path) -> list[str]:
    lift = {r["row"]: r for r in _json(root, "reports/adaptation/adaptation.json")["rows"]}
    shear = next(v for k, v in lift.items() if k.startswith("shear retention"))
    return [
        "another lab's GelSight (`gelsight-lift`), unseen objects",
        "`shear-retention-gelsight-lift` (shipped)",
        f"right on {_interval(shear['operating_point']['accuracy'])} of grasps, ROC AUC "
        f"{_interval(shear['roc_auc'], percent=False)}. Its promise: {_promise('shear-retention-gelsight-lift')}",
    ]


def _readme_stnet(root: Path) -> list[str]:
    sim = {r["model"]: r for r in _csv(root, "reports/stnet-sim-seed0/stnet.csv")}
    return [
        "simulated binocular marker sensor, held-out sequences",
        "`stnet` (compact)",
        f"precision {_pct(float(sim['stnet']['precision']))}, recall {_pct(float(sim['stnet']['recall']))}, "
        f"F1 {_pct(float(sim['stnet']['f1']))}",
    ]


#: README's rows: (report, what the row says when it is missing, its writer)
_README_ROWS = (
    ("reports/grasp-motionnet-k5", ("GelSight Mini, both fingers, unseen objects", "`motionnet` (shipped)"), _readme_motionnet),
    ("reports/grasp-motionnet-1sensor-k5", ("GelSight Mini, one finger, unseen objects", "`motionnet-gelsight-1` (shipped)"), _readme_one_finger),
    ("reports/grasp-motion-energy", ("the same, non-learned baseline", "`motion-energy`"), _readme_baseline),
    ("reports/adaptation", ("another lab's GelSight (`gelsight-lift`), unseen objects", "`shear-retention-gelsight-lift` (shipped)"), _readme_lift),
    ("reports/stnet-sim-seed0", ("simulated binocular marker sensor, held-out sequences", "`stnet` (compact)"), _readme_stnet),
)  # fmt: skip


def readme(root: Path) -> str:
    """README's one table: a line per shipped detector (and the non-learned baseline), each from its
    report; the shipped detectors' promise about held grasps from the checkpoints themselves. A row
    whose report today's code has not made yet says so."""
    rows = []
    for report, (test, detector), write in _README_ROWS:
        if (root / report).exists():
            rows.append([*write(root), f"`{report}`"])
        else:
            rows.append(
                [test, detector, "not measured by today's code yet: `dvc repro` (dvc.yaml) writes it", f"`{report}`"]
            )
    return _table(
        ["sensor and test", "detector", "result (95% intervals)", "report"], rows, ["---", "---", "---", "---"]
    )


def rates(root: Path) -> str:
    """The shipped detector at other frame rates, on its clock and without it (one row a condition)."""
    rows = []
    for r in _json(root, "reports/rates/rates.json")["rows"]:
        c, p = r["clock"], r["plain"]
        rows.append(
            [
                r["condition"],
                f"{c['warned']} of {c['slip_runs']}",
                f"{c['false_positive_grasps']} of {c['held_runs']}",
                f"{p['warned']} of {p['slip_runs']}",
                f"{p['false_positive_grasps']} of {p['held_runs']}",
            ]
        )
    header = [
        "the same runs",
        "slips warned in time, on the detector's clock",
        "held grasps alarming",
        "slips warned in time, each frame taken as 40 ms",
        "held grasps alarming",
    ]
    return _table(header, rows, ["---", "---:", "---:", "---:", "---:"])


def ros(root: Path) -> str:
    """The ROS 2 node's latency in the loop, beside the detector's own push time."""
    doc = _json(root, "reports/ros/ros.json")
    lat, push = doc["latency_ms"], doc["push_ms"]
    rows = [
        ["publication to reading", f"{lat['p50']:.1f}", f"{lat['p99']:.1f}"],
        ["the detector's push", f"{push['p50']:.1f}", f"{push['p99']:.1f}"],
    ]
    lost = doc["frames"] - doc["readings"]
    table = _table(["two sensors at 25 frames/s", "p50 (ms)", "p99 (ms)"], rows, ["---", "---:", "---:"])
    return (
        table.rstrip("\n") + f"\n\n{doc['readings']} readings for {doc['frames']} frame pairs ({lost} without one).\n"
    )


def looks_table(rows: list[dict], bound: bool) -> str:
    """Looks of another unit of the sensor (one row a look); with ``bound``, whether each look keeps within
    2 slips warned and 2 held grasps alarming of the first row."""
    header = ["the same runs, as another unit sees them", "slips warned in time", "held grasps alarming"]
    cells = [
        [r["look"], f"{r['warned']} of {r['slip_runs']}", f"{r['false_positive_grasps']} of {r['held_runs']}"]
        for r in rows
    ]
    if not bound:
        return _table(header, cells, ["---", "---:", "---:"])
    first = rows[0]
    for r, c in zip(rows, cells):
        near = (
            abs(r["warned"] - first["warned"]) <= 2
            and abs(r["false_positive_grasps"] - first["false_positive_grasps"]) <= 2
        )
        c.append("yes" if near else "no")
    return _table([*header, "within 2 of as recorded"], cells, ["---", "---:", "---:", "---"])


def looks(root: Path, report: str = "reports/looks") -> str:
    """A detector as another unit of the sensor sees the runs: the shipped one on its own training runs
    (``reports/looks``), or the recipe's folds on their held-out objects, with the bound column."""
    doc = _json(root, f"{report}/looks.json")
    return looks_table(doc["rows"], bound="operating_point" not in doc)


# tables the report writers of studies/grasp share with the pages (one source for each figure)


def _with_interval(k: int, n: int, interval) -> str:
    lo, hi = interval
    return f"{k} of {n} ({100 * lo:.0f}-{100 * hi:.0f}%)"


def folds_table(doc: dict[str, Any]) -> str:
    """The leave-objects-out study as a Markdown table: each condition's slips warned in time and held
    grasps alarming (95% Wilson intervals), the detector beside the non-learned baseline."""
    base = any("baseline" in r for r in doc["rows"])
    head = "| the same runs, objects never trained on | slips warned in time | held grasps alarming |"
    head += " baseline: slips warned in time | baseline: held grasps alarming |" if base else ""
    lines = [head + " detector within 2 of 25 frames/s |", "|---|---:|---:|" + ("---:|---:|" if base else "") + "---|"]
    first = doc["rows"][0]["detector"]
    for r in doc["rows"]:
        cells = [r["condition"]]
        for name in ("detector", "baseline") if base else ("detector",):
            c = r[name]
            cells.append(_with_interval(c["warned"], c["slip_runs"], c["warned_interval"]))
            cells.append(_with_interval(c["false_positive_grasps"], c["held_runs"], c["false_positive_interval"]))
        d = r["detector"]
        near = (
            abs(d["warned"] - first["warned"]) <= 2
            and abs(d["false_positive_grasps"] - first["false_positive_grasps"]) <= 2
        )
        cells.append("yes" if near else "no")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def lift_table(rows: list[dict[str, Any]]) -> str:
    lines = [
        "| gelsight-lift grasps | slipped grasps caught | held grasps alarming | right, thresholds chosen on the other objects |",
        "|---|---:|---:|---:|",
    ]
    for r in rows:
        acc = r["leave_objects_out_accuracy"]
        lo, hi = acc["interval"]
        lines.append(
            f"| {r['condition']} | {r['caught']} of {r['slipped']} | {r['held_alarming']} of {r['held']} | "
            f"{100 * acc['value']:.0f}% ({100 * lo:.0f}-{100 * hi:.0f}%) |"
        )
    return "\n".join(lines) + "\n"


def adapt_table(doc: dict) -> str:
    """``adapt.json`` as a Markdown table: each candidate and baseline judged on objects it never saw,
    then the figure of what adapt keeps (the choice made without each object), the families it did not
    try and why, and its advice."""

    def rng(m) -> str:
        lo, hi = m["interval"]
        return f"{100 * m['value']:.0f}% ({100 * lo:.0f}-{100 * hi:.0f}%)"

    lines = [
        "| judged on objects it never saw | balanced accuracy (95% range) | right on (95% range) | ranking (ROC AUC) "
        "| slips caught | held grasps alarming |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for c in doc.get("candidates", []):
        m = c["measure"]
        op = m["operating_point"]
        lines.append(
            f"| {c['name']}{' (kept)' if c['name'] == doc['chosen'] else ''} | {rng(op['balanced_accuracy'])} | "
            f"{rng(op['accuracy'])} | {rng(m['roc_auc'])} | {c['slips_caught']} of {m['slipped']} | "
            f"{c['held_alarming']} of {m['grasps'] - m['slipped']} |"
        )
    for name, m in doc.get("baselines", {}).items():
        lo = m["leave_objects_out"]
        lines.append(
            f"| baseline: {name} | {rng(lo['balanced_accuracy'])} | {rng(lo['accuracy'])} | {rng(m['roc_auc'])} | | |"
        )
    kept = doc.get("kept")
    if kept:
        m = kept["measure"]
        op = m["operating_point"]
        lines.append(
            f"| **what adapt keeps, chosen without each object** | **{rng(op['balanced_accuracy'])}** | "
            f"**{rng(op['accuracy'])}** | | {kept['slips_caught']} of {m['slipped']} | "
            f"{kept['held_alarming']} of {m['grasps'] - m['slipped']} |"
        )
    notes = [f"Not tried: {', '.join(names)}: {why}." for why, names in _grouped(doc.get("not_tried", {})).items()]
    advice = doc.get("advice") or [doc["why"]]
    return (
        "\n".join(lines)
        + "\n\n"
        + "".join(n + "\n" for n in notes)
        + "\n"
        + " ".join(a[:1].upper() + a[1:].rstrip(".") + "." for a in advice)
        + "\n"
    )


def _grouped(reasons: dict[str, str]) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for name, why in reasons.items():
        out.setdefault(why, []).append(f"`{name}`")
    return out


def curve_table(doc: dict[str, Any]) -> str:
    """The curve as a Markdown table: a row per number of objects trained on."""
    lines = [
        f"`{doc['family']}` made from the grasps of k of the {doc['objects']} objects, judged on the others' grasps "
        f"(each k: up to 5 draws of objects, pooled; the range is the draws' lowest and highest).",
        "",
        "| objects trained on | grasps trained on (mean) | right on, other objects' grasps | balanced accuracy |",
        "|---:|---:|---:|---:|",
    ]
    for p in doc["points"]:
        accs = [r["accuracy"] for r in p["draws"]]
        lines.append(
            f"| {p['objects']} | {p['grasps']:.0f} | {100 * p['accuracy']:.0f}% ({100 * min(accs):.0f}-{100 * max(accs):.0f}%) "
            f"| {100 * p['balanced_accuracy']:.0f}% |"
        )
    return "\n".join(lines) + "\n"


#: The derived sensors adapt is measured on: (title, report folder).
ADAPT_REPORTS = (
    ("the shared wiggle grasps as one camera, 160 x 120 px, 12.5 frames/s", "reports/adapt-derived"),
    ("`gelsight-lift` resized to 300 x 400 px (frame folders, 30 frames/s)", "reports/adapt-lift-300x400"),
    ("`gelsight-lift` resized to 240 x 320 px (frame folders, 30 frames/s)", "reports/adapt-lift-240x320"),
)


def adapt_derived(root: Path) -> str:
    """slipsense adapt on every derived sensor: each candidate and baseline on objects it never saw,
    what it keeps; and the learning curve of the lift sensor's kept family."""
    parts = []
    for title, report in ADAPT_REPORTS:
        if not (root / report).exists():
            parts.append(f"**{title}**: {_NOT_YET} (`{report}`).\n")
            continue
        doc = _json(root, f"{report}/adapt.json")
        g = doc["kept"]["measure"] if doc.get("kept") else doc["candidates"][0]["measure"]
        parts.append(
            f"**{title}**: {g['grasps']} grasps of {g['objects']} objects; report `{report}`.\n\n" + adapt_table(doc)
        )
    curve = root / "reports/adapt-lift-300x400/learning-curve.json"
    if curve.is_file():
        parts.append(
            "**How many objects to record** (`reports/adapt-lift-300x400`): "
            + curve_table(json.loads(curve.read_text()))
        )
    return "\n".join(parts)


def rates_folds(root: Path, report: str = "reports/rates-folds") -> str:
    """A recipe's folds at other frame rates on their held-out objects, and gelsight-lift at half rate."""
    doc = _json(root, f"{report}/rates.json")
    return folds_table(doc) + ("\n" + lift_table(doc["lift"]) if doc.get("lift") else "")


def pipeline_stages(root: Path) -> list[dict[str, Any]]:
    """The stages of ``dvc.yaml``, ``foreach`` ones expanded: ``{"name", "cmd": [...], "outs": [...]}``
    (``${item}`` and the file's ``vars`` filled in, as DVC does)."""
    import yaml

    doc = yaml.safe_load((root / "dvc.yaml").read_text(encoding="utf-8"))
    values = {k: v for entry in doc.get("vars", []) for k, v in entry.items()}

    def fill(text: str, item: Any = None) -> str:
        text = text.replace("${item}", str(item)) if item is not None else text
        return re.sub(r"\$\{(\w+)\}", lambda m: str(values.get(m.group(1), m.group(0))), text)

    def one(name: str, body: dict, item: Any = None) -> dict[str, Any]:
        cmd = body["cmd"] if isinstance(body["cmd"], list) else [body["cmd"]]
        outs = [next(iter(o)) if isinstance(o, dict) else o for o in body.get("outs", [])]
        return {"name": name, "cmd": [fill(c, item) for c in cmd], "outs": [fill(o, item) for o in outs]}

    stages = []
    for name, body in doc["stages"].items():
        if "foreach" in body:
            items = body["foreach"]
            if isinstance(items, str):  # "${folds}": a list of the file's vars
                items = values[items.strip("${}")]
            stages += [one(f"{name}@{item}", body["do"], item) for item in items]
        else:
            stages.append(one(name, body))
    return stages


def stages(root: Path) -> str:
    """studies/README.md's table of the pipeline: every stage, its report, the command that writes the
    report and how long that command took on the machine its provenance names."""
    import yaml

    lock_path = root / "dvc.lock"
    ran = yaml.safe_load(lock_path.read_text(encoding="utf-8")).get("stages", {}) if lock_path.is_file() else {}
    rows = []
    for stage in pipeline_stages(root):
        made = [root / o / "provenance.json" for o in stage["outs"] if (root / o / "provenance.json").is_file()]
        prov = [json.loads(p.read_text(encoding="utf-8")) for p in made]
        when = (
            "; ".join(f"{p['seconds']:.0f} s at `{p['commit']}`, {p['machine'].split(', ')[-1]}" for p in prov)
            if prov
            else "made by `dvc repro` (a page: no time recorded)"
            if stage["name"] in ran
            else "not yet made by today's code"
        )
        steps = len(stage["cmd"])
        rows.append(
            [
                f"`{stage['name']}`",
                ", ".join(f"`{o}`" for o in stage["outs"]),
                f"`{stage['cmd'][-1]}`" + (f" (the last of {steps} commands)" if steps > 1 else ""),
                when,
            ]
        )
    table = _table(["stage", "report", "command", "the report's command took"], rows, ["---", "---", "---", "---"])
    cited = [root / r / "provenance.json" for r, _, _ in _README_ROWS]
    if all(p.is_file() for p in cited):
        total = sum(json.loads(p.read_text(encoding="utf-8"))["seconds"] for p in cited)
        table += f"\nThe {len(cited)} stages the README's table cites took {total / 60:.0f} minutes together.\n"
    return table


def slip_velocity(root: Path) -> str:
    """docs/gel-motion.md: how well the object's motion against the gel is measured, from ``reports/slip-velocity``."""
    d = _json(root, "reports/slip-velocity/velocity.json")
    sim, lift, mini = d["simulated"], d["lift"], d["mini"]
    e, a, k = sim["speed_error_mm_s"], sim["angle_error_deg"], sim["stick_share_error"]
    still = ", ".join(f"{p} {100 * v:.0f}%" for p, v in sim["below_slip_floor"].items() if v is not None)
    rows = [
        [
            "simulated marker sensor, gross slip at 2-8 mm/s (a seed the settings were not chosen on)",
            f"speed error {e['mean']:.2f} mm/s mean (95%: {e['p2.5']:.1f} to {e['p97.5']:.1f}); direction error "
            f"95% under {a['p97.5']:.0f} degrees; stick share off by {k['mean_abs']:.2f} on average",
        ],
        [
            f"simulated, nothing sliding: readings below the slip floor ({sim['slip_floor_mm_s']:g} mm/s)",
            still,
        ],
        [
            f"gelsight-lift, {lift['grasps']} grasps, each object left out",
            f"per-grasp peak ranks slipped above held at ROC AUC {lift['auc']:.2f} (the outside camera alone: "
            f"{lift['reference_auc']:.2f}); per frame Spearman {lift['spearman']:.2f} with the outside camera; "
            f"{lift['settled_frames_without_value']} of {lift['settled_frames_in_contact']} frames in contact after "
            "0.2 s without a value",
        ],
        [
            f"GelSight Mini, {mini['runs']} grasps (shipped settings, chosen on no Mini grasp)",
            f"held wiggles below the slipped grasps' last second at per-grasp ROC AUC {mini['auc']:.2f}",
        ],
    ]
    note = "From `reports/slip-velocity`, which also draws a GelSight Mini grasp's speed over time.\n"
    return note + "\n" + _table(["where", "how well"], rows, ["---", "---"])


FIGURES: dict[str, Figure] = {
    "readme": Figure(tuple(r for r, _, _ in _README_ROWS), readme, rows_pending=True),
    "per-grasp": Figure(tuple(r for _, r in _GRASP_ROWS), per_grasp),
    "seed-spread": Figure(tuple(r for _, r in _SEED_ROWS), seed_spread, rows_pending=True),
    "precursors": Figure(("reports/precursors",), precursors),
    "adaptation": Figure(("reports/adaptation",), adaptation),
    "stnet-sim": Figure(tuple(r for _, r in _STNET_SIM), stnet_sim, rows_pending=True),
    "stnet-real": Figure(tuple(f"reports/stnet-real/fold{k}" for k in range(5)), stnet_real),
    "rates": Figure(("reports/rates",), rates),
    "ros": Figure(("reports/ros",), ros),
    "looks": Figure(("reports/looks",), looks),
    "adapt": Figure(tuple(r for _, r in ADAPT_REPORTS), adapt_derived, rows_pending=True),
    "rates-folds": Figure(("reports/rates-folds",), rates_folds),
    "looks-folds": Figure(("reports/looks-folds",), lambda root: looks(root, "reports/looks-folds")),
    "stages": Figure(("dvc.yaml",), stages),
    "slip-velocity": Figure(("reports/slip-velocity",), slip_velocity),
}


# ---------------------------------------------------------------------------------------- pages


def pages(root: Path) -> list[Path]:
    """The pages that carry figures: README.md, docs/*.md and studies/README.md."""
    found = [root / "README.md", *sorted((root / "docs").glob("*.md")), root / "studies" / "README.md"]
    return [p for p in found if p.is_file()]


def _render(page: Path, root: Path, problems: list[str]) -> str:
    text = page.read_text(encoding="utf-8")
    rel = page.relative_to(root).as_posix()
    opened = _OPEN.findall(text)
    closed = [m.group("name") for m in _BLOCK.finditer(text)]
    for name in opened:
        if opened.count(name) != closed.count(name):
            problems.append(f"{rel}: figures:{name} has no matching <!-- /figures:{name} -->")

    def body(m: re.Match) -> str:
        name = m.group("name")
        figure = FIGURES.get(name)
        if figure is None:
            problems.append(f"{rel}: figures:{name} is not a known figure (studies/pages.py FIGURES)")
            return m.group(0)
        missing = [r for r in figure.reports if not (root / r).exists()]
        if missing and not figure.rows_pending:
            unknown = [r for r in missing if not _a_stage_writes(root, r)]
            if unknown:
                problems.append(
                    f"{rel}: figures:{name}: no report {', '.join(unknown)}, and no stage of dvc.yaml writes it"
                )
                return m.group(0)
            new = _pending(missing)
            if new != m.group("body"):
                problems.append(f"{rel}: figures:{name} does not say that {', '.join(missing)} is still to be made")
            return f"<!-- figures:{name} -->\n{new}<!-- /figures:{name} -->"
        try:
            new = figure.write(root)
        except (OSError, KeyError, ValueError, StopIteration) as e:
            problems.append(f"{rel}: figures:{name}: its report cannot be read ({type(e).__name__}: {e})")
            return m.group(0)
        if new != m.group("body"):
            problems.append(f"{rel}: figures:{name} disagrees with {', '.join(figure.reports)}")
        return f"<!-- figures:{name} -->\n{new}<!-- /figures:{name} -->"

    return _BLOCK.sub(body, text)


def _a_stage_writes(root: Path, report: str) -> bool:
    """Whether a stage of the DVC pipeline (``dvc.yaml``) has ``report`` as its output (a ``${item}``
    of a ``foreach`` stage stands for any value)."""
    try:
        text = (root / "dvc.yaml").read_text(encoding="utf-8")
    except OSError:
        return False
    outs = re.findall(r"^\s+- (reports/\S+):\s*$", text, re.M)
    return any(re.fullmatch(re.escape(o).replace(re.escape("${item}"), r"[\w.-]+"), report) for o in outs)


def _pending(missing: list[str]) -> str:
    """The block of a figure whose reports today's code has not made yet: what makes them."""
    names = ", ".join(f"`{r}`" for r in missing)
    return f"*Not measured by today's code yet: `dvc repro` (dvc.yaml) writes {names}.*\n"


def check(root: str | Path = ROOT) -> list[str]:
    """Every page and figure whose text disagrees with its reports (empty: all agree). Writes nothing."""
    root = Path(root)
    problems: list[str] = []
    for page in pages(root):
        _render(page, root, problems)
    return problems


def write(root: str | Path = ROOT) -> list[Path]:
    """Rewrite every figure block from its reports; returns the pages that changed. A block whose
    report cannot be read, or an unknown figure, is left as it is (``check`` names it)."""
    root = Path(root)
    changed = []
    for page in pages(root):
        new = _render(page, root, [])
        if new != page.read_text(encoding="utf-8"):
            page.write_text(new, encoding="utf-8")
            changed.append(page)
    return changed


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m studies.pages", description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="change nothing; exit 1 if a page disagrees")
    parser.add_argument("--root", default=str(ROOT), help="the project folder (default: this checkout)")
    args = parser.parse_args(argv)
    if args.check:
        problems = check(args.root)
        for line in problems:
            print(line)
        if problems:
            print("run `python -m studies.pages` to write the figures from the reports", file=sys.stderr)
        return 1 if problems else 0
    for page in write(args.root):
        print(f"wrote {page}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
