"""What following the gel's markers costs a live loop: per-push latency of the shipped detectors with
the slip velocity and shear field (``gel_motion=True``, the default) and without, side by side in one
run, one thread, on real frames: a gelsight-lift grasp (640 x 480, one finger; target p99 <= 33 ms, a
frame period at 30 frames/s) and a GelSight Mini run (320 x 240, both fingers).

    .venv/bin/python bench/bench_gel_motion.py --out bench/results/avx512/gel-motion.md

Each pass resets the detector and pushes the grasp's frames from its first (the velocity needs the
grasp from its start); the two settings alternate pass by pass; p50 / p99 / max over every push.
"""

from __future__ import annotations

import argparse
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from slipsense.paths import data_root  # noqa: E402
from slipsense.recordings.video import read_video  # noqa: E402
from slipsense.resources import shipped_model  # noqa: E402
from slipsense.streaming.detector import SlipDetector  # noqa: E402

from markdown import emit  # bench/markdown.py: run as python bench/NAME.py

TARGET_P99_MS = 33.0
CASES = {
    "gelsight-lift grasp, shear-retention-gelsight-lift, 1 finger": (
        "shear-retention-gelsight-lift",
        ["gelsight-lift/object001/068_00_mm"],
    ),
    "GelSight Mini run, motionnet-gelsight, 2 fingers": (
        "motionnet-gelsight",
        ["gelsight-slip/blue_mug/exp_num_9/camera_0.avi", "gelsight-slip/blue_mug/exp_num_9/camera_2.avi"],
    ),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passes", type=int, default=20)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    torch.set_num_threads(1)
    rows = []
    for case, (name, files) in CASES.items():
        videos = [read_video(data_root() / f, expected_size=None) for f in files]
        dets = {
            on: SlipDetector.from_checkpoint(shipped_model(name), sensors=len(files), gel_motion=on)
            for on in (False, True)
        }
        times = {False: [], True: []}
        for _ in range(args.passes):
            for on, det in dets.items():
                det.reset()
                for frames in zip(*videos):
                    t = time.perf_counter()
                    det.push(*frames)
                    times[on].append((time.perf_counter() - t) * 1e3)
        stats = {on: (np.percentile(v, 50), np.percentile(v, 99), max(v)) for on, v in times.items()}
        rows.append((case, stats, len(videos[0])))
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    lines = [
        "# The gel's motion in every reading: what it costs a push",
        "",
        f"`python bench/bench_gel_motion.py --passes {args.passes}`: commit {commit}, {platform.processor() or platform.machine()}, "
        f"one thread, {time.strftime('%Y-%m-%d')}. Milliseconds per push (both fingers' frames for two).",
        "",
        "| case | frames | without: p50 / p99 / max | with slip velocity: p50 / p99 / max | p99 ratio | p99 within 33 ms |",
        "|---|---:|---:|---:|---:|---|",
    ]
    for case, s, n in rows:
        off, on = s[False], s[True]
        lines.append(
            f"| {case} | {n} | {off[0]:.2f} / {off[1]:.2f} / {off[2]:.2f} | {on[0]:.2f} / {on[1]:.2f} / {on[2]:.2f} "
            f"| {on[1] / off[1]:.1f}x | {'yes' if on[1] <= TARGET_P99_MS else 'NO'} |"
        )
    emit(lines, args.out)


if __name__ == "__main__":
    main()
