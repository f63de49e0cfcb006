"""The pages' copied tables (studies.experiments.tables): what a page shows is its report's text."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from studies.__main__ import app
from studies.experiments.tables import sync

ROOT = Path(__file__).resolve().parents[2]


def test_the_repositorys_pages_show_their_reports_tables():
    assert sync(ROOT, check=True) == [], "run `slipsense experiment tables`"


def test_a_page_is_updated_from_its_report_and_a_section_can_be_picked(tmp_path):
    (tmp_path / "reports").mkdir()
    (tmp_path / "reports" / "r.md").write_text("# r\n\n## Per grasp\n\n| a |\n|---|\n| 2 |\n\n## Folds\n\n| f |\n")
    page = tmp_path / "README.md"
    page.write_text("intro\n<!-- from reports/r.md#Per grasp -->\n| a |\n| 1 |\n<!-- end -->\nafter\n")
    res = CliRunner().invoke(app, ["experiment", "tables", "--root", str(tmp_path), "--check"])
    assert res.exit_code == 1 and "out of date" in res.output
    res = CliRunner().invoke(app, ["experiment", "tables", "--root", str(tmp_path)])
    assert res.exit_code == 0
    assert page.read_text() == "intro\n<!-- from reports/r.md#Per grasp -->\n| a |\n|---|\n| 2 |\n<!-- end -->\nafter\n"
    assert sync(tmp_path, check=True) == []


@pytest.mark.parametrize("src", ["reports/missing.md", "reports/r.md#No such heading"])
def test_a_missing_source_is_one_line_naming_the_page(tmp_path, src):
    (tmp_path / "reports").mkdir()
    (tmp_path / "reports" / "r.md").write_text("# r\n")
    (tmp_path / "README.md").write_text(f"<!-- from {src} -->\n<!-- end -->\n")
    res = CliRunner().invoke(app, ["experiment", "tables", "--root", str(tmp_path)])
    assert res.exit_code == 2 and res.output.startswith("error:") and "Traceback" not in res.output


def test_an_unterminated_marker_is_refused(tmp_path):
    (tmp_path / "reports").mkdir()
    (tmp_path / "reports" / "r.md").write_text("| a |\n")
    (tmp_path / "README.md").write_text(
        "<!-- from reports/r.md -->\nold\n<!-- from reports/r.md -->\nx\n<!-- end -->\n"
    )
    res = CliRunner().invoke(app, ["experiment", "tables", "--root", str(tmp_path)])
    assert res.exit_code == 2 and "no <!-- end -->" in res.output
