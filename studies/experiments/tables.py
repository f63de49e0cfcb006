"""``slipsense experiment tables``: the result tables of README.md and docs/ copied from their reports,
so that a figure has one source and the pages cannot disagree with it.

A page marks each copied table::

    <!-- from reports/adaptation/adaptation.md -->
    ...replaced by the report's text...
    <!-- end -->

``from PATH#Heading`` copies only the section under that Markdown heading (up to the next heading
of its level or above). Paths are relative to the project root (the folder holding README.md).
"""

from __future__ import annotations

import re
from pathlib import Path

from slipsense.atomic import write_text
from slipsense.errors import InputError

_BLOCK = re.compile(r"(<!-- from (?P<src>[^\n]+?) -->\n)(?P<body>(?:(?!<!-- from ).)*?)(<!-- end -->)", re.S)
_OPEN = re.compile(r"<!-- from [^\n]+? -->")


def _section(text: str, heading: str, source: Path) -> str:
    lines = text.splitlines()
    for i, line in enumerate(lines):
        level = len(line) - len(line.lstrip("#"))
        if level and line[level:].strip() == heading:
            end = next(
                (j for j in range(i + 1, len(lines)) if 0 < len(lines[j]) - len(lines[j].lstrip("#")) <= level),
                len(lines),
            )
            return "\n".join(lines[i + 1 : end]).strip("\n")
    raise InputError(source, f"no heading {heading!r}")


def _source_text(root: Path, src: str, page: Path) -> str:
    path, _, heading = src.partition("#")
    source = root / path
    if Path(path).is_absolute() or ".." in Path(path).parts:
        raise InputError(page, f"copies a table from {path}: give a path inside the project")
    if not source.is_file():
        raise InputError(page, f"copies a table from {path}, which does not exist (run the command that writes it)")
    text = source.read_text(encoding="utf-8")
    return (_section(text, heading, source) if heading else text).strip("\n") + "\n"


def sync_page(page: Path, root: Path, write: bool = True) -> bool:
    """Replace every marked block of ``page`` by its source's text; True when the page changed (with
    ``write=False``: would change)."""
    text = page.read_text(encoding="utf-8")
    if len(_OPEN.findall(text)) != len(_BLOCK.findall(text)):
        raise InputError(page, "a <!-- from ... --> marker has no <!-- end --> before the next one")
    new = _BLOCK.sub(lambda m: m.group(1) + _source_text(root, m.group("src"), page) + m.group(4), text)
    if new != text and write:
        write_text(page, new)
    return new != text


def pages(root: Path) -> list[Path]:
    """The pages that may copy tables: README.md and docs/*.md."""
    return [p for p in [root / "README.md", *sorted((root / "docs").glob("*.md"))] if p.is_file()]


def sync(root: str | Path = ".", check: bool = False) -> list[Path]:
    """Bring every page's copied tables up to date (``check``: change nothing); returns the pages that
    changed (or are out of date)."""
    root = Path(root)
    if not (root / "README.md").is_file():
        raise InputError(root, "no README.md here: give the project folder")
    return [p for p in pages(root) if sync_page(p, root, write=not check)]
