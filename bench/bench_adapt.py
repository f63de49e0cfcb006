"""``slipsense adapt`` on the 44 grasps of a user's own GelSight: wall time of the whole command, and
when the first candidate's figure is printed.

    .venv/bin/python bench/bench_adapt.py                       # this tree alone, Markdown on stdout
    .venv/bin/python bench/bench_adapt.py --baseline 89300cf --json adapt-bench.json   # side by side

The sensor is the shared ``gelsight-lift`` grasps (5 objects, 44 grasps) with every frame resized to
``--size`` (300 x 400 by default, so no shipped detector matches it by size), frame folders with
``slip.txt`` and a ``sensor.json`` stating 30 frames/s, as a user of another GelSight records them
(``studies.grasp.derive.resized_frame_folders``; made once under ``--work``). What is timed: one
``slipsense adapt --recordings SENSOR --out OUT`` in a fresh process with an empty output folder and
an empty cache (``SLIPSENSE_CACHE`` of its own), as a user's first run. Target (issue: your sensor,
your detector): at most 5 minutes on 2 cores; the first figure within a minute.

With ``--baseline COMMIT`` the same command runs with that commit's code too (a temporary git worktree,
``PYTHONPATH`` to it), one after the other on the same machine, each with an empty cache: the ratio
(this tree's seconds over the baseline's) is the figure to compare across days, not the seconds.
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


def run_adapt(tree: Path, sensor: Path, work: Path) -> dict:
    """One ``slipsense adapt`` of ``sensor`` with ``tree``'s code, an empty output folder and cache:
    its seconds, when its first figure came, what it kept."""
    out, cache = work / "out", work / "cache"
    for d in (out, cache):
        shutil.rmtree(d, ignore_errors=True)
    env = {**os.environ, "SLIPSENSE_CACHE": str(cache), "PYTHONPATH": str(tree)}
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
    t0, first = time.perf_counter(), None
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=tree) as proc:
        for line in proc.stdout:
            if first is None and "% (95% range" in line:
                first = time.perf_counter() - t0
    total = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"adapt failed with {tree}'s code (exit {proc.returncode})")
    doc = json.loads((out / "adapt.json").read_text())
    kept = doc.get("kept", {}).get("measure", {}).get("operating_point", {})
    return {
        "seconds": round(total, 1),
        "first_figure_s": None if first is None else round(first, 1),
        "chosen": doc.get("chosen"),
        "kept_accuracy": kept.get("accuracy", {}).get("value"),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="300x400", help="frame size of the derived sensor, HxW")
    ap.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "slipsense-bench-adapt")
    ap.add_argument("--baseline", default=None, help="a commit to run side by side (e.g. 89300cf)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    h, w = (int(v) for v in args.size.lower().split("x"))
    sensor = args.work / f"lift-{h}x{w}"
    if not (sensor / "sensor.json").is_file():
        resized_frame_folders(data_root() / "gelsight-lift", sensor, size=(h, w), progress=True)
    trees = {"this tree": ROOT}
    base = None
    if args.baseline:
        base = Path(tempfile.mkdtemp()) / "baseline"
        subprocess.run(["git", "worktree", "add", "--detach", str(base), args.baseline], cwd=ROOT, check=True,
                       capture_output=True)  # fmt: skip
        trees = {f"baseline {args.baseline}": base, **trees}
    try:
        results = {name: run_adapt(tree, sensor, args.work) for name, tree in trees.items()}
    finally:
        if base is not None:
            subprocess.run(["git", "worktree", "remove", "--force", str(base)], cwd=ROOT, check=False)
    print("| code | adapt, seconds | first figure, seconds | of the 5-minute target | kept | nested accuracy |")
    print("|---|---:|---:|---:|---|---:|")
    for name, r in results.items():
        acc, first = r["kept_accuracy"], r["first_figure_s"]
        print(
            f"| {name} | {r['seconds']:.0f} | {'-' if first is None else f'{first:.0f}'} | {r['seconds'] / 300:.2f} | "
            f"{r['chosen']} | {'-' if acc is None else f'{100 * acc:.0f}%'} |"
        )
    doc = {"size": [h, w], "grasps": 44, "target_s": 300, "cores": os.cpu_count(), "results": results}
    if args.baseline:
        doc["ratio"] = round(results["this tree"]["seconds"] / results[f"baseline {args.baseline}"]["seconds"], 3)
        print(f"ratio (this tree / baseline {args.baseline}): {doc['ratio']:.3f}")
    if args.json:
        args.json.write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
