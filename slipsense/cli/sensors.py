"""``slipsense markers``: track the gel markers of real recordings into labelled marker sequences,
the input of the marker models (STNet, TemNet)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer


def register(app: typer.Typer) -> None:
    from slipsense.cli.common import friendly

    @app.command()
    @friendly
    def markers(
        out: Path = typer.Option(..., help="output .npz (x (N,T,M,3), y, groups = object)"),
        recordings: Optional[Path] = typer.Option(None, help="recordings folder (default: the shared recordings)"),
        frames: int = typer.Option(12, help="frames per marker sequence"),
        n_markers: str = typer.Option(
            "7x9",
            help="ROWSxCOLS: every tracked marker resampled onto that grid (gel pads differ in marker count); "
            "or N: the N markers nearest the centre",
        ),
        horizon: int = typer.Option(0, help="slip sequences end this many frames before the moment of slip"),
        wiggle_per_video: int = typer.Option(2, help="sequences drawn from each video that did not slip"),
        seed: int = typer.Option(0, help="seed of everything random"),
        on_error: str = typer.Option("raise", help="raise: stop at a bad video; skip: warn, name it and leave it out"),
        progress: bool = typer.Option(True, help="progress bars on long work (--no-progress: none)"),
        overrides: Optional[Path] = typer.Option(
            None, help="label overrides CSV (e.g. configs/gelsight-label-overrides.csv)"
        ),
    ):
        """Track the gel markers of real GelSight recordings (KLT) into labelled marker sequences."""
        from slipsense.atomic import check_output_file
        from slipsense.cli.common import check_seed
        from slipsense.paths import gelsight_recordings
        from slipsense.recordings.markers import marker_layout
        from slipsense.marker_sequences import real_marker_dataset, save_marker_npz

        check_seed(seed)
        marker_layout(n_markers)  # a bad layout is refused before anything is tracked
        check_output_file(out, "--out")
        options = dict(horizon=horizon, wiggle_per_video=wiggle_per_video, seed=seed, on_error=on_error)
        options.update(progress=progress, overrides=overrides)
        arrays = real_marker_dataset(recordings or gelsight_recordings(), frames=frames, n_markers=n_markers, **options)
        save_marker_npz(arrays, out)
        typer.echo(
            f"{len(arrays['y'])} windows ({int(arrays['y'].sum())} slip) from "
            f"{len(set(arrays['groups'].tolist()))} objects -> {out}"
        )
