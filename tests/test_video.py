"""Video decoding (slipsense.recordings.video) and recording discovery (slipsense.recordings.folders)."""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from slipsense import paths
from slipsense.errors import ConfigError, InputError
from slipsense.recordings import video as video_mod
from slipsense.recordings.folders import (
    SkippedInputWarning,
    find_recordings,
    validate_recordings,
)
from slipsense.recordings.video import TRUNCATION_TOLERANCE, VideoInfo, probe_video, read_video

from striped_video import frame_for, index_of, write_video  # noqa: E402


def one_line(exc: pytest.ExceptionInfo, path: Path, *words: str) -> None:
    text = str(exc.value)
    assert "\n" not in text
    assert text.startswith(f"{path}: ")
    for word in words:
        assert word in text, text


# --------------------------------------------------------------------------------- read / probe


def test_read_video_round_trip(tmp_path):
    path = write_video(tmp_path / "v.avi", 30)
    frames = read_video(path)
    assert frames.shape == (30, 240, 320, 3) and frames.dtype == np.uint8
    assert [index_of(f) for f in frames] == list(range(30))


def test_probe_video_matches_read(tmp_path):
    path = write_video(tmp_path / "v.avi", 30)
    info = probe_video(path)
    assert info == VideoInfo(n_frames=30, height=240, width=320, fps=25.0, fourcc=info.fourcc)
    assert info.fourcc  # XVID is stored as an MPEG-4 part 2 tag


def test_missing_file(tmp_path):
    for fn in (read_video, probe_video):
        with pytest.raises(InputError) as exc:
            fn(tmp_path / "nope.avi")
        one_line(exc, tmp_path / "nope.avi", "does not exist")


def test_directory_instead_of_file(tmp_path):
    with pytest.raises(InputError, match="not a file"):
        read_video(tmp_path)


def test_empty_file(tmp_path):
    path = tmp_path / "empty.avi"
    path.write_bytes(b"")
    for fn in (read_video, probe_video):
        with pytest.raises(InputError) as exc:
            fn(path)
        one_line(exc, path, "empty")


def test_png_renamed_avi(tmp_path):
    png = tmp_path / "img.png"
    assert cv2.imwrite(str(png), frame_for(3))
    path = tmp_path / "img.avi"
    png.rename(path)
    # FFmpeg alone would "open" this as a one-frame video; the container check must refuse it.
    for fn in (read_video, probe_video):
        with pytest.raises(InputError) as exc:
            fn(path)
        one_line(exc, path, "not a video", "PNG")


@pytest.mark.parametrize("content", [b"hello, not a video\n", bytes(range(256)) * 8, b"RIFF\x00\x00\x00\x00WAVEfmt "])
def test_other_non_videos(tmp_path, content):
    path = tmp_path / "junk.avi"
    path.write_bytes(content)
    with pytest.raises(InputError) as exc:
        read_video(path)
    one_line(exc, path, "not a video")


def test_truncated_avi(tmp_path):
    path = write_video(tmp_path / "v.avi", 40)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError) as exc:
        read_video(path)
    one_line(exc, path, "truncated", "40 frames")
    with pytest.raises(InputError) as exc:
        probe_video(path)
    one_line(exc, path, "truncated")


def test_avi_cut_inside_header(tmp_path):
    path = write_video(tmp_path / "v.avi", 10)
    path.write_bytes(path.read_bytes()[:300])
    with pytest.raises(InputError) as exc:
        read_video(path)
    assert str(exc.value).startswith(f"{path}: ")


def test_lost_index_only_is_accepted(tmp_path):
    # The last bytes of an AVI are its index; every frame is still there and decodes.
    path = write_video(tmp_path / "v.avi", 20)
    path.write_bytes(path.read_bytes()[:-64])
    frames = read_video(path)
    assert len(frames) >= 20 - TRUNCATION_TOLERANCE
    assert [index_of(f) for f in frames] == list(range(len(frames)))


def test_wrong_resolution(tmp_path):
    path = write_video(tmp_path / "small.avi", 10, size=(120, 160))
    for fn in (read_video, probe_video):
        with pytest.raises(InputError) as exc:
            fn(path, expected_size=(240, 320))
        one_line(exc, path, "160x120", "expected 320x240")
    assert read_video(path).shape == (10, 120, 160, 3)  # no size is assumed
    assert read_video(path, expected_size=None).shape == (10, 120, 160, 3)
    assert read_video(path, expected_size=(120, 160)).shape == (10, 120, 160, 3)
    assert probe_video(path, expected_size=None).width == 160


def test_one_frame_video(tmp_path):
    path = write_video(tmp_path / "one.avi", 1)
    for fn in (read_video, probe_video):
        with pytest.raises(InputError) as exc:
            fn(path)
        one_line(exc, path, "only 1 frame", "at least 2")
    assert read_video(path, min_frames=1).shape == (1, 240, 320, 3)


