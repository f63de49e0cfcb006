"""reports/ is the DVC pipeline's output (dvc.yaml): every folder there is a stage's, made by its
command, with its provenance; `dvc status` notices a changed recipe."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest
import yaml

from studies import pages

ROOT = Path(__file__).resolve().parent.parent
DVC = ROOT / ".venv" / "bin" / "dvc"
STAGES = pages.pipeline_stages(ROOT)
OUTS = {out: stage for stage in STAGES for out in stage["outs"]}


def _lock() -> dict:
    path = ROOT / "dvc.lock"
    return yaml.safe_load(path.read_text()).get("stages", {}) if path.exists() else {}


def test_every_report_is_a_stage_output():
    strays = []
    for entry in sorted((ROOT / "reports").iterdir()):
        rel = entry.relative_to(ROOT).as_posix()
        inside = [o for o in OUTS if o == rel or o.startswith(rel + "/")]
        if not inside:
            strays.append(rel)
    assert strays == [], f"not the output of any stage of dvc.yaml: {strays}"


def test_every_report_there_was_made_by_its_stage_and_says_how():
    lock = _lock()
    for out, stage in OUTS.items():
        path = ROOT / out
        if not path.exists():
            continue  # still to be made: the pages say so
        assert stage["name"] in lock, f"{out} is on disk but dvc.lock has no run of stage {stage['name']}"
        assert stage["cmd"] == (c if isinstance(c := lock[stage["name"]]["cmd"], list) else [c])
        if path.is_dir():
            prov = json.loads((path / "provenance.json").read_text())
            assert prov["command"] in [c.removeprefix("OMP_NUM_THREADS=1 ") for c in stage["cmd"]], out
            assert prov["commit"] and prov["machine"] and prov["date"] and prov["seconds"] > 0
            assert prov["code_changed_since_commit"] is False, f"{out} was made from uncommitted code"
        text = "\n".join(p.read_text(errors="ignore") for p in ([path] if path.is_file() else path.rglob("*.md")))
        assert "not recorded" not in text, out


def test_every_figure_on_a_page_reads_stage_outputs():
    for name, figure in pages.FIGURES.items():
        for report in figure.reports:
            if report != "dvc.yaml":
                assert any(report == o or report.startswith(o + "/") for o in OUTS), (name, report)


def test_the_shipped_recipes_settings_are_the_stages_params():
    doc = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    for stage in ("grasp-motionnet-k5", "grasp-motionnet-seed"):
        body = doc[stage].get("do", doc[stage])
        assert {"configs/motionnet.yaml": ["model", "train"]} in body["params"], stage


def _status(clone: Path) -> dict:
    done = subprocess.run([str(DVC), "status", "--json"], cwd=clone, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


@pytest.mark.skipif(not DVC.exists(), reason="DVC comes with the full set-up (scripts/setup.sh)")
def test_a_fresh_clone_is_up_to_date_until_the_recipes_seed_changes(tmp_path):
    """In a clone (beside the shared data, as the checkout is), `dvc status` says what it says in the
    checkout: a stage up to date here is up to date there (no path or machine leaks into dvc.lock);
    with the shipped recipe's seed changed, `dvc status` names every stage that trains it, for that
    reason, and no other stage for it. (Whether HEAD is up to date is the release's state, not the
    test's: code changed since a stage ran makes it stale until `dvc repro` runs it again.)"""
    (tmp_path / "shared").symlink_to((ROOT.parent / "shared").resolve())
    clone = tmp_path / "main"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    ran = set(_lock())
    fresh_here = ran - set(_status(ROOT))
    assert not fresh_here & set(_status(clone)), "stages up to date here are not in a fresh clone"

    recipe = clone / "configs" / "motionnet.yaml"
    recipe.write_text(recipe.read_text().replace("  seed: 0", "  seed: 1"))
    changed = _status(clone)

    def recipe_changed(stage: str) -> bool:
        # DVC names the params file with its changed keys: {"configs/motionnet.yaml": {"train": "modified"}}
        return any(
            c.get("changed deps", {}).get("configs/motionnet.yaml") == {"train": "modified"}
            for c in changed.get(stage, [])
        )

    trains_it = {s["name"] for s in STAGES if any("configs/motionnet.yaml" in c for c in s["cmd"])} & ran
    assert trains_it, "no stage of the shipped recipe has run"
    assert all(recipe_changed(s) for s in trains_it), changed
    assert not any(recipe_changed(s) for s in changed if s not in trains_it)


def test_a_shipped_detectors_promise_on_unseen_objects_is_its_reports():
    """The promise `watch` and `models` state for a shipped detector, measured on objects it never saw,
    is the figure of the cross-validation report it names (stamped by `python -m studies grasp promise
    --unseen REPORT`): rebuilt reports and checkpoints cannot drift apart unnoticed."""
    from slipsense.checkpoint import read_info
    from slipsense.resources import shipped_model, shipped_models
    from studies.grasp.promise import unseen_figures

    stamped = 0
    for name in shipped_models():
        unseen = (read_info(shipped_model(name)).get("operating_point") or {}).get("held_alarm_unseen")
        if not unseen or not (ROOT / unseen["report"]).is_dir():
            continue
        k, n, _ = unseen_figures(ROOT / unseen["report"], unseen.get("row"))
        assert (unseen["alarming"], unseen["held_grasps"]) == (k, n), (
            f"{name}: run python -m studies grasp promise {shipped_model(name)} --unseen {unseen['report']}"
        )
        stamped += 1
    assert stamped >= 3  # both GelSight Mini detectors and the lift one
