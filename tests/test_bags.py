"""ROS 2 bags in, readings out (JSON lines, a bag topic), and live capture at the source's rate."""

from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from conftest import REAL_RUN, needs_data
from slipsense.cli import app
from slipsense.errors import InputError
from slipsense.recordings.bags import UnpairedFramesWarning, pair_by_time, read_bag
from slipsense.streaming.capture import CaptureThread, PacedReader

FRAMES = 60  # of the real run: enough for the shipped detector to answer (start-up 10 frames)


def write_bag(
    path: Path,
    videos,
    topics,
    offsets_ns=(0, 3_000_000),
    compressed=(False, True),
    extra_string=False,
    slots=None,
    logged_in_order=False,
):
    """A rosbag2 (sqlite3) with one image topic per video: Image bgr8, or CompressedImage PNG
    (lossless), frames 40 ms apart, each topic's stamps shifted by its offset. ``slots``: per topic,
    the 40 ms slot of each of its frames (default 0, 1, 2, ...: a slot left out is a frame missing);
    ``logged_in_order``: messages logged 40 ms apart in the order written, whatever their header stamps."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    Image, Compressed = ts.types["sensor_msgs/msg/Image"], ts.types["sensor_msgs/msg/CompressedImage"]
    Header, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    String = ts.types["std_msgs/msg/String"]
    with Writer(path, version=9) as w:
        conns = [
            w.add_connection(t, (Compressed if c else Image).__msgtype__, typestore=ts)
            for t, c in zip(topics, compressed)
        ]
        text = w.add_connection("/notes", String.__msgtype__, typestore=ts) if extra_string else None
        slots = slots or [range(len(v)) for v in videos]
        for k in range(max(len(v) for v in videos)):
            for conn, video, off, comp, at in zip(conns, videos, offsets_ns, compressed, slots):
                if k >= len(video):
                    continue
                ns = 1_700_000_000_000_000_000 + at[k] * 40_000_000 + off
                header = Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id="gel")
                img = video[k]
                if comp:
                    msg = Compressed(
                        header=header, format="png", data=np.frombuffer(cv2.imencode(".png", img)[1], np.uint8)
                    )
                else:
                    h, wd = img.shape[:2]
                    msg = Image(
                        header=header,
                        height=h,
                        width=wd,
                        encoding="bgr8",
                        is_bigendian=0,
                        step=wd * 3,
                        data=img.reshape(-1),
                    )
                logged = 1_700_000_000_000_000_000 + k * 40_000_000 + off if logged_in_order else ns
                w.write(conn, logged, ts.serialize_cdr(msg, conn.msgtype))
            if text is not None:
                w.write(text, 1_700_000_000_000_000_000 + k, ts.serialize_cdr(String(data="hi"), String.__msgtype__))
    return path


def _videos(n=FRAMES):
    from slipsense.recordings.video import read_video

    return [read_video(REAL_RUN / f"{c}.avi", expected_size=None)[:n] for c in ("camera_0", "camera_2")]


def _run_folder(tmp_path, videos):
    """The same frames as a recordings experiment folder (lossless FFV1 AVI)."""
    folder = tmp_path / "run"
    folder.mkdir()
    for name, video in zip(("camera_0", "camera_2"), videos):
        w = cv2.VideoWriter(str(folder / f"{name}.avi"), cv2.VideoWriter_fourcc(*"FFV1"), 25, video.shape[2:0:-1])
        for f in video:
            w.write(f)
        w.release()
    return folder


def _jsonl(path):
    return [json.loads(line) for line in Path(path).read_text().splitlines()]


@needs_data
def test_a_bag_streams_like_the_same_frames_from_avi(tmp_path, cache, one_thread):
    videos = _videos()
    bag = write_bag(tmp_path / "grasp_bag", videos, ["/left/image_raw", "/right/image_raw"])
    topics = ["--topic", "/left/image_raw", "--topic", "/right/image_raw"]
    res = CliRunner().invoke(
        app, ["watch", str(bag), *topics, "--jsonl", str(tmp_path / "bag.jsonl"), "--bag-out", str(tmp_path / "alarms")]
    )
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(app, ["watch", str(_run_folder(tmp_path, videos)), "--jsonl", str(tmp_path / "avi.jsonl")])
    assert res.exit_code == 0, res.output
    from_bag, from_avi = _jsonl(tmp_path / "bag.jsonl"), _jsonl(tmp_path / "avi.jsonl")
    assert len(from_bag) == len(from_avi) == FRAMES
    assert [r["probability"] for r in from_bag] == [r["probability"] for r in from_avi]
    assert from_bag[0]["probability"] is None and from_bag[-1]["probability"] is not None
    assert from_bag[1]["stamp"] - from_bag[0]["stamp"] == pytest.approx(0.04, abs=1e-6)  # the bag's header time
    assert from_avi[1]["stamp"] == pytest.approx(0.04)  # index / fps
    assert all(r["latency_ms"] > 0 and isinstance(r["alarm"], bool) for r in from_bag)

    from slipsense.streaming.readings import read_bag_readings

    topic = read_bag_readings(tmp_path / "alarms")
    assert [r["frame"] for r in topic] == list(range(FRAMES)) and [r["alarm"] for r in topic] == [
        r["alarm"] for r in from_bag
    ]
    assert topic[-1]["probability"] == pytest.approx(from_bag[-1]["probability"], abs=1e-6)

    stdout = CliRunner().invoke(app, ["watch", str(bag), *topics, "--jsonl", "-", "--max-frames", "12"])
    assert stdout.exit_code == 0
    lines = [line for line in stdout.stdout.splitlines() if line.startswith("{")]
    assert len(lines) == 12 and json.loads(lines[-1])["frame"] == 11


def test_bag_bad_input_is_one_line(tmp_path):
    rng = np.random.default_rng(0)
    video = [rng.integers(0, 255, (6, 24, 32, 3), dtype=np.uint8)] * 2
    good = write_bag(tmp_path / "good", video, ["/a", "/b"], extra_string=True)
    cases = {
        "no topic /c": ["--topic", "/a", "--topic", "/c"],
        "/notes holds std_msgs/msg/String": ["--topic", "/a", "--topic", "/notes"],
    }
    for expect, topics in cases.items():
        res = CliRunner().invoke(app, ["watch", str(good), *topics])
        assert res.exit_code == 2 and expect in res.output and "good" in res.output, res.output
        assert "Traceback" not in res.output
    apart = write_bag(tmp_path / "apart", video, ["/a", "/b"], offsets_ns=(0, 100 * 10**9))
    res = CliRunner().invoke(app, ["watch", str(apart), "--topic", "/a", "--topic", "/b"])
    assert res.exit_code == 2 and "do not pair" in res.output and "apart" in res.output
    broken = tmp_path / "broken"
    broken.mkdir()
    for f in good.iterdir():
        (broken / f.name).write_bytes(f.read_bytes())
    db = next(broken.glob("*.db3"))
    db.write_bytes(db.read_bytes()[: db.stat().st_size // 3])
    res = CliRunner().invoke(app, ["watch", str(broken), "--topic", "/a", "--topic", "/b"])
    assert res.exit_code == 2 and "broken" in res.output and "Traceback" not in res.output, res.output
    res = CliRunner().invoke(app, ["watch", str(good), "--topic", "/a", "--topic", "/b", "--bag-out", str(good)])
    assert res.exit_code == 2 and "new bag folder" in res.output
    res = CliRunner().invoke(app, ["watch", str(REAL_RUN), "--topic", "/a"])
    assert res.exit_code == 2 and "not a bag" in res.output


def test_pairing_by_time():
    a = np.array([0, 40, 80, 120, 160]) * 10**6
    b = np.array([3, 43, 121, 163, 200]) * 10**6  # frame at 80 missing on b
    idx = pair_by_time([a, b], 20 * 10**6)
    assert idx.tolist() == [[0, 0], [1, 1], [3, 2], [4, 3]]


def test_read_bag_pairs_and_counts_dropped(tmp_path):
    rng = np.random.default_rng(1)
    v = rng.integers(0, 255, (5, 8, 10, 3), dtype=np.uint8)
    bag = write_bag(tmp_path / "b", [v, v[:4]], ["/l", "/r"], compressed=(True, False))
    got = read_bag(bag, ["/l", "/r"])
    assert len(got.frames) == 4 and got.dropped == {"/l": 1, "/r": 0}
    assert all(np.array_equal(got.frames[k][0], v[k]) and np.array_equal(got.frames[k][1], v[k]) for k in range(4))
    assert got.fps == pytest.approx(25.0)


def _drifting_bag(path: Path, right_slots):
    """40 frames on /left/image_raw (slots 0..39), and on /right/image_raw a frame in each of
    ``right_slots`` (3 ms later): a /left frame whose slot /right lacks finds no partner."""
    rng = np.random.default_rng(2)
    left = rng.integers(0, 255, (40, 24, 32, 3), dtype=np.uint8)
    right = left[list(right_slots)]
    return write_bag(path, [left, right], ["/left/image_raw", "/right/image_raw"], slots=[range(40), list(right_slots)])


DRIFT_TOPICS = ["--topic", "/left/image_raw", "--topic", "/right/image_raw"]


def test_a_bag_whose_topics_drift_apart_inside_is_refused_in_one_line(tmp_path):
    """12 of 40 /left frames have no /right partner in the middle of the bag: the 28 pairs left would
    skip half a second, so a model's lags would span other times. Refused, naming the bag."""
    bag = _drifting_bag(tmp_path / "drifting", [k for k in range(40) if not 14 <= k < 26])
    res = CliRunner().invoke(app, ["watch", str(bag), *DRIFT_TOPICS])
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output and "frames," not in res.output  # nothing streamed
    errors = [line for line in res.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and str(bag) in errors[0], res.output
    assert "12 of 40 frames of /left/image_raw found no partner within 20 ms" in errors[0]
    assert "520 ms between paired frames 13 and 14" in errors[0]
    with pytest.raises(InputError, match="missing inside the stream"):
        read_bag(bag, ["/left/image_raw", "/right/image_raw"])
    # bag convert reads it the same way: no recording with a hole in it
    res = CliRunner().invoke(app, ["bag", "convert", str(bag), "--out", str(tmp_path / "rec"), *DRIFT_TOPICS])
    assert res.exit_code == 2 and "missing inside the stream" in res.output and not (tmp_path / "rec").exists()


def test_a_frame_missing_from_every_topic_is_refused_too(tmp_path):
    """One topic (nothing to pair) whose sensor lost frame 20: the stream skips 80 ms there."""
    rng = np.random.default_rng(3)
    video = rng.integers(0, 255, (39, 24, 32, 3), dtype=np.uint8)
    bag = write_bag(tmp_path / "b", [video], ["/a"], slots=[[k for k in range(40) if k != 20]])
    with pytest.raises(InputError, match=r"a frame was not recorded.*80 ms between paired frames 19 and 20"):
        read_bag(bag, ["/a"])


def test_frames_left_unpaired_at_the_ends_only_are_warned_about(tmp_path, cache, one_thread, recwarn):
    """/right starts 6 frames late and stops 6 early: the 28 pairs are evenly spaced, so the bag
    streams, with a warning naming the bag, the topic and the count."""
    bag = _drifting_bag(tmp_path / "late_start", range(6, 34))
    res = CliRunner().invoke(app, ["watch", str(bag), *DRIFT_TOPICS, "--quiet"])
    assert res.exit_code == 0, res.output
    assert "28 frames" in res.output
    warned = [str(w.message) for w in recwarn.list if issubclass(w.category, UnpairedFramesWarning)]
    assert warned == [f"{bag}: 12 of 40 frames of /left/image_raw found no partner within 20 ms; left out"]
    got = read_bag(bag, ["/left/image_raw", "/right/image_raw"])
    assert len(got.frames) == 28 and got.dropped == {"/left/image_raw": 12, "/right/image_raw": 0}
    assert (np.diff(got.stamps, axis=0) == 40_000_000).all()


def test_the_unpaired_warning_is_one_line_on_stderr(tmp_path, cache):
    """Outside pytest's recorder the command line prints the warning as one "warning: ..." line on
    stderr (`bag convert` reads bags as `watch` does)."""
    import os
    import subprocess
    import sys

    bag = _drifting_bag(tmp_path / "late_start", range(6, 34))
    code = "import sys; from slipsense.cli import main; sys.argv = ['slipsense'] + sys.argv[1:]; main()"
    args = ["bag", "convert", str(bag), "--out", str(tmp_path / "rec"), *DRIFT_TOPICS]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=120, env=env)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.splitlines() == [
        f"warning: {bag}: 12 of 40 frames of /left/image_raw found no partner within 20 ms; left out"
    ]
    assert "28 frames x 2 sensors" in proc.stdout


