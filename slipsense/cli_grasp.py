"""``slipsense grasp train`` and ``slipsense grasp folds``: detectors trained on whole grasps and
judged per grasp on objects they never saw (registered by slipsense.cli)."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path
from typing import List, Optional

import typer

grasp_app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="Detectors over whole grasps (both sensors, every frame), judged per grasp.",
)

SET_HELP = (
    "KEY=VALUE: a training setting (epochs, lr, chunk, negatives, hard_negatives, onset_frames, horizon, "
    "inner_folds, positive_weight, ...) or a model setting (width, lags, dilations, ... or model.KEY)"
)


def _prepare(
    model, sets, size, epochs, seed, inner_folds, recordings, overrides, on_error, progress, threads, out=None
):
    from slipsense.cli import _default_recordings, _parse_sets, check_seed, parse_hw
    from slipsense.grasp_train import load_grasp_data, make_config

    if threads is not None:
        import torch

        torch.set_num_threads(threads)
    from slipsense.atomic import check_output_dir

    check_output_dir(out, "--out")
    settings = _parse_sets(sets)
    if epochs is not None:
        settings["epochs"] = epochs
    if inner_folds is not None:
        settings["inner_folds"] = inner_folds
    settings["seed"] = check_seed(seed)
    hw = parse_hw(size)
    cfg = make_config(model, settings, hw)
    image_size = tuple(cfg.model_config.get("image_size") or _model_size(model))
    root = recordings or _default_recordings()
    runs, labels = load_grasp_data(root, overrides, image_size, on_error, progress)
    from slipsense.config import portable_path

    data = {
        "recordings": portable_path(root),
        "overrides": None if overrides is None else portable_path(overrides),
        "image_size": list(image_size),
    }
    return cfg, runs, labels, data


def _model_size(name: str) -> tuple[int, int]:
    from slipsense.models import build

    return tuple(build(name).image_size)


def _command() -> str:
    return "slipsense " + " ".join(shlex.quote(a) for a in sys.argv[1:])


def register(app: typer.Typer) -> None:
    from slipsense.cli import friendly

    @grasp_app.command("train")
    @friendly
    def train(
        out: Path = typer.Option(..., help="output folder: detector.safetensors, metrics.csv, curves.png"),
        model: str = typer.Option("motionnet", help="a model that takes whole grasps (motionnet, motion-energy)"),
        fold: Optional[int] = typer.Option(
            None, help="hold out this fold of objects (with --folds); default: train on every object"
        ),
        folds: int = typer.Option(5, help="folds by object, with --fold"),
        sets: Optional[List[str]] = typer.Option(None, "--set", help=SET_HELP),
        size: Optional[str] = typer.Option(None, help="grey frame size HxW (default: the model's, 30x40)"),
        epochs: Optional[int] = typer.Option(None, help="training epochs"),
        inner_folds: Optional[int] = typer.Option(None, help="inner folds for the operating point (0: training runs)"),
        seed: int = typer.Option(0, help="seed of everything random"),
        recordings: Optional[Path] = typer.Option(
            None, help="recordings folder (default: $SLIPSENSE_DATA/gelsight-slip)"
        ),
        overrides: Optional[Path] = typer.Option(None, help="label overrides CSV"),
        on_error: str = typer.Option("raise", help="raise or skip bad recordings"),
        progress: bool = typer.Option(True),
        threads: Optional[int] = typer.Option(None, help="torch threads"),
    ):
        """Train a grasp detector (and its alarm operating point, chosen on its training objects)."""
        from slipsense.errors import ConfigError
        from slipsense.grasp_train import object_split, train_detector

        cfg, runs, labels, data = _prepare(
            model, sets, size, epochs, seed, inner_folds, recordings, overrides, on_error, progress, threads, out
        )
        held: list[str] = []
        if fold is not None:
            split = object_split([r for r in runs if r.usable], folds, cfg.seed)
            if not 0 <= fold < len(split):
                raise ConfigError(f"--fold must be in 0..{len(split) - 1}, got {fold}")
            held = split[fold]
        data["command"] = _command()
        res = train_detector(runs, labels, cfg, out, held, data=data, progress=progress)
        op = res["operating_point"]
        typer.echo(
            f"detector -> {res['checkpoint']} (threshold {op['threshold']:g}, debounce {op['debounce']}, "
            f"chosen on {op['chosen_on']})"
        )
        if held:
            g, c = res["per_grasp"], res["clips"]
            typer.echo(
                f"held-out objects ({', '.join(held)}): warned in time {g['warned']}/{g['slip_runs']}, "
                f"premature {g['premature']}, missed {g['missed']}, false-positive grasps "
                f"{g['false_positive_grasps']}/{g['held_runs']}; clips: accuracy {c['accuracy']:.3f} "
                f"(always-wiggle {c['always_wiggle_accuracy']:.3f}), balanced {c['balanced_accuracy']:.3f}, "
                f"F1 {c['f1']:.3f}"
            )

    @grasp_app.command("folds")
    @friendly
    def folds_cmd(
        out: Path = typer.Option(..., help="report folder: fold<k>.json, folds.json, README.md, tradeoff.png"),
        model: str = typer.Option("motionnet", help="a model that takes whole grasps"),
        folds: int = typer.Option(5, help="folds by object"),
        sets: Optional[List[str]] = typer.Option(None, "--set", help=SET_HELP),
        size: Optional[str] = typer.Option(None, help="grey frame size HxW"),
        epochs: Optional[int] = typer.Option(None, help="training epochs"),
        inner_folds: Optional[int] = typer.Option(None, help="inner folds for the operating point (0: training runs)"),
        seed: int = typer.Option(0, help="seed of everything random"),
        recordings: Optional[Path] = typer.Option(None, help="recordings folder"),
        overrides: Optional[Path] = typer.Option(None, help="label overrides CSV"),
        on_error: str = typer.Option("raise", help="raise or skip bad recordings"),
        progress: bool = typer.Option(True),
        threads: Optional[int] = typer.Option(None, help="torch threads"),
    ):
        """Leave objects out: one detector per fold, each replayed on its unseen objects, pooled."""
        from slipsense.grasp_folds import run_folds

        cfg, runs, labels, data = _prepare(
            model, sets, size, epochs, seed, inner_folds, recordings, overrides, on_error, progress, threads, out
        )
        rep = run_folds(
            runs, labels, cfg, out, folds, meta={"command": _command(), **data}, progress=progress, echo=typer.echo
        )
        g, c = rep["pooled"]["per_grasp"], rep["pooled"]["clips"]
        typer.echo(
            f"pooled: warned in time {g['warned']}/{g['slip_runs']} (median lead "
            f"{g['median_lead_frames']} frames), premature {g['premature']}, missed {g['missed']}; "
            f"false-positive grasps {g['false_positive_grasps']}/{g['held_runs']}; alarming at rest "
            f"{g['runs_alarming_at_rest']} runs; clips: accuracy {c['accuracy']:.3f} (always-wiggle "
            f"{c['always_wiggle_accuracy']:.3f}), balanced {c['balanced_accuracy']:.3f}, F1 {c['f1']:.3f} "
            f"-> {out}/README.md"
        )

    app.add_typer(grasp_app, name="grasp")
