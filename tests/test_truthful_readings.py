"""Live outputs say no more than the code does: per-finger probabilities only where the model judges
each finger apart (a slip on one finger's frames raises that finger's value), `--combine` and
`--heatmap` refused in one line where they would change nothing, one slip one alarm onset (the
hold), printed probabilities that never round across the threshold, and one promise about held
grasps, read from the checkpoint, wherever it is printed."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from slipsense.alarm import alarm_trace, hold, onsets, shown_probability
from slipsense.checkpoint import read_info
from slipsense.cli import app
from slipsense.errors import ConfigError
from slipsense.measures.promise import promise_text
from slipsense.models import build
from slipsense.resources import shipped_model, shipped_models
from slipsense.streaming.detector import Reading, SlipDetector
from slipsense.sensors.gel_motion import GelMotion
from slipsense.streaming.readings import JsonlWriter, reading_record
from slipsense.watch import reading_line, watch_source
from tests.conftest import REAL_RUN, needs_data, write_grasp_video

runner = CliRunner()
MUG = REAL_RUN.parents[1] / "blue_mug" / "exp_num_9"
README = Path(__file__).resolve().parents[1] / "README.md"


@pytest.fixture(autouse=True)
def _one_thread(one_thread):
    yield


def _frames(n: int, seed: int, moving: bool) -> np.ndarray:
    """48 x 64 BGR frames of still noise; ``moving``: a bright bar sweeps across them."""
    rng = np.random.default_rng(seed)
    out = rng.integers(90, 110, (n, 48, 64, 3), dtype=np.uint8)
    if moving:
        for t in range(n):
            out[t, :, (t * 9) % 60 : (t * 9) % 60 + 6] = 250
    return out


def test_a_model_that_fuses_the_fingers_reports_no_per_finger_value_and_refuses_combine():
    model = build("motionnet", width=4, features=8, temporal=8, lags=[1, 2], dilations=[1], image_size=[12, 16])
    det = SlipDetector(model, sensors=2)
    assert not det.per_sensor and not det.has_heatmap
    a, b = _frames(16, 1, True), _frames(16, 2, False)
    readings = [det.push(a[i], b[i]) for i in range(16)]
    answered = [r for r in readings if r.probability is not None]
    assert answered and all(r.per_sensor is None for r in answered)  # before: the fused value twice
    record = reading_record(answered[-1], 0.0, 0.1)
    assert record["per_sensor"] is None
    assert det.replay(a, b).per_sensor.shape == (16, 1)
    with pytest.raises(ConfigError, match="fuses its 2 sensors"):
        SlipDetector(model, sensors=2, combine="mean")


def test_a_model_that_judges_each_finger_apart_raises_the_slipping_fingers_value():
    model = build("vivit", **_vivit_small())
    det = SlipDetector(model, sensors=2, threshold=0.99)
    still, moving = _frames(8, 3, False), _frames(8, 3, True)
    r_moving_left = [det.push(moving[i], still[i]) for i in range(8)][-1]
    det.reset()
    r_moving_right = [det.push(still[i], moving[i]) for i in range(8)][-1]
    assert det.per_sensor and r_moving_left.per_sensor is not None
    # the finger whose frames change is the one whose value changes: the values swap with the fingers
    assert r_moving_left.per_sensor == pytest.approx(r_moving_right.per_sensor[::-1], abs=1e-7)
    assert abs(r_moving_left.per_sensor[0] - r_moving_left.per_sensor[1]) > 1e-5
    mean = SlipDetector(model, sensors=2, combine="mean")
    r_mean = [mean.push(moving[i], still[i]) for i in range(8)][-1]
    assert r_mean.probability == pytest.approx(np.mean(r_moving_left.per_sensor), abs=1e-9)
    assert r_mean.probability != pytest.approx(r_moving_left.probability, abs=1e-7)  # --combine does something


def _vivit_small() -> dict:
    from slipsense.models import model_class

    return model_class("vivit").small_config()


def test_an_alarm_holds_so_one_dip_is_one_onset():
    p = np.array([np.nan, 0.2, 0.99, 0.5, 0.5, 0.99, 0.99, 0.1, 0.1, 0.1, 0.1, 0.99])
    plain = alarm_trace(p, 0.9)
    assert onsets(plain).tolist() == [2, 5, 11]
    held = alarm_trace(p, 0.9, hold_frames=2)
    assert onsets(held).tolist() == [2, 11]  # the two-frame dip is held over; the long gap is not
    assert held[[2, 3, 4, 5, 6, 7, 8]].all() and not held[9:11].any()
    # holding never moves a first alarm nor makes a trace alarm that did not
    for k in range(5):
        h = hold(plain, k)
        assert np.flatnonzero(h)[0] == np.flatnonzero(plain)[0] and h[plain].all()
    assert not hold(np.zeros(5, bool), 3).any()


def test_pushing_and_replaying_give_the_same_held_alarm():
    model = build("motionnet", width=4, features=8, temporal=8, lags=[1, 2], dilations=[1], image_size=[12, 16])
    a, b = _frames(40, 4, True), _frames(40, 5, True)
    probe = SlipDetector(model, sensors=2).replay(a, b).probability
    threshold = float(np.nanmedian(probe))  # an alarm that comes and goes
    det = SlipDetector(model, sensors=2, threshold=threshold, hold=0.2)
    pushed = np.array([det.push(a[i], b[i]).alarm for i in range(40)])
    trace = det.replay(a, b)
    assert trace.hold == 5 and np.array_equal(pushed, trace.alarm)
    assert len(onsets(pushed)) <= len(onsets(SlipDetector(model, sensors=2, threshold=threshold).replay(a, b).alarm))


@pytest.mark.parametrize("bad", [-1, 61, float("nan"), "x"])
def test_a_bad_hold_is_refused(bad):
    model = build("motionnet", width=4, features=8, temporal=8, lags=[1, 2], dilations=[1], image_size=[12, 16])
    with pytest.raises(ConfigError, match="hold"):
        SlipDetector(model, sensors=2, hold=bad)


def test_a_printed_probability_never_reads_across_the_threshold():
    assert shown_probability(0.9975, 0.998) == "0.997"
    assert shown_probability(0.9980, 0.998) == "0.998"
    assert shown_probability(0.99801, 0.998) == "0.999"
    assert shown_probability(0.4, 0.5) == "0.400" and shown_probability(0.123456, 0.9) == "0.123"
    line = reading_line(Reading(109, 0.9975, None, False), 0.998)
    assert "p=0.997" in line and "ALARM" not in line and "[" not in line
    assert reading_line(Reading(110, 0.9975, None, True), 0.998).endswith("ALARM (held)")
    assert "[0.910 0.400]" in reading_line(Reading(3, 0.91, (0.91, 0.4), False), 0.95)


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A made-up two-finger run at the GelSight Mini's size."""
    root = tmp_path_factory.mktemp("run") / "thing" / "exp_num_1"
    for cam in (0, 2):
        write_grasp_video(root / f"camera_{cam}.avi", 30, (5, 29), False, seed=cam)
    return root


