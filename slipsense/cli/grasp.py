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
    "section.key=value: train.KEY (epochs, lr, chunk, negatives, hard_negatives, onset_frames, horizon, "
    "inner_folds, positive_weight, ...), model.KEY (width, lags, dilations, ...) or data.KEY; a bare "
    "KEY=VALUE is a training setting if it names one, else a model setting"
)


def _prepare(
    config, model, sets, size, epochs, seed, inner_folds, recordings, overrides, on_error, progress, threads, out=None
):
    """The configuration tree's training config, data and stored metadata (:func:`prepare_tree`)."""
    tree = _grasp_tree(config, model, sets, size, epochs, seed, inner_folds, recordings, overrides, on_error)
    return prepare_tree(tree, progress, threads, out)


def _grasp_tree(config, model, sets, size, epochs, seed, inner_folds, recordings, overrides, on_error):
    """The configuration tree: defaults < --config < options < --set."""
    from slipsense.cli.common import parse_hw
    from slipsense.training.grasps import GraspTrainConfig
    from slipsense.run_config import empty_tree, given, load_tree, merge, parse_sets

    layer = parse_sets(sets, bare="bare")
    train_keys = set(GraspTrainConfig.__dataclass_fields__) - {"model", "model_config"}
    for key, value in layer.pop("bare", {}).items():  # a bare key is a training setting if it names one
        layer.setdefault("train" if key in train_keys else "model", {})[key] = value
    options = {
        "model": {"name": model, "image_size": list(parse_hw(size)) if size else None},
        "data": {"recordings": recordings, "overrides": overrides, "on_error": on_error},
        "train": {"epochs": epochs, "inner_folds": inner_folds, "seed": seed},
    }
    return merge(load_tree(config) if config else empty_tree(), given(options), layer)


def prepare_tree(tree, progress: bool = True, threads: int | None = None, out=None):
    """From a grasp configuration tree (model / data / train sections): the training config, the
    runs, their labels and the metadata checkpoints keep."""
    from slipsense.cli.common import default_recordings, check_seed
    from slipsense.training.grasps import GraspTrainConfig, load_grasp_data, make_config
    from slipsense.run_config import check_keys, to_plain

    if threads is not None:
        import torch

        torch.set_num_threads(threads)
    from slipsense.atomic import check_output_dir

    check_output_dir(out, "--out")
    train_keys = set(GraspTrainConfig.__dataclass_fields__) - {"model", "model_config"}
    check_keys(
        tree,
        {"train": train_keys, "data": ("recordings", "overrides", "on_error", "sensor"), "model": None},
        "grasp configuration",
    )
    name = tree["model"].pop("name", "motionnet")
    tree["train"]["seed"] = check_seed(tree["train"].get("seed", 0))
    settings = {**tree["train"], **{f"model.{k}": v for k, v in tree["model"].items()}}
    cfg = make_config(name, settings)
    image_size = tuple(cfg.model_config.get("image_size") or _model_size(name))
    from slipsense.config import resolve_path

    root = resolve_path(tree["data"].get("recordings") or default_recordings())
    overrides = tree["data"].get("overrides")
    overrides = resolve_path(overrides) if overrides is not None else None
    from slipsense.sensors.spec import GELSIGHT_MINI, sensor_named

    sensor = sensor_named(tree["data"]["sensor"]) if tree["data"].get("sensor") else GELSIGHT_MINI
    runs, labels = load_grasp_data(
        root, overrides, image_size, tree["data"].get("on_error", "raise"), progress, sensor=sensor
    )
    from slipsense.models import build

    sensors = build(name, **cfg.model_config).sensors
    if sensors == 1:  # a one-finger detector: each camera of a run is a grasp of its own
        from slipsense.recordings.runs import per_sensor

        runs = per_sensor(runs)
    from slipsense.config import portable_path

    tree["model"] = {"name": name, **cfg.model_config}
    data = {
        "recordings": portable_path(root),
        "overrides": None if overrides is None else portable_path(overrides),
        "image_size": list(image_size),
        "sensors_per_grasp": sensors,
        "sensor": sensor.to_dict(),
        "config": to_plain(tree),
    }
    return cfg, runs, labels, data


