"""One way to judge: the checkpoint opened once and the folder scanned once; every measure comes from
the registry into the JSON, the printed summary and the cross-validation reports; false alarms per
hour of holding against detectors that are always on, always off and right."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

import slipsense.checkpoint as checkpoint_module
from slipsense.cli import app
from slipsense.measures import MEASURES, Judged, measure_all, register
from slipsense.measures.holding import false_alarms_per_hour
from slipsense.measures.pergrasp import RunTrace
from slipsense.training.folds import _write_report

runner = CliRunner()
FPS = 25.0


def _run(obj: str, slipped: bool, n: int = 500, moment: int | None = None) -> RunTrace:
    rest = np.zeros(n, bool)
    rest[:20] = True  # the gel untouched before the grasp
    return RunTrace(obj, 1, slipped, moment, n, np.zeros(n), rest, ("camera_0",), FPS, FPS)


def _with(runs: list[RunTrace], alarm) -> list[RunTrace]:
    """``runs`` whose probability is 1 where ``alarm(run)`` (a bool array) says so, else 0."""
    for r in runs:
        r.probability = alarm(r).astype(float)
    return runs


def _grasps() -> list[RunTrace]:
    return [_run(f"o{i}", False) for i in range(4)] + [_run(f"o{i}", True, moment=400) for i in range(4)]


def _judged(runs) -> Judged:
    return Judged(runs, [(0.5, 1, 0.5)] * len(runs), horizon=50, startup=10)


def test_false_alarms_per_hour_always_off_is_zero_and_always_on_is_one_per_held_grasp():
    off = false_alarms_per_hour(_judged(_with(_grasps(), lambda r: np.zeros(r.n_frames, bool))))
    assert off["false_alarms"] == 0 and off["per_hour"]["value"] == 0.0
    on = false_alarms_per_hour(_judged(_with(_grasps(), lambda r: np.ones(r.n_frames, bool))))
    # one onset per grasp's held part: 4 held grasps (frames 20..499 in contact) and 4 slips (20..349)
    hours = (4 * 480 + 4 * 330) / FPS / 3600
    assert on["false_alarms"] == 8 and on["grasps"] == 8
    assert on["per_hour"]["value"] == pytest.approx(8 / hours)
    lo, hi = on["per_hour"]["interval"]
    assert lo <= on["per_hour"]["value"] <= hi


def test_a_rate_over_seconds_of_contact_is_not_stated_and_says_why():
    """8 grasps of 20 s: under 10 minutes of contact, one alarm is no rate per hour; 40 grasps of 20 s
    (13 minutes) state it."""
    from slipsense.measures.holding import MIN_MINUTES, words

    def once(r):
        a = np.zeros(r.n_frames, bool)
        a[100] = not r.slipped and r.object == "o0"
        return a

    few = false_alarms_per_hour(_judged(_with(_grasps(), once)))
    assert few["false_alarms"] == 1 and few["enough"] is False and few["minimum_minutes"] == MIN_MINUTES
    (line,) = words(few)
    assert "not stated" in line and f"at least {MIN_MINUTES:g} minutes" in line
    assert f"{few['per_hour']['value']:.0f}" not in line.split("over")[0]  # no rate before the counts
    many = false_alarms_per_hour(_judged(_with([r for _ in range(5) for r in _grasps()], once)))
    assert many["enough"] is True and "not stated" not in words(many)[0]


def test_a_detector_that_warns_only_in_the_horizon_raises_no_false_alarm():
    def in_time(r):
        a = np.zeros(r.n_frames, bool)
        if r.slipped:
            a[370:401] = True  # 30 frames before the moment: a warning, not a false alarm
        return a

    assert false_alarms_per_hour(_judged(_with(_grasps(), in_time)))["false_alarms"] == 0


def test_a_flickering_alarm_counts_once_within_the_hold_and_slips_without_moment_are_left_out():
    def flicker(r):
        a = np.zeros(r.n_frames, bool)
        a[100:300:5] = True  # on every 5th frame: 0.2 s apart, inside the 0.5 s hold
        return a

    runs = _with([_run("a", False), _run("b", True, moment=None)], flicker)
    res = false_alarms_per_hour(_judged(runs))
    assert res["false_alarms"] == 1 and res["grasps"] == 1


def test_the_measure_is_in_the_json_and_the_summary_of_evaluate(tmp_path, cache, grasp_recordings):
    out = tmp_path / "e.json"
    res = runner.invoke(app, ["evaluate", "--recordings", str(grasp_recordings), "--json", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    doc = json.loads(out.read_text())
    fa = doc["false_alarms_per_hour"]
    assert set(fa) == {"false_alarms", "hours", "grasps", "per_hour", "enough", "minimum_minutes"} and fa["hours"] > 0
    assert "False alarms per hour of holding" in res.stdout


def test_evaluate_opens_the_checkpoint_once_and_lists_each_folder_once(
    tmp_path, cache, grasp_recordings, monkeypatch, folder_opens
):
    from slipsense.resources import shipped_model

    weights = []
    load_file = checkpoint_module.load_file
    monkeypatch.setattr(checkpoint_module, "load_file", lambda p, *a, **k: weights.append(p) or load_file(p, *a, **k))
    runs = sorted({p.parent for p in grasp_recordings.glob("*/*/*.avi")})
    for given in ([], ["--checkpoint", str(shipped_model("motionnet-gelsight"))]):
        weights.clear()
        with folder_opens:
            res = runner.invoke(app, ["evaluate", "--recordings", str(grasp_recordings), "--no-progress", *given])
        assert res.exit_code == 0, res.output
        assert len(weights) == 1, weights
        assert folder_opens.count(grasp_recordings) == 1, folder_opens.listed
        assert len(runs) > 3 and [folder_opens.count(r) for r in runs] == [1] * len(runs)


def test_a_frame_folder_set_is_listed_once_too(tmp_path, cache, folder_opens):
    """The shipped detector of another sensor (gelsight-lift: its own file layout) is chosen from the
    folder's one listing: grasps as frame folders read the same whatever the sensor says; their rate
    comes from the same listing (not looked up again for every grasp)."""
    from test_frame_folders import _grasp

    root = tmp_path / "lift"
    for i in range(2):
        lines = []
        for g, slipped in enumerate((True, False)):
            name = f"06{g}_{i}0"
            _grasp(root / f"object{i:03d}" / f"{name}_mm", slipped, seed=10 * i + g, n=8, size=(480, 640))
            lines.append(f"6{g}.{i} {'fail 0' if slipped else 'ok 1'} 100 300 200 {name} _s09_")
        (root / f"object{i:03d}_result.dat").write_text("\n".join(lines))
    with folder_opens:
        res = runner.invoke(app, ["evaluate", "--recordings", str(root), "--no-progress"])
    assert res.exit_code == 0, res.output
    assert "shear-retention-gelsight-lift" in res.stderr
    assert folder_opens.count(root) == 1 and folder_opens.count(root / "object000") == 1, folder_opens.listed


def _fold(k: int, runs: list[RunTrace]) -> dict:
    """A fold as ``slipsense train --cross-validate`` stores it (the figures the pooling reads)."""
    stored = [
        {
            "object": r.object,
            "experiment": r.experiment,
            "cameras": list(r.cameras),
            "moment_of_slip": r.moment_of_slip,
            "slipped": r.slipped,
            "outcome": "clean" if not r.slipped else "missed",
            "first_alarm": None,
            "lead": None,
            "rest": np.flatnonzero(r.rest).tolist(),
            "probability": r.probability.tolist(),
        }
        for r in runs
    ]
    per_grasp = {"runs_alarming_at_rest": 0, "held_alarm_fraction": 0.0, "warned": 0, "slip_runs": 1}
    return {
        "fold": k,
        "objects": [runs[0].object],
        "operating_point": {"threshold": 0.5, "debounce": 1, "hold_s": 0.5, "startup": 10},
        "per_grasp": {**per_grasp, "false_positive_grasps": 0, "held_runs": 1},
        "clips": {"f1": 0.0},
        "runs": stored,
        "clip_probability": [0.1],
        "clip_label": [0],
        "seconds": 1.0,
    }


def _report(tmp_path, alarm) -> dict:
    folds = [_fold(k, _with([_run(f"o{k}", False), _run(f"o{k}", True, moment=400)], alarm)) for k in range(2)]
    head = {"train_config": {"model": "motionnet", "horizon": 50, "inner_folds": 2}, "folds": 2, "sensor": {"fps": FPS}}
    head["data"] = {"runs": 4, "slip_with_moment": 2, "slip_without_moment": 0, "held": 2}
    return _write_report(tmp_path, head, folds, "test")


def test_the_fold_reports_pool_every_registered_measure(tmp_path):
    on = _report(tmp_path, lambda r: np.ones(r.n_frames, bool))
    assert on["pooled"]["false_alarms_per_hour"]["false_alarms"] == 4
    readme = (tmp_path / "README.md").read_text()
    assert "False alarms per hour of holding" in readme
    assert json.loads((tmp_path / "folds.json").read_text())["pooled"]["false_alarms_per_hour"]["grasps"] == 4
    off = _report(tmp_path, lambda r: np.zeros(r.n_frames, bool))
    assert off["pooled"]["false_alarms_per_hour"]["per_hour"]["value"] == 0.0


def test_a_new_measure_is_one_function_and_one_entry(tmp_path, cache, grasp_recordings):
    def words(result, context):
        return [f"Longest grasp: {result['frames']} frames."]

    @register("longest_grasp", words)
    def longest_grasp(judged):
        return {"frames": max(r.n_frames for r in judged.runs)}

    try:
        out = tmp_path / "e.json"
        res = runner.invoke(
            app, ["evaluate", "--recordings", str(grasp_recordings), "--json", str(out), "--no-progress"]
        )
        assert json.loads(out.read_text())["longest_grasp"] == {"frames": 70}
        assert "Longest grasp: 70 frames." in res.stdout
        report = _report(tmp_path, lambda r: np.zeros(r.n_frames, bool))
        assert report["pooled"]["longest_grasp"] == {"frames": 500}
        assert "Longest grasp: 500 frames." in (tmp_path / "README.md").read_text()
    finally:
        del MEASURES["longest_grasp"]


def test_every_measure_applies_to_made_runs_without_reading_anything():
    results = measure_all(_judged(_with(_grasps(), lambda r: np.zeros(r.n_frames, bool))))
    assert {"per_grasp", "grasp_measure", "false_alarms_per_hour"} <= set(results)
    assert "clips" not in results  # no clips cut: nothing to say
    assert math.isnan(results["grasp_measure"]["detector"]["roc_auc"]["value"]) is False
