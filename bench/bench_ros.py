"""The ROS 2 node in the loop: from an image's publication to its reading's arrival, two sensors at
25 frames/s over a whole shared run, beside the detector's own push time.

    .venv/bin/python bench/bench_ros.py                      # Markdown on stdout
    .venv/bin/python bench/bench_ros.py --runs 3 --json ros.json

A player node publishes a run's two videos as ``sensor_msgs/Image`` at 25 per second with their
header stamps; ``slipsense ros`` runs as its own process (loopback, Fast DDS from the package
registry); the player subscribes to ``/slipsense/reading``. Latency: the reading's arrival minus the
publication of the later of its two images (wall clock of the player). ``push``: the detector's own
time per frame pair, as the node measures it (``latency_ms`` of each reading). Frames without a
reading (dropped or unpaired) are counted, never left out silently. Target (issue 40): p99 under one
frame period (40 ms).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import random
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from slipsense.paths import gelsight_recordings  # noqa: E402
from slipsense.provenance import write_provenance  # noqa: E402
from slipsense.recordings.video import read_video  # noqa: E402
from slipsense.ros_node import READING_TOPIC  # noqa: E402

TOPICS = ("/left/image_raw", "/right/image_raw")


def play(run: Path, backend: str) -> dict:
    """One run through the node; per-frame latencies (ms) and what was lost."""
    import rclpy
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import Image
    from std_msgs.msg import String

    videos = [read_video(run / f"{c}.avi") for c in ("camera_0", "camera_2")]
    n = len(videos[0])
    args = ["--ros-args", "-p", f"topics:={list(TOPICS)}", "-p", f"backend:={backend}"]
    node = subprocess.Popen(
        [sys.executable, "-m", "slipsense.ros_node", *args],
        env={**os.environ, "OMP_NUM_THREADS": "1"},
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    rclpy.init()
    me = rclpy.create_node("slipsense_bench_player")
    published: dict[int, float] = {}
    arrived: dict[int, tuple[float, float]] = {}

    def on_reading(msg):
        r = json.loads(msg.data)
        arrived[r["frame"]] = (time.perf_counter(), r["latency_ms"])

    try:
        me.create_subscription(String, READING_TOPIC, on_reading, 500)
        pubs = [me.create_publisher(Image, t, QoSProfile(depth=50)) for t in TOPICS]
        deadline = time.monotonic() + 60
        while any(p.get_subscription_count() == 0 for p in pubs) or me.count_publishers(READING_TOPIC) == 0:
            if node.poll() is not None or time.monotonic() > deadline:
                raise SystemExit(f"the node did not come up:\n{node.stdout.read()}")
            rclpy.spin_once(me, timeout_sec=0.1)
        time.sleep(0.5)
        base, start = 1_700_000_000 * 10**9, time.monotonic()
        for k in range(n):
            sec, nsec = divmod(base + k * 40_000_000, 1_000_000_000)
            for pub, video in zip(pubs, videos):
                msg = Image(height=240, width=320, encoding="bgr8", is_bigendian=0, step=960)
                msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nsec
                msg.data = video[k].tobytes()
                pub.publish(msg)
            published[k] = time.perf_counter()
            while time.monotonic() < start + (k + 1) * 0.04:
                rclpy.spin_once(me, timeout_sec=0.002)
        deadline = time.monotonic() + 5
        while len(arrived) < n and time.monotonic() < deadline:
            rclpy.spin_once(me, timeout_sec=0.01)
    finally:
        me.destroy_node()
        rclpy.shutdown()
        node.terminate()
        log = node.communicate(timeout=30)[0]
    lat = [1e3 * (arrived[k][0] - published[k]) for k in sorted(arrived) if k in published]
    push = [arrived[k][1] for k in sorted(arrived)]
    summary = next((line for line in log.splitlines() if "frame pairs judged" in line), "")
    return {"run": str(run), "frames": n, "readings": len(arrived), "latency_ms": lat, "push_ms": push, "node": summary}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1, help="shared runs to play, one after another")
    ap.add_argument("--backend", default="auto", help="the node's backend: auto, torch or onnx")
    ap.add_argument(
        "--out", type=Path, default=None, help="report folder: README.md (the table, how it was made), ros.json"
    )
    args = ap.parse_args(argv)
    started = time.time()
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(1, 100)))
    runs = sorted(p for p in gelsight_recordings().glob("*/exp_num_*") if (p / "camera_2.avi").is_file())
    results = [play(run, args.backend) for run in random.Random(0).sample(runs, args.runs)]
    lat = np.concatenate([r["latency_ms"] for r in results])
    push = np.concatenate([r["push_ms"] for r in results])
    frames, got = sum(r["frames"] for r in results), sum(r["readings"] for r in results)
    table = "\n".join(
        [
            "| two sensors at 25 frames/s | p50 (ms) | p99 (ms) | max (ms) |",
            "|---|---:|---:|---:|",
            f"| publication to reading | {np.percentile(lat, 50):.2f} | {np.percentile(lat, 99):.2f} | {lat.max():.2f} |",
            f"| the detector's push | {np.percentile(push, 50):.2f} | {np.percentile(push, 99):.2f} | {push.max():.2f} |",
        ]
    )
    lost = f"{got} readings for {frames} frame pairs ({frames - got} without one)"
    print(table + "\n\n" + lost + "; node: " + "; ".join(r["node"] for r in results))
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        summary = {
            "latency_ms": {"p50": float(np.percentile(lat, 50)), "p99": float(np.percentile(lat, 99))},
            "push_ms": {"p50": float(np.percentile(push, 50)), "p99": float(np.percentile(push, 99))},
            "frames": frames,
            "readings": got,
            "runs": [{k: v for k, v in r.items() if k not in ("latency_ms", "push_ms")} for r in results],
        }
        (args.out / "ros.json").write_text(json.dumps(summary, indent=1))
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
        command = "python bench/bench_ros.py " + " ".join(argv if argv is not None else sys.argv[1:])
        (args.out / "README.md").write_text(
            "# The ROS 2 node in the loop\n\n"
            f"Command: `{command}`  \nCommit {commit}, {platform.system()} {platform.machine()}, "
            f"{os.cpu_count()} cores, {datetime.date.today().isoformat()}; backend {args.backend}.\n\n"
            f"{table}\n\n{lost}.\n"
        )
        write_provenance(args.out, command, started, time.time())  # last: the report is whole
    return 0


if __name__ == "__main__":
    sys.exit(main())
