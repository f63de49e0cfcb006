"""A ROS 2 node: the slip detector on two image topics, readings out on two topics.

    python -m slipsense.streaming.ros_node --ros-args -p left:=/left/image_raw -p right:=/right/image_raw

rclpy comes with a ROS 2 installation and is not installable from the package registries slipsense
uses, so this file is not imported by the library or its tests; it is a thin shell over tested parts:
image messages are decoded by :func:`slipsense.recordings.bags.decode_image` (the bag reader's),
frames are pushed to :class:`slipsense.streaming.detector.SlipDetector`, and each reading is the
record of :func:`slipsense.streaming.readings.reading_record`, published as JSON on
``/slipsense/reading`` (``std_msgs/String``) and as ``std_msgs/Bool`` on ``/slipsense/alarm``. The two
image topics are paired by header stamp (``message_filters.ApproximateTimeSynchronizer``, slop of half
a frame period), as :func:`slipsense.recordings.bags.pair_by_time` pairs a bag's.
"""

from __future__ import annotations

import json
import time

from slipsense.recordings.bags import COMPRESSED, IMAGE, decode_image
from slipsense.streaming.detector import SlipDetector
from slipsense.streaming.readings import reading_record


def main() -> None:  # pragma: no cover - needs a ROS 2 installation
    import message_filters
    import rclpy
    from rclpy.node import Node
    from sensor_msgs.msg import CompressedImage, Image
    from std_msgs.msg import Bool, String

    class SlipNode(Node):
        def __init__(self):
            super().__init__("slipsense")
            topics = [self.declare_parameter(k, f"/{k}/image_raw").value for k in ("left", "right")]
            compressed = self.declare_parameter("compressed", False).value
            checkpoint = self.declare_parameter("checkpoint", "").value
            kind, self.msgtype = (CompressedImage, COMPRESSED) if compressed else (Image, IMAGE)
            self.detector = (
                SlipDetector.from_checkpoint(checkpoint, sensors=2, backend="onnx")
                if checkpoint
                else SlipDetector.pretrained(backend="onnx")
            )
            subs = [message_filters.Subscriber(self, kind, t) for t in topics]
            slop = 0.5 / self.detector.sensor.fps
            self.sync = message_filters.ApproximateTimeSynchronizer(subs, queue_size=4, slop=slop)
            self.sync.registerCallback(self.on_frames)
            self.readings = self.create_publisher(String, "/slipsense/reading", 10)
            self.alarms = self.create_publisher(Bool, "/slipsense/alarm", 10)

        def on_frames(self, *msgs):
            frames = [decode_image(m, self.msgtype, "ROS 2 image") for m in msgs]
            t0 = time.perf_counter()
            reading = self.detector.push(*frames)
            stamp = msgs[0].header.stamp.sec + msgs[0].header.stamp.nanosec * 1e-9
            record = reading_record(reading, stamp, (time.perf_counter() - t0) * 1e3)
            self.readings.publish(String(data=json.dumps(record)))
            self.alarms.publish(Bool(data=record["alarm"]))

    rclpy.init()
    node = SlipNode()
    try:
        rclpy.spin(node)
    finally:
        node.destroy_node()
        rclpy.shutdown()


if __name__ == "__main__":  # pragma: no cover
    main()
