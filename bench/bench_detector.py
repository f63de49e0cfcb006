"""Per-push latency of the shipped detector as a gripper runs it: two sensors, default settings,
frames of a real recording, side by side in one run with the same detector on ONNX Runtime, the
one-finger detector (one camera per push), the paper's ViViT detector and, where the shared
``gelsight-lift`` grasps are there, that GelSight's shipped detector (shear retention) on its 480 x 640
frames.

    .venv/bin/python bench/bench_detector.py --threads 1 --out bench/results/detector.md

What is timed: ``SlipDetector.from_checkpoint(path, sensors=2, gel_motion=False).push(left, right)`` (``push(left)`` for
the one-finger detector) on the 240 x 320
BGR frames of both cameras of a shared recording (looped), everything a live loop pays per frame
pair. The detectors are timed in interleaved rounds (the machine may be shared), each push on its
own; p50 / p99 / max over all timed pushes. Target (issue 11): p99 <= 2 ms per push, one thread.
The model and its operating point only (``gel_motion=False``): what following the gel's markers for the
slip velocity adds is timed by ``bench/bench_gel_motion.py``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from slipsense.paths import data_root, gelsight_recordings  # noqa: E402
from slipsense.streaming.detector import DEFAULT_CHECKPOINT, SlipDetector  # noqa: E402
from slipsense.recordings.video import read_video  # noqa: E402
from slipsense.resources import shipped_model  # noqa: E402

from markdown import emit  # bench/markdown.py: run as python bench/NAME.py

TARGET_P99_MS = 2.0
VIVIT_CHECKPOINT = shipped_model("vivit-gelsight")
ONE_FINGER = shipped_model("motionnet-gelsight-1")
LIFT = shipped_model("shear-retention-gelsight-lift")
LIFT_GRASP = "gelsight-lift/object001/068_00_mm"  # a grasp that slipped, under SLIPSENSE_DATA


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--pushes", type=int, default=400, help="timed pushes per detector per round")
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--run", default="lemon/exp_num_1", help="recording (object/exp_num_N) whose frames are pushed")
    parser.add_argument("--checkpoint", type=Path, default=DEFAULT_CHECKPOINT, help="the detector to time")
    parser.add_argument("--out", type=Path, help="also write the Markdown report here")
    parser.add_argument("--json", type=Path, help="also write the numbers as JSON here")
    parser.add_argument("--no-onnx", action="store_true", help="leave out the ONNX Runtime row")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    folder = gelsight_recordings() / args.run
    cams = [read_video(folder / f"camera_{c}.avi") for c in (0, 2)]
    lift_folder = data_root() / LIFT_GRASP
    lift = [read_video(lift_folder, expected_size=None)] if lift_folder.is_dir() and LIFT.is_file() else None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        stem = args.checkpoint.stem
        detectors = {
            f"shipped ({stem}), PyTorch": SlipDetector.from_checkpoint(
                args.checkpoint, sensors=2, backend="torch", gel_motion=False
            )
        }
        if not args.no_onnx:
            detectors[f"shipped ({stem}), ONNX Runtime"] = SlipDetector.from_checkpoint(
                args.checkpoint, sensors=2, backend="onnx", gel_motion=False
            )
        if ONE_FINGER.is_file():
            detectors["one finger (motionnet-gelsight-1), PyTorch"] = SlipDetector.from_checkpoint(
                ONE_FINGER, sensors=1, backend="torch", gel_motion=False
            )
        if VIVIT_CHECKPOINT.is_file() and VIVIT_CHECKPOINT != args.checkpoint:
            detectors["paper ViViT (vivit-gelsight), PyTorch"] = SlipDetector.from_checkpoint(
                VIVIT_CHECKPOINT, sensors=2, backend="torch", gel_motion=False
            )
        sources = {name: cams for name in detectors}
        for backend, label in (("torch", "PyTorch"), ("onnx", "ONNX Runtime")):
            if lift is not None and not (backend == "onnx" and args.no_onnx):
                name = f"gelsight-lift (shear-retention-gelsight-lift, 480 x 640), {label}"
                detectors[name] = SlipDetector.from_checkpoint(LIFT, sensors=1, backend=backend, gel_motion=False)
                sources[name] = lift
    times: dict[str, list[float]] = {k: [] for k in detectors}
    for name, det in detectors.items():  # warm up: fill windows, first-call allocations
        src = sources[name]
        for i in range(40):
            det.push(*(src[s][i % len(src[s])] for s in range(det.sensors)))
    for _ in range(args.rounds):
        for name, det in detectors.items():
            src = sources[name]
            for i in range(args.pushes):
                frames = [src[s][i % len(src[s])] for s in range(det.sensors)]
                t0 = time.perf_counter()
                det.push(*frames)
                times[name].append(time.perf_counter() - t0)
    rows = []
    for name, ts in times.items():
        ms = np.asarray(ts) * 1000
        rows.append(
            {
                "detector": name,
                "pushes": len(ms),
                "p50_ms": float(np.percentile(ms, 50)),
                "p99_ms": float(np.percentile(ms, 99)),
                "max_ms": float(ms.max()),
            }
        )
    from studies.experiments.report import cpu_description

    lines = [
        f"# Live detector latency, two sensors, {args.threads} thread(s)",
        "",
        f"`python bench/bench_detector.py --threads {args.threads}` on {cpu_description()}; frames of "
        f"`{args.run}` (240 x 320, both cameras)"
        + (f"; the gelsight-lift rows: `{LIFT_GRASP}` (480 x 640, one camera)." if lift is not None else "."),
        "",
        "| detector | pushes | p50 ms | p99 ms | max ms | p50 / shipped on PyTorch | p99 target 2 ms |",
        "|---|---:|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['detector']} | {r['pushes']} | {r['p50_ms']:.3f} | {r['p99_ms']:.3f} | {r['max_ms']:.2f} | "
            f"{r['p50_ms'] / rows[0]['p50_ms']:.2f}x | {'met' if r['p99_ms'] <= TARGET_P99_MS else 'missed'} |"
        )
    emit(lines, args.out)
    if args.json:
        args.json.write_text(json.dumps({"threads": args.threads, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
