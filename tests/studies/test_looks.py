"""The looks of another sensor unit that the robustness study applies to the recorded frames."""

from __future__ import annotations

import numpy as np

from studies.grasp.looks import LOOKS, table


def test_each_look_keeps_the_video_a_video_and_changes_it_as_named():
    v = np.full((3, 24, 32, 3), 200, np.uint8)
    assert LOOKS["as recorded"] is None
    assert LOOKS["exposure x0.7"](v).max() == 140 and LOOKS["exposure x1.3"](v).max() == 255  # clipped
    tinted = LOOKS["LED tint (B -20, R +25)"](v)
    assert tinted[..., 0].max() == 180 and tinted[..., 2].max() == 225 and tinted.dtype == np.uint8
    step = np.zeros((1, 24, 32, 3), np.uint8)
    step[:, :, 16:] = 255
    blurred = LOOKS["Gaussian blur (5 px, sigma 1.5)"](step)
    assert blurred.shape == step.shape and 0 < blurred[0, 10, 15, 0] < 255


def test_the_table_counts_runs():
    doc = {
        "rows": [{"look": "exposure x0.7", "warned": 7, "slip_runs": 51, "false_positive_grasps": 0, "held_runs": 85}]
    }
    assert "| exposure x0.7 | 7 of 51 | 0 of 85 |" in table(doc)
