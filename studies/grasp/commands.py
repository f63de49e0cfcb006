"""``python -m studies grasp ...``: the grasp analyses behind the project's findings (bounds,
precursors, other operating-point rules, reports side by side, restated promises, the adaptation
study and the early-warning sweep). Each writes a report folder; none is needed to use a detector."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from slipsense.atomic import check_output_dir, check_output_file, write_text
from slipsense.checkpoint import read_info
from slipsense.cli.common import check_seed, command_line, friendly
from slipsense.cli.live import THREADS_HELP, set_threads
from slipsense.paths import data_root, gelsight_recordings, resolve_path
from slipsense.errors import ConfigError
from slipsense.measures.promise import promise_text
from slipsense.resources import shipped_model
from slipsense.training.grasps import load_grasp_data
from studies.grasp.adaptation import adaptation_study, table, write
from studies.grasp.ceiling import held_out_traces, one_threshold, per_fold, phases
from studies.grasp.derive import adapt_report, derive_sensor, resized_frame_folders, slower_frame_folders
from studies.grasp.early_warning import DEFAULT_THRESHOLDS, run_early_warning
from studies.grasp.hold import hold_study
from studies.grasp.hold import table as hold_table
from studies.grasp.learning_curve import curve_table, learning_curve
from studies.grasp.looks import looks_folds_study, looks_study
from studies.grasp.looks import table as looks_table
from studies.grasp.looks import write as write_looks
from studies.grasp.precursors import aligned_means, precursor_table, summary, write_report
from studies.grasp.promise import promise_from_report, restate_promise
from studies.grasp.rates import folds_study, lift_study, rates_study
from studies.grasp.rates import folds_table as rates_folds_table
from studies.grasp.rates import table as rates_table
from studies.grasp.rates import write as write_rates
from studies.grasp.rates import write_folds as write_rates_folds
from studies.grasp.rechoose import compare_markdown, rechoose

group = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="Grasp analyses: bounds, precursors, operating-point rules, comparisons, adaptation, early warning.",
)


@group.command("early-warning")
@friendly
def early_warning(
    checkpoint: Optional[Path] = typer.Option(None, help="video-model checkpoint (default: the shipped detector)"),
    recordings: Optional[Path] = typer.Option(None, help="recordings folder (default: $SLIPSENSE_DATA/gelsight-slip)"),
    out: Path = typer.Option(..., help="output folder for CSV, JSON and PNGs"),
    thresholds: str = typer.Option(
        DEFAULT_THRESHOLDS,
        help="comma-separated alarm thresholds (the checkpoint's own operating point is always added)",
    ),
    horizon: float = typer.Option(2.0, help="seconds before the moment of slip in which a first alarm is in time"),
    debounce: Optional[int] = typer.Option(
        None, help="frames in a row above the threshold before an alarm (default: the checkpoint's)"
    ),
    overrides: Optional[Path] = typer.Option(None, help="label overrides CSV (object,experiment,camera,moment)"),
    labels: Optional[Path] = typer.Option(None, help="labels CSV (slipsense label) instead of automatic labels"),
    combine: Optional[str] = typer.Option(
        None, help="max or mean of the two cameras' probabilities (models that judge each camera apart)"
    ),
    backend: str = typer.Option("torch", help="torch or onnx"),
    dtype: str = typer.Option("float32", help="float32, or int8 with --backend onnx"),
    limit: Optional[int] = typer.Option(None, help="replay only the first N runs"),
    fps: Optional[float] = typer.Option(
        None, help="frame rate, for lead times in ms (default: the checkpoint's sensor's)"
    ),
    on_error: str = typer.Option("raise", help="raise or skip bad recordings folders"),
    progress: bool = typer.Option(True),
    threads: Optional[int] = typer.Option(None, help=THREADS_HELP),
):
    """Per-grasp early warning: slips warned in time, premature, missed; grasps that held yet alarmed."""
    set_threads(threads)
    summary = run_early_warning(
        checkpoint,
        recordings,
        out,
        thresholds,
        labels,
        combine,
        backend,
        limit,
        fps,
        on_error,
        progress,
        dtype,
        horizon=horizon,
        debounce=debounce,
        overrides=overrides,
    )
    typer.echo(summary)


@group.command("rechoose")
@friendly
def rechoose_cmd(
    src: Path = typer.Argument(
        ..., help="a `slipsense train --cross-validate` report folder (its fold files keep inner traces)"
    ),
    out: Path = typer.Option(..., help="report folder to write: README.md, folds.json, tradeoff.png"),
    max_held_alarm: Optional[float] = typer.Option(
        0.05, help="at most this fraction of held grasps may alarm (0.05: 5%); a negative value: best score"
    ),
):
    """Choose every fold's operating point again by another rule, on its training objects' inner
    traces, and pool: no training (seconds)."""

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


@group.command("compare")
@friendly
def compare_cmd(
    reports: List[Path] = typer.Argument(..., help="`slipsense train --cross-validate` report folders"),
    label: List[str] = typer.Option([], "--label", help="a row's name, one per report in order (repeat)"),
    out: Optional[Path] = typer.Option(None, help="Markdown file to write (default: print only)"),
):
    """Folds reports side by side: slips warned in time, premature, missed, false-positive grasps
    with their intervals, one row per report (for a detector and its non-learned baseline)."""

    if out is not None:
        check_output_file(out, "--out")
    text = compare_markdown(reports, label, command=command_line())
    if out is not None:
        write_text(out, text)
    typer.echo(text if out is None else f"{len(reports)} report(s) -> {out}")


@group.command("precursors")
@friendly
def precursors_cmd(
    out: Path = typer.Option(..., help="report folder: README.md, precursors.csv/.json/.png"),
    recordings: Optional[Path] = typer.Option(None, help="recordings folder (default: the shared recordings)"),
    overrides: Optional[Path] = typer.Option(None, help="label overrides CSV"),
    window: int = typer.Option(10, min=2, max=100, help="frames before the moment of slip that are measured"),
    progress: bool = typer.Option(True),
):
    """Which slips show anything before contact is lost, against their own grasp and held grasps."""

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


@group.command("ceiling")
@friendly
def ceiling_cmd(
    reports: List[Path] = typer.Argument(
        ..., help="folds reports (slipsense train --cross-validate --out) with their fold files"
    ),
    fp: List[int] = typer.Option([0, 4, 8, 13], "--fp", help="false-positive grasps allowed (repeat)"),
    show_phases: bool = typer.Option(False, "--phases", help="where held grasps peak and slips are lost"),
):
    """Bounds, not results: the most slips any operating point tuned on the held-out runs could warn of."""

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


@group.command("promise")
@friendly
def promise_cmd(
    checkpoint: Path = typer.Argument(..., help="a grasp detector whose operating point came from inner folds"),
    workers: Optional[int] = typer.Option(None, help="training processes (default: one per core)"),
    unseen: Optional[Path] = typer.Option(
        None, help="instead: the promise from this cross-validation report of its recipe (objects it never saw)"
    ),
    row: Optional[str] = typer.Option(None, help="with --unseen: the adaptation study's row (its first words)"),
    progress: bool = typer.Option(True),
):
    """State what a detector promises on new objects: its inner folds trained again, judged at its
    threshold (held-alarm rate, bound counting objects); or, with --unseen, what its recipe's
    leave-objects-out cross-validation measured on held grasps of objects it never saw."""

    if unseen is not None:
        promise_from_report(checkpoint, unseen, row)
    else:
        restate_promise(checkpoint, workers=workers, progress=progress)
    typer.echo(f"{checkpoint}: {promise_text(read_info(checkpoint)['operating_point'])}")


@group.command("adaptation")
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


@group.command("rates")
@friendly
def rates_cmd(
    out: Path = typer.Option(Path("reports/rates"), help="report folder: README.md (the table), rates.json"),
    recordings: Optional[Path] = typer.Option(None, help="recordings folder (default: the shared recordings)"),
    checkpoint: Optional[Path] = typer.Option(None, help="a two-finger detector (default: the shipped one)"),
    folds: Optional[Path] = typer.Option(
        None,
        help="instead: a folder of fold<k>/ trainings (slipsense train --fold k): each judged on its held-out objects",
    ),
    baseline_folds: Optional[Path] = typer.Option(
        None, help="with --folds: the non-learned baseline's fold<k>/ beside it"
    ),
    lift: Optional[Path] = typer.Option(
        None, help="with --folds: the gelsight-lift data too, as recorded and at half its rate"
    ),
    seed: int = typer.Option(0, help="seed of the dropped frames"),
    progress: bool = typer.Option(True, help="progress bars"),
):
    """The shipped detector at 15 and 12.5 frames/s and with 10% of frame pairs dropped, on its clock and
    without it, judged per grasp; with --folds, a recipe's folds on their held-out objects."""
    check_output_dir(out, "--out")
    if folds is not None:
        doc = folds_study(
            resolve_path(recordings or gelsight_recordings()), folds, baseline_folds, check_seed(seed), progress
        )
        if lift is not None:
            doc["lift"] = lift_study(resolve_path(lift), progress)
        paths = write_rates_folds(doc, out, command_line())
        typer.echo(rates_folds_table(doc))
        typer.echo(f"-> {', '.join(str(p) for p in paths)}")
        return
    doc = rates_study(
        resolve_path(recordings or gelsight_recordings()),
        checkpoint or shipped_model(),
        seed=check_seed(seed),
        progress=progress,
    )
    paths = write_rates(doc, out, command_line())
    typer.echo(rates_table(doc))
    typer.echo(f"-> {', '.join(str(p) for p in paths)}")


