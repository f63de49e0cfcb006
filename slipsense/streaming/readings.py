"""Alarms out: the detector's readings as JSON lines or as messages in a ROS 2 bag, for a controller or
a logger to consume.

One record per pushed frame::

    {"frame": 57, "stamp": 1700000002.28, "probability": 0.91, "per_sensor": [0.91, 0.40],
     "alarm": true, "latency_ms": 0.31,
     "slip": [{"translation": [12.1, -3.4], "omega": 0.35, "stick": 0.2, "speed": 13.0}, null],
     "slip_velocity_unit": "mm/s", "slip_omega_unit": "rad/s",
     "shear": [{"displacement": [0.41, -0.1], "divergence": 0.02, "curl": 0.01, "contact": 0.3}, null]}

``frame``: the frame's 0-based number in its source since the stream started, counting frames the
source had but that were never judged (a live camera's frames replaced while the detector was busy,
a ROS 2 node's pairs left out), so a gap in ``frame`` is a loss; ``stamp``: when the frame was taken (s: a bag's
header stamp, a live camera's capture clock, ``index / fps`` for a file); ``probability``: null while
the detector has not seen enough frames; ``latency_ms``: time the detector took for this frame;
``slip``: per sensor how the object moves against the gel (:class:`~slipsense.sensors.gel_motion.GelMotion`):
``translation`` its in-plane velocity ``[vx, vy]`` (image axes: x right, y down) in
``slip_velocity_unit`` (``mm/s`` where the sensor states its pixel size, else ``px/s``), ``omega`` its
rotation rate about the contact's centre in ``slip_omega_unit`` (``rad/s``; positive from +x towards
+y), ``stick`` the share (0-1) of the contact where it still sticks, ``speed`` how fast it moves
against the gel on average over the contact (translation and turn together, in
``slip_velocity_unit``); null for a sensor without contact; ``shear``: per sensor the shear field (mean displacement in the translation's length unit,
divergence, curl, share of markers in contact); ``slip``, its two units and ``shear`` all null where
the sensor's gel has no markers.

In a bag, the same record goes on a topic (``/slipsense/reading`` by default) as a ``std_msgs/msg/String``
holding the JSON line: the very message the ROS 2 node (:mod:`slipsense.ros_node`) publishes on
``/slipsense/reading``, so one topic name has one message type live and in a bag, and any reader
(``rosbags``, ``ros2 bag``, Foxglove) decodes it without the project. Bags written before by
``slipsense_msgs/msg/SlipReading`` (:data:`SLIP_READING_MSG`) are still read by :func:`read_bag_readings`.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any


from slipsense.errors import OutputError

#: the ROS 2 message definition of one reading in bags of earlier versions (read, no longer written)
SLIP_READING_MSG = """std_msgs/Header header
uint32 frame
float32 probability
float32[] per_sensor
bool alarm
float32 latency_ms
"""
SLIP_READING = "slipsense_msgs/msg/SlipReading"
#: the message type of a reading on ``/slipsense/reading``, from the node and in a bag: the JSON record
READING_MSGTYPE = "std_msgs/msg/String"


def reading_record(reading, stamp: float, latency_ms: float, frame: int | None = None) -> dict[str, Any]:
    """A :class:`~slipsense.streaming.detector.Reading` as the JSON-ready record above; ``frame``: the
    frame's number in its source (default: the reading's, the count of pushes)."""

    def number(p):  # a NaN probability (it raises the alarm) has no JSON form: null, with the alarm on
        return None if p is None or math.isnan(p) else round(float(p), 6)

    gel = reading.gel
    return {
        "frame": int(reading.index if frame is None else frame),
        "stamp": float(stamp),
        "probability": number(reading.probability),
        "per_sensor": None if reading.per_sensor is None else [number(p) for p in reading.per_sensor],
        "alarm": bool(reading.alarm),
        "latency_ms": round(float(latency_ms), 4),
        "slip": None if gel is None else list(reading.slip),
        "slip_velocity_unit": reading.slip_velocity_unit,
        "slip_omega_unit": reading.slip_omega_unit,
        "shear": None if gel is None else [None if g is None else g.to_dict() for g in gel],
    }


class JsonlWriter:
    """Records as JSON lines to ``path`` (``"-"``: standard output), flushed line by line so a
    consumer reading the file as it grows sees each reading at once."""

    def __init__(self, path: str | Path):
        self.path = str(path)
        if self.path == "-":
            self._fh = sys.stdout
        else:
            try:
                Path(self.path).parent.mkdir(parents=True, exist_ok=True)
                self._fh = open(self.path, "w", encoding="utf-8")
            except OSError as exc:
                raise OutputError(self.path, f"cannot be written ({exc.strerror or exc})") from None

    def write(self, record: dict[str, Any]) -> None:
        self._fh.write(json.dumps(record, allow_nan=False) + "\n")
        self._fh.flush()

    def close(self) -> None:
        if self._fh is not sys.stdout:
            self._fh.close()


def _typestore():
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # ~0.3 s: only for bags

    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(SLIP_READING_MSG, SLIP_READING))
    return store


class BagWriter:
    """Records as ``std_msgs/msg/String`` messages (the JSON record, as the ROS 2 node publishes it) on
    ``topic`` of a new rosbag2 folder ``path`` (sqlite3 storage), each stamped with its frame's time."""

    def __init__(self, path: str | Path, topic: str = "/slipsense/reading"):
        from rosbags.rosbag2 import Writer  # ~0.3 s to import: only for bags

        self.path, self.topic = Path(path), topic
        if self.path.exists():
            raise OutputError(self.path, "exists; a bag is written to a new folder")
        self.store = _typestore()
        self._msg = self.store.types[READING_MSGTYPE]
        try:
            self._writer = Writer(self.path, version=9)
            self._writer.open()
        except Exception as exc:  # rosbags' WriterError, an OSError
            raise OutputError(self.path, f"cannot be written ({exc})") from None
        self._conn = self._writer.add_connection(self.topic, READING_MSGTYPE, typestore=self.store)

    def write(self, record: dict[str, Any]) -> None:
        ns = int(round(record["stamp"] * 1e9))
        msg = self._msg(data=json.dumps(record, allow_nan=False))
        self._writer.write(self._conn, ns, self.store.serialize_cdr(msg, READING_MSGTYPE))

    def close(self) -> None:
        self._writer.close()


def read_bag_readings(path: str | Path, topic: str = "/slipsense/reading") -> list[dict[str, Any]]:
    """The records a :class:`BagWriter` wrote (JSON strings; in bags of earlier versions
    ``slipsense_msgs/msg/SlipReading`` messages, their NaN probability back to None)."""
    from rosbags.highlevel import AnyReader  # ~0.3 s to import: only for bags

    out = []
    with AnyReader([Path(path)], default_typestore=_typestore()) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        for conn, _, raw in reader.messages(connections=conns):
            m = reader.deserialize(raw, conn.msgtype)
            if conn.msgtype == READING_MSGTYPE:
                out.append(json.loads(m.data))
                continue
            p, stamp = float(m.probability), m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
            record = {"frame": int(m.frame), "stamp": stamp, "probability": None if math.isnan(p) else p}
            record["per_sensor"] = [float(v) for v in m.per_sensor] or None
            out.append({**record, "alarm": bool(m.alarm), "latency_ms": float(m.latency_ms)})
    return out
