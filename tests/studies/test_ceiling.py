"""`slipsense grasp ceiling`: the exact bound on what any operating point could give a folds report's
traces, checked against detectors whose answer is known (perfect, always on, always off)."""

from __future__ import annotations

import json

import numpy as np
from typer.testing import CliRunner

from studies.__main__ import app
from studies.grasp.ceiling import held_out_traces, one_threshold, per_fold

N, HORIZON = 120, 20


def _run(moment, p):
    return {"moment_of_slip": moment, "probability": [None] * 10 + [float(v) for v in p[10:]]}


def _report(folder, kind):
    """Two folds of 3 slip and 3 held runs each; ``kind`` decides the detector's traces."""
    folder.mkdir()
    for k in range(2):
        runs = []
        for i in range(6):
            moment = 80 if i < 3 else None
            if kind == "perfect":
                p = np.full(N, 0.1)
                if moment is not None:
                    p[moment - 5 : moment + 1] = 0.9
            else:
                p = np.full(N, 1.0 if kind == "always-on" else 0.0)
            runs.append(_run(moment, p))
        (folder / f"fold{k}.json").write_text(json.dumps({"runs": runs}))
    (folder / "folds.json").write_text(json.dumps({"folds": 2, "train_config": {"horizon": HORIZON}}))
    return folder


def test_bounds_of_known_detectors(tmp_path):
    perfect = held_out_traces(_report(tmp_path / "perfect", "perfect"))
    assert one_threshold(perfect, 0)[1] == 6 and per_fold(perfect, 0) == (6, 0)
    on = held_out_traces(_report(tmp_path / "on", "always-on"))
    assert one_threshold(on, 6)[1:3] == (0, 0)  # warns of nothing in time at any threshold
    assert per_fold(on, 6) == (0, 0)
    off = held_out_traces(_report(tmp_path / "off", "always-off"))
    assert one_threshold(off, 0)[1:3] == (0, 0) and per_fold(off, 6) == (0, 0)


def test_command_prints_bounds_and_refuses_a_report_without_traces(tmp_path):
    report = _report(tmp_path / "r", "perfect")
    res = CliRunner().invoke(app, ["grasp", "ceiling", str(report), "--fp", "0"])
    assert res.exit_code == 0, res.output
    assert "one threshold 6 (0 premature), per fold 6 (0)" in res.output
    (report / "fold1.json").unlink()
    res = CliRunner().invoke(app, ["grasp", "ceiling", str(report)])
    assert res.exit_code == 2 and "fold files" in res.output and "Traceback" not in res.output
