"""``slipsense evaluate``: judge a checkpoint on labelled data (registered by slipsense.cli).

The work is :func:`slipsense.evaluation.checkpoints.evaluate_checkpoint`; what it prints is
:func:`slipsense.evaluation.summary.summary_lines`, in words; the figures in full go to ``--json``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer


def register(app: typer.Typer) -> None:
    from slipsense.cli.common import check_nonnegative, friendly

    @app.command()
    @friendly
    def evaluate(
        checkpoint: Optional[Path] = typer.Option(
            None, help="a .safetensors checkpoint (default: the shipped detector, judged per grasp)"
        ),
        recordings: Optional[Path] = typer.Option(
            None, help="evaluate on this recordings folder (every clip; every run per grasp for a grasp detector)"
        ),
        split_file: Optional[Path] = typer.Option(None, help="a run's split.json: evaluate on its held-out part"),
        markers: Optional[Path] = typer.Option(None, help="marker-sequence .npz: evaluate on all of it"),
        json_out: Optional[Path] = typer.Option(
            None, "--json", help="write every figure and each grasp's outcome to this JSON file (default: none)"
        ),
        png: Optional[Path] = typer.Option(
            None, help="clip models: confusion-matrix picture (default: beside --json where it is given, else none)"
        ),
        noise_std: float = typer.Option(0.0, help="add Gaussian noise of this std (0..255 scale) to clips"),
        on_error: str = typer.Option(
            "raise", help="raise: stop at a video that cannot be read; skip: warn, leave its grasp out, judge the rest"
        ),
        overrides: Optional[Path] = typer.Option(None, help="CSV of hand labels for --recordings"),
        sensor: Optional[str] = typer.Option(
            None, help="the registered sensor --recordings were taken with, where they state none (no sensor.json)"
        ),
        progress: bool = typer.Option(True, help="show progress bars on stderr"),
        dtype: str = typer.Option(
            "float32", help="inference numerics: float32, bfloat16 (STNet/TemNet) or int8 weights"
        ),
        per_grasp: bool = typer.Option(True, help="video clip models: also replay the runs and judge them per grasp"),
    ):
        """Evaluate a checkpoint: a grasp detector per grasp (every run replayed: slips warned in time,
        too early or missed, false alarms on held grasps), a clip or marker model per clip (accuracy,
        precision, recall, F1). Prints a short summary; --json keeps every figure."""
        from slipsense.atomic import check_output_file
        from slipsense.evaluation.summary import summary_lines
        from slipsense.recordings.folders import check_on_error
        from slipsense.evaluation.checkpoints import evaluate_checkpoint

        check_on_error(on_error)
        check_nonnegative(noise_std, "--noise-std")
        check_output_file(json_out, "--json")
        check_output_file(png, "--png")
        options = dict(split=split_file, markers=markers, json_out=json_out, png=png, noise_std=noise_std)
        options.update(on_error=on_error, overrides=overrides, progress=progress, dtype=dtype, per_grasp=per_grasp)
        if sensor is not None:
            from slipsense.sensors.spec import sensor_named

            options["sensor"] = sensor_named(sensor)
        metrics = evaluate_checkpoint(checkpoint, recordings, echo=lambda line: typer.echo(line, err=True), **options)
        typer.echo("\n".join(summary_lines(metrics)))
        if json_out is not None:
            typer.echo(f"every figure: {json_out}")
