"""Watch a source through a slip detector: open it at the sensor's rate, push every frame, write
the readings (JSON lines, a bag), an annotated picture and a summary. What ``slipsense watch`` runs."""

from __future__ import annotations

import itertools
import os
import sys
import time
from pathlib import Path
from typing import Any, Optional, Sequence

from slipsense.alarm import shown_probability
from slipsense.atomic import check_output_file
from slipsense.checkpoint import load_model, read_info
from slipsense.errors import ConfigError, InputError
from slipsense.measures.promise import promise_text
from slipsense.models.base import window_geometry
from slipsense.models.runners import resolve_backend
from slipsense.recordings.frame_folders import camera_folders
from slipsense.recordings.frames import frame_files
from slipsense.recordings.video import probe_video
from slipsense.resources import default_model_name, shipped_model
from slipsense.sensors.spec import sensor_of
from slipsense.streaming.annotate import AnnotatedWriter, Annotator, check_suffix
from slipsense.streaming.capture import CaptureThread, PacedReader
from slipsense.streaming.detector import DEFAULT_CHECKPOINT, SlipDetector, check_hold, check_settings, onnx_cache_dir
from slipsense.streaming.detector import shipped_name
from slipsense.streaming.detector import stored_hold, stored_operating_point
from slipsense.streaming.readings import BagWriter, JsonlWriter, reading_record
from slipsense.streaming.sources import Source, capture_source, open_source


def echo(message: str, err: bool = False) -> None:
    """A line to standard output (or standard error), flushed: the readings of a live run."""
    print(message, file=sys.stderr if err else sys.stdout, flush=True)


def checkpoint_or_shipped(path: Optional[Path], sensors: int | None = None) -> Path:
    """The checkpoint given, else the shipped detector for ``sensors`` (one finger or both)."""
    if path is not None:
        if not Path(path).is_file():
            raise InputError(path, "checkpoint not found (--checkpoint names a file that is not there)")
        return Path(path)
    path = shipped_model(default_model_name(sensors))
    if not Path(path).is_file():
        raise InputError(path, "the shipped detector is missing from this installation (reinstall slipsense)")
    return Path(path)


def _shipped_for_source(source: str, sensors: int) -> Path:
    """The shipped detector for what ``source`` holds: by its frame size where it is a video or a
    frame folder (a 480 x 640 GelSight gets the one calibrated to it), else by its sensor count."""
    size = None
    path = Path(source)
    frames = path if path.is_dir() and not any(path.glob("camera_*")) else None
    if path.is_dir() and frames is None:  # a grasp of camera_* frame folders: the first camera's size
        frames = next((p for p in camera_folders(path) if frame_files(p)), None)
    if path.is_file() and path.suffix.lower() != ".npy" or frames is not None:
        try:
            info = probe_video(frames or path, expected_size=None, min_frames=1)
            size = (info.height, info.width)
        except InputError:
            size = None  # opening the source reports what is wrong with it
    return checkpoint_or_shipped(shipped_model(shipped_name(sensors, size)))


