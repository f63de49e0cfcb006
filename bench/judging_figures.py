"""Do the figures of ``slipsense evaluate`` hold? The shipped detectors judged on the shared
``gelsight-slip`` runs, the ``gelsight-lift`` grasps and a frame-folder copy of them (resized to 300 x 400,
``python -m studies grasp resize``), compared figure by figure with the references in
``reports/judging-figures/`` (written by an earlier commit with ``--write``).

Every figure of a reference must come out the same (NaN equal to NaN); figures a newer evaluation adds
(a new measure) are listed, not compared.

    python bench/judging_figures.py            # compare; exit 1 on any figure that moved
    python bench/judging_figures.py --write    # make the references anew (a change that moves figures on purpose)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REFERENCES = ROOT / "reports" / "judging-figures"


def _data() -> Path:
    return Path(os.environ.get("SLIPSENSE_DATA", ROOT.parent / "shared" / "data"))


def _leaves(x, path=""):
    if isinstance(x, dict):
        for k, v in x.items():
            yield from _leaves(v, f"{path}/{k}")
    elif isinstance(x, list):
        for i, v in enumerate(x):
            yield from _leaves(v, f"{path}/{i}")
    else:
        yield path, x


def _same(a, b) -> bool:
    nan = lambda v: isinstance(v, float) and math.isnan(v)  # noqa: E731
    return a == b or (nan(a) and nan(b))


def compare(reference: dict, got: dict) -> tuple[list[str], list[str]]:
    """``(moved, added)``: the reference's figures that differ or are gone, and the new top-level keys."""
    ref, new = dict(_leaves(reference)), dict(_leaves(got))
    moved = [f"{k}: {ref[k]!r} -> {new.get(k, 'gone')!r}" for k in ref if k not in new or not _same(ref[k], new[k])]
    return moved, sorted({k for k in got} - {k for k in reference})


def _evaluate(recordings: Path, out: Path) -> dict:
    cmd = [sys.executable, "-m", "slipsense.cli", "evaluate", "--recordings", str(recordings), "--json", str(out)]
    subprocess.run([*cmd, "--no-progress"], check=True, stdout=subprocess.DEVNULL)
    return json.loads(out.read_text())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", action="store_true", help="write the references instead of comparing")
    args = parser.parse_args()
    data = _data()
    failed = False
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / "gelsight-lift-300x400"
        subprocess.run(
            [sys.executable, "-m", "studies", "grasp", "resize", "--out", str(copy), "--no-progress"],
            cwd=ROOT,
            check=True,
            stdout=subprocess.DEVNULL,
        )
        for name, folder in (
            ("gelsight-slip", data / "gelsight-slip"),
            ("gelsight-lift", data / "gelsight-lift"),
            (copy.name, copy),
        ):
            got = _evaluate(folder, Path(tmp) / f"{name}.json")
            got["recordings"] = name  # where it lay: not a figure
            for rate in got.get("frame_rate", {}).get("recordings", []):  # a sensor.json's path, likewise
                rate["from"] = rate["from"].replace(str(folder), name)
            reference = REFERENCES / f"{name}.json"
            if args.write:
                REFERENCES.mkdir(parents=True, exist_ok=True)
                reference.write_text(json.dumps(got, indent=1, default=float) + "\n")
                print(f"{name}: written {reference.relative_to(ROOT)}")
                continue
            moved, added = compare(json.loads(reference.read_text()), got)
            failed |= bool(moved)
            figures = len(dict(_leaves(json.loads(reference.read_text()))))
            print(
                f"{name}: {figures - len(moved)} of {figures} figures the same"
                + (f"; new: {', '.join(added)}" if added else "")
            )
            for line in moved[:20]:
                print(f"  moved {line}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
