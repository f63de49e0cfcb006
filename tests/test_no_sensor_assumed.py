"""No sensor is assumed: it comes from the data (``sensor.json``, a registered layout), a checkpoint or
the user (``--sensor``); a recordings folder that states none is refused in one line saying how to state
it, and the GelSight Mini is named only by the registry and where a shipped detector names its sensor."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from slipsense.cli import app
from slipsense.recordings.folders import find_recordings, stated_sensor
from slipsense.recordings.recording_set import Recordings
from slipsense.sensors.spec import GELSIGHT_MINI, SENSORS, SensorSpec
from test_frame_folders import _grasp

runner = CliRunner()
REPO = Path(__file__).resolve().parents[1]

#: Where the GelSight Mini may be named outside the sensor registry, and why: each names the sensor
#: of a shipped GelSight Mini detector or the registry's public export.
NAMES_THE_MINI = {
    "slipsense/__init__.py": "the registry's public name, exported",
}


def _mini_mentions() -> dict[str, int]:
    found = {}
    for folder in ("slipsense", "studies", "bench"):
        for path in sorted((REPO / folder).rglob("*.py")):
            rel = path.relative_to(REPO).as_posix()
            if rel.startswith("slipsense/sensors/"):
                continue
            n = len(re.findall(r"\bGELSIGHT_MINI\b", path.read_text(encoding="utf-8")))
            if n:
                found[rel] = n
    return found


def test_the_gelsight_mini_is_named_only_by_the_registry_and_shipped_detectors():
    stray = {f: n for f, n in _mini_mentions().items() if f not in NAMES_THE_MINI}
    assert not stray, f"GELSIGHT_MINI named outside slipsense/sensors/ (a sensor assumed?): {stray}"


def _frames_without_sensor(root: Path) -> Path:
    for i, slipped in enumerate((True, False)):
        _grasp(root / "cup" / f"grasp_{i}", slipped, seed=i, n=6, size=(48, 64))
    return root


@pytest.mark.parametrize(
    "command",
    [
        ["label", "--csv", "{tmp}/labels.csv"],
        ["evaluate", "--no-progress"],
        ["train", "--epochs", "1", "--out", "{tmp}/run", "--no-progress"],
    ],
)
def test_frame_folders_that_state_no_sensor_are_refused_in_one_line(tmp_path, cache, command):
    root = _frames_without_sensor(tmp_path / "mine")
    args = [a.replace("{tmp}", str(tmp_path)) for a in command]
    res = runner.invoke(app, [args[0], "--recordings", str(root), *args[1:]])
    assert res.exit_code == 2, res.output
    lines = [line for line in res.output.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in res.output, res.output
    assert str(root) in lines[0] and "no sensor is stated" in lines[0] and "sensor.json" in lines[0]
    assert "--sensor NAME" in lines[0] or "data.sensor=NAME" in lines[0]


def test_a_sensor_the_user_names_is_the_data_s(tmp_path, cache, monkeypatch):
    root = _frames_without_sensor(tmp_path / "mine")
    csv = str(tmp_path / "l.csv")
    res = runner.invoke(app, ["label", "--recordings", str(root), "--csv", csv, "--sensor", "nope"])
    assert res.exit_code == 2 and "unknown sensor 'nope'" in res.output
    res = runner.invoke(app, ["label", "--recordings", str(root), "--csv", csv, "--sensor", "gelsight-lift"])
    assert res.exit_code == 2 and "expected 640x480" in res.output  # that sensor's frame size
    tiny = SensorSpec("tiny-gelsight", "video", 50.0, image_size=(48, 64))
    monkeypatch.setitem(SENSORS, tiny.name, tiny)
    res = runner.invoke(app, ["label", "--recordings", str(root), "--csv", csv, "--sensor", tiny.name])
    assert res.exit_code == 0, res.output
    data = Recordings.open(root, stated=tiny)
    assert data.sensor == tiny and data.rate(data.listed[0]) == (50.0, "the tiny-gelsight sensor (--sensor)")


def test_the_sensor_comes_from_the_data(tmp_path, grasp_recordings):
    assert stated_sensor(grasp_recordings) == GELSIGHT_MINI  # its registered layout of videos
    assert Recordings.open(grasp_recordings).sensor == GELSIGHT_MINI
    root = _frames_without_sensor(tmp_path / "mine")
    assert stated_sensor(root) is None
    (root / "sensor.json").write_text(json.dumps({"name": "my-gelsight", "output": "video", "fps": 50}))
    assert stated_sensor(root).fps == 50.0 and find_recordings(root)
