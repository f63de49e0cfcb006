"""studies/lift_reference.py: the object's motion against the fingers from the outside camera.

Synthetic scenes with a teal finger on the left and a black finger on the right, as the external
camera of gelsight-lift sees them, and a textured object between them moved by a known rigid motion;
then one slipped and one held grasp of the shared data, where it is present.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from studies.lift_reference import find_region, lift_grasps, peak, read_frames, reference_motion

FPS = 30.0
H, W = 240, 320
PIVOT = (185.0, 125.0)  # the object turns about this point of its first frame


def _texture(shape: tuple[int, ...], seed: int, lo: float, hi: float, blur: float = 1.5) -> np.ndarray:
    t = cv2.GaussianBlur(np.random.default_rng(seed).random(shape).astype(np.float32), (0, 0), blur)
    return lo + (hi - lo) * (t - t.min()) / (t.max() - t.min())


def _scene(step=(0.0, 0.0, 0.0), common=(0.0, 0.0), n=21, noise=0.0) -> list[np.ndarray]:
    """n BGR frames: the object moves by step = (dx, dy, dtheta) per frame (px, px, rad, clockwise as
    the image is seen) about PIVOT, the whole picture (fingers and all) by ``common`` px per frame."""
    background = np.repeat(_texture((H, W), 1, 185, 215, 4)[..., None], 3, axis=2)
    teal = np.array([210.0, 180.0, 20.0]) * _texture((H, W), 2, 0.75, 1.0)[..., None]
    black = np.repeat(_texture((H, W), 3, 12, 45)[..., None], 3, axis=2)
    stuff = np.repeat(_texture((H, W), 4, 70, 230)[..., None], 3, axis=2)  # the object's surface
    on_object = np.zeros((H, W), np.float32)
    on_object[50:210, 120:260] = 1  # wider than the gap: the fingers cover its sides
    rng = np.random.default_rng(5)
    frames = []
    for k in range(n):
        dx, dy, th = (k * s for s in step)
        c, s = math.cos(th), math.sin(th)
        px, py = PIVOT
        m = np.array([[c, -s, px - c * px + s * py + dx], [s, c, py - s * px - c * py + dy]])
        obj = cv2.warpAffine(stuff, m, (W, H), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        mask = cv2.warpAffine(on_object, m, (W, H), flags=cv2.INTER_LINEAR)[..., None]
        img = background * (1 - mask) + obj * mask
        img[90:165, 40:150] = teal[90:165, 40:150]  # the GelSight finger, its tip at x 150
        img[105:240, 215:300] = black[105:240, 215:300]  # the black finger, its inner edge at x 215
        shift = np.array([[1.0, 0, k * common[0]], [0, 1.0, k * common[1]]])
        img = cv2.warpAffine(
            img.astype(np.float32), shift, (W, H), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT
        )
        if noise:
            img = img + rng.normal(0, noise, img.shape)
        frames.append(np.clip(img, 0, 255).astype(np.uint8))
    return frames


def _write(frames: list[np.ndarray], folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for i, f in enumerate(frames):
        cv2.imwrite(str(folder / f"external_img_{i:08d}.png"), f)
    return folder


def _expected(m: dict, step, common=(0.0, 0.0)) -> tuple[np.ndarray, float]:
    """The true velocity against the fingers (px/s) at the centre of the object's box, per frame, and
    omega (rad/s)."""
    x0, y0, x1, y1 = m["region"]["object_box"]
    cx, cy = (x0 + x1 - 1) / 2, (y0 + y1 - 1) / 2
    dx, dy, th = step
    v = []
    for k in range(1, m["frames"]):
        # the pivot rides with the object, and with the picture's common shift
        px, py = PIVOT[0] + (k - 1) * (dx + common[0]), PIVOT[1] + (k - 1) * (dy + common[1])
        v.append((dx - math.sin(th) * (cy - py), dy + math.sin(th) * (cx - px)))
    return np.array(v) * FPS, th * FPS


@pytest.mark.parametrize("common", [(0.0, 0.0), (0.25, -0.15)], ids=["still fingers", "fingers shifted too"])
def test_a_known_rigid_motion_is_read_back(tmp_path, common):
    step = (0.4, 1.0, 0.01)  # px, px, rad per frame: 12 and 30 px/s, 0.3 rad/s
    m = reference_motion(_write(_scene(step, common), tmp_path / "grasp"), FPS)
    assert m["usable"] and m["frames"] == 21
    x0, y0, x1, y1 = m["region"]["object_box"]
    assert 150 < x0 < x1 < 215 and 85 <= y0 < y1 <= 170  # between the fingers, level with the pad
    assert np.isnan(m["translation"][0]).all() and np.isnan(m["omega"][0]) and np.isnan(m["relative_speed"][0])
    v, omega = _expected(m, step, common)
    # DIS at its finest level (half the image's resolution) reads sub-pixel shifts to about 0.1 px
    assert np.abs(m["translation"][1:] - v).max() < 4.5  # px/s (0.15 px per frame), of 32
    assert np.abs(m["omega"][1:] - omega).max() < 0.075  # rad/s, of 0.3
    assert np.allclose(m["speed"][1:], np.hypot(*m["translation"][1:].T))
    lever = m["region"]["lever"]
    assert np.allclose(m["relative_speed"][1:], np.hypot(m["speed"][1:], m["omega"][1:] * lever))
    assert np.abs(m["finger_motion"][1:] - np.array(common) * FPS).max() < 4.5


def test_a_still_scene_reads_near_zero(tmp_path):
    m = reference_motion(_write(_scene(noise=2.0), tmp_path / "grasp"), FPS)
    assert m["usable"]
    assert peak(m["relative_speed"]) < 1.5  # px/s: 0.05 px per frame
    assert np.nanmax(np.abs(m["omega"])) < 0.05


def test_no_fingers_no_region(tmp_path):
    grey = [np.full((H, W, 3), 200, np.uint8)] * 3
    m = reference_motion(_write(grey, tmp_path / "grasp"), FPS)
    assert not m["usable"] and m["region"] is None and np.isnan(m["relative_speed"]).all()
    assert find_region(grey[0]) is None


def test_the_frames_must_be_there(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="at least 2 frames"):
        read_frames(tmp_path / "empty")


def test_a_real_slipped_grasp_peaks_above_a_held_one():
    grasps = {(g.object, g.grasp): g for g in lift_grasps()}
    slipped, held = grasps.get(("object003", "052_100_mm")), grasps.get(("object003", "052_000_mm"))
    if slipped is None or held is None or not slipped.external.is_dir() or not held.external.is_dir():
        pytest.skip("the shared gelsight-lift data is not here (SLIPSENSE_DATA)")
    assert slipped.slipped and not held.slipped and slipped.gelsight.is_dir()
    fast, still = reference_motion(slipped.external), reference_motion(held.external)
    assert fast["usable"] and still["usable"] and fast["frames"] == still["frames"] == 21
    assert peak(fast["relative_speed"]) > 2 * peak(still["relative_speed"])
    again = reference_motion(slipped.external)  # deterministic: the same numbers twice
    assert np.array_equal(again["relative_speed"], fast["relative_speed"], equal_nan=True)
    everything = lift_grasps()
    assert len(everything) == 44 and sum(g.slipped for g in everything) == 19
