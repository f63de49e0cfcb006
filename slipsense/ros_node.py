"""A ROS 2 node: a slip detector on one or two image topics; its readings, its alarms and an account of
every frame pair out (docs/streaming.md: the topics, their QoS, the parameters and the account).

    slipsense ros --topic /left/image_raw --topic /right/image_raw --threads 1
    python -m slipsense.ros_node --ros-args -p topics:="['/left/image_raw', '/right/image_raw']" -p threads:=1

Install with ``pip install "slipsense[ros]"`` (no ROS installation needed). Parameters: ``topics`` (one
``sensor_msgs/Image`` topic per sensor, ``CompressedImage`` with ``compressed:=true``), ``checkpoint``
(default: the shipped detector for that many sensors), ``backend``, ``threshold`` and ``hold``
(negative, the default: the checkpoint's operating point), ``tolerance`` (seconds between the stamps
of a pair; 0: half a frame period of the detector's sensor), ``max_lag`` (seconds: a pair this much
older than the newest one waiting is skipped), ``threads`` (0: torch's) and ``gel_motion`` (false: no
slip followed, readings carry null, the push about a millisecond a finger faster).

In: each image topic best effort, volatile, keep last :data:`QUEUE_DEPTH`. Out, reliable:
``/slipsense/reading`` (a JSON reading per judged frame pair, the record of ``slipsense watch
--jsonl``); the same reading in standard types for a controller that parses no JSON, every judged
frame pair: ``/slipsense/alarm`` (``std_msgs/Bool``), ``/slipsense/probability`` (``std_msgs/Float32``,
NaN while the detector has no answer) and ``/slipsense/slip_velocity`` (``geometry_msgs/TwistStamped``
per finger: ``twist.linear.x/y`` the reading's ``translation`` in m/s, ``twist.angular.z`` its ``omega``
in rad/s, the rest 0; ``frame_id`` ``finger_<k>`` for the k-th topic, the frame's stamp; only while that
finger touches, and only for a sensor that states its pixel size: a twist of a px/s sensor would have
no linear part in m/s, and a zero or NaN there would read as a velocity, so its omega is on
``/slipsense/reading`` alone, as every sensor's stick share and speed are); and ``/slipsense/status``
(transient local, every second: every frame pair judged or left out, by cause: :meth:`ReadingLoop.status`).
The detector runs on its own clock from the header stamps. Faults are logged in one line each and the
node keeps running.
"""

from __future__ import annotations

import collections
import json
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Sequence

import numpy as np

from slipsense.checkpoint import read_info
from slipsense.errors import ConfigError, SlipsenseError
from slipsense.measures.promise import promise_text
from slipsense.recordings.bags import COMPRESSED, IMAGE, decode_image
from slipsense.resources import default_model_name, shipped_model
from slipsense.streaming.detector import SlipDetector
from slipsense.streaming.readings import reading_record

READING_TOPIC, ALARM_TOPIC, STATUS_TOPIC = "/slipsense/reading", "/slipsense/alarm", "/slipsense/status"
PROBABILITY_TOPIC, VELOCITY_TOPIC = "/slipsense/probability", "/slipsense/slip_velocity"
#: Why a frame pair got no reading, in the order the status lists them: the first topic's message never
#: arrived (lost), no message of every other topic within the tolerance (unpaired), an image of the wrong
#: encoding or size (undecodable), its stamp not after the last judged pair's (late), or a pair more than
#: ``max_lag`` newer was waiting while the detector was busy (behind).
CAUSES = ("lost", "unpaired", "undecodable", "late", "behind")
#: A topic without a message for this long (seconds) is reported as stopped.
SILENT_S = 1.0
#: Seconds between status messages (and at most between status log lines).
STATUS_S = 1.0
#: Default ``max_lag`` (seconds).
MAX_LAG_S = 0.1
#: Messages each image subscription holds while the node is busy; older ones are dropped (and counted).
QUEUE_DEPTH = 10
#: Frames of one topic kept waiting for partners before the oldest is given up (counted as unpaired).
PAIRER_DEPTH = 64


