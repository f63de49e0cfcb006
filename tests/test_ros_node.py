"""The ROS 2 node: its pairing and faults without ROS, then end to end with rclpy from the package
registry: a run's two videos published as image messages at 25 per second, the node in its own
process, its readings equal to ``slipsense watch --jsonl`` of the same run frame for frame."""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys
import time
from types import SimpleNamespace

import numpy as np
import pytest

from conftest import needs_data
from slipsense.config import gelsight_recordings
from slipsense.ros_node import ALARM_TOPIC, READING_TOPIC, ReadingLoop, StampPairer
from slipsense.streaming.detector import SlipDetector

RUN = gelsight_recordings() / "blue_mug" / "exp_num_9"  # it slips, and the shipped detector warns


def test_frames_are_paired_by_stamp_and_the_unpaired_are_counted():
    p = StampPairer(2, tolerance_ns=20_000_000)
    assert p.add(0, 0, "a0") == [] and p.add(1, 3_000_000, "b0") == [(0, ["a0", "b0"])]
    assert p.add(0, 40_000_000, "a1") == [] and p.add(0, 80_000_000, "a2") == []  # the right sensor is late
    assert p.add(1, 81_000_000, "b2") == [(80_000_000, ["a2", "b2"])] and p.unpaired == [1, 0]


def _msg(stamp_ns, img, encoding="bgr8"):
    h, w = img.shape[:2]
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    header = SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=nsec))
    return SimpleNamespace(header=header, height=h, width=w, step=w * 3, encoding=encoding, data=img.tobytes())


def test_faults_are_logged_in_a_line_and_nothing_is_published_for_frames_not_judged():
    det = SlipDetector.pretrained(sensors=1, backend="torch")
    published, logged = [], []
    loop = ReadingLoop(det, ["/cam"], "sensor_msgs/msg/Image", lambda *a: published.append(a), logged.append)
    frames = np.random.default_rng(0).integers(0, 255, (4, 240, 320, 3), dtype=np.uint8)
    loop.on_message(0, _msg(0, frames[0]))
    loop.on_message(0, _msg(40_000_000, frames[1], encoding="yuv422"))  # an encoding it does not read
    loop.on_message(0, _msg(80_000_000, frames[2]))
    loop.on_message(0, _msg(60_000_000, frames[3]))  # a stamp that goes backwards
    assert len(published) == 2 and [r["frame"] for r, _, _ in published] == [0, 1]
    assert len(logged) == 2 and "yuv422" in logged[0] and "backwards" in logged[1]
    loop.last_seen[0] -= 5.0
    loop.check_silence()
    assert "/cam: no message for" in logged[-1] and loop.refused == 2
    det.close()


def _watch_reference(tmp_path) -> list[dict]:
    out = tmp_path / "watch.jsonl"
    cmd = [sys.executable, "-m", "slipsense.cli", "watch", str(RUN), "--backend", "torch", "--jsonl", str(out)]
    subprocess.run([*cmd, "--quiet"], check=True, capture_output=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    return [json.loads(line) for line in out.read_text().splitlines()]


@needs_data
def test_the_node_reads_what_watch_reads_frame_for_frame(tmp_path):
    rclpy = pytest.importorskip("rclpy", reason='the ROS extra is not installed (pip install "slipsense[ros]")')
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import Image
    from std_msgs.msg import Header, String

    from slipsense.recordings.video import read_video

    reference = _watch_reference(tmp_path)
    videos = [read_video(RUN / f"{c}.avi") for c in ("camera_0", "camera_2")]
    env = {
        **os.environ,
        "ROS_DOMAIN_ID": str(random.randint(1, 100)),  # tests running side by side do not hear each other
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "OMP_NUM_THREADS": "1",
    }
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    args = ["--ros-args", "-p", "topics:=['/left/image_raw', '/right/image_raw']", "-p", "backend:=torch"]
    node = subprocess.Popen(
        [sys.executable, "-m", "slipsense.ros_node", *args],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    rclpy.init()
    me = rclpy.create_node("slipsense_test_player")
    try:
        readings, alarms = [], []
        me.create_subscription(String, READING_TOPIC, lambda m: readings.append(json.loads(m.data)), 500)
        me.create_subscription(Header, ALARM_TOPIC, lambda m: alarms.append(m), 500)
        pubs = [me.create_publisher(Image, t, QoSProfile(depth=50)) for t in ("/left/image_raw", "/right/image_raw")]
        deadline = time.monotonic() + 60
        while any(p.get_subscription_count() == 0 for p in pubs) or me.count_publishers(READING_TOPIC) == 0:
            assert node.poll() is None and time.monotonic() < deadline, node.stdout.read() if node.poll() else "no node"
            rclpy.spin_once(me, timeout_sec=0.1)
        time.sleep(0.5)  # the node's subscriptions matched ours both ways
        base, start = 1_700_000_000 * 10**9, time.monotonic()
        for k in range(len(videos[0])):
            sec, nsec = divmod(base + k * 40_000_000, 1_000_000_000)
            for pub, video in zip(pubs, videos):
                msg = Image(height=240, width=320, encoding="bgr8", is_bigendian=0, step=960)
                msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id = sec, nsec, "gel"
                msg.data = video[k].tobytes()
                pub.publish(msg)
            # 25 per second; on a loaded machine no faster than the node judges, so that its sensor-data
            # subscription (best effort, a short queue, as a camera driver's) never has to drop a frame
            late = time.monotonic() + 10
            while time.monotonic() < start + (k + 1) * 0.04 or (len(readings) <= k and time.monotonic() < late):
                rclpy.spin_once(me, timeout_sec=0.005)
        deadline = time.monotonic() + 15
        while len(readings) < len(reference) and time.monotonic() < deadline:
            rclpy.spin_once(me, timeout_sec=0.05)
    finally:
        me.destroy_node()
        rclpy.shutdown()
        node.terminate()
        log = node.communicate(timeout=30)[0]
    assert len(readings) == len(reference), log
    assert [r["frame"] for r in readings] == [r["frame"] for r in reference]
    assert [r["alarm"] for r in readings] == [r["alarm"] for r in reference] and any(r["alarm"] for r in reference)
    for got, want in zip(readings, reference):
        assert (got["probability"] is None) == (want["probability"] is None)
        if want["probability"] is not None:
            assert got["probability"] == pytest.approx(want["probability"], abs=1e-6)
    assert len(alarms) == sum(r["alarm"] for r in reference)
    assert "25 frames/s (the header stamps)" in log and "alarm at" in log and "left out:" not in log, log
    assert "rosout" not in log, log  # the node stops cleanly on SIGTERM
    assert "frame pairs judged, 0 left out, unpaired messages: /left/image_raw 0, /right/image_raw 0" in log, log
