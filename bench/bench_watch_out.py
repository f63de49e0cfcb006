"""``slipsense watch RUN --out run.gif`` / ``--out run.mp4``: wall time against the video's length,
file size and mode, side by side with the same run watched without a picture.

    .venv/bin/python bench/bench_watch_out.py                    # Markdown on stdout
    .venv/bin/python bench/bench_watch_out.py --rounds 5 --mediancut --json watch-out.json

What is timed: one :func:`slipsense.watch.watch_source` call (what ``slipsense watch`` runs once its
imports are done): opening the run, loading the shipped detector, pushing every frame pair, drawing
the annotated picture and writing the file. The cases run in interleaved rounds (the machine may be
shared); the table gives the median. ``x real time``: the video's seconds (frames / the run's
frame rate) over the wall seconds; above 1 the picture is made faster than the sensor records, the
target (issue: watch --out too slow) is 2x or more for the two-finger run ``blue_mug/exp_num_9`` (143
frames, 5.7 s). ``--mediancut`` adds the writer as it was before (a MEDIANCUT palette of its own for
every frame, dithered), for the ratio of old to new. ``mode``: the file's permission bits (0666 less
the umask is what a plain ``open()`` gives).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import slipsense.watch as watch  # noqa: E402
from slipsense.atomic import write_with  # noqa: E402
from slipsense.paths import gelsight_recordings  # noqa: E402
from slipsense.streaming.annotate import AnnotatedWriter  # noqa: E402


class MedianCutWriter(AnnotatedWriter):
    """The GIF writer before: every frame quantized to its own MEDIANCUT palette (Pillow's default
    dithering), all frames handed to Pillow's GIF writer at the end."""

    def __init__(self, path, fps=25.0):
        super().__init__(path, fps)
        self._old: list[Image.Image] = []

    def add(self, picture):
        rgb = Image.fromarray(cv2.cvtColor(picture, cv2.COLOR_BGR2RGB))
        self._old.append(rgb.quantize(colors=256, method=Image.Quantize.MEDIANCUT))

    def close(self):
        first, rest = self._old[0], self._old[1:]
        kw = dict(save_all=True, append_images=rest, duration=int(round(1000 / self.fps)), loop=0)
        write_with(self.path, lambda tmp: first.save(tmp, format="GIF", **kw))
        return self.path


def watch_once(run: Path, out: Path | None, writer=AnnotatedWriter) -> dict:
    """One watch of ``run``, the seconds it took and what it wrote."""
    if out is not None:
        out.unlink(missing_ok=True)
    watch.AnnotatedWriter = writer
    try:
        t0 = time.perf_counter()
        summary = watch.watch_source(str(run), None, out=out, quiet=True, echo=lambda *a, **k: None)
        seconds = time.perf_counter() - t0
    finally:
        watch.AnnotatedWriter = AnnotatedWriter
    row = {"seconds": seconds, "frames": summary["frames"]}
    if out is not None:
        row["bytes"] = out.stat().st_size
        row["mode"] = oct(out.stat().st_mode & 0o777)
        if out.suffix == ".gif":
            with Image.open(out) as gif:
                row["gif_frames"] = gif.n_frames
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", type=Path, default=None, help="a run folder (default: the shared blue_mug/exp_num_9)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--mediancut", action="store_true", help="also the GIF writer as it was before (slow)")
    ap.add_argument("--json", type=Path, help="also write the numbers as JSON here")
    args = ap.parse_args(argv)
    run = args.run or gelsight_recordings() / "blue_mug" / "exp_num_9"
    fps = cv2.VideoCapture(str(run / "camera_0.avi")).get(cv2.CAP_PROP_FPS) or 25.0

    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="bench-watch-out-") as tmp:
        cases = {
            "no picture": (None, AnnotatedWriter),
            "--out run.gif": (Path(tmp) / "run.gif", AnnotatedWriter),
            "--out run.mp4": (Path(tmp) / "run.mp4", AnnotatedWriter),
        }
        if args.mediancut:
            cases["--out run.gif (before: MEDIANCUT per frame)"] = (Path(tmp) / "old.gif", MedianCutWriter)
        watch_once(run, None)  # warm up: the detector's first load, the source's first decode
        rows: dict[str, list[dict]] = {name: [] for name in cases}
        for r in range(args.rounds):
            for name, (out, writer) in cases.items():
                rows[name].append(watch_once(run, out, writer))
                print(f"round {r + 1}: {name} {rows[name][-1]['seconds']:.2f} s", file=sys.stderr, flush=True)

    frames = rows["no picture"][0]["frames"]
    video_s = frames / fps
    lines = [
        f"# `slipsense watch {run.parent.name}/{run.name} --out ...`: {frames} frames, {video_s:.2f} s of video",
        "",
        f"Load average before {load_before[0]:.2f}, after {os.getloadavg()[0]:.2f}; "
        f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}; median of {args.rounds} round(s).",
        "",
        "| output | wall (s) | x real time | per frame (ms) | size (MB) | mode | GIF frames |",
        "|---|---:|---:|---:|---:|---|---:|",
    ]
    summary = {}
    for name, rs in rows.items():
        s = statistics.median(r["seconds"] for r in rs)
        last = rs[-1]
        size = "-" if "bytes" not in last else f"{last['bytes'] / 1e6:.2f}"
        lines.append(
            f"| {name} | {s:.2f} | {video_s / s:.2f}x | {s / frames * 1e3:.1f} | {size} | {last.get('mode', '-')} | "
            f"{last.get('gif_frames', '-')} |"
        )
        summary[name] = {
            "seconds": s,
            "realtime_ratio": video_s / s,
            **{k: v for k, v in last.items() if k != "seconds"},
        }
    base = statistics.median(r["seconds"] for r in rows["no picture"])
    lines += [
        "",
        "Picture cost over the plain watch: "
        + ", ".join(
            f"{name} +{statistics.median(r['seconds'] for r in rs) - base:.2f} s"
            for name, rs in rows.items()
            if name != "no picture"
        )
        + ".",
    ]
    if args.mediancut:
        old = summary["--out run.gif (before: MEDIANCUT per frame)"]
        new = summary["--out run.gif"]
        lines.append(
            f"GIF before / now: {old['seconds'] / new['seconds']:.1f}x the time, {old['bytes'] / new['bytes']:.1f}x the size."
        )
    report = "\n".join(lines)
    print(report)
    if args.json:
        args.json.write_text(
            json.dumps({"run": str(run), "frames": frames, "video_s": video_s, "cases": summary}, indent=1)
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
