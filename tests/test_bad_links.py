"""Bad links and unreadable folders inside a recordings folder through the command line: one line
naming the path and what is wrong, exit 2, never a traceback; with ``--on-error skip`` the bad
recording is left out with a warning.

Every folder is made here. Permission bits do not stop root, so where the tests run as root an
unreadable folder is one ``os.scandir`` refuses (a monkeypatch); otherwise it is mode 000.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from slipsense.cli import app
from slipsense.recordings.folders import SkippedInputWarning
from striped_video import write_video

runner = CliRunner()


def _video_root(root: Path) -> Path:
    """Two good runs and the run ``bad/exp_num_1`` holding a good camera_2.avi (camera_0.avi is the test's)."""
    for obj in ("cup", "mug"):
        for cam in ("camera_0", "camera_2"):
            write_video(root / obj / "exp_num_1" / f"{cam}.avi", 12)
    write_video(root / "bad" / "exp_num_1" / "camera_2.avi", 12)
    return root / "bad" / "exp_num_1"


def _grasp(folder: Path, n: int = 5) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        cv2.imwrite(str(folder / f"frame_{i:03d}.png"), np.full((24, 32, 3), 40 + 30 * i, np.uint8))


def _frame_root(root: Path) -> Path:
    """Two objects of two grasps each as frame folders; the grasp ``mug/002_00`` is the test's to spoil."""
    for obj in ("cup", "mug"):
        _grasp(root / obj / "001_00")
        _grasp(root / obj / "002_00")
        (root / f"{obj}_result.dat").write_text("1 ok 1 0 0 0 001_00 x\n2 fail 0 0 0 0 002_00 x\n")
    (root / "sensor.json").write_text('{"name": "tiny", "output": "video", "fps": 25, "image_size": [24, 32]}')
    return root / "mug" / "002_00"


@pytest.fixture
def unreadable(monkeypatch):
    """``unreadable(folder)``: make ``folder`` one that cannot be listed (see the module notes)."""
    denied: list[Path] = []
    if os.geteuid() == 0:
        real = os.scandir

        def scandir(path="."):
            if Path(os.path.abspath(os.fspath(path))) in denied:
                raise PermissionError(13, "Permission denied", os.fspath(path))
            return real(path)

        monkeypatch.setattr(os, "scandir", scandir)

    def make(folder: Path) -> None:
        denied.append(Path(os.path.abspath(folder)))
        if os.geteuid() != 0:
            folder.chmod(0)

    yield make
    for folder in denied:
        folder.chmod(0o755)


def _label(root: Path, tmp_path: Path, *extra: str):
    csv = tmp_path / "labels.csv"
    result = runner.invoke(app, ["label", "--recordings", str(root), "--csv", str(csv), "--no-progress", *extra])
    assert "Traceback" not in result.output, result.output
    return result, csv


def _one_error(result, path: Path, words: str) -> str:
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.startswith("error: ")]
    assert len(lines) == 1, result.output
    assert str(path) in lines[0] and words in lines[0], lines[0]
    return lines[0]


def _warned(recwarn) -> list[str]:
    return [str(w.message) for w in recwarn if issubclass(w.category, SkippedInputWarning)]


def _video_loop(exp: Path) -> Path:
    (exp / "camera_0.avi").symlink_to("camera_0.avi")
    return exp / "camera_0.avi"


def _video_loop_of_two(exp: Path) -> Path:
    (exp / "camera_0.avi").symlink_to("other.avi")
    (exp / "other.avi").symlink_to("camera_0.avi")
    return exp / "camera_0.avi"


def _video_dangling(exp: Path) -> Path:
    (exp / "camera_0.avi").symlink_to("missing.avi")
    return exp / "camera_0.avi"


VIDEO_LINKS = {
    "loop": (_video_loop, "a symbolic link that loops"),
    "loop of two": (_video_loop_of_two, "a symbolic link that loops"),
    "dangling": (_video_dangling, "a link to a file that does not exist (it points to missing.avi)"),
}


def test_evaluate_names_a_video_link_that_loops(tmp_path, cache):
    bad = _video_loop(_video_root(tmp_path / "rec"))
    result = runner.invoke(app, ["evaluate", "--recordings", str(tmp_path / "rec"), "--no-progress"])
    assert "Traceback" not in result.output, result.output
    _one_error(result, bad, "a symbolic link that loops")


