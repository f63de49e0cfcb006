"""Commands for live detection: ``watch``, ``ros`` and ``export`` (registered by slipsense.cli)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from slipsense.errors import ConfigError, InputError


GEL_MOTION = typer.Option(
    True,
    "--gel-motion/--no-gel-motion",
    help="follow each finger's gel for the object's motion against it (translation, turn, stick share) and "
    "the shear field in every reading (about 1 ms a finger; where the gel has no markers, readings carry null "
    "either way)",
)
THREADS_HELP = (
    "intra-op threads for torch and ONNX Runtime (default: torch's). Use 1 on a busy machine: the "
    "small per-frame operations then wait for no descheduled worker thread"
)


# options ``watch`` and ``ros`` share
THRESHOLD = typer.Option(
    None, help="alarm when the slip probability is >= this (default: the checkpoint's operating point)"
)
HOLD = typer.Option(None, help="seconds an alarm stays on once raised (default: the checkpoint's; 0: none)")
TOLERANCE = typer.Option(
    None, help="seconds: the largest stamp difference of paired frames (default half a frame period)"
)
BACKEND = typer.Option("auto", help="auto (ONNX Runtime where installed, else PyTorch), torch or onnx")


def set_threads(threads: Optional[int]) -> None:
    if threads is None:
        return
    if threads < 1:
        raise ConfigError(f"--threads must be a positive integer, got {threads}")
    import torch

    torch.set_num_threads(threads)


def register(app: typer.Typer) -> None:
    """Add ``watch`` and ``export`` to the slipsense app."""
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
        threshold: Optional[float] = THRESHOLD,
        out: Optional[Path] = typer.Option(None, help="annotated output: .gif, .mp4 or .avi"),
        combine: Optional[str] = typer.Option(
            None,
            help="two sensors, for a model that judges each apart (ViViT, 3D ResNet, STNet): max (default) or "
            "mean of their probabilities; refused for a model that fuses them (the shipped detectors)",
        ),
        backend: str = BACKEND,
        dtype: str = typer.Option("float32", help="float32, or int8 with --backend onnx (quantized products)"),
        max_frames: Optional[int] = typer.Option(None, help="stop after this many frames"),
        heatmap: Optional[bool] = typer.Option(
            None,
            "--heatmap/--no-heatmap",
            help="draw the model's heat map in --out (default: where the model has one: ViViT's attention, "
            "STNet's marker saliency; --heatmap is refused for a model without one)",
        ),
        hold: Optional[float] = HOLD,
        quiet: bool = typer.Option(False, help="print only alarm onsets and the summary"),
        threads: Optional[int] = typer.Option(None, help=THREADS_HELP),
        topic: list[str] = typer.Option(
            [], help="a bag's image topic (sensor_msgs Image or CompressedImage), once per sensor, in order"
        ),
        tolerance: Optional[float] = TOLERANCE,
        jsonl: Optional[str] = typer.Option(
            None, help="write every reading as a JSON line to this file (- for standard output)"
        ),
        bag_out: Optional[Path] = typer.Option(
            None,
            help="write every reading to a new ROS 2 bag (topic /slipsense/reading, std_msgs/msg/String JSON records)",
        ),
        fps: Optional[float] = typer.Option(
            None,
            help="the source's frame rate where it states none (a folder of frames without sensor.json, a "
            "marker .npy) or states it wrongly; videos, bags and cameras carry their own clock",
        ),
        realtime: bool = typer.Option(
            False, help="play a recorded source at the sensor's rate through the live capture path"
        ),
        gel_motion: bool = GEL_MOTION,
    ):
        """Stream a video, an experiment folder, a ROS 2 bag or cameras through a slip detector."""
        from slipsense.watch import watch_source  # torch and OpenCV: when the command runs, not for --help

        set_threads(threads)
        options = dict(quiet=quiet, dtype=dtype, topics=topic, tolerance=tolerance, jsonl=jsonl, bag_out=bag_out)
        options.update(realtime=realtime, fps=fps, hold=hold, gel_motion=gel_motion)
        watch_source(source, checkpoint, threshold, out, combine, backend, max_frames, heatmap, **options)

    @app.command("ros")
    @friendly
    def ros(
        topic: list[str] = typer.Option(
            [], help="an image topic, once per sensor, in order (default /left/image_raw and /right/image_raw)"
        ),
        checkpoint: Optional[Path] = typer.Option(None, help="checkpoint (default: the shipped detector)"),
        threshold: Optional[float] = THRESHOLD,
        hold: Optional[float] = HOLD,
        backend: str = BACKEND,
        threads: Optional[int] = typer.Option(None, help=THREADS_HELP),
        compressed: bool = typer.Option(False, help="the topics carry sensor_msgs/CompressedImage"),
        tolerance: Optional[float] = TOLERANCE,
        max_lag: float = typer.Option(
            0.1,
            help="seconds: while the detector is busy, a frame pair this much older than the newest one waiting "
            "is skipped (counted as behind), so readings keep up with the cameras",
        ),
        gel_motion: bool = GEL_MOTION,
    ):
        """Run the detector as a ROS 2 node: image topics in; /slipsense/reading (std_msgs/String, one JSON
        reading per frame pair), /slipsense/alarm (Bool), /slipsense/probability, /slipsense/slip_velocity and
        /slipsense/status (JSON, every second: every
        frame pair judged or left out, by cause) out (needs: pip install "slipsense\\[ros]")."""
        try:
            import rclpy  # noqa: F401  (the ROS extra)
        except ImportError:
            raise ConfigError('the ROS 2 node needs rclpy: pip install "slipsense[ros]"') from None
        from slipsense.ros_node import main as run_node

        set_threads(threads)
        if threshold is not None and not 0.0 <= threshold <= 1.0:
            raise ConfigError(f"--threshold must be in [0, 1], got {threshold:g}")
        if (tolerance is not None and tolerance <= 0) or max_lag < 0:
            raise ConfigError("--tolerance must be > 0 and --max-lag >= 0 (seconds)")
        if checkpoint is not None and not checkpoint.is_file():
            raise InputError(checkpoint, "checkpoint not found")
        if hold is not None:
            from slipsense.streaming.detector import check_hold

            hold = check_hold(hold)
        given = dict(topics=list(topic) or None, checkpoint=checkpoint and str(checkpoint), threshold=threshold)
        given.update(hold=hold, threads=threads, tolerance=tolerance)  # typer hands floats and an int
        overrides = {"backend": backend, "compressed": compressed, "max_lag": float(max_lag), "gel_motion": gel_motion}
        run_node(argv=[], overrides={**overrides, **{k: v for k, v in given.items() if v is not None}})

    @app.command("export")
    @friendly
    def export(
        checkpoint: Optional[Path] = typer.Option(None, help="checkpoint (default: the shipped detector)"),
        out: Path = typer.Option(..., help="output .onnx file (streaming parts go beside it)"),
        batch: Optional[int] = typer.Option(None, help="fixed batch size (default: dynamic)"),
        streaming: bool = typer.Option(
            True,
            help="also write the parts the live detector runs beside it, <stem>.<part>.onnx: "
            "<stem>.frame.onnx and <stem>.step.onnx (motionnet, motion-energy, shear-retention), "
            "<stem>.frame.onnx and <stem>.window.onnx (vivit, stnet, temnet); none for resnet3d50",
        ),
        verify: bool = typer.Option(True, help="compare ONNX Runtime with PyTorch on a random input"),
    ):
        """Export a checkpoint to ONNX: the whole model at --out (<stem>.onnx) and, with --streaming,
        the parts the live detector runs beside it."""
        from slipsense.streaming.export import export_onnx
        from slipsense.watch import checkpoint_or_shipped

        result = export_onnx(checkpoint_or_shipped(checkpoint), out, batch=batch, streaming=streaming, verify=verify)
        for key, path in result.paths.items():
            diff = result.max_abs_diff.get(key)
            shown = "" if diff is None else f", max |onnx - torch| = {diff:.2e}"
            typer.echo(f"{key:6s} {path}  ({result.exporter[key]} exporter{shown})")