@group.command("derive")
@friendly
def derive_cmd(
    out: Path = typer.Option(..., help="folder for the derived sensor's grasps (frame folders, sensor.json)"),
    recordings: Optional[Path] = typer.Option(None, help="recordings folder (default: the shared recordings)"),
    width: int = typer.Option(160, help="frame width, pixels"),
    height: int = typer.Option(120, help="frame height, pixels"),
    every: int = typer.Option(2, help="keep every N-th frame (2: 12.5 frames/s from 25)"),
    camera: str = typer.Option("camera_0", help="the one camera kept"),
    frames: bool = typer.Option(False, help="instead: a frame-folder set (gelsight-lift) at 1/--every of its rate"),
    progress: bool = typer.Option(True, help="progress bars"),
):
    """A user's own sensor made from the shared recordings: one camera, smaller frames, a lower rate,
    as frame folders labelled per grasp (what slipsense adapt is measured on); with --frames, the
    gelsight-lift grasps at a lower rate."""
    if frames:
        n = slower_frame_folders(resolve_path(recordings or data_root() / "gelsight-lift"), out, every)
        typer.echo(f"{n} grasps -> {out}")
        return
    n = derive_sensor(
        resolve_path(recordings or gelsight_recordings()), out, (height, width), every, camera, progress=progress
    )
    typer.echo(f"{n} grasps -> {out}")


