"""``python -m studies experiment <name>``: the experiments of :mod:`studies.experiments` (registered by studies/__main__.py).

Each command writes ``<name>.csv``, ``<name>.png``, ``<name>.md`` and ``config.json`` into ``--out``
(default ``reports/<name>``); ``--quick`` is the documented smaller setting (120x160 clips, patch
20x20, fewer epochs), labelled as such in every output.
"""

import functools
import inspect
from pathlib import Path
from typing import Any, List, Optional

import typer

from slipsense.cli.common import command_line, parse_hw
from slipsense.errors import ConfigError

HELP = (
    "Run the papers' experiments (and two beyond them) into report folders; "
    "`results` gathers them into studies/docs/results.md."
)
P = inspect.Parameter
_DEFINITIONS: list = []  # (name, train, fn), turned into commands by register()


def _opt(name: str, annotation, default, *decls: str, help: str = ""):
    return P(name, P.KEYWORD_ONLY, default=typer.Option(default, *decls, help=help), annotation=annotation)


#: Options every experiment takes (params only the first group).
BASE_OPTIONS = [
    _opt("out", Optional[Path], None, help="report folder (default reports/<experiment>)"),
    _opt(
        "quick",
        bool,
        False,
        "--quick",
        help="the documented smaller setting: 120x160 clips, patch 20x20, "
        "fewer epochs (labelled QUICK in every output)",
    ),
    _opt("seed", int, 0, help="seed of model initialisation, batch order and augmentation"),
    _opt("size", Optional[str], None, help="clip size HxW (default 240x320; --quick 120x160)"),
    _opt("patch", Optional[str], None, help="ViViT patch HxW (default: the 6x8 grid, 40x40 at 240x320)"),
    _opt(
        "set_",
        Optional[List[str]],
        None,
        "--set",
        help="model config MODEL.KEY=VALUE, e.g. --set vivit.dim=16 (repeatable)",
    ),
    _opt("progress", bool, True, "--progress/--no-progress", help="progress bars and per-epoch lines"),
]
TRAIN_OPTIONS = [
    _opt("epochs", Optional[int], None, help="epochs for every model (default: the paper's; --quick fewer)"),
    _opt("batch_size", Optional[int], None, help="batch size for every model (default: the paper's)"),
    _opt("lr", Optional[float], None, help="learning rate for every model (default: the paper's)"),
    _opt(
        "train_set",
        Optional[List[str]],
        None,
        "--train-set",
        help="training setting MODEL.KEY=VALUE, e.g. --train-set stnet.lr=1e-4 (repeatable)",
    ),
    _opt("data_seed", int, 0, help="seed of the object folds, wiggle windows and random clip splits"),
    _opt("fold", int, 0, help="held-out object fold"),
    _opt("folds", int, 5, help="number of object folds"),
    _opt("test_objects", Optional[str], None, help="comma-separated held-out objects (instead of --fold)"),
    _opt("augment", bool, True, "--augment/--no-augment", help="append the paper's transformed training copies"),
    _opt(
        "marker_copies",
        int,
        4,
        help="with --augment, marker windows: each one and copies-1 mirrored, shifted copies (markers on a grid)",
    ),
    _opt("recordings", Optional[Path], None, help="GelSight recordings folder (default $SLIPSENSE_DATA/gelsight-slip)"),
    _opt(
        "overrides",
        Optional[Path],
        None,
        help="hand-label CSV (default: the shipped configs/gelsight-label-overrides.csv)",
    ),
    _opt("no_overrides", bool, False, "--no-overrides", help="use the automatic labels only"),
    _opt("on_error", str, "raise", help="raise: stop at a bad video; skip: warn and leave it out"),
    _opt("device", str, "auto", help="auto, cpu, cuda, cuda:1..."),
    _opt("workers", int, 0, help="DataLoader worker processes"),
    _opt("max_steps_per_epoch", Optional[int], None, help="cap training steps per epoch (smoke runs)"),
    _opt("resume", bool, False, "--resume", help="continue interrupted training runs under OUT/runs"),
]


def _parse_model_sets(items: Optional[List[str]], option: str) -> dict:
    """``MODEL.KEY=VALUE`` items -> ``{model: {key: value}}``; values parsed as JSON where possible."""
    import json

    out: dict = {}
    for item in items or []:
        if "=" not in item or "." not in item.split("=", 1)[0]:
            raise ConfigError(f"{option} expects MODEL.KEY=VALUE, got {item!r}")
        lhs, raw = item.split("=", 1)
        model, key = lhs.split(".", 1)
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw
        out.setdefault(model.strip(), {})[key.strip()] = value
    return out


