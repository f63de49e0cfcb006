"""What the command line and the README tell a user is what the code does: `slipsense models` lists
the shipped detectors, `export --help` names the files export writes, the README's `fit` names objects
that exist, every frame-rate message names one range, and a missing camera is one line."""

from __future__ import annotations

import ast
import inspect
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import typer.main
from typer.testing import CliRunner

import slipsense
from conftest import needs_data
from slipsense.cli import app
from slipsense.errors import SlipsenseError

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
runner = CliRunner()


# 1. `slipsense models` ------------------------------------------------------------------------
def test_models_lists_every_registered_model_and_every_shipped_detector_with_its_promise():
    from slipsense.checkpoint import read_info
    from slipsense.models import available
    from slipsense.resources import shipped_model, shipped_models

    res = runner.invoke(app, ["models"])
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    for name in available():
        assert any(line.split()[:1] == [name] for line in lines), name
    assert "127,268,027" in res.output  # STNet at the paper's size, counted without initialising it
    assert shipped_models(), "no shipped detector found"
    for name in shipped_models():
        info = read_info(shipped_model(name))
        row = next((line for line in lines if line.split()[:1] == [name]), None)
        assert row is not None, f"slipsense models does not list the shipped detector {name}"
        assert info["model"] in row and info["sensor"]["name"] in row and f"{info['sensor']['fps']:g}" in row
        from slipsense.cli.listing import detector_promise  # the one place the promise is read

        assert row.endswith(detector_promise(info)), row


# 2. `slipsense export --help` -----------------------------------------------------------------
def _streaming_help() -> str:
    export = typer.main.get_command(app).commands["export"]
    return next(p.help for p in export.params if p.name == "streaming")


def test_export_help_names_the_files_export_writes_for_every_model():
    """The parts export writes (``<stem>.<name>.onnx`` for each of the model's streaming parts, none
    where the only part is the whole model again: slipsense.streaming.export) are the ones the help
    names, and the help names no other."""
    import torch

    from slipsense.models import available, build
    from slipsense.models.base import window_geometry
    from slipsense.models.onnx import streaming_names

    text = _streaming_help()
    written = set()
    from slipsense.models import model_class

    # the library's own models (other tests register made-up ones in this process)
    for name in [n for n in available() if model_class(n).__module__.startswith("slipsense.models")]:
        with torch.device("meta"):
            model = build(name)
        # a model that fixes no frame size of its own streams at its checkpoint's clip size
        names = streaming_names(model, window_geometry(model, {"data": {"clip_spec": {"size": [60, 80]}}}))
        files = [] if names == ["window"] else [f"<stem>.{n}.onnx" for n in names]
        for f in files:
            assert f in text, f"export --help does not name {f}, which export writes for {name}"
        written |= set(files)
    named = set(re.findall(r"<stem>\.\w+\.onnx", text))
    assert named <= written, f"export --help names files export never writes: {sorted(named - written)}"


def test_export_of_the_shipped_detector_writes_what_the_help_names(tmp_path, one_thread):
    pytest.importorskip("onnx")
    res = runner.invoke(app, ["export", "--out", str(tmp_path / "m.onnx"), "--no-verify"])
    assert res.exit_code == 0, res.output
    parts = sorted(p.name for p in tmp_path.glob("m.*.onnx"))
    assert parts, "no streaming part written"
    text = _streaming_help()
    for name in parts:
        assert "<stem>" + name[1:] in text, f"export wrote {name}; its --help does not name it"


# 3. the README's Python -----------------------------------------------------------------------
def _readme_calls(function: str) -> list[ast.Call]:
    """Every call ``slipsense.<function>(...)`` in the README's inline and block code."""
    calls = []
    for snippet in re.findall(r"`([^`\n]+)`", README.read_text(encoding="utf-8")):
        try:
            tree = ast.parse(snippet)
        except SyntaxError:
            continue
        for node in ast.walk(tree):
            f = getattr(node, "func", None)
            if isinstance(f, ast.Attribute) and f.attr == function and getattr(f.value, "id", "") == "slipsense":
                calls.append(node)
    return calls


def test_readme_fit_and_evaluate_sentences_are_calls_the_api_takes():
    fits, evaluates = _readme_calls("fit"), _readme_calls("evaluate")
    assert fits and evaluates
    for call, function in [(c, slipsense.fit) for c in fits] + [(c, slipsense.evaluate) for c in evaluates]:
        args = [None] * len(call.args)
        kwargs = {k.arg: None for k in call.keywords}
        inspect.signature(function).bind(*args, **kwargs)  # TypeError: the README names another signature


@needs_data
def test_every_object_the_readme_holds_out_is_in_the_shared_recordings():
    """The README's ``fit(recordings, ..., held_out=[...])`` runs on the shared recordings of its quick
    start: each object it holds out must be one of them (``"mug"`` was not: it is ``"blue_mug"``)."""
    from slipsense.paths import gelsight_recordings
    from slipsense.recordings.folders import find_recordings

    objects = {r.object for r in find_recordings(gelsight_recordings(), on_error="skip")}
    held = [ast.literal_eval(k.value) for call in _readme_calls("fit") for k in call.keywords if k.arg == "held_out"]
    assert held, "the README's fit sentence holds no object out"
    for names in held:
        missing = sorted(set(names) - objects)
        assert not missing, f"README holds out {missing}, not objects of the shared recordings"


