"""`slipsense grasp compare`: folds reports side by side, each count with its Wilson interval."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from studies.__main__ import app


def _report(folder, warned, fp, rule=0.05, sensors=2):
    folder.mkdir()
    per_grasp = {
        "slip_runs": 51,
        "warned": warned,
        "premature": 1,
        "missed": 50 - warned,
        "median_lead_frames": 3.0,
        "held_runs": 85,
        "false_positive_grasps": fp,
    }
    report = {
        "sensors_per_grasp": sensors,
        "train_config": {"model": "motionnet", "max_held_alarm": rule, "inner_folds": 3},
        "pooled": {"per_grasp": per_grasp, "clips_at_half": {"f1": 0.5}},
    }
    (folder / "folds.json").write_text(json.dumps(report))
    return folder


def test_rows_side_by_side_with_intervals(tmp_path):
    on = _report(tmp_path / "always-on", 0, 85, rule=None)
    net = _report(tmp_path / "net", 11, 0, sensors=1)
    out = tmp_path / "compare.md"
    res = CliRunner().invoke(app, ["grasp", "compare", str(on), str(net), "--label", "always on", "--label", "net"])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(app, ["grasp", "compare", str(on), str(net), "--out", str(out)])
    assert res.exit_code == 0, res.output
    rows = [line for line in out.read_text().splitlines() if line.startswith("| `motionnet`")]
    assert len(rows) == 2
    assert "best score (3 inner folds) | 0/51 (0.0%-7.0%)" in rows[0] and "85/85 (95.7%-100.0%)" in rows[0]
    assert rows[1].startswith("| `motionnet`, one finger | at most 5% of held grasps alarming")
    assert "11/51 (12.5%-34.6%)" in rows[1] and "0/85 (0.0%-4.3%)" in rows[1]


def test_bad_reports_and_labels_are_refused(tmp_path):
    net = _report(tmp_path / "net", 11, 0)
    res = CliRunner().invoke(app, ["grasp", "compare", str(net), str(tmp_path)])
    assert res.exit_code == 2 and "folds.json" in res.output and "Traceback" not in res.output
    res = CliRunner().invoke(app, ["grasp", "compare", str(net), "--label", "a", "--label", "b"])
    assert res.exit_code == 2 and "2 label(s) for 1 report(s)" in res.output
