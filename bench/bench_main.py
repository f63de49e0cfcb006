"""The README's first command, ``bash scripts/main.sh``, on a fresh clone with empty caches: its phases
timed, side by side with another commit's.

    .venv/bin/python bench/bench_main.py --baseline 89300cf --json reports-bench-main.json

Each side is a ``git clone`` of the commit (beside a link to the shared data, as a checkout is) with no
``.venv`` and its own empty ``SLIPSENSE_CACHE``; ``scripts/main.sh`` runs traced (``set -x``) with a
clock in its trace prompt, so each phase's start is read from the trace: set-up (``scripts/setup.sh``:
the virtual environment and pip), ``label``, ``train`` (the inner folds and the final model: one
command) and ``evaluate`` (the held-out objects, per grasp and per clip). The two sides run one after
the other on the same machine; the ratio (baseline seconds over this tree's: above 1, this tree is
faster) is the figure to compare across days, not the seconds. Target (issue "The first run in three
minutes"): 180 s on 2 cores, a ratio of at least 2.5 against ``89300cf``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: the phases of scripts/main.sh, by the command that starts each
PHASES = {
    "set-up": "scripts/setup.sh",
    "label": "slipsense label",
    "train": "slipsense train",
    "evaluate": "slipsense evaluate",
}


def shared_data() -> Path:
    return Path(os.environ.get("SLIPSENSE_DATA", ROOT.parent / "shared" / "data")).resolve()


def run_main(rev: str, work: Path) -> dict:
    """``bash scripts/main.sh`` in a fresh clone of ``rev`` under ``work``: total seconds and per phase."""
    (work / "shared").symlink_to(shared_data().parent)
    clone = work / "main"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    subprocess.run(["git", "checkout", "-q", "--detach", rev], cwd=clone, check=True)
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH")}
    env.update(SLIPSENSE_CACHE=str(work / "cache"), SLIPSENSE_DATA=str(work / "shared" / "data"))
    # the trace prompt set inside: bash run as root ignores a PS4 from the environment
    traced = r'PS4="+@\$EPOCHREALTIME "; set -x; . scripts/main.sh'
    t0 = time.time()
    done = subprocess.run(["bash", "-c", traced, "scripts/main.sh"], cwd=clone, env=env, capture_output=True, text=True)
    total = time.time() - t0
    if done.returncode != 0:
        raise SystemExit(f"main.sh of {rev} failed ({done.returncode}): {done.stderr[-2000:]}")
    starts = {}
    for line in done.stderr.splitlines():
        m = re.match(r"^\++@(\d+\.\d+) (.*)$", line)
        if m:
            for phase, words in PHASES.items():
                if phase not in starts and words in m.group(2):
                    starts[phase] = float(m.group(1))
    order = sorted(starts, key=starts.get)
    ends = [starts[p] for p in order[1:]] + [t0 + total]
    phases = {p: round(end - starts[p], 1) for p, end in zip(order, ends)}
    return {"commit": rev, "seconds": round(total, 1), "phases": phases}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", default="89300cf", help="the commit to run side by side (default 89300cf)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    head = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
    ).stdout.strip()
    results = {}
    for name, rev in (("baseline", args.baseline), ("this tree", head)):
        with tempfile.TemporaryDirectory() as tmp:
            results[name] = run_main(rev, Path(tmp))
    phases = list(PHASES)
    print(f"| code | main.sh, seconds | {' | '.join(phases)} |")
    print("|---|---:|" + "---:|" * len(phases))
    for name, r in results.items():
        cells = " | ".join(str(r["phases"].get(p, "-")) for p in phases)
        print(f"| {name} ({r['commit']}) | {r['seconds']} | {cells} |")
    ratio = results["baseline"]["seconds"] / results["this tree"]["seconds"]
    print(f"ratio (baseline / this tree): {ratio:.2f}  (target: this tree at most 180 s, ratio at least 2.5)")
    if args.json:
        doc = {"results": results, "ratio": round(ratio, 3), "cores": os.cpu_count(), "target_s": 180}
        args.json.write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
