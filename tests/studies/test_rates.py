"""The frame-rate study's conditions: which recorded frames a slower or lossier sensor would have given."""

from __future__ import annotations

import numpy as np

from studies.grasp.rates import at_rate, dropped, table


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
