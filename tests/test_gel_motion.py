"""The gel's motion in readings: the object's slip velocity and the shear field from the markers
(slipsense.sensors.gel_motion), on synthetic gels whose truth is known."""

from __future__ import annotations

import json

import numpy as np
import pytest

from slipsense.models import build
from slipsense.sensors.gel_motion import CloudMotionStream, GelMotionStream, footprint
from slipsense.sensors.spec import GELSIGHT_MINI, SensorSpec
from slipsense.streaming.detector import SlipDetector
from slipsense.streaming.readings import reading_record
from tests.conftest import REAL_RUN, needs_data
from tests.test_markers import H, W, grid, render

FPS = 25.0
STILL, REST, SLIDE = 12, 14, 24  # frames without contact, resting, sliding
STEP = 2.0  # px a frame while sliding: 50 px/s


def _gel_video(seed: int = 0) -> np.ndarray:
    """A gel whose markers stay while an object's imprint (a bright Gaussian in the shading) appears,
    rests, then slides +x at STEP px a frame: slip at 50 px/s, the gel's surface left behind."""
    markers = grid()
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    frames = []
    for t in range(STILL + REST + SLIDE):
        frame = render(markers, seed=seed + t).astype(np.float32)
        if t >= STILL:
            cx = 110.0 + STEP * max(0, t - STILL - REST)
            imprint = 60.0 * np.exp(-((xx - cx) ** 2 + (yy - 120.0) ** 2) / (2 * 28.0**2))
            frame = frame + imprint[..., None] * np.array([1.0, 0.6, 0.3])
        frames.append(np.clip(frame, 0, 255).astype(np.uint8))
    return np.stack(frames)


def test_the_slip_speed_and_direction_of_an_imprint_sliding_over_still_markers():
    stream = GelMotionStream(FPS, mm_per_pixel=0.1, window_s=0.2)
    motions = [stream.push(f) for f in _gel_video()]
    assert motions[0] is not None and motions[0].velocity is None and motions[0].unit == "mm"
    resting = [m.velocity for m in motions[STILL + 6 : STILL + REST] if m.velocity is not None]
    sliding = np.array([m.velocity for m in motions[STILL + REST + 6 :] if m.velocity is not None])
    assert len(resting) >= 5 and max(np.hypot(*v) for v in resting) < 0.5  # mm/s: nothing slides
    assert len(sliding) >= 15
    assert np.median(sliding[:, 0]) == pytest.approx(5.0, abs=0.75)  # 50 px/s x 0.1 mm/px
    assert abs(np.median(sliding[:, 1])) < 0.5
    assert all(m.contact > 0 for m in motions[STILL + 2 :])


def test_no_contact_no_velocity_and_the_shear_field_of_a_known_displacement():
    # a uniform stretch of 1% and a twist of 0.02 rad: divergence 0.02, curl 0.04
    x = np.stack(np.meshgrid(np.arange(10.0), np.arange(8.0)), -1).reshape(-1, 2) * 3.0
    a = np.array([[0.01, -0.02], [0.02, 0.01]])
    d = (x - x.mean(0)) @ a.T + [0.3, -0.1]
    found = footprint(x, np.ones(len(x)), d)
    centroid, mean, div, curl, contact = found
    assert mean == pytest.approx([0.3, -0.1]) and div == pytest.approx(0.02) and curl == pytest.approx(0.04)
    assert contact == 1.0 and footprint(x, np.zeros(len(x)), d) is None
    clouds = CloudMotionStream(20.0)
    flat = np.concatenate([x, np.zeros((len(x), 1))], 1)
    assert all(clouds.push(flat).velocity is None for _ in range(10))  # a gel nothing presses


def _tiny_motionnet():
    return build("motionnet", width=4, features=8, temporal=8, lags=[1, 2], dilations=[1], image_size=[12, 16])


