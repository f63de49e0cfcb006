"""`slipsense evaluate` prints words, not JSON: counts that match its --json file, no file unasked,
bad videos skipped with --on-error skip, and one frame count for a truncated video in every command."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from conftest import write_grasp_video
from slipsense.cli import app
from slipsense.evaluation.summary import summary_lines

runner = CliRunner()


def _truncate(path: Path) -> Path:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])  # the container still opens; its last frames are gone
    return path


@pytest.fixture
def three_runs(tmp_path) -> tuple[Path, Path]:
    """Three runs of two 48 x 64 cameras (two slip, one holds); one camera of the ``pen`` run truncated."""
    root = tmp_path / "rec"
    for i, (obj, slip) in enumerate([("cup", True), ("mug", False), ("pen", True)]):
        run = root / obj / "exp_num_1"
        for cam in (0, 2):
            write_grasp_video(run / f"camera_{cam}.avi", 60, (15, 40 if slip else 59), slip, seed=2 * i + cam)
        if slip:
            (run / "slip.txt").write_text("")
    return root, _truncate(root / "pen" / "exp_num_1" / "camera_2.avi")


def _json_lines(text: str) -> list[str]:
    out = []
    for line in text.splitlines():
        try:
            if isinstance(json.loads(line), dict):
                out.append(line)
        except ValueError:
            pass
    return out


def test_skip_leaves_the_truncated_video_out_names_it_and_judges_the_rest(tmp_path, cache, three_runs, monkeypatch):
    root, bad = three_runs
    monkeypatch.chdir(tmp_path)
    res = runner.invoke(app, ["evaluate", "--recordings", str(root), "--no-progress"])
    assert res.exit_code == 2 and str(bad) in res.stderr  # stops at the bad video by default
    # as a user runs it: the warnings reach stderr as the command line prints them
    args = [sys.executable, "-m", "slipsense.cli", "evaluate", "--recordings", str(root), "--on-error", "skip"]
    env = {**os.environ, "SLIPSENSE_CACHE": str(cache), "OMP_NUM_THREADS": "1"}
    res = subprocess.run([*args, "--no-progress"], capture_output=True, text=True, env=env, timeout=300)
    assert res.returncode == 0, res.stderr
    warned = [l for l in res.stderr.splitlines() if l.startswith("warning: ") and str(bad) in l]
    assert warned and "truncated" in warned[0] and "skipped" in warned[0], res.stderr
    assert "1 of 2 grasps slipped, 2 objects" in res.stdout  # cup and mug judged, pen left out
    assert not _json_lines(res.stdout), res.stdout
    assert not (tmp_path / "evaluation.json").exists() and not list(tmp_path.glob("*.png"))  # none unasked


def test_summary_counts_are_the_json_files_counts(tmp_path, cache, three_runs):
    root, bad = three_runs
    shutil.rmtree(root / "pen")
    # marked slipped, but never touched: no moment of slip in its video (counted apart, not lost)
    for cam in (0, 2):
        write_grasp_video(root / "box" / "exp_num_1" / f"camera_{cam}.avi", 60, (70, 80), False, seed=10 + cam)
    (root / "box" / "exp_num_1" / "slip.txt").write_text("")
    doc = tmp_path / "e.json"
    res = runner.invoke(app, ["evaluate", "--recordings", str(root), "--json", str(doc), "--no-progress"])
    assert res.exit_code == 0, res.output
    m = json.loads(doc.read_text())
    d, g = m["grasp_measure"]["detector"], m["per_grasp"]
    assert g["slips_without_moment"] == 1 and g["slip_runs"] == 1  # box: slipped, no moment found
    assert g["slip_runs"] + g["slips_without_moment"] == d["slipped"]  # every slipped grasp counted once
    assert g["slip_runs"] + g["slips_without_moment"] + g["held_runs"] == d["grasps"] == len(m["runs"])
    text = res.stdout
    assert f"{d['slipped']} of {d['grasps']} grasps slipped, {d['objects']} objects ({g['held_runs']} held)" in text
    early = re.search(
        r"on the (\d+) slipped grasps? whose .*?: (\d+) warned in time .*?, (\d+) too early .*?, (\d+) missed", text
    )
    assert early, text
    assert [int(v) for v in early.groups()] == [g["slip_runs"], g["warned"], g["premature"], g["missed"]]
    fp = re.search(r"False alarms: (\d+) of (\d+) held grasp", text)
    assert [int(v) for v in fp.groups()] == [g["false_positive_grasps"], g["held_runs"]]
    c = m["clips"]["operating_point"]
    assert f"{c['clips']} clips, {c['slip_clips']} ending just before a slip" in text
    assert summary_lines(m) == text.splitlines()[: len(summary_lines(m))]  # the library's lines, as printed
    for jargon in ("always-wiggle", " x2", "l-o-o"):
        assert jargon not in text


def test_grasps_labelled_as_a_whole_get_no_clip_accuracy_or_early_warning_figures():
    m = {
        "threshold": 0.3,
        "debounce": 1,
        "horizon": 50,
        "per_grasp": {
            "slip_runs": 0,
            "warned": 0,
            "premature": 0,
            "missed": 0,
            "held_runs": 3,
            "false_positive_grasps": 1,
            "slips_without_moment": 2,
            "median_lead_ms": float("nan"),
        },
        "clips": {"operating_point": {"clips": 6, "slip_clips": 0, "accuracy": 0.8, "always_wiggle_accuracy": 1.0}},
        "grasp_measure": {
            "detector": {"grasps": 5, "slipped": 2, "objects": 2, "roc_auc": {"value": 0.9, "interval": [0.5, 1.0]}},
            "baselines": {},
            "not_beaten": [],
        },
    }
    text = "\n".join(summary_lines(m))
    assert "2 of 5 grasps slipped" in text and "1 of 3 held grasps" in text
    assert "early-warning figures do not apply" in text
    assert "clip" not in text.lower() and "warned in time" not in text and "slip_runs" not in text


def test_a_truncated_video_reports_the_same_decoded_count_in_evaluate_calibrate_and_watch(tmp_path, cache, three_runs):
    root, bad = three_runs
    said = []
    for args in (
        ["evaluate", "--recordings", str(root), "--no-progress"],
        ["calibrate", "--recordings", str(root), "--out", str(tmp_path / "c.safetensors"), "--no-progress"],
        ["watch", str(bad.parent), "--quiet"],
    ):
        res = runner.invoke(app, args)
        lines = [l for l in res.stderr.splitlines() if l.startswith("error: ")]
        assert res.exit_code == 2 and len(lines) == 1 and str(bad) in lines[0], res.output
        said.append(re.search(r"states (\d+) frames but only (\d+) could be decoded", lines[0]).groups())
    assert said[0] == said[1] == said[2], said
