"""The Markdown page a benchmark prints and, with ``--out``, keeps (``bench/results/...``)."""

from __future__ import annotations

from pathlib import Path


def emit(lines: list[str], out: Path | None) -> str:
    """``lines`` as one page: printed, and written to ``out`` (its folder made) where given."""
    text = "\n".join(lines) + "\n"
    print(text)
    if out:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text)
    return text
