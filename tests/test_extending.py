"""docs/extending.md done once, in this file alone: a new sensor (another folder layout and frame
rate) and a new model, then every verb on them through the command line."""

from __future__ import annotations

import json

import pytest
import torch
from torch import nn
from typer.testing import CliRunner

from conftest import write_grasp_video
from slipsense.checkpoint import read_info
from slipsense.cli import app
from slipsense.errors import InputError
from slipsense.models.base import VideoModel, check_video_values, register
from slipsense.sensors.spec import SensorSpec, register_sensor
from slipsense.streaming.detector import SlipDetector

TOY_SENSOR = register_sensor(
    SensorSpec(
        name="test-toy-sensor",
        output="video",
        fps=50.0,
        image_size=(48, 64),
        camera_glob="finger_*.avi",
        experiment_pattern=r"^trial(\d+)$",
        slip_marker="SLIPPED",
    )
)


@register("test-toy-net")
class ToyNet(VideoModel):
    """Mean colour of each frame -> a linear layer over time: the smallest model of the contract."""

    def __init__(self, frames: int = 3, image_size=(24, 32)):
        super().__init__()
        self.frames, self.image_size = int(frames), tuple(image_size)
        self.head = nn.Linear(3 * self.frames, 2)

    def config(self) -> dict:
        return {"frames": self.frames, "image_size": list(self.image_size)}

    def check_input(self, x):
        if x.ndim != 5 or tuple(x.shape[1:]) != (self.frames, 3, *self.image_size):
            raise InputError(None, f"test-toy-net takes (B, {self.frames}, 3, {self.image_size}), got {tuple(x.shape)}")
        check_video_values(x)

    def forward(self, x):
        self.check_input(x)
        return self.head(x.mean(dim=(3, 4)).flatten(1))


@pytest.fixture(scope="module")
def toy_recordings(tmp_path_factory):
    """The toy sensor's layout: <object>/trial<N>/finger_<k>.avi, SLIPPED when it slipped."""
    root = tmp_path_factory.mktemp("toy")
    for i in range(4):
        for exp, slip in ((1, True), (2, False)):
            for cam in (0, 1):
                path = root / f"obj{i}" / f"trial{exp}" / f"finger_{cam}.avi"
                write_grasp_video(path, 70, (20, 50 if slip else 69), slip, seed=100 * i + 10 * exp + cam)
            if slip:
                (root / f"obj{i}" / f"trial{exp}" / "SLIPPED").write_text("")
    return root


def _ok(args):
    res = CliRunner().invoke(app, [str(a) for a in args])
    assert res.exit_code == 0, res.output
    return res


def test_a_new_model_on_a_new_sensor_through_every_verb(tmp_path, toy_recordings, cache):
    out = tmp_path / "toy"
    common = ["--recordings", toy_recordings, "--set", "data.sensor=test-toy-sensor", "--test-objects", "obj3"]
    _ok(["train", "--model", "test-toy-net", *common, "--frames", 3, "--size", "24x32", "--epochs", 1,
         "--out", out, "--no-progress"])  # fmt: skip
    assert read_info(out / "last.safetensors")["sensor"]["fps"] == 50.0
    _ok(["evaluate", "--checkpoint", out / "last.safetensors", "--split-file", out / "split.json",
         "--json", tmp_path / "e.json", "--no-progress"])  # fmt: skip
    assert json.loads((tmp_path / "e.json").read_text())["n_clips"] > 0
    _ok(["export", "--checkpoint", out / "last.safetensors", "--out", tmp_path / "toy.onnx"])
    res = _ok(["watch", toy_recordings / "obj3" / "trial1", "--checkpoint", out / "last.safetensors",
               "--max-frames", 10, "--threshold", 0.5])  # fmt: skip
    assert sum(line.startswith("frame") for line in res.output.splitlines()) == 10

    grasp = tmp_path / "grasp"  # the default detector's recipe on the new sensor
    _ok(["train", "--model", "motionnet", *common, "--set", "train.inner_folds=0", "--epochs", 1,
         "--out", grasp, "--no-progress"])  # fmt: skip
    det = SlipDetector.from_checkpoint(grasp / "detector.safetensors")
    assert det.sensor == TOY_SENSOR and det.sensors == 2
    _ok(["evaluate", "--checkpoint", grasp / "detector.safetensors", "--recordings", toy_recordings,
         "--json", tmp_path / "g.json", "--no-progress"])  # fmt: skip
    assert json.loads((tmp_path / "g.json").read_text())["per_grasp"]["slip_runs"] == 4


def test_an_unknown_sensor_is_one_line(tmp_path, toy_recordings):
    res = CliRunner().invoke(
        app,
        ["train", "--model", "motionnet", "--recordings", str(toy_recordings), "--set", "data.sensor=nope",
         "--out", str(tmp_path / "x")],
    )  # fmt: skip
    assert res.exit_code == 2 and "unknown sensor 'nope'" in res.output and "gelsight-mini" in res.output


def test_toy_model_streams_like_its_forward(one_thread):
    import numpy as np

    torch.manual_seed(0)
    model = ToyNet().eval()
    det = SlipDetector(model)
    assert det.geometry["frames"] == 3 and det.geometry["image_size"] == (24, 32)
    frames = np.random.default_rng(0).integers(0, 256, (5, 24, 32, 3), dtype=np.uint8)
    readings = [det.push(f) for f in frames]
    window = torch.from_numpy(frames[-3:]).permute(0, 3, 1, 2).float()[None] / 255.0
    with torch.no_grad():
        want = float(torch.softmax(model(window), -1)[0, 1])
    assert readings[1].probability is None and abs(readings[-1].probability - want) < 1e-6
