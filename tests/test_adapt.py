"""`slipsense adapt`: the shipped detector as is, recalibrated and fine-tuned, judged on objects each
never saw beside the baselines; the best kept only where it beats them, with the reason in words;
too few grasps or nothing better said plainly, and no detector written then; a second run resumes."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from slipsense.adapt import Candidate, choose
from slipsense.cli import app
from tests.test_frame_folders import _lift_data

runner = CliRunner()
SLIPPED = np.array([True, True, False, False] * 3)
OBJECTS = np.repeat(["a", "b", "c"], 4)


def _candidate(name: str, caught: int, alarming: int) -> Candidate:
    """A candidate catching ``caught`` of the 6 slips and alarming on ``alarming`` of the 6 held grasps."""
    alarmed = np.zeros(12, bool)
    alarmed[np.flatnonzero(SLIPPED)[:caught]] = True
    alarmed[np.flatnonzero(~SLIPPED)[:alarming]] = True
    return Candidate(name, alarmed.astype(float), alarmed, SLIPPED, OBJECTS)


BASELINE = {"value": 0.6, "interval": [0.5, 0.7]}


def test_the_best_candidate_is_kept_only_where_it_beats_the_detector_as_is_and_the_baseline():
    as_is, recal, tuned = _candidate("as is", 0, 0), _candidate("recalibrated", 3, 0), _candidate("fine-tuned", 6, 0)
    chosen, why = choose([as_is, recal, tuned], "frame_difference", BASELINE, "shipped")
    assert chosen is tuned and why.startswith("fine-tuned: the best")
    chosen, why = choose([_candidate("as is", 6, 0), recal, tuned], "frame_difference", BASELINE, "shipped")
    assert chosen is None and "keep using it (shipped" in why  # as is already does as well
    weak = [as_is, _candidate("recalibrated", 1, 0), _candidate("fine-tuned", 1, 0)]
    chosen, why = choose(weak, "frame_difference", BASELINE, "shipped")
    assert chosen is None and "no detector beats the best baseline (frame_difference" in why
    # always off and always on are no better than chance: never kept, whatever the baseline
    off, on = _candidate("recalibrated", 0, 0), _candidate("fine-tuned", 6, 6)
    chosen, _ = choose([as_is, off, on], "majority_class", {"value": 0.4, "interval": [0.3, 0.5]}, "shipped")
    assert chosen is None and off.balanced_accuracy == on.balanced_accuracy == 0.5


def test_too_few_grasps_say_what_to_record_and_write_no_detector(tmp_path, cache):
    root = _lift_data(tmp_path / "lift", objects=1)
    res = runner.invoke(app, ["adapt", "--recordings", str(root), "--out", str(tmp_path / "mine"), "--no-progress"])
    assert res.exit_code == 0, res.output
    assert "too few" in res.output and "grasps of 2 more object(s)" in res.output
    assert not (tmp_path / "mine" / "detector.safetensors").exists()
    assert json.loads((tmp_path / "mine" / "adapt.json").read_text())["chosen"] is None


@pytest.mark.parametrize("bad", [["--folds", "1"], ["--budget", "1.5"], ["--epochs", "0"]])
def test_bad_settings_end_in_one_line(tmp_path, bad):
    res = runner.invoke(app, ["adapt", "--recordings", str(tmp_path), "--out", str(tmp_path / "o"), *bad])
    assert res.exit_code == 2 and res.output.count("error: ") == 1, res.output


def test_adapt_judges_every_candidate_on_unseen_objects_and_resumes(tmp_path, cache, one_thread):
    root = _lift_data(tmp_path / "lift")
    out = tmp_path / "mine"
    args = ["adapt", "--recordings", str(root), "--out", str(out), "--epochs", "1", "--folds", "3", "--no-progress"]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    for words in (
        "your grasps: 12 (6 slipped, 6 held) of 3 objects",
        "as is",
        "recalibrated",
        "fine-tuned",
        "best baseline",
    ):
        assert words in res.output
    doc = json.loads((out / "adapt.json").read_text())
    assert [c["name"] for c in doc["candidates"]] == ["as is", "recalibrated", "fine-tuned"]
    assert all(c["measure"]["grasps"] == 12 for c in doc["candidates"])
    assert (out / "detector.safetensors").exists() == (doc["chosen"] is not None)
    folds = sorted(out.glob("folds/fold*/detector.safetensors"))
    assert len(folds) == 3
    before = [p.stat().st_mtime_ns for p in folds]
    res = runner.invoke(app, args)  # again: every fold's training is found, none is repeated
    assert res.exit_code == 0 and [p.stat().st_mtime_ns for p in folds] == before
    assert json.loads((out / "adapt.json").read_text())["candidates"] == doc["candidates"]