def train_from_tree(
    tree,
    out,
    *,
    held: list[str] | None = None,
    fold: int | None = None,
    folds: int = 5,
    progress: bool = True,
    resume: bool = False,
    workers: int | None = None,
    threads: int | None = None,
    echo=typer.echo,
) -> dict:
    """Train a grasp detector from a configuration tree (what ``slipsense grasp train`` and
    ``slipsense train --model motionnet`` run): every object but ``held`` (or fold ``fold`` of
    ``folds``), writing ``out/detector.safetensors``, ``metrics.csv``, ``curves.png``, ``config.yaml``."""
    from slipsense.atomic import write_text
    from slipsense.errors import ConfigError
    from slipsense.training.grasp_detector import object_split, train_detector
    from slipsense.run_config import dump_tree

    import os

    ranked = int(os.environ.get("WORLD_SIZE", "1")) > 1
    if ranked and workers not in (None, 1):
        raise ConfigError("under torchrun every training is shared out between the ranks: leave --workers out")
    progress = progress and int(os.environ.get("RANK", "0")) == 0
    cfg, runs, labels, data = prepare_tree(tree, progress, threads, out)
    held = list(held or [])
    if fold is not None:
        split = object_split([r for r in runs if r.usable], folds, cfg.folds_seed)
        if not 0 <= fold < len(split):
            raise ConfigError(f"--fold must be in 0..{len(split) - 1}, got {fold}")
        held = split[fold]
    data["command"] = _command()
    res = train_detector(runs, labels, cfg, out, held, data=data, progress=progress, workers=workers, resume=resume)
    if ranked and int(os.environ.get("RANK", "0")) != 0:
        return res  # rank 0 writes and reports
    write_text(Path(out) / "config.yaml", dump_tree(data["config"]))
    op = res["operating_point"]
    echo(
        f"detector -> {res['checkpoint']} (threshold {op['threshold']:g}, debounce {op['debounce']}, "
        f"chosen on {op['chosen_on']})"
    )
    if held:
        g, c = res["per_grasp"], res["clips"]
        echo(
            f"held-out objects ({', '.join(held)}): warned in time {g['warned']}/{g['slip_runs']}, "
            f"premature {g['premature']}, missed {g['missed']}, false-positive grasps "
            f"{g['false_positive_grasps']}/{g['held_runs']}; clips: accuracy {c['accuracy']:.3f} "
            f"(always-wiggle {c['always_wiggle_accuracy']:.3f}), balanced {c['balanced_accuracy']:.3f}, "
            f"F1 {c['f1']:.3f}"
        )
    return res


def _model_size(name: str) -> tuple[int, int]:
    from slipsense.models import build

    return tuple(build(name).image_size)


def _command() -> str:
    return "slipsense " + " ".join(shlex.quote(a) for a in sys.argv[1:])


