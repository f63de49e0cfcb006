"""``slipsense train``: any registered model, the default detector unless ``--model`` says otherwise;
one fold held out, or every fold in turn (``--cross-validate``) for the leave-objects-out report."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from slipsense.cli.common import command_line, friendly, parse_hw
from slipsense.config_tree import DEFAULT_MODEL, empty_tree, given, load_tree, merge, parse_sets

SET_HELP = (
    "section.key=value, section model, data or train, e.g. train.lr=0.001, model.width=16, "
    "data.sensor=gelsight-mini, train.num_workers=2 (clip models' data loaders); a bare key=value is a "
    "training setting where it names one, else a model setting; repeatable"
)


def report_training(res: dict, echo=typer.echo) -> None:
    """What a training prints after it: the detector and its operating point where one was chosen,
    and the held-out objects' per-grasp outcomes when some were held out."""
    op = res.get("operating_point")
    if op:
        echo(
            f"detector -> {res['checkpoint']} (alarm when P(slip) >= {op['threshold']:g} for {op['debounce']} "
            f"frame(s) in a row, chosen on {op.get('chosen_on', 'the training objects')})"
        )
    if res.get("held_out") and res.get("per_grasp"):
        g = res["per_grasp"]
        echo(
            f"on the held-out objects ({', '.join(res['held_out'])}): {g['warned']} of {g['slip_runs']} slips warned "
            f"in time, {g['premature']} warned too early, {g['missed']} missed; {g['false_positive_grasps']} of "
            f"{g['held_runs']} grasps that held alarmed"
        )


def report_folds(rep: dict, out: Path, echo=typer.echo) -> None:
    """The pooled leave-objects-out figures in words: per grasp for a detector, per clip for a clip model."""
    pooled = rep["pooled"]
    g = pooled.get("per_grasp")
    if g:
        lead = g.get("median_lead_frames")
        echo(
            f"unseen objects, pooled over the folds: {g['warned']} of {g['slip_runs']} slips warned in time"
            + (f" (median {lead:g} frames ahead)" if lead is not None else "")
            + f", {g['premature']} too early, {g['missed']} missed; {g['false_positive_grasps']} of {g['held_runs']} "
            f"grasps that held alarmed -> {out}/README.md"
        )
        return
    echo(
        f"unseen objects, pooled over the folds: {pooled['n_clips']} clips, accuracy {pooled['accuracy']:.3f}, "
        f"precision {pooled['precision']:.3f}, recall {pooled['recall']:.3f}, F1 {pooled['f1']:.3f} -> {out}"
    )