@dataclass
class StampPairer:
    """Frames of several topics paired by header stamp (integer nanoseconds), in stamp order.

    ``add(k, stamp, frame)`` queues topic ``k``'s frame and returns the pairs now complete: the oldest
    frame of every topic, when their stamps lie within ``tolerance_ns`` of each other; an older frame
    that can no longer find partners (or one pushed out of a queue of ``depth`` waiting frames) is
    dropped and counted in ``unpaired[k]``."""

    topics: int
    tolerance_ns: int
    unpaired: list[int] = field(default_factory=list)
    depth: int = PAIRER_DEPTH

    def __post_init__(self):
        self._queues: list[collections.deque] = [collections.deque() for _ in range(self.topics)]
        self.unpaired = [0] * self.topics

    def _drop(self, k: int) -> None:
        self._queues[k].popleft()
        self.unpaired[k] += 1

    def add(self, k: int, stamp: int, frame: Any) -> list[tuple[int, list[Any]]]:
        self._queues[k].append((stamp, frame))
        if len(self._queues[k]) > self.depth:  # a partner topic is silent: give the oldest up, counted
            self._drop(k)
        pairs = []
        while all(self._queues):
            heads = [q[0][0] for q in self._queues]
            if max(heads) - min(heads) <= self.tolerance_ns:
                frames = [q.popleft() for q in self._queues]
                pairs.append((frames[0][0], [f for _, f in frames]))
                continue
            self._drop(int(np.argmin(heads)))  # it can pair with nothing that is still to come
        return pairs


class SequenceGaps:
    """Messages of one topic that never reached the node: the gaps in each publisher's publication
    sequence numbers (``MessageInfo`` of rclpy; a middleware that gives none counts nothing)."""

    def __init__(self):
        self._last: dict[Any, int] = {}

    def missed(self, info: Optional[dict]) -> int:
        """Messages of this message's publisher sent between the previous one heard and this one."""
        seq = (info or {}).get("publication_sequence_number")
        if not isinstance(seq, int) or seq <= 0 or seq >= 2**63:  # unsupported: none, 0 or the max
            return 0
        gid = info.get("publisher_gid")
        key = bytes(gid["data"]) if isinstance(gid, dict) and "data" in gid else repr(gid)
        last = self._last.get(key)
        self._last[key] = seq if last is None else max(last, seq)
        return 0 if last is None or seq <= last else seq - last - 1


