"""``python -m studies``: the studies' own entry point, run from the checkout (see studies/README.md).

python -m studies experiment params --quick      the papers' experiments, one report folder each
python -m studies grasp ceiling reports/...      the grasp analyses behind the findings
python -m studies velocity --out reports/slip-velocity   the slip velocity checked where its truth is known
"""

from __future__ import annotations

import time

import typer

from slipsense.cli import common
from studies.experiments.commands import register as register_experiments
from studies.grasp.commands import group as grasp_group
from studies.stnet.commands import group as stnet_group
from studies.velocity_command import velocity

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="The studies behind slipsense's figures: the papers' experiments and the grasp analyses.",
)
register_experiments(app)
app.add_typer(grasp_group, name="grasp")
app.add_typer(stnet_group, name="stnet")
app.command("velocity")(velocity)


def main() -> None:
    common.PROG = "python -m studies"  # reports name the command that made them
    started = time.time()
    try:
        app()
    except SystemExit as done:
        if done.code in (0, None):
            common.record_provenance(started)  # every study writes a report folder
        raise


if __name__ == "__main__":
    main()
