"""The pictures ``slipsense watch --out`` writes: a GIF or MP4 anyone may read (the mode a plain
``open()`` gives under the umask), one GIF frame per frame pushed, showing what was drawn, and no file
at all when the run fails."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from slipsense.sensors.gel_motion import GelMotion
from slipsense.streaming.annotate import AnnotatedWriter, Annotator
from slipsense.streaming.detector import Reading


@pytest.fixture
def umask():
    """Set the umask for the test (``umask(value)``); the one before is restored."""
    before = os.umask(0o022)
    os.umask(before)
    yield os.umask
    os.umask(before)


def gel_frames(n: int, seed: int = 0, size=(240, 320)) -> list[np.ndarray]:
    """Gel-like BGR frames: a tinted gradient with dark markers drifting right, camera noise, and
    from the middle on a brighter exposure (a picture the first palette fits badly)."""
    rng = np.random.default_rng(seed)
    h, w = size
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    base = np.stack([90 + 60 * xx / w, 110 + 40 * yy / h, 70 + 30 * (xx + yy) / (w + h)], axis=-1)
    frames = []
    for t in range(n):
        f = base * (1.5 if t >= n // 2 else 1.0) + rng.normal(0, 2, base.shape)
        for cy in range(20, h, 40):
            for cx in range(20, w, 40):
                cv2.circle(f, (cx + t, cy), 7, (30, 35, 30), -1)
        frames.append(np.clip(f, 0, 255).astype(np.uint8))
    return frames


def annotated(n: int) -> list[np.ndarray]:
    """What `watch` draws for a two-finger run of ``n`` frames (window filling, no slip, then alarm)."""
    annot = Annotator(threshold=0.5, sensors=2, fps=25)
    left, right = gel_frames(n, 1), gel_frames(n, 2)
    pictures = []
    for k in range(n):
        p = None if k < 4 else min(1.0, k / n + 0.2)
        per = None if p is None else (p, p / 2)
        r = Reading(index=k, probability=p, per_sensor=per, alarm=p is not None and p >= 0.5)
        pictures.append(annot.draw([left[k], right[k]], r))
    return pictures


def decoded(path: Path) -> list[np.ndarray]:
    """Every frame of a GIF as a viewer shows it (BGR)."""
    with Image.open(path) as gif:
        frames = []
        for k in range(gif.n_frames):
            gif.seek(k)
            frames.append(cv2.cvtColor(np.asarray(gif.convert("RGB")), cv2.COLOR_RGB2BGR))
    return frames


def test_gif_has_a_frame_per_picture_and_shows_what_was_drawn(tmp_path):
    pictures = annotated(40)
    pictures += [pictures[-1]] * 3  # pictures that do not change are still a frame each
    writer = AnnotatedWriter(tmp_path / "run.gif", fps=25)
    for p in pictures:
        writer.add(p)
    assert writer.close() == tmp_path / "run.gif"
    with Image.open(tmp_path / "run.gif") as gif:
        assert gif.n_frames == len(pictures) and gif.info["duration"] == 40 and gif.size == (640, 358)
    shown = decoded(tmp_path / "run.gif")
    for k, (got, want) in enumerate(zip(shown, pictures)):
        err = np.abs(got.astype(np.int16) - want).max(axis=-1)
        assert err.mean() < 6, k  # 255 colours, a few levels off on average
        # the banner and its text are drawn in colours the palette holds exactly
        assert np.array_equal(got[:28, 300:], want[:28, 300:]), k


def test_gif_is_not_the_size_of_a_frame_each(tmp_path):
    """Only what changes between frames is written: much less than a full palette frame each."""
    pictures = annotated(40)
    writer = AnnotatedWriter(tmp_path / "run.gif", fps=25)
    for p in pictures:
        writer.add(p)
    writer.close()
    h, w = pictures[0].shape[:2]
    assert (tmp_path / "run.gif").stat().st_size < 0.5 * len(pictures) * h * w


def test_gif_frames_of_few_colours_are_exact_through_moves_and_a_new_palette(tmp_path):
    """A square moving over a plain ground, the ground changing colour halfway: every frame as a
    viewer composes it equals its picture, pixel for pixel (nothing stale from frames before)."""
    pictures = []
    for k in range(20):
        p = np.full((120, 160, 3), (128, 128, 128) if k < 10 else (90, 160, 30), np.uint8)
        p[40:70, 5 + 4 * k : 35 + 4 * k] = (255, 255, 255)
        p[100:, : 8 * k] = (0, 0, 200)
        pictures.append(p)
    writer = AnnotatedWriter(tmp_path / "moves.gif", fps=25)
    for p in pictures:
        writer.add(p)
    writer.close()
    shown = decoded(tmp_path / "moves.gif")
    assert len(shown) == len(pictures)
    for k, (got, want) in enumerate(zip(shown, pictures)):
        assert np.array_equal(got, want), k


def test_gif_follows_a_slow_change_of_the_whole_picture(tmp_path):
    """Exposure creeping up (0.7 levels a frame): pixels kept from earlier frames do not drift away
    from the picture, and the palette is made again when the picture has left it."""
    h, w = 120, 160
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    base = np.stack([90 + 60 * xx / w, 110 + 40 * yy / h, 70 + 30 * (xx + yy) / (w + h)], axis=-1)
    rng = np.random.default_rng(0)
    pictures = [np.clip(base + 0.7 * t + rng.normal(0, 1, base.shape), 0, 255).astype(np.uint8) for t in range(40)]
    writer = AnnotatedWriter(tmp_path / "ramp.gif", fps=25)
    for p in pictures:
        writer.add(p)
    writer.close()
    for k, (got, want) in enumerate(zip(decoded(tmp_path / "ramp.gif"), pictures)):
        err = np.abs(got.astype(np.int16) - want).max(axis=-1)
        assert err.mean() < 12 and np.percentile(err, 99) < 24, k


@pytest.mark.parametrize("suffix", [".gif", ".mp4"])
@pytest.mark.parametrize("mask", [0o022, 0o077])
def test_written_picture_has_the_mode_of_a_plain_open(tmp_path, umask, suffix, mask):
    umask(mask)
    out = tmp_path / f"run{suffix}"
    writer = AnnotatedWriter(out, fps=25)
    for p in annotated(6):
        writer.add(p)
    writer.close()
    assert out.stat().st_mode & 0o777 == 0o666 & ~mask
    if mask == 0o022:
        assert out.stat().st_mode & 0o044 == 0o044  # readable by others
    assert [p.name for p in tmp_path.iterdir()] == [out.name]  # no temporary file left


@pytest.mark.parametrize("suffix", [".gif", ".mp4"])
def test_aborted_picture_leaves_no_file(tmp_path, suffix):
    writer = AnnotatedWriter(tmp_path / f"run{suffix}", fps=25)
    for p in annotated(5):
        writer.add(p)
    writer.abort()
    assert list(tmp_path.iterdir()) == []
    assert writer.close() is None


def test_watch_out_gif_and_mp4_readable_by_others_one_frame_per_push(tmp_path, umask):
    from typer.testing import CliRunner

    from slipsense.cli import app

    umask(0o022)
    video = tmp_path / "gel.avi"
    w = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"XVID"), 25, (320, 240))
    for f in gel_frames(20):
        w.write(f)
    w.release()
    for suffix in (".gif", ".mp4"):
        out = tmp_path / f"run{suffix}"
        res = CliRunner().invoke(app, ["watch", str(video), "--out", str(out), "--quiet"])
        assert res.exit_code == 0, res.output
        assert "20 frames" in res.output
        assert out.stat().st_mode & 0o777 == 0o644
        if suffix == ".gif":
            with Image.open(out) as gif:
                assert gif.n_frames == 20
        else:
            cap = cv2.VideoCapture(str(out))
            assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 20
            cap.release()


def slip_drawn(translation, omega, stick) -> np.ndarray:
    """Where one finger's slip is drawn (yellow) on a plain grey frame: a (240, 320) mask of its panel."""
    speed = None if translation is None else float(np.hypot(*translation))
    gel = GelMotion(translation, omega, stick, speed, (0.0, 0.0), 0.0, 0.0, 0.0 if stick is None else 0.5, "mm")
    picture = Annotator(threshold=0.5, sensors=1, fps=25).draw(
        [np.full((240, 320, 3), 100, np.uint8)], Reading(0, None, None, False, (gel,), "mm")
    )
    panel = picture[28 : 28 + 240].astype(int)
    return (panel[..., 0] < 80) & (panel[..., 1] > 180) & (panel[..., 2] > 180)


