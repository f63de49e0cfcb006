"""Annotated pictures for ``slipsense watch --out``: sensor frames with heat maps, the probability
trace with its threshold line, the alarm banner; written as GIF or MP4."""

from __future__ import annotations

import collections
import math
import os
import tempfile
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np
from PIL import Image

from slipsense.atomic import write_with
from slipsense.errors import InputError
from slipsense.streaming.detector import FPS, Reading

#: Seconds of probability history the trace panel shows.
TRACE_SECONDS = 6.0


class Annotator:
    """Draws one annotated picture per reading: the sensor frame(s) with the heat map, the
    probability trace with the threshold line, and the alarm state. BGR uint8 pictures.

    ``panel_height``: pixel height each sensor frame is drawn at.
    """

    def __init__(self, threshold: float, sensors: int, fps: float = FPS, panel_height: int = 240):
        self.threshold, self.sensors, self.fps, self.panel_height = threshold, sensors, fps, panel_height
        self.history: collections.deque[float] = collections.deque(maxlen=int(TRACE_SECONDS * fps))

    def draw(
        self,
        frames: Sequence[np.ndarray],
        reading: Reading,
        heatmaps: Sequence[np.ndarray | None] = (),
        clouds: Sequence[np.ndarray | None] = (),
    ) -> np.ndarray:
        """``frames``: per sensor a BGR image or None (marker-only sensors); ``heatmaps``: per sensor
        a patch-grid map ``(Hp, Wp)``, a per-marker map ``(M,)`` or None; ``clouds``: per sensor the
        ``(M, 3)`` cloud the marker map refers to (its x, y are drawn)."""
        self.history.append(math.nan if reading.probability is None else reading.probability)
        panels = []
        for s in range(self.sensors):
            frame = frames[s] if s < len(frames) else None
            heat = heatmaps[s] if s < len(heatmaps) else None
            cloud = clouds[s] if s < len(clouds) else None
            p = None if reading.per_sensor is None else reading.per_sensor[s]
            panels.append(self._sensor_panel(frame, heat, cloud, s, p))
        top = np.concatenate(panels, axis=1)
        width = top.shape[1]
        return np.concatenate([self._banner(reading, width), top, self._trace(width)], axis=0)

    def _sensor_panel(self, frame, heat, cloud, sensor, p) -> np.ndarray:
        h = self.panel_height
        if frame is not None:
            w = max(1, int(round(frame.shape[1] * h / frame.shape[0])))
            img = cv2.resize(np.ascontiguousarray(frame), (w, h), interpolation=cv2.INTER_AREA)
        else:
            w = int(round(h * 4 / 3))
            img = np.full((h, w, 3), 40, np.uint8)
        if heat is not None and heat.ndim == 2:
            m = heat / max(float(heat.max()), 1e-12)
            m = cv2.resize(m.astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
            colour = cv2.applyColorMap(np.clip(m * 255, 0, 255).astype(np.uint8), cv2.COLORMAP_JET)
            img = cv2.addWeighted(img, 0.6, colour, 0.4, 0)
        if cloud is not None:
            xy = cloud[:, :2].astype(np.float64)
            lo, hi = xy.min(axis=0), xy.max(axis=0)
            span = np.maximum(hi - lo, 1e-9)
            pix = 10 + (xy - lo) / span * np.array([w - 20, h - 20])
            sal = np.zeros(len(xy)) if heat is None or heat.ndim != 1 else heat
            colours = cv2.applyColorMap(np.clip(sal * 255, 0, 255).astype(np.uint8)[:, None], cv2.COLORMAP_JET)[:, 0]
            for (x, y), c in zip(pix, colours):
                cv2.circle(img, (int(x), int(y)), 3, tuple(int(v) for v in c), -1, cv2.LINE_AA)
        label = f"sensor {sensor}" + ("" if p is None else f"  p={p:.2f}")
        cv2.putText(img, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        return img

    def _banner(self, reading: Reading, width: int) -> np.ndarray:
        bar = np.zeros((28, width, 3), np.uint8)
        if reading.probability is None:
            bar[:] = (90, 90, 90)
            state = "filling window"
        elif reading.alarm:
            bar[:] = (0, 0, 200)
            state = f"SLIP ALARM  p={reading.probability:.2f}"
        else:
            bar[:] = (0, 120, 0)
            state = f"no slip  p={reading.probability:.2f}"
        text = f"frame {reading.index}  t={reading.index / self.fps:6.2f} s   {state}"
        cv2.putText(bar, text, (6, 19), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
        return bar

    def _trace(self, width: int, height: int = 90) -> np.ndarray:
        img = np.full((height, width, 3), 255, np.uint8)
        top, bottom, left, right = 6, height - 8, 30, width - 6
        cv2.putText(img, "1", (12, top + 8), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
        cv2.putText(img, "0", (12, bottom), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
        cv2.rectangle(img, (left, top), (right, bottom), (200, 200, 200), 1)

        def y_of(p: float) -> int:
            return int(round(bottom - p * (bottom - top)))

        yt = y_of(self.threshold)
        for x in range(left, right, 8):  # dashed threshold line
            cv2.line(img, (x, yt), (min(x + 4, right), yt), (0, 0, 220), 1)
        n = self.history.maxlen or 1
        step = (right - left) / max(n - 1, 1)
        pts = [(int(round(left + i * step)), y_of(p)) for i, p in enumerate(self.history) if not math.isnan(p)]
        if len(pts) > 1:
            cv2.polylines(img, [np.array(pts, np.int32)], False, (160, 60, 0), 2, cv2.LINE_AA)
        elif pts:
            cv2.circle(img, pts[0], 2, (160, 60, 0), -1)
        cv2.putText(
            img,
            f"slip probability (last {TRACE_SECONDS:g} s), threshold {self.threshold:g}",
            (left + 4, top + 12),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.35,
            (80, 80, 80),
            1,
            cv2.LINE_AA,
        )
        return img


class AnnotatedWriter:
    """Collects annotated BGR pictures and writes them as a GIF (Pillow) or a video (OpenCV), atomically.

    ``.gif``: 256-colour frames held in memory (1 byte per pixel) until :meth:`close`;
    ``.mp4`` (mp4v) / ``.avi`` (MJPG): streamed to a temporary file, renamed on :meth:`close`.
    """

    def __init__(self, path: str | Path, fps: float = FPS):
        self.path = Path(path)
        self.fps = fps
        suffix = self.path.suffix.lower()
        if suffix not in (".gif", ".mp4", ".avi"):
            raise InputError(self.path, "output must end in .gif, .mp4 or .avi")
        self.kind = suffix
        self._frames: list[Any] = []
        self._writer = None
        self._tmp: Path | None = None
        self._size: tuple[int, int] | None = None

    def add(self, picture: np.ndarray) -> None:
        if self._size is None:
            self._size = (picture.shape[1], picture.shape[0])
        elif (picture.shape[1], picture.shape[0]) != self._size:
            picture = cv2.resize(picture, self._size, interpolation=cv2.INTER_AREA)
        if self.kind == ".gif":
            rgb = Image.fromarray(cv2.cvtColor(picture, cv2.COLOR_BGR2RGB))
            self._frames.append(rgb.quantize(colors=256, method=Image.Quantize.MEDIANCUT))
            return
        if self._writer is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(
                prefix=f".{self.path.stem}.", suffix=f".tmp{self.path.suffix}", dir=self.path.parent
            )

            os.close(fd)
            self._tmp = Path(tmp)
            fourcc = cv2.VideoWriter_fourcc(*("mp4v" if self.kind == ".mp4" else "MJPG"))
            self._writer = cv2.VideoWriter(str(self._tmp), fourcc, self.fps, self._size)
            if not self._writer.isOpened():
                self._tmp.unlink(missing_ok=True)
                raise InputError(self.path, "OpenCV cannot write this video format here")
        self._writer.write(picture)

    def close(self) -> Path | None:
        """Finish the file; returns its path (None when no picture was added)."""
        if self.kind == ".gif":
            if not self._frames:
                return None

            first, rest = self._frames[0], self._frames[1:]
            write_with(
                self.path,
                lambda tmp: first.save(
                    tmp, format="GIF", save_all=True, append_images=rest, duration=int(round(1000 / self.fps)), loop=0
                ),
            )
            self._frames = []
            return self.path
        if self._writer is None:
            return None
        self._writer.release()
        self._writer = None
        os.replace(self._tmp, self.path)
        return self.path

    def abort(self) -> None:
        if self._writer is not None:
            self._writer.release()
            self._writer = None
        if self._tmp is not None and self._tmp.exists():
            self._tmp.unlink()
        self._frames = []