def register(app: typer.Typer) -> None:
    @app.command()
    @friendly
    def train(
        out: Path = typer.Option(Path("runs/latest"), help="output folder (checkpoint, config.yaml, metrics.csv)"),
        config: Optional[Path] = typer.Option(
            None, help="a configuration tree (YAML: model/data/train), e.g. configs/motionnet.yaml"
        ),
        model: Optional[str] = typer.Option(
            None, help=f"a registered model (default {DEFAULT_MODEL}, the slip detector; `slipsense models` lists all)"
        ),
        recordings: Optional[Path] = typer.Option(
            None, help="recordings folder (default: $SLIPSENSE_DATA/gelsight-slip)"
        ),
        markers: Optional[Path] = typer.Option(None, help="marker-sequence .npz, for STNet and TemNet"),
        sets: Optional[List[str]] = typer.Option(None, "--set", help=SET_HELP),
        preset: Optional[str] = typer.Option(None, help="a named model configuration (e.g. paper, compact)"),
        fold: Optional[int] = typer.Option(None, help="hold out fold k of --folds folds of objects and judge on it"),
        folds: Optional[int] = typer.Option(None, help="folds by object (default 5), with --fold or --cross-validate"),
        cross_validate: bool = typer.Option(
            False,
            "--cross-validate",
            help="train one model per fold, each judged on the objects it never saw, pooled into OUT/README.md",
        ),
        test_objects: Optional[str] = typer.Option(None, help="comma-separated objects to hold out and judge on"),
        epochs: Optional[int] = typer.Option(None, help="training epochs (default: the model's recipe)"),
        batch_size: Optional[int] = typer.Option(None, help="batch size per process"),
        lr: Optional[float] = typer.Option(None, help="learning rate"),
        seed: Optional[int] = typer.Option(None, help="seed of everything random (default 0)"),
        size: Optional[str] = typer.Option(None, help="frame size HxW the model sees (default: the model's)"),
        inner_folds: Optional[int] = typer.Option(
            None, help="grasp detectors: inner folds that choose the alarm threshold (0: the training runs)"
        ),
        frames: Optional[int] = typer.Option(None, help="clip models: frames per clip (2..12; default 5)"),
        horizon: Optional[int] = typer.Option(
            None, help="clip models: slip clips end this many frames before the moment of slip"
        ),
        split: Optional[str] = typer.Option(
            None, help="clip models: objects (default, leave objects out), clips (random 90/10) or all"
        ),
        augment: Optional[bool] = typer.Option(
            None, help="clip models: append the paper's transformed copies to the training set (default on)"
        ),
        workers: Optional[int] = typer.Option(
            None,
            min=1,
            help="grasp detectors: trainings side by side (default one per core; results do not depend on it)",
        ),
        threads: Optional[int] = typer.Option(None, help="torch threads of each training process"),
        device: Optional[str] = typer.Option(None, help="clip models: auto (default), cpu, cuda, cuda:1, ..."),
        resume: bool = typer.Option(False, help="continue a killed training from OUT (same weights as unkilled)"),
        overrides: Optional[Path] = typer.Option(None, help="CSV of hand labels replacing automatic moments of slip"),
        sensor: Optional[str] = typer.Option(
            None, help="the registered sensor --recordings were taken with, where they state none (data.sensor)"
        ),
        on_error: Optional[str] = typer.Option(
            None, help="raise (default): stop at a bad recording; skip: warn, name it and leave it out"
        ),
        progress: bool = typer.Option(True, help="progress bars and per-epoch lines"),
    ):
        """Train a model on recordings or marker sequences: the slip detector (motionnet) unless --model
        says otherwise. With --fold or --test-objects, judge it on objects it never saw; with
        --cross-validate, every fold in turn, pooled (leave objects out). Works under torchrun (DDP).

        Settings come from the model's defaults and its own recipe (with the recordings' cameras per
        grasp as model.sensors, and no camera start-up for grasps labelled as a whole), then --config,
        then these options, then --set; the resolved tree is kept in every checkpoint and written to
        OUT/config.yaml."""
        from slipsense.training import recipe

        data = dict(size=list(parse_hw(size)) if size else None, recordings=recordings, markers=markers, frames=frames)
        data.update(horizon=horizon, split=split, test_objects=test_objects, fold=fold, folds=folds, augment=augment)
        data.update(on_error=on_error, overrides=overrides, sensor=sensor)
        training = dict(epochs=epochs, batch_size=batch_size, lr=lr, device=device, seed=seed, inner_folds=inner_folds)
        options = {"model": {"name": model, "preset": preset}, "data": data, "train": training}
        # defaults < --config < options < --set; a bare --set KEY=VALUE goes to the model section, and
        # RunConfig.from_tree (every check, once) moves it to training where it names a training setting
        tree = merge(load_tree(config) if config else empty_tree(), given(options), parse_sets(sets))
        run = recipe.RunConfig.from_tree(tree)
        if cross_validate:
            rep = recipe.cross_validate(
                run, out, run.data.folds, progress=progress, workers=workers, threads=threads, command=command_line()
            )
            report_folds(rep, out)
            return
        res = recipe.fit(
            run, out, progress=progress, resume=resume, workers=workers, threads=threads, command=command_line()
        )
        report_training(res)
