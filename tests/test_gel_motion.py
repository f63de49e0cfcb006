"""The object's motion against the gel (slipsense.sensors.gel_motion): translation, turn and the share
that sticks, on synthetic gels whose truth is known, and what readings carry of it."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from slipsense.models import build
from slipsense.sensors.gel_motion import CloudMotionStream, GelMotionStream, footprint
from slipsense.sensors.spec import GELSIGHT_MINI, STARTUP_FRAMES, SensorSpec
from slipsense.streaming.detector import SlipDetector
from slipsense.streaming.readings import reading_record
from tests.conftest import REAL_RUN, needs_data
from tests.test_markers import H, W, grid, render

FPS = 25.0
#: frames without contact, resting, sticking (object and gel move together), sliding, turning
STILL, REST, STICK, SLIDE, TURN = 10, 8, 14, 16, 16
STEP = 1.0  # px a frame, the object's translation while it sticks and while it slides: 25 px/s
TWIST = 0.02  # rad a frame while it turns: 0.5 rad/s
MM = 0.1  # mm per px of the synthetic sensor
CENTRE = np.array([150.0, 120.0])  # px, where the object touches first


def _imprint(seed: int = 3) -> np.ndarray:
    """A textured object's imprint ``(H, W)`` centred at ``CENTRE``: bumps of random heights in a disc."""
    rng = np.random.default_rng(seed)
    r, a = 45.0 * np.sqrt(rng.uniform(0, 1, 40)), rng.uniform(0, 2 * np.pi, 40)
    image = np.zeros((H, W), np.float32)
    for x, y, h in zip(CENTRE[0] + r * np.cos(a), CENTRE[1] + r * np.sin(a), rng.uniform(20.0, 45.0, 40)):
        cv2.circle(image, (int(round(x)), int(round(y))), 1, float(h), -1)
    return cv2.GaussianBlur(image, (0, 0), 6.0) * 25.0


def _scene(phase_frames=(STILL, REST, STICK, SLIDE, TURN), markers: bool = True, seed: int = 0):
    """Frames and the truth per frame: the object's motion against the gel ``(vx, vy, omega)`` (px/s,
    rad/s). The imprint: textured bumps in a disc; the markers: a grid that moves with the object while
    it sticks and stays while the object slides or turns (about the imprint's centre)."""
    texture = _imprint()
    shift, angle, gel_shift = np.zeros(2), 0.0, np.zeros(2)
    still, rest, stick, slide, turn = phase_frames
    frames, truth = [], []
    for t in range(sum(phase_frames)):
        moving = np.zeros(3)
        if still + rest <= t < still + rest + stick:
            shift, gel_shift = shift + (STEP, 0.0), gel_shift + (STEP, 0.0)
        elif still + rest + stick <= t < still + rest + stick + slide:
            shift, moving = shift + (STEP, 0.0), np.array([STEP * FPS, 0.0, 0.0])
        elif t >= still + rest + stick + slide:
            angle, moving = angle + TWIST, np.array([0.0, 0.0, TWIST * FPS])
        pts = grid() + gel_shift if markers else np.zeros((0, 2))
        frame = render(pts, seed=seed + t).astype(np.float32)
        if t >= still:
            # image axes (y down): a positive angle turns +x towards +y; OpenCV's angle is the other way
            pose = cv2.getRotationMatrix2D(tuple(CENTRE), -np.degrees(angle), 1.0)
            pose[:, 2] += shift
            imprint = cv2.warpAffine(texture, pose, (W, H))
            frame = frame + imprint[..., None] * np.array([1.0, 0.6, 0.3], np.float32)
        frames.append(np.clip(frame, 0, 255).astype(np.uint8))
        truth.append(moving)
    return np.stack(frames), np.array(truth)