@group.command("resize")
@friendly
def resize_cmd(
    out: Path = typer.Option(..., help="folder for the resized grasps (frame folders, slip.txt, sensor.json)"),
    recordings: Optional[Path] = typer.Option(None, help="frame-folder grasps (default: the shared gelsight-lift)"),
    height: int = typer.Option(300, min=8, max=2048, help="frame height, pixels"),
    width: int = typer.Option(400, min=8, max=2048, help="frame width, pixels"),
    fps: float = typer.Option(30.0, help="the frame rate sensor.json states (gelsight-lift: 30 frames/s)"),
    progress: bool = typer.Option(True, help="progress bars"),
):
    """Grasps as folders of frames (gelsight-lift) as a user's sensor of another frame size gives them:
    every frame resized, slip.txt in each slipped grasp, a sensor.json stating the rate and size
    (what `slipsense train --model shear-retention --recordings OUT` is checked on, docs/new-sensor.md)."""
    n = resized_frame_folders(
        resolve_path(recordings or data_root() / "gelsight-lift"), out, (height, width), fps, progress=progress
    )
    typer.echo(f"{n} grasps of {height} x {width} frames -> {out}")


@group.command("adapt-report")
@friendly
def adapt_report_cmd(
    sensor: Path = typer.Option(..., help="the derived sensor's folder (python -m studies grasp derive --out ...)"),
    work: Path = typer.Option(..., help="slipsense adapt's --out (kept: a second run resumes from its folds)"),
    out: Path = typer.Option(Path("reports/adapt-derived"), help="report folder: README.md, adapt.json"),
    derive: str = typer.Option(
        "python -m studies grasp derive --out SENSOR", help="the command that made the sensor (for the report)"
    ),
    progress: bool = typer.Option(True, help="progress bars"),
):
    """slipsense adapt on a derived sensor, timed, and its report: every candidate and baseline judged on
    objects it never saw, what was kept and why."""
    import time

    from slipsense.adapt import adapt

    t0 = time.perf_counter()
    adapt(sensor, work, progress=progress, echo=typer.echo)
    seconds = time.perf_counter() - t0
    commands = [
        derive,
        f"slipsense adapt --recordings SENSOR --out WORK   # timed here: {seconds:.0f} s",
        f"{command_line()}",
    ]
    typer.echo(f"-> {adapt_report(work, out, commands, seconds, sensor)}")


