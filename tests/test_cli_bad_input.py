"""The bad-input corpus through the command line: one line naming the file and the problem, exit 2.

Every case is made here, in a temporary folder; with ``--on-error skip`` bad videos are warned about
and left out instead.
"""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from slipsense.cli import app

runner = CliRunner()


def _video(path: Path, n: int, size=(240, 320)) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    h, w = size
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"XVID"), 25.0, (w, h))
    for i in range(n):
        vw.write(np.full((h, w, 3), (i * 7) % 255, np.uint8))
    vw.release()
    return path


def _good_run(root: Path, obj="cup", exp=1, n=30):
    for cam in ("camera_0", "camera_2"):
        _video(root / obj / f"exp_num_{exp}" / f"{cam}.avi", n)


def _bad_cases(root: Path) -> dict[str, tuple[Path, str]]:
    """name -> (the bad file, a word the error must contain)."""
    cases = {}
    empty = root / "empty" / "exp_num_1" / "camera_0.avi"
    empty.parent.mkdir(parents=True)
    empty.write_bytes(b"")
    cases["empty file"] = (empty, "empty")
    good = _video(root / "trunc" / "exp_num_1" / "camera_0.avi", 60)
    data = good.read_bytes()
    good.write_bytes(data[: len(data) // 3])
    cases["truncated AVI"] = (good, "trunc")
    png = root / "png" / "exp_num_1" / "camera_0.avi"
    png.parent.mkdir(parents=True)
    cv2.imwrite(str(png.with_suffix(".png")), np.zeros((240, 320, 3), np.uint8))
    png.with_suffix(".png").rename(png)
    cases["PNG renamed to .avi"] = (png, "PNG")
    cases["wrong resolution"] = (_video(root / "small" / "exp_num_1" / "camera_0.avi", 20, (120, 160)), "160")
    cases["one-frame video"] = (_video(root / "one" / "exp_num_1" / "camera_0.avi", 1), "frame")
    return cases


def _error_line(result) -> str:
    text = result.stderr if hasattr(result, "stderr") else result.output
    lines = [l for l in text.splitlines() if l.startswith("error: ")]
    assert len(lines) == 1, text
    return lines[0]


@pytest.mark.parametrize("case", ["empty file", "truncated AVI", "PNG renamed to .avi", "wrong resolution",
                                  "one-frame video"])
def test_bad_video_stops_label_with_one_line(tmp_path, case):
    root = tmp_path / "rec"
    bad, word = _bad_cases(tmp_path / "all")[case]
    # One object folder holding the bad video beside a good run.
    _good_run(root)
    target = root / "bad" / "exp_num_1" / "camera_0.avi"
    target.parent.mkdir(parents=True)
    target.write_bytes(bad.read_bytes())
    result = runner.invoke(app, ["label", "--recordings", str(root), "--csv", str(tmp_path / "l.csv"), "--no-progress"])
    assert result.exit_code == 2, result.output
    line = _error_line(result)
    assert str(target) in line and word.lower() in line.lower(), line
    assert not (tmp_path / "l.csv").exists()


def test_skip_flag_warns_and_leaves_bad_videos_out(tmp_path):
    root = tmp_path / "rec"
    _good_run(root)
    (root / "bad" / "exp_num_1").mkdir(parents=True)
    (root / "bad" / "exp_num_1" / "camera_0.avi").write_bytes(b"")
    (root / "novideo" / "exp_num_1").mkdir(parents=True)  # an experiment folder without videos
    result = runner.invoke(app, ["label", "--recordings", str(root), "--csv", str(tmp_path / "l.csv"),
                                 "--on-error", "skip", "--no-progress"])
    assert result.exit_code == 0, result.output
    rows = (tmp_path / "l.csv").read_text().strip().splitlines()
    assert len(rows) == 3 and all(r.startswith(("object", "cup")) for r in rows)


def test_experiment_folder_without_videos_is_an_error(tmp_path):
    root = tmp_path / "rec"
    _good_run(root)
    (root / "novideo" / "exp_num_4").mkdir(parents=True)
    result = runner.invoke(app, ["label", "--recordings", str(root), "--csv", str(tmp_path / "l.csv"), "--no-progress"])
    assert result.exit_code == 2
    assert "exp_num_4" in _error_line(result)


def test_missing_recordings_folder(tmp_path):
    result = runner.invoke(app, ["label", "--recordings", str(tmp_path / "nope"), "--csv", str(tmp_path / "l.csv")])
    assert result.exit_code == 2 and "nope" in _error_line(result)


def test_corrupt_and_foreign_checkpoints(tmp_path):
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"\x00" * 100)
    result = runner.invoke(app, ["evaluate", "--checkpoint", str(bad), "--markers", str(tmp_path / "m.npz")])
    assert result.exit_code == 2 and "bad.safetensors" in _error_line(result)


@pytest.mark.parametrize("problem, make, word", [
    ("nan", lambda x: x.__setitem__((1, 2, 3, 0), np.nan), "NaN"),
    ("inf", lambda x: x.__setitem__((0, 0, 0, 2), np.inf), "inf"),
])
def test_marker_file_with_nonfinite_values(tmp_path, problem, make, word):
    x = np.zeros((4, 12, 6, 3), np.float32)
    make(x)
    path = tmp_path / f"{problem}.npz"
    np.savez(path, x=x, y=np.array([0, 1, 0, 1]))
    result = runner.invoke(app, ["train", "--model", "temnet", "--markers", str(path), "--out", str(tmp_path / "r")])
    assert result.exit_code == 2
    line = _error_line(result)
    assert path.name in line and word.lower() in line.lower(), line


def test_marker_file_with_wrong_shape(tmp_path):
    path = tmp_path / "shape.npz"
    np.savez(path, x=np.zeros((4, 12, 6, 2), np.float32), y=np.array([0, 1, 0, 1]))
    result = runner.invoke(app, ["train", "--model", "temnet", "--markers", str(path), "--out", str(tmp_path / "r")])
    assert result.exit_code == 2 and "shape.npz" in _error_line(result)


@pytest.mark.parametrize("args, word", [
    (["--set", "no_such_key=3"], "no_such_key"),
    (["--epochs", "0"], "epochs"),
    (["--lr", "-1"], "lr"),
    (["--frames", "40"], "frames"),
    (["--size", "big"], "size"),
])
def test_bad_config_values(tmp_path, args, word):
    root = tmp_path / "rec"
    _good_run(root)
    result = runner.invoke(app, ["train", "--model", "vivit", "--recordings", str(root), "--out", str(tmp_path / "r"),
                                 "--no-progress", *args])
    assert result.exit_code == 2, result.output
    assert word in _error_line(result)
