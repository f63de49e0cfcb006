"""The bad-input corpus through the command line: one line naming the file and the problem, exit 2.

Every case is made here, in a temporary folder; with ``--on-error skip`` bad videos are warned about
and left out instead.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from conftest import TINY_TRAIN_ARGS
from slipsense.cli import app
from studies.__main__ import app as studies_app

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


@pytest.mark.parametrize(
    "case", ["empty file", "truncated AVI", "PNG renamed to .avi", "wrong resolution", "one-frame video"]
)
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
    result = runner.invoke(
        app,
        ["label", "--recordings", str(root), "--csv", str(tmp_path / "l.csv"), "--on-error", "skip", "--no-progress"],
    )
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


def test_checkpoint_with_weights_of_another_dtype_is_refused(tmp_path):
    """int64 weights would be cast to float by load_state_dict: nonsense predictions and exit 0."""
    from safetensors.torch import load_file, save_file

    from slipsense.checkpoint import META_KEY, read_info
    from slipsense.streaming.detector import DEFAULT_CHECKPOINT

    info = read_info(DEFAULT_CHECKPOINT)
    state = {
        k: (v * 1000).to(torch.int64) if v.is_floating_point() else v
        for k, v in load_file(str(DEFAULT_CHECKPOINT)).items()
    }
    bad = tmp_path / "int64.safetensors"
    save_file(state, str(bad), metadata={META_KEY: json.dumps(info)})
    result = runner.invoke(app, ["evaluate", "--checkpoint", str(bad), "--recordings", str(tmp_path)])
    assert result.exit_code == 2, result.output
    line = _error_line(result)
    assert "int64.safetensors" in line and "torch.int64" in line, line


@pytest.mark.parametrize(
    "problem, make, word",
    [
        ("nan", lambda x: x.__setitem__((1, 2, 3, 0), np.nan), "NaN"),
        ("inf", lambda x: x.__setitem__((0, 0, 0, 2), np.inf), "inf"),
    ],
)
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


@pytest.mark.parametrize(
    "args, word",
    [
        (["--set", "no_such_key=3"], "no_such_key"),
        (["--epochs", "0"], "epochs"),
        (["--lr", "-1"], "lr"),
        (["--frames", "40"], "frames"),
        (["--size", "big"], "size"),
    ],
)
def test_bad_config_values(tmp_path, args, word):
    root = tmp_path / "rec"
    _good_run(root)
    result = runner.invoke(
        app,
        ["train", "--model", "vivit", "--recordings", str(root), "--out", str(tmp_path / "r"), "--no-progress", *args],
    )
    assert result.exit_code == 2, result.output
    assert word in _error_line(result)


# ------------------------------------------------------------------ issue 12: more bad-input classes


def _markers_npz(path: Path, n: int = 24, **extra) -> Path:
    rng = np.random.default_rng(0)
    arrays = {
        "x": rng.normal(size=(n, 4, 5, 3)).astype(np.float32),
        "y": np.arange(n) % 2,
        "groups": np.arange(n) // 2,
        **extra,
    }
    np.savez(path, **arrays)
    return path


def _stderr_lines(result) -> list[str]:
    text = result.stderr if hasattr(result, "stderr") else result.output
    return text.splitlines()


def _one_error(result, *words) -> str:
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    line = _error_line(result)
    for w in words:
        assert w in line, line
    return line


@pytest.fixture
def unwritable(tmp_path):
    """A folder nothing can be created in (permission bits do not stop root: use /proc then)."""
    if os.geteuid() == 0:
        yield Path("/proc/self/slipsense-test")
        return
    folder = tmp_path / "readonly"
    folder.mkdir()
    folder.chmod(0o555)
    yield folder
    folder.chmod(0o755)


@pytest.fixture
def run_dir(tmp_path):
    """A trained tiny TemNet run (its checkpoint) and its marker file."""
    _markers_npz(tmp_path / "m.npz")
    result = runner.invoke(
        app,
        [
            "train",
            *TINY_TRAIN_ARGS,
            "--markers",
            str(tmp_path / "m.npz"),
            "--out",
            str(tmp_path / "run"),
            "--epochs",
            "1",
        ],
    )
    assert result.exit_code == 0, result.output
    return tmp_path / "run"


# output paths --------------------------------------------------------------------------------
def test_label_csv_that_is_a_folder_or_unwritable(tmp_path, cache, unwritable):
    root = tmp_path / "rec"
    _good_run(root)
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "keep.txt").write_text("mine")
    result = runner.invoke(app, ["label", "--recordings", str(root), "--csv", str(tmp_path / "out"), "--no-progress"])
    _one_error(result, str(tmp_path / "out"), "folder")
    assert (tmp_path / "out" / "keep.txt").read_text() == "mine"
    result = runner.invoke(
        app, ["label", "--recordings", str(root), "--csv", str(unwritable / "l.csv"), "--no-progress"]
    )
    _one_error(result, "l.csv", "cannot be written")
    assert not (tmp_path / "cache" / "labels").exists()  # refused before any work


def test_evaluate_json_and_train_out_that_cannot_be_written(tmp_path, run_dir, unwritable):
    ck = run_dir / "last.safetensors"
    before = ck.read_bytes()
    (tmp_path / "eval.json").mkdir()
    result = runner.invoke(
        app,
        [
            "evaluate",
            "--checkpoint",
            str(ck),
            "--markers",
            str(tmp_path / "m.npz"),
            "--json",
            str(tmp_path / "eval.json"),
            "--no-progress",
        ],
    )
    _one_error(result, "eval.json", "folder")
    result = runner.invoke(
        app,
        [
            "evaluate",
            "--checkpoint",
            str(ck),
            "--markers",
            str(tmp_path / "m.npz"),
            "--json",
            str(unwritable / "e.json"),
            "--no-progress",
        ],
    )
    _one_error(result, "e.json", "cannot be written")
    (tmp_path / "afile").write_text("mine")
    result = runner.invoke(
        app, ["train", *TINY_TRAIN_ARGS, "--markers", str(tmp_path / "m.npz"), "--out", str(tmp_path / "afile")]
    )
    _one_error(result, "afile", "is a file")
    result = runner.invoke(
        app, ["train", *TINY_TRAIN_ARGS, "--markers", str(tmp_path / "m.npz"), "--out", str(unwritable / "r")]
    )
    _one_error(result, "cannot be written")
    assert (tmp_path / "afile").read_text() == "mine" and ck.read_bytes() == before


def test_simulate_out_that_cannot_be_written(tmp_path, unwritable):
    (tmp_path / "sim.npz").mkdir()
    result = runner.invoke(
        studies_app, ["stnet", "simulate", "--out", str(tmp_path / "sim.npz"), "--sequences", "1", "--no-progress"]
    )
    _one_error(result, "sim.npz", "folder")
    result = runner.invoke(
        studies_app, ["stnet", "simulate", "--out", str(unwritable / "sim.npz"), "--sequences", "1", "--no-progress"]
    )
    _one_error(result, "sim.npz", "cannot be written")
    result = runner.invoke(
        studies_app, ["stnet", "simulate", "--out", str(tmp_path / "sim.txt"), "--sequences", "1", "--no-progress"]
    )
    _one_error(result, "sim.txt", ".npz")


def test_write_failure_inside_atomic_path_is_one_line(tmp_path):
    from slipsense.atomic import write_text
    from slipsense.errors import OutputError

    (tmp_path / "d").mkdir()
    with pytest.raises(OutputError, match="is a folder"):
        write_text(tmp_path / "d", "x")
    (tmp_path / "f").write_text("mine")
    with pytest.raises(OSError):  # an OutputError is an OSError too: caches that only warn still catch it
        write_text(tmp_path / "f" / "below.txt", "x")
    assert (tmp_path / "f").read_text() == "mine"


# checkpoint configs --------------------------------------------------------------------------
def _rewrite_config(src: Path, dst: Path, **changes) -> Path:
    from safetensors import safe_open
    from safetensors.torch import save_file

    with safe_open(str(src), framework="pt") as fh:
        meta = fh.metadata()
        tensors = {k: fh.get_tensor(k) for k in fh.keys()}
    info = json.loads(meta["slipsense"])
    for k, v in changes.items():
        if k == "model_config":
            info["model_config"] = v
        else:
            info["model_config"][k] = v
    save_file(tensors, str(dst), metadata={"slipsense": json.dumps(info)})
    return dst


@pytest.mark.parametrize(
    "change, word",
    [
        ({"d_model": 10**9}, "out of range"),
        ({"blocks": 10**7}, "out of range"),
        ({"ff_dim": 4000, "blocks": 400}, "missing"),  # in range; refused on the meta device
        ({"ff_dim": 16}, "has shape"),
        ({"model_config": [8, 2]}, "mapping"),
        ({"d_model": float("inf")}, "out of range"),
    ],
)
def test_checkpoint_configs_out_of_bounds_are_refused_before_allocating(tmp_path, run_dir, change, word):
    import time

    bad = _rewrite_config(run_dir / "last.safetensors", tmp_path / "bad.safetensors", **change)
    t = time.perf_counter()
    result = runner.invoke(
        app,
        [
            "evaluate",
            "--checkpoint",
            str(bad),
            "--markers",
            str(tmp_path / "m.npz"),
            "--json",
            str(tmp_path / "e.json"),
            "--no-progress",
        ],
    )
    _one_error(result, "bad.safetensors", word)
    assert time.perf_counter() - t < 60  # refused from the header, not after building the model (slack: shared CPU)


# recordings ----------------------------------------------------------------------------------
def test_skip_leaves_out_a_run_whose_cameras_differ_in_frame_count(tmp_path, cache, recwarn):
    root = tmp_path / "rec"
    _good_run(root, obj="cup")
    _video(root / "mug" / "exp_num_1" / "camera_0.avi", 30)
    _video(root / "mug" / "exp_num_1" / "camera_2.avi", 24)
    csv_out = tmp_path / "l.csv"
    result = runner.invoke(app, ["label", "--recordings", str(root), "--csv", str(csv_out), "--no-progress"])
    _one_error(result, "mug", "differ in frame count")
    result = runner.invoke(
        app, ["label", "--recordings", str(root), "--csv", str(csv_out), "--on-error", "skip", "--no-progress"]
    )
    assert result.exit_code == 0, result.output
    # (pytest records warnings; the command line prints each as one "warning: ..." line)
    assert any("mug" in str(w.message) and "skipped" in str(w.message) for w in recwarn.list)
    rows = csv_out.read_text().strip().splitlines()[1:]
    assert len(rows) == 2 and all(r.startswith("cup,") for r in rows)


def test_one_camera_and_upper_case_avi_are_warned_about(tmp_path, cache, recwarn):
    root = tmp_path / "rec"
    _video(root / "cup" / "exp_num_1" / "camera_0.avi", 30)
    (root / "cup" / "exp_num_1" / "camera_0.avi").rename(root / "cup" / "exp_num_1" / "camera_2.AVI")
    _video(root / "cup" / "exp_num_1" / "camera_0.avi", 30)
    result = runner.invoke(app, ["label", "--recordings", str(root), "--csv", str(tmp_path / "l.csv"), "--no-progress"])
    assert result.exit_code == 0, result.output
    warned = [str(w.message) for w in recwarn.list]
    assert any("camera_2.AVI" in l and "not used" in l for l in warned), warned
    assert any("only one sensor video" in l for l in warned), warned


@pytest.mark.parametrize(
    "row, words",
    [
        ("plate,1,,20", ["line 2", "unknown object 'plate'"]),
        ("cup,7,,20", ["line 2", "no experiment 7"]),
        ("cup,1,,500", ["line 2", "moment 500 is outside 0..29"]),
        ("cup,1,camera_2,40", ["line 2", "outside"]),
    ],
)
def test_override_csv_errors_name_file_and_line(tmp_path, cache, row, words):
    root = tmp_path / "rec"
    _good_run(root)
    ov = tmp_path / "hand.csv"
    ov.write_text("object,experiment,camera,moment_of_slip\n" + row + "\n")
    result = runner.invoke(
        app,
        ["label", "--recordings", str(root), "--csv", str(tmp_path / "l.csv"), "--overrides", str(ov), "--no-progress"],
    )
    _one_error(result, str(ov), *words)
    assert not (tmp_path / "l.csv").exists()


# marker files --------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "extra, word",
    [
        ({"fps": np.array("fast")}, "fps"),
        ({"fps": np.array(-3.0)}, "fps"),
        ({"object": np.zeros(24, np.int64), "object_names": np.array("cup")}, "object_names"),
    ],
)
def test_marker_npz_metadata_is_checked(tmp_path, extra, word):
    path = _markers_npz(tmp_path / "meta.npz", **extra)
    result = runner.invoke(app, ["train", *TINY_TRAIN_ARGS, "--markers", str(path), "--out", str(tmp_path / "r")])
    _one_error(result, "meta.npz", word)


def test_marker_values_out_of_range_are_refused(tmp_path):
    x = np.zeros((24, 4, 5, 3), np.float32)
    x[3, 2, 1, 0] = 1e30
    path = tmp_path / "huge.npz"
    np.savez(path, x=x, y=np.arange(24) % 2, groups=np.arange(24) // 2)
    result = runner.invoke(app, ["train", *TINY_TRAIN_ARGS, "--markers", str(path), "--out", str(tmp_path / "r")])
    _one_error(result, "huge.npz", "out of range", "sample 3, frame 2, marker 1")


def test_marker_npz_reads_only_the_keys_it_uses(tmp_path):
    from slipsense.sensors.marker_npz import load_marker_npz

    # an unused object array (it would need unpickling) and an unused big one are never read
    path = _markers_npz(tmp_path / "extra.npz", notes=np.array([{"a": 1}], dtype=object))
    ds = load_marker_npz(path)
    assert ds.x.shape == (24, 4, 5, 3)


# numbers -------------------------------------------------------------------------------------
@pytest.mark.parametrize("cmd", ["train", "simulate"])
@pytest.mark.parametrize("seed", ["-5", str(2**40)])
def test_bad_seeds(tmp_path, cmd, seed):
    _markers_npz(tmp_path / "m.npz")
    args = {
        "train": ["train", *TINY_TRAIN_ARGS, "--markers", str(tmp_path / "m.npz"), "--out", str(tmp_path / "r")],
        "simulate": ["stnet", "simulate", "--out", str(tmp_path / "s.npz"), "--no-progress"],
    }[cmd]
    result = runner.invoke(studies_app if cmd == "simulate" else app, [*args, "--seed", seed])
    _one_error(result, "--seed")
    assert not (tmp_path / "r").exists() and not (tmp_path / "s.npz").exists()


@pytest.mark.parametrize("std", ["-5", "nan", "inf"])
def test_bad_noise_std(tmp_path, run_dir, std):
    result = runner.invoke(
        app,
        [
            "evaluate",
            "--checkpoint",
            str(run_dir / "last.safetensors"),
            "--markers",
            str(tmp_path / "m.npz"),
            "--json",
            str(tmp_path / "e.json"),
            "--noise-std",
            std,
        ],
    )
    _one_error(result, "--noise-std")
    assert not (tmp_path / "e.json").exists()


# library log noise ---------------------------------------------------------------------------
def test_corrupt_and_foreign_videos_make_no_library_log_noise(tmp_path):
    good = _video(tmp_path / "good.avi", 40)
    data = bytearray(good.read_bytes())
    for k in range(len(data) // 3, len(data) - 2000, 997):
        data[k] ^= 0xFF
    (tmp_path / "corrupt.avi").write_bytes(bytes(data))
    (tmp_path / "fake.avi").write_bytes(b"RIFF\x00\x00\x00\x00AVI not really a video")
    code = (
        "import sys\nfrom slipsense.recordings.video import probe_video, read_video\n"
        "for p in sys.argv[1:]:\n"
        "    try:\n        probe_video(p, expected_size=None); read_video(p, expected_size=None)\n"
        "    except Exception as e:\n        print('refused', e)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "OPENCV_FFMPEG_LOGLEVEL"}
    proc = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path / "corrupt.avi"), str(tmp_path / "fake.avi")],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == "", proc.stderr  # no "[mpeg4 @ 0x...] ac-tex damaged", no "[ WARN:0] ..."
    assert "refused" in proc.stdout and "fake.avi" in proc.stdout


@pytest.mark.parametrize("sensor", [{"name": "x", "output": "video", "fps": -1}, {"name": "x", "fps": 25}, "mini"])
def test_checkpoint_with_a_malformed_sensor_spec_is_refused(tmp_path, sensor):
    from safetensors.torch import load_file, save_file

    from slipsense.checkpoint import META_KEY, read_info
    from slipsense.streaming.detector import DEFAULT_CHECKPOINT

    info = {**read_info(DEFAULT_CHECKPOINT), "sensor": sensor}
    bad = tmp_path / "sensor.safetensors"
    save_file(load_file(str(DEFAULT_CHECKPOINT)), str(bad), metadata={META_KEY: json.dumps(info)})
    run = tmp_path / "run"
    run.mkdir()
    for cam in (0, 2):
        w = cv2.VideoWriter(str(run / f"camera_{cam}.avi"), cv2.VideoWriter_fourcc(*"XVID"), 25, (64, 48))
        for _ in range(3):
            w.write(np.zeros((48, 64, 3), np.uint8))
        w.release()
    result = runner.invoke(app, ["watch", str(run), "--checkpoint", str(bad)])
    assert result.exit_code == 2, result.output
    line = _error_line(result)
    assert "sensor.safetensors" in line and "sensor" in line, line
