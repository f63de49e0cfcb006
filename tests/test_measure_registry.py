"""The registry of measures is the one source of per-grasp figures: a measure written in one place
reaches ``evaluate``'s JSON and summary, the cross-validation's fold table and adapt's table, and
adapt ranks by the value a registered measure names."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from slipsense.cli import app

runner = CliRunner()


@pytest.fixture
def share_slipped():
    """A measure registered the way a new one would be (one function, one ``register`` call), removed after."""
    from slipsense.measures import MEASURES, register

    def words(result, context):
        return [f"Share of grasps that slipped (a test measure): {100 * result['share']:.0f}%."]

    @register("share_slipped", words, rank=lambda r: r["share"], label="share slipped (test)")
    def share(judged):
        return {"share": float(np.mean([r.slipped for r in judged.runs])), "grasps": len(judged.runs)}

    yield "share_slipped"
    MEASURES.pop("share_slipped")


def test_a_new_measure_reaches_the_json_the_summary_the_held_out_result_and_the_fold_table(
    tmp_path, cache, one_thread, grasp_recordings, share_slipped
):
    out = tmp_path / "e.json"
    res = runner.invoke(app, ["evaluate", "--recordings", str(grasp_recordings), "--json", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    assert json.loads(out.read_text())[share_slipped] == {"share": 0.5, "grasps": 8}
    assert "Share of grasps that slipped (a test measure): 50%." in res.stdout

    import slipsense

    trained = slipsense.fit(
        grasp_recordings, tmp_path / "fit", model="motion-energy", held_out=["obj1"], progress=False
    )
    assert trained.held_out["measures"][share_slipped] == 0.5  # the held-out object's grasps: 1 of 2 slipped

    folds = tmp_path / "folds"
    args = ["train", "--cross-validate", "--out", str(folds), "--recordings", str(grasp_recordings), "--folds", "2",
            "--model", "motion-energy", "--no-progress"]  # fmt: skip
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    report = json.loads((folds / "folds.json").read_text())
    assert [f["measures"][share_slipped] for f in report["per_fold"]] == [0.5, 0.5]  # each fold: 2 of 4 slipped
    readme = (folds / "README.md").read_text()
    table = readme[readme.index("## Every registered measure, fold by fold") :]
    assert "share slipped (test)" in table.splitlines()[2] and "| 0 |" in table and "50%" in table


def test_adapt_ranks_by_a_registered_measure_and_its_table_shows_every_one(
    tmp_path, cache, one_thread, share_slipped, folder_opens
):
    """... and adapt lists its folder once (in this process: `strace -f` of the command finds once in all)."""
    from test_adapt import _grasps_of

    from slipsense.adapt import RANK_BY
    from slipsense.measures import MEASURES

    assert MEASURES[RANK_BY].rank is not None  # adapt's choice reads a value the registry names
    root = _grasps_of(
        tmp_path / "set", {"object000": (True, False) * 3, "object001": (False,) * 3, "object002": (True,) * 3}
    )
    out = tmp_path / "mine"
    args = ["adapt", "--recordings", str(root), "--out", str(out), "--epochs", "1", "--folds", "3", "--no-progress"]
    with folder_opens:
        res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    assert folder_opens.count(root) == 1 and folder_opens.count(root / "object000") == 1
    doc = json.loads((out / "adapt.json").read_text())
    replayed = [c for c in doc["candidates"]]
    assert all(c["measures"][share_slipped] == 0.5 for c in replayed), [c["measures"] for c in replayed]
    assert all(
        c["measures"][RANK_BY] == c["measure"]["operating_point"]["balanced_accuracy"]["value"] for c in replayed
    )
    assert res.output.count("share slipped (test) 50%") == len(replayed)
    # a rate the measure does not state (minutes of contact too few) is neither ranked nor shown
    rates = [c["measures"]["false_alarms_per_hour"] for c in replayed if "false_alarms_per_hour" in c["measures"]]
    assert rates and all(math.isnan(r) for r in rates)
    assert "false alarms per hour" not in res.output