def test_a_gel_that_sticks_slides_and_turns_gives_the_objects_motion_against_it_and_the_share_that_sticks():
    frames, truth = _scene()
    stream = GelMotionStream(FPS, mm_per_pixel=MM)
    motions = [stream.push(f) for f in frames]
    assert motions[0] is not None and motions[0].translation is None and motions[0].unit == "mm"
    assert all(m.translation is None for m in motions[:STILL])  # no contact: no motion, not a zero one
    settle = 4  # frames of lag and median after each change of phase
    start = STILL + REST
    phases = {
        "stick": range(start + settle, start + STICK),
        "slide": range(start + STICK + settle, start + STICK + SLIDE),
        "turn": range(start + STICK + SLIDE + settle, len(frames)),
    }
    got = {
        k: np.array([[*motions[i].translation, motions[i].omega, motions[i].stick] for i in r])
        for k, r in phases.items()
    }
    med = {k: np.median(v, axis=0) for k, v in got.items()}
    # sticking: the gel moves with the object, nothing moves against it
    assert np.hypot(*med["stick"][:2]) < 0.5 and abs(med["stick"][2]) < 0.05 and med["stick"][3] > 0.8
    # sliding +x at 25 px/s = 2.5 mm/s over a gel that stays
    assert med["slide"][0] == pytest.approx(STEP * FPS * MM, abs=0.4) and abs(med["slide"][1]) < 0.4
    assert abs(med["slide"][2]) < 0.1 and med["slide"][3] < 0.3
    # turning about its centre at 0.5 rad/s, from +x towards +y
    assert med["turn"][2] == pytest.approx(TWIST * FPS, abs=0.1) and med["turn"][3] < 0.5


def test_a_gel_without_markers_gives_no_motion():
    frames, _ = _scene((2, 2, 2, 2, 2), markers=False)
    stream = GelMotionStream(FPS, mm_per_pixel=MM)
    assert all(stream.push(f) is None for f in frames)


def test_the_shear_field_of_a_known_displacement_and_no_contact_no_motion():
    # a uniform stretch of 1% and a twist of 0.02 rad: divergence 0.02, curl 0.04
    x = np.stack(np.meshgrid(np.arange(10.0), np.arange(8.0)), -1).reshape(-1, 2) * 3.0
    a = np.array([[0.01, -0.02], [0.02, 0.01]])
    d = (x - x.mean(0)) @ a.T + [0.3, -0.1]
    centroid, mean, div, curl, contact = footprint(x, np.ones(len(x)), d)
    assert mean == pytest.approx([0.3, -0.1]) and div == pytest.approx(0.02) and curl == pytest.approx(0.04)
    assert contact == 1.0 and footprint(x, np.zeros(len(x)), d) is None
    clouds = CloudMotionStream(20.0)
    flat = np.concatenate([x, np.zeros((len(x), 1))], 1)
    assert all(clouds.push(flat).translation is None for _ in range(10))  # a gel nothing presses


def _pressed(x: np.ndarray, centre, drag) -> np.ndarray:
    """A cloud: a round dent 1 mm deep at ``centre`` (mm), its contact dragged by ``drag`` (mm)."""
    r = np.linalg.norm(x - centre, axis=1)
    dent = np.clip(1.0 - (r / 3.0) ** 2, 0.0, None)
    xy = x + (dent > 0)[:, None] * np.asarray(drag) * dent[:, None]
    return np.concatenate([xy, -dent[:, None]], 1)


def test_a_marker_cloud_reads_a_slide_but_not_a_roll_where_friction_does_not_drag_the_gel():
    x = np.stack(np.meshgrid(np.arange(-10.0, 10.5, 1.0), np.arange(-8.0, 8.5, 1.0)), -1).reshape(-1, 2)
    fps, speed = 20.0, 4.0  # mm/s
    slides, rolls = CloudMotionStream(fps), CloudMotionStream(fps)
    for t in range(30):
        centre = (-4.0 + speed * t / fps, 0.0)
        slide, roll = slides.push(_pressed(x, centre, (0.3, 0.0))), rolls.push(_pressed(x, centre, (0.0, 0.0)))
    assert slide.translation[0] == pytest.approx(speed, abs=0.4) and abs(slide.translation[1]) < 0.3
    assert slide.stick < 0.5  # the gel stays dragged while the object moves on: it slips
    assert roll.translation == (0.0, 0.0) and roll.speed == 0.0 and roll.stick > 0.5  # rolling is stick


GV_STILL, GV_REST, GV_SLIDE, GV_STEP = 12, 14, 24, 2.0  # the family's gel: 2 px a frame