def _invoke(args):
    return runner.invoke(app, [str(a) for a in args])


def test_heatmap_and_combine_are_refused_for_the_shipped_detector_in_one_line(run, tmp_path, cache):
    for extra in (["--heatmap", "--out", tmp_path / "x.gif"], ["--combine", "mean"]):
        res = _invoke(["watch", run, "--checkpoint", shipped_model("motionnet-gelsight"), "--quiet", *extra])
        assert res.exit_code == 2 and res.output.count("error: ") == 1, res.output
        assert "Traceback" not in res.output
    assert not (tmp_path / "x.gif").exists()


@needs_data
def test_one_slip_is_one_alarm_onset_on_the_mug(cache):
    lines: list[str] = []
    summary = watch_source(str(MUG), None, echo=lambda m, err=False: lines.append(m))
    assert summary["alarm_onsets"] == [108]  # before: 108 and 112, one slip reported as two onsets
    assert not any(re.search(r"p=0\.99[89].*", line) and "ALARM" not in line for line in lines[3:])


def _promises() -> dict[str, str]:
    out = {}
    for name in shipped_models():
        op = read_info(shipped_model(name)).get("operating_point")
        if isinstance(op, dict) and op.get("held_alarm"):
            out[name] = promise_text(op)
    return out


def test_every_place_that_states_a_promise_reads_it_from_the_checkpoint(run, cache):
    promises = _promises()
    assert set(promises) >= {"motionnet-gelsight", "motionnet-gelsight-1", "shear-retention-gelsight-lift"}
    readme = README.read_text()
    for name, text in promises.items():
        assert text in readme, f"README's table states another promise than {name}'s checkpoint"
    listed = _invoke(["models"])
    assert listed.exit_code == 0, listed.output
    for name, text in promises.items():
        assert name in listed.output and text in listed.output, name
    lines: list[str] = []
    watch_source(str(run), shipped_model("motionnet-gelsight"), max_frames=1, echo=lambda m, err=False: lines.append(m))
    assert promises["motionnet-gelsight"] in lines


