"""The model's clock: a source at another rate, with dropped frames or jitter, gives the model frames
at the rate it was trained on; at that rate frames pass through untouched."""

from __future__ import annotations

import numpy as np
import pytest

from slipsense.errors import ConfigError, InputError
from slipsense.streaming.clock import ModelClock, blend, check_fps, resample
from slipsense.streaming.detector import SlipDetector


def _frames(n, seed=0, size=(30, 40)):
    return np.random.default_rng(seed).integers(0, 256, (n, *size, 3), dtype=np.uint8)


def test_at_the_models_rate_every_frame_passes_through_untouched():
    clock, video = ModelClock(25.0), _frames(10)
    for k, f in enumerate(video):
        (tick,) = clock.ticks(k / 25.0, [f])
        assert tick[0] is f


def test_a_slower_source_gets_the_moments_between_its_frames_blended():
    clock, video = ModelClock(25.0), list(_frames(4))
    ticks = [clock.ticks(k / 12.5, [f]) for k, f in enumerate(video)]
    assert [len(t) for t in ticks] == [1, 2, 2, 2]  # 12.5 frames/s: two ticks a frame after the first
    assert ticks[1][1][0] is video[1] and np.array_equal(ticks[1][0][0], blend(video[0], video[1], 0.5))
    half = (video[0].astype(np.float32) + video[1]) / 2
    assert np.abs(ticks[1][0][0] - half).max() <= 0.5


def test_a_faster_source_steps_the_model_at_its_rate_and_dropped_frames_are_filled():
    clock = ModelClock(25.0)
    counts = [len(clock.ticks(k / 50.0, [f])) for k, f in enumerate(_frames(9))]
    assert counts == [1, 0, 1, 0, 1, 0, 1, 0, 1]
    clock = ModelClock(25.0)
    stamps = [0.0, 0.04, 0.12, 0.16]  # the frame at 0.08 s was dropped
    assert [len(clock.ticks(t, [f])) for t, f in zip(stamps, _frames(4))] == [1, 1, 2, 1]


def test_stamps_that_go_backwards_and_long_pauses():
    clock = ModelClock(25.0, name="cam0")
    clock.ticks(1.0, [_frames(1)[0]])
    with pytest.raises(InputError, match="cam0.*backwards"):
        clock.ticks(0.5, [_frames(1)[0]])
    assert len(clock.ticks(3.0, [_frames(1)[0]])) == 1 and clock.gaps == 1  # no 50 made-up frames


@pytest.mark.parametrize("fps", [0, 1000, float("nan"), -25, True, "25"])
def test_rates_out_of_range_are_refused(fps):
    with pytest.raises(ConfigError, match="frame rate"):
        check_fps(fps, "--fps")
    with pytest.raises(InputError, match="sensor.json.*frame rate"):
        check_fps(fps, "sensor.json")


def test_resample_gives_what_the_clock_gives_frame_by_frame():
    video, stamps = _frames(7), np.array([0, 0.07, 0.13, 0.2, 0.26, 0.33, 0.4])
    ticks, last = resample([video], stamps, 25.0)
    clock, pushed = ModelClock(25.0), []
    for t, f in zip(stamps, video):
        pushed += [x[0] for x in clock.ticks(t, [f])]
    assert len(ticks[0]) == len(pushed) == 11 and all(np.array_equal(a, b) for a, b in zip(ticks[0], pushed))
    assert last.tolist() == [0, 1, 3, 5, 6, 8, 10]


def _detector():
    import torch

    from slipsense.models import build

    torch.manual_seed(0)
    model = build(
        "motionnet", width=2, features=4, temporal=4, lags=[1, 2], dilations=[1], image_size=[12, 16], sensors=1
    )
    return SlipDetector(model, sensors=1, info={"operating_point": {"startup": 0}})


def test_stamped_pushes_at_the_models_rate_equal_plain_pushes_and_replay_equals_pushes():
    video = _frames(30, size=(24, 32))
    plain, stamped = _detector(), _detector()
    a = [plain.push(f).probability for f in video]
    b = [stamped.push(f, stamp=k / 25.0).probability for k, f in enumerate(video)]
    assert a == b
    stamps = np.cumsum(np.r_[0, np.random.default_rng(1).uniform(0.05, 0.09, 29)])  # about 15 frames/s, jitter
    slow = _detector()
    pushed = np.array([slow.push(f, stamp=t).probability for f, t in zip(video, stamps)], dtype=float)
    replayed = slow.replay(video, stamps=stamps).probability
    assert np.allclose(np.nan_to_num(pushed, nan=-1), np.nan_to_num(replayed, nan=-1), atol=1e-5)
    assert slow.push(video[0], stamp=stamps[-1] + 0.04).index == 30  # readings count source frames


def test_watch_reads_a_video_at_the_rate_it_states_and_stamps_readings_on_its_clock(tmp_path):
    """A 12.5 frames/s AVI: readings k at k / 12.5 s, the GIF plays at the same speed, and the
    detector (trained at 25 frames/s) is told so in one line."""
    import json

    import cv2
    from PIL import Image
    from typer.testing import CliRunner

    from slipsense.cli import app

    video = tmp_path / "slow.avi"
    w = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"XVID"), 12.5, (320, 240))
    for f in _frames(20, size=(240, 320)):
        w.write(f)
    w.release()
    out, gif = tmp_path / "r.jsonl", tmp_path / "r.gif"
    res = CliRunner().invoke(app, ["watch", str(video), "--jsonl", str(out), "--out", str(gif), "--quiet"])
    assert res.exit_code == 0, res.output
    assert "12.5 frames/s (the video's stated rate); the detector runs at 25 frames/s" in res.output
    stamps = [json.loads(line)["stamp"] for line in out.read_text().splitlines()]
    assert stamps == pytest.approx([k / 12.5 for k in range(20)])
    assert Image.open(gif).info["duration"] == 80  # ms a frame: real time
