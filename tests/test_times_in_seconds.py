"""Every time the judge reads is in seconds: the warning horizon is 2 s and the start-up 0.4 s at any
frame rate, counted in frames at the rate of the detector and its runs."""

import numpy as np
import pytest

from slipsense.errors import ConfigError
from slipsense.measures import Judged, measure_all
from slipsense.measures.pergrasp import RunTrace
from slipsense.measures.registry import HORIZON_S, STARTUP_S, horizon_frames, startup_frames, to_frames


def _slip(fps: float, early_s: float, seconds: float = 12.0) -> RunTrace:
    """A slip run at ``fps`` whose moment of slip is at 10 s, alarming from ``early_s`` before it on."""
    n, moment = int(seconds * fps), int(10 * fps)
    p = np.zeros(n)
    p[moment - to_frames(early_s, fps) : moment + 1] = 1.0
    return RunTrace("o", 1, True, moment, n, p, np.zeros(n, bool), ("camera_0",), fps, fps)


def _judged(runs, fps: float) -> Judged:
    """The runs as the judge hands them to the measures: horizon and start-up from seconds at the rate."""
    return Judged(runs, [(0.5, 1, 0.0)] * len(runs), horizon_frames(fps), startup_frames(fps))


@pytest.mark.parametrize("fps", [25.0, 50.0, 30.0])
def test_an_alarm_1_5_s_early_is_in_time_and_2_5_s_early_is_not_at_any_rate(fps):
    in_time = measure_all(_judged([_slip(fps, 1.5)], fps), ["per_grasp"])["per_grasp"]
    assert (in_time["warned"], in_time["premature"]) == (1, 0)
    assert in_time["median_lead_ms"] == pytest.approx(1500.0, abs=1000 / fps)
    early = measure_all(_judged([_slip(fps, 2.5)], fps), ["per_grasp"])["per_grasp"]
    assert (early["warned"], early["premature"]) == (0, 1)


def test_the_horizon_is_two_seconds_in_frames_at_the_rate():
    assert (HORIZON_S, STARTUP_S) == (2.0, 0.4)
    assert (horizon_frames(25.0), startup_frames(25.0)) == (50, 10)  # the GelSight Mini's pinned figures
    assert (horizon_frames(50.0), startup_frames(50.0)) == (100, 20)
    assert (horizon_frames(30.0), startup_frames(30.0)) == (60, 12)


def test_a_run_judged_without_a_horizon_takes_two_seconds_at_its_detector_rate():
    run = _slip(50.0, 1.5)
    assert run.outcome(0.5).outcome == "warned"  # 75 frames early: within 100, not within 50
    assert _slip(50.0, 2.5).outcome(0.5).outcome == "premature"


def test_a_run_without_a_rate_or_a_horizon_without_a_time_is_refused():
    with pytest.raises(ConfigError, match="fps"):
        RunTrace("o", 1, False, None, 10, np.zeros(10))
    for bad in (0, -1.0, float("nan"), float("inf"), True):
        with pytest.raises(ConfigError, match="seconds"):
            horizon_frames(25.0, bad)


def test_a_grasp_detector_trains_its_warning_window_in_seconds():
    """The training recipe's horizon and start-up are 2 s and 0.4 s at the recordings' sensor's rate."""
    from slipsense.models import model_class
    from slipsense.models.base import RecordingsShape

    motionnet = model_class("motionnet")
    at50 = motionnet.training_defaults(RecordingsShape(cameras=2, per_grasp=False, fps=50.0))
    at25 = motionnet.training_defaults(RecordingsShape(cameras=2, per_grasp=False, fps=25.0))
    assert (at50["horizon"], at50["startup"]) == (100, 20) and (at25["horizon"], at25["startup"]) == (50, 10)
    whole = motionnet.training_defaults(RecordingsShape(cameras=1, per_grasp=True, fps=30.0))
    assert whole["horizon"] == 60 and whole["startup"] == 0  # labelled as a whole: no camera start-up
