"""The precursor report: a slip that shows motion before the loss stands out, one that shows none
does not, and the command writes its report."""

from __future__ import annotations

import json

import numpy as np
from typer.testing import CliRunner

from studies.__main__ import app
from studies.grasp.precursors import precursor_table, summary
from slipsense.recordings.runs import GraspRun


def _run(i, slipped, moment, loud_before, n=300, seed=0):
    rng = np.random.default_rng(seed + i)
    gray = rng.integers(100, 103, (2, n, 12, 16), dtype=np.uint8)  # calm gels, a little noise
    contact = np.zeros((2, n), np.float32)
    contact[:, 30 : (moment + 1 if moment else n)] = 20.0  # touched from frame 30 until the loss
    if loud_before:
        for t in range(moment - 8, moment + 1):
            gray[:, t, :, (3 * t) % 16] = 250  # a stripe sliding over the gel before the loss
    return GraspRun(f"obj{i}", 1, slipped, moment, gray, contact, ("camera_0", "camera_2"))


def test_a_loud_slip_stands_out_and_a_silent_one_does_not():
    runs = [_run(0, True, 250, True), _run(1, True, 250, False)] + [_run(k, False, None, False) for k in range(2, 12)]
    rows = precursor_table(runs, window=10)
    loud, silent = rows
    assert loud["motion"]["stands_out"] and loud["motion"]["held_fraction"] == 0.0
    assert loud["motion"]["own_percentile"] == 1.0 and loud["any"]
    assert not silent["motion"]["stands_out"] and silent["motion"]["held_fraction"] > 0.1
    assert summary(rows)["any"] >= 1 and summary(rows)["slip_runs"] == 2


def test_precursors_command_writes_its_report(tmp_path, grasp_recordings, cache):
    out = tmp_path / "prec"
    res = CliRunner().invoke(
        app, ["grasp", "precursors", "--out", str(out), "--recordings", str(grasp_recordings), "--no-progress"]
    )
    assert res.exit_code == 0, res.output
    doc = json.loads((out / "precursors.json").read_text())
    assert doc["summary"]["slip_runs"] == 4 and len(doc["runs"]) == 4
    assert (out / "precursors.png").is_file() and "stand out" in (out / "README.md").read_text()