def watch_source(
    source: str,
    checkpoint: Optional[Path],
    threshold: Optional[float] = None,
    out: Optional[Path] = None,
    combine: Optional[str] = None,
    backend: str = "auto",
    max_frames: Optional[int] = None,
    heatmap: Optional[bool] = None,
    echo=echo,
    quiet: bool = False,
    dtype: str = "float32",
    topics: Sequence[str] = (),
    tolerance: Optional[float] = None,
    jsonl: Optional[str] = None,
    bag_out: Optional[Path] = None,
    realtime: bool = False,
    fps: Optional[float] = None,
    hold: Optional[float] = None,
    gel_motion: bool = True,
) -> dict[str, Any]:
    """Stream ``source`` through the detector; print a line per frame; optionally write an annotated
    GIF/video, the readings as JSON lines (``jsonl``, ``"-"`` for standard output) and into a new bag
    (``bag_out``). ``topics``: a bag's image topics, one per sensor; ``realtime``: play a file at the
    source's rate through the live capture path; ``fps``: the source's rate where it states none (a
    folder of frames without ``sensor.json``) or states it wrongly. The detector runs on its own clock
    (:meth:`SlipDetector.push` with the source's stamps), so any source rate gives the model what it was
    trained on; readings are one per source frame, stamped on the source's clock. ``combine``: max or
    mean of the sensors' probabilities, for models that judge each apart (refused for models that
    fuse them); ``heatmap``: None draws the model's heat map in ``out`` where it has one, True asks for
    it (refused for a model without one), False leaves it out; ``hold``: seconds an alarm holds
    (default: the checkpoint's); ``gel_motion``: follow the gel's markers for the slip velocity.
    Returns ``{"frames", "alarm_onsets", "first_alarm", "out", "source"}`` (``source``: what the source
    reports of its delivery)."""
    if max_frames is not None and max_frames < 0:
        raise ConfigError(f"--max-frames must be 0 or more, got {max_frames}")
    if out is not None:
        check_output_file(out, "--out")
        check_suffix(out)  # refuse a wrong suffix before any work
    if bag_out is not None and Path(bag_out).exists():
        raise InputError(bag_out, "exists; --bag-out writes a new bag folder")
    # the user's own settings are checked before any source is opened or checkpoint blamed
    check_settings(0.5 if threshold is None else threshold, 1, combine, backend, dtype)
    if hold is not None:
        check_hold(hold)
    if checkpoint is None:  # the shipped detectors read videos: one for one finger, one for both
        # the shipped detectors share one sensor (their checkpoints name it): its files and camera settings
        shipped = sensor_of(read_info(DEFAULT_CHECKPOINT), DEFAULT_CHECKPOINT)
        src = _open(source, None, shipped, topics, tolerance, realtime, fps=fps)
        try:
            ckpt = _shipped_for_source(source, src.sensors)
            model, info = load_model(ckpt)
        except BaseException:
            src.close()
            raise
    else:
        ckpt = checkpoint_or_shipped(checkpoint)
        model, info = load_model(ckpt)
        sensor = sensor_of(info, ckpt)  # a malformed sensor spec is named with its file
        src = _open(source, model, sensor, topics, tolerance, realtime, window_geometry(model, info), fps)
    own_point = threshold is None
    threshold, debounce = stored_operating_point(ckpt, info, threshold, None)
    backend = resolve_backend(backend, model)
    settings = dict(threshold=threshold, sensors=src.sensors, combine=combine, dtype=dtype, debounce=debounce)
    settings["gel_motion"] = gel_motion
    try:
        onnx_dir = onnx_cache_dir(ckpt) if backend == "onnx" else None
        det = SlipDetector(
            model, backend=backend, info=info, onnx_dir=onnx_dir, hold=stored_hold(info, hold), **settings
        )
        if heatmap and not det.has_heatmap:
            det.close()
            raise ConfigError(f"{det.model_name} has no heat map to draw (--heatmap is for ViViT, STNet and TemNet)")
    except ConfigError as exc:  # e.g. one camera given to a two-finger model: name the checkpoint
        src.close()
        raise InputError(ckpt, str(exc)) from None

    def note(line: str) -> None:  # standard output carries the readings with --jsonl -
        echo(line, err=jsonl == "-")

    if not quiet:
        runs_on = "ONNX Runtime" if det.backend == "onnx" else "PyTorch"
        fused = "" if det.per_sensor or det.sensors == 1 else " fused into one probability"
        held = f", held {det.hold:g} s" if det.hold else ""
        note(f"{Path(ckpt).stem} on {runs_on}, {det.sensors} sensor(s){fused}, alarm at {det.threshold:g}{held}")
        if own_point:  # the checkpoint's own operating point: what it promises
            note(promise_text(info.get("operating_point")))
    note(rate_line(src, det))
    annot = Annotator(det.threshold, det.sensors, fps=src.fps) if out is not None else None
    draw_heat = det.has_heatmap and heatmap is not False
    writer = AnnotatedWriter(out, fps=src.fps) if out is not None else None  # plays at the source's speed
    sinks: list = []
    try:
        if jsonl is not None:
            sinks.append(JsonlWriter(jsonl))
        if bag_out is not None:
            sinks.append(BagWriter(bag_out))
    except BaseException:
        for sink in [*sinks, src, det]:
            sink.close()
        raise
    onsets: list[int] = []
    previous, n = False, 0
    losses = _LossReport(src, lambda line: echo(line, err=True))
    try:
        for step in itertools.islice(src.frames(), max_frames):  # takes no frame beyond the last pushed
            display, inputs = step.display, step.inputs
            t0 = time.perf_counter()
            try:
                r = det.push(*inputs, stamp=step.stamp)
            except InputError as exc:  # stamps that go backwards: the source is what is wrong
                raise InputError(src.name, exc.problem) if exc.path is None else exc from None
            latency_ms = (time.perf_counter() - t0) * 1e3
            n += 1
            if sinks:
                record = reading_record(r, step.stamp, latency_ms, frame=step.frame)
                for sink in sinks:
                    sink.write(record)
            if r.alarm and not previous:
                onsets.append(r.index)
            previous = r.alarm
            if jsonl != "-" and (not quiet or (r.alarm and onsets and onsets[-1] == r.index)):
                echo(reading_line(r, det.threshold))
            if writer is not None:
                heat = [det.heatmap(s) for s in range(det.sensors)] if draw_heat else []
                clouds = list(inputs) if src.converted else []
                writer.add(annot.draw(display, r, heat, clouds))
            losses.every(LOSS_REPORT_S)
    except KeyboardInterrupt:  # a live camera is stopped with Ctrl-C: still write what was seen
        pass
    except BrokenPipeError:  # `--jsonl - | head`: the reader has gone; stop as if stopped by hand
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
    summary = {"frames": n, "alarm_onsets": onsets, "first_alarm": onsets[0] if onsets else None}
    summary.update(backend=det.backend, out=None if written is None else str(written), source=src.stats())
    first = f", first at frame {onsets[0]}" if onsets else ""
    note(f"{n} frames, {len(onsets)} alarm onset(s){first}" + (f" -> {written}" if written else ""))
    for line in camera_lines(summary["source"]):
        note(line)
    return summary


