"""Reliability promises of issue 12 (docs/reliability.md): run folders never run code, training and
evaluation refuse empty data, a refused --resume writes nothing, caches are verified."""

from __future__ import annotations

import json
import math
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from slipsense.checkpoint import load_resume_state, save_resume_state
from conftest import TINY_TRAIN_ARGS
from slipsense.cli import app
from slipsense.errors import InputError

runner = CliRunner()

#: A TemNet small enough to train in a fraction of a second.


def _markers(path: Path, n: int = 24, groups=None, frames: int = 4, markers: int = 5) -> Path:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(n, frames, markers, 3)).astype(np.float32)
    y = np.arange(n) % 2
    g = np.arange(n) // 2 if groups is None else np.asarray(groups)
    np.savez(path, x=x, y=y, groups=g)
    return path


def _error_line(result) -> str:
    text = result.stderr if hasattr(result, "stderr") else result.output
    lines = [l for l in text.splitlines() if l.startswith("error: ")]
    assert len(lines) == 1, text
    assert "Traceback" not in text, text
    return lines[0]


def _train(tmp_path, out, *extra):
    return runner.invoke(
        app, ["train", *TINY_TRAIN_ARGS, "--markers", str(tmp_path / "m.npz"), "--out", str(out), *extra]
    )


# ------------------------------------------------------------------------------ 1. no pickles
class _Evil:
    """Unpickling this creates the file ``marker``: what a planted resume.pt could do."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


@pytest.mark.parametrize("fmt", ["pickle", "torch.save"])
def test_malicious_resume_state_is_refused_and_not_run(tmp_path, fmt):
    _markers(tmp_path / "m.npz")
    out = tmp_path / "run"
    assert _train(tmp_path, out, "--epochs", "1").exit_code == 0
    split_before = (out / "split.json").read_bytes()
    marker = tmp_path / "pwned"
    if fmt == "pickle":
        (out / "resume.pt").write_bytes(pickle.dumps(_Evil(marker)))
    else:
        torch.save({"model": _Evil(marker)}, out / "resume.pt")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    result = _train(tmp_path, out, "--epochs", "2", "--resume")
    assert result.exit_code == 2, result.output
    line = _error_line(result)
    assert "resume.pt" in line and "pickle" in line, line
    assert not marker.exists()
    # nothing in the run folder was touched
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert (out / "split.json").read_bytes() == split_before


def test_resume_state_is_data_only_and_round_trips(tmp_path):
    import random

    state = {
        "model": {"w": torch.randn(3, 2), "tied": torch.arange(4)},
        "optimizer": {
            "state": {0: {"step": torch.tensor(3.0)}},
            "param_groups": [{"lr": 1e-3, "betas": (0.9, 0.999), "params": [0], "foreach": None}],
        },
        "scheduler": {"last_epoch": 2},
        "rng": {"python": random.getstate(), "numpy": np.random.get_state(), "torch": torch.get_rng_state()},
        "history": [{"epoch": 1, "val_loss": math.inf}],
        "best": -math.inf,
        "epoch": 0,
    }
    path = tmp_path / "resume.pt"
    save_resume_state(path, state)
    back = load_resume_state(path)
    assert back["optimizer"]["state"][0]["step"].item() == 3.0  # int keys survive
    assert back["optimizer"]["param_groups"][0]["betas"] == (0.9, 0.999)
    assert back["rng"]["python"] == state["rng"]["python"]
    np.testing.assert_array_equal(back["rng"]["numpy"][1], state["rng"]["numpy"][1])
    assert back["rng"]["numpy"][1].dtype == np.uint32
    assert torch.equal(back["rng"]["torch"], state["rng"]["torch"])
    assert back["best"] == -math.inf and back["history"][0]["val_loss"] == math.inf
    # The file is plain safetensors: no pickle opcodes, nothing to execute.
    assert path.read_bytes()[8:9] == b"{"
    with pytest.raises(TypeError, match="plain data"):
        save_resume_state(tmp_path / "bad.pt", {**state, "model": _Evil(tmp_path / "x")})


def test_damaged_resume_states_are_one_line_errors(tmp_path):
    path = tmp_path / "resume.pt"
    save_resume_state(
        path, {"model": {}, "optimizer": {}, "scheduler": {}, "rng": {}, "history": [], "best": 0.0, "epoch": 1}
    )
    data = path.read_bytes()
    for name, payload, word in [
        ("trunc", data[:-3] if len(data) > 200 else data[:20], "unreadable"),
        ("empty", b"", "not a slipsense resume"),
        ("text", b"hello world, not a state", "not a slipsense resume"),
    ]:
        p = tmp_path / f"{name}.pt"
        p.write_bytes(payload)
        with pytest.raises(InputError, match=word):
            load_resume_state(p)
    from safetensors.torch import save_file

    save_file(
        {"a": torch.zeros(1)},
        str(tmp_path / "foreign.pt"),
        metadata={"slipsense-resume": '{"format": 1, "state": {"__code__": 1}}'},
    )
    with pytest.raises(InputError, match="malformed"):
        load_resume_state(tmp_path / "foreign.pt")


def test_resume_of_another_model_changes_nothing(tmp_path):
    _markers(tmp_path / "m.npz")
    out = tmp_path / "run"
    assert _train(tmp_path, out, "--epochs", "1").exit_code == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    # another size: the weights in resume.pt do not fit
    result = runner.invoke(
        app,
        [
            "train",
            *TINY_TRAIN_ARGS,
            "--set",
            "ff_dim=16",
            "--markers",
            str(tmp_path / "m.npz"),
            "--out",
            str(out),
            "--epochs",
            "2",
            "--resume",
        ],
    )
    assert result.exit_code == 2, result.output
    assert "resume.pt" in _error_line(result) and "does not fit the model" in _error_line(result)
    # another split: split.json would change
    _markers(tmp_path / "m2.npz", groups=np.arange(24) // 3)
    result = runner.invoke(
        app,
        [
            "train",
            *TINY_TRAIN_ARGS,
            "--markers",
            str(tmp_path / "m2.npz"),
            "--out",
            str(out),
            "--epochs",
            "2",
            "--resume",
        ],
    )
    assert result.exit_code == 2, result.output
    assert "split.json" in _error_line(result) and "test_indices" in _error_line(result)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    # another learning rate: the optimisation would not be the one that began
    result = _train(tmp_path, out, "--epochs", "2", "--lr", "0.5", "--resume")
    assert result.exit_code == 2, result.output
    assert "resume.pt" in _error_line(result) and "settings differ" in _error_line(result)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    # the same command resumes
    result = _train(tmp_path, out, "--epochs", "2", "--resume")
    assert result.exit_code == 0, result.output
    assert len((out / "metrics.csv").read_text().strip().splitlines()) == 3


# ------------------------------------------------------------------------- 2. nothing is not success
def _recordings(root: Path, objects=("cup", "pen"), n: int = 30, cameras=("camera_0", "camera_2")) -> Path:
    """One slip run per object (uniform grey videos) and an override CSV giving each a moment of slip."""
    import cv2

    rows = ["object,experiment,camera,moment_of_slip"]
    for obj in objects:
        folder = root / obj / "exp_num_1"
        folder.mkdir(parents=True)
        (folder / "slip.txt").write_text("")
        for cam in cameras:
            vw = cv2.VideoWriter(str(folder / f"{cam}.avi"), cv2.VideoWriter_fourcc(*"XVID"), 25.0, (320, 240))
            for i in range(n):
                vw.write(np.full((240, 320, 3), 80 + i, np.uint8))
            vw.release()
        rows.append(f"{obj},1,,{n - 5}")
    (root.parent / "overrides.csv").write_text("\n".join(rows) + "\n")
    return root


def test_training_with_every_object_held_out_is_refused(tmp_path, cache):
    rec = _recordings(tmp_path / "rec")
    out = tmp_path / "run"
    result = runner.invoke(
        app,
        [
            "train",
            "--model",
            "vivit",
            "--recordings",
            str(rec),
            "--overrides",
            str(tmp_path / "overrides.csv"),
            "--size",
            "48x64",
            "--frames",
            "2",
            "--test-objects",
            "cup,pen",
            "--out",
            str(out),
            "--no-progress",
        ],
    )
    assert result.exit_code == 2, result.output
    assert "nothing is left to train on" in _error_line(result)
    assert not out.exists()


def test_training_on_markers_of_one_group_is_refused(tmp_path):
    _markers(tmp_path / "m.npz", groups=np.zeros(24, int))
    result = _train(tmp_path, tmp_path / "run", "--epochs", "1")
    assert result.exit_code == 2, result.output
    line = _error_line(result)
    assert "m.npz" in line and "one group" in line
    assert not (tmp_path / "run").exists()


def test_fit_refuses_an_empty_training_set(tmp_path):
    from slipsense.datasets import MarkerDataset
    from slipsense.errors import ConfigError
    from slipsense.models import build
    from slipsense.training.clips import TrainConfig, fit

    model = build("temnet", frames=4, markers=5, d_model=8, heads=2, blocks=1, ff_dim=8, head_hidden=0)
    empty = MarkerDataset(np.zeros((0, 4, 5, 3), np.float32), np.zeros(0, np.int64))
    with pytest.raises(ConfigError, match="training set is empty"):
        fit(model, empty, None, TrainConfig(epochs=1, progress=False), tmp_path / "run")
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    "split, word",
    [
        ({"kind": "markers", "test_indices": []}, "no test items"),
        ({"kind": "markers"}, "lacks test_indices"),
        ({"kind": "markers", "test_indices": [0, -1]}, "negative"),
        ({"kind": "markers", "test_indices": [0, 500]}, "out of range"),
        ({"kind": "markers", "test_indices": [1, 1]}, "repeats"),
        ({"kind": "markers", "test_indices": "0,1"}, "list of integers"),
        ({"kind": "markers", "test_indices": [0.5]}, "list of integers"),
        ({"kind": "video", "test_indices": [0]}, "video data"),
        ([1, 2, 3], "JSON object"),
    ],
)
def test_bad_split_files_are_refused(tmp_path, split, word):
    _markers(tmp_path / "m.npz")
    assert _train(tmp_path, tmp_path / "run", "--epochs", "1").exit_code == 0
    if isinstance(split, dict) and split.get("kind") == "markers" and "markers" not in split:
        split["markers"] = str(tmp_path / "m.npz")
    path = tmp_path / "split.json"
    path.write_text(json.dumps(split))
    json_out = tmp_path / "eval.json"
    result = runner.invoke(
        app,
        [
            "evaluate",
            "--checkpoint",
            str(tmp_path / "run" / "last.safetensors"),
            "--split-file",
            str(path),
            "--json",
            str(json_out),
            "--no-progress",
        ],
    )
    assert result.exit_code == 2, result.output
    line = _error_line(result)
    assert "split.json" in line and word in line, line
    assert not json_out.exists()


def test_resume_files_are_told_apart_by_content_not_by_their_first_byte(tmp_path):
    # a safetensors header length whose low byte is 0x80 (the pickle protocol opcode) still loads
    base = {"model": {}, "optimizer": {}, "scheduler": {}, "rng": {}, "history": [], "best": 0.0, "epoch": 0}
    seen = set()
    for pad in range(0, 300):
        path = tmp_path / f"r{pad}.pt"
        save_resume_state(path, {**base, "history": [{"note": "x" * pad}]})
        seen.add(path.read_bytes()[0])
        assert load_resume_state(path)["history"][0]["note"] == "x" * pad
    assert 0x80 in seen


def test_a_marker_file_on_a_grid_makes_a_checkpoint_that_replays_on_that_grid(tmp_path):
    """`slipsense markers` writes how it took the markers from the videos (`marker_layout`); a model
    trained on that file keeps it, so its replay takes a camera's markers the same way. A file without
    one (simulated, a user's) makes a model that is not replayed over videos."""
    from slipsense.errors import ConfigError
    from slipsense.evaluation.replay import replay_recordings
    from slipsense.streaming.detector import SlipDetector

    path = _markers(tmp_path / "m.npz", markers=6)
    with np.load(path) as z:
        arrays = dict(z)
    np.savez(path, **arrays, marker_layout=np.array("2x3"))
    assert _train(tmp_path, tmp_path / "r", "--epochs", "1").exit_code == 0
    det = SlipDetector.from_checkpoint(tmp_path / "r" / "last.safetensors", threshold=0.5)
    assert det.cache_product == "markers:2x3"
    assert det.sensor.name == "gelsight-mini"  # tracked in GelSight videos: replayed over their folders
    assert json.loads((tmp_path / "r" / "split.json").read_text())["clip_spec"] == {"marker_layout": "2x3"}
    np.savez(path, **arrays, marker_layout=np.array("2x2"))
    assert "marker_layout '2x2' holds 4 markers, x has 6" in _error_line(_train(tmp_path, tmp_path / "s"))
    np.savez(path, **arrays, marker_layout=np.array("two"))
    assert "marker_layout is unreadable" in _error_line(_train(tmp_path, tmp_path / "u"))
    np.savez(path, **arrays)  # no grid: the markers as they are
    assert _train(tmp_path, tmp_path / "t", "--epochs", "1").exit_code == 0
    evaluated = runner.invoke(
        app, ["evaluate", "--checkpoint", str(tmp_path / "r" / "last.safetensors"), "--markers", str(path)]
    )
    assert evaluated.exit_code == 2  # the file's markers were not taken as the checkpoint's were
    assert "holds markers not tracked in videos" in _error_line(evaluated) and "'2x3'" in _error_line(evaluated)
    untracked = SlipDetector.from_checkpoint(tmp_path / "t" / "last.safetensors", threshold=0.5)
    assert untracked.cache_product is None
    with pytest.raises(ConfigError, match="not tracked in videos"):
        replay_recordings(untracked, [], {}, progress=False)
