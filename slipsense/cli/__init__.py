"""The ``slipsense`` command line. Every command turns a bad input into one line and exit code 2."""

from __future__ import annotations

import importlib
import json
import os
import time
import warnings
from pathlib import Path
from typing import Optional

import typer

from slipsense.cli.common import friendly, one_line_warning, record_provenance

_HELP = "Slip detection and prediction from vision-based tactile sensors."
app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False, help=_HELP)


@app.command()
@friendly
def label(
    recordings: Path = typer.Option(None, help="recordings folder (default: $SLIPSENSE_DATA/gelsight-slip)"),
    csv: Path = typer.Option(..., help="output CSV, one row per video"),
    overrides: Optional[Path] = typer.Option(None, help="CSV of hand labels that replace automatic ones"),
    on_error: str = typer.Option("raise", help="raise: stop at a bad video; skip: warn and leave it out"),
    sensor: Optional[str] = typer.Option(
        None, help="the registered sensor the recordings were taken with, where they state none (no sensor.json)"
    ),
    progress: bool = typer.Option(True, help="progress bars on long work (--no-progress: none)"),
):
    """Find the moment of slip in every video and write it as CSV."""
    from slipsense.recordings.recording_set import Recordings
    from slipsense.recordings.label_csv import read_overrides_csv, write_labels_csv
    from slipsense.sensors.spec import sensor_named
    from slipsense.atomic import check_output_file
    from slipsense.paths import gelsight_recordings

    check_output_file(csv, "--csv")
    stated = sensor_named(sensor) if sensor is not None else None
    data = Recordings.open(recordings or gelsight_recordings(), on_error=on_error, stated=stated)
    if overrides:
        read_overrides_csv(overrides)  # a malformed file is refused before any video is decoded
    # the path, not the parsed rows: labelling reads it against the recordings, so an error names the file and line
    # the frame size the data's sensor states (its sensor.json, its layout's or the one named)
    labels = data.labelled(overrides, whole_runs=False, progress=progress, expected_size=data.sensor.image_size).labels
    write_labels_csv(labels, csv)
    n_slip = sum(1 for l in labels.values() if l.moment_of_slip is not None)
    typer.echo(f"{len(labels)} videos labelled ({n_slip} with a moment of slip) -> {csv}")


@app.command()
@friendly
def calibrate(
    recordings: Path = typer.Option(..., help="your own grasps (held ones required; slipped ones where you have them)"),
    out: Optional[Path] = typer.Option(None, help="the calibrated checkpoint to write"),
    check: Optional[Path] = typer.Option(
        None, help="instead: leave each object out in turn, calibrate on the others, judge it; JSON here"
    ),
    checkpoint: Optional[Path] = typer.Option(None, help="default: the shipped detector for the data"),
    budget: float = typer.Option(0.05, help="fraction of the held grasps allowed to alarm"),
    overrides: Optional[Path] = typer.Option(None, help="CSV of hand labels for --recordings"),
    on_error: str = typer.Option(
        "raise", help="raise: stop at a video that cannot be read; skip: warn, leave its grasp out, use the rest"
    ),
    progress: bool = typer.Option(True, help="progress bars on long work (--no-progress: none)"),
):
    """Calibrate a detector to your sensor: a new alarm threshold chosen on your grasps, so that at
    most --budget of the held ones alarm, stated with its bound on new objects (weights unchanged)."""
    from slipsense.atomic import check_output_file, write_text
    from slipsense.errors import ConfigError
    from slipsense.evaluation import calibrate as calibration

    if (out is None) == (check is None):
        raise ConfigError("give --out (write a calibrated checkpoint) or --check (judge calibration by objects)")
    if check is not None:
        check_output_file(check, "--check")
        doc = calibration.check_by_objects(
            checkpoint, recordings, budget=budget, overrides=overrides, progress=progress, on_error=on_error
        )
        write_text(check, json.dumps(doc, indent=1))
        typer.echo("\n".join(calibration.check_lines(doc) + [f"-> {check}"]))
        return
    check_output_file(out, "--out")
    result = calibration.calibrate(
        out, checkpoint, recordings, budget=budget, overrides=overrides, progress=progress, on_error=on_error
    )
    typer.echo("\n".join(result.lines()))


@app.command()
@friendly
def adapt(
    recordings: Path = typer.Option(..., help="your own grasps, slipped and held, of several objects"),
    out: Path = typer.Option(..., help="folder: detector.safetensors (where one is kept), adapt.json, folds/"),
    budget: float = typer.Option(0.05, help="fraction of the held grasps allowed to alarm"),
    folds: int = typer.Option(5, help="object folds that judge the trained candidates on objects they never saw"),
    epochs: int = typer.Option(10, help="fine-tuning epochs"),
    seed: int = typer.Option(0, help="seed of the object folds and the trainings"),
    progress: bool = typer.Option(True, help="progress bars on long work (--no-progress: none)"),
):
    """Fit a detector to your sensor: the shipped detector as is and recalibrated, every registered
    family that can learn from your grasps (shear retention where the gels carry markers, ...) and the
    shipped weights fine-tuned, each judged on objects it never saw beside non-learned baselines; the
    best is kept, with the figure of choosing it without each object, and the summary says what was
    chosen and why. A killed run resumes."""
    from slipsense.adapt import adapt as run
    from slipsense.errors import ConfigError
    from slipsense.config_tree import check_seed

    if not 0.0 <= budget < 1.0:
        raise ConfigError(f"--budget must be a fraction in [0, 1), got {budget!r}")
    if folds < 2 or epochs < 1:
        raise ConfigError(f"--folds must be 2 or more and --epochs 1 or more, got {folds} and {epochs}")
    settings = dict(budget=budget, folds=folds, epochs=epochs, seed=check_seed(seed), progress=progress)
    run(recordings, out, echo=typer.echo, **settings)


@app.command()
@friendly
def models():
    """List the registered models and the shipped detectors (sensor, cameras, frame rate, promise)."""
    from slipsense.cli.listing import models_text

    typer.echo(models_text())


# commands defined beside their subsystems (live detection, export, sensors, experiments)
for _module in ("train", "evaluate", "live", "sensors", "bags", "record"):
    importlib.import_module(f"slipsense.cli.{_module}").register(app)


#: Commands whose ``--out`` folder is a report: ``provenance.json`` is written there when they succeed.
REPORTING = {"train", "adapt"}


def _rank() -> int:
    """This process's rank under torchrun (0 alone): one process writes the provenance."""
    return int(os.environ.get("RANK", "0"))


def main() -> None:
    """The console script: the process-wide settings of a command-line run, then the command."""
    # PyTorch backs its large CPU tensors with huge pages where this is set before it starts (read once,
    # at its first allocation; forked workers inherit it): a training epoch ran 12% faster with the same
    # weights, fewer page faults for the frame differences and activations each step allocates again.
    os.environ.setdefault("THP_MEM_ALLOC_ENABLE", "1")
    warnings.formatwarning = one_line_warning
    started = time.time()
    try:
        app()
    except SystemExit as done:
        _leave_process_group(wait=done.code in (0, None))  # a rank that failed does not wait for the others
        if done.code in (0, None) and _rank() == 0:
            record_provenance(started, REPORTING)
        raise
    _leave_process_group()


def _leave_process_group(wait: bool = True) -> None:
    """:func:`slipsense.training.distributed.finish`, where a command imported torch.distributed (a
    process group exists only there): `slipsense --help` does not start torch (4 s) to find none."""
    import sys

    if "torch.distributed" in sys.modules:
        from slipsense.training.distributed import finish

        finish(wait=wait)
