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


def test_a_worn_gel_loses_a_tenth_of_its_markers_and_nothing_else():
    import cv2

    from slipsense.sensors.marker_detection import detect_markers

    frame = np.full((240, 320, 3), (170, 150, 120), np.uint8)
    for y in range(30, 240, 45):
        for x in range(30, 320, 45):
            cv2.circle(frame, (x, y), 8, (40, 40, 40), -1)
    v = np.repeat(frame[None], 12, axis=0)
    worn = LOOKS["10% of the gel's markers gone"](v)
    before, after = len(detect_markers(v[10])), len(detect_markers(worn[10]))
    assert before - after == round(0.1 * before) and worn.shape == v.shape and worn.dtype == np.uint8
    changed = np.flatnonzero((worn != v).any(axis=(0, 3)).any(axis=1))
    assert 0 < len(changed) < 240  # only rows around the painted markers
    assert np.array_equal(worn[0], worn[-1])  # the same markers gone in every frame