#: Seconds between the lines a live source's losses are reported in while it runs (only when they grow).
LOSS_REPORT_S = 5.0


def camera_lines(stats: dict[str, Any]) -> list[str]:
    """What live cameras delivered, a line per camera: every frame captured is pushed or counted."""
    return [
        f"{cam['camera']}: {cam['fps']:.2f} frames/s captured, {cam['delivered']} of {cam['grabbed']} "
        f"pushed, {cam['dropped']} dropped (replaced before the detector took them), {cam['repeated']} repeated"
        for cam in stats.get("cameras", [])
    ]


class _LossReport:
    """While a live source runs: its cameras' lines on standard error every ``seconds``, when frames
    were dropped since the last (a controller's log sees losses as they happen, not only at exit)."""

    def __init__(self, src, say):
        self.src, self.say = src, say
        self.next = time.monotonic()
        self.dropped = 0

    def every(self, seconds: float) -> None:
        now = time.monotonic()
        if now < self.next:
            return
        self.next = now + seconds
        stats = self.src.stats()
        dropped = sum(cam["dropped"] for cam in stats.get("cameras", []))
        if dropped > self.dropped:
            self.dropped = dropped
            for line in camera_lines(stats):
                self.say(line)


def _open(source, model, sensor, topics, tolerance, realtime, geometry=None, fps=None):
    """The source on its own clock (``fps``: the user's statement of its rate), with the sensor's camera
    files and capture settings (cameras are asked for the sensor's rate)."""
    size = tuple(sensor.image_size) if sensor.image_size else None
    camera = dict(camera_fps=sensor.fps, capture_format=sensor.capture_format, frame_size=size)
    src = open_source(
        source, model, sensor.camera_glob, geometry, topics=topics, fps=fps, tolerance_s=tolerance, **camera
    )
    if not realtime:
        return src
    if src.converted or src.stats().get("cameras"):
        src.close()
        raise ConfigError(
            "--realtime plays recorded frames (a video, a recordings folder or a bag) at the sensor's rate"
        )
    steps = list(src.frames())
    src.close()
    live: list = []
    name, clock = f"{src.name} in real time", f"{src.clock}, played on the capture clock"

    def play():  # the clock starts at the first frame asked for, once the detector is ready
        readers = [PacedReader([s.inputs[k] for s in steps], src.fps).read for k in range(src.sensors)]
        threads = [CaptureThread(read, f"{src.name}[{k}]") for k, read in enumerate(readers)]
        live.append(capture_source(name, threads, src.fps, tolerance))
        yield from live[0].frames()

    stats = lambda: live[0].stats() if live else {}  # noqa: E731
    return Source(name, src.sensors, play(), lambda: [s.close() for s in live], stats, fps=src.fps, clock=clock)


def rate_line(src, det) -> str:
    """What rate the source delivers at, where that was read, and the rate the detector runs at."""
    same = abs(src.fps - det.sensor.fps) < 0.01 * det.sensor.fps
    return f"{src.name}: {src.fps:g} frames/s ({src.clock}); the detector runs at {det.sensor.fps:g} frames/s" + (
        " too" if same else f", its clock fills in between ({det.sensor.name}'s rate, as it was trained)"
    )


def reading_line(r, threshold: float) -> str:
    """One reading in words: its probability never printed across ``threshold`` (a value under it
    never rounds up to it), per-sensor values only where the model has them."""
    if r.probability is None:
        return f"frame {r.index:5d}  p=  -    (filling window)"
    shown = " ".join(shown_probability(p, threshold) for p in r.per_sensor or ())
    sensors = "" if r.per_sensor is None else f"  [{shown}]"
    state = ("  ALARM" if not r.probability < threshold else "  ALARM (held)") if r.alarm else ""
    return f"frame {r.index:5d}  p={shown_probability(r.probability, threshold)}{sensors}{state}"


__all__ = ["checkpoint_or_shipped", "echo", "reading_line", "watch_source"]