def _gel_video(seed: int = 0) -> np.ndarray:
    """A gel whose markers stay while an object's imprint (a bright Gaussian in the shading) appears,
    rests, then slides +x at STEP px a frame: slip at 50 px/s, the gel's surface left behind."""
    markers = grid()
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    frames = []
    for t in range(GV_STILL + GV_REST + GV_SLIDE):
        frame = render(markers, seed=seed + t).astype(np.float32)
        if t >= GV_STILL:
            cx = 110.0 + GV_STEP * max(0, t - GV_STILL - GV_REST)
            imprint = 60.0 * np.exp(-((xx - cx) ** 2 + (yy - 120.0) ** 2) / (2 * 28.0**2))
            frame = frame + imprint[..., None] * np.array([1.0, 0.6, 0.3])
        frames.append(np.clip(frame, 0, 255).astype(np.uint8))
    return np.stack(frames)


def _tiny_motionnet():
    return build("motionnet", width=4, features=8, temporal=8, lags=[1, 2], dilations=[1], image_size=[12, 16])


def test_readings_carry_each_fingers_translation_turn_and_stick_share_and_a_plain_gel_none():
    still = STILL + STARTUP_FRAMES  # the detector takes the GelSight Mini's start-up frames for no scene
    frames, _ = _scene((still, REST, 0, SLIDE, 0))
    det = SlipDetector(_tiny_motionnet(), sensors=2)  # the GelSight Mini's spec: markers, 0.0585 mm/px
    assert det.sensor.gel_markers and det.sensor.mm_per_pixel == GELSIGHT_MINI.mm_per_pixel
    readings = [det.push(f, f[:, ::-1].copy()) for f in frames]
    last = readings[-1]
    assert last.slip_velocity_unit == "mm/s" and last.slip_omega_unit == "rad/s" and len(last.gel) == 2
    vx = [r.gel[0].translation[0] for r in readings[still + REST + 6 :]]
    mirrored = [r.gel[1].translation[0] for r in readings[still + REST + 6 :]]
    assert np.median(vx) == pytest.approx(STEP * FPS * GELSIGHT_MINI.mm_per_pixel, abs=0.4)
    assert np.median(mirrored) < -0.8  # the mirrored finger sees it slide the other way
    record = reading_record(last, 1.0, 0.5)
    assert record["slip_velocity_unit"] == "mm/s" and record["slip_omega_unit"] == "rad/s"
    assert record["slip"][0] == last.gel[0].slip_dict() and set(record["slip"][0]) == {
        "translation",
        "omega",
        "stick",
        "speed",
    }
    assert set(record["shear"][0]) == {"displacement", "divergence", "curl", "contact"}
    assert reading_record(readings[still - 1], 1.0, 0.5)["slip"] == [None, None]  # no contact: null, not zero

    plain = {**GELSIGHT_MINI.to_dict(), "name": "plain-gel", "gel_markers": False}
    det = SlipDetector(_tiny_motionnet(), sensors=2, info={"sensor": plain})
    reading = [det.push(f, f) for f in frames[:5]][-1]
    assert reading.slip is None and reading.slip_velocity_unit is None
    record = reading_record(reading, 1.0, 0.5)
    assert record["slip"] is None and record["slip_velocity_unit"] is None and record["shear"] is None
    off = SlipDetector(_tiny_motionnet(), sensors=2, gel_motion=False)
    assert off.push(frames[0], frames[0]).slip is None


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
    resting, sliding = p[GV_STILL + 6 : GV_STILL + GV_REST], p[GV_STILL + GV_REST + 6 :]
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
    run = REAL_RUN.parent.parent / "wallet" / "exp_num_1"  # an object whose imprint the gel shows early
    for flag in ("--gel-motion", "--no-gel-motion"):
        out = tmp_path / f"{flag}.jsonl"
        args = ["watch", str(run), "--max-frames", "40", "--jsonl", str(out), "--quiet", flag]
        res = CliRunner().invoke(app, args)
        assert res.exit_code == 0, res.output
        got[flag] = [json.loads(line) for line in out.read_text().splitlines()]
    on, off = got["--gel-motion"], got["--no-gel-motion"]
    assert all(r["slip_velocity_unit"] == "mm/s" and len(r["slip"]) == 2 for r in on)
    assert any(v is not None for r in on for v in r["slip"])  # the fingers touch within 40 frames
    assert all(r["slip"] is None and r["slip_velocity_unit"] is None and r["shear"] is None for r in off)
    assert [r["probability"] for r in on] == [r["probability"] for r in off]  # the detector's own answer unchanged
