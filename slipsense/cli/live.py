"""Commands for live detection: ``watch``, ``early-warning`` and ``export`` (registered by slipsense.cli)."""

from __future__ import annotations

import itertools
import time
import warnings

from pathlib import Path
from typing import Any, Optional, Sequence

import typer

from slipsense.errors import ConfigError, InputError

#: Default alarm thresholds of ``early-warning``.
DEFAULT_THRESHOLDS = "0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8,0.9"


def parse_thresholds(text: str) -> list[float]:
    """``"0.1,0.5,0.9"`` -> ``[0.1, 0.5, 0.9]``; each in [0, 1], sorted, duplicates removed."""
    try:
        values = sorted({float(v) for v in text.split(",") if v.strip()})
    except ValueError:
        raise ConfigError(f"--thresholds must be comma-separated numbers in [0, 1], got {text!r}") from None
    if not values or any(not 0.0 <= v <= 1.0 for v in values):
        raise ConfigError(f"--thresholds must be comma-separated numbers in [0, 1], got {text!r}")
    return values


THREADS_HELP = (
    "intra-op threads for torch and ONNX Runtime (default: torch's). Use 1 on a busy machine: the "
    "small per-frame operations then wait for no descheduled worker thread"
)


def _set_threads(threads: Optional[int]) -> None:
    if threads is None:
        return
    if threads < 1:
        raise ConfigError(f"--threads must be a positive integer, got {threads}")
    import torch

    torch.set_num_threads(threads)


def _checkpoint(path: Optional[Path], sensors: int | None = None) -> Path:
    """The checkpoint given, else the shipped detector for ``sensors`` (one finger or both)."""
    from slipsense.resources import default_model_name, shipped_model

    path = path or shipped_model(default_model_name(sensors))
    if not Path(path).is_file():
        raise InputError(path, "checkpoint not found (pass --checkpoint CKPT)")
    return Path(path)


def _shipped_for_source(source: str, sensors: int) -> Path:
    """The shipped detector for what ``source`` holds: by its frame size where it is a video or a
    frame folder (a 480 x 640 GelSight gets the one calibrated to it), else by its sensor count."""
    from slipsense.recordings.video import probe_video
    from slipsense.resources import shipped_model
    from slipsense.streaming.detector import shipped_name

    size = None
    path = Path(source)
    if path.is_file() and path.suffix.lower() != ".npy" or path.is_dir() and not any(path.glob("camera_*")):
        try:
            info = probe_video(path, expected_size=None, min_frames=1)
            size = (info.height, info.width)
        except InputError:
            size = None  # opening the source reports what is wrong with it
    return _checkpoint(shipped_model(shipped_name(sensors, size)))


# ---------------------------------------------------------------------------------------------
# commands
# ---------------------------------------------------------------------------------------------