def _consume(th: CaptureThread, seconds_per_frame: float):
    seen, last = [], 0
    while True:
        item = th.next(last, timeout=1.0)
        if item is None:
            return seen
        last = item[0]
        seen.append(int(item[2][0, 0, 0]))  # the frame's own index, written into its first pixel
        time.sleep(seconds_per_frame)


def _numbered(n):
    frames = np.zeros((n, 4, 4, 3), np.uint8)
    frames[:, 0, 0, 0] = np.arange(n) % 256
    return list(frames)


def test_capture_keeps_the_source_rate_with_a_30ms_consumer():
    th = CaptureThread(PacedReader(_numbered(75), fps=25.0).read, "paced")
    seen = _consume(th, 0.030)
    stats = th.stats()
    th.close()
    assert stats["fps"] == pytest.approx(25.0, rel=0.02)
    # the consumer keeps up: every frame (a busy machine may delay a few past the next, which are then
    # counted as dropped, as they should be; the slow consumer below loses more than 20)
    assert stats["delivered"] >= 0.95 * 75 and stats["dropped"] == 75 - len(seen) and seen == sorted(seen)


def test_capture_reports_drops_truthfully_with_a_slow_consumer():
    th = CaptureThread(PacedReader(_numbered(75), fps=25.0).read, "paced")
    seen = _consume(th, 0.065)
    stats = th.stats()
    th.close()
    assert stats["fps"] == pytest.approx(25.0, rel=0.02)  # the camera side keeps its rate
    missing = 75 - len(seen)
    assert missing > 20 and stats["dropped"] == missing and stats["grabbed"] == 75
    assert seen == sorted(seen) and stats["repeated"] == 0


