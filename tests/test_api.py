"""The top-level Python API (slipsense/__init__.py, slipsense/api.py) and the README's quick start."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import slipsense
import slipsense.resources
from conftest import REAL_RUN, needs_data
from slipsense.errors import ConfigError

README = Path(__file__).resolve().parent.parent / "README.md"
SMALL = dict(
    width=4,
    features=8,
    temporal=8,
    lags=[1, 5, 10],
    dilations=[1, 2, 4],
    chunk=16,
    negatives=1,
    hard_negatives=1,
    image_size=[12, 16],
    epochs=2,
    inner_folds=0,
)


def test_import_is_light_and_names_resolve():
    code = "import sys, slipsense; assert 'torch' not in sys.modules; print(sorted(slipsense.__all__))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert "SlipDetector" in out and "fit" in out and "evaluate" in out
    for name in slipsense.__all__:
        assert getattr(slipsense, name) is not None
    with pytest.raises(AttributeError):
        slipsense.no_such_name  # noqa: B018


def test_pretrained_detector_streams_made_up_frames(one_thread):
    det = slipsense.SlipDetector.pretrained()  # a grasp model's sensors by default: both fingers
    assert det.kind == "grasp" and det.sensors == 2 and 0 < det.threshold <= 1
    frames = np.random.default_rng(0).integers(0, 256, (15, 240, 320, 3), dtype=np.uint8)
    readings = [det.push(f, f) for f in frames]
    assert readings[0].probability is None and readings[-1].probability is not None
    with pytest.raises(ConfigError, match="shipped"):
        slipsense.SlipDetector.pretrained("no-such-model")


def test_fit_then_evaluate_return_objects(tmp_path, grasp_recordings, cache, one_thread):
    trained = slipsense.fit(grasp_recordings, tmp_path / "det", held_out=["obj0"], progress=False, **SMALL)
    assert trained.checkpoint.is_file() and 0 <= trained.operating_point["threshold"] <= 1
    assert len(trained.history) == 2 and "epoch" in trained.history[0]
    assert trained.held_out["per_grasp"]["slip_runs"] + trained.held_out["per_grasp"]["held_runs"] == 2
    report = slipsense.evaluate(trained.checkpoint, grasp_recordings, progress=False)
    summary = report.per_grasp()
    assert summary["slip_runs"] == 4 and summary["held_runs"] == 4
    assert report.threshold == trained.operating_point["threshold"]
    assert report.to_json(tmp_path / "eval.json").is_file()
    assert trained.detector().sensors == 2


def test_fit_applies_what_the_command_line_applies(tmp_path, grasp_recordings, cache, one_thread):
    """One recipe: a one-finger detector trained from Python sees each camera as a grasp of its own
    and stores the sensor spec, as `slipsense train` does (both go through training.recipe.fit)."""
    from slipsense.checkpoint import read_info

    trained = slipsense.fit(grasp_recordings, tmp_path / "one", held_out=["obj0"], progress=False, sensors=1, **SMALL)
    g = trained.held_out["per_grasp"]
    assert g["slip_runs"] + g["held_runs"] == 4  # obj0's two runs, two cameras each
    info = read_info(trained.checkpoint)
    assert info["data"]["sensors_per_grasp"] == 1 and info["sensor"]["name"] == "gelsight-mini"
    assert trained.detector().sensors == 1


def _quick_start() -> tuple[str, str]:
    """The README's quick start: its code and the printout it says the code gives."""
    text = README.read_text(encoding="utf-8")
    section = text[text.index("## Quick start") :]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    printed = re.search(r"\nprints\n\n```\n(.*?)```", section, re.S).group(1)
    return code, printed


@needs_data
def test_readme_quick_start_prints_what_the_readme_says(tmp_path, one_thread):
    code, printed = _quick_start()
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert result.returncode == 0, result.stderr
    assert result.stdout == printed


def test_api_names_survive_importing_every_module():
    """slipsense.fit / slipsense.evaluate are functions even after every submodule is imported (no
    submodule shares their names)."""
    import pkgutil

    for mod in pkgutil.walk_packages(slipsense.__path__, "slipsense."):
        __import__(mod.name)
    assert callable(slipsense.fit) and callable(slipsense.evaluate) and callable(slipsense.SlipDetector)
    assert not isinstance(slipsense.evaluate, type(slipsense))


def test_wheel_carries_the_shipped_detectors_and_overrides(tmp_path):
    """`pip install .` (not editable) must bring the package data: build the wheel and look inside."""
    import zipfile

    root = README.parent
    build = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(tmp_path),
            str(root),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    if build.returncode != 0 and "No module named" in build.stderr:
        pytest.skip(f"cannot build a wheel here: {build.stderr.strip().splitlines()[-1]}")
    assert build.returncode == 0, build.stderr
    wheel = next(tmp_path.glob("slipsense-*.whl"))
    names = set(zipfile.ZipFile(wheel).namelist())
    for name in slipsense.resources.shipped_models():
        assert f"slipsense/resources/models/{name}.safetensors" in names
    assert "slipsense/resources/gelsight-label-overrides.csv" in names