# 4. frame rates -------------------------------------------------------------------------------
RANGE = re.compile(r"(\d+(?:\.\d+)?) to (\d+(?:\.\d+)?) frames per second")


def _rate_errors(fps) -> dict[str, str]:
    """The message every rate check gives ``fps``: sensor.json, a checkpoint's sensor, --fps of
    watch, record and bag convert, a marker file's fps, and the simulator's and early-warning's."""
    from slipsense.recordings.bags import check_timing
    from slipsense.sensors import marker_npz
    from slipsense.sensors.spec import SensorSpec
    from slipsense.streaming.clock import check_fps
    from studies.grasp.early_warning import run_early_warning
    from studies.stnet.sim_model import SimConfig

    def message(fn) -> str:
        with pytest.raises((SlipsenseError, ValueError)) as caught:
            fn()
        return str(caught.value)

    return {
        "sensor spec": message(lambda: SensorSpec.from_dict({"name": "x", "output": "video", "fps": fps})),
        "--fps": message(lambda: check_fps(fps, "--fps")),
        "bag --fps": message(lambda: check_timing(fps)),
        "marker file": message(lambda: marker_npz._fps(np.array(float(fps)), "m.npz")),
        "simulator": message(lambda: SimConfig(fps=fps)),
        "early-warning --fps": message(lambda: run_early_warning(None, None, Path("unused"), fps=fps)),
    }


def _frames_with_sensor_json(root: Path, fps) -> Path:
    grasp = root / "mug" / "exp_num_1"
    grasp.mkdir(parents=True)
    for t in range(3):
        cv2.imwrite(str(grasp / f"frame_{t:04d}.jpg"), np.full((48, 64, 3), 100 + t, np.uint8))
    (root / "sensor.json").write_text(json.dumps({"name": "mine", "output": "video", "fps": fps}))
    return grasp


def test_a_rate_of_0_and_of_500_get_the_same_range_everywhere(tmp_path):
    ranges = {}
    for fps in (0, 500):
        grasp = _frames_with_sensor_json(tmp_path / str(fps), fps)
        res = runner.invoke(app, ["watch", str(grasp), "--max-frames", "1"])
        assert res.exit_code == 2, res.output
        line = res.output.strip().splitlines()[-1]
        assert "sensor.json" in line and RANGE.search(line), line
        ranges[f"sensor.json {fps}"] = RANGE.search(line).groups()
        for where, text in _rate_errors(fps).items():
            assert RANGE.search(text), f"{where}, rate {fps}: {text}"
            ranges[f"{where} {fps}"] = RANGE.search(text).groups()
    assert set(ranges.values()) == {("1", "240")}, ranges


# 5. a camera that is not there ----------------------------------------------------------------
def test_watching_cameras_that_are_not_there_is_one_error_line():
    indices = (98, 99)
    if any(Path(f"/dev/video{i}").exists() for i in indices):
        pytest.skip("a camera is at the index this test takes to be free")
    env = {k: v for k, v in os.environ.items() if k != "OPENCV_LOG_LEVEL"} | {"OMP_NUM_THREADS": "1"}
    proc = subprocess.run(
        [sys.executable, "-m", "slipsense.cli", "watch", ",".join(map(str, indices)), "--max-frames", "1"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=env,
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "camera 98" in lines[0], proc.stderr


# 6. the README's length -----------------------------------------------------------------------
MAX_README_LINES = 150


def test_readme_is_at_most_150_lines():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= MAX_README_LINES, f"README.md has {len(lines)} lines; at most {MAX_README_LINES}"


def test_words_that_said_something_untrue_now_say_what_is_wrong(tmp_path, monkeypatch):
    """A --checkpoint that is not there is not told to pass --checkpoint; an empty folder names both
    layouts; an empty grasp folder is called empty, not misnamed; adapt on a bad folder leaves no
    empty --out behind; the promise says which objects are its units."""
    monkeypatch.chdir(tmp_path)
    res = runner.invoke(app, ["watch", str(tmp_path), "--checkpoint", "nope.safetensors", "--max-frames", "1"])
    assert res.exit_code == 2 and "pass --checkpoint" not in res.output and "nope.safetensors" in res.output
    (tmp_path / "empty").mkdir()
    res = runner.invoke(app, ["evaluate", "--recordings", "empty", "--no-progress"])
    assert res.exit_code == 2 and "camera_*.avi" in res.output and "frame folders" in res.output, res.output
    (tmp_path / "set" / "object000" / "060_00_mm").mkdir(parents=True)
    res = runner.invoke(app, ["evaluate", "--recordings", "set", "--no-progress"])
    assert res.exit_code == 2 and "grasp folder is empty" in res.output and "does not match" not in res.output
    res = runner.invoke(app, ["adapt", "--recordings", "empty", "--out", "mine", "--no-progress"])
    assert res.exit_code == 2 and not (tmp_path / "mine").exists()
    from slipsense.measures.promise import held_alarm_promise, promise_text

    promise = promise_text({"held_alarm": held_alarm_promise([False, True, False], ["a", "b", "b"])})
    assert "counting each of the 2 objects with held grasps as one unit" in promise
