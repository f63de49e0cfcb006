"""`slipsense grasp train|folds` and `early-warning` with a grasp detector, on small made-up recordings."""

import json

import pytest
from typer.testing import CliRunner

from slipsense.cli import app
from studies.__main__ import app as studies_app

SMALL = [
    "--set",
    "width=4",
    "--set",
    "features=8",
    "--set",
    "temporal=8",
    "--set",
    "lags=[1,5,10]",
    "--set",
    "dilations=[1,2,4]",
    "--set",
    "chunk=16",
    "--set",
    "negatives=1",
    "--set",
    "hard_negatives=1",
    "--size",
    "12x16",
    "--epochs",
    "2",
    "--no-progress",
    "--threads",
    "1",
]


@pytest.fixture(scope="module")
def grasps(grasp_recordings):
    return grasp_recordings


def test_grasp_train_then_early_warning(tmp_path, grasps, monkeypatch):
    monkeypatch.setenv("SLIPSENSE_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "det"
    res = CliRunner().invoke(
        app,
        [
            "train",
            "--out",
            str(out),
            "--recordings",
            str(grasps),
            "--fold",
            "0",
            "--folds",
            "2",
            "--inner-folds",
            "2",
            *SMALL,
        ],
    )
    assert res.exit_code == 0, res.output
    assert "held-out objects" in res.output and "slips warned in time" in res.output
    from slipsense.checkpoint import read_info

    info = read_info(out / "detector.safetensors")
    assert info["model"] == "motionnet" and 0 <= info["operating_point"]["threshold"] <= 1
    assert info["train_config"]["epochs"] == 2 and info["data"]["held_out_objects"]
    assert (out / "curves.png").exists() and (out / "metrics.csv").read_text().count("\n") == 3
    held = json.loads((out / "held_out.json").read_text())
    assert held["per_grasp"]["slip_runs"] + held["per_grasp"]["held_runs"] == 4
    ew = tmp_path / "ew"
    res = CliRunner().invoke(
        studies_app,
        [
            "grasp",
            "early-warning",
            "--checkpoint",
            str(out / "detector.safetensors"),
            "--recordings",
            str(grasps),
            "--out",
            str(ew),
            "--no-progress",
        ],
    )
    assert res.exit_code == 0, res.output
    assert "checkpoint's operating point" in res.output
    gif = tmp_path / "run.gif"
    res = CliRunner().invoke(
        app,
        [
            "watch",
            str(grasps / "obj0" / "exp_num_1"),
            "--checkpoint",
            str(out / "detector.safetensors"),
            "--out",
            str(gif),
            "--max-frames",
            "15",
        ],
    )
    assert res.exit_code == 0, res.output
    assert gif.read_bytes()[:3] == b"GIF" and "filling window" in res.output
    doc = json.loads((ew / "early_warning.json").read_text())
    assert doc["operating_point"]["threshold"] == info["operating_point"]["threshold"]
    assert len(doc["runs"]) == 8
    # `slipsense evaluate` judges a grasp detector per grasp, with the same outcomes as early-warning
    ev = tmp_path / "eval.json"
    args = ["evaluate", "--checkpoint", str(out / "detector.safetensors"), "--recordings", str(grasps)]
    res = CliRunner().invoke(app, [*args, "--json", str(ev), "--no-progress"])
    assert res.exit_code == 0, res.output
    got = json.loads(ev.read_text())
    assert got["threshold"] == info["operating_point"]["threshold"] and len(got["runs"]) == 8
    assert got["per_grasp"]["slip_runs"] == 4 and got["per_grasp"]["held_runs"] == 4
    clips = got["clips"]["operating_point"]  # the papers' clip protocol on the same traces
    assert clips["slip_clips"] == 8 and clips["clips"] > 8 and 0 < clips["always_wiggle_accuracy"] < 1
    assert "warned in time" in res.output and "calling every clip no-slip would be right on" in res.output
    res = CliRunner().invoke(app, [*args[:3], "--split-file", str(ev), "--json", str(tmp_path / "e2.json")])
    assert res.exit_code == 2 and "holds a grasp detector" in res.output


def test_grasp_folds_resume(tmp_path, grasps, monkeypatch):
    monkeypatch.setenv("SLIPSENSE_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "folds"
    args = [
        "train",
        "--cross-validate",
        "--out",
        str(out),
        "--recordings",
        str(grasps),
        "--folds",
        "2",
        "--inner-folds",
        "0",
        *SMALL,
    ]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    rep = json.loads((out / "folds.json").read_text())
    assert rep["pooled"]["per_grasp"]["slip_runs"] == 4 and rep["pooled"]["per_grasp"]["held_runs"] == 4
    assert rep["pooled"]["clips"]["always_wiggle_accuracy"] is not None
    assert (out / "README.md").read_text().startswith("# motionnet") and (out / "tradeoff.png").exists()
    before = (out / "fold0.json").stat().st_mtime_ns
    res = CliRunner().invoke(app, args)  # a rerun reuses the finished folds
    assert res.exit_code == 0 and (out / "fold0.json").stat().st_mtime_ns == before


def test_grasp_folds_choose_settings_on_each_folds_training_objects(tmp_path, grasps, monkeypatch):
    """`train.choose` under folds: each fold tries every setting on its own training objects (inner
    folds), keeps one, and its fold file keeps the inner traces of the setting it kept."""
    monkeypatch.setenv("SLIPSENSE_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "folds"
    args = [
        "train",
        "--cross-validate",
        "--out",
        str(out),
        "--recordings",
        str(grasps),
        "--folds",
        "2",
        "--inner-folds",
        "2",
    ]
    res = CliRunner().invoke(app, [*args, *SMALL, "--epochs", "1", "--set", 'train.choose={"width": [2, 4]}'])
    assert res.exit_code == 0, res.output
    for k, fold in enumerate(json.loads((out / "folds.json").read_text())["per_fold"]):
        op = fold["operating_point"]
        assert [t["settings"]["width"] for t in op["tried"]] == [2, 4] and op["settings"]["width"] in (2, 4)
        inner = json.loads((out / f"fold{k}.json").read_text())["inner"]
        runs = [(r["object"], r["experiment"], tuple(r["cameras"])) for r in inner]
        assert len(runs) == len(set(runs)) > 0  # one trace per training run (the kept setting's: chosen_part)
    # the kept setting's inner traces: the same rule chosen again on them gives each fold's point back
    res = CliRunner().invoke(
        studies_app, ["grasp", "rechoose", str(out), "--out", str(tmp_path / "again"), "--max-held-alarm", "-1"]
    )
    assert res.exit_code == 0, res.output
    again = json.loads((tmp_path / "again" / "folds.json").read_text())["per_fold"]
    folds = json.loads((out / "folds.json").read_text())["per_fold"]
    assert [f["operating_point"]["threshold"] for f in again] == [f["operating_point"]["threshold"] for f in folds]


def test_grasp_bad_settings_one_line(tmp_path, grasps):
    for extra in (["--set", "width=100000"], ["--set", "epochs=-1"], ["--fold", "7"], ["--set", "nonsense=1"]):
        res = CliRunner().invoke(
            app, ["train", "--out", str(tmp_path / "x"), "--recordings", str(grasps), "--no-progress", *extra]
        )
        assert res.exit_code == 2, (extra, res.output)
        assert res.output.strip().startswith("error:") and "Traceback" not in res.output


def test_grasp_folds_same_results_on_one_or_two_workers(tmp_path, grasps, monkeypatch):
    """Each training is one seeded single-thread job: where it ran does not change a number."""
    monkeypatch.setenv("SLIPSENSE_CACHE", str(tmp_path / "cache"))
    docs = []
    for workers in ("1", "2"):
        out = tmp_path / f"folds-{workers}"
        args = ["train", "--cross-validate", "--out", str(out), "--recordings", str(grasps), "--folds", "2"]
        res = CliRunner().invoke(app, [*args, "--inner-folds", "2", "--workers", workers, *SMALL])
        assert res.exit_code == 0, res.output
        docs.append([json.loads((out / f"fold{k}.json").read_text()) for k in (0, 1)])
    for a, b in zip(*docs):
        assert (
            a["operating_point"] == b["operating_point"]
            and a["history"][-1]["train_loss"] == b["history"][-1]["train_loss"]
        )
        assert [r["probability"] for r in a["runs"]] == [r["probability"] for r in b["runs"]]
        assert a["inner"] and len(a["inner"]) == 4  # the 4 training runs' out-of-fold traces are kept

    # another operating-point rule chosen on the kept inner traces, without training
    rep = tmp_path / "strict"
    res = CliRunner().invoke(
        studies_app, ["grasp", "rechoose", str(tmp_path / "folds-1"), "--out", str(rep), "--max-held-alarm", "0"]
    )
    assert res.exit_code == 0, res.output
    doc = json.loads((rep / "folds.json").read_text())
    assert doc["train_config"]["max_held_alarm"] == 0 and "95%" in (rep / "README.md").read_text()
    for f in doc["per_fold"]:
        assert "0% of held grasps" in f["operating_point"]["rule"]
    assert "warned_low" in doc["curve"][0] and (rep / "tradeoff.png").is_file()
    other = tmp_path / "folds-2" / "fold1.json"  # a fold a later run with other settings wrote
    other.write_text(json.dumps({**json.loads(other.read_text()), "config_key": "another"}))
    res = CliRunner().invoke(
        studies_app, ["grasp", "rechoose", str(tmp_path / "folds-2"), "--out", str(tmp_path / "y")]
    )
    assert res.exit_code == 2 and "fold1.json" in res.output and "other settings" in res.output
    old = tmp_path / "folds-1" / "fold0.json"  # a fold file written before inner traces were kept
    fold = json.loads(old.read_text())
    old.write_text(json.dumps({**fold, "inner": []}))
    res = CliRunner().invoke(
        studies_app, ["grasp", "rechoose", str(tmp_path / "folds-1"), "--out", str(tmp_path / "x")]
    )
    assert res.exit_code == 2 and "fold0.json" in res.output and "inner-fold traces" in res.output


def _weights(path):
    from safetensors.torch import load_file

    return load_file(str(path))


def test_train_model_motionnet_resumes_after_sigkill(tmp_path, grasps, monkeypatch, one_thread):
    """`slipsense train --model motionnet` trains the default detector through the grasp task;
    SIGKILLed mid-training and started again with --resume it ends with the weights of an
    uninterrupted run."""
    monkeypatch.setenv("SLIPSENSE_CACHE", str(tmp_path / "cache"))
    args = [
        "train",
        "--model",
        "motionnet",
        "--recordings",
        str(grasps),
        "--test-objects",
        "obj3",
        "--set",
        "train.inner_folds=0",
        "--set",
        "train.mine_every=1",
        *[a for a in SMALL if a not in ("--threads", "1")],
    ]
    args[args.index("--epochs") + 1] = "40"
    whole = CliRunner().invoke(app, [*args, "--out", str(tmp_path / "whole")])
    assert whole.exit_code == 0, whole.output
    assert "held-out objects (obj3)" in whole.output

    from conftest import killed_once

    cut = tmp_path / "cut"
    assert killed_once(cut / "resume" / "job0.state", [*args, "--out", cut]) < 40
    assert not (cut / "detector.safetensors").exists()
    resumed = CliRunner().invoke(app, [*args, "--out", str(cut), "--resume"])
    assert resumed.exit_code == 0, resumed.output
    a, b = _weights(tmp_path / "whole" / "detector.safetensors"), _weights(cut / "detector.safetensors")
    assert a.keys() == b.keys() and all(bool((a[k] == b[k]).all()) for k in a)


def test_train_model_motionnet_refuses_clip_options(tmp_path, grasps):
    res = CliRunner().invoke(
        app,
        ["train", "--model", "motionnet", "--recordings", str(grasps), "--frames", "5", "--out", str(tmp_path / "r")],
    )
    assert res.exit_code == 2 and "frames" in res.output and "clip models" in res.output


def test_train_model_motionnet_under_torchrun_equals_one_process(tmp_path, grasps, monkeypatch):
    """`torchrun -m slipsense.cli train --model motionnet`: 2 ranks share every step's runs (and `-m slipsense.cli` runs the CLI); the
    detector's learned weights equal one process's with --set train.accumulate=2 (batch-norm running
    statistics are rank 0's; no hard negatives, which are mined from them); one set of files, written
    by rank 0."""
    import os
    import subprocess
    import sys

    monkeypatch.setenv("SLIPSENSE_CACHE", str(tmp_path / "cache"))
    args = ["train", "--model", "motionnet", "--recordings", str(grasps), "--test-objects", "obj3"]
    args += ["--set", "train.inner_folds=0", *[a for a in SMALL if a not in ("--threads", "1")]]
    args[args.index("hard_negatives=1")] = "hard_negatives=0"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "SLIPSENSE_CACHE": str(tmp_path / "cache")}
    one = CliRunner().invoke(app, [*args, "--set", "train.accumulate=2", "--out", str(tmp_path / "one")])
    assert one.exit_code == 0, one.output
    torchrun = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2"]
    proc = subprocess.run(
        [*torchrun, "-m", "slipsense.cli", *args, "--out", str(tmp_path / "ddp")],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.count("held-out objects (obj3)") == 1  # rank 0 reports
    a, b = _weights(tmp_path / "one" / "detector.safetensors"), _weights(tmp_path / "ddp" / "detector.safetensors")
    learned = [k for k in a if "running_" not in k and "num_batches" not in k]
    for k in learned:
        assert (a[k] - b[k]).abs().max() < 1e-5, k
    for name in ("last.safetensors", "best.safetensors", "metrics.csv", "curves.png", "held_out.json"):
        assert (tmp_path / "ddp" / name).is_file(), name

    monkeypatch.setenv("WORLD_SIZE", "2")
    res = CliRunner().invoke(
        app, ["train", "--recordings", str(grasps), "--workers", "2", "--out", str(tmp_path / "w")]
    )
    assert res.exit_code == 2 and "leave --workers out" in res.output


def test_a_fold_file_is_reused_only_under_the_key_of_todays_whole_settings_and_code(tmp_path, monkeypatch):
    """A fold file written with other settings, before one of today's settings existed, or by other
    code, is trained again."""
    import hashlib

    import slipsense.provenance
    from slipsense.provenance import code_digest
    from slipsense.training.folds import _config_key, _load_fold
    from slipsense.training.grasps import GraspTrainConfig

    cfg = GraspTrainConfig()
    key = _config_key(cfg, 5, [])
    today = json.dumps({"cfg": cfg.to_dict(), "code": code_digest(), "folds": 5, "labels": []}, sort_keys=True)
    assert key == hashlib.sha256(today.encode()).hexdigest()[:16]
    assert _config_key(GraspTrainConfig(lr=0.01), 5, []) != key
    monkeypatch.setattr(slipsense.provenance, "code_digest", lambda: "other code")
    assert _config_key(cfg, 5, []) != key
    monkeypatch.undo()
    before = {k: v for k, v in cfg.to_dict().items() if k != "accumulate"}
    old = hashlib.sha256(
        json.dumps({"cfg": before, "code": code_digest(), "folds": 5, "labels": []}, sort_keys=True).encode()
    )
    fold = tmp_path / "fold0.json"
    fold.write_text(json.dumps({"config_key": key, "fold": 0}))
    assert _load_fold(fold, key) == {"config_key": key, "fold": 0}
    fold.write_text(json.dumps({"config_key": old.hexdigest()[:16], "fold": 0}))
    assert _load_fold(fold, key) is None


def test_grasp_promise_restates_what_training_stated(tmp_path, grasps, monkeypatch):
    """A detector trained before checkpoints carried a held-alarm bound gets it from its own recipe's
    inner folds trained again: the same numbers the training stated."""
    from slipsense.checkpoint import read_info, update_info

    monkeypatch.setenv("SLIPSENSE_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "det"
    args = ["train", "--recordings", str(grasps), "--out", str(out), "--inner-folds", "2", *SMALL]
    assert CliRunner().invoke(app, args).exit_code == 0
    ckpt = out / "detector.safetensors"
    op = read_info(ckpt)["operating_point"]
    stated = op.pop("held_alarm")
    assert stated["held_objects"] == 4 and stated["held_grasps"] == 4
    update_info(ckpt, {"operating_point": op})  # as checkpoints were written before
    res = CliRunner().invoke(studies_app, ["grasp", "promise", str(ckpt), "--workers", "1", "--no-progress"])
    assert res.exit_code == 0, res.output
    again = read_info(ckpt)["operating_point"]["held_alarm"]
    assert again.pop("restated") and again == stated
    assert "on new objects at most" in res.output


def test_the_kept_settings_part_is_its_detector_and_inner_folds():
    from slipsense.training.grasp_detector import FitJob, chosen_part

    jobs = [FitJob((0,), (1,), settings=(("width", w),)) for w in (2, 2, 4, 4)]
    results = ["a", "b", "c", "d"]
    assert chosen_part(jobs, results, {"settings": {"width": 2}}) == (jobs[:2], ["a", "b"])
    assert chosen_part(jobs, results, {"settings": {"width": 4}}) == (jobs[2:], ["c", "d"])
    assert chosen_part(jobs[:2], results[:2], {}) == (jobs[:2], ["a", "b"])  # nothing chosen: all


def test_choosing_settings_of_a_fine_tuned_model_is_refused():
    import pytest

    from slipsense.errors import ConfigError
    from slipsense.training.grasps import GraspTrainConfig

    with pytest.raises(ConfigError, match="train.init"):
        GraspTrainConfig(init="shipped.safetensors", choose={"width": [4, 8]})
