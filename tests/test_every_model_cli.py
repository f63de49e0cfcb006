"""One product: every registered model goes through the same verbs on the command line.

For each model (at its contract size): ``slipsense train --model NAME``, the same training SIGKILLed
after its first epoch and continued with ``--resume`` (the same weights), ``slipsense evaluate`` (per grasp for a
grasp model, per clip for clip and marker models), ``slipsense export`` (ONNX files verified against
PyTorch) and ``slipsense watch`` (a real recording where the shared data is there, or a marker stream). A new registered model is covered
by this test without a line of its own; what differs per kind is only the data it is given.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from safetensors.torch import load_file
from typer.testing import CliRunner

from slipsense.checkpoint import read_info
from slipsense.cli import app
from slipsense.models import available, model_class

BUILT_IN = [name for name in available() if not name.startswith("test-")]


def _markers(path, frames: int, markers: int):
    rng = np.random.default_rng(0)
    x = rng.normal(0, 1, (24, frames, markers, 3)).astype(np.float32)
    y = (x[:, -1, :, 0].mean(1) > 0).astype(np.int64)
    np.savez(path, x=x, y=y, groups=np.arange(24) // 2)
    np.save(path.with_suffix(".npy"), x[:10].reshape(-1, markers, 3))  # a 40-frame stream
    return path


def _invoke(args):
    res = CliRunner().invoke(app, [str(a) for a in args])
    assert res.exit_code == 0, f"{args[0]}: {res.output}"
    return res


@pytest.mark.parametrize("name", BUILT_IN)
def test_every_model_trains_resumes_evaluates_exports_and_streams(name, tmp_path, grasp_recordings, cache, one_thread):
    cls = model_class(name)
    small = cls.small_config()
    sets = [x for k, v in small.items() for x in ("--set", f"model.{k}={json.dumps(v)}")]
    out = tmp_path / "run"
    from conftest import REAL_RUN, killed_once

    # watched: a real recording where the shared data is there (both cameras), else a made-up one
    run_folder = REAL_RUN if (REAL_RUN / "camera_0.avi").is_file() else grasp_recordings / "obj0" / "exp_num_1"
    if cls.input_kind == "markers":
        npz = _markers(tmp_path / "m.npz", small["frames"], small["markers"])
        data, stream = ["--markers", npz], npz.with_suffix(".npy")
    elif cls.input_kind == "video":
        size = small.get("image_size", [48, 64])
        data = ["--recordings", grasp_recordings, "--frames", small["frames"], "--size", f"{size[0]}x{size[1]}"]
        stream = run_folder
    else:
        data, stream = ["--recordings", grasp_recordings, "--set", "train.inner_folds=0"], run_folder
    train = ["train", "--model", name, *sets, *data, "--epochs", 6, "--test-objects", "obj3", "--no-progress"]
    _invoke([*train, "--out", out])
    ckpt = out / ("detector.safetensors" if cls.training_task == "grasps" else "last.safetensors")
    op = read_info(ckpt).get("operating_point")  # every detector on recordings alarms at a chosen point
    assert (op is not None) == (cls.input_kind != "markers")
    assert op is None or ("training" in op["chosen_on"] and 0 <= op["threshold"] <= 1)

    # SIGKILLed once its first epoch is saved, then --resume: the weights of the uninterrupted run
    # (every run on one thread: float sums split over two threads round differently)
    cut = tmp_path / "cut"
    state = cut / ("resume/job0.state" if cls.training_task == "grasps" else "resume.pt")
    assert killed_once(state, [*train, "--out", cut]) < 6  # killed mid-training
    _invoke([*train, "--out", cut, "--resume"])
    whole, resumed = load_file(str(ckpt)), load_file(str(cut / ckpt.name))
    assert whole.keys() == resumed.keys() and all(bool((whole[k] == resumed[k]).all()) for k in whole)

    where = (
        ["--recordings", grasp_recordings] if cls.training_task == "grasps" else ["--split-file", out / "split.json"]
    )
    _invoke(["evaluate", "--checkpoint", ckpt, *where, "--json", tmp_path / "e.json", "--no-progress"])
    doc = json.loads((tmp_path / "e.json").read_text())
    # per grasp where runs replay (grasp and video models), per clip for every model
    assert ("per_grasp" in doc) == (cls.input_kind != "markers") and ("accuracy" in doc or "clips" in doc)

    res = _invoke(["export", "--checkpoint", ckpt, "--out", tmp_path / "m.onnx"])
    diffs = [float(line.rsplit("= ", 1)[1].rstrip(")")) for line in res.output.splitlines() if "max |onnx" in line]
    assert (tmp_path / "m.onnx").is_file() and diffs and max(diffs) <= 1e-4

    # on PyTorch: each model's ONNX Runtime stream is held to it in tests/test_model_contract.py
    res = _invoke(["watch", stream, "--checkpoint", ckpt, "--max-frames", 30, "--threshold", 0.5, "--backend", "torch"])
    assert sum(line.startswith("frame") for line in res.output.splitlines()) == 30


def test_a_clip_model_is_replayed_with_the_cameras_the_runs_have(tmp_path, grasp_recordings, cache):
    """Per grasp, a clip model sees every camera of a run; runs of one camera replay with one sensor,
    and runs that differ in camera count leave the clip metrics standing (the replay is skipped)."""
    import shutil

    small = model_class("vivit").small_config()
    sets = [x for k, v in small.items() for x in ("--set", f"model.{k}={json.dumps(v)}")]
    out = tmp_path / "vivit"
    _invoke(["train", "--model", "vivit", *sets, "--recordings", grasp_recordings, "--frames", 3, "--size", "48x64",
             "--epochs", 1, "--split", "all", "--out", out, "--no-progress"])  # fmt: skip
    one, mixed = tmp_path / "one", tmp_path / "mixed"
    for root in (one, mixed):
        shutil.copytree(grasp_recordings, root)
    for cam in one.glob("*/*/camera_2.avi"):
        cam.unlink()
    (mixed / "obj0" / "exp_num_1" / "camera_2.avi").unlink()
    for root, name in ((one, "one.json"), (mixed, "mixed.json")):
        res = CliRunner().invoke(
            app, ["evaluate", "--checkpoint", str(out / "last.safetensors"), "--recordings", str(root),
                  "--json", str(tmp_path / name), "--no-progress"],
        )  # fmt: skip
        assert res.exit_code == 0, res.output
    one_doc, mixed_doc = (json.loads((tmp_path / n).read_text()) for n in ("one.json", "mixed.json"))
    assert one_doc["per_grasp"]["slip_runs"] == 4 and one_doc["n_clips"] > 0
    assert "different numbers of camera" in mixed_doc["per_grasp"]["skipped"] and mixed_doc["n_clips"] > 0