def stamp_ns(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


class ReadingLoop:
    """What the node does with image messages, apart from ROS: count them, pair them by stamp, decode
    each pair, push it on the detector's clock and hand the judged frame's record to
    ``publish(record, stamp_ns, alarm)``; faults go to ``log`` in one line each, and every pair that
    gets no reading is counted by cause (:meth:`status`).

    ``on_message`` (the subscriptions' callback) only counts and pairs. With ``inline`` the pairs are
    judged there and then; else by :meth:`read_pending`, which :meth:`start` runs on a thread of its
    own, so the subscriptions' queues are emptied while the detector works."""

    def __init__(
        self,
        detector: SlipDetector,
        topics: Sequence[str],
        msgtype: str,
        publish: Callable,
        log: Callable,
        tolerance_s: float | None = None,
        max_lag_s: float = MAX_LAG_S,
        inline: bool = True,
    ):
        self.detector, self.topics, self.msgtype = detector, list(topics), msgtype
        self.publish, self.log, self.inline = publish, log, inline
        tolerance = 0.5 / detector.sensor.fps if tolerance_s is None else float(tolerance_s)
        self.max_lag_ns = int(round(max_lag_s * 1e9))
        self.pairer = StampPairer(len(self.topics), int(round(tolerance * 1e9)))  # its unpaired[0]: left out
        self.gaps = [SequenceGaps() for _ in self.topics]
        self.received = [0] * len(self.topics)  # messages per topic
        self.lost = [0] * len(self.topics)  # messages per topic that never arrived
        self.pairs = 0  # pair indices given out: messages of the first topic, arrived or lost
        self.judged = 0
        self.left_out = dict.fromkeys(CAUSES, 0)  # "unpaired" counted by the pairer
        self.first_ns: int | None = None
        self.last_judged_ns: int | None = None
        self.last_seen = [0.0] * len(self.topics)
        self.silent = [False] * len(self.topics)
        self.rate_told = False
        self.error: BaseException | None = None
        self._stamps: list[int] = []
        self._ready: collections.deque = collections.deque()  # (index, stamp_ns, messages) to judge
        self._cond = threading.Condition()  # guards the counts and _ready
        self._stopping = False
        self._thread: threading.Thread | None = None

    def on_message(self, k: int, msg: Any, info: Optional[dict] = None) -> None:
        self.last_seen[k] = time.monotonic()
        if self.silent[k]:
            self.log(f"{self.topics[k]}: messages again")
            self.silent[k] = False
        stamp = stamp_ns(msg)
        with self._cond:
            missed = self.gaps[k].missed(info)
            self.received[k] += 1
            self.lost[k] += missed
            index = None
            if k == 0:  # the first topic numbers the pairs, the lost ones included
                if len(self._stamps) < 10:  # the source's rate: stamps as sent, not as judged (some are left out)
                    self._stamps.append(stamp)
                self.left_out["lost"] += missed
                index = self.pairs + missed
                self.pairs = index + 1
            for pair_stamp, items in self.pairer.add(k, stamp, (index, msg)):
                self._ready.append((items[0][0], pair_stamp, [m for _, m in items]))
            while len(self._ready) > 1 and self._ready[-1][1] - self._ready[0][1] > self.max_lag_ns:
                self._ready.popleft()  # stale already: the queue holds no more than max_lag of frames
                self.left_out["behind"] += 1
            if self._ready:
                self._cond.notify()
        if self.inline:
            self.read_pending()

    def read_pending(self) -> None:
        """Judge the pairs waiting, oldest first; one more than ``max_lag`` older than the newest
        waiting is left out as ``behind``."""
        while True:
            with self._cond:
                if not self._ready or self._stopping:
                    return
                index, stamp, msgs = self._ready.popleft()
                if self._ready and self._ready[-1][1] - stamp > self.max_lag_ns:
                    self.left_out["behind"] += 1
                    continue
            self.read_pair(index, stamp, msgs)

    def _leave_out(self, cause: str, why: str | None = None) -> None:
        with self._cond:
            self.left_out[cause] += 1
        if why is not None:
            self.log(f"left out ({cause}): {why}")

    def read_pair(self, index: int, stamp: int, msgs: Sequence[Any]) -> None:
        where = f"{', '.join(self.topics)} at {stamp * 1e-9:.6f} s"
        if self.last_judged_ns is not None and stamp <= self.last_judged_ns:
            before = self.last_judged_ns * 1e-9
            return self._leave_out("late", f"{where}: the stamp goes backwards (the last judged: {before:.6f} s)")
        try:
            frames = [decode_image(m, self.msgtype, t) for m, t in zip(msgs, self.topics)]
        except SlipsenseError as exc:
            return self._leave_out("undecodable", str(exc))
        if self.first_ns is None:
            self.first_ns = stamp
        t = (stamp - self.first_ns) * 1e-9  # seconds since the first pair: exact, whatever the epoch
        t0 = time.perf_counter()
        try:
            reading = self.detector.push(*frames, stamp=t)
        except SlipsenseError as exc:  # a frame of another size than the detector's first
            return self._leave_out("undecodable", f"{where}: {exc}")
        latency_ms = (time.perf_counter() - t0) * 1e3
        self.last_judged_ns = stamp
        record = reading_record(reading, stamp * 1e-9, latency_ms, frame=index)  # the pair as received
        with self._cond:
            self.judged += 1
        if not self.rate_told:  # the source's rate, once ten messages of the first topic came
            with self._cond:
                stamps = sorted(self._stamps) if len(self._stamps) == 10 else None
            if stamps is not None:
                fps = 1e9 / float(np.median(np.diff(stamps)))
                self.log(
                    f"{', '.join(self.topics)}: {fps:.3g} frames/s (the header stamps); "
                    f"the detector runs at {self.detector.sensor.fps:g} frames/s"
                )
                self.rate_told = True
        self.publish(record, stamp, reading.alarm)

    def start(self, on_error: Callable[[], None] | None = None) -> None:
        """Judge on a thread of its own until :meth:`stop`; an unexpected error is kept in ``error``,
        logged, and ``on_error`` called (the node stops)."""

        def work():
            try:
                while True:
                    with self._cond:
                        self._cond.wait_for(lambda: self._ready or self._stopping)
                        if self._stopping:
                            return
                    self.read_pending()
            except BaseException as exc:  # noqa: BLE001  (handed to the node, which stops on it)
                self.error = exc
                self.log(f"the detector stopped: {type(exc).__name__}: {exc}")
                if on_error is not None:
                    on_error()

        self.inline = False
        self._thread = threading.Thread(target=work, name="slipsense-detector", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop judging after the pair in hand; pairs still waiting stay pending."""
        with self._cond:
            self._stopping = True
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=10)

    def check_silence(self) -> None:
        now = time.monotonic()
        for k, seen in enumerate(self.last_seen):
            if not self.silent[k] and now - seen > SILENT_S:
                self.silent[k] = True
                what = "no message yet" if seen == 0.0 else f"no message for {now - seen:.1f} s"
                self.log(f"{self.topics[k]}: {what}")

    def status(self) -> dict[str, Any]:
        """Every pair so far: ``pairs == judged + sum(left_out.values()) + pending``; and per topic the
        messages received, lost on the way and left without partners."""
        with self._cond:
            left = {**self.left_out, "unpaired": self.pairer.unpaired[0]}
            return {
                "pairs": self.pairs,
                "judged": self.judged,
                "left_out": left,
                "pending": self.pairs - self.judged - sum(left.values()),
                "topics": [
                    {"topic": t, "received": r, "lost": lo, "unpaired": u}
                    for t, r, lo, u in zip(self.topics, self.received, self.lost, self.pairer.unpaired)
                ],
            }

    def summary(self, status: dict[str, Any] | None = None) -> str:
        s = status or self.status()
        causes = ", ".join(f"{c} {n}" for c, n in s["left_out"].items())
        topics = "; ".join(
            f"{t['topic']} {t['received']} ({t['lost']} lost, {t['unpaired']} unpaired)" for t in s["topics"]
        )
        return (
            f"frame pairs judged {s['judged']} of {s['pairs']}, left out {sum(s['left_out'].values())} ({causes}), "
            f"pending {s['pending']}; messages received: {topics}"
        )


def twists(record: dict) -> list[tuple[tuple[float, float], float] | None]:
    """Each finger's slip of a reading as ROS states a twist: ``((vx, vy) in m/s, omega in rad/s)``,
    None for a finger without contact; nothing for a reading in px/s (the sensor states no pixel
    size) or without markers."""
    if record.get("slip_velocity_unit") != "mm/s":
        return []
    return [
        None if s is None else ((s["translation"][0] * 1e-3, s["translation"][1] * 1e-3), s["omega"])
        for s in record["slip"]
    ]


def _number(node: Any, name: str, default: float) -> float:
    """A numeric parameter that takes an integer too (``-p threshold:=1``)."""
    from rcl_interfaces.msg import ParameterDescriptor

    value = node.declare_parameter(name, default, ParameterDescriptor(dynamic_typing=True)).value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"parameter {name} must be a number, got {value!r}")
    return float(value)


def main(argv: Sequence[str] | None = None, overrides: dict[str, Any] | None = None) -> None:
    """Run the node until it is stopped (Ctrl-C, SIGTERM); ``overrides``: parameters set in code
    (what ``slipsense ros`` passes), over the ``--ros-args`` ones."""
    import rclpy  # the ROS extra: imported where the node runs, so the library imports without it
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CompressedImage, Image
    from geometry_msgs.msg import TwistStamped
    from std_msgs.msg import Bool, Float32, String

    rclpy.init(args=list(argv) if argv is not None else sys.argv)
    params = [Parameter(k, value=v) for k, v in (overrides or {}).items()]
    node = Node("slipsense", parameter_overrides=params, enable_rosout=False)  # its log is its own output
    log = node.get_logger().info
    topics = list(node.declare_parameter("topics", ["/left/image_raw", "/right/image_raw"]).value)
    compressed = bool(node.declare_parameter("compressed", False).value)
    checkpoint = str(node.declare_parameter("checkpoint", "").value)
    backend = str(node.declare_parameter("backend", "auto").value)
    threshold = _number(node, "threshold", -1.0)
    hold = _number(node, "hold", -1.0)
    tolerance = _number(node, "tolerance", 0.0)
    max_lag = _number(node, "max_lag", MAX_LAG_S)
    threads = int(node.declare_parameter("threads", 0).value)
    gel_motion = bool(node.declare_parameter("gel_motion", True).value)
    kind, msgtype = (CompressedImage, COMPRESSED) if compressed else (Image, IMAGE)
    if threads < 0 or tolerance < 0 or max_lag < 0:
        raise ConfigError(f"threads, tolerance and max_lag must be >= 0, got {threads}, {tolerance:g}, {max_lag:g}")
    import torch  # the detector's; its thread count also sets ONNX Runtime's

    if threads:
        torch.set_num_threads(threads)
    path = checkpoint or shipped_model(default_model_name(len(topics)))
    # the detector's alarm settings: the checkpoint's operating point unless set
    alarm_settings = {"threshold": None if threshold < 0 else threshold, "hold": None if hold < 0 else hold}
    detector = SlipDetector.from_checkpoint(
        path, sensors=len(topics), backend=backend, gel_motion=gel_motion, **alarm_settings
    )
    log(
        f"{detector.model_name} on {detector.backend}, {len(topics)} sensor(s), alarm at {detector.threshold:g}"
        f"{'' if threshold < 0 else ' (set)'}, held {detector.hold:g} s, {torch.get_num_threads()} thread(s)"
    )
    if threshold < 0:  # the checkpoint's own operating point: what it promises
        log(promise_text(read_info(path).get("operating_point")))
    out_qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
    readings = node.create_publisher(String, READING_TOPIC, out_qos)
    alarms = node.create_publisher(Bool, ALARM_TOPIC, out_qos)
    probabilities = node.create_publisher(Float32, PROBABILITY_TOPIC, out_qos)
    slips = node.create_publisher(TwistStamped, VELOCITY_TOPIC, out_qos)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    statuses = node.create_publisher(String, STATUS_TOPIC, latched)
    best_effort = dict(reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
    in_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=QUEUE_DEPTH, **best_effort)

    def publish(record: dict, stamp: int, alarm: bool) -> None:
        readings.publish(String(data=json.dumps(record)))
        alarms.publish(Bool(data=bool(alarm)))
        p = record["probability"]
        probabilities.publish(Float32(data=float("nan") if p is None else float(p)))
        for k, twist in enumerate(twists(record)):
            if twist is not None:
                msg = TwistStamped()
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
                msg.header.frame_id = f"finger_{k}"
                (msg.twist.linear.x, msg.twist.linear.y), msg.twist.angular.z = twist
                slips.publish(msg)

    loop = ReadingLoop(detector, topics, msgtype, publish, log, tolerance_s=tolerance or None, max_lag_s=max_lag)
    told: list[Any] = [None]

    def report() -> None:
        status = loop.status()
        statuses.publish(String(data=json.dumps(status)))
        losses = [*status["left_out"].values(), *(n for t in status["topics"] for n in (t["lost"], t["unpaired"]))]
        if any(losses) and losses != told[0]:  # a healthy node stays quiet
            log(f"status: {loop.summary(status)}")
        told[0] = losses

    for k, topic in enumerate(topics):
        node.create_subscription(kind, topic, lambda msg, info, k=k: loop.on_message(k, msg, info), in_qos)
    node.create_timer(0.5, loop.check_silence)
    node.create_timer(STATUS_S, report)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    loop.start(on_error=executor.wake)
    log(
        f"listening on {', '.join(topics)}; readings on {READING_TOPIC} (and {ALARM_TOPIC}, {PROBABILITY_TOPIC}, "
        f"{VELOCITY_TOPIC}), the account of every frame pair on {STATUS_TOPIC}"
    )
    try:
        while rclpy.ok() and loop.error is None:
            executor.spin_once(timeout_sec=0.5)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        loop.stop()
        log(loop.summary())
        detector.close()
        executor.shutdown(timeout_sec=1)
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    if loop.error is not None:
        raise loop.error


if __name__ == "__main__":
    main()
