"""Alarms out: the detector's readings as JSON lines or as messages in a ROS 2 bag, for a controller or
a logger to consume.

One record per pushed frame::

    {"frame": 57, "stamp": 1700000002.28, "probability": 0.91, "per_sensor": [0.91, 0.40],
     "alarm": true, "latency_ms": 0.31}

``frame``: 0-based index since the stream started; ``stamp``: when the frame was taken (s: a bag's
header stamp, a live camera's capture clock, ``index / fps`` for a file); ``probability``: null while
the detector has not seen enough frames; ``latency_ms``: time the detector took for this frame.

In a bag, the same fields go on a topic (``/slipsense/reading`` by default) of the project's message
``slipsense_msgs/msg/SlipReading`` (:data:`SLIP_READING_MSG`), registered in the bag so any reader
(``rosbags``, ``ros2 bag``, Foxglove) decodes it without the project.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from slipsense.errors import OutputError

#: the ROS 2 message definition of one reading
SLIP_READING_MSG = """std_msgs/Header header
uint32 frame
float32 probability
float32[] per_sensor
bool alarm
float32 latency_ms
"""
SLIP_READING = "slipsense_msgs/msg/SlipReading"


def reading_record(reading, stamp: float, latency_ms: float) -> dict[str, Any]:
    """A :class:`~slipsense.streaming.detector.Reading` as the JSON-ready record above."""

    def number(p):  # a NaN probability (it raises the alarm) has no JSON form: null, with the alarm on
        return None if p is None or math.isnan(p) else round(float(p), 6)

    return {
        "frame": int(reading.index),
        "stamp": float(stamp),
        "probability": number(reading.probability),
        "per_sensor": None if reading.per_sensor is None else [number(p) for p in reading.per_sensor],
        "alarm": bool(reading.alarm),
        "latency_ms": round(float(latency_ms), 4),
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
    """Records as ``slipsense_msgs/msg/SlipReading`` messages on ``topic`` of a new rosbag2 folder
    ``path`` (sqlite3 storage), each stamped with its frame's time."""

    def __init__(self, path: str | Path, topic: str = "/slipsense/reading", frame_id: str = "slipsense"):
        from rosbags.rosbag2 import Writer  # ~0.3 s to import: only for bags

        self.path, self.topic, self.frame_id = Path(path), topic, frame_id
        if self.path.exists():
            raise OutputError(self.path, "exists; a bag is written to a new folder")
        self.store = _typestore()
        self._msg = self.store.types[SLIP_READING]
        self._header = self.store.types["std_msgs/msg/Header"]
        self._time = self.store.types["builtin_interfaces/msg/Time"]
        try:
            self._writer = Writer(self.path, version=9)
            self._writer.open()
        except Exception as exc:  # rosbags' WriterError, an OSError
            raise OutputError(self.path, f"cannot be written ({exc})") from None
        self._conn = self._writer.add_connection(self.topic, SLIP_READING, typestore=self.store)

    def write(self, record: dict[str, Any]) -> None:
        ns = int(round(record["stamp"] * 1e9))
        p = record["probability"]
        msg = self._msg(
            header=self._header(
                stamp=self._time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id=self.frame_id
            ),
            frame=record["frame"],
            probability=math.nan if p is None else p,
            per_sensor=np.asarray([math.nan if v is None else v for v in record["per_sensor"] or []], np.float32),
            alarm=record["alarm"],
            latency_ms=record["latency_ms"],
        )
        self._writer.write(self._conn, ns, self.store.serialize_cdr(msg, SLIP_READING))

    def close(self) -> None:
        self._writer.close()


def read_bag_readings(path: str | Path, topic: str = "/slipsense/reading") -> list[dict[str, Any]]:
    """The records a :class:`BagWriter` wrote (NaN probability back to None)."""
    from rosbags.highlevel import AnyReader  # ~0.3 s to import: only for bags

    out = []
    with AnyReader([Path(path)], default_typestore=_typestore()) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        for conn, _, raw in reader.messages(connections=conns):
            m = reader.deserialize(raw, conn.msgtype)
            p = float(m.probability)
            out.append(
                {
                    "frame": int(m.frame),
                    "stamp": m.header.stamp.sec + m.header.stamp.nanosec * 1e-9,
                    "probability": None if math.isnan(p) else p,
                    "per_sensor": [float(v) for v in m.per_sensor] or None,
                    "alarm": bool(m.alarm),
                    "latency_ms": float(m.latency_ms),
                }
            )
    return out
