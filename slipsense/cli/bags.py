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
    from slipsense.cli.common import friendly

    bag_app = typer.Typer(help="ROS 2 bags: convert them to the recordings layout")
    app.add_typer(bag_app, name="bag")

    @bag_app.command("convert")
    @friendly
    def convert(
        bag: Path = typer.Argument(
            ..., help="a rosbag2 folder or .db3 / .mcap file; or a folder of bags, <object>/<bag> each"
        ),
        out: Path = typer.Option(
            ...,
            help="the experiment folder to write (RECORDINGS/<object>/exp_num_<N>); for a folder of bags, RECORDINGS",
        ),
        topic: list[str] = typer.Option(..., help="an image topic, once per sensor, in order"),
        slipped: bool = typer.Option(False, help="the object slipped in this grasp (writes slip.txt)"),
        label_topic: Optional[str] = typer.Option(
            None, help="a std_msgs/msg/Bool topic: the object slipped when any message is true"
        ),
        labels: Optional[Path] = typer.Option(
            None,
            help="CSV with columns bag,slipped (bag: <object>/<bag name>; slipped: 1 or 0) for a folder of bags; "
            "a bag it does not name held, unless slip.txt is in it",
        ),
        fps: float = typer.Option(25.0, help="the sensor's frame rate (the videos' rate; pairing tolerance)"),
        tolerance: Optional[float] = typer.Option(None, help="seconds: largest stamp difference of paired frames"),
    ):
        """Write bags' image topics as camera_<k>.avi (lossless FFV1) with slip.txt where the object
        slipped: every command that takes recordings then reads them. A folder of bags becomes
        OUT/<object>/exp_num_<N>, N counting each object's bags in name order."""
        from slipsense.recordings.bags import check_timing, is_bag

        check_timing(fps, tolerance)
        if sum(bool(x) for x in (slipped, label_topic, labels)) > 1:
            raise ConfigError("give one of --slipped, --label-topic and --labels")
        if is_bag(bag):
            if labels is not None:
                raise ConfigError("--labels is for a folder of bags; for one bag use --slipped or --label-topic")
            _convert_one(bag, out, topic, slipped, label_topic, fps, tolerance)
            return
        if not Path(bag).is_dir():
            raise InputError(bag, "neither a ROS 2 bag nor a folder of them")
        if slipped:
            raise ConfigError("--slipped is for one bag; a folder of bags takes --labels or --label-topic")
        marks = _read_labels(labels) if labels is not None else {}
        found = [
            (o.name, b) for o in sorted(Path(bag).iterdir()) if o.is_dir() for b in sorted(o.iterdir()) if is_bag(b)
        ]
        if not found:
            raise InputError(bag, "holds no bags (expected <object>/<bag>)")
        unknown = sorted(set(marks) - {f"{o}/{b.name}" for o, b in found})
        if unknown:
            raise InputError(labels, f"names bags that are not there: {', '.join(unknown[:5])}")
        counts: dict[str, int] = {}
        for obj, b in found:
            counts[obj] = counts.get(obj, 0) + 1
            mark = marks.get(f"{obj}/{b.name}", False) or (b / "slip.txt").is_file()
            _convert_one(b, Path(out) / obj / f"exp_num_{counts[obj]}", topic, mark, label_topic, fps, tolerance)


def _read_labels(path: Path) -> dict[str, bool]:
    """``{"<object>/<bag>": slipped}`` from a CSV with columns bag,slipped; InputError naming the line."""
    import csv

    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InputError(path, f"cannot be read as CSV ({exc})") from None
    out = {}
    for line, row in enumerate(rows, start=2):
        if set(row) < {"bag", "slipped"} or row.get("bag") is None:
            raise InputError(path, "needs the columns bag,slipped")
        value = (row.get("slipped") or "").strip().lower()
        if value not in ("1", "0", "true", "false", "yes", "no"):
            raise InputError(path, f"line {line}: slipped must be 1 or 0, got {row.get('slipped')!r}")
        out[row["bag"].strip().strip("/")] = value in ("1", "true", "yes")
    return out


def _convert_one(bag, out, topics, slipped, label_topic, fps, tolerance) -> None:
    from slipsense.recordings.bags import read_bag, write_recording

    frames = read_bag(bag, topics, fps=fps, tolerance_s=tolerance)
    if label_topic:
        slipped = slipped_from_topic(bag, label_topic)
    write_recording(frames, out, [f"camera_{k}" for k in range(len(topics))], slipped=slipped, fps=fps)
    dropped = ", ".join(f"{t}: {n}" for t, n in frames.dropped.items() if n)
    typer.echo(
        f"{out}: {len(frames.frames)} frames x {len(topics)} sensors ({frames.fps:.2f} frames/s), "
        f"{'slipped' if slipped else 'held'}" + (f"; left unpaired {dropped}" if dropped else "")
    )
