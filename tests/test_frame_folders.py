"""Grasps as folders of frames, labelled per grasp (the gelsight-lift layout): found, read, judged by
`slipsense evaluate` with the outcome measure and its baselines, and every bad input refused in one line."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from slipsense.checkpoint import read_info
from slipsense.cli import app
from slipsense.models import model_class
from studies.__main__ import app as studies_app
from slipsense.recordings.folders import find_recordings
from slipsense.recordings.video import read_video

runner = CliRunner()


def _grasp(folder: Path, slipped: bool, seed: int, n: int = 12, size=(48, 64), start: int = 7675) -> None:
    """A pressed square that stays put (held) or keeps sliding (slipped), one JPEG per frame."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True)
    h, w = size
    for t in range(n):
        f = np.full((h, w, 3), 110, np.uint8) + rng.integers(0, 4, (h, w, 3), dtype=np.uint8)
        x = 10 + (3 * t if slipped else 0)
        f[12:36, x : x + 16] = 200
        cv2.imwrite(str(folder / f"gelsight_imgw{folder.name[:6]}_s09_{start + t:08d}.jpg"), f)


def _lift_data(root: Path, objects: int = 3) -> Path:
    """``objects`` objects of four grasps (two slipped) in the gelsight-lift layout."""
    for i in range(objects):
        lines = []
        for g, slipped in enumerate((True, False, True, False)):
            name = f"06{g}_{i}0"
            _grasp(root / f"object{i:03d}" / f"{name}_mm", slipped, seed=10 * i + g)
            lines.append(f"6{g}.{i} {'fail 0' if slipped else 'ok 1'} 100 300 200 {name} _s09_")
        (root / f"object{i:03d}_result.dat").write_text("\n".join(lines))  # no final newline, as published
    return root


def test_frame_folders_are_found_labelled_per_grasp_and_read_in_order(tmp_path):
    root = _lift_data(tmp_path / "lift")
    recs = find_recordings(root)
    assert len(recs) == 12 and all(r.per_grasp and r.camera == "gelsight" for r in recs)
    first = recs[0]
    assert (first.object, first.experiment, first.slipped) == ("object000", 6000, True)  # 060_00_mm
    frames = read_video(first.path, expected_size=None)
    assert frames.shape == (12, 48, 64, 3)
    files = sorted(first.path.iterdir())
    assert np.array_equal(frames[5], cv2.imread(str(files[5])))