def test_readings_of_a_marker_gel_carry_each_fingers_slip_velocity_and_unit_and_a_plain_gel_none():
    video = _gel_video()
    det = SlipDetector(_tiny_motionnet(), sensors=2)  # the GelSight Mini's spec: markers, 0.0585 mm/px
    assert det.sensor.gel_markers and det.sensor.mm_per_pixel == GELSIGHT_MINI.mm_per_pixel
    readings = [det.push(f, f[:, ::-1].copy()) for f in video]
    last = readings[-1]
    assert last.slip_velocity_unit == "mm/s" and len(last.slip_velocity) == 2
    vx = [r.slip_velocity[0][0] for r in readings[STILL + REST + 8 :]]
    mirrored = [r.slip_velocity[1][0] for r in readings[STILL + REST + 8 :]]
    assert np.median(vx) == pytest.approx(50 * 0.0585, abs=0.5) and np.median(mirrored) < -2.0  # the other way
    record = reading_record(last, 1.0, 0.5)
    assert record["slip_velocity_unit"] == "mm/s"
    assert record["slip_velocity"] == [[pytest.approx(v, abs=1e-5) for v in f] for f in last.slip_velocity]
    assert set(record["shear"][0]) == {"displacement", "divergence", "curl", "contact"}

    plain = {**GELSIGHT_MINI.to_dict(), "name": "plain-gel", "gel_markers": False}
    det = SlipDetector(_tiny_motionnet(), sensors=2, info={"sensor": plain})
    reading = [det.push(f, f) for f in video][-1]
    assert reading.slip_velocity is None and reading.slip_velocity_unit is None
    record = reading_record(reading, 1.0, 0.5)
    assert record["slip_velocity"] is None and record["slip_velocity_unit"] is None and record["shear"] is None
    off = SlipDetector(_tiny_motionnet(), sensors=2, gel_motion=False)
    assert off.push(video[0], video[0]).slip_velocity is None


def test_a_sensor_spec_states_its_pixel_size_and_markers_or_is_refused():
    spec = SensorSpec.from_dict({**GELSIGHT_MINI.to_dict(), "name": "x", "mm_per_pixel": 0.05})
    assert spec.mm_per_pixel == 0.05 and spec.gel_markers
    for bad in ({"mm_per_pixel": -1}, {"mm_per_pixel": "0.1"}, {"gel_markers": "yes"}):
        with pytest.raises(ValueError, match="mm_per_pixel|gel_markers"):
            SensorSpec.from_dict({**GELSIGHT_MINI.to_dict(), "name": "x", **bad})


def test_the_slip_velocity_family_alarms_where_the_imprint_slides_not_where_it_rests():
    import cv2
    import torch

    model = build("slip-velocity", sensors=1, image_size=[120, 160], window=5).eval()
    video = _gel_video()
    gray = np.stack(
        [cv2.resize(cv2.cvtColor(f, cv2.COLOR_BGR2GRAY), (160, 120), interpolation=cv2.INTER_AREA) for f in video]
    )
    with torch.no_grad():
        p = torch.softmax(model(torch.from_numpy(gray[None, None]).float() / 255.0)[0], -1)[:, 1].numpy()
    resting, sliding = p[STILL + 6 : STILL + REST], p[STILL + REST + 6 :]
    # 1 px a frame at half size: a speed of 1 against the bias 0.5 px a frame (logit 2 ln 2)
    assert resting.max() < 0.2 and np.median(sliding) > 0.75


def test_adapt_tries_the_slip_velocity_family_where_the_gel_has_markers_only():
    from slipsense.adapt import Grasps, families

    def grasps(markers: bool) -> Grasps:
        found = (markers, "a marker grid" if markers else "no marker grid")
        return Grasps(60, ["a", "b", "c"], 1, (480, 640), 30.0, [], found)

    tried, why_not = families(grasps(True))
    assert "slip-velocity" in tried and "shear-retention" in tried
    tried, why_not = families(grasps(False))
    assert "slip-velocity" not in tried and why_not["slip-velocity"] == "needs a gel with markers: no marker grid"


@needs_data
def test_watch_gives_each_fingers_slip_velocity_and_no_gel_motion_leaves_it_out(tmp_path):
    from typer.testing import CliRunner

    from slipsense.cli import app

    got = {}
    for flag in ("--gel-motion", "--no-gel-motion"):
        out = tmp_path / f"{flag}.jsonl"
        args = ["watch", str(REAL_RUN), "--max-frames", "40", "--jsonl", str(out), "--quiet", flag]
        res = CliRunner().invoke(app, args)
        assert res.exit_code == 0, res.output
        got[flag] = [json.loads(line) for line in out.read_text().splitlines()]
    on, off = got["--gel-motion"], got["--no-gel-motion"]
    assert all(r["slip_velocity_unit"] == "mm/s" and len(r["slip_velocity"]) == 2 for r in on)
    assert any(v is not None for r in on for v in r["slip_velocity"])  # the fingers touch within 40 frames
    assert all(r["slip_velocity"] is None and r["slip_velocity_unit"] is None and r["shear"] is None for r in off)
    assert [r["probability"] for r in on] == [r["probability"] for r in off]  # the detector's own answer unchanged