def test_capture_counts_repeated_frames():
    frames = _numbered(6)
    frames = [frames[0], frames[0], frames[1], frames[2], frames[2], frames[2]]
    th = CaptureThread(PacedReader(frames, fps=200.0).read, "repeats")
    _consume(th, 0.0)
    assert th.stats()["repeated"] == 3
    th.close()


@needs_data
def test_watch_realtime_plays_at_the_sensor_rate(tmp_path, one_thread):
    res = CliRunner().invoke(app, ["watch", str(REAL_RUN), "--realtime", "--max-frames", "30", "--quiet"])
    assert res.exit_code == 0, res.output
    import re

    rates = re.findall(r"([\d.]+) frames/s captured, (\d+) of (\d+) pushed, (\d+) dropped", res.output)
    assert len(rates) == 2  # both fingers, each behind its own capture thread
    for fps, pushed, grabbed, dropped in rates:
        # frames read after the last push are neither pushed nor dropped: the stream was stopped
        assert float(fps) == pytest.approx(25.0, rel=0.05) and int(dropped) <= 2 and int(pushed) >= 30


def _add_bool_topic(bag: Path, topic: str, values):
    """A bag holding only a std_msgs/msg/Bool topic (a label topic without images)."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    Bool = ts.types["std_msgs/msg/Bool"]
    with Writer(bag, version=9) as w:
        c = w.add_connection(topic, Bool.__msgtype__, typestore=ts)
        for k, v in enumerate(values):
            w.write(c, 1_700_000_000_000_000_000 + k, ts.serialize_cdr(Bool(data=v), Bool.__msgtype__))
    return bag


def test_bag_convert_writes_the_recordings_layout(tmp_path, cache):
    from slipsense.recordings.folders import find_recordings
    from slipsense.recordings.video import read_video

    rng = np.random.default_rng(2)
    v = [rng.integers(0, 255, (8, 24, 32, 3), dtype=np.uint8) for _ in range(2)]
    bag = write_bag(tmp_path / "b", v, ["/l", "/r"])
    out = tmp_path / "rec" / "cup" / "exp_num_3"
    res = CliRunner().invoke(
        app, ["bag", "convert", str(bag), "--topic", "/l", "--topic", "/r", "--out", str(out), "--slipped"]
    )
    assert res.exit_code == 0, res.output
    assert "8 frames x 2 sensors" in res.output and (out / "slip.txt").is_file()
    for k in range(2):
        assert np.array_equal(read_video(out / f"camera_{k}.avi", expected_size=None), v[k])  # lossless
    recs = find_recordings(tmp_path / "rec")
    assert [(r.object, r.experiment, r.camera, r.slipped) for r in recs] == [
        ("cup", 3, "camera_0", True),
        ("cup", 3, "camera_1", True),
    ]

    labels = _add_bool_topic(tmp_path / "labels", "/slip", [False, True])
    res = CliRunner().invoke(app, ["bag", "convert", str(labels), "--topic", "/l", "--out", str(tmp_path / "x")])
    assert res.exit_code == 2 and "no topic /l" in res.output
    res = CliRunner().invoke(
        app, ["bag", "convert", str(bag), "--topic", "/l", "--label-topic", "/r", "--out", str(tmp_path / "y")]
    )
    assert res.exit_code == 2 and "not std_msgs/msg/Bool" in res.output


def test_a_folder_of_bags_is_a_recordings_folder(tmp_path, cache):
    """Bags in place of experiment folders: every command that takes recordings reads them."""
    from slipsense.recordings.folders import find_recordings
    from slipsense.recordings.video import read_video

    rng = np.random.default_rng(3)
    v = [rng.integers(0, 255, (6, 24, 32, 3), dtype=np.uint8) for _ in range(2)]
    write_bag(tmp_path / "bags" / "cup" / "exp_num_1", v, ["/a/image", "/b/image"])
    slipped = write_bag(tmp_path / "bags" / "cup" / "exp_num_2", v, ["/a/image", "/b/image"])
    (slipped / "slip.txt").write_text("")
    recs = find_recordings(tmp_path / "bags")
    assert [(r.experiment, r.camera, r.slipped) for r in recs] == [
        (1, "camera_0", False),
        (1, "camera_1", False),
        (2, "camera_0", True),
        (2, "camera_1", True),
    ]
    assert np.array_equal(read_video(recs[1].path, expected_size=None), v[1])
    again = find_recordings(tmp_path / "bags")  # converted once: the cached videos are reused
    assert [r.path for r in again] == [r.path for r in recs]


def test_decode_image_takes_ros_messages_of_every_read_encoding():
    """What the ROS 2 node hands in: rclpy messages hold ``data`` as an array of bytes."""
    import array
    from types import SimpleNamespace

    from slipsense.recordings.bags import COMPRESSED, IMAGE, decode_image
    from slipsense import ros_node  # imports without rclpy; main() needs the ROS extra

    assert callable(ros_node.main)
    rng = np.random.default_rng(4)
    bgr = rng.integers(0, 255, (5, 7, 3), dtype=np.uint8)
    padded = np.zeros((5, 24), np.uint8)  # a row step longer than width x channels
    padded[:, :21] = bgr[:, :, ::-1].reshape(5, 21)
    msgs = {
        "bgr8": (bgr.reshape(-1), 21),
        "rgb8": (padded.reshape(-1), 24),
        "mono8": (bgr[:, :, 0].reshape(-1), 7),
    }
    for encoding, (data, step) in msgs.items():
        msg = SimpleNamespace(height=5, width=7, step=step, encoding=encoding, data=array.array("B", data.tobytes()))
        got = decode_image(msg, IMAGE, "t")
        want = cv2.cvtColor(bgr[:, :, 0], cv2.COLOR_GRAY2BGR) if encoding == "mono8" else bgr
        assert np.array_equal(got, want), encoding
    png = SimpleNamespace(format="png", data=array.array("B", cv2.imencode(".png", bgr)[1].tobytes()))
    assert np.array_equal(decode_image(png, COMPRESSED, "t"), bgr)
    from slipsense.errors import InputError

    with pytest.raises(InputError, match="16UC1"):
        decode_image(SimpleNamespace(height=5, width=7, step=14, encoding="16UC1", data=b"\0" * 70), IMAGE, "t")
    with pytest.raises(InputError, match="holds 3 bytes"):
        decode_image(SimpleNamespace(height=5, width=7, step=21, encoding="bgr8", data=b"abc"), IMAGE, "t")


def test_bag_convert_a_folder_of_bags_with_a_labels_csv(tmp_path, cache):
    from slipsense.recordings.folders import find_recordings

    rng = np.random.default_rng(5)
    v = [rng.integers(0, 255, (4, 16, 20, 3), dtype=np.uint8) for _ in range(2)]
    for obj, name in (("cup", "grasp_a"), ("cup", "grasp_b"), ("pear", "morning")):
        write_bag(tmp_path / "bags" / obj / name, v, ["/l", "/r"])
    csv = tmp_path / "labels.csv"
    csv.write_text("bag,slipped\ncup/grasp_b,1\npear/morning,0\n")
    args = ["bag", "convert", str(tmp_path / "bags"), "--topic", "/l", "--topic", "/r", "--out", str(tmp_path / "rec")]
    res = CliRunner().invoke(app, [*args, "--labels", str(csv)])
    assert res.exit_code == 0, res.output
    recs = find_recordings(tmp_path / "rec")
    assert sorted({(r.object, r.experiment, r.slipped) for r in recs}) == [
        ("cup", 1, False),
        ("cup", 2, True),
        ("pear", 1, False),
    ]
    csv.write_text("bag,slipped\ncup/nowhere,1\n")
    res = CliRunner().invoke(app, [*args, "--labels", str(csv)])
    assert res.exit_code == 2 and "labels.csv" in res.output and "cup/nowhere" in res.output
    csv.write_text("bag,slipped\ncup/grasp_a,maybe\n")
    res = CliRunner().invoke(app, [*args, "--labels", str(csv)])
    assert res.exit_code == 2 and "line 2" in res.output


def test_watch_and_convert_refuse_bad_settings_in_one_line(tmp_path):
    rng = np.random.default_rng(6)
    v = [rng.integers(0, 255, (4, 16, 20, 3), dtype=np.uint8) for _ in range(2)]
    bag = write_bag(tmp_path / "b", v, ["/l", "/r"])
    topics = ["--topic", "/l", "--topic", "/r"]
    res = CliRunner().invoke(app, ["watch", str(bag), *topics, "--threshold", "1.5"])
    assert res.exit_code == 2 and "threshold" in res.output and "safetensors" not in res.output
    for bad in (["--fps", "0"], ["--fps", "nan"], ["--tolerance", "-1"]):
        res = CliRunner().invoke(app, ["bag", "convert", str(bag), *topics, "--out", str(tmp_path / "x"), *bad])
        assert res.exit_code == 2 and "Traceback" not in res.output and bad[0] in res.output, res.output
    res = CliRunner().invoke(app, ["watch", str(bag), *topics, "--tolerance", "nan"])
    assert res.exit_code == 2 and "--tolerance" in res.output


@needs_data
def test_a_topic_whose_header_stamps_go_backwards_is_refused_in_one_line(tmp_path):
    from slipsense.cli import app

    bag = write_bag(tmp_path / "back", _videos(6), ["/l", "/r"], slots=[[0, 1, 3, 2, 4, 5]] * 2, logged_in_order=True)
    res = CliRunner().invoke(app, ["watch", str(bag), "--topic", "/l", "--topic", "/r"])
    lines = [line for line in res.output.splitlines() if line.startswith("error: ")]
    assert res.exit_code == 2 and len(lines) == 1, res.output
    assert str(bag) in lines[0] and "/l: header stamps go backwards at message 3" in lines[0]
