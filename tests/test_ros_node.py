"""The ROS 2 node: its pairing, faults and account of every frame pair without ROS, then end to end
with rclpy from the package registry: a run's two videos published as image messages at 25 per
second, the node in its own process, its readings equal to ``slipsense watch --jsonl`` of the same run
frame for frame; and a node whose detector is too slow for a burst of frames, every pair published
judged or counted left out by cause."""

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
from slipsense.paths import gelsight_recordings
from slipsense.ros_node import ALARM_TOPIC, CAUSES, PROBABILITY_TOPIC, READING_TOPIC, STATUS_TOPIC, VELOCITY_TOPIC
from slipsense.ros_node import ReadingLoop, StampPairer, twists
from slipsense.streaming.detector import SlipDetector

RUN = gelsight_recordings() / "blue_mug" / "exp_num_9"  # it slips, and the shipped detector warns


def test_frames_are_paired_by_stamp_and_the_unpaired_are_counted():
    p = StampPairer(2, tolerance_ns=20_000_000)
    assert p.add(0, 0, "a0") == [] and p.add(1, 3_000_000, "b0") == [(0, ["a0", "b0"])]
    assert p.add(0, 40_000_000, "a1") == [] and p.add(0, 80_000_000, "a2") == []  # the right sensor is late
    assert p.add(1, 81_000_000, "b2") == [(80_000_000, ["a2", "b2"])] and p.unpaired == [1, 0]


def test_a_twist_per_finger_in_contact_in_si_units_and_none_for_a_sensor_in_px():
    slip = [{"translation": [12.5, -4.0], "omega": 0.35, "stick": 0.2}, None]
    assert twists({"slip": slip, "slip_velocity_unit": "mm/s"}) == [((0.0125, -0.004), 0.35), None]
    assert twists({"slip": slip, "slip_velocity_unit": "px/s"}) == []  # no linear velocity in m/s to give
    assert twists({"slip": None, "slip_velocity_unit": None}) == []  # a gel without markers


def _msg(stamp_ns, img, encoding="bgr8"):
    h, w = img.shape[:2]
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    header = SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=nsec))
    return SimpleNamespace(header=header, height=h, width=w, step=w * 3, encoding=encoding, data=img.tobytes())


def test_every_frame_pair_is_judged_or_left_out_by_cause_and_its_number_shows_the_gap():
    """Two topics, 13 pairs sent: one lost on the way (a gap in its publisher's sequence numbers), one
    whose partner was lost, one undecodable, one late, two skipped while the detector was behind."""
    det = SlipDetector.pretrained(sensors=2, backend="torch")
    published, logged = [], []
    loop = ReadingLoop(det, ["/l", "/r"], "sensor_msgs/msg/Image", lambda *a: published.append(a), logged.append)
    loop.inline = False  # read when read_pending is called, as the node's detector thread does
    img = np.random.default_rng(1).integers(0, 255, (240, 320, 3), dtype=np.uint8)
    seq = [0, 0]

    def send(k, stamp_ms, lost=False, encoding="bgr8"):
        seq[k] += 1
        if not lost:
            info = {"publication_sequence_number": seq[k], "publisher_gid": {"data": bytes([k] * 16)}}
            loop.on_message(k, _msg(stamp_ms * 1_000_000, img, encoding), info)

    for i in range(7):  # pairs 0-6
        send(0, 40 * i, lost=i == 3)
        send(1, 40 * i + 3, lost=i == 4, encoding="yuv422" if i == 5 else "bgr8")
        loop.read_pending()
    send(0, 80), send(1, 80)  # pair 7: a stamp already judged
    loop.read_pending()
    for i in range(7, 12):  # pairs 8-12 arrive while the detector is busy
        send(0, 40 * i), send(1, 40 * i + 3)
    loop.read_pending()  # 8 and 9 are more than max_lag (0.1 s) older than 12: skipped
    status = loop.status()
    assert status["left_out"] == {"lost": 1, "unpaired": 1, "undecodable": 1, "late": 1, "behind": 2}
    assert status["pairs"] == 13 and status["judged"] == 7 and status["pending"] == 0
    assert [r["frame"] for r, _, _ in published] == [0, 1, 2, 6, 10, 11, 12]
    assert [s for _, s, _ in published] == [40_000_000 * i for i in (0, 1, 2, 6, 9, 10, 11)]
    assert [r["stamp"] for r, _, _ in published] == pytest.approx([0.04 * i for i in (0, 1, 2, 6, 9, 10, 11)])
    assert [t["lost"] for t in status["topics"]] == [1, 1] and [t["unpaired"] for t in status["topics"]] == [1, 1]
    assert [t["received"] for t in status["topics"]] == [12, 12]
    assert "frame pairs judged 7 of 13, left out 6 (lost 1, unpaired 1, undecodable 1, late 1, behind 2)" in (
        loop.summary()
    )
    faults = [line for line in logged if "frames/s (the header stamps)" not in line]  # the rate: told once
    assert len(faults) == 2 and "yuv422" in faults[0] and "backwards" in faults[1]  # one line each
    det.close()


