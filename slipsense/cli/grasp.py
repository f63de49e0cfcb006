"""``slipsense grasp train`` and ``slipsense grasp folds``: detectors trained on whole grasps and
judged per grasp on objects they never saw (registered by slipsense.cli)."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from slipsense.cli.common import check_seed, command_line

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
    tree = merge(load_tree(config) if config else empty_tree(), given(options), layer)
    tree["model"]["name"] = tree["model"].get("name") or "motionnet"
    return tree


def report_training(res: dict, echo=typer.echo) -> None:
    """What a training prints after it: the detector and its operating point where one was chosen,
    and the held-out objects' per-grasp outcomes when some were held out."""
    op = res.get("operating_point")
    if op:
        echo(
            f"detector -> {res['checkpoint']} (threshold {op['threshold']:g}, debounce {op['debounce']}, "
            f"chosen on {op.get('chosen_on', 'the training objects')})"
        )
    if res.get("held_out") and res.get("per_grasp"):
        g, c = res["per_grasp"], res["clips"]
        echo(
            f"held-out objects ({', '.join(res['held_out'])}): warned in time {g['warned']}/{g['slip_runs']}, "
            f"premature {g['premature']}, missed {g['missed']}, false-positive grasps "
            f"{g['false_positive_grasps']}/{g['held_runs']}; clips: accuracy {c['accuracy']:.3f} "
            f"(always-wiggle {c['always_wiggle_accuracy']:.3f}), balanced {c['balanced_accuracy']:.3f}, "
            f"F1 {c['f1']:.3f}"
        )


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
            None, help="a model that takes whole grasps (motionnet by default; `slipsense models` lists them all)"
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
        from slipsense.training.recipe import fit

        tree = _grasp_tree(config, model, sets, size, epochs, seed, inner_folds, recordings, overrides, on_error)
        tree["data"].update(fold=fold, folds=folds)
        res = fit(tree, out, progress=progress, resume=resume, workers=workers, threads=threads, command=command_line())
        report_training(res)

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
        from slipsense.training.recipe import cross_validate

        tree = _grasp_tree(config, model, sets, size, epochs, seed, inner_folds, recordings, overrides, on_error)
        rep = cross_validate(
            tree, out, folds, progress=progress, workers=workers, threads=threads, command=command_line()
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
        src: Path = typer.Argument(
            ..., help="a `slipsense grasp folds` report folder (its fold files keep inner traces)"
        ),
        out: Path = typer.Option(..., help="report folder to write: README.md, folds.json, tradeoff.png"),
        max_held_alarm: Optional[float] = typer.Option(
            0.05, help="at most this fraction of held grasps may alarm (0.05: 5%); a negative value: best score"
        ),
    ):
        """Choose every fold's operating point again by another rule, on its training objects' inner
        traces, and pool: no training (seconds)."""
        from slipsense.atomic import check_output_dir
        from slipsense.evaluation.folds import rechoose

        check_output_dir(out, "--out")
        k = None if max_held_alarm is not None and max_held_alarm < 0 else max_held_alarm
        rep = rechoose(src, out, k, command=command_line(), echo=typer.echo)
        g = rep["pooled"]["per_grasp"]
        ci = g.get("intervals", {})
        typer.echo(
            f"pooled: warned in time {g['warned']}/{g['slip_runs']} (95% {100 * ci.get('warned_low', float('nan')):.0f}-"
            f"{100 * ci.get('warned_high', float('nan')):.0f}%), premature {g['premature']}; false-positive grasps "
            f"{g['false_positive_grasps']}/{g['held_runs']} (95% {100 * ci.get('fp_low', float('nan')):.0f}-"
            f"{100 * ci.get('fp_high', float('nan')):.0f}%) -> {out}/README.md"
        )

    @grasp_app.command("compare")
    @friendly
    def compare_cmd(
        reports: List[Path] = typer.Argument(..., help="`slipsense grasp folds` report folders"),
        label: List[str] = typer.Option([], "--label", help="a row's name, one per report in order (repeat)"),
        out: Optional[Path] = typer.Option(None, help="Markdown file to write (default: print only)"),
    ):
        """Folds reports side by side: slips warned in time, premature, missed, false-positive grasps
        with their intervals, one row per report (for a detector and its non-learned baseline)."""
        from slipsense.atomic import check_output_file, write_text
        from slipsense.evaluation.folds import compare_markdown

        if out is not None:
            check_output_file(out, "--out")
        text = compare_markdown(reports, label, command=command_line())
        if out is not None:
            write_text(out, text)
        typer.echo(text if out is None else f"{len(reports)} report(s) -> {out}")

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
        from slipsense.config import gelsight_recordings, resolve_path
        from slipsense.evaluation.precursors import aligned_means, precursor_table, summary, write_report
        from slipsense.training.grasps import load_grasp_data

        check_output_dir(out, "--out")
        root = resolve_path(recordings or gelsight_recordings())
        runs, _ = load_grasp_data(root, overrides, (30, 40), progress=progress)
        rows = precursor_table(runs, window)
        write_report(rows, aligned_means(runs), out, command=command_line(), window=window)
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

    @grasp_app.command("promise")
    @friendly
    def promise_cmd(
        checkpoint: Path = typer.Argument(..., help="a grasp detector whose operating point came from inner folds"),
        workers: Optional[int] = typer.Option(None, help="training processes (default: one per core)"),
        progress: bool = typer.Option(True),
    ):
        """State what a detector trained before checkpoints carried it promises on new objects: its
        inner folds trained again, judged at its threshold (held-alarm rate, bound counting objects)."""
        from slipsense.evaluation.pergrasp import promise_text
        from slipsense.checkpoint import read_info
        from slipsense.training.recipe import restate_promise

        restate_promise(checkpoint, workers=workers, progress=progress)
        typer.echo(f"{checkpoint}: {promise_text(read_info(checkpoint)['operating_point'])}")

    @grasp_app.command("adaptation")
    @friendly
    def adaptation_cmd(
        recordings: Path = typer.Option(..., help="grasps of another sensor, one camera each, labelled per grasp"),
        out: Path = typer.Option(Path("reports/adaptation"), help="report folder"),
        epochs: int = typer.Option(10, help="epochs of every training"),
        also: Optional[Path] = typer.Option(
            None, help="the shipped detector's own recordings: add the row trained from scratch on both sets"
        ),
        seed: int = typer.Option(0, help="seed of the grasp draws and the trainings"),
        workers: Optional[int] = typer.Option(
            None, min=1, help="processes training side by side (default: one per core; results do not depend on it)"
        ),
        progress: bool = typer.Option(True),
    ):
        """Leave-objects-out on a new sensor: the shipped one-finger detector as is, recalibrated,
        fine-tuned on 5, 10, 20 and all grasps, trained on the set alone, beside the baselines."""
        from slipsense.atomic import check_output_dir
        from slipsense.errors import ConfigError
        from slipsense.experiments.adaptation import adaptation_study, table, write

        if not 1 <= epochs <= 1000:
            raise ConfigError(f"--epochs must be in 1..1000, got {epochs}")
        check_output_dir(out, "--out")
        doc = adaptation_study(
            recordings, epochs=epochs, seed=check_seed(seed), progress=progress, also=also, workers=workers
        )
        doc["command"] = command_line()
        paths = write(doc, out)
        typer.echo(table(doc))
        typer.echo(f"-> {', '.join(str(p) for p in paths)}")

    app.add_typer(grasp_app, name="grasp")
