"""``slipsense evaluate --recordings gelsight-slip`` (the shipped detector judged on the 150 shared
runs) timed side by side with another commit of this repository, as a ratio.

    .venv/bin/python bench/bench_evaluate.py                       # this tree against HEAD
    .venv/bin/python bench/bench_evaluate.py --baseline HEAD~1 --rounds 5 --json evaluate.json

The baseline commit is checked out into a temporary git worktree and run with the same Python and
the same cache (``$SLIPSENSE_CACHE``), so both read frames and labels from warm caches; one untimed
run of each warms them first. Rounds alternate the two (the machine may be shared) and the median of
each is compared: ``ratio`` = this tree's seconds over the baseline's (below 1: faster). What is timed
is the whole command as a user runs it: imports, opening the detector, scanning the folder, labels,
the replay of every run, every measure, the summary.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _data() -> Path:
    return Path(os.environ.get("SLIPSENSE_DATA", ROOT.parent / "shared" / "data"))


def timed(tree: Path, recordings: Path) -> float:
    """Seconds of one ``slipsense evaluate`` run with ``tree``'s code."""
    env = {**os.environ, "PYTHONPATH": str(tree), "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")}
    cmd = [sys.executable, "-m", "slipsense.cli", "evaluate", "--recordings", str(recordings), "--no-progress"]
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, cwd=tree, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline", default="HEAD", help="the commit to compare with (default: HEAD)")
    parser.add_argument("--rounds", type=int, default=3, help="timed runs of each, alternating")
    parser.add_argument("--recordings", type=Path, default=None, help="default: the shared gelsight-slip runs")
    parser.add_argument("--json", type=Path, default=None, help="write the times and the ratio here")
    args = parser.parse_args()
    recordings = args.recordings or _data() / "gelsight-slip"
    rev = subprocess.run(
        ["git", "rev-parse", "--short", args.baseline], cwd=ROOT, check=True, capture_output=True, text=True
    ).stdout.strip()
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp) / "baseline"
        subprocess.run(
            ["git", "worktree", "add", "--detach", str(base), rev], cwd=ROOT, check=True, capture_output=True
        )
        try:
            trees = {"baseline": base, "this tree": ROOT}
            for tree in trees.values():
                timed(tree, recordings)  # warm the caches, untimed
            times: dict[str, list[float]] = {name: [] for name in trees}
            for _ in range(args.rounds):
                for name, tree in trees.items():
                    times[name].append(timed(tree, recordings))
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(base)], cwd=ROOT, check=False)
    median = {name: statistics.median(t) for name, t in times.items()}
    ratio = median["this tree"] / median["baseline"]
    print(f"slipsense evaluate --recordings {recordings.name} ({args.rounds} rounds, median seconds)")
    print(f"  baseline {rev}: {median['baseline']:.1f} s  {[round(t, 1) for t in times['baseline']]}")
    print(f"  this tree:    {median['this tree']:.1f} s  {[round(t, 1) for t in times['this tree']]}")
    print(f"  ratio (this tree / baseline): {ratio:.3f}")
    if args.json is not None:
        doc = {"baseline": rev, "recordings": recordings.name, "seconds": times, "median": median, "ratio": ratio}
        args.json.write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
