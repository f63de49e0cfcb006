"""Training loop: DDP equivalence of grasp training, resume after SIGKILL, checkpoints and their errors
(clip training under torchrun: tests/test_reliability_ddp.py)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from slipsense.checkpoint import load_model, read_info, save_checkpoint
from slipsense.errors import ConfigError, InputError
from slipsense.training.clips import TrainConfig

SCRIPT = Path(__file__).parent / "support" / "tiny_train.py"


def _script(script, args) -> None:
    import runpy

    torch.set_num_threads(1)
    sys.path.insert(0, str(script.parent))
    sys.argv = [str(script), *args]
    runpy.run_path(str(script), run_name="__main__")


def _run(args, torchrun=False, check=True, script=SCRIPT) -> int:
    """Run ``script`` (tiny_train.py) with ``args``: under torchrun (2 fresh processes), else in a forked
    process (torch already imported: seconds saved per run). Returns the exit code (negative: killed)."""
    args = [str(a) for a in args]
    if not torchrun:
        import multiprocessing

        proc = multiprocessing.get_context("fork").Process(target=_script, args=(script, args))
        proc.start()
        proc.join(240)
        if check and proc.exitcode != 0:
            raise AssertionError(f"{script.name} {' '.join(args)} failed ({proc.exitcode})")
        return proc.exitcode
    env = {**os.environ, "PYTHONPATH": str(script.parent), "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2", str(script), *args]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=240)
    if check and proc.returncode != 0:
        raise AssertionError(f"{cmd} failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}")
    return proc.returncode


def _weights(out):
    return torch.load(Path(out) / "final.pt")


def _assert_same(a, b, atol):
    assert a.keys() == b.keys()
    for k in a:
        torch.testing.assert_close(a[k], b[k], atol=atol, rtol=0)


def test_resume_after_sigkill_matches_uninterrupted(tmp_path):
    _run([tmp_path / "full", 16, 5])
    # 64 items per epoch: dies in the middle of epoch 4, after the epoch-3 checkpoint.
    assert _run([tmp_path / "cut", 16, 5, 64 * 3 + 40], check=False) != 0  # killed
    assert (tmp_path / "cut" / "resume.pt").exists() and not (tmp_path / "cut" / "final.pt").exists()
    assert len((tmp_path / "cut" / "metrics.csv").read_text().strip().splitlines()) == 4
    _run([tmp_path / "cut", 16, 5, "--resume"])
    _assert_same(_weights(tmp_path / "full"), _weights(tmp_path / "cut"), atol=0)
    full = (tmp_path / "full" / "metrics.csv").read_text().splitlines()
    cut = (tmp_path / "cut" / "metrics.csv").read_text().splitlines()
    strip = lambda rows: [",".join(r.split(",")[:-1]) for r in rows]  # last column: seconds
    assert strip(full) == strip(cut)


def test_checkpoint_roundtrip_and_errors(tmp_path):
    sys.path.insert(0, str(SCRIPT.parent))
    from tiny_train import TinyNet

    model = TinyNet(hidden=5)
    path = save_checkpoint(tmp_path / "m.safetensors", model, {"data": {"note": "x"}})
    info = read_info(path)
    assert info["model"] == "test-tiny" and info["model_config"]["hidden"] == 5
    loaded, _ = load_model(path)
    _assert_same(model.state_dict(), loaded.state_dict(), atol=0)

    with pytest.raises(InputError, match="expected 'vivit'"):
        load_model(path, expect_model="vivit")
    bad = tmp_path / "corrupt.safetensors"
    bad.write_bytes(path.read_bytes()[:40])
    with pytest.raises(InputError, match="corrupt.safetensors"):
        load_model(bad)
    trunc = tmp_path / "trunc.safetensors"
    trunc.write_bytes(path.read_bytes()[:-8])
    with pytest.raises(InputError, match="trunc.safetensors"):
        load_model(trunc)
    with pytest.raises(InputError, match="not found"):
        load_model(tmp_path / "missing.safetensors")
    # Same model name, other sizes: the weights do not fit the config the file claims.
    from safetensors.torch import save_file

    meta = {"slipsense": json.dumps({"model": "test-tiny", "model_config": {"hidden": 5}})}
    save_file(
        {k: v.contiguous() for k, v in TinyNet(hidden=7).state_dict().items()},
        str(tmp_path / "misfit.safetensors"),
        metadata=meta,
    )
    with pytest.raises(InputError, match="misfit.safetensors: weight .* has shape"):
        load_model(tmp_path / "misfit.safetensors")
    save_file({"w": torch.zeros(2)}, str(tmp_path / "foreign.safetensors"))
    with pytest.raises(InputError, match="not a slipsense checkpoint"):
        load_model(tmp_path / "foreign.safetensors")


def test_train_config_rejects_bad_values():
    with pytest.raises(ConfigError, match="unknown keys"):
        TrainConfig.from_dict({"epochz": 3})
    for bad in ({"epochs": 0}, {"lr": -1.0}, {"gamma": 2.0}, {"batch_size": 0}, {"lr": float("nan")}):
        with pytest.raises(ConfigError):
            TrainConfig.from_dict(bad)


def test_pooling_folds_sums_confusions(tmp_path):
    from slipsense.training.folds import pool

    for k, cm in enumerate(([[8, 0], [2, 2]], [[5, 1], [0, 3]])):
        (tmp_path / f"f{k}").mkdir()
        m = {
            "confusion": cm,
            "accuracy": 0,
            "precision": 0,
            "recall": 0,
            "f1": 0,
            "n_clips": 0,
            "n_slip": 0,
            "n_wiggle": 0,
        }
        (tmp_path / f"f{k}" / "evaluation.json").write_text(json.dumps(m))
    out = pool([tmp_path / "f0", tmp_path / "f1"])
    assert out["pooled"]["confusion"] == [[13, 1], [2, 5]]
    assert out["pooled"]["recall"] == pytest.approx(5 / 7) and out["pooled"]["precision"] == pytest.approx(5 / 6)
    with pytest.raises(InputError, match="evaluation.json"):
        pool([tmp_path / "missing"])


def test_resume_split_check_reads_tuples_as_json_does(tmp_path):
    """A clip size given as a tuple is written to split.json as a list: the same split, not another."""
    import json

    from slipsense.errors import InputError
    from slipsense.readers import check_same_split

    info = {"kind": "video", "split": "objects", "test_objects": ["cup"], "clip_spec": {"size": (48, 64)}}
    (tmp_path / "split.json").write_text(json.dumps(info))
    check_same_split(tmp_path / "split.json", info)  # nothing changed: no error
    with pytest.raises(InputError, match="clip_spec differ"):
        check_same_split(tmp_path / "split.json", {**info, "clip_spec": {"size": (60, 80)}})