def test_shipped_overrides_apply_to_the_shared_recordings_only(tmp_path):
    """One data path: every command labels through data.label_runs, which gives runs of the shared
    recordings the shipped hand labels unless told otherwise."""
    from slipsense.paths import gelsight_recordings
    from slipsense.recordings.labels import shipped_overrides_for
    from slipsense.recordings.types import Recording

    def rec(root, obj, exp, cam):
        return Recording(
            object=obj, experiment=exp, camera=cam, path=root / obj / f"exp_num_{exp}" / f"{cam}.avi", slipped=True
        )

    shared = gelsight_recordings()
    ov = shipped_overrides_for([rec(shared, "screw_driver_red", 2, "camera_0"), rec(shared, "lemon", 1, "camera_0")])
    assert ov is not None and set(ov) == {("screw_driver_red", 2, None)}
    assert shipped_overrides_for([rec(tmp_path, "screw_driver_red", 2, "camera_0")]) is None
    assert shipped_overrides_for([rec(shared, "lemon", 1, "camera_0")]) is None


def test_shipped_detectors_record_their_sensor_and_one_finger_has_its_own(one_thread):
    from slipsense.checkpoint import read_info
    from slipsense.sensors.spec import GELSIGHT_LIFT, GELSIGHT_MINI, SensorSpec

    for name in slipsense.resources.shipped_models():
        spec = SensorSpec.from_dict(read_info(slipsense.resources.shipped_model(name))["sensor"])
        assert spec == (GELSIGHT_LIFT if name.endswith("-lift") else GELSIGHT_MINI)
    one, two = slipsense.SlipDetector.pretrained(sensors=1), slipsense.SlipDetector.pretrained()
    assert (one.sensors, two.sensors) == (1, 2) and one.sensor.fps == 25.0
    frame = np.full((240, 320, 3), 120, np.uint8)
    readings = [one.push(frame) for _ in range(15)]
    assert readings[9].probability is None and readings[-1].probability is not None


@needs_data
def test_watch_one_camera_uses_the_one_finger_detector(tmp_path, cache, one_thread):
    """`slipsense watch RUN/camera_0.avi`: one GelSight, the shipped one-finger detector."""
    from typer.testing import CliRunner

    from conftest import REAL_RUN
    from slipsense.cli import app

    res = CliRunner().invoke(app, ["watch", str(REAL_RUN / "camera_0.avi"), "--max-frames", "40", "--quiet"])
    assert res.exit_code == 0, res.output
    two = slipsense.SlipDetector.pretrained()  # two-finger model given one camera: one line, exit 2
    assert two.sensors == 2
    ckpt = slipsense.resources.shipped_model("motionnet-gelsight")
    res = CliRunner().invoke(
        app, ["watch", str(REAL_RUN / "camera_0.avi"), "--checkpoint", str(ckpt), "--max-frames", "5"]
    )
    assert res.exit_code == 2 and "motionnet-gelsight.safetensors" in res.output and "2 sensor" in res.output


@needs_data
def test_a_model_of_tracked_markers_is_judged_per_grasp_on_recordings(tmp_path, one_thread):
    """A marker file from `slipsense markers` (here: made up, its markers said to be every tracked
    marker on a 2 x 3 grid) trains a GelSight model that `slipsense.evaluate` replays over recordings,
    each camera's markers tracked and resampled the same way."""
    from typer.testing import CliRunner

    from conftest import TINY_TRAIN_ARGS
    from slipsense.cli import app

    rng = np.random.default_rng(0)
    x = rng.normal(size=(24, 4, 6, 3)).astype(np.float32)
    np.savez(tmp_path / "m.npz", x=x, y=np.arange(24) % 2, groups=np.arange(24) // 2, marker_layout=np.array("2x3"))
    args = [
        "train",
        *TINY_TRAIN_ARGS,
        "--markers",
        str(tmp_path / "m.npz"),
        "--out",
        str(tmp_path / "r"),
        "--epochs",
        "1",
    ]
    assert CliRunner().invoke(app, args).exit_code == 0
    recordings = tmp_path / "recordings" / "avocado_real"  # its slip with a moment and a grasp that held
    recordings.mkdir(parents=True)
    for run in ("exp_num_2", "exp_num_4"):
        (recordings / run).symlink_to(REAL_RUN.parent / run)
    ev = slipsense.evaluate(tmp_path / "r" / "last.safetensors", recordings.parent, threshold=0.5, progress=False)
    summary = ev.per_grasp()
    assert (summary["slip_runs"], summary["held_runs"]) == (1, 1)
    assert all(len(r.probability) == r.n_frames and np.isfinite(r.probability[20:]).all() for r in ev.runs)