def watch_source(
    source: str,
    checkpoint: Optional[Path],
    threshold: Optional[float] = None,
    out: Optional[Path] = None,
    combine: str = "max",
    backend: str = "auto",
    max_frames: Optional[int] = None,
    heatmap: bool = True,
    echo=typer.echo,
    quiet: bool = False,
    dtype: str = "float32",
    topics: Sequence[str] = (),
    tolerance: Optional[float] = None,
    jsonl: Optional[str] = None,
    bag_out: Optional[Path] = None,
    realtime: bool = False,
) -> dict[str, Any]:
    """Stream ``source`` through the detector; print a line per frame; optionally write an annotated
    GIF/video, the readings as JSON lines (``jsonl``, ``"-"`` for standard output) and into a new bag
    (``bag_out``). ``topics``: a bag's image topics, one per sensor; ``realtime``: play a file at the
    sensor's rate through the live capture path. Returns ``{"frames", "alarm_onsets", "first_alarm",
    "out", "source"}`` (``source``: what the source reports of its delivery)."""
    from slipsense.checkpoint import load_model
    from slipsense.sensors.spec import GELSIGHT_MINI, sensor_of
    from slipsense.streaming.annotate import AnnotatedWriter, Annotator
    from slipsense.models.runners import resolve_backend
    from slipsense.models.base import window_geometry
    from slipsense.streaming.detector import SlipDetector, check_settings, onnx_cache_dir, stored_operating_point
    from slipsense.streaming.readings import reading_record

    from slipsense.atomic import check_output_file

    if max_frames is not None and max_frames < 0:
        raise ConfigError(f"--max-frames must be 0 or more, got {max_frames}")
    if out is not None:
        check_output_file(out, "--out")
        AnnotatedWriter(out)  # refuse a wrong suffix before any work
    if bag_out is not None and Path(bag_out).exists():
        raise InputError(bag_out, "exists; --bag-out writes a new bag folder")
    # the user's own settings are checked before any source is opened or checkpoint blamed
    check_settings(0.5 if threshold is None else threshold, 1, combine, backend, dtype)
    if checkpoint is None:  # the shipped detectors read videos: one for one finger, one for both
        sensor = GELSIGHT_MINI
        src = _open(source, None, sensor, topics, tolerance, realtime)  # the shipped detectors take pictures
        try:
            ckpt = _shipped_for_source(source, src.sensors)
            model, info = load_model(ckpt)
        except BaseException:
            src.close()
            raise
        if sensor_of(info, ckpt).fps != sensor.fps:  # picked for another sensor: its rate stamps the frames
            src.close()
            sensor = sensor_of(info, ckpt)
            src = _open(source, None, sensor, topics, tolerance, realtime)
    else:
        ckpt = _checkpoint(checkpoint)
        model, info = load_model(ckpt)
        sensor = sensor_of(info, ckpt)  # a malformed sensor spec is named with its file
        src = _open(source, model, sensor, topics, tolerance, realtime, window_geometry(model, info))
    own_point = threshold is None
    threshold, debounce = stored_operating_point(ckpt, info, threshold, None)
    backend = resolve_backend(backend, model)
    try:
        det = SlipDetector(
            model,
            threshold=threshold,
            sensors=src.sensors,
            combine=combine,
            backend=backend,
            info=info,
            onnx_dir=onnx_cache_dir(ckpt) if backend == "onnx" else None,
            dtype=dtype,
            debounce=debounce,
        )
    except ConfigError as exc:  # e.g. one camera given to a two-finger model: name the checkpoint
        src.close()
        raise InputError(ckpt, str(exc)) from None
    if not quiet:
        runs_on = "ONNX Runtime" if det.backend == "onnx" else "PyTorch"
        echo(f"{Path(ckpt).stem} on {runs_on}, {det.sensors} sensor(s), alarm at {det.threshold:g}", err=jsonl == "-")
        if own_point:  # the checkpoint's own operating point: what it promises
            from slipsense.evaluation.pergrasp import promise_text

            echo(promise_text(info.get("operating_point")), err=jsonl == "-")
    annot = Annotator(det.threshold, det.sensors, fps=det.sensor.fps) if out is not None else None
    writer = AnnotatedWriter(out, fps=det.sensor.fps) if out is not None else None
    sinks = _sinks(jsonl, bag_out, src, det)
    onsets: list[int] = []
    previous = False
    n = 0
    try:
        for step in itertools.islice(src.frames(), max_frames):  # takes no frame beyond the last pushed
            display, inputs = step.display, step.inputs
            t0 = time.perf_counter()
            r = det.push(*inputs)
            latency_ms = (time.perf_counter() - t0) * 1e3
            n += 1
            if sinks:
                record = reading_record(r, step.stamp, latency_ms)
                for sink in sinks:
                    sink.write(record)
            if r.alarm and not previous:
                onsets.append(r.index)
            previous = r.alarm
            if jsonl != "-" and (not quiet or (r.alarm and onsets and onsets[-1] == r.index)):
                echo(_reading_line(r))
            if writer is not None:
                heat = [det.heatmap(s) for s in range(det.sensors)] if heatmap else []
                clouds = list(inputs) if src.converted else []
                writer.add(annot.draw(display, r, heat, clouds))
    except KeyboardInterrupt:  # a live camera is stopped with Ctrl-C: still write what was seen
        pass
    except BrokenPipeError:  # `--jsonl - | head`: the reader has gone; stop as if stopped by hand
        import os
        import sys

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no error at exit's flush
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    finally:
        src.close()
        det.close()
        for sink in sinks:
            sink.close()
    written = writer.close() if writer is not None else None
    summary = {
        "frames": n,
        "alarm_onsets": onsets,
        "first_alarm": onsets[0] if onsets else None,
        "backend": det.backend,
        "out": None if written is None else str(written),
        "source": src.stats(),
    }
    echo(
        f"{n} frames, {len(onsets)} alarm onset(s)"
        + (f", first at frame {onsets[0]}" if onsets else "")
        + (f" -> {written}" if written else ""),
        err=jsonl == "-",  # standard output carries the readings then
    )
    for cam in summary["source"].get("cameras", []):
        echo(
            f"{cam['camera']}: {cam['fps']:.2f} frames/s captured, {cam['delivered']} of {cam['grabbed']} "
            f"pushed, {cam['dropped']} dropped, {cam['repeated']} repeated",
            err=jsonl == "-",
        )
    return summary


