"""``python -m studies velocity``: the slip-velocity report (:mod:`studies.velocity`)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from slipsense.atomic import check_output_dir, write_text
from slipsense.cli.common import command_line, friendly
from slipsense.paths import data_root


@friendly
def velocity(
    out: Path = typer.Option(Path("reports/slip-velocity"), help="report folder"),
    data: Optional[Path] = typer.Option(None, help="shared data folder (default: $SLIPSENSE_DATA)"),
    sequences: int = typer.Option(8, help="simulated sequences per object and motion pattern (test seed)"),
):
    """The object's motion against the gel, checked: simulated known velocities, gelsight-lift beside its
    outside camera (objects left out), the GelSight Mini's held wiggles against its slips."""
    from studies.provenance import provenance
    from studies.velocity import markdown, velocity_study

    check_output_dir(out, "--out")
    doc = velocity_study(data or data_root(), out, sequences)
    text = markdown(doc)
    write_text(
        out / "README.md",
        f"# The object's motion against the gel, checked\n\n`{command_line()}`\n\n{provenance()}\n\n"
        f"What is measured: slipsense/sensors/gel_motion.py (camera-in-gel: the imprint's rigid motion less the "
        f"gel surface's; marker clouds: the footprint over the material where friction drags the gel).\n\n"
        f"{text}\n",
    )
    typer.echo(text + f"\n-> {out}")
