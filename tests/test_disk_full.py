"""A disk that fills up while a checkpoint is written: one line naming the file and exit 2, never a
traceback from safetensors; no temporary file left behind; and ``--resume`` once there is space
again ends with the weights of a training that never stopped."""

from __future__ import annotations

import errno
from pathlib import Path

import numpy as np
import pytest
import safetensors.torch
from safetensors import SafetensorError
from safetensors.torch import load_file
from typer.testing import CliRunner

from conftest import TINY_TRAIN_ARGS
from slipsense.atomic import write_with
from slipsense.cli import app
from slipsense.errors import OutputError

runner = CliRunner()

#: what safetensors raises for a full disk: 0.5 and later, and before
ENOSPC_ERRORS = {
    "safetensors": lambda tmp: SafetensorError(
        f'Error while serializing: I/O error: No space left on device (os error 28) at path "{tmp.parent}/.tmpX1"'
    ),
    "safetensors-old": lambda tmp: SafetensorError(
        'Error while serializing: IoError(Os { code: 28, kind: StorageFull, message: "No space left on device" })'
    ),
    "oserror": lambda tmp: OSError(errno.ENOSPC, "No space left on device"),
}


def _markers(path):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(24, 4, 5, 3)).astype(np.float32)
    np.savez(path, x=x, y=np.arange(24) % 2, groups=np.arange(24) // 2)
    return path


def _train(markers, out, *extra):
    args = ["train", *TINY_TRAIN_ARGS, "--markers", markers, "--out", out, "--epochs", "3", "--seed", "0", *extra]
    return runner.invoke(app, [str(a) for a in args])


def _temporaries(folder):
    return sorted(p.name for p in folder.rglob("*") if ".tmp" in p.name or p.name.startswith(".slipsense"))


@pytest.mark.parametrize("error", sorted(ENOSPC_ERRORS))
def test_full_disk_while_writing_a_checkpoint_is_one_line_and_resume_gives_the_same_weights(
    error, tmp_path, monkeypatch, cache, one_thread
):
    markers = _markers(tmp_path / "m.npz")
    whole = _train(markers, tmp_path / "whole")
    assert whole.exit_code == 0, whole.output

    real_save = safetensors.torch.save_file
    calls = []

    def save_file(tensors, filename, metadata=None):
        """The disk is full at the second epoch's checkpoint: half a file written, then the error."""
        calls.append(Path(filename).name)
        if sum(name.startswith(".last.") for name in calls) == 2:  # the second epoch's last.safetensors
            with open(filename, "wb") as fh:
                fh.write(b"\0" * 100)
            raise ENOSPC_ERRORS[error](tmp_path / "cut")
        return real_save(tensors, filename, metadata=metadata)

    monkeypatch.setattr(safetensors.torch, "save_file", save_file)
    cut = tmp_path / "cut"
    result = _train(markers, cut)
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output and isinstance(result.exception, SystemExit)
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert errors == [f"error: {cut / 'last.safetensors'}: cannot be written (No space left on device)"]
    assert _temporaries(cut) == []
    assert (cut / "resume.pt").exists()  # the first epoch's, whole

    monkeypatch.setattr(safetensors.torch, "save_file", real_save)  # space freed
    resumed = _train(markers, cut, "--resume")
    assert resumed.exit_code == 0, resumed.output
    a, b = load_file(tmp_path / "whole" / "last.safetensors"), load_file(cut / "last.safetensors")
    assert a.keys() == b.keys() and all((a[k] == b[k]).all() for k in a)
    assert _temporaries(cut) == []


@pytest.mark.parametrize("error", sorted(ENOSPC_ERRORS))
def test_a_failed_write_names_the_final_path_and_leaves_no_temporary(error, tmp_path):
    (tmp_path / "x.safetensors").write_bytes(b"old")

    def writer(tmp):
        tmp.write_bytes(b"half")
        raise ENOSPC_ERRORS[error](tmp)

    with pytest.raises(OutputError) as caught:
        write_with(tmp_path / "x.safetensors", writer)
    assert str(caught.value) == f"{tmp_path / 'x.safetensors'}: cannot be written (No space left on device)"
    assert (tmp_path / "x.safetensors").read_bytes() == b"old"  # the old file intact
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.safetensors"]


def test_other_errors_of_a_writer_are_not_taken_for_a_full_disk(tmp_path):
    def writer(tmp):
        raise ValueError("a bug")

    with pytest.raises(ValueError, match="a bug"):
        write_with(tmp_path / "x.safetensors", writer)
    assert list(tmp_path.iterdir()) == []
