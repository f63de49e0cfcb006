"""A ROS 2 node: a slip detector on one or two image topics, its readings and alarms out.

    slipsense ros --topic /left/image_raw --topic /right/image_raw
    python -m slipsense.ros_node --ros-args -p topics:="['/left/image_raw', '/right/image_raw']"

Install with ``pip install "slipsense[ros]"`` (rclpy and the messages from the package registry; no
ROS installation needed). Parameters: ``topics`` (one image topic per sensor, ``sensor_msgs/Image``
or, with ``compressed:=true``, ``CompressedImage``), ``checkpoint`` (default: the shipped detector
for that many sensors), ``backend`` (auto, torch or onnx), ``tolerance`` (seconds between the stamps
of a pair; default half a frame period of the detector's sensor). Subscriptions use the sensor-data
QoS a camera driver publishes with.

Out: ``/slipsense/reading`` (``std_msgs/String``, one JSON reading per judged frame pair, the record
of ``slipsense watch --jsonl``) and ``/slipsense/alarm`` (``std_msgs/Header``, stamped with the frame's
header stamp, published for every judged frame while the alarm is on). The detector runs on its own
clock from the header stamps (:meth:`~slipsense.streaming.detector.SlipDetector.push` with stamps),
so a camera at another rate gives it what it was trained on.

Faults are logged in one line each and the node keeps running: a message that cannot be decoded
(wrong encoding or size) or whose stamp goes backwards is left out and no reading is published for
it; a topic silent for a second, a sensor that starts late and unpaired messages are reported.
"""

from __future__ import annotations

import collections
import json
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from slipsense.checkpoint import read_info
from slipsense.errors import SlipsenseError
from slipsense.evaluation.pergrasp import promise_text
from slipsense.recordings.bags import COMPRESSED, IMAGE, decode_image
from slipsense.resources import default_model_name, shipped_model
from slipsense.streaming.detector import SlipDetector
from slipsense.streaming.readings import reading_record

READING_TOPIC, ALARM_TOPIC = "/slipsense/reading", "/slipsense/alarm"
#: A topic without a message for this long (seconds) is reported as stopped.
SILENT_S = 1.0


@dataclass
class StampPairer:
    """Frames of several topics paired by header stamp (integer nanoseconds), in stamp order.

    ``add(k, stamp, frame)`` queues topic ``k``'s frame and returns the pairs now complete: the oldest
    frame of every topic, when their stamps lie within ``tolerance_ns`` of each other; an older frame
    that can no longer find partners is dropped and counted in ``unpaired[k]``."""

    topics: int
    tolerance_ns: int
    unpaired: list[int] = field(default_factory=list)

    def __post_init__(self):
        self._queues: list[collections.deque] = [collections.deque(maxlen=64) for _ in range(self.topics)]
        self.unpaired = [0] * self.topics

    def add(self, k: int, stamp: int, frame: Any) -> list[tuple[int, list[Any]]]:
        self._queues[k].append((stamp, frame))
        pairs = []
        while all(self._queues):
            heads = [q[0][0] for q in self._queues]
            if max(heads) - min(heads) <= self.tolerance_ns:
                frames = [q.popleft() for q in self._queues]
                pairs.append((frames[0][0], [f for _, f in frames]))
                continue
            oldest = int(np.argmin(heads))  # it can pair with nothing that is still to come
            self._queues[oldest].popleft()
            self.unpaired[oldest] += 1
        return pairs


