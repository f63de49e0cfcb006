"""The frame-rate study's conditions: which recorded frames a slower or lossier sensor would have given."""

from __future__ import annotations

import numpy as np

from studies.grasp.rates import at_rate, dropped, folds_study, rates_study, table
from studies.pages import folds_table


def test_a_slower_sensor_takes_the_recorded_frame_at_or_before_each_of_its_moments():
    idx, stamps = at_rate(12.5).frames(10, np.random.default_rng(0))
    assert idx.tolist() == [0, 2, 4, 6, 8] and np.allclose(stamps, np.arange(5) / 12.5)
    idx, stamps = at_rate(15.0).frames(11, np.random.default_rng(0))
    assert idx.tolist() == [0, 1, 3, 5, 6, 8, 10] and np.allclose(np.diff(stamps), 1 / 15)
    assert np.all(idx / 25.0 <= stamps + 1e-9) and np.all(stamps - idx / 25.0 < 1 / 25)


def test_dropped_frames_keep_their_stamps_and_the_ends():
    cond = dropped(0.1)
    idx, stamps = cond.frames(1000, np.random.default_rng(0))
    assert idx[0] == 0 and idx[-1] == 999 and 850 < len(idx) < 950 and np.allclose(stamps, idx / 25.0)
    assert cond.fps == 22.5


def test_the_table_reads_as_counts_of_runs():
    row = {"slip_runs": 5, "warned": 2, "premature": 0, "missed": 3, "held_runs": 9, "false_positive_grasps": 1}
    text = table({"rows": [{"condition": "as recorded", "clock": row, "plain": {**row, "warned": 1}}]})
    assert "| as recorded | 2 of 5 | 1 of 9 | 1 of 5 | 1 of 9 |" in text


def test_folds_table_puts_the_baseline_beside_and_says_which_rows_keep_the_bound():
    def row(warned, fp):
        return {
            "slip_runs": 10, "warned": warned, "held_runs": 20, "false_positive_grasps": fp,
            "warned_interval": (0.1, 0.5), "false_positive_interval": (0.0, 0.2),
        }  # fmt: skip

    doc = {
        "rows": [
            {"condition": "as recorded", "detector": row(5, 1), "baseline": row(4, 3)},
            {"condition": "slower", "detector": row(3, 3), "baseline": row(4, 3)},
            {"condition": "slowest", "detector": row(2, 1), "baseline": row(4, 3)},
        ]
    }
    text = folds_table(doc)
    assert "| as recorded | 5 of 10 (10-50%) | 1 of 20 (0-20%) | 4 of 10 (10-50%) | 3 of 20 (0-20%) | yes |" in text
    assert "| slower | 3 of 10" in text and text.splitlines()[3].endswith("| yes |")
    assert text.splitlines()[4].endswith("| no |")  # 3 slips fewer


def test_the_folds_pool_every_held_out_run_once(tmp_path, cache, grasp_recordings):
    """Two folds of two objects each, the same detector in both: pooled, they judge every run once,
    as one replay of the whole folder does."""
    import json
    import shutil

    from slipsense.resources import shipped_model

    for k, held in enumerate((["obj0", "obj1"], ["obj2", "obj3"])):
        (tmp_path / "folds" / f"fold{k}").mkdir(parents=True)
        shutil.copy(shipped_model(), tmp_path / "folds" / f"fold{k}" / "detector.safetensors")
        (tmp_path / "folds" / f"fold{k}" / "held_out.json").write_text(json.dumps({"objects": held}))
    pooled = folds_study(grasp_recordings, tmp_path / "folds", progress=False)
    whole = rates_study(grasp_recordings, shipped_model(), progress=False)
    assert len(pooled["folds"]) == 2
    for p, w in zip(pooled["rows"][:3], whole["rows"][:3]):  # the dropped frames are drawn differently
        assert p["detector"] == w["clock"] and p["detector"]["slip_runs"] + p["detector"]["held_runs"] == 8


def test_a_frame_folder_set_at_half_its_rate_is_read_back_at_that_rate(tmp_path):
    from slipsense.recordings.recording_set import Recordings
    from slipsense.recordings.video import read_video
    from studies.grasp.derive import slower_frame_folders
    from tests.test_frame_folders import _lift_data

    root = _lift_data(tmp_path / "lift")
    assert slower_frame_folders(root, tmp_path / "half", every=2) == 12
    full, half = Recordings.open(root).listed, Recordings.open(tmp_path / "half")
    assert [(r.object, r.slipped) for r in full] == [(r.object, r.slipped) for r in half]
    a, b = read_video(full[0].path, expected_size=None), read_video(half.listed[0].path, expected_size=None)
    assert len(b) == 6 and np.array_equal(a[::2], b)  # the same frames, every other one
    assert half.rate(half.listed[0]) == (15.0, str(tmp_path / "half" / "sensor.json"))