def test_the_sources_rate_is_read_from_the_stamps_sent_not_from_the_pairs_judged():
    """Pairs stamped 40 ms apart, every other one left out while the detector is behind: the log says
    25 frames/s, the source's rate (it said 12.5, the judged pairs' spacing)."""
    det = SlipDetector.pretrained(sensors=2, backend="torch")
    logged = []
    loop = ReadingLoop(det, ["/l", "/r"], "sensor_msgs/msg/Image", lambda *a: None, logged.append, max_lag_s=0.03)
    loop.inline = False
    img = np.random.default_rng(1).integers(0, 255, (240, 320, 3), dtype=np.uint8)
    for i in range(0, 24, 2):  # two pairs arrive between judgements: the older is left out, behind
        for j in (i, i + 1):
            loop.on_message(0, _msg(40_000_000 * j, img)), loop.on_message(1, _msg(40_000_000 * j, img))
        loop.read_pending()
    assert loop.status()["left_out"]["behind"] == 12
    (rate,) = [line for line in logged if "frames/s (the header stamps)" in line]
    assert "/l, /r: 25 frames/s (the header stamps)" in rate, rate
    det.close()


def test_a_silent_partner_topic_leaves_its_frames_counted_not_queued_for_ever():
    p = StampPairer(2, tolerance_ns=20_000_000, depth=3)
    for i in range(5):
        assert p.add(0, i * 40_000_000, f"a{i}") == []
    assert p.unpaired == [2, 0] and p.add(1, 80_000_000, "b2") == [(80_000_000, ["a2", "b2"])]  # the oldest went


def test_one_reading_type_on_the_topic_from_the_node_and_in_a_bag(tmp_path):
    """``watch --bag-out`` writes on /slipsense/reading what the node publishes there: a std_msgs/String
    holding the JSON record; bags written before as slipsense_msgs/msg/SlipReading are still read."""
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import Writer

    from slipsense.streaming.readings import (
        READING_MSGTYPE,
        SLIP_READING,
        BagWriter,
        _typestore,
        read_bag_readings,
    )

    records = [
        {"frame": 0, "stamp": 1700000000.0, "probability": None, "per_sensor": None, "alarm": False, "latency_ms": 1.5},
        {
            "frame": 2,
            "stamp": 1700000000.08,
            "probability": 0.9,
            "per_sensor": [0.9, 0.1],
            "alarm": True,
            "latency_ms": 1,
        },
    ]
    writer = BagWriter(tmp_path / "new")
    for r in records:
        writer.write(r)
    writer.close()
    with AnyReader([tmp_path / "new"]) as reader:
        assert [(c.topic, c.msgtype) for c in reader.connections] == [(READING_TOPIC, READING_MSGTYPE)]
        texts = [reader.deserialize(raw, c.msgtype).data for c, _, raw in reader.messages()]
    assert [json.loads(t) for t in texts] == records == read_bag_readings(tmp_path / "new")
    assert READING_MSGTYPE == "std_msgs/msg/String"  # the node's publisher: std_msgs.msg.String

    store = _typestore()  # a bag of an earlier version
    old, header, stamp = (
        store.types[SLIP_READING],
        store.types["std_msgs/msg/Header"],
        store.types["builtin_interfaces/msg/Time"],
    )
    with Writer(tmp_path / "old", version=9) as w:
        conn = w.add_connection(READING_TOPIC, SLIP_READING, typestore=store)
        msg = old(
            header=header(stamp=stamp(sec=1700000000, nanosec=80_000_000), frame_id="slipsense"),
            frame=2,
            probability=float("nan"),
            per_sensor=np.asarray([0.5], np.float32),
            alarm=True,
            latency_ms=1.0,
        )
        w.write(conn, 1, store.serialize_cdr(msg, SLIP_READING))
    (got,) = read_bag_readings(tmp_path / "old")
    assert got["frame"] == 2 and got["probability"] is None and got["alarm"] and got["per_sensor"] == [0.5]


