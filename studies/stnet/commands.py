"""``python -m studies stnet simulate``: the binocular marker sensor of the STNet study, simulated
(no binocular recordings are public): 6 objects x 4 motion patterns, 12-frame windows of 3D marker
clouds reconstructed by refraction-aware stereo, saved as a marker ``.npz`` that ``slipsense train
--markers`` reads."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from slipsense.atomic import check_output_dir, check_output_file
from slipsense.cli.common import check_seed, friendly
from slipsense.errors import InputError
from studies.stnet.simulator import SimConfig, make_dataset, plot_patterns, save_dataset

group = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="The STNet study's binocular sensor: simulate marker sequences.",
)


@group.command()
@friendly
def simulate(
    out: Path = typer.Option(..., help="output .npz (x (N,12,552,3) mm, y, groups = sequence id)"),
    sequences: int = typer.Option(
        24,
        help="sequences per (object, motion pattern); 24 (about 16,800 windows, 1.3 GB) is what the compact STNet needs (studies/docs/simulator.md)",
    ),
    seed: int = typer.Option(0, help="seed of everything random"),
    figures: Optional[Path] = typer.Option(None, help="also draw each motion pattern's displacement field here"),
    progress: bool = typer.Option(True, help="progress bars on long work (--no-progress: none)"),
):
    """Simulate the binocular marker sensor: 6 objects x 4 motion patterns, 12-frame windows."""
    check_seed(seed)
    if out.suffix != ".npz":
        raise InputError(out, "marker datasets are saved as .npz; give a path ending in .npz")
    check_output_file(out, "--out")
    check_output_dir(figures, "--figures")
    cfg = SimConfig(seed=seed, n_sequences=sequences)
    ds = make_dataset(cfg, progress=progress)
    save_dataset(ds, out)
    typer.echo(f"{len(ds)} windows ({int(ds.y.sum())} slip) from {len(set(ds.groups.tolist()))} sequences -> {out}")
    if figures is not None:
        for p in plot_patterns(cfg, figures):
            typer.echo(f"figure {p}")
