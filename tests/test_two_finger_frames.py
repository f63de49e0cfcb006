"""Two fingers as frames: grasps of ``camera_0/`` and ``camera_2/`` frame folders are read as two-camera
runs by every command, the two-finger shipped detector judges them, and a grasp whose cameras do not
match is refused in one line (one camera per grasp: tests/test_frame_folders.py)."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from slipsense.cli import app
from slipsense.recordings.folders import camera_counts, find_recordings
from slipsense.recordings.video import read_video

from conftest import needs_data

runner = CliRunner()
CAMERAS = ("camera_0", "camera_2")


def _camera(folder: Path, slipped: bool, seed: int, n: int, size: tuple[int, int]) -> None:
    """One finger's frames of a grasp: a pressed square that stays put (held) or keeps sliding."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True)
    h, w = size
    for t in range(n):
        f = np.full((h, w, 3), 110, np.uint8) + rng.integers(0, 4, (h, w, 3), dtype=np.uint8)
        x = w // 6 + (max(1, w // 20) * t if slipped else 0)
        f[h // 4 : 3 * h // 4, x : x + w // 4] = 200
        cv2.imwrite(str(folder / f"frame_{t:05d}.png"), f)


def _two_finger_data(root: Path, objects: int = 3, n: int = 10, size=(48, 64), cameras=CAMERAS) -> Path:
    """``objects`` objects of two grasps (one slipped: ``slip.txt``), each camera a folder of frames,
    with a ``sensor.json`` at 25 frames/s stating the frame size."""
    for i in range(objects):
        for g, slipped in ((1, True), (2, False)):
            grasp = root / f"obj{i}" / f"exp_num_{g}"
            for c, cam in enumerate(cameras):
                _camera(grasp / cam, slipped, seed=100 * i + 10 * g + c, n=n, size=size)
            if slipped:
                (grasp / "slip.txt").write_text("")
    sensor = {"name": "my-two-finger-gelsight", "output": "video", "fps": 25, "image_size": list(size)}
    (root / "sensor.json").write_text(json.dumps(sensor))
    return root


def _error(res) -> str:
    lines = [l for l in res.output.splitlines() if l.startswith("error: ")]
    assert res.exit_code == 2 and len(lines) == 1, res.output
    return lines[0]


def test_camera_folders_are_read_as_two_camera_runs_with_both_cameras_in_order(tmp_path):
    root = _two_finger_data(tmp_path / "mine")
    recs = find_recordings(root)
    assert camera_counts(recs) == [2] and len(recs) == 12
    assert [r.key for r in recs[:2]] == [("obj0", 1, "camera_0"), ("obj0", 1, "camera_2")]
    assert all(r.per_grasp and r.path == root / r.object / f"exp_num_{r.experiment}" / r.camera for r in recs)
    assert [r.slipped for r in recs[:4]] == [True, True, False, False]  # slip.txt in the grasp folder
    frames = read_video(recs[1].path, expected_size=None)
    assert frames.shape == (10, 48, 64, 3)
    assert np.array_equal(frames[7], cv2.imread(str(recs[1].path / "frame_00007.png")))
    assert not np.array_equal(frames[7], read_video(recs[0].path, expected_size=None)[7])  # each its own camera


def test_evaluate_judges_two_finger_frames_with_the_two_finger_detector(tmp_path, cache):
    """At the GelSight Mini's 240 x 320 the shipped two-finger detector is chosen and replays both
    cameras of every grasp; with one camera folder per grasp the one-finger detector is."""
    from slipsense.evaluation.judge import judge, shipped_for

    root = _two_finger_data(tmp_path / "mine", objects=2, n=6, size=(240, 320))
    assert shipped_for(root).stem == "motionnet-gelsight"
    out = tmp_path / "ev.json"
    res = runner.invoke(app, ["evaluate", "--recordings", str(root), "--json", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    assert "evaluating the shipped detector motionnet-gelsight\n" in res.output
    assert "2 of 4 grasps slipped, 2 objects" in res.output
    doc = json.loads(out.read_text())
    assert doc["frame_rate"]["recordings"] == [{"fps": 25.0, "from": str(root / "sensor.json"), "runs": 4}]
    ev = judge(None, root, progress=False)
    assert [r.cameras for r in ev.runs] == [CAMERAS] * 4 and ev.startup == 0  # labelled as a whole
    for grasp in root.glob("*/*"):
        shutil.rmtree(grasp / "camera_2")
    assert shipped_for(root).stem == "motionnet-gelsight-1"


def test_small_two_finger_frames_replay_as_two_camera_runs(tmp_path, cache):
    from slipsense.evaluation.judge import judge

    root = _two_finger_data(tmp_path / "mine", objects=2, n=8)
    ev = judge(None, root, progress=False)
    assert len(ev.runs) == 4 and all(r.cameras == CAMERAS and r.n_frames == 8 for r in ev.runs)


def _break_count(root: Path) -> tuple[Path, str]:
    sorted((root / "obj1" / "exp_num_2" / "camera_2").iterdir())[-1].unlink()
    return root / "obj1" / "exp_num_2", "differ in frame count (camera_0 10, camera_2 9)"


def _break_one_camera(root: Path) -> tuple[Path, str]:
    shutil.rmtree(root / "obj2" / "exp_num_1" / "camera_0")
    return root / "obj2" / "exp_num_1", "holds camera_2, where"


def _break_frames_beside(root: Path) -> tuple[Path, str]:
    _camera(root / "obj0" / "exp_num_2" / "extra", False, seed=1, n=2, size=(48, 64))
    for frame in (root / "obj0" / "exp_num_2" / "extra").iterdir():
        frame.rename(root / "obj0" / "exp_num_2" / frame.name)
    return root / "obj0" / "exp_num_2", "beside its camera_* folders"


def _break_empty_camera(root: Path) -> tuple[Path, str]:
    for frame in (root / "obj1" / "exp_num_1" / "camera_0").iterdir():
        frame.unlink()
    return root / "obj1" / "exp_num_1" / "camera_0", "holds no image files"


@pytest.mark.parametrize("breaks", [_break_count, _break_one_camera, _break_frames_beside, _break_empty_camera])
def test_cameras_of_a_grasp_that_do_not_match_end_in_one_line(tmp_path, cache, breaks):
    root = _two_finger_data(tmp_path / "mine")
    path, words = breaks(root)
    out = tmp_path / "e.json"
    res = runner.invoke(app, ["evaluate", "--recordings", str(root), "--json", str(out), "--no-progress"])
    line = _error(res)
    assert f"{path}: " in line and words in line, line
    assert not out.exists()


def test_label_calibrate_adapt_and_watch_take_two_finger_frames(tmp_path, cache):
    root = _two_finger_data(tmp_path / "mine")
    res = runner.invoke(app, ["label", "--recordings", str(root), "--csv", str(tmp_path / "l.csv"), "--no-progress"])
    assert res.exit_code == 0 and "12 videos labelled (0 with a moment of slip)" in res.output, res.output
    assert "obj0,1,camera_2" in (tmp_path / "l.csv").read_text()
    mine = tmp_path / "mine.safetensors"
    res = runner.invoke(app, ["calibrate", "--recordings", str(root), "--out", str(mine), "--no-progress"])
    assert res.exit_code == 0, res.output
    from slipsense.checkpoint import read_info

    info = read_info(mine)
    assert info["model_config"]["sensors"] == 2 and info["operating_point"]["held_alarm"]["held_grasps"] == 3
    few = _two_finger_data(tmp_path / "few", objects=2)  # too few to fine-tune: adapt says so and stops
    res = runner.invoke(app, ["adapt", "--recordings", str(few), "--out", str(tmp_path / "ad"), "--no-progress"])
    assert res.exit_code == 0, res.output
    assert "4 (2 slipped, 2 held) of 2 objects, 64x48 px, 2 camera(s) a grasp" in res.output
    assert json.loads((tmp_path / "ad" / "adapt.json").read_text())["shipped"] == "motionnet-gelsight.safetensors"
    grasp = root / "obj0" / "exp_num_1"
    out = tmp_path / "r.jsonl"
    res = runner.invoke(app, ["watch", str(grasp), "--jsonl", str(out)])
    assert res.exit_code == 0 and "motionnet-gelsight on" in res.output.splitlines()[0], res.output
    stamps = [json.loads(line)["stamp"] for line in out.read_text().splitlines()]
    assert stamps == pytest.approx([k / 25 for k in range(10)])  # the data's sensor.json rate
    res = runner.invoke(app, ["watch", str(grasp / "camera_2"), "--quiet"])  # one finger's frames
    assert res.exit_code == 0 and "10 frames" in res.output, res.output
    sorted((grasp / "camera_0").iterdir())[0].unlink()
    res = runner.invoke(app, ["watch", str(grasp), "--quiet"])
    assert f"{grasp}: " in _error(res) and "differ in frame count" in _error(res)


def test_train_reads_two_finger_frames_as_two_finger_runs(tmp_path, cache, one_thread):
    from slipsense.checkpoint import read_info

    root = _two_finger_data(tmp_path / "mine", n=12)
    out = tmp_path / "det"
    res = runner.invoke(app, ["train", "--recordings", str(root), "--set", "model.width=4", "--set",
                              "train.startup=0", "--epochs", "1", "--inner-folds", "0", "--out", str(out),
                              "--no-progress"])  # fmt: skip
    assert res.exit_code == 0, res.output
    info = read_info(out / "detector.safetensors")
    assert info["model_config"]["sensors"] == 2 and info["data"]["sensors_per_grasp"] == 2
    assert info["sensor"]["name"] == "my-two-finger-gelsight"


@needs_data
def test_the_shared_grasps_as_two_finger_frames_replay_as_their_videos(tmp_path, cache):
    """Two objects of the shared wiggle grasps as PNG frame folders: every run replays to the same
    probabilities as its videos, so the detector's per-grasp figures (judged from the first frame, as
    frame folders are) are the same; the frame folders are labelled as a whole (no moment of slip)."""
    from slipsense.paths import gelsight_recordings
    from slipsense.evaluation.judge import judge
    from studies.grasp.derive import two_finger_frame_folders

    objects = ["glass_box", "jute_basket"]
    frames = tmp_path / "frames"
    assert two_finger_frame_folders(gelsight_recordings(), frames, objects) == 7
    sensor = json.loads((frames / "sensor.json").read_text())
    assert sensor["fps"] == 25.0 and sensor["image_size"] == [240, 320]
    assert sorted(p.name for p in (frames / "glass_box" / "exp_num_1").iterdir()) == [*CAMERAS, "slip.txt"]
    videos = judge(None, gelsight_recordings(), objects=objects, progress=False)
    ours = judge(None, frames, progress=False)
    assert [(r.object, r.experiment, r.cameras, r.slipped) for r in ours.runs] == [
        (r.object, r.experiment, r.cameras, r.slipped) for r in videos.runs
    ]
    for a, b in zip(ours.runs, videos.runs):
        assert np.array_equal(a.probability, b.probability, equal_nan=True)  # nan: before the first window
    judged = dataclasses.replace(videos, startup=ours.startup)
    assert ours.grasp_measure(draws=200)["detector"] == judged.grasp_measure(draws=200)["detector"]