def test_zero_frame_video(tmp_path):
    path = write_video(tmp_path / "zero.avi", 0)
    for fn in (read_video, probe_video):
        with pytest.raises(InputError) as exc:
            fn(path)
        one_line(exc, path, "no decodable frames")


def test_min_frames_above_length(tmp_path):
    path = write_video(tmp_path / "v.avi", 6)
    with pytest.raises(InputError, match="only 6 frames, need at least 7"):
        read_video(path, min_frames=7)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"min_frames": 0},
        {"min_frames": True},
        {"expected_size": (240,)},
        {"expected_size": (0, 320)},
        {"expected_size": "240x320"},
    ],
)
def test_bad_arguments(tmp_path, kwargs):
    path = write_video(tmp_path / "v.avi", 3)
    with pytest.raises(InputError):
        read_video(path, **kwargs)


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root reads files whatever their mode")
def test_unreadable_file(tmp_path):
    path = write_video(tmp_path / "v.avi", 5)
    path.chmod(0)
    try:
        with pytest.raises(InputError) as exc:
            read_video(path)
        one_line(exc, path, "permission denied")
    finally:
        path.chmod(0o644)


class FakeCapture:
    """Stands in for cv2.VideoCapture: yields the given frames, claims the given count."""

    def __init__(self, frames, count=None):
        self.frames, self.i = frames, 0
        self.count = len(frames) if count is None else count

    def isOpened(self):
        return True

    def get(self, prop):
        h, w = self.frames[0].shape[:2]
        return {
            cv2.CAP_PROP_FRAME_COUNT: self.count,
            cv2.CAP_PROP_FRAME_WIDTH: w,
            cv2.CAP_PROP_FRAME_HEIGHT: h,
            cv2.CAP_PROP_FPS: 25.0,
            cv2.CAP_PROP_FOURCC: 0,
        }.get(prop, 0.0)

    def read(self, image=None):
        if self.i >= len(self.frames):
            return False, None
        self.i += 1
        return True, self.frames[self.i - 1].copy()

    def set(self, prop, value):
        self.i = int(value)
        return True

    def release(self):
        pass


def test_inconsistent_frame_shapes(tmp_path, monkeypatch):
    path = write_video(tmp_path / "v.avi", 3)  # a real container, so the file checks pass
    frames = [frame_for(0), frame_for(1), frame_for(2, size=(120, 160))]
    monkeypatch.setattr(video_mod, "_open_capture", lambda p: FakeCapture(frames))
    with pytest.raises(InputError) as exc:
        read_video(path, expected_size=None)
    one_line(exc, path, "inconsistent frame sizes", "frame 2")
    monkeypatch.setattr(video_mod, "_open_capture", lambda p: FakeCapture(frames))
    with pytest.raises(InputError, match="inconsistent frame sizes"):
        probe_video(path, expected_size=None, min_frames=1)


def test_more_frames_than_stated_are_kept(tmp_path, monkeypatch):
    path = write_video(tmp_path / "v.avi", 3)
    frames = [frame_for(i) for i in range(5)]
    monkeypatch.setattr(video_mod, "_open_capture", lambda p: FakeCapture(frames, count=3))
    got = read_video(path)
    assert [index_of(f) for f in got] == [0, 1, 2, 3, 4]


def test_opencv_errors_become_input_errors(tmp_path, monkeypatch):
    path = write_video(tmp_path / "v.avi", 3)

    class Exploding(FakeCapture):
        def read(self, image=None):
            raise cv2.error("boom\nwith a second line")

    monkeypatch.setattr(video_mod, "_open_capture", lambda p: Exploding([frame_for(0)]))
    with pytest.raises(InputError) as exc:
        read_video(path)
    one_line(exc, path, "decoding failed at frame 0", "boom")


# ----------------------------------------------------------------------------------------- folders


def make_tree(
    root: Path, spec: dict[str, dict[int, bool]], n_frames: int = 4, cameras=("camera_0", "camera_2")
) -> None:
    """spec: object -> {experiment number -> slipped}."""
    for obj, exps in spec.items():
        for num, slipped in exps.items():
            d = root / obj / f"exp_num_{num}"
            for cam in cameras:
                write_video(d / f"{cam}.avi", n_frames, size=(48, 64))
            if slipped:
                (d / "slip.txt").write_text("")


def test_find_recordings_sorted_and_complete(tmp_path):
    make_tree(tmp_path, {"pear": {2: False, 10: True}, "apple": {1: True}})
    (tmp_path / "LICENSE").write_text("x")  # stray files at the top are ignored
    (tmp_path / ".hidden").mkdir()
    recs = find_recordings(tmp_path)
    assert [r.key for r in recs] == [
        ("apple", 1, "camera_0"),
        ("apple", 1, "camera_2"),
        ("pear", 2, "camera_0"),
        ("pear", 2, "camera_2"),
        ("pear", 10, "camera_0"),
        ("pear", 10, "camera_2"),
    ]  # numeric, not lexical, experiment order
    assert [r.slipped for r in recs] == [True, True, False, False, True, True]
    assert recs[0].path == tmp_path / "apple" / "exp_num_1" / "camera_0.avi"


