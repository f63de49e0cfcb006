"""Commands for live detection: ``watch``, ``ros`` and ``export`` (registered by slipsense.cli)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from slipsense.errors import ConfigError, InputError


THREADS_HELP = (
    "intra-op threads for torch and ONNX Runtime (default: torch's). Use 1 on a busy machine: the "
    "small per-frame operations then wait for no descheduled worker thread"
)


def set_threads(threads: Optional[int]) -> None:
    if threads is None:
        return
    if threads < 1:
        raise ConfigError(f"--threads must be a positive integer, got {threads}")
    import torch

    torch.set_num_threads(threads)


def checkpoint_path(path: Path) -> Path:
    """``path`` if it is a file; else one error naming it."""
    if not Path(path).is_file():
        raise InputError(path, "checkpoint not found")
    return Path(path)


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
        fps: Optional[float] = typer.Option(
            None,
            help="the source's frame rate where it states none (a folder of frames without sensor.json, a "
            "marker .npy) or states it wrongly; videos, bags and cameras carry their own clock",
        ),
        realtime: bool = typer.Option(
            False, help="play a recorded source at the sensor's rate through the live capture path"
        ),
    ):
        """Stream a video, an experiment folder, a ROS 2 bag or cameras through a slip detector."""
        from slipsense.watch import watch_source  # torch and OpenCV: when the command runs, not for --help

        set_threads(threads)
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
            fps=fps,
        )

    @app.command("ros")
    @friendly
    def ros(
        topic: list[str] = typer.Option(
            [], help="an image topic, once per sensor, in order (default /left/image_raw and /right/image_raw)"
        ),
        checkpoint: Optional[Path] = typer.Option(None, help="checkpoint (default: the shipped detector)"),
        backend: str = typer.Option("auto", help="auto (ONNX Runtime where installed, else PyTorch), torch or onnx"),
        compressed: bool = typer.Option(False, help="the topics carry sensor_msgs/CompressedImage"),
    ):
        """Run the detector as a ROS 2 node: image topics in, /slipsense/reading (JSON) and
        /slipsense/alarm (stamped) out (needs: pip install "slipsense\\[ros]")."""
        try:
            import rclpy  # noqa: F401  (the ROS extra)
        except ImportError:
            raise ConfigError('the ROS 2 node needs rclpy: pip install "slipsense[ros]"') from None
        from slipsense.ros_node import main as run_node

        overrides = {"backend": backend, "compressed": compressed}
        if topic:
            overrides["topics"] = list(topic)
        if checkpoint is not None:
            overrides["checkpoint"] = str(checkpoint_path(checkpoint))
        run_node(argv=[], overrides=overrides)

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
        from slipsense.watch import checkpoint_or_shipped

        result = export_onnx(checkpoint_or_shipped(checkpoint), out, batch=batch, streaming=streaming, verify=verify)
        for key, path in result.paths.items():
            diff = result.max_abs_diff.get(key)
            typer.echo(
                f"{key:6s} {path}  ({result.exporter[key]} exporter"
                + ("" if diff is None else f", max |onnx - torch| = {diff:.2e}")
                + ")"
            )