@group.command("looks")
@friendly
def looks_cmd(
    out: Path = typer.Option(Path("reports/looks"), help="report folder: README.md (the table), looks.json"),
    recordings: Optional[Path] = typer.Option(None, help="recordings folder (default: the shared recordings)"),
    checkpoint: Optional[Path] = typer.Option(None, help="a two-finger detector (default: the shipped one)"),
    folds: Optional[Path] = typer.Option(
        None, help="instead: a folder of fold<k>/ trainings (slipsense train --fold k), each on its held-out objects"
    ),
    progress: bool = typer.Option(True, help="progress bars"),
):
    """The shipped detector as a dimmer or brighter unit, another LED tint, a softer focus or a gel that
    lost markers sees the runs, judged per grasp; with --folds, a recipe's folds on their held-out objects."""
    check_output_dir(out, "--out")
    root = resolve_path(recordings or gelsight_recordings())
    if folds is not None:
        doc = looks_folds_study(root, folds, progress)
    else:
        doc = looks_study(root, checkpoint or shipped_model(), progress)
    paths = write_looks(doc, out, command_line())
    typer.echo(looks_table(doc))
    typer.echo(f"-> {', '.join(str(p) for p in paths)}")


@group.command("hold")
@friendly
def hold_cmd(
    checkpoint: Optional[Path] = typer.Option(None, help="detector (default: the shipped one for the recordings)"),
    recordings: Optional[Path] = typer.Option(None, help="recordings folder (default: $SLIPSENSE_DATA/gelsight-slip)"),
    out: Path = typer.Option(Path("reports/hold"), help="report folder"),
):
    """How long an alarm should hold: alarm onsets per slip and per held grasp at several hold times."""
    import json

    from studies.provenance import provenance

    check_output_dir(out, "--out")
    doc = hold_study(checkpoint, recordings)
    doc["command"] = command_line()
    text = hold_table(doc)
    out.mkdir(parents=True, exist_ok=True)
    write_text(out / "hold.json", json.dumps(doc, indent=1))
    write_text(
        out / "README.md",
        f"# How long an alarm holds\n\n`{doc['command']}`\n\n{provenance()}\n\n"
        f"{doc['checkpoint']} at threshold {doc['operating_point']['threshold']:g} x{doc['operating_point']['debounce']}, "
        f"replayed over {doc['runs']} runs (its own training objects among them: the dips are what is measured, "
        f"not how often it warns). Onsets of slips count up to the moment contact is lost.\n\n{text}\n",
    )
    typer.echo(text + f"\n-> {out}")


@group.command("learning-curve")
@friendly
def learning_curve_cmd(
    sensor: Path = typer.Option(..., help="a user's sensor: grasps labelled per grasp (frame folders, sensor.json)"),
    family: str = typer.Option("shear-retention", help="the registered family to make, with its own recipe"),
    work: Path = typer.Option(..., help="folder for the trainings (kept: a second run resumes)"),
    out: Path = typer.Option(..., help="report folder: learning-curve.json, learning-curve.md"),
    progress: bool = typer.Option(True, help="progress bars"),
):
    """How many objects to record: the family made from k objects' grasps, judged on the others'."""
    import json

    from studies.provenance import provenance

    doc = learning_curve(sensor, family, work, progress=progress)
    doc["command"] = command_line()
    text = curve_table(doc)
    out.mkdir(parents=True, exist_ok=True)
    write_text(out / "learning-curve.json", json.dumps(doc, indent=1))
    write_text(out / "learning-curve.md", f"`{doc['command']}`\n\n{provenance()}\n\n{text}")
    typer.echo(text + f"-> {out}")