def test_find_recordings_root_problems(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        find_recordings(tmp_path / "missing")
    f = tmp_path / "file"
    f.write_text("")
    with pytest.raises(InputError, match="not a folder"):
        find_recordings(f)
    empty = tmp_path / "empty"
    empty.mkdir()
    for on_error in ("raise", "skip"):
        with pytest.raises(InputError, match="no object folders"):
            find_recordings(empty, on_error=on_error)
    with pytest.raises(ConfigError):
        find_recordings(tmp_path, on_error="ignore")


def test_experiment_without_videos_raises_or_skips(tmp_path):
    make_tree(tmp_path, {"apple": {1: False}})
    bad = tmp_path / "apple" / "exp_num_2"
    bad.mkdir()
    (bad / "slip.txt").write_text("")
    with pytest.raises(InputError) as exc:
        find_recordings(tmp_path)
    one_line(exc, bad, "no camera_*.avi")
    with pytest.warns(SkippedInputWarning, match="exp_num_2.*no camera_"):
        recs = find_recordings(tmp_path, on_error="skip")
    assert {r.experiment for r in recs} == {1}


def test_bad_experiment_names_and_duplicates(tmp_path):
    make_tree(tmp_path, {"apple": {1: False}})
    (tmp_path / "apple" / "experiment_3").mkdir()
    with pytest.raises(InputError, match="does not match exp_num_<N>"):
        find_recordings(tmp_path)
    with pytest.warns(SkippedInputWarning, match="experiment_3"):
        assert len(find_recordings(tmp_path, on_error="skip")) == 2
    (tmp_path / "apple" / "experiment_3").rmdir()
    write_video(tmp_path / "apple" / "exp_num_01" / "camera_0.avi", 2, size=(48, 64))
    with pytest.raises(InputError, match="experiment 1 also found"):
        find_recordings(tmp_path)


def test_object_without_experiments(tmp_path):
    make_tree(tmp_path, {"apple": {1: False}})
    (tmp_path / "banana").mkdir()
    with pytest.raises(InputError, match="banana: object folder holds no exp_num"):
        find_recordings(tmp_path)
    with pytest.warns(SkippedInputWarning):
        assert {r.object for r in find_recordings(tmp_path, on_error="skip")} == {"apple"}


def test_skip_everything_still_raises(tmp_path):
    (tmp_path / "apple" / "exp_num_1").mkdir(parents=True)
    with pytest.warns(SkippedInputWarning), pytest.raises(InputError, match="no usable recordings"):
        find_recordings(tmp_path, on_error="skip")


def test_validate_recordings(tmp_path):
    make_tree(tmp_path, {"apple": {1: False, 2: True}}, n_frames=4)
    broken = tmp_path / "apple" / "exp_num_2" / "camera_2.avi"
    broken.write_bytes(broken.read_bytes()[:400])
    recs = find_recordings(tmp_path)  # structure only: the broken file is still listed
    assert len(recs) == 4
    with pytest.raises(InputError) as exc:
        validate_recordings(recs, expected_size=(48, 64))
    assert str(exc.value).startswith(f"{broken}: ")
    with pytest.warns(SkippedInputWarning) as record:
        good = validate_recordings(recs, on_error="skip", expected_size=(48, 64))
    assert [r.path for r in good] == [r.path for r in recs if r.path != broken]
    assert len(record) == 1 and str(broken) in str(record[0].message)
    # Wrong size is a validation failure too.
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert validate_recordings(recs, on_error="skip", expected_size=(240, 320)) == []
    assert len(caught) == 4


# -------------------------------------------------------------------------------------- real data

REAL = paths.gelsight_recordings()


@pytest.mark.skipif(not REAL.is_dir(), reason="shared GelSight recordings not present")
def test_real_recordings():
    recs = find_recordings(REAL)
    assert len(recs) >= 2 and all(r.camera.startswith("camera_") for r in recs)
    rec = recs[0]
    info = probe_video(rec.path)
    frames = read_video(rec.path)
    assert frames.shape == (info.n_frames, 240, 320, 3) and frames.dtype == np.uint8
    assert info.fps == pytest.approx(25.0)
    # Both cameras of a run have the same number of frames (README).
    partner = next(r for r in recs if r.object == rec.object and r.experiment == rec.experiment and r != rec)
    assert probe_video(partner.path).n_frames == info.n_frames


def test_absurd_header_count_is_reported_not_allocated(tmp_path, monkeypatch):
    path = write_video(tmp_path / "v.avi", 3)
    frames = [frame_for(i) for i in range(4)]
    monkeypatch.setattr(video_mod, "_open_capture", lambda p: FakeCapture(frames, count=900_000))
    with pytest.raises(InputError, match="truncated: the container states 900000 frames but only 4"):
        read_video(path)