def test_faults_are_logged_in_a_line_and_nothing_is_published_for_frames_not_judged():
    det = SlipDetector.pretrained(sensors=1, backend="torch")
    published, logged = [], []
    loop = ReadingLoop(det, ["/cam"], "sensor_msgs/msg/Image", lambda *a: published.append(a), logged.append)
    frames = np.random.default_rng(0).integers(0, 255, (4, 240, 320, 3), dtype=np.uint8)
    loop.on_message(0, _msg(0, frames[0]))
    loop.on_message(0, _msg(40_000_000, frames[1], encoding="yuv422"))  # an encoding it does not read
    loop.on_message(0, _msg(80_000_000, frames[2]))
    loop.on_message(0, _msg(60_000_000, frames[3]))  # a stamp that goes backwards
    assert len(published) == 2 and [r["frame"] for r, _, _ in published] == [0, 2]  # the gap: frame 1 left out
    assert len(logged) == 2 and "yuv422" in logged[0] and "backwards" in logged[1]
    loop.last_seen[0] -= 5.0
    loop.check_silence()
    assert "/cam: no message for" in logged[-1]
    status = loop.status()
    assert status["pairs"] == 4 and status["judged"] == 2 and status["pending"] == 0
    assert status["left_out"] == {**dict.fromkeys(CAUSES, 0), "undecodable": 1, "late": 1}
    det.close()


