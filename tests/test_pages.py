"""The figures on README.md and docs/*.md are the reports' (studies/pages.py), and the check notices
when a page or a report changes without the other."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from studies import pages

ROOT = Path(__file__).resolve().parent.parent


def _blocks(text: str) -> list[str]:
    return [m.group("name") for m in pages._BLOCK.finditer(text)]


def test_every_page_agrees_with_its_reports():
    problems = pages.check(ROOT)
    assert problems == [], "\n".join(problems) + "\nrun: python -m studies.pages"


def test_the_readme_carries_its_one_table_of_figures():
    assert _blocks((ROOT / "README.md").read_text(encoding="utf-8")) == ["readme"]


def test_every_figure_is_on_some_page():
    used = {name for page in pages.pages(ROOT) for name in _blocks(page.read_text(encoding="utf-8"))}
    assert used == set(pages.FIGURES)


@pytest.fixture
def copy(tmp_path: Path) -> Path:
    """README, docs and the reports the figures read, copied to a temporary project."""
    shutil.copy(ROOT / "README.md", tmp_path / "README.md")
    shutil.copy(ROOT / "dvc.yaml", tmp_path / "dvc.yaml")
    shutil.copy(ROOT / "dvc.lock", tmp_path / "dvc.lock")
    shutil.copytree(ROOT / "docs", tmp_path / "docs")
    (tmp_path / "studies").mkdir()
    shutil.copy(ROOT / "studies" / "README.md", tmp_path / "studies" / "README.md")
    for stage in pages.pipeline_stages(ROOT):
        for report in stage["outs"]:
            if (ROOT / report).is_dir():
                shutil.copytree(ROOT / report, tmp_path / report, dirs_exist_ok=True)
            elif (ROOT / report).is_file():
                (tmp_path / report).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy(ROOT / report, tmp_path / report)
    assert pages.check(tmp_path) == []
    return tmp_path


def _warned(root: Path) -> int:
    """The shipped recipe's slips warned in time, as its leave-objects-out report has it."""
    data = json.loads((root / "reports/grasp-motionnet-k5/folds.json").read_text(encoding="utf-8"))
    return data["pooled"]["per_grasp"]["warned"]


def test_a_number_changed_on_a_page_is_found(copy: Path):
    readme = copy / "README.md"
    text = readme.read_text(encoding="utf-8")
    start = text.index("<!-- figures:readme -->")
    warned = _warned(copy)
    at = text.index(f"{warned}/51", start)
    readme.write_text(text[:at] + f"{warned + 1}/51" + text[at + len(f"{warned}/51") :], encoding="utf-8")
    problems = pages.check(copy)
    assert len(problems) == 1 and problems[0].startswith("README.md: figures:readme disagrees with")


def test_a_report_changed_under_a_page_is_found_and_written_back(copy: Path):
    folds = copy / "reports/grasp-motionnet-k5/folds.json"
    data = json.loads(folds.read_text(encoding="utf-8"))
    warned = data["pooled"]["per_grasp"]["warned"]
    data["pooled"]["per_grasp"]["warned"] += 1
    folds.write_text(json.dumps(data), encoding="utf-8")
    problems = pages.check(copy)
    assert any(p.startswith("README.md: figures:readme") for p in problems)
    assert any("figures:per-grasp" in p for p in problems)
    assert pages.main(["--check", "--root", str(copy)]) == 1

    pages.write(copy)
    assert pages.check(copy) == []
    assert f"{warned + 1}/51" in (copy / "README.md").read_text(encoding="utf-8")


def test_unknown_unclosed_and_unreadable_blocks_are_named(copy: Path):
    page = copy / "docs" / "planted.md"
    page.write_text(
        "<!-- figures:nothing -->\nx\n<!-- /figures:nothing -->\n<!-- figures:precursors -->\nopen\n",
        encoding="utf-8",
    )
    (copy / "reports/precursors/precursors.json").write_text("{}", encoding="utf-8")
    problems = pages.check(copy)
    assert "docs/planted.md: figures:nothing is not a known figure (studies/pages.py FIGURES)" in problems
    assert any(p.startswith("docs/planted.md: figures:precursors has no matching") for p in problems)
    assert any("figures:precursors: its report cannot be read" in p for p in problems)


def test_a_report_not_made_yet_is_said_so_and_one_no_stage_makes_is_an_error(copy: Path):
    shutil.rmtree(copy / "reports/precursors")
    problems = pages.check(copy)
    assert any("figures:precursors does not say that reports/precursors is still to be made" in p for p in problems)
    pages.write(copy)
    assert pages.check(copy) == []
    assert "`dvc repro` (dvc.yaml) writes `reports/precursors`" in (copy / "docs/detector.md").read_text()
    dvc = copy / "dvc.yaml"
    dvc.write_text(dvc.read_text().replace("reports/precursors", "reports/elsewhere"), encoding="utf-8")
    assert any("no report reports/precursors, and no stage of dvc.yaml writes it" in p for p in pages.check(copy))