def _parse_list(text: str, kind, option: str) -> list:
    try:
        values = [kind(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ConfigError(f"{option} must be comma-separated numbers, got {text!r}") from None
    if not values:
        raise ConfigError(f"{option} is empty")
    return values


def _settings(name: str, kw: dict):
    from studies.experiments.settings import Settings

    return Settings(
        out=kw["out"] or Path("reports") / name,
        seed=kw["seed"],
        data_seed=kw.get("data_seed", 0),
        quick=kw["quick"],
        epochs=kw.get("epochs"),
        size=parse_hw(kw["size"], "--size"),
        patch=parse_hw(kw["patch"], "--patch"),
        batch_size=kw.get("batch_size"),
        lr=kw.get("lr"),
        device=kw.get("device", "auto"),
        workers=kw.get("workers", 0),
        fold=kw.get("fold", 0),
        folds=kw.get("folds", 5),
        test_objects=[o for o in (kw.get("test_objects") or "").split(",") if o],
        augment=kw.get("augment", True),
        marker_copies=kw.get("marker_copies", 4),
        max_steps_per_epoch=kw.get("max_steps_per_epoch"),
        model_overrides=_parse_model_sets(kw["set_"], "--set"),
        train_overrides=_parse_model_sets(kw.get("train_set"), "--train-set"),
        resume=kw.get("resume", False),
        progress=kw["progress"],
        command=command_line(),
    )


def _source(kw: dict):
    from studies.experiments.source import DataSource

    overrides: Any = None if kw["no_overrides"] else (kw["overrides"] or "default")
    return DataSource(kw["recordings"], overrides=overrides, on_error=kw["on_error"], progress=kw["progress"])


def _experiment(name: str, train: bool = True):
    """Mark ``fn(settings, kw, **own_options)`` as ``python -m studies experiment <name>`` (with the common options)."""

    def deco(fn):
        _DEFINITIONS.append((name, train, fn))
        return fn

    return deco


def _command(name: str, train: bool, fn):
    from slipsense.cli.common import friendly

    common = BASE_OPTIONS + (TRAIN_OPTIONS if train else [])
    common_names = [p.name for p in common]
    own = [p for p in inspect.signature(fn).parameters.values() if p.name not in ("settings", "kw")]

    @functools.wraps(fn)
    def wrapper(**kwargs):
        from slipsense.atomic import check_output_dir
        from slipsense.cli.common import check_seed

        kw = {k: kwargs.pop(k) for k in common_names}
        check_seed(kw["seed"])
        if "data_seed" in kw:
            check_seed(kw["data_seed"], "--data-seed")
        settings = _settings(name, kw)
        check_output_dir(settings.out, "--out")
        paths = fn(settings, kw, **kwargs)
        for key in ("csv", "md", "png", "config"):
            if key in paths:
                typer.echo(f"{key:6s} {paths[key]}")

    wrapper.__signature__ = inspect.Signature(own + common)
    wrapper.__annotations__ = {p.name: p.annotation for p in own + common}
    return friendly(wrapper)


@_experiment("params", train=False)
def params_cmd(settings, kw):
    """Parameter count of each model at the papers' settings, against the counts the papers state."""
    from studies.experiments.params import run_params

    return run_params(settings)["paths"]


@_experiment("video-compare")
def video_compare_cmd(
    settings,
    kw,
    resnet_weights: Optional[Path] = typer.Option(
        None, help="start the 3D ResNet-50 from these weights (.safetensors/.pt; pytorchvideo names accepted)"
    ),
    inference_clips: int = typer.Option(50, help="held-out clips timed at batch 1"),
    models: str = typer.Option("vivit,resnet3d50", help="the models compared: vivit, resnet3d50 or both"),
):
    """ViViT vs 3D ResNet-50 (ViViT paper III-B): parameters, training time, inference rate, held-out scores."""
    from studies.experiments.video_compare import run_video_compare

    chosen = [m.strip() for m in models.split(",") if m.strip()]
    return run_video_compare(
        settings, _source(kw), resnet_weights=resnet_weights, inference_clips=inference_clips, models=chosen
    )["paths"]


@_experiment("frames")
def frames_cmd(
    settings,
    kw,
    frames: str = typer.Option("5,4,3,2", help="clip lengths to compare"),
    test_fraction: float = typer.Option(0.1, help="random clip-level test share of the training objects"),
):
    """ViViT with 5, 4, 3, 2 frames (ViViT paper Fig. 7): train / test / held-out accuracy per epoch."""
    from studies.experiments.frames import run_frames

    return run_frames(
        settings, _source(kw), frames_list=_parse_list(frames, int, "--frames"), test_fraction=test_fraction
    )["paths"]


@_experiment("noise")
def noise_cmd(
    settings,
    kw,
    checkpoint: Optional[Path] = typer.Option(None, help="a trained ViViT .safetensors (default: train one here)"),
    stds: str = typer.Option("0,5,10,15,20,30,50", help="noise standard deviations (0..255 scale)"),
):
    """ViViT accuracy on held-out objects vs Gaussian noise std (ViViT paper Fig. 8)."""
    from studies.experiments.noise import run_noise

    return run_noise(settings, _source(kw), checkpoint=checkpoint, stds=_parse_list(stds, float, "--stds"))["paths"]


@_experiment("stnet")
def stnet_cmd(
    settings,
    kw,
    data: str = typer.Option("sim,real", help="sim (simulated sensor), real (tracked GelSight markers) or both"),
    preset: str = typer.Option("compact", help="STNet/TemNet size: compact (CPU), paper, paper-ff4096"),
    sim_sequences: Optional[int] = typer.Option(
        None, help="simulated sequences per object and pattern (default 24; --quick 2)"
    ),
    markers: str = typer.Option(
        "7x9",
        help="real data: ROWSxCOLS, every tracked marker resampled onto that grid; or N, the N markers nearest the centre",
    ),
    frames: int = typer.Option(12, help="frames per real marker window"),
):
    """STNet vs TemNet (STNet paper Table II, Fig. 7) on simulated and real marker sequences."""
    from studies.experiments.stnet import run_stnet

    kinds = [d.strip() for d in data.split(",") if d.strip()]
    return run_stnet(
        settings,
        _source(kw) if "real" in kinds else None,
        data=kinds,
        preset=preset,
        sim_sequences=sim_sequences,
        markers=markers,
        frames=frames,
    )["paths"]


@_experiment("marker-baseline", train=False)
def marker_baseline_cmd(
    settings,
    kw,
    sim_sequences: Optional[int] = typer.Option(
        None, help="simulated sequences per object and pattern (default 24, as experiment stnet; --quick 2)"
    ),
):
    """Is slip learnable in the simulated marker windows? Gradient boosting on displacement-field
    features, on experiment stnet's windows and split (no network)."""
    from studies.experiments.marker_baseline import run_marker_baseline

    return run_marker_baseline(settings, sim_sequences=sim_sequences)["paths"]


@_experiment("horizon")
def horizon_cmd(
    settings,
    kw,
    horizons: str = typer.Option("0,2,5,10", help="frames between a slip clip's end and the moment of slip"),
):
    """ViViT on held-out objects with clips ending 0, 2, 5, 10 frames before the slip (beyond the papers)."""
    from studies.experiments.horizon import run_horizon

    values = _parse_list(horizons, int, "--horizons")
    return run_horizon(settings, _source(kw), horizons=values)["paths"]


@_experiment("all-models")
def all_models_cmd(
    settings,
    kw,
    frames: int = typer.Option(5, help="frames per window (clips and marker sequences alike)"),
    markers: int = typer.Option(32, help="tracked markers per frame for STNet/TemNet"),
    preset: str = typer.Option("compact", help="STNet/TemNet size: compact, paper, paper-ff4096"),
):
    """ViViT, 3D ResNet-50, STNet, TemNet on the same held-out windows (beyond the papers)."""
    from studies.experiments.all_models import run_all_models

    return run_all_models(settings, _source(kw), frames=frames, n_markers=markers, preset=preset)["paths"]


def _results_cmd(
    reports: Path = typer.Option(Path("reports"), help="folder holding the report folders"),
    out: Path = typer.Option(Path("studies/docs/results.md"), help="Markdown file to write"),
):
    """Gather every report folder under --reports into one Markdown page, one section per experiment."""
    from slipsense.atomic import check_output_file
    from studies.experiments.results import collect_results, find_reports

    check_output_file(out, "--out")
    path = collect_results(reports, out)
    found = find_reports(reports)
    typer.echo(f"{sum(map(len, found.values()))} report(s) of {len(found)} experiment(s) -> {path}")


def register(app: typer.Typer) -> None:
    """Add ``python -m studies experiment <name>`` for every experiment and ``results``."""
    from slipsense.cli.common import friendly

    group = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False, help=HELP)
    for name, train, fn in _DEFINITIONS:
        group.command(name, help=fn.__doc__)(_command(name, train, fn))
    group.command("results")(friendly(_results_cmd))
    app.add_typer(group, name="experiment")
