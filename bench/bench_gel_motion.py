"""What the object's motion against the gel costs a live loop: per-push latency of the shipped
detectors, on one thread, on real frames, three settings side by side in one run:

1. this checkout, ``gel_motion=False`` (the motion off);
2. this checkout, ``gel_motion=True`` (the default: the object's motion against the gel in every reading);
3. a baseline commit (``--baseline``, default ``a1fcfc3``), ``gel_motion=True``, its code run from a
   temporary git worktree of that commit (removed afterwards).

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_gel_motion.py --out bench/results/avx512/gel-motion.md \\
        --json bench/results/avx512/gel-motion.json
    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_gel_motion.py --rounds 2 --passes 1   # a quick check

Cases: a GelSight Mini run (``gelsight-slip/lemon/exp_num_1``, 450 frames of 320 x 240, both fingers,
shipped ``motionnet-gelsight``; target p99 <= 3 ms per push with the motion on) and a gelsight-lift
grasp (``gelsight-lift/object001/068_00_mm``, 21 frames of 640 x 480, one finger, shipped
``shear-retention-gelsight-lift``; target p99 <= 10 ms). The shared data is found by
``slipsense.paths.data_root()`` (``$SLIPSENSE_DATA``), passed on to every worker.

Each measurement is a worker: this script in a subprocess (``--worker CASE --setting on|off
--passes N``) with ``cwd`` and ``PYTHONPATH`` set to the checkout or the baseline's worktree (it checks
that ``slipsense`` was imported from there), ``OMP_NUM_THREADS=1``, ``torch.set_num_threads(1)`` (ONNX
Runtime follows it) and ``cv2.setNumThreads(1)``. It reads the frames once with the project's reader,
makes the detector, then runs one untimed warm-up pass and ``N`` timed passes; each pass is
``det.reset()`` and the case's frames pushed from the first; it prints the milliseconds of every
timed push as JSON. The main mode runs ``--rounds`` rounds; in each, every case gets one worker per
setting, the order of the three rotating round by round, so drift of a shared machine hits all
three alike. p50 / p99 / max are over every timed push of all rounds.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SCRIPT = Path(__file__).resolve()
ROOT = SCRIPT.parent.parent

# key: (title, shipped model, files under the data root, target p99 in ms with the motion on)
CASES = {
    "mini": (
        "GelSight Mini, both fingers, shipped `motionnet-gelsight`",
        "motionnet-gelsight",
        ["gelsight-slip/lemon/exp_num_1/camera_0.avi", "gelsight-slip/lemon/exp_num_1/camera_2.avi"],
        3.0,
    ),
    "lift": (
        "gelsight-lift, one 640 x 480 finger, shipped `shear-retention-gelsight-lift`",
        "shear-retention-gelsight-lift",
        ["gelsight-lift/object001/068_00_mm"],
        10.0,
    ),
}
MINI_FRAMES = 450  # the GelSight Mini case is a 450-frame run
SETTINGS = ("off", "on", "baseline")  # baseline: the baseline's code with the motion on


# ---------------------------------------------------------------------------------------------- worker
def worker(case: str, setting: str, passes: int) -> dict:
    """One worker's measurement with the code ``slipsense`` imports from (``PYTHONPATH``/``cwd``): the
    milliseconds of every timed push, after one untimed warm-up pass."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import cv2
    import torch

    torch.set_num_threads(1)
    cv2.setNumThreads(1)

    import slipsense
    from slipsense.paths import data_root
    from slipsense.recordings.video import read_video
    from slipsense.resources import shipped_model
    from slipsense.streaming.detector import SlipDetector

    here = Path.cwd().resolve()
    imported = Path(slipsense.__file__).resolve()
    if here not in imported.parents:
        raise SystemExit(f"slipsense was imported from {imported}, not from {here}")
    _, model, files, _ = CASES[case]
    videos = [read_video(data_root() / f, expected_size=None) for f in files]
    n = len(videos[0])
    if any(len(v) != n for v in videos):
        raise SystemExit(f"{case}: the fingers' videos differ in length: {[len(v) for v in videos]}")
    if case == "mini" and n != MINI_FRAMES:
        raise SystemExit(f"{case}: {files[0]} has {n} frames, not {MINI_FRAMES}")
    frames = [tuple(np.ascontiguousarray(v[i]) for v in videos) for i in range(n)]
    det = SlipDetector.from_checkpoint(shipped_model(model), sensors=len(files), gel_motion=setting == "on")
    ms: list[float] = []
    for p in range(1 + passes):  # pass 0: warm-up, untimed
        det.reset()
        for fr in frames:
            t = time.perf_counter()
            det.push(*fr)
            dt = (time.perf_counter() - t) * 1e3
            if p:
                ms.append(dt)
    return {
        "case": case,
        "setting": setting,
        "frames": n,
        "passes": passes,
        "backend": getattr(det, "backend", None),
        "torch_threads": torch.get_num_threads(),
        "slipsense": str(imported.parent),
        "ms": [round(x, 4) for x in ms],
    }


# ------------------------------------------------------------------------------------------- main mode
def git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, check=True, capture_output=True, text=True).stdout.strip()


def run_worker(tree: Path, case: str, setting: str, passes: int, data: Path) -> dict:
    """This script's worker mode in a subprocess importing ``slipsense`` from ``tree``."""
    env = {**os.environ, "PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1", "SLIPSENSE_DATA": str(data)}
    on_off = "off" if setting == "off" else "on"
    cmd = [sys.executable, str(SCRIPT), "--worker", case, "--setting", on_off, "--passes", str(passes)]
    done = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(
            f"worker {case} / {setting} with {tree}'s code failed (exit {done.returncode}):\n"
            f"{done.stdout[-2000:]}\n{done.stderr[-4000:]}"
        )
    last = [line for line in done.stdout.splitlines() if line.startswith("{")][-1]
    return json.loads(last)


