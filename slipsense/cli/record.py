"""``slipsense record``: capture grasps from cameras into the recordings layout."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer


def _stdin_commands():
    """``commands(index)`` for :func:`slipsense.streaming.record.record`: the lines typed on standard
    input since the last call (a thread reads them, so frames keep coming while nobody types)."""
    import queue
    import sys
    import threading

    lines: queue.Queue[str] = queue.Queue()

    def read():
        for line in sys.stdin:
            lines.put(line.strip().lower())

    threading.Thread(target=read, name="slipsense-record-keys", daemon=True).start()

    def commands(index: int) -> list[str]:
        return [lines.get_nowait() for _ in range(lines.qsize())]  # this thread alone takes from the queue

    return commands


def register(app: typer.Typer) -> None:
    from slipsense.cli.common import friendly

    @app.command()
    @friendly
    def record(
        source: str = typer.Argument(..., help="camera index (two fingers: 0,2), or a video / run folder to cut"),
        out: Path = typer.Option(..., help="recordings folder: <out>/<object>/exp_num_<N>/camera_<i>.avi"),
        object_name: str = typer.Option(..., "--object", help="the object grasped (names its folder)"),
        by_contact: bool = typer.Option(False, help="start and stop each grasp when the gels are touched and let go"),
        sensor: Optional[str] = typer.Option(
            None, help="the registered sensor recorded (default: the shipped detectors' sensor, the GelSight Mini)"
        ),
        fps: Optional[float] = typer.Option(
            None, help="frame rate asked of the cameras (default: the sensor's), or of a folder of frames"
        ),
        max_grasps: Optional[int] = typer.Option(None, help="stop after this many grasps"),
    ):
        """Record grasps: Enter starts and stops a grasp, s + Enter marks it slipped, q + Enter quits
        (--by-contact: the gels start and stop it). Every command then reads the folder."""
        from slipsense.checkpoint import read_info
        from slipsense.errors import ConfigError
        from slipsense.resources import shipped_model
        from slipsense.sensors.spec import sensor_named, sensor_of
        from slipsense.streaming.clock import check_fps
        from slipsense.streaming.record import check_object_name, record as run
        from slipsense.streaming.sources import open_source

        check_object_name(object_name)
        if max_grasps is not None and max_grasps < 1:
            raise ConfigError(f"--max-grasps must be 1 or more, got {max_grasps}")
        # recorded for the shipped detectors unless told otherwise: their checkpoint names their sensor
        spec = sensor_named(sensor) if sensor is not None else sensor_of(read_info(shipped_model()), shipped_model())
        camera = spec.fps if fps is None else check_fps(fps, "--fps")
        live = all(part.strip().isdigit() for part in source.split(","))
        src = open_source(
            source, None, fps=None if live else fps, camera_fps=camera, capture_format=spec.capture_format
        )
        # a recorded run standing in for the cameras keeps its label: its slip.txt marks every grasp cut from it
        folder = Path(source) if Path(source).is_dir() else Path(source).parent
        source_slipped = not live and (folder / "slip.txt").is_file()
        try:
            keys = "the gels start and stop each grasp" if by_contact else "Enter starts and stops a grasp"
            if source_slipped:
                keys += f"; the source is labelled slipped ({folder / 'slip.txt'}), so its grasps are too"
            typer.echo(
                f"{src.name}: {src.sensors} camera(s) at {src.fps:g} frames/s ({src.clock}); {keys}, "
                "s + Enter marks it slipped, q + Enter quits"
            )
            options = dict(by_contact=by_contact, max_grasps=max_grasps, echo=typer.echo, source_slipped=source_slipped)
            steps = (step.display for step in src.frames())
            done = run(steps, out, object_name, src.fps, commands=_stdin_commands(), **options)
        finally:
            src.close()
        typer.echo(f"{len(done)} grasp(s) recorded in {out}")
