"""``slipsense adapt`` on the 44 grasps of a user's own GelSight: wall time of the whole command, and
when the first candidate's figure is printed.

    .venv/bin/python bench/bench_adapt.py                       # Markdown on stdout
    .venv/bin/python bench/bench_adapt.py --size 240x320 --json adapt-bench.json

The sensor is the shared ``gelsight-lift`` grasps (5 objects, 44 grasps) with every frame resized to
``--size`` (300 x 400 by default, so no shipped detector matches it by size), frame folders with
``slip.txt`` and a ``sensor.json`` stating 30 frames/s, as a user of another GelSight records them
(``studies.grasp.derive.resized_frame_folders``; made once under ``--work``). What is timed: one
``slipsense adapt --recordings SENSOR --out OUT`` in a fresh process with an empty output folder and
an empty cache (``SLIPSENSE_CACHE`` of its own), as a user's first run. Target (issue: your sensor,
your detector): at most 5 minutes on 2 cores; the first figure within a minute.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from slipsense.paths import data_root  # noqa: E402
from studies.grasp.derive import resized_frame_folders  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="300x400", help="frame size of the derived sensor, HxW")
    ap.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "slipsense-bench-adapt")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    h, w = (int(v) for v in args.size.lower().split("x"))
    sensor = args.work / f"lift-{h}x{w}"
    if not (sensor / "sensor.json").is_file():
        resized_frame_folders(data_root() / "gelsight-lift", sensor, size=(h, w), progress=True)
    out, cache = args.work / "out", args.work / "cache"
    for d in (out, cache):
        shutil.rmtree(d, ignore_errors=True)
    env = {**os.environ, "SLIPSENSE_CACHE": str(cache)}
    cmd = [
        sys.executable,
        "-m",
        "slipsense.cli",
        "adapt",
        "--recordings",
        str(sensor),
        "--out",
        str(out),
        "--no-progress",
    ]
    t0 = time.perf_counter()
    first = None
    lines = []
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env) as proc:
        for line in proc.stdout:
            lines.append(line.rstrip())
            if first is None and "% (95% range" in line:
                first = time.perf_counter() - t0
    total = time.perf_counter() - t0
    doc = json.loads((out / "adapt.json").read_text())
    kept = doc.get("kept", {}).get("measure", {}).get("operating_point", {})
    result = {
        "command": " ".join(cmd[2:]),
        "size": [h, w],
        "seconds": round(total, 1),
        "first_figure_s": None if first is None else round(first, 1),
        "target_s": 300,
        "ratio_to_target": round(total / 300, 2),
        "chosen": doc.get("chosen"),
        "kept_accuracy": kept.get("accuracy", {}).get("value"),
        "cores": os.cpu_count(),
    }
    print("| sensor | adapt, seconds | first figure, seconds | of the 5-minute target | kept | nested accuracy |")
    print("|---|---:|---:|---:|---|---:|")
    acc = result["kept_accuracy"]
    print(
        f"| gelsight-lift at {h} x {w}, 44 grasps | {total:.0f} | {first or float('nan'):.0f} | "
        f"{result['ratio_to_target']:.2f} | {result['chosen']} | {'-' if acc is None else f'{100 * acc:.0f}%'} |"
    )
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return proc.returncode


if __name__ == "__main__":
    raise SystemExit(main())
