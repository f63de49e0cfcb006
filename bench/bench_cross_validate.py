"""The shipped recipe's 5-fold cross-validation, wall time, side by side with another commit.

    .venv/bin/python bench/bench_cross_validate.py --baseline 89300cf --out bench/results/avx512/cross-validate.md

What is timed: ``slipsense train --cross-validate --folds 5 --config configs/motionnet.yaml --workers 2``
on the shared GelSight Mini recordings, in a fresh process with an empty output folder and an empty
cache (``SLIPSENSE_CACHE`` of its own: labelling and frame decoding included, as a user's first run),
first with the baseline commit's code (a temporary git worktree, ``PYTHONPATH`` to it, its own
``configs/motionnet.yaml``), then with this tree's, one after the other on the same machine. The ratio
(baseline's seconds over this tree's) is the figure to compare across days; the pooled per-grasp
figures of both are printed beside it, so a change of what training produces shows.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from slipsense.paths import data_root  # noqa: E402

from markdown import emit  # bench/markdown.py: run as python bench/NAME.py


def run_folds(tree: Path, work: Path) -> dict:
    """One cross-validation with ``tree``'s code: its seconds and pooled per-grasp figures."""
    out, cache = work / "out", work / "cache"
    for d in (out, cache):
        shutil.rmtree(d, ignore_errors=True)
    env = {**os.environ, "SLIPSENSE_CACHE": str(cache), "PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1"}
    env["SLIPSENSE_DATA"] = str(data_root())  # the baseline's worktree has no shared data beside it
    cmd = [sys.executable, "-m", "slipsense.cli", "train", "--cross-validate", "--folds", "5"]
    cmd += ["--config", "configs/motionnet.yaml", "--workers", "2", "--out", str(out), "--no-progress"]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=tree)
    seconds = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"{tree}: exit {done.returncode}\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}")
    g = json.loads((out / "folds.json").read_text())["pooled"]["per_grasp"]
    keys = ("warned", "slip_runs", "premature", "false_positive_grasps", "held_runs")
    return {"seconds": seconds, **{k: g[k] for k in keys}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", required=True, help="commit to compare with")
    ap.add_argument("--out", type=Path, default=None, help="Markdown table to write")
    args = ap.parse_args()
    git = lambda *a: subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True, check=True).stdout.strip()  # noqa: E731
    head = git("rev-parse", "--short", "HEAD")
    with tempfile.TemporaryDirectory(prefix="bench-cv-") as tmp:
        tmp = Path(tmp)
        base_tree = tmp / "baseline"
        git("worktree", "add", "--detach", str(base_tree), args.baseline)
        try:
            results = {args.baseline: run_folds(base_tree, tmp / "b"), head: run_folds(ROOT, tmp / "h")}
        finally:
            git("worktree", "remove", "--force", str(base_tree))
    base, now = results[args.baseline], results[head]
    lines = [
        "# The shipped recipe's 5-fold cross-validation, side by side",
        "",
        f"`python bench/bench_cross_validate.py --baseline {args.baseline}`: {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} cores, {time.strftime('%Y-%m-%d')}; `--workers 2`, empty caches, one after the other.",
        "",
        "| code | seconds | slips warned in time | premature | held grasps alarming |",
        "|---|---:|---:|---:|---:|",
    ]
    for commit, r in results.items():
        lines.append(
            f"| `{commit}` | {r['seconds']:.0f} | {r['warned']} of {r['slip_runs']} | {r['premature']} "
            f"| {r['false_positive_grasps']} of {r['held_runs']} |"
        )
    lines += ["", f"Ratio (`{args.baseline}` over `{head}`): {base['seconds'] / now['seconds']:.2f}x faster now."]
    emit(lines, args.out)


if __name__ == "__main__":
    main()
