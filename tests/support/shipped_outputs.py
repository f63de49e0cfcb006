"""The shipped detectors' per-frame outputs on a few shared runs, as ``slipsense watch --jsonl`` gives
them: written once by ``python tests/support/shipped_outputs.py OUT.json`` and compared by
tests/test_shipped_outputs.py, so a change that alters what a shipped checkpoint says is seen."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

#: (checkpoint file in slipsense/resources/models, run relative to $SLIPSENSE_DATA, frames at most)
CASES = [
    ("motionnet-gelsight.safetensors", "gelsight-slip/ball_white_thread/exp_num_9", None),
    ("motionnet-gelsight-1.safetensors", "gelsight-slip/lemon/exp_num_1/camera_0.avi", None),
    ("vivit-gelsight.safetensors", "gelsight-slip/avocado_real/exp_num_1/camera_2.avi", 40),
    ("shear-retention-gelsight-lift.safetensors", "gelsight-lift/object001/066_60_mm", None),
]


def outputs(data: Path, models: Path, python: str = sys.executable) -> dict[str, dict]:
    """Every case's readings: ``{"<checkpoint> <run>": {"p": [...], "alarm": [...]}}`` (PyTorch backend)."""
    found = {}
    with tempfile.TemporaryDirectory() as tmp:
        for ckpt, run, limit in CASES:
            out = Path(tmp) / "r.jsonl"
            args = [python, "-m", "slipsense.cli", "watch", str(data / run), "--checkpoint", str(models / ckpt)]
            args += ["--backend", "torch", "--jsonl", str(out), "--quiet", "--threads", "1"]
            args += ["--max-frames", str(limit)] if limit else []
            subprocess.run(args, check=True, capture_output=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
            rows = [json.loads(line) for line in out.read_text().splitlines()]
            found[f"{ckpt} {run}"] = {
                "p": [None if r["probability"] is None else round(r["probability"], 6) for r in rows],
                "alarm": [bool(r["alarm"]) for r in rows],
            }
    return found


if __name__ == "__main__":
    here = Path(__file__).resolve().parents[2]
    data = Path(os.environ.get("SLIPSENSE_DATA", here.parent / "shared" / "data"))
    doc = outputs(data, here / "slipsense" / "resources" / "models")
    Path(sys.argv[1]).write_text(json.dumps(doc, separators=(",", ":")) + "\n")
