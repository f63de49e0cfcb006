"""Every report folder says what made it: provenance.json from `slipsense train|adapt --out DIR` and
from every `python -m studies` command (slipsense/provenance.py)."""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from slipsense.provenance import code_digest, out_folder

ROOT = Path(__file__).resolve().parent.parent


def test_the_out_folder_is_read_from_either_spelling(tmp_path):
    assert out_folder(["--x", "1", "--out", str(tmp_path)]) == tmp_path
    assert out_folder([f"--out={tmp_path}"]) == tmp_path
    assert out_folder(["--out", str(tmp_path / "missing")]) is None
    assert out_folder(["--out"]) is None and out_folder([]) is None


def test_the_code_digest_is_stable_and_short():
    assert code_digest() == code_digest() and len(code_digest()) == 16


def _provenance(folder: Path, command: str) -> dict:
    doc = json.loads((folder / "provenance.json").read_text())
    assert doc["command"] == command
    assert doc["commit"] and doc["machine"] and doc["date"][:2] == "20" and doc["seconds"] >= 0
    assert set(doc["versions"]) == {"python", "torch", "slipsense"}
    return doc


@pytest.mark.parametrize("failing", [False, True])
def test_a_study_records_its_command_commit_machine_date_and_time(tmp_path, failing):
    out = tmp_path / "params"
    args = ["experiment", "params", "--out", str(out), "--no-progress"] + (["--seed", "-1"] if failing else [])
    done = subprocess.run([sys.executable, "-m", "studies", *args], cwd=ROOT, capture_output=True, text=True)
    if failing:  # a command that failed leaves no record claiming a report
        assert done.returncode == 2 and not (out / "provenance.json").exists()
        return
    assert done.returncode == 0, done.stderr
    _provenance(out, "python -m studies " + " ".join(args))


def test_a_training_records_its_provenance_but_other_commands_do_not(tmp_path, grasp_recordings, cache):
    from slipsense.cli import main

    out = tmp_path / "det"
    args = ["train", "--recordings", str(grasp_recordings), "--out", str(out), "--set", "width=4", "--set",
            "features=8", "--set", "temporal=8", "--set", "lags=[1,5]", "--set", "dilations=[1,2]", "--size",
            "12x16", "--epochs", "1", "--inner-folds", "0", "--no-progress", "--threads", "1"]  # fmt: skip
    for argv in (args, ["models"]):
        old = sys.argv
        sys.argv = ["slipsense", *argv]
        try:
            with pytest.raises(SystemExit) as done:
                main()
        finally:
            sys.argv = old
        assert done.value.code in (0, None)
    _provenance(out, "slipsense " + shlex.join(args))