def _open(source, model, sensor, topics, tolerance, realtime, geometry=None):
    """The source, with the sensor's rate, camera files and capture settings."""
    from slipsense.streaming.sources import open_source

    size = tuple(sensor.image_size) if sensor.image_size else None
    src = open_source(
        source,
        model,
        sensor.camera_glob,
        geometry,
        topics=topics,
        fps=sensor.fps,
        tolerance_s=tolerance,
        capture_format=sensor.capture_format,
        frame_size=size,
    )
    if not realtime:
        return src
    if src.converted or src.stats().get("cameras"):
        src.close()
        raise ConfigError(
            "--realtime plays recorded frames (a video, a recordings folder or a bag) at the sensor's rate"
        )
    from slipsense.streaming.capture import CaptureThread, PacedReader
    from slipsense.streaming.sources import capture_source
    from slipsense.streaming.sources import Source

    steps = list(src.frames())
    src.close()
    live: list = []

    def play():  # the clock starts at the first frame asked for, once the detector is ready
        threads = [
            CaptureThread(PacedReader([s.inputs[k] for s in steps], sensor.fps).read, f"{src.name}[{k}]")
            for k in range(src.sensors)
        ]
        live.append(capture_source(f"{src.name} in real time", threads, sensor.fps, tolerance))
        yield from live[0].frames()

    return Source(
        f"{src.name} in real time",
        src.sensors,
        play(),
        closer=lambda: [s.close() for s in live],
        stats=lambda: live[0].stats() if live else {},
    )


def _sinks(jsonl, bag_out, src, det) -> list:
    from slipsense.streaming.readings import BagWriter, JsonlWriter

    sinks = []
    try:
        if jsonl is not None:
            sinks.append(JsonlWriter(jsonl))
        if bag_out is not None:
            sinks.append(BagWriter(bag_out))
    except BaseException:
        for sink in sinks:
            sink.close()
        src.close()
        det.close()
        raise
    return sinks


def _reading_line(r) -> str:
    if r.probability is None:
        return f"frame {r.index:5d}  p=  -    (filling window)"
    sensors = " ".join(f"{p:.3f}" for p in r.per_sensor)
    return f"frame {r.index:5d}  p={r.probability:.3f}  [{sensors}]" + ("  ALARM" if r.alarm else "")