def test_evaluate_a_frame_folder_set_prints_the_outcome_measure_with_baselines(tmp_path, cache):
    root = _lift_data(tmp_path / "lift")
    out = tmp_path / "ev.json"
    res = runner.invoke(app, ["evaluate", "--recordings", str(root), "--json", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    assert "shear-retention-gelsight-lift" in res.output  # laid out as that data set: its sensor's detector
    assert "6 of 12 grasps slipped, 3 objects" in res.output
    for name in ("detector", "majority_class", "frame_difference", "mean_frame_difference", "difference_to_contact"):
        assert name in res.output
    assert "early-warning figures do not apply" in res.output
    assert "Frame rate: read at 30 frames/s (the gelsight-lift layout); the detector runs at 30 frames/s." in res.output
    doc = json.loads(out.read_text())
    assert doc["frame_rate"] == {
        "detector": 30.0,
        "recordings": [{"fps": 30.0, "from": "the gelsight-lift layout", "runs": 12}],
    }
    measure = doc["grasp_measure"]
    assert measure["detector"]["grasps"] == 12
    # the sliding square is what the frame difference sees: it ranks these grasps perfectly
    assert measure["baselines"]["mean_frame_difference"]["roc_auc"]["value"] == 1.0
    lo, hi = measure["detector"]["roc_auc"]["interval"]
    assert 0.0 <= lo <= measure["detector"]["roc_auc"]["value"] <= hi <= 1.0


def _error(res) -> str:
    lines = [l for l in res.output.splitlines() if l.startswith("error: ")]
    assert res.exit_code == 2 and len(lines) == 1, res.output
    return lines[0]


def _break_missing_frame(root: Path) -> tuple[Path, str]:
    folder = root / "object001" / "061_10_mm"
    sorted(folder.iterdir())[4].unlink()
    return folder, "missing"


def _break_unreadable_frame(root: Path) -> tuple[Path, str]:
    frame = sorted((root / "object001" / "061_10_mm").iterdir())[3]
    frame.write_bytes(b"\xff\xd8\xff garbage")
    return frame, "cannot be decoded"


def _break_mixed_sizes(root: Path) -> tuple[Path, str]:
    frame = sorted((root / "object002" / "062_20_mm").iterdir())[-1]
    cv2.imwrite(str(frame), np.zeros((40, 64, 3), np.uint8))
    return frame, "mixed sizes"


def _break_line_without_folder(root: Path) -> tuple[Path, str]:
    path = root / "object000_result.dat"
    path.write_text(path.read_text() + "\n70 ok 1 1 2 1 070_00 _s09_\n")
    return path, "070_00"


def _break_folder_without_line(root: Path) -> tuple[Path, str]:
    folder = root / "object000" / "069_00_mm"
    _grasp(folder, False, seed=99)
    return folder, "no line"


def _break_bad_outcome(root: Path) -> tuple[Path, str]:
    path = root / "object002_result.dat"
    path.write_text(path.read_text().replace("ok 1", "maybe 1", 1))
    return path, "outcome"


@pytest.mark.parametrize(
    "breaks",
    [
        _break_missing_frame,
        _break_unreadable_frame,
        _break_mixed_sizes,
        _break_line_without_folder,
        _break_folder_without_line,
        _break_bad_outcome,
    ],
)
def test_bad_frame_folders_and_label_files_end_in_one_line(tmp_path, cache, breaks):
    root = _lift_data(tmp_path / "lift")
    path, words = breaks(root)
    res = runner.invoke(
        app, ["evaluate", "--recordings", str(root), "--json", str(tmp_path / "e.json"), "--no-progress"]
    )
    line = _error(res)
    assert str(path) in line and words in line, line
    assert not (tmp_path / "e.json").exists()


def test_label_and_watch_take_frame_folders(tmp_path, cache):
    root = _lift_data(tmp_path / "lift", objects=1)
    res = runner.invoke(app, ["label", "--recordings", str(root), "--csv", str(tmp_path / "l.csv"), "--no-progress"])
    assert "expected 640x480" in _error(res)  # laid out as gelsight-lift: that sensor's size, unless stated
    sensor = {"name": "tiny-gelsight", "output": "video", "fps": 30, "image_size": [48, 64]}
    (root / "sensor.json").write_text(json.dumps(sensor))
    res = runner.invoke(app, ["label", "--recordings", str(root), "--csv", str(tmp_path / "l.csv"), "--no-progress"])
    assert res.exit_code == 0 and "4 videos labelled (0 with a moment of slip)" in res.output, res.output
    res = runner.invoke(app, ["watch", str(root / "object000" / "060_00_mm"), "--quiet"])
    assert res.exit_code == 0 and "12 frames" in res.output, res.output


def test_calibrate_chooses_a_threshold_on_the_users_grasps_and_states_its_promise(tmp_path, cache):
    from slipsense.checkpoint import read_info
    from slipsense.evaluation.calibrate import calibrated_threshold

    root = _lift_data(tmp_path / "lift")
    out = tmp_path / "mine.safetensors"
    res = runner.invoke(app, ["calibrate", "--recordings", str(root), "--out", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    op = read_info(out)["operating_point"]
    assert op["held_alarm"]["held_grasps"] == 6 and op["held_alarm"]["held_objects"] == 3
    assert op["held_alarm"]["alarming"] == 0  # 5% of 6 held grasps allows none
    assert op["held_alarm"]["bound_counting_objects"] > op["held_alarm"]["bound_counting_grasps"] > 0
    assert "at most" in res.output and "counting the 3 objects" in res.output
    doc = tmp_path / "e.json"
    res = runner.invoke(app, ["evaluate", "--checkpoint", str(out), "--recordings", str(root), "--json", str(doc)])
    assert res.exit_code == 0 and json.loads(doc.read_text())["threshold"] == op["threshold"]
    # the rule itself: just above the held grasps that must stay quiet, below the slipped ones above them
    assert calibrated_threshold([0.1, 0.2, 0.3], [0.5, 0.05], 0.0) == pytest.approx(0.4)
    assert calibrated_threshold([0.1, 0.2, 0.9] + [0.0] * 17, [0.5], 0.05) == pytest.approx(0.35)


def test_calibrate_at_another_rate_keeps_the_detectors_clock_and_says_so(tmp_path, cache):
    """Grasps taken at 15 frames/s calibrate the shipped one-finger detector (trained at 25): the rate
    is printed, the calibrated copy keeps the 25 frames/s clock (frames resampled to it, as during calibration), so
    judging it again gives the figures calibration printed."""
    from slipsense.checkpoint import read_info

    root = _lift_data(tmp_path / "lift")
    (root / "sensor.json").write_text(
        json.dumps({"name": "my-lift", "output": "video", "fps": 15, "image_size": [48, 64], "camera_glob": "*.jpg"})
    )
    out = tmp_path / "mine.safetensors"
    res = runner.invoke(app, ["calibrate", "--recordings", str(root), "--out", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    assert "read at 15 frames/s" in res.output and "the detector runs at 25 frames/s: frames taken at" in res.output
    info = read_info(out)
    assert info["sensor"]["fps"] == 25.0 and info["sensor"]["name"] == "my-lift"
    doc = tmp_path / "e.json"
    res = runner.invoke(app, ["evaluate", "--checkpoint", str(out), "--recordings", str(root), "--json", str(doc)])
    assert res.exit_code == 0, res.output
    alarming = info["operating_point"]["held_alarm"]["alarming"]
    assert json.loads(doc.read_text())["per_grasp"]["false_positive_grasps"] == alarming


def test_calibrate_without_held_grasps_or_with_a_bad_budget_ends_in_one_line(tmp_path, cache):
    root = _lift_data(tmp_path / "lift", objects=1)
    path = root / "object000_result.dat"
    path.write_text(path.read_text().replace("ok 1", "fail 0"))
    out = tmp_path / "mine.safetensors"
    res = runner.invoke(app, ["calibrate", "--recordings", str(root), "--out", str(out), "--no-progress"])
    assert "no grasp that held" in _error(res) and not out.exists()
    res = runner.invoke(app, ["calibrate", "--recordings", str(root), "--out", str(out), "--budget", "1.5"])
    assert "--budget" in _error(res)


def test_calibration_is_judged_on_objects_left_out(tmp_path, cache):
    root = _lift_data(tmp_path / "lift")
    doc_path = tmp_path / "check.json"
    res = runner.invoke(app, ["calibrate", "--recordings", str(root), "--check", str(doc_path), "--no-progress"])
    assert res.exit_code == 0, res.output
    doc = json.loads(doc_path.read_text())
    assert [r["object"] for r in doc["objects"]] == ["object000", "object001", "object002"]
    assert doc["held"] == 6 and doc["slipped"] == 6 and "pooled:" in res.output
    assert 0 <= doc["held_alarm_rate"] <= 1 and doc["largest_stated_bound"] > 0
    res = runner.invoke(app, ["calibrate", "--recordings", str(root), "--no-progress"])
    assert "--out" in _error(res)


def test_the_shipped_detector_is_picked_by_the_inputs_sensor():
    from slipsense.checkpoint import read_info
    from slipsense.resources import shipped_model
    from slipsense.streaming.detector import SlipDetector, shipped_name

    assert shipped_name(1, (480, 640)) == "shear-retention-gelsight-lift"
    assert shipped_name(1, (240, 320)) == "motionnet-gelsight-1"
    assert shipped_name(2, (240, 320)) == shipped_name() == "motionnet-gelsight"
    assert shipped_name(2, (480, 640)) == "motionnet-gelsight"  # none shipped for two such fingers
    info = read_info(shipped_model("shear-retention-gelsight-lift"))
    assert info["sensor"]["name"] == "gelsight-lift"
    held = info["operating_point"]["held_alarm"]
    assert held["held_objects"] == 5 and held["bound_counting_objects"] > held["rate"]
    det = SlipDetector.pretrained(sensors=1, image_size=(480, 640), backend="torch")
    assert det.threshold == info["operating_point"]["threshold"]


def test_grasps_labelled_as_a_whole_fine_tune_the_shipped_detector(tmp_path, cache, one_thread):
    """Slipped grasps without a moment train as bags of frames (the most slip-like frame is slip); the
    detector starts from the shipped weights and its threshold is chosen per grasp."""
    from slipsense.checkpoint import read_info
    from slipsense.resources import ONE_SENSOR_DETECTOR, shipped_model

    root = _lift_data(tmp_path / "lift")
    out = tmp_path / "tuned"
    init = str(shipped_model(ONE_SENSOR_DETECTOR))
    args = ["train", "--recordings", str(root), "--set", f"train.init={init}", "--set", "train.startup=0"]
    res = runner.invoke(app, [*args, "--epochs", "2", "--inner-folds", "0", "--out", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    info = read_info(out / "detector.safetensors")
    assert info["model_config"] == read_info(init)["model_config"]  # the shipped model, trained further
    from slipsense.paths import resolve_path

    assert (
        info["sensor"]["name"] == "gelsight-lift"
        and resolve_path(info["train_config"]["init"]).resolve() == Path(init).resolve()
    )
    op = info["operating_point"]
    assert "labelled as a whole" in op["rule"] and op["startup"] == 0 and op["held_alarm"]["held_grasps"] == 6
    res = runner.invoke(app, [*args, "--set", "model.width=4", "--out", str(tmp_path / "x"), "--no-progress"])
    assert "come from train.init" in _error(res)


def test_a_bag_is_learned_from_its_most_slip_like_frame():
    import torch

    from slipsense.training.grasps import BAG, GraspTask

    task = object.__new__(GraspTask)
    task.cfg = type("C", (), {"chunk": 4})()
    task.weight = torch.tensor([1.0, 1.0])
    start = torch.zeros(2, 4, 2)
    start[1, 2, 1] = 1.0  # frame 2 is the bag's most slip-like
    logits = start.requires_grad_()
    y = torch.tensor([[0, 0, 0, 0], [-1, BAG, BAG, BAG]])
    loss, stats = task.loss(lambda x, n: logits, (None, y, 1.0), 1.0, 1)
    loss.backward()
    g = logits.grad
    assert g[1, 0].abs().sum() == 0  # an ignored frame
    assert g[1, 2, 1] < 0 and g[1, 1, 1] == 0 and g[1, 3, 1] == 0  # only the most slip-like frame learns
    assert (g[0, :, 1] > 0).all()  # held frames are pushed away from slip


def _two_shear_candidates(monkeypatch):
    """The shear row's recipe with 2 settings to choose among (16 ship): the same code, less time."""
    from slipsense.models import model_class

    shear = model_class("shear-retention")
    monkeypatch.setattr(shear, "recipe", {**shear.recipe, "choose": {"gate": [0.5, 1.0], "letgo": [0.4]}})


def test_the_adaptation_study_runs_every_row(tmp_path, cache, one_thread, grasp_recordings, monkeypatch):
    from studies.grasp.adaptation import adaptation_study, write

    _two_shear_candidates(monkeypatch)
    root = _lift_data(tmp_path / "lift")
    doc = adaptation_study(root, sizes=(5,), epochs=1, draws=50, progress=False, also=grasp_recordings, also_epochs=1)
    names = [r["row"] for r in doc["rows"]]
    assert names[:4] == ["as is", "recalibrated", "fine-tuned, 5 grasps", "this set alone"]
    grasps = {r["row"]: r["grasps"] for r in doc["rows"]}
    assert grasps["fine-tuned, 5 grasps"] == 36 and grasps["as is"] == 12  # three draws of 5 grasps, pooled
    assert any(n.startswith("baseline") for n in names) and any(n.startswith("shear retention") for n in names)
    both = next(r for r in doc["rows"] if r["row"].startswith("trained on both sets"))
    assert "16 grasps of" in both["row"] and both["grasps"] == 12  # the other set's 8 runs, each camera a grasp
    paths = write(doc, tmp_path / "report")
    assert all(p.is_file() for p in paths) and "| recalibrated |" in paths[1].read_text()


def test_review_cases_of_frame_folders_are_refused_in_one_line(tmp_path, cache):
    root = _lift_data(tmp_path / "lift")
    res = runner.invoke(
        studies_app,
        ["grasp", "early-warning", "--recordings", str(root), "--out", str(tmp_path / "ew"), "--no-progress"],
    )
    assert "slipsense evaluate" in _error(res)  # no moment to warn before
    stray = root / "object001" / "061_10_mm" / "preview.jpg"
    cv2.imwrite(str(stray), np.zeros((48, 64, 3), np.uint8))
    res = runner.invoke(
        app, ["evaluate", "--recordings", str(root), "--json", str(tmp_path / "e.json"), "--no-progress"]
    )
    assert str(stray) in _error(res)  # an unnumbered image would have been frame 0
    stray.unlink()
    (root / "object002_result.dat").unlink()  # its grasps would all read as held
    res = runner.invoke(
        app, ["evaluate", "--recordings", str(root), "--json", str(tmp_path / "e.json"), "--no-progress"]
    )
    assert "object002" in _error(res) and "object002_result.dat" in _error(res)


def test_held_out_grasps_labelled_as_a_whole_are_not_counted_as_held(tmp_path, cache, one_thread):
    from slipsense.resources import ONE_SENSOR_DETECTOR, shipped_model

    root = _lift_data(tmp_path / "lift")
    out = tmp_path / "tuned"
    init = str(shipped_model(ONE_SENSOR_DETECTOR))
    args = ["train", "--recordings", str(root), "--set", f"train.init={init}", "--set", "train.startup=0"]
    res = runner.invoke(
        app, [*args, "--epochs", "1", "--fold", "0", "--folds", "3", "--out", str(out), "--no-progress"]
    )
    assert res.exit_code == 0, res.output
    held_out = json.loads((out / "held_out.json").read_text())
    assert held_out["per_grasp"]["held_runs"] == 2 and held_out["per_grasp"]["slip_runs"] == 0
    # the run's own configuration trains again (its model settings are the init checkpoint's)
    res = runner.invoke(app, ["train", "--config", str(out / "config.yaml"), "--out", str(tmp_path / "again"),
                              "--epochs", "1", "--no-progress"])  # fmt: skip
    assert res.exit_code == 0, res.output


def test_watch_stamps_a_grasp_folder_at_the_rate_its_data_states(tmp_path, cache):
    grasp = tmp_path / "object000" / "060_00_mm"
    _grasp(grasp, False, seed=1, n=4, size=(480, 640))  # the gelsight-lift sensor's frame size
    out = tmp_path / "r.jsonl"
    res = runner.invoke(app, ["watch", str(grasp), "--jsonl", str(out)])
    assert res.exit_code == 2 and "060_00_mm: a folder of frames states no frame rate" in _error(res)
    res = runner.invoke(app, ["watch", str(grasp), "--jsonl", str(out), "--fps", "1000"])
    assert res.exit_code == 2 and "--fps" in _error(res) and "frame rate" in _error(res)
    (tmp_path / "sensor.json").write_text(json.dumps({"name": "my-gelsight", "output": "video", "fps": 12.5}))
    res = runner.invoke(app, ["watch", str(grasp), "--jsonl", str(out)])
    assert "shear-retention-gelsight-lift on PyTorch" in res.output.splitlines()[0]  # its faster backend
    assert res.exit_code == 0, res.output
    assert "12.5 frames/s" in res.output and "the detector runs at 30 frames/s" in res.output
    stamps = [json.loads(line)["stamp"] for line in out.read_text().splitlines()]
    assert stamps == pytest.approx([k / 12.5 for k in range(4)])  # the source's clock, not the model's
    res = runner.invoke(app, ["watch", str(grasp), "--jsonl", str(out), "--fps", "30"])
    assert res.exit_code == 0 and "30 frames/s (--fps)" in res.output, res.output
    (tmp_path / "sensor.json").write_text(json.dumps({"name": "my-gelsight", "output": "video", "fps": 1000}))
    res = runner.invoke(app, ["watch", str(grasp)])
    assert res.exit_code == 2 and "sensor.json" in _error(res) and "frame rate" in _error(res)


def test_folds_train_on_another_data_set_too_but_never_hold_it_out_or_judge_it(
    tmp_path, cache, one_thread, grasp_recordings
):
    """``data.also``: the lift grasps join every fold's training (one finger: each camera a grasp), the
    folds and their verdicts stay on the first set's objects, and the operating point is chosen on them."""
    lift = _lift_data(tmp_path / "lift")
    out = tmp_path / "folds"
    args = ["train", "--cross-validate", "--out", str(out), "--recordings", str(grasp_recordings), "--folds", "2",
            "--inner-folds", "0", "--epochs", "1", "--set", f"data.also={lift}", "--no-progress"]  # fmt: skip
    res = runner.invoke(app, args)  # both fingers at once: the lift grasps have one camera
    assert res.exit_code == 2 and "data.also" in res.output and "1 camera" in res.output, res.output
    res = runner.invoke(app, [*args, "--set", "model.sensors=1"])
    assert res.exit_code == 0, res.output
    rep = json.loads((out / "folds.json").read_text())
    held = [o for f in rep["per_fold"] for o in f["objects"]]
    assert sorted(held) == ["obj0", "obj1", "obj2", "obj3"]  # never a lift object
    assert rep["pooled"]["per_grasp"]["slip_runs"] == 8 and rep["pooled"]["per_grasp"]["held_runs"] == 8
    assert rep["data"]["runs"] == 16 and rep["data"]["also_runs"] == 12  # the lift grasps: read, trained on, apart
    assert "labelled as a whole" not in rep["per_fold"][0]["operating_point"]["rule"]  # chosen on the first set
    res = runner.invoke(app, [*args[:-3], "--set", f"data.also={grasp_recordings}", "--set", "model.sensors=1"])
    assert res.exit_code == 2 and "the training recordings themselves" in res.output, res.output


def test_the_adaptation_study_gives_the_same_numbers_on_one_or_two_workers(
    tmp_path, cache, one_thread, grasp_recordings, monkeypatch
):
    from studies.grasp.adaptation import adaptation_study

    _two_shear_candidates(monkeypatch)
    root = _lift_data(tmp_path / "lift")
    kw = dict(sizes=(None,), epochs=1, draws=50, progress=False, also=grasp_recordings, also_epochs=1)
    docs = [adaptation_study(root, workers=w, **kw) for w in (1, 2)]
    assert any(r["row"].startswith("trained on both sets") for r in docs[0]["rows"])
    for a, b in zip(*(d["rows"] for d in docs)):
        assert a["row"] == b["row"] and a["roc_auc"] == b["roc_auc"] and a["held_alarming"] == b["held_alarming"]
        assert a.get("operating_point") == b.get("operating_point")


def test_a_recipe_chooses_model_settings_on_the_training_grasps(tmp_path, cache, one_thread):
    """`train.choose`: every combination of the listed model settings is judged as the detector is
    (here without gradient training: epochs 0), the best by the rule's score on the training grasps
    ships, and the checkpoint says which were tried; a grid too big, or one folds cannot run, is refused."""
    from slipsense.checkpoint import read_info

    root = _lift_data(tmp_path / "lift")
    out = tmp_path / "shear"
    choose = '{"gate": [0.3, 2.0], "letgo": [0.4]}'
    res = runner.invoke(app, ["train", "--recordings", str(root), "--model", "shear-retention",
        "--set", "model.sensors=1", "--set", "model.image_size=[40,60]", "--set", "train.startup=0",
        "--set", "train.epochs=0", "--set", "train.inner_folds=0", "--set", f"train.choose={choose}",
        "--out", str(out), "--no-progress"])  # fmt: skip
    assert res.exit_code == 0, res.output
    info = read_info(out / "detector.safetensors")
    op = info["operating_point"]
    tried = {t["settings"]["gate"]: t["score"] for t in op["tried"]}
    assert sorted(tried) == [0.3, 2.0] and op["settings"]["letgo"] == 0.4
    assert info["model_config"]["gate"] == op["settings"]["gate"]
    assert tried[op["settings"]["gate"]] == max(tried.values()) == op["score_on_training_runs"]
    big = '{"gate": [' + ",".join(["0.5"] * 65) + "]}"
    res = runner.invoke(app, ["train", "--recordings", str(root), "--model", "shear-retention",
        "--set", f"train.choose={big}", "--out", str(tmp_path / "big"), "--no-progress"])  # fmt: skip
    assert "65 combinations" in _error(res)


#: the long command docs/new-sensor.md gave before `train --model` took the model's recipe
SHEAR_FLAGS = ["--set", "model.sensors=1", "--set", "model.softness=0", "--set", "train.startup=0",
               "--set", "train.epochs=0", "--set", "train.inner_folds=0"]  # fmt: skip


def _shear_train(root: Path, out: Path, *extra: str):
    res = runner.invoke(app, ["train", "--recordings", str(root), "--model", "shear-retention", *extra,
                              "--out", str(out), "--no-progress"])  # fmt: skip
    assert res.exit_code == 0, res.output
    return res.output.replace(str(out), "OUT"), json.loads(json.dumps(read_info(out / "detector.safetensors")))


def test_train_model_shear_retention_takes_its_recipe_and_the_datas_cameras(tmp_path, cache, one_thread, monkeypatch):
    """`train --model shear-retention --recordings MINE` with no --set: the model's recipe (no gradient,
    sharp steps, gate and letgo chosen on the grasps), one sensor per one-camera grasp and no camera
    start-up for grasps labelled as a whole: the operating point and printed figures of the long
    command with the six flags; slipsense.fit(model=...) is the same; a setting given still wins."""
    import slipsense

    _two_shear_candidates(monkeypatch)
    root = _lift_data(tmp_path / "lift")
    choose = json.dumps(model_class("shear-retention").recipe["choose"])
    plain_out, plain = _shear_train(root, tmp_path / "plain")
    long_out, long = _shear_train(root, tmp_path / "long", *SHEAR_FLAGS, "--set", f"train.choose={choose}")
    assert plain_out == long_out and "chosen on the training runs themselves" in plain_out
    assert plain["operating_point"] == long["operating_point"] and plain["model_config"] == long["model_config"]
    assert plain["train_config"] == long["train_config"] and plain["history"] == long["history"] == []
    op, model = plain["operating_point"], plain["model_config"]
    assert model["sensors"] == 1 and model["softness"] == 0 and model["image_size"] == [120, 160]
    assert op["startup"] == 0 and len(op["tried"]) == 2 and plain["train_config"]["inner_folds"] == 0
    assert (tmp_path / "plain" / "config.yaml").is_file()
    # the Python entry takes the same path
    trained = slipsense.fit(root, tmp_path / "api", model="shear-retention", progress=False)
    assert json.loads(json.dumps(trained.operating_point)) == plain["operating_point"]
    # what the user gives wins over the recipe and over what the data implies
    _, over = _shear_train(root, tmp_path / "over", "--set", "train.startup=2", "--set", "model.softness=1")
    assert over["train_config"]["startup"] == over["operating_point"]["startup"] == 2
    assert over["model_config"]["softness"] == 1 and over["train_config"]["epochs"] == 0  # the rest: the recipe


def test_a_model_built_for_other_cameras_than_the_grasps_have_is_refused_in_words(tmp_path, cache):
    """Two sensors asked of one-camera grasps: one line saying what the data has and what the model
    expects, exit code 2, no traceback, before any frame is decoded."""
    root = _lift_data(tmp_path / "lift")
    res = runner.invoke(app, ["train", "--recordings", str(root), "--model", "shear-retention",
                              "--set", "model.sensors=2", "--out", str(tmp_path / "x"), "--no-progress"])  # fmt: skip
    line = _error(res)
    assert isinstance(res.exception, SystemExit) and not (cache / "frames").exists()
    assert f"the recordings ({root}): 1 camera per grasp, read as 120x160 grey frames" in line
    assert "shear-retention was built for 2 sensors (model.sensors=2)" in line and "model.sensors=1" in line


def test_calibrate_says_so_and_what_to_do_next_when_it_catches_no_slip():
    from slipsense.evaluation.calibrate import Calibration

    held = {"held_grasps": 20, "alarming": 0, "rate": 0.0, "bound_counting_objects": 0.3}
    held |= {"bound_counting_grasps": 0.14, "held_objects": 5}
    before = {"threshold": 0.99, "held_alarming": 0, "slipped_caught": 0}
    ship = Path("/pkg/motionnet-gelsight-1.safetensors")
    none = Calibration(Path("mine.safetensors"), 0.9, 1, held, 11, 0, before, ship).lines()
    assert "catches none of the 11 slipped grasps" in none[-2] and f"train.init={ship}" in none[-1]
    some = Calibration(Path("mine.safetensors"), 0.9, 1, held, 11, 3, before, ship).lines()
    assert not any(line.startswith(("warning", "next")) for line in some)
    blind = Calibration(Path("mine.safetensors"), 0.9, 1, held, 0, 0, before, ship).lines()
    assert "no slipped grasps" in blind[-1]


@pytest.mark.parametrize(
    "sensor, problem",
    [
        (None, "no sensor is stated for it: put a sensor.json in it"),
        ({"name": "mine", "output": "video", "fps": 0}, "a frame rate must be 1 to 240 frames per second, got 0"),
        ({"name": "mine", "output": "video", "fps": 1000}, "a frame rate must be 1 to 240 frames per second"),
    ],
)
def test_frame_folders_without_a_usable_rate_are_refused_in_one_line(tmp_path, cache, sensor, problem):
    """Frames in a folder carry no time: a recordings folder of them with no sensor.json (and no
    --sensor), or one stating a rate of 0 or 1,000 frames/s, is refused by evaluate, naming the folder
    or the file and the problem."""
    root = tmp_path / "mine"
    _grasp(root / "mug" / "exp_num_1", slipped=True, seed=1)
    if sensor is not None:
        (root / "sensor.json").write_text(json.dumps(sensor))
    res = runner.invoke(app, ["evaluate", "--recordings", str(root), "--no-progress"])
    line = _error(res)
    assert problem in line and str(root / "sensor.json" if sensor else root) in line