def test_readings_as_json_carry_what_the_detector_knows(run, tmp_path, cache):
    out = tmp_path / "r.jsonl"
    res = _invoke(["watch", run, "--jsonl", out, "--quiet"])
    assert res.exit_code == 0, res.output
    records = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(records) == 30 and all(r["per_sensor"] is None for r in records)


def test_a_record_carries_each_fingers_slip_and_null_for_a_finger_without_contact(tmp_path):
    touching = GelMotion((12.123456, -3.4), 0.35, 0.2, 13.5, (0.41, -0.1), 0.02, 0.01, 0.3, "mm")
    untouched = GelMotion(None, None, None, None, (0.0, 0.0), 0.0, 0.0, 0.0, "mm")
    reading = Reading(57, 0.91, None, True, (touching, untouched), "mm")
    writer = JsonlWriter(tmp_path / "r.jsonl")
    writer.write(reading_record(reading, 2.28, 0.31))
    writer.close()
    (record,) = [json.loads(line) for line in (tmp_path / "r.jsonl").read_text().splitlines()]
    assert record["slip"] == [{"translation": [12.1235, -3.4], "omega": 0.35, "stick": 0.2, "speed": 13.5}, None]
    assert record["slip_velocity_unit"] == "mm/s" and record["slip_omega_unit"] == "rad/s"
    assert record["shear"][0]["contact"] == 0.3 and "slip_velocity" not in record  # no field copying another
    # the Python reading says what the record says, in the same words
    assert list(reading.slip) == record["slip"]
    assert (reading.slip_velocity_unit, reading.slip_omega_unit) == ("mm/s", "rad/s")
    assert "slip_velocity_unit='mm/s'" in repr(reading) and "gel_unit" not in repr(reading)
    assert reading_record(Reading(0, None, None, False, (None, touching), "px"), 0.0, 0.1)["slip"][0] is None
    assert Reading(0, None, None, False, (touching,), "px").slip_velocity_unit == "px/s"
    plain = reading_record(Reading(0, 0.1, None, False), 0.0, 0.1)  # a gel without markers: nothing made up
    assert [plain[k] for k in ("slip", "slip_velocity_unit", "slip_omega_unit", "shear")] == [None] * 4


@needs_data
def test_a_busy_detector_on_live_cameras_leaves_gaps_in_frame_numbers_that_the_counts_explain(
    tmp_path, cache, monkeypatch
):
    """Cameras played at 25 frames/s into a detector that takes 60 ms a push: the frames replaced
    before it took them show as gaps in the readings' ``frame`` and are counted as dropped."""
    import time as clock

    push = SlipDetector.push

    def slow_push(self, *frames, stamp=None):
        clock.sleep(0.06)
        return push(self, *frames, stamp=stamp)

    monkeypatch.setattr(SlipDetector, "push", slow_push)
    out = tmp_path / "r.jsonl"
    said: list[str] = []
    summary = watch_source(
        str(REAL_RUN), None, max_frames=40, realtime=True, jsonl=str(out), echo=lambda m, err=False: said.append(m)
    )
    frames = [json.loads(line)["frame"] for line in out.read_text().splitlines()]
    assert len(frames) == 40 and frames == sorted(set(frames))
    gaps = sum(b - a - 1 for a, b in zip(frames, frames[1:])) + frames[0]
    first = summary["source"]["cameras"][0]
    assert gaps > 10 and gaps == first["dropped"]  # every frame of the camera pushed or counted
    assert any("dropped (replaced before the detector took them)" in line for line in said)


def test_ros_takes_the_options_the_docs_advise(monkeypatch):
    """`slipsense ros --threads 1 --threshold 0.9 --hold 0.2` hands them to the node; bad values are one line."""
    pytest.importorskip("rclpy")
    import slipsense.ros_node as ros_node

    seen = {}
    monkeypatch.setattr(ros_node, "main", lambda argv=None, overrides=None: seen.update(overrides or {}))
    res = _invoke(["ros", "--threads", "1", "--threshold", "0.9", "--hold", "0.2", "--max-lag", "0.05"])
    assert res.exit_code == 0, res.output
    assert seen["threads"] == 1 and seen["threshold"] == 0.9 and seen["hold"] == 0.2 and seen["max_lag"] == 0.05
    for bad, words in ((["--threshold", "2"], "--threshold must be in [0, 1]"), (["--hold", "-1"], "hold must be")):
        res = _invoke(["ros", *bad])
        assert res.exit_code == 2 and res.output.count("error: ") == 1 and words in res.output, res.output