def _watch_reference(tmp_path) -> list[dict]:
    out = tmp_path / "watch.jsonl"
    cmd = [sys.executable, "-m", "slipsense.cli", "watch", str(RUN), "--backend", "torch", "--jsonl", str(out)]
    subprocess.run([*cmd, "--quiet"], check=True, capture_output=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    return [json.loads(line) for line in out.read_text().splitlines()]


def _ros_env() -> dict[str, str]:
    """The environment of a node under test, also set in this process (its player)."""
    env = {
        **os.environ,
        "ROS_DOMAIN_ID": str(random.randint(1, 100)),  # tests running side by side do not hear each other
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "OMP_NUM_THREADS": "1",
    }
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    return env


def _wait_for_node(rclpy, me, pubs, node) -> None:
    """Until the node in ``node`` (a process) subscribes to ``pubs`` and publishes readings."""
    deadline = time.monotonic() + 60
    while any(p.get_subscription_count() == 0 for p in pubs) or me.count_publishers(READING_TOPIC) == 0:
        assert node.poll() is None and time.monotonic() < deadline, node.stdout.read() if node.poll() else "no node"
        rclpy.spin_once(me, timeout_sec=0.1)
    time.sleep(0.5)  # the node's subscriptions matched ours both ways


def _stop(me, node) -> str:
    """Leave ROS (this test's node ``me``), end the slipsense node's process; its log."""
    import rclpy

    me.destroy_node()
    rclpy.shutdown()
    node.terminate()
    return node.communicate(timeout=30)[0]


@needs_data
def test_the_node_reads_what_watch_reads_frame_for_frame(tmp_path):
    rclpy = pytest.importorskip("rclpy", reason='the ROS extra is not installed (pip install "slipsense[ros]")')
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import Image
    from geometry_msgs.msg import TwistStamped
    from std_msgs.msg import Bool, Float32, String

    from slipsense.recordings.video import read_video

    reference = _watch_reference(tmp_path)
    videos = [read_video(RUN / f"{c}.avi") for c in ("camera_0", "camera_2")]
    env = _ros_env()
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
        readings, alarms, probabilities, velocities = [], [], [], []
        me.create_subscription(String, READING_TOPIC, lambda m: readings.append(json.loads(m.data)), 500)
        me.create_subscription(Bool, ALARM_TOPIC, lambda m: alarms.append(m.data), 500)
        me.create_subscription(Float32, PROBABILITY_TOPIC, lambda m: probabilities.append(m.data), 500)
        me.create_subscription(TwistStamped, VELOCITY_TOPIC, lambda m: velocities.append(m), 1000)
        pubs = [me.create_publisher(Image, t, QoSProfile(depth=50)) for t in ("/left/image_raw", "/right/image_raw")]
        _wait_for_node(rclpy, me, pubs, node)
        published_types = dict(me.get_topic_names_and_types())[VELOCITY_TOPIC]
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
        log = _stop(me, node)
    assert len(readings) == len(reference), log
    assert [r["frame"] for r in readings] == [r["frame"] for r in reference]
    assert [r["alarm"] for r in readings] == [r["alarm"] for r in reference] and any(r["alarm"] for r in reference)
    for got, want in zip(readings, reference):
        assert (got["probability"] is None) == (want["probability"] is None)
        if want["probability"] is not None:
            assert got["probability"] == pytest.approx(want["probability"], abs=1e-6)
    # the same reading in standard types: the alarm and the probability of every judged pair, and each
    # finger's slip as a twist where it touches (watch's translation in mm/s as m/s, its omega in rad/s),
    # stamped with its frame
    assert alarms == [r["alarm"] for r in reference]
    want_p = [np.nan if r["probability"] is None else r["probability"] for r in reference]
    np.testing.assert_allclose(probabilities, want_p, atol=1e-6)
    assert published_types == ["geometry_msgs/msg/TwistStamped"]
    assert all(r["slip_velocity_unit"] == "mm/s" and len(r["slip"]) == 2 for r in reference)
    want_v = [(k, r["frame"], s) for r in reference for k, s in enumerate(r["slip"]) if s is not None]
    got_v = [(int(m.header.frame_id[-1]), m.header.stamp.sec, m.header.stamp.nanosec, m.twist) for m in velocities]
    assert len(want_v) > 50 and len(got_v) == len(want_v)
    for (k, frame, s), (gk, sec, nsec, twist) in zip(want_v, got_v):
        assert gk == k and (sec * 10**9 + nsec - 1_700_000_000 * 10**9) == frame * 40_000_000
        (vx, vy), omega = s["translation"], s["omega"]
        linear, angular = twist.linear, twist.angular
        assert (linear.x, linear.y, linear.z) == pytest.approx((vx * 1e-3, vy * 1e-3, 0.0), abs=1e-9)
        assert (angular.x, angular.y, angular.z) == pytest.approx((0.0, 0.0, omega), abs=1e-9)
    assert "25 frames/s (the header stamps)" in log and "alarm at" in log and "left out:" not in log, log
    assert "rosout" not in log, log  # the node stops cleanly on SIGTERM
    n = len(reference)
    assert f"frame pairs judged {n} of {n}, left out 0 (lost 0, unpaired 0, undecodable 0, late 0, behind 0)" in log
    assert f"/left/image_raw {n} (0 lost, 0 unpaired); /right/image_raw {n} (0 lost, 0 unpaired)" in log, log


#: the node with a detector too slow for the frame rate: every push sleeps first
SLOW_NODE = """
import sys, time
from slipsense.streaming.detector import SlipDetector
push = SlipDetector.push
def slow(self, *frames, **kwargs):
    time.sleep({sleep})
    return push(self, *frames, **kwargs)
SlipDetector.push = slow
from slipsense.ros_node import main
main(sys.argv)
"""


def test_a_slow_detector_given_a_burst_judges_or_counts_every_frame_pair():
    """A detector taking over 60 ms a pair, frame pairs arriving at 100 a second (stamped 40 ms apart)
    on a busy machine: every pair published is judged (a reading) or counted left out by cause, and
    the readings' frame numbers are the pairs' as published, so their gaps are the pairs left out."""
    rclpy = pytest.importorskip("rclpy", reason='the ROS extra is not installed (pip install "slipsense[ros]")')
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from sensor_msgs.msg import Image
    from std_msgs.msg import String

    env = _ros_env()
    topics = ["/left/image_raw", "/right/image_raw"]
    args = ["--ros-args", "-p", f"topics:={topics}", "-p", "backend:=torch", "-p", "threads:=1"]
    node = subprocess.Popen(
        [sys.executable, "-c", SLOW_NODE.format(sleep=0.06), *args],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    n, base, period = 150, 1_700_000_000 * 10**9, 40_000_000
    images = np.random.default_rng(2).integers(0, 255, (8, 240, 320, 3), dtype=np.uint8)
    rclpy.init()
    me = rclpy.create_node("slipsense_test_burst")
    readings, statuses = [], []
    try:
        me.create_subscription(String, READING_TOPIC, lambda m: readings.append(json.loads(m.data)), 1000)
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        me.create_subscription(String, STATUS_TOPIC, lambda m: statuses.append(json.loads(m.data)), latched)
        pubs = [me.create_publisher(Image, t, QoSProfile(depth=50)) for t in topics]
        _wait_for_node(rclpy, me, pubs, node)

        def publish(k):
            sec, nsec = divmod(base + k * period, 1_000_000_000)
            for j, pub in enumerate(pubs):
                msg = Image(height=240, width=320, encoding="bgr8", is_bigendian=0, step=960)
                msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nsec
                msg.data = images[(k + j) % len(images)].tobytes()
                pub.publish(msg)

        start = time.monotonic()
        for k in range(n):  # 100 pairs a second, the detector judging fewer than 17
            publish(k)
            while time.monotonic() < start + (k + 1) * 0.01:
                rclpy.spin_once(me, timeout_sec=0.002)
        pause = time.monotonic() + 1.5
        while time.monotonic() < pause:
            rclpy.spin_once(me, timeout_sec=0.05)
        publish(n)  # a last pair, after the burst: a pair lost at the end of the burst shows as its gap
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not (
            statuses
            and statuses[-1]["pairs"] == n + 1
            and statuses[-1]["pending"] == 0
            and len(readings) == statuses[-1]["judged"]
        ):
            rclpy.spin_once(me, timeout_sec=0.05)
    finally:
        log = _stop(me, node)
    assert statuses, log
    status = statuses[-1]
    left_out = sum(status["left_out"].values())
    numbers = f"{n + 1} pairs published, {len(readings)} readings, left out {status['left_out']}; node log:\n{log}"
    assert status["pairs"] == n + 1 and status["pending"] == 0, numbers
    assert len(readings) == status["judged"] and len(readings) + left_out == n + 1, numbers
    frames = [r["frame"] for r in readings]
    assert frames == sorted(set(frames)) and frames[-1] == n, numbers  # the gaps: n + 1 - len(readings) pairs
    assert all(round(r["stamp"] * 1e9) == pytest.approx(base + r["frame"] * period, abs=1_000) for r in readings)
    assert status["left_out"]["behind"] > 0 and len(readings) < n // 2, numbers  # the detector was behind
    judged, pairs = status["judged"], status["pairs"]
    assert "status: frame pairs judged" in log and f"frame pairs judged {judged} of {pairs}, left out {left_out}" in log
    print(numbers.split("; node log")[0])