class ReadingLoop:
    """What the node does with paired frames, apart from ROS: decode, push on the detector's clock,
    and hand each judged frame's record to ``publish``; faults go to ``log`` in one line each."""

    def __init__(self, detector: SlipDetector, topics: Sequence[str], msgtype: str, publish: Callable, log: Callable):
        self.detector, self.topics, self.msgtype = detector, list(topics), msgtype
        self.publish, self.log = publish, log
        tolerance_ns = int(round(0.5e9 / detector.sensor.fps))
        self.pairer = StampPairer(len(self.topics), tolerance_ns)
        self.first_ns: int | None = None
        self.last_seen = [0.0] * len(self.topics)
        self.silent = [False] * len(self.topics)
        self.judged = self.refused = 0
        self.rate_told = False
        self._stamps: list[int] = []

    def on_message(self, k: int, msg: Any) -> None:
        self.last_seen[k] = time.monotonic()
        if self.silent[k]:
            self.log(f"{self.topics[k]}: messages again")
            self.silent[k] = False
        stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
        try:
            frame = decode_image(msg, self.msgtype, self.topics[k])
        except SlipsenseError as exc:
            self.refused += 1
            self.log(f"left out: {exc}")
            return
        for pair_stamp, frames in self.pairer.add(k, stamp, frame):
            self.judge(pair_stamp, frames)

    def judge(self, stamp_ns: int, frames: list[np.ndarray]) -> None:
        if self.first_ns is None:
            self.first_ns = stamp_ns
        t = (stamp_ns - self.first_ns) * 1e-9  # seconds since the first pair: exact, whatever the epoch
        t0 = time.perf_counter()
        try:
            reading = self.detector.push(*frames, stamp=t)
        except SlipsenseError as exc:  # stamps that go backwards, a frame of another size
            self.refused += 1
            self.log(f"left out: {', '.join(self.topics)} at {stamp_ns * 1e-9:.6f} s: {exc}")
            return
        latency_ms = (time.perf_counter() - t0) * 1e3
        self.judged += 1
        self._tell_rate(stamp_ns)
        self.publish(reading_record(reading, stamp_ns * 1e-9, latency_ms), stamp_ns, reading.alarm)

    def _tell_rate(self, stamp_ns: int) -> None:
        if self.rate_told:
            return
        self._stamps.append(stamp_ns)
        if len(self._stamps) == 10:
            fps = 1e9 / float(np.median(np.diff(self._stamps)))
            self.log(
                f"{', '.join(self.topics)}: {fps:.3g} frames/s (the header stamps); "
                f"the detector runs at {self.detector.sensor.fps:g} frames/s"
            )
            self.rate_told = True

    def check_silence(self) -> None:
        now = time.monotonic()
        for k, seen in enumerate(self.last_seen):
            if not self.silent[k] and now - seen > SILENT_S:
                self.silent[k] = True
                what = "no message yet" if seen == 0.0 else f"no message for {now - seen:.1f} s"
                self.log(f"{self.topics[k]}: {what}")

    def summary(self) -> str:
        unpaired = ", ".join(f"{t} {n}" for t, n in zip(self.topics, self.pairer.unpaired))
        return f"{self.judged} frame pairs judged, {self.refused} left out, unpaired messages: {unpaired}"


def main(argv: Sequence[str] | None = None, overrides: dict[str, Any] | None = None) -> None:
    """Run the node until it is stopped (Ctrl-C, SIGTERM); ``overrides``: parameters set in code
    (what ``slipsense ros`` passes), over the ``--ros-args`` ones."""
    import rclpy  # the ROS extra: imported where the node runs, so the library imports without it
    from rclpy.executors import ExternalShutdownException
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CompressedImage, Image
    from std_msgs.msg import Header, String

    rclpy.init(args=list(argv) if argv is not None else sys.argv)
    params = [Parameter(k, value=v) for k, v in (overrides or {}).items()]
    node = Node("slipsense", parameter_overrides=params, enable_rosout=False)  # its log is its own output
    log = node.get_logger().info
    topics = list(node.declare_parameter("topics", ["/left/image_raw", "/right/image_raw"]).value)
    compressed = bool(node.declare_parameter("compressed", False).value)
    checkpoint = str(node.declare_parameter("checkpoint", "").value)
    backend = str(node.declare_parameter("backend", "auto").value)
    kind, msgtype = (CompressedImage, COMPRESSED) if compressed else (Image, IMAGE)
    if checkpoint:
        detector = SlipDetector.from_checkpoint(checkpoint, sensors=len(topics), backend=backend)
    else:
        detector = SlipDetector.pretrained(sensors=len(topics), backend=backend)
    log(f"{detector.model_name} on {detector.backend}, {len(topics)} sensor(s), alarm at {detector.threshold:g}")
    log(promise_text(read_info(checkpoint or shipped_model(default_model_name(len(topics)))).get("operating_point")))
    readings = node.create_publisher(String, READING_TOPIC, 10)
    alarms = node.create_publisher(Header, ALARM_TOPIC, 10)

    def publish(record: dict, stamp_ns: int, alarm: bool) -> None:
        readings.publish(String(data=json.dumps(record)))
        if alarm:
            header = Header(frame_id="slip")
            header.stamp.sec, header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
            alarms.publish(header)

    loop = ReadingLoop(detector, topics, msgtype, publish, log)
    for k, topic in enumerate(topics):
        node.create_subscription(kind, topic, lambda msg, k=k: loop.on_message(k, msg), qos_profile_sensor_data)
    node.create_timer(0.5, loop.check_silence)
    log(f"listening on {', '.join(topics)}; readings on {READING_TOPIC}, alarms on {ALARM_TOPIC}")
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        log(loop.summary())
        detector.close()
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


if __name__ == "__main__":
    main()
