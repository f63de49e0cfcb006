"""``slipsense bag``: ROS 2 bags to the recordings layout (registered by slipsense.cli)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from slipsense.errors import ConfigError, InputError


def slipped_from_topic(bag: Path, topic: str) -> bool:
    """True when any ``std_msgs/msg/Bool`` message on ``topic`` is true (a grasp controller's or a
    person's "it slipped" mark); InputError naming the bag for a missing topic or another type."""
    from slipsense.recordings.bags import bag_error, open_reader

    try:
        with open_reader(bag) as reader:
            conns = [c for c in reader.connections if c.topic == topic]
            if not conns:
                raise InputError(bag, f"no label topic {topic}")
            if conns[0].msgtype != "std_msgs/msg/Bool":
                raise InputError(bag, f"label topic {topic} holds {conns[0].msgtype}, not std_msgs/msg/Bool")
            return any(
                bool(reader.deserialize(raw, c.msgtype).data) for c, _, raw in reader.messages(connections=conns)
            )
    except InputError:
        raise
    except Exception as exc:
        raise bag_error(bag, exc) from None


def register(app: typer.Typer) -> None:
    from slipsense.cli import friendly

    bag_app = typer.Typer(help="ROS 2 bags: convert them to the recordings layout")
    app.add_typer(bag_app, name="bag")

    @bag_app.command("convert")
    @friendly
    def convert(
        bag: Path = typer.Argument(..., help="a rosbag2 folder, or a .db3 / .mcap file"),
        out: Path = typer.Option(..., help="the experiment folder to write, e.g. RECORDINGS/<object>/exp_num_<N>"),
        topic: list[str] = typer.Option(..., help="an image topic, once per sensor, in order"),
        slipped: bool = typer.Option(False, help="the object slipped in this grasp (writes slip.txt)"),
        label_topic: Optional[str] = typer.Option(
            None, help="a std_msgs/msg/Bool topic: the object slipped when any message is true"
        ),
        fps: float = typer.Option(25.0, help="the sensor's frame rate (the videos' rate; pairing tolerance)"),
        tolerance: Optional[float] = typer.Option(None, help="seconds: largest stamp difference of paired frames"),
    ):
        """Write a bag's image topics as camera_<k>.avi (lossless FFV1) with slip.txt when it slipped:
        every command that takes recordings then reads it."""
        from slipsense.recordings.bags import read_bag, write_recording

        if slipped and label_topic:
            raise ConfigError("give --slipped or --label-topic, not both")
        frames = read_bag(bag, topic, fps=fps, tolerance_s=tolerance)
        if label_topic:
            slipped = slipped_from_topic(bag, label_topic)
        names = [f"camera_{k}" for k in range(len(topic))]
        write_recording(frames, out, names, slipped=slipped, fps=fps)
        dropped = ", ".join(f"{t}: {n}" for t, n in frames.dropped.items() if n)
        typer.echo(
            f"{out}: {len(frames.frames)} frames x {len(topic)} sensors ({frames.fps:.2f} frames/s), "
            f"{'slipped' if slipped else 'held'}" + (f"; left unpaired {dropped}" if dropped else "")
        )
