"""One set of recordings, read once: ``Recordings.open`` lists each folder once, and whatever is asked
of the set after (another sensor's layout, a fold, a rate, a worker's pickled copy) lists nothing again."""

from __future__ import annotations

import json
import pickle

import pytest
from dataclasses import replace

from slipsense.errors import InputError
from slipsense.recordings.recording_set import Recordings
from slipsense.sensors.spec import GELSIGHT_LIFT, GELSIGHT_MINI


def test_a_video_set_is_listed_once_and_folds_rates_and_copies_list_nothing(grasp_recordings, folder_opens):
    with folder_opens:
        data = Recordings.open(grasp_recordings)
    runs = sorted({r.path.parent for r in data.listed})
    assert folder_opens.count(grasp_recordings) == 1 and all(folder_opens.count(r) == 1 for r in runs)
    assert data.objects == ["obj0", "obj1", "obj2", "obj3"] and len(data) == 16 and not data.frames
    with folder_opens:
        fold = data.without(["obj0"])
        again = pickle.loads(pickle.dumps(fold))  # what a worker process receives
        lift_layout = again.read_with(GELSIGHT_LIFT)
        checked = again.checked()
        rate = again.rate(checked[0])
    assert folder_opens.listed == []
    assert fold.objects == again.objects == ["obj1", "obj2", "obj3"] and len(checked) == 12
    assert lift_layout.listed == again.listed  # a layout of frame folders reads videos as the study laid them out
    assert rate == (25.0, "the video's stated rate")
    assert data.subset(["obj2"]).objects == ["obj2"] and data.only(checked[:2]).listed == tuple(checked[:2])


def test_a_frame_folder_set_states_its_sensor_and_rate_once(tmp_path, folder_opens):
    from test_frame_folders import _lift_data

    root = _lift_data(tmp_path / "lift")
    with folder_opens:
        data = Recordings.open(root, sensor=None)
        rates = {data.rate(r) for r in data.listed}
    assert folder_opens.count(root) == 1
    assert data.frames and data.stated == GELSIGHT_LIFT and data.sensor == GELSIGHT_LIFT
    assert rates == {(GELSIGHT_LIFT.fps, "the gelsight-lift layout")}
    (root / "sensor.json").write_text(json.dumps({"name": "my-gelsight", "output": "video", "fps": 12.5}))
    mine = Recordings.open(root)
    assert mine.stated.name == "my-gelsight" and mine.sensor.name == "my-gelsight"  # the sensor it states
    assert mine.rate(mine.listed[0]) == (12.5, str(root / "sensor.json"))


def test_frames_that_state_no_rate_are_refused_saying_how_to_state_it(tmp_path):
    from test_frame_folders import _grasp

    root = tmp_path / "mine"
    for i, slipped in enumerate((True, False)):
        _grasp(root / "cup" / f"grasp_{i}", slipped, seed=i, n=6, size=(48, 64))
    with pytest.raises(InputError, match=r"mine: no sensor is stated for it: put a sensor.json in it .* --sensor NAME"):
        Recordings.open(root)  # no sensor is assumed
    data = Recordings.open(root, GELSIGHT_MINI)  # read as a detector's sensor: its rate is not the data's
    assert data.frames and data.stated is None and data.sensor == GELSIGHT_MINI
    with pytest.raises(InputError, match=r"states no frame rate: state it in a sensor.json"):
        data.rate(data.listed[0])
    mine = Recordings.open(root, stated=replace(GELSIGHT_MINI, name="mine", fps=50.0))  # the user's --sensor
    assert mine.rate(mine.listed[0])[0] == 50.0
    with pytest.raises(InputError, match="recordings folder does not exist"):
        Recordings.open(tmp_path / "nope")


def test_a_video_skipped_once_still_raises_when_asked_to(grasp_recordings, tmp_path):
    import shutil

    from slipsense.recordings.folders import SkippedInputWarning

    root = tmp_path / "grasps"
    shutil.copytree(grasp_recordings, root)
    (root / "obj1" / "exp_num_2" / "camera_0.avi").write_bytes(b"not a video")
    data = Recordings.open(root)
    with pytest.warns(SkippedInputWarning):
        assert len(data.checked("skip")) == 15
    with pytest.raises(InputError, match="camera_0.avi"):
        data.checked("raise")


def test_grasps_are_read_once_per_set(grasp_recordings, cache, monkeypatch):
    import numpy as np

    from slipsense.training import grasps

    reads = []
    real = grasps._read_grasp_data
    monkeypatch.setattr(grasps, "_read_grasp_data", lambda *a: reads.append(1) or real(*a))
    data = Recordings.open(grasp_recordings)
    runs, labels = grasps.load_grasp_data(data, progress=False)
    again, _ = grasps.load_grasp_data(data.without([]), progress=False)  # a fold of the same set
    assert len(reads) == 1 and [r.key for r in again] == [r.key for r in runs]
    assert again[0].gray is runs[0].gray  # the same frames, not read again
    grasps.load_grasp_data(data, overrides=False, progress=False)  # no hand labels here: the same labels, kept
    assert len(reads) == 1
    grasps.load_grasp_data(data.without(["obj0"]), progress=False)  # other runs: read
    assert len(reads) == 2
    copy = pickle.loads(pickle.dumps(data))  # what a spawned worker receives: names, never frames
    assert copy._kept == {} and len(pickle.dumps(data)) < 100_000 and isinstance(runs[0].gray, np.ndarray)
