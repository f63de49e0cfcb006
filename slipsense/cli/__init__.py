"""The ``slipsense`` command line. Every command turns a bad input into one line and exit code 2."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import List, Optional

import typer

from slipsense.cli.common import check_seed, friendly, parse_hw

# PyTorch backs its large CPU tensors with huge pages where this is set before it starts (read once, at its
# first allocation; forked workers inherit it): a training epoch ran 12% faster with the same weights,
# fewer page faults for the frame differences and activations each step allocates again.
os.environ.setdefault("THP_MEM_ALLOC_ENABLE", "1")

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="Slip detection and prediction from vision-based tactile sensors.",
)


@app.command()
@friendly
def label(
    recordings: Path = typer.Option(None, help="recordings folder (default: $SLIPSENSE_DATA/gelsight-slip)"),
    csv: Path = typer.Option(..., help="output CSV, one row per video"),
    overrides: Optional[Path] = typer.Option(None, help="CSV of hand labels that replace automatic ones"),
    on_error: str = typer.Option("raise", help="raise: stop at a bad video; skip: warn and leave it out"),
    progress: bool = typer.Option(True),
):
    """Find the moment of slip in every video and write it as CSV."""
    from slipsense.data import label_runs
    from slipsense.recordings.folders import find_recordings, validate_recordings
    from slipsense.recordings.frame_folders import data_sensor
    from slipsense.recordings.label_csv import read_overrides_csv, write_labels_csv
    from slipsense.sensors.spec import GELSIGHT_MINI

    from slipsense.atomic import check_output_file
    from slipsense.config import gelsight_recordings

    check_output_file(csv, "--csv")
    root = recordings or gelsight_recordings()
    sensor = data_sensor(root) or GELSIGHT_MINI  # frame folders state their own size
    recs = validate_recordings(find_recordings(root, on_error=on_error), on_error, sensor.image_size)
    if overrides:
        read_overrides_csv(overrides)  # a malformed file is refused before any video is decoded
    # the path, not the parsed rows: label_recordings reads it against the recordings, so an error
    # names the file and line
    labels = label_runs(recs, overrides=overrides, on_error=on_error, progress=progress)
    write_labels_csv(labels, csv)
    n_slip = sum(1 for l in labels.values() if l.moment_of_slip is not None)
    typer.echo(f"{len(labels)} videos labelled ({n_slip} with a moment of slip) -> {csv}")


@app.command()
@friendly
def train(
    config: Optional[Path] = typer.Option(
        None, help="a configuration tree (YAML: model/data/train), e.g. configs/vivit-paper.yaml"
    ),
    model: Optional[str] = typer.Option(None, help="model name (see `slipsense models`; default vivit)"),
    recordings: Optional[Path] = typer.Option(None, help="GelSight recordings folder (video models)"),
    markers: Optional[Path] = typer.Option(None, help="marker-sequence .npz (STNet/TemNet)"),
    out: Path = typer.Option(Path("runs/latest"), help="run folder"),
    preset: Optional[str] = typer.Option(None, help="named model configuration (e.g. paper, compact)"),
    set_: Optional[List[str]] = typer.Option(
        None,
        "--set",
        help="section.key=value, section model, data or train (a bare key=value sets model.key); repeatable",
    ),
    frames: Optional[int] = typer.Option(None, help="frames per clip (2..12; default 5)"),
    horizon: Optional[int] = typer.Option(None, help="slip clips end this many frames before the moment of slip"),
    size: Optional[str] = typer.Option(None, help="clip size HxW (default 240x320)"),
    wiggle_per_video: Optional[int] = typer.Option(
        None, help="wiggle windows drawn from each non-slip video (default 2)"
    ),
    split: Optional[str] = typer.Option(
        None, help="objects (default): leave objects out; clips: random 90/10 by clip; all: train on everything"
    ),
    test_objects: Optional[str] = typer.Option(None, help="comma-separated held-out objects"),
    fold: Optional[int] = typer.Option(None, help="hold out fold k of --folds object folds"),
    folds: Optional[int] = typer.Option(None, help="object folds (default 5)"),
    test_fraction: Optional[float] = typer.Option(
        None, help="for --split clips, or marker data: test share (default 0.1)"
    ),
    augment: Optional[bool] = typer.Option(
        None, help="append the paper's transformed copies to the training set (default on)"
    ),
    epochs: Optional[int] = typer.Option(None),
    batch_size: Optional[int] = typer.Option(None, help="per process; under torchrun the global batch is world x this"),
    accumulate: Optional[int] = typer.Option(
        None,
        help="micro-batches per process per step (global batch: world x "
        "batch size x this); 1 process x accumulate N draws the "
        "dropout masks of N processes",
    ),
    lr: Optional[float] = typer.Option(None),
    weight_decay: Optional[float] = typer.Option(None),
    seed: Optional[int] = typer.Option(None, help="default 0"),
    workers: Optional[int] = typer.Option(None, help="DataLoader worker processes"),
    device: Optional[str] = typer.Option(None, help="auto (default), cpu, cuda, cuda:1, ..."),
    max_steps_per_epoch: Optional[int] = typer.Option(None, help="cap steps per epoch (smoke runs)"),
    resume: bool = typer.Option(False, help="continue from OUT/resume.pt"),
    cross_validate: bool = typer.Option(
        False, "--cross-validate", help="train every fold of --folds (default 5) into OUT/fold<k>, pooled into OUT"
    ),
    on_error: Optional[str] = typer.Option(
        None, help="raise (default): stop at a bad video; skip: warn and leave it out"
    ),
    overrides: Optional[Path] = typer.Option(None, help="CSV of hand labels replacing automatic moments of slip"),
    progress: bool = typer.Option(True),
):
    """Train a model on recordings or marker sequences (works under torchrun for DDP); with
    --cross-validate, every fold by object, each judged on its unseen objects, pooled.

    Settings come from the command's defaults, then --config, then the options given here, then --set;
    the resolved tree is stored in every checkpoint and written to OUT/config.yaml."""
    from slipsense.atomic import check_output_dir
    from slipsense.run_config import empty_tree, given, load_tree, merge, parse_sets
    from slipsense.training.clips import TrainRequest

    check_output_dir(out, "--out")
    options = {
        "model": {"name": model, "preset": preset},
        "data": dict(
            recordings=recordings,
            markers=markers,
            frames=frames,
            horizon=horizon,
            size=list(parse_hw(size)) if size else None,
            wiggle_per_video=wiggle_per_video,
            split=split,
            test_objects=test_objects,
            fold=fold,
            folds=folds,
            test_fraction=test_fraction,
            augment=augment,
            on_error=on_error,
            overrides=overrides,
        ),
        "train": dict(
            epochs=epochs,
            batch_size=batch_size,
            accumulate=accumulate,
            lr=lr,
            weight_decay=weight_decay,
            num_workers=workers,
            device=device,
            max_steps_per_epoch=max_steps_per_epoch,
            seed=seed,
        ),
    }
    tree = merge(load_tree(config) if config else empty_tree(), given(options), parse_sets(set_))
    check_seed(tree["train"].get("seed", 0))
    from slipsense.cli.common import command_line
    from slipsense.cli.grasp import report_training
    from slipsense.training.recipe import fit

    tree["model"]["name"] = tree["model"].get("name") or TrainRequest.model
    if cross_validate:
        from slipsense.training.recipe import cross_validate as run_folds

        n = tree["data"].get("folds") or 5
        report = run_folds(tree, out, n, progress=progress, command=command_line())
        pooled = report["pooled"]
        shown = pooled.get("per_grasp") or {k: pooled[k] for k in ("accuracy", "precision", "recall", "f1", "n_clips")}
        typer.echo(f"{n} folds pooled: {json.dumps(shown, default=float)} -> {out}")
        return
    res = fit(tree, out, progress=progress, resume=resume, command=command_line())
    report_training(res)


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
    progress: bool = typer.Option(True),
):
    """Calibrate a detector to your sensor: a new alarm threshold chosen on your grasps, so that at
    most --budget of the held ones alarm, stated with its bound on new objects (weights unchanged)."""
    from slipsense.atomic import check_output_file, write_text
    from slipsense.errors import ConfigError
    from slipsense.evaluation import calibrate as calibration

    if (out is None) == (check is None):
        raise ConfigError("give --out (write a calibrated checkpoint) or --check (judge calibration by objects)")
    overrides = True if overrides is None else overrides
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
        out,
        checkpoint,
        recordings,
        budget=budget,
        overrides=True if overrides is None else overrides,
        progress=progress,
        on_error=on_error,
    )
    typer.echo("\n".join(result.lines()))


@app.command()
@friendly
def models():
    """List the registered models and their parameter counts at default settings."""
    import torch

    from slipsense.models import available, build, count_parameters

    for name in available():
        with torch.device("meta"):  # counted without allocating (STNet at the paper's size: 127 M)
            n = count_parameters(build(name))
        typer.echo(f"{name:12s} {n:>12,d} parameters")


def _register_extensions() -> None:
    """Commands defined beside their subsystems (live detection, export, sensors, experiments)."""
    import importlib

    modules = ("evaluate", "live", "sensors", "experiments", "grasp", "bags", "record")
    for mod in modules:
        importlib.import_module(f"slipsense.cli.{mod}").register(app)


_register_extensions()


def main() -> None:  # console-script entry point
    try:
        app()
    except SystemExit as done:
        _leave_process_group(wait=done.code in (0, None))  # a rank that failed does not wait for the others
        raise
    _leave_process_group()


def _leave_process_group(wait: bool = True) -> None:
    """:func:`slipsense.training.distributed.finish`, where a command imported torch.distributed (a
    process group exists only there): `slipsense --help` does not start torch (4 s) to find none."""
    import sys

    if "torch.distributed" in sys.modules:
        from slipsense.training.distributed import finish

        finish(wait=wait)
