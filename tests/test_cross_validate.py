"""`slipsense train --cross-validate`: one leave-objects-out for every model, from the same tree."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from slipsense.cli import app
from slipsense.models import model_class


def test_a_clip_model_cross_validates_and_a_second_call_keeps_the_judged_folds(
    tmp_path, grasp_recordings, cache, one_thread
):
    small = model_class("vivit").small_config()
    sets = [x for k, v in small.items() for x in ("--set", f"model.{k}={json.dumps(v)}")]
    out = tmp_path / "cv"
    args = ["train", "--model", "vivit", *sets, "--recordings", str(grasp_recordings), "--frames", "3", "--size",
            "48x64", "--epochs", "1", "--folds", "2", "--cross-validate", "--out", str(out), "--no-progress"]  # fmt: skip
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    report = json.loads((out / "folds.json").read_text())
    assert [f["run"] for f in report["folds"]] == ["fold0", "fold1"]
    held = [set(f["test_objects"]) for f in report["folds"]]
    assert not held[0] & held[1] and held[0] | held[1] == {"obj0", "obj1", "obj2", "obj3"}  # every object once
    assert report["pooled"]["n_clips"] == sum(f["n_clips"] for f in report["folds"])
    stamp = (out / "fold0" / "evaluation.json").stat().st_mtime_ns
    assert CliRunner().invoke(app, args).exit_code == 0
    assert (out / "fold0" / "evaluation.json").stat().st_mtime_ns == stamp  # judged folds are kept
    res = CliRunner().invoke(app, [*args[:-3], "--fold", "0", "--out", str(tmp_path / "x")])
    assert res.exit_code == 2 and "--fold" in res.output