@pytest.mark.parametrize("case", VIDEO_LINKS)
def test_skip_leaves_a_bad_video_link_out(tmp_path, cache, recwarn, case):
    make, words = VIDEO_LINKS[case]
    bad = make(_video_root(tmp_path / "rec"))
    result, csv = _label(tmp_path / "rec", tmp_path, "--on-error", "skip")
    assert result.exit_code == 0, result.output
    assert f"{bad}: {words}; skipped" in _warned(recwarn), _warned(recwarn)
    rows = csv.read_text().splitlines()[1:]
    assert len(rows) == 5 and not any(r.startswith("bad,1,camera_0,") for r in rows), rows


def test_a_dangling_link_as_an_experiment_folder_is_one_line(tmp_path, cache):
    write_video(_video_root(tmp_path / "rec") / "camera_0.avi", 12)
    bad = tmp_path / "rec" / "mug" / "exp_num_2"
    bad.symlink_to("nowhere")
    result, _ = _label(tmp_path / "rec", tmp_path)
    _one_error(result, bad, "a link to a folder that does not exist")


@pytest.mark.parametrize("which", ["experiment", "object"])
def test_an_unreadable_folder_is_one_line(tmp_path, cache, unreadable, which):
    exp = _video_root(tmp_path / "rec")
    # "bad" is the first object by name: the first look at the layout lists it
    bad = exp if which == "experiment" else exp.parent
    unreadable(bad)
    result, csv = _label(tmp_path / "rec", tmp_path)
    _one_error(result, bad, "permission denied")
    assert not csv.exists()


def test_skip_leaves_an_unreadable_object_folder_out(tmp_path, cache, unreadable, recwarn):
    _video_root(tmp_path / "rec")
    unreadable(tmp_path / "rec" / "mug")
    result, csv = _label(tmp_path / "rec", tmp_path, "--on-error", "skip")
    assert result.exit_code == 0, result.output
    warned = _warned(recwarn)
    assert any(w.startswith(f"{tmp_path / 'rec' / 'mug'}: ") and "permission denied" in w for w in warned), warned
    assert not any(r.startswith("mug,") for r in csv.read_text().splitlines())


# ---- frame folders


def _frame_loop(grasp: Path) -> Path:
    frame = grasp / "frame_004.png"
    frame.unlink()
    frame.symlink_to(frame.name)
    return frame


def _frame_dangling(grasp: Path) -> Path:
    # a frame in the middle: the cheap probe decodes only the first and the last
    frame = grasp / "frame_002.png"
    frame.unlink()
    frame.symlink_to("gone.png")
    return frame


FRAME_LINKS = {
    "loop": (_frame_loop, "a symbolic link that loops"),
    "dangling": (_frame_dangling, "a link to a file that does not exist (it points to gone.png)"),
}


#: Every bad link, in a video layout and in frame folders: (the layout's maker, the link's maker, the words).
BAD_LINKS = {f"video {k}": (_video_root, *v) for k, v in VIDEO_LINKS.items()}
BAD_LINKS |= {f"frames {k}": (_frame_root, *v) for k, v in FRAME_LINKS.items()}


@pytest.mark.parametrize("case", BAD_LINKS)
def test_a_bad_link_is_one_line(tmp_path, cache, case):
    root, make, words = BAD_LINKS[case]
    bad = make(root(tmp_path / "rec"))
    result, csv = _label(tmp_path / "rec", tmp_path)
    _one_error(result, bad, words)
    assert not csv.exists()


@pytest.mark.parametrize("case", FRAME_LINKS)
def test_skip_leaves_a_grasp_with_a_bad_frame_link_out(tmp_path, cache, recwarn, case):
    make, words = FRAME_LINKS[case]
    bad = make(_frame_root(tmp_path / "rec"))
    result, csv = _label(tmp_path / "rec", tmp_path, "--on-error", "skip")
    assert result.exit_code == 0, result.output
    assert f"{bad}: {words}; skipped" in _warned(recwarn), _warned(recwarn)
    rows = csv.read_text().splitlines()[1:]
    assert len(rows) == 3 and not any(r.startswith("mug,200,") for r in rows), rows


def test_an_unreadable_grasp_folder_is_one_line_or_left_out(tmp_path, cache, unreadable, recwarn):
    grasp = _frame_root(tmp_path / "rec")
    unreadable(grasp)
    result, csv = _label(tmp_path / "rec", tmp_path)
    _one_error(result, grasp, "permission denied")
    assert not csv.exists()
    result, csv = _label(tmp_path / "rec", tmp_path, "--on-error", "skip")
    assert result.exit_code == 0, result.output
    warned = _warned(recwarn)
    assert any(w.startswith(f"{grasp}: ") and "permission denied" in w for w in warned), warned
    assert not any(r.startswith("mug,200,") for r in csv.read_text().splitlines())