def test_the_picture_shows_each_fingers_translation_turn_and_stick_share():
    assert not slip_drawn(None, None, None).any()  # no contact: nothing drawn
    above = slice(0, 120)  # the panel's upper half, where the arc starts (straight above the centre)
    clockwise, anticlockwise = slip_drawn((0.0, 0.0), 0.5, 1.0), slip_drawn((0.0, 0.0), -0.5, 1.0)
    # +omega turns +x towards +y: clockwise as drawn, from the top to the right; -omega to the left
    assert clockwise[above, 165:].sum() > 50 and not clockwise[above, :155].any()
    assert anticlockwise[above, :155].sum() > 50 and not anticlockwise[above, 165:].any()
    faster = slip_drawn((0.0, 0.0), 1.0, 1.0)
    assert faster[:200].sum() > 1.5 * clockwise[:200].sum()  # a longer sweep for a faster turn
    sliding = slip_drawn((10.0, 0.0), 0.0, 1.0)
    assert sliding[118:123, 165:].any() and not sliding[:100].any()  # an arrow to the right, no arc
    # the stick share as a bar: its filled part (a row inside the bar's frame) grows with the share
    filled = [slip_drawn((10.0, 0.0), 0.0, s)[240 - 27, 8:85].sum() for s in (0.0, 0.5, 1.0)]
    assert filled[0] == 0 and 35 <= filled[1] <= 42 and filled[2] == 77