def register(app: typer.Typer) -> None:
    from slipsense.cli.common import friendly

    @grasp_app.command("train")
    @friendly
    def train(
        out: Path = typer.Option(..., help="output folder: detector.safetensors, metrics.csv, curves.png"),
        config: Optional[Path] = typer.Option(
            None, help="a configuration tree (YAML: model/data/train), e.g. configs/motionnet.yaml"
        ),
        model: Optional[str] = typer.Option(
            None, help="a model that takes whole grasps (motionnet (default), motion-energy)"
        ),
        fold: Optional[int] = typer.Option(
            None, help="hold out this fold of objects (with --folds); default: train on every object"
        ),
        folds: int = typer.Option(5, help="folds by object, with --fold"),
        sets: Optional[List[str]] = typer.Option(None, "--set", help=SET_HELP),
        size: Optional[str] = typer.Option(None, help="grey frame size HxW (default: the model's, 30x40)"),
        epochs: Optional[int] = typer.Option(None, help="training epochs"),
        inner_folds: Optional[int] = typer.Option(None, help="inner folds for the operating point (0: training runs)"),
        seed: Optional[int] = typer.Option(None, help="seed of everything random (default 0)"),
        recordings: Optional[Path] = typer.Option(
            None, help="recordings folder (default: $SLIPSENSE_DATA/gelsight-slip)"
        ),
        overrides: Optional[Path] = typer.Option(None, help="label overrides CSV"),
        on_error: Optional[str] = typer.Option(None, help="raise (default) or skip bad recordings"),
        progress: bool = typer.Option(True),
        threads: Optional[int] = typer.Option(None, help="torch threads (with --workers 1; each worker uses one)"),
        workers: Optional[int] = typer.Option(
            None, min=1, help="processes training side by side (default: one per core; results do not depend on it)"
        ),
        resume: bool = typer.Option(False, help="continue a killed training from OUT/resume/ (same weights)"),
    ):
        """Train a grasp detector (and its alarm operating point, chosen on its training objects)."""
        tree = _grasp_tree(config, model, sets, size, epochs, seed, inner_folds, recordings, overrides, on_error)
        train_from_tree(
            tree, out, fold=fold, folds=folds, progress=progress, resume=resume, workers=workers, threads=threads
        )

    @grasp_app.command("folds")
    @friendly
    def folds_cmd(
        out: Path = typer.Option(..., help="report folder: fold<k>.json, folds.json, README.md, tradeoff.png"),
        config: Optional[Path] = typer.Option(
            None, help="a configuration tree (YAML: model/data/train), e.g. configs/motionnet.yaml"
        ),
        model: Optional[str] = typer.Option(None, help="a model that takes whole grasps (default motionnet)"),
        folds: int = typer.Option(5, help="folds by object"),
        sets: Optional[List[str]] = typer.Option(None, "--set", help=SET_HELP),
        size: Optional[str] = typer.Option(None, help="grey frame size HxW"),
        epochs: Optional[int] = typer.Option(None, help="training epochs"),
        inner_folds: Optional[int] = typer.Option(None, help="inner folds for the operating point (0: training runs)"),
        seed: Optional[int] = typer.Option(None, help="seed of everything random (default 0)"),
        recordings: Optional[Path] = typer.Option(None, help="recordings folder"),
        overrides: Optional[Path] = typer.Option(None, help="label overrides CSV"),
        on_error: Optional[str] = typer.Option(None, help="raise (default) or skip bad recordings"),
        progress: bool = typer.Option(True),
        threads: Optional[int] = typer.Option(None, help="torch threads (with --workers 1; each worker uses one)"),
        workers: Optional[int] = typer.Option(
            None, min=1, help="processes training side by side (default: one per core; results do not depend on it)"
        ),
    ):
        """Leave objects out: one detector per fold, each replayed on its unseen objects, pooled."""
        from slipsense.evaluation.folds import run_folds

        cfg, runs, labels, data = _prepare(
            config,
            model,
            sets,
            size,
            epochs,
            seed,
            inner_folds,
            recordings,
            overrides,
            on_error,
            progress,
            threads,
            out,
        )
        rep = run_folds(
            runs,
            labels,
            cfg,
            out,
            folds,
            meta={"command": _command(), **data},
            progress=progress,
            echo=typer.echo,
            workers=workers,
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

    @grasp_app.command("rechoose")
    @friendly
    def rechoose_cmd(
        src: list[Path] = typer.Argument(
            ...,
            help="a `slipsense grasp folds` report folder (its fold files keep inner traces); several reports "
            "of the same recipe and folds with other seeds: their traces are averaged (a seed ensemble)",
        ),
        out: Path = typer.Option(..., help="report folder to write: README.md, folds.json, tradeoff.png"),
        max_held_alarm: Optional[float] = typer.Option(
            0.05, help="at most this fraction of held grasps may alarm (0.05: 5%); a negative value: best score"
        ),
        any_recipe: bool = typer.Option(
            False, help="the reports may be different recipes on the same folds (an ensemble of different detectors)"
        ),
    ):
        """Choose every fold's operating point again by another rule, on its training objects' inner
        traces, and pool: no training (seconds). Several reports: the mean of their detectors."""
        from slipsense.atomic import check_output_dir
        from slipsense.evaluation.folds import rechoose

        check_output_dir(out, "--out")
        k = None if max_held_alarm is not None and max_held_alarm < 0 else max_held_alarm
        rep = rechoose(src, out, k, command=_command(), echo=typer.echo, any_recipe=any_recipe)
        g = rep["pooled"]["per_grasp"]
        ci = g.get("intervals", {})
        typer.echo(
            f"pooled: warned in time {g['warned']}/{g['slip_runs']} (95% {100 * ci.get('warned_low', float('nan')):.0f}-"
            f"{100 * ci.get('warned_high', float('nan')):.0f}%), premature {g['premature']}; false-positive grasps "
            f"{g['false_positive_grasps']}/{g['held_runs']} (95% {100 * ci.get('fp_low', float('nan')):.0f}-"
            f"{100 * ci.get('fp_high', float('nan')):.0f}%) -> {out}/README.md"
        )

    @grasp_app.command("precursors")
    @friendly
    def precursors_cmd(
        out: Path = typer.Option(..., help="report folder: README.md, precursors.csv/.json/.png"),
        recordings: Optional[Path] = typer.Option(None, help="recordings folder (default: the shared recordings)"),
        overrides: Optional[Path] = typer.Option(None, help="label overrides CSV"),
        window: int = typer.Option(10, min=2, max=100, help="frames before the moment of slip that are measured"),
        progress: bool = typer.Option(True),
    ):
        """Which slips show anything before contact is lost, against their own grasp and held grasps."""
        from slipsense.atomic import check_output_dir
        from slipsense.cli.common import default_recordings
        from slipsense.config import resolve_path
        from slipsense.evaluation.precursors import aligned_means, precursor_table, summary, write_report
        from slipsense.training.grasps import load_grasp_data

        check_output_dir(out, "--out")
        root = resolve_path(recordings or default_recordings())
        runs, _ = load_grasp_data(root, overrides, (30, 40), progress=progress)
        rows = precursor_table(runs, window)
        write_report(rows, aligned_means(runs), out, command=_command(), window=window)
        s = summary(rows)
        typer.echo(
            f"{s['any']} of {s['slip_runs']} slips stand out on some signal before contact is lost (motion "
            f"{s['motion']}, change over 1 s {s['change_1s']}, contact fading {s['contact_fading']}) -> {out}/README.md"
        )

    @grasp_app.command("ceiling")
    @friendly
    def ceiling_cmd(
        reports: List[Path] = typer.Argument(..., help="folds reports (grasp folds --out) with their fold files"),
        fp: List[int] = typer.Option([0, 4, 8, 13], "--fp", help="false-positive grasps allowed (repeat)"),
        show_phases: bool = typer.Option(False, "--phases", help="where held grasps peak and slips are lost"),
    ):
        """Bounds, not results: the most slips any operating point tuned on the held-out runs could warn of."""
        from slipsense.errors import ConfigError
        from slipsense.evaluation.ceiling import held_out_traces, one_threshold, per_fold, phases

        if any(k < 0 for k in fp):
            raise ConfigError(f"--fp must be 0 or more, got {fp}")
        for report in reports:
            traces = held_out_traces(report)
            cells = []
            for k in fp:
                one = one_threshold(traces, k)
                warned, premature = per_fold(traces, k)
                cells.append(f"<= {k} FP: one threshold {one[1]} ({one[2]} premature), per fold {warned} ({premature})")
            slips = sum(m is not None for m in traces[1])
            typer.echo(f"{report} (slips {slips}): " + " | ".join(cells))
            if show_phases:
                ph = phases(traces)
                typer.echo(
                    f"  held grasps' 10 highest peaks at frames {ph['held_peaks']}; slips lost at frames < 60: "
                    f"{ph['lost_before_60']}, 60-150: {ph['lost_60_150']}, > 150: {ph['lost_after_150']}"
                )

    app.add_typer(grasp_app, name="grasp")