def register(app: typer.Typer) -> None:
    """Add ``watch``, ``early-warning`` and ``export`` to the slipsense app."""
    from slipsense.cli.common import friendly

    @app.command()
    @friendly
    def watch(
        source: str = typer.Argument(
            ...,
            help="video file, recordings experiment folder (camera_*.avi as sensors), ROS 2 bag (with "
            "--topic), marker .npy, or camera index (0; two fingers: 0,2)",
        ),
        checkpoint: Optional[Path] = typer.Option(
            None, help="checkpoint (default: the shipped detector, models/motionnet-gelsight.safetensors)"
        ),
        threshold: Optional[float] = typer.Option(
            None, help="alarm when the slip probability is >= this (default: the checkpoint's operating point)"
        ),
        out: Optional[Path] = typer.Option(None, help="annotated output: .gif, .mp4 or .avi"),
        combine: str = typer.Option("max", help="two sensors: max or mean of their probabilities"),
        backend: str = typer.Option("auto", help="auto (ONNX Runtime where installed, else PyTorch), torch or onnx"),
        dtype: str = typer.Option("float32", help="float32, or int8 with --backend onnx (quantized products)"),
        max_frames: Optional[int] = typer.Option(None, help="stop after this many frames"),
        heatmap: bool = typer.Option(True, help="draw the attention / saliency heat map in --out"),
        quiet: bool = typer.Option(False, help="print only alarm onsets and the summary"),
        threads: Optional[int] = typer.Option(None, help=THREADS_HELP),
        topic: list[str] = typer.Option(
            [], help="a bag's image topic (sensor_msgs Image or CompressedImage), once per sensor, in order"
        ),
        tolerance: Optional[float] = typer.Option(
            None, help="seconds: the largest stamp difference of paired frames (default half a frame period)"
        ),
        jsonl: Optional[str] = typer.Option(
            None, help="write every reading as a JSON line to this file (- for standard output)"
        ),
        bag_out: Optional[Path] = typer.Option(
            None,
            help="write every reading to a new ROS 2 bag (topic /slipsense/reading, slipsense_msgs/msg/SlipReading)",
        ),
        realtime: bool = typer.Option(
            False, help="play a recorded source at the sensor's rate through the live capture path"
        ),
    ):
        """Stream a video, an experiment folder, a ROS 2 bag or cameras through a slip detector."""
        _set_threads(threads)
        watch_source(
            source,
            checkpoint,
            threshold,
            out,
            combine,
            backend,
            max_frames,
            heatmap,
            quiet=quiet,
            dtype=dtype,
            topics=topic,
            tolerance=tolerance,
            jsonl=jsonl,
            bag_out=bag_out,
            realtime=realtime,
        )

    @app.command("early-warning")
    @friendly
    def early_warning(
        checkpoint: Optional[Path] = typer.Option(None, help="video-model checkpoint (default: the shipped detector)"),
        recordings: Optional[Path] = typer.Option(
            None, help="recordings folder (default: $SLIPSENSE_DATA/gelsight-slip)"
        ),
        out: Path = typer.Option(..., help="output folder for CSV, JSON and PNGs"),
        thresholds: str = typer.Option(
            DEFAULT_THRESHOLDS,
            help="comma-separated alarm thresholds (the checkpoint's own operating point is always added)",
        ),
        horizon: int = typer.Option(50, help="frames before the moment of slip in which a first alarm is in time"),
        debounce: Optional[int] = typer.Option(
            None, help="frames in a row above the threshold before an alarm (default: the checkpoint's)"
        ),
        overrides: Optional[Path] = typer.Option(None, help="label overrides CSV (object,experiment,camera,moment)"),
        labels: Optional[Path] = typer.Option(None, help="labels CSV (slipsense label) instead of automatic labels"),
        combine: str = typer.Option("max", help="max or mean of the two cameras' probabilities"),
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
        _set_threads(threads)
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

    @app.command("export")
    @friendly
    def export(
        checkpoint: Optional[Path] = typer.Option(None, help="checkpoint (default: the shipped detector)"),
        out: Path = typer.Option(..., help="output .onnx file (streaming parts go beside it)"),
        batch: Optional[int] = typer.Option(None, help="fixed batch size (default: dynamic)"),
        streaming: bool = typer.Option(True, help="also write <stem>.frame.onnx / <stem>.window.onnx"),
        verify: bool = typer.Option(True, help="compare ONNX Runtime with PyTorch on a random input"),
    ):
        """Export a checkpoint to ONNX (and the live detector's streaming parts)."""
        from slipsense.streaming.export import export_onnx

        result = export_onnx(_checkpoint(checkpoint), out, batch=batch, streaming=streaming, verify=verify)
        for key, path in result.paths.items():
            diff = result.max_abs_diff.get(key)
            typer.echo(
                f"{key:6s} {path}  ({result.exporter[key]} exporter"
                + ("" if diff is None else f", max |onnx - torch| = {diff:.2e}")
                + ")"
            )


def run_early_warning(
    checkpoint: Optional[Path],
    recordings: Optional[Path],
    out: Path,
    thresholds: str | Sequence[float] = DEFAULT_THRESHOLDS,
    labels: Optional[Path] = None,
    combine: str = "max",
    backend: str = "torch",
    limit: Optional[int] = None,
    fps: float | None = None,
    on_error: str = "raise",
    progress: bool = True,
    dtype: str = "float32",
    horizon: int = 50,
    debounce: Optional[int] = None,
    overrides: Optional[Path] = None,
) -> str:
    """The ``early-warning`` command as a function; returns the summary text it prints."""
    from slipsense.config import gelsight_recordings
    from slipsense.evaluation.early_warning import early_warning_table, replay_recordings, write_early_warning
    from slipsense.streaming.detector import SlipDetector
    from slipsense.recordings.folders import camera_counts, find_recordings
    from slipsense.recordings.label_csv import read_labels_csv

    ths = parse_thresholds(thresholds) if isinstance(thresholds, str) else [float(t) for t in thresholds]
    if limit is not None and limit < 1:
        raise ConfigError(f"--limit must be a positive integer, got {limit}")
    if fps is not None and not fps > 0:
        raise ConfigError(f"--fps must be positive, got {fps}")
    if isinstance(horizon, bool) or not isinstance(horizon, int) or not 1 <= horizon <= 100_000:
        raise ConfigError(f"--horizon must be a whole number of frames >= 1, got {horizon!r}")
    from slipsense.atomic import check_output_dir

    check_output_dir(out, "--out")
    from slipsense.checkpoint import read_info
    from slipsense.sensors.spec import sensor_of

    root = Path(recordings) if recordings else gelsight_recordings()
    if checkpoint is None:
        from slipsense.evaluation.replay import shipped_for

        checkpoint = shipped_for(root)  # one camera per grasp: the one-finger detector
    ckpt = _checkpoint(checkpoint)
    info = read_info(ckpt)
    recs = find_recordings(root, on_error=on_error, sensor=sensor_of(info, ckpt))
    if all(r.per_grasp for r in recs):
        raise InputError(
            root, "grasps labelled as a whole have no moment of slip to warn before: judge them with slipsense evaluate"
        )
    counts = camera_counts(recs)
    if len(counts) != 1:
        raise InputError(root, f"runs hold different numbers of camera videos ({counts}); early warning needs the same")
    lab = read_labels_csv(labels) if labels is not None else None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a checkpoint without a threshold: the table covers thresholds anyway
        fixed = info["model_config"].get("sensors")  # a model trained on so many fingers
        det = SlipDetector.from_checkpoint(
            ckpt, sensors=fixed or counts[0], combine=combine, backend=backend, dtype=dtype, debounce=debounce
        )
    if det.threshold not in ths:
        ths = sorted(ths + [det.threshold])
    try:
        runs = replay_recordings(det, recs, lab, progress=progress, limit=limit, overrides=overrides)
    finally:
        det.close()
    meta = {
        "checkpoint": str(ckpt),
        "model": det.model_name,
        "recordings": str(root),
        "combine": combine,
        "backend": backend,
        "dtype": dtype,
        "sensors": det.sensors,
        "operating_point": {"threshold": det.threshold, "debounce": det.debounce},
    }
    fps = fps or det.sensor.fps
    paths = write_early_warning(runs, ths, out, debounce=det.debounce, horizon=horizon, fps=fps, meta=meta)
    rows = early_warning_table(runs, ths, det.debounce, horizon, fps)
    slips = sum(r.slipped for r in runs)
    lines = [
        f"{slips} slip runs, {len(runs) - slips} runs that held; horizon {horizon} frames, debounce {det.debounce}",
        "threshold  warned in time  premature  missed  median lead (ms)  false-positive grasps  alarm at rest",
    ]
    for row in rows:
        mark = "  <- checkpoint's operating point" if row["threshold"] == det.threshold else ""
        lines.append(
            f"{row['threshold']:9.3g}  {row['warned']:>6d}/{row['slip_runs']:<7d} {row['premature']:>9d}  "
            f"{row['missed']:>6d}  {row['median_lead_ms']:16.0f}  {row['false_positive_grasps']:>11d}/"
            f"{row['held_runs']:<9d} {row['runs_alarming_at_rest']:>13d}{mark}"
        )
    lines.append("-> " + ", ".join(str(p) for p in paths.values()))
    return "\n".join(lines)


__all__ = [
    "DEFAULT_THRESHOLDS",
    "parse_thresholds",
    "register",
    "run_early_warning",
    "watch_source",
]