def stats(ms: list[float]) -> dict:
    a = np.asarray(ms)
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "max": float(a.max())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", default="a1fcfc3", help="commit whose code runs as the third setting")
    ap.add_argument("--rounds", type=int, default=5, help="rounds; each runs every setting once per case")
    ap.add_argument("--passes", type=int, default=3, help="timed passes per worker (after one warm-up)")
    ap.add_argument("--case", action="append", choices=list(CASES), help="only this case (repeatable)")
    ap.add_argument("--out", type=Path, default=None, help="Markdown page to write")
    ap.add_argument("--json", type=Path, default=None, help="raw numbers to write")
    ap.add_argument("--worker", choices=list(CASES), help=argparse.SUPPRESS)
    ap.add_argument("--setting", choices=("on", "off"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        if not args.setting:
            ap.error("--worker needs --setting on|off")
        print(json.dumps(worker(args.worker, args.setting, args.passes)))
        return 0
    if args.rounds < 1 or args.passes < 1:
        ap.error("--rounds and --passes must be at least 1")

    sys.path.insert(0, str(ROOT))
    from slipsense.paths import data_root

    from markdown import emit  # bench/markdown.py: run as python bench/NAME.py

    data = data_root()
    cases = args.case or list(CASES)
    head = git("rev-parse", "--short", "HEAD")
    dirty = bool(git("status", "--porcelain", "--untracked-files=no", "--", "slipsense"))
    base = git("rev-parse", "--short", f"{args.baseline}^{{commit}}")
    results = {c: {s: [] for s in SETTINGS} for c in cases}
    workers: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="bench-gel-motion-") as tmp:
        tree = Path(tmp) / "baseline"
        git("worktree", "add", "--detach", str(tree), base)
        try:
            trees = {"off": ROOT, "on": ROOT, "baseline": tree}
            for r in range(args.rounds):
                order = SETTINGS[r % 3 :] + SETTINGS[: r % 3]
                for case in cases:
                    for setting in order:
                        t0 = time.perf_counter()
                        w = run_worker(trees[setting], case, setting, args.passes, data)
                        results[case][setting] += w["ms"]
                        meta = {k: v for k, v in w.items() if k != "ms"}
                        workers.append({"round": r, **meta, "setting": setting, "ms": w["ms"]})
                        print(
                            f"round {r + 1}/{args.rounds} {case} {setting:8s}: {len(w['ms'])} pushes, "
                            f"p50 {np.percentile(w['ms'], 50):.2f} ms ({time.perf_counter() - t0:.0f} s, "
                            f"{w['backend']})",
                            file=sys.stderr,
                        )
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=ROOT, check=False)

    frames = {w["case"]: w["frames"] for w in workers}
    summary = {}
    for case in cases:
        s = {k: stats(v) for k, v in results[case].items()}
        target = CASES[case][3]
        summary[case] = {
            "title": CASES[case][0],
            "frames": frames[case],
            "backend": {w["setting"]: w["backend"] for w in workers if w["case"] == case},
            "pushes": {k: len(v) for k, v in results[case].items()},
            **s,
            "p99_on_over_off": s["on"]["p99"] / s["off"]["p99"],
            "p99_on_over_baseline": s["on"]["p99"] / s["baseline"]["p99"],
            "target_p99_ms": target,
            "meets_target": s["on"]["p99"] <= target,
        }
    cmd = "OMP_NUM_THREADS=1 python bench/bench_gel_motion.py " + " ".join(argv if argv is not None else sys.argv[1:])
    machine = f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores"
    this = f"`{head}`" + (" + uncommitted changes under slipsense/" if dirty else "")
    lines = [
        "# The object's motion against the gel in every reading: what it costs a push",
        "",
        f"`{cmd.strip()}`: this checkout {this}, baseline `{base}`; {machine}; one thread; "
        f"{time.strftime('%Y-%m-%d')}. {args.rounds} rounds x {args.passes} timed passes per setting (each worker's "
        f"first pass a warm-up, untimed), settings alternating round by round. Milliseconds per push (both "
        f"fingers' frames for two).",
        "",
        "| case | backend | frames | pushes timed | motion off: p50 / p99 / max | motion on: p50 / p99 / max "
        f"| baseline `{base}`, on: p50 / p99 / max | p99 on / off | p99 on / baseline | p99 on within target |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    fmt = lambda d: f"{d['p50']:.2f} / {d['p99']:.2f} / {d['max']:.2f}"  # noqa: E731
    for case, s in summary.items():
        lines.append(
            f"| {s['title']} | {' / '.join(sorted(set(s['backend'].values())))} | {s['frames']} | {s['pushes']['on']} | {fmt(s['off'])} | {fmt(s['on'])} "
            f"| {fmt(s['baseline'])} | {s['p99_on_over_off']:.2f}x | {s['p99_on_over_baseline']:.2f}x "
            f"| {'yes' if s['meets_target'] else 'NO'} (<= {s['target_p99_ms']:g} ms) |"
        )
    emit(lines, args.out)
    if args.json:
        doc = {
            "command": cmd.strip(),
            "commit": head,
            "uncommitted_changes": dirty,
            "baseline": base,
            "machine": machine,
            "cpu_count": os.cpu_count(),
            "date": time.strftime("%Y-%m-%d"),
            "rounds": args.rounds,
            "passes": args.passes,
            "summary": summary,
            "workers": workers,
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
