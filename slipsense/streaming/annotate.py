"""Annotated pictures for ``slipsense watch --out``: sensor frames with heat maps, the probability
trace with its threshold line, the alarm banner; written as GIF or MP4."""

from __future__ import annotations

import collections
import math
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np
from PIL import Image

from slipsense.alarm import shown_probability
from slipsense.atomic import atomic_path, write_with
from slipsense.errors import InputError
from slipsense.streaming.detector import Reading

#: Seconds of probability history the trace panel shows.
TRACE_SECONDS = 6.0


class Annotator:
    """Draws one annotated picture per reading: the sensor frame(s) with the heat map, the
    probability trace with the threshold line, and the alarm state. BGR uint8 pictures.

    ``panel_height``: pixel height each sensor frame is drawn at.
    """

    def __init__(self, threshold: float, sensors: int, fps: float, panel_height: int = 240):
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
            panel = self._sensor_panel(frame, heat, cloud, s, p)
            slip = None if reading.slip is None else reading.slip[s]
            if slip is not None:
                _draw_slip(panel, slip, reading.slip_velocity_unit)
            panels.append(panel)
        top = np.concatenate(panels, axis=1)
        width = top.shape[1]
        return np.concatenate([self._banner(reading, width), top, self._trace(width)], axis=0)

    def _sensor_panel(self, frame, heat, cloud, sensor, p) -> np.ndarray:
        """One sensor's picture: its frame (or its cloud's markers), the heat map, its probability."""
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
        label = f"sensor {sensor}" + ("" if p is None else f"  p={shown_probability(p, self.threshold, 2)}")
        cv2.putText(img, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        return img

    def _banner(self, reading: Reading, width: int) -> np.ndarray:
        bar = np.zeros((28, width, 3), np.uint8)
        if reading.probability is None:
            bar[:] = (90, 90, 90)
            state = "filling window"
        elif reading.alarm:
            bar[:] = (0, 0, 200)
            state = f"SLIP ALARM  p={shown_probability(reading.probability, self.threshold)}"
        else:
            bar[:] = (0, 120, 0)
            state = f"no slip  p={shown_probability(reading.probability, self.threshold)}"
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
        title = f"slip probability (last {TRACE_SECONDS:g} s), threshold {self.threshold:g}"
        cv2.putText(img, title, (left + 4, top + 12), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (80, 80, 80), 1, cv2.LINE_AA)
        return img


#: The colours the Annotator draws with (RGB), kept exact in every GIF palette whatever the sensor
#: frames look like: banners, text, the trace and its threshold line.
_DRAWN_COLOURS = ((0, 0, 0), (255, 255, 255), (90, 90, 90), (0, 120, 0), (200, 0, 0), (40, 40, 40), (0, 60, 160))
_DRAWN_COLOURS += ((220, 0, 0), (200, 200, 200), (80, 80, 80))


class _GifFrames:
    """BGR pictures as GIF frames on one shared palette, each frame holding only what changed.

    The palette (255 colours: the drawn colours and an octree palette of a picture) is made from the
    first picture and again whenever a picture fits it badly (a camera's exposure settling, a heat
    map appearing): its mean error over :attr:`REFIT` times the error the palette was made with, plus
    one level. Pictures are mapped through a table of the nearest palette entry of each 5-bit-per-channel
    colour, filled in as colours first appear; no dithering. A pixel whose shown colour is within
    :attr:`LOSSY` levels (largest channel difference) of its best palette colour keeps it and is
    written transparent (index 255), so the sensors' still parts and the unchanged panels cost next
    to nothing; a frame with a new palette is written whole. 1 byte a pixel is held per frame until
    the GIF is written.
    """

    TRANSPARENT = 255
    BITS = 5
    LOSSY = 8
    REFIT = 1.5

    def __init__(self) -> None:
        self.frames: list[Image.Image] = []
        self._shown: np.ndarray | None = None  # palette index each pixel shows after the last frame
        self._error = 0.0
        self._last_empty = False

    def _palette(self, picture: np.ndarray) -> None:
        """A palette made from ``picture``, its nearest-entry table empty."""
        n = self.TRANSPARENT - len(_DRAWN_COLOURS)
        rgb = Image.fromarray(cv2.cvtColor(picture, cv2.COLOR_BGR2RGB))
        own = rgb.quantize(colors=n, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).getpalette() or []
        pal = np.concatenate(
            [np.asarray(_DRAWN_COLOURS, np.float32), np.asarray(own[: 3 * n], np.float32).reshape(-1, 3)]
        )  # RGB, at most 255 entries: index 255 stays free for transparency
        self._pal, self._norms = pal, (pal**2).sum(axis=1)
        self._lut = np.full(1 << (3 * self.BITS), self.TRANSPARENT, np.uint8)  # 255: not looked up yet
        table = np.zeros((256, 3), np.uint8)
        table[: len(pal)] = pal
        self._rgb = table.tobytes()
        self._channels = [np.ascontiguousarray(table[:, c]) for c in (2, 1, 0)]  # B, G, R of each index

    def _look_up(self, keys: np.ndarray) -> None:
        """Fill the table for the colour cells ``keys`` (``r << 10 | g << 5 | b``, 5 bits each)."""
        cells = np.flatnonzero(np.bincount(keys, minlength=self._lut.size))
        mask, shift = (1 << self.BITS) - 1, 8 - self.BITS
        rgb = np.stack([cells >> (2 * self.BITS), (cells >> self.BITS) & mask, cells & mask], axis=1)
        centres = (rgb * (1 << shift) + ((1 << shift) - 1) / 2).astype(np.float32)
        for i in range(0, len(cells), 8192):
            near = (self._norms[None] - 2 * centres[i : i + 8192] @ self._pal.T).argmin(axis=1)
            self._lut[cells[i : i + 8192]] = near

    def _map(self, picture: np.ndarray, planes: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Palette indices of ``picture`` (its B, G, R ``planes``) and each pixel's error."""
        h, w = picture.shape[:2]
        q = picture.reshape(-1, 3) >> (8 - self.BITS)
        key = q[:, 2].astype(np.uint16)
        key <<= self.BITS
        key |= q[:, 1]
        key <<= self.BITS
        key |= q[:, 0]
        idx = np.take(self._lut, key)
        new = idx == self.TRANSPARENT
        if new.any():
            self._look_up(key[new])
            idx = np.take(self._lut, key)
        idx = idx.reshape(h, w)
        return idx, self._error_of(planes, idx)

    def _error_of(self, planes: Sequence[np.ndarray], idx: np.ndarray) -> np.ndarray:
        """How far the colours of palette indices ``idx`` are from the picture: its largest channel difference."""
        b, g, r = (cv2.absdiff(plane, cv2.LUT(idx, c)) for plane, c in zip(planes, self._channels))
        return cv2.max(cv2.max(b, g), r)

    def add(self, picture: np.ndarray) -> None:
        picture = np.ascontiguousarray(picture)
        planes = cv2.split(picture)
        whole = self._shown is None
        if not whole:
            idx, err = self._map(picture, planes)
            whole = cv2.mean(err)[0] > self.REFIT * self._error + 1
        if whole:  # a new palette; the frame is written whole
            self._palette(picture)
            idx, err = self._map(picture, planes)
            self._error = cv2.mean(err)[0]
            out, self._last_empty = idx, False
        else:
            # a pixel keeps what it shows while that is nearly as close as the best palette colour
            keep = cv2.compare(self._error_of(planes, self._shown), cv2.add(err, self.LOSSY), cv2.CMP_LE)
            cv2.copyTo(self._shown, keep, idx)  # in place: idx is what each pixel shows now
            out = cv2.bitwise_or(idx, keep)  # 255 (transparent) where kept
            empty = cv2.countNonZero(keep) == keep.size
            if empty and self._last_empty:  # two empty frames in a row would be merged into one
                out[0, 0] = idx[0, 0]
                empty = False
            self._last_empty = empty
        self._shown = idx
        frame = Image.fromarray(out, "P")
        frame.putpalette(self._rgb)
        frame.info["transparency"] = self.TRANSPARENT
        self.frames.append(frame)

    def save(self, path: Path, fps: float) -> None:
        first, rest = self.frames[0], self.frames[1:]
        # not optimized: the frames are already differences on one palette; disposal 1: each drawn over the last
        gif = dict(save_all=True, append_images=rest, duration=int(round(1000 / fps)), loop=0, optimize=False)
        first.save(path, format="GIF", disposal=1, transparency=self.TRANSPARENT, **gif)


class _Aborted(Exception):
    """Thrown into :func:`atomic_path` to drop its temporary file."""


def check_suffix(path: str | Path) -> str:
    """The kind of annotated output ``path`` asks for (its suffix); InputError for one not written."""
    suffix = Path(path).suffix.lower()
    if suffix not in (".gif", ".mp4", ".avi"):
        raise InputError(Path(path), "output must end in .gif, .mp4 or .avi")
    return suffix


class AnnotatedWriter:
    """Collects annotated BGR pictures and writes them as a GIF (Pillow) or a video (OpenCV), atomically,
    with the mode a plain ``open()`` gives (0666 less the umask).

    ``.gif``: frames on a shared 255-colour palette, each holding only what changed (see
    :class:`_GifFrames`), 1 byte a pixel held in memory until :meth:`close`;
    ``.mp4`` (mp4v) / ``.avi`` (MJPG): streamed to a temporary file, renamed on :meth:`close`.
    """

    def __init__(self, path: str | Path, fps: float):
        self.path = Path(path)
        self.fps = fps
        suffix = check_suffix(self.path)
        self.kind = suffix
        self._gif = _GifFrames() if suffix == ".gif" else None
        self._writer = None
        self._atomic: Any = None  # the open atomic_path of a video
        self._size: tuple[int, int] | None = None

    def add(self, picture: np.ndarray) -> None:
        if self._size is None:
            self._size = (picture.shape[1], picture.shape[0])
        elif (picture.shape[1], picture.shape[0]) != self._size:
            picture = cv2.resize(picture, self._size, interpolation=cv2.INTER_AREA)
        if self._gif is not None:
            self._gif.add(picture)
            return
        if self._writer is None:
            self._atomic = atomic_path(self.path)
            tmp = self._atomic.__enter__()
            fourcc = cv2.VideoWriter_fourcc(*("mp4v" if self.kind == ".mp4" else "MJPG"))
            self._writer = cv2.VideoWriter(str(tmp), fourcc, self.fps, self._size)
            if not self._writer.isOpened():
                self.abort()
                raise InputError(self.path, "OpenCV cannot write this video format here")
        self._writer.write(picture)

    def close(self) -> Path | None:
        """Finish the file; returns its path (None when no picture was added)."""
        if self._gif is not None:
            if not self._gif.frames:
                return None
            write_with(self.path, lambda tmp: self._gif.save(tmp, self.fps))
            self._gif = _GifFrames()
            return self.path
        if self._writer is None:
            return None
        self._writer.release()
        self._writer = None
        atomic, self._atomic = self._atomic, None
        atomic.__exit__(None, None, None)  # fsync, mode, rename
        return self.path

    def abort(self) -> None:
        if self._writer is not None:
            self._writer.release()
            self._writer = None
        if self._atomic is not None:
            atomic, self._atomic = self._atomic, None
            atomic.__exit__(_Aborted, _Aborted(), None)  # removes the temporary file
        if self._gif is not None:
            self._gif = _GifFrames()


#: Slip speeds drawn as an arrow half the panel long (faster ones are drawn that long too).
_FULL_ARROW = {"mm/s": 20.0, "px/s": 400.0}
#: Rotation rate (rad/s) drawn as an arc of half a turn (faster ones are drawn that far too).
_FULL_TURN = 1.0
_SLIP_COLOUR = (0, 255, 255)


def _draw_slip(panel: np.ndarray, slip: dict, unit: str | None) -> None:
    """One finger's slip (a reading's ``slip`` entry) over its panel, in place: the translation as an
    arrow and the rotation as an arc about the panel's centre, the stick share as a bar, and along the
    bottom in words the slip speed over the contact, the rotation and the stick share."""
    h, w = panel.shape[:2]
    centre, reach = (w // 2, h // 2), 0.5 * min(h, w)
    _draw_translation(panel, slip["translation"], unit, centre, reach)
    _draw_turn(panel, slip["omega"], centre, int(round(0.6 * reach)))
    bar = (6, h - 30, 86, h - 24)
    cv2.rectangle(panel, bar[:2], bar[2:], _SLIP_COLOUR, 1)
    fill = bar[0] + int(round(slip["stick"] * (bar[2] - bar[0])))
    if fill > bar[0]:
        cv2.rectangle(panel, bar[:2], (fill, bar[3]), _SLIP_COLOUR, -1)
    text = f"slip {slip['speed']:.1f} {unit or ''}  turn {slip['omega']:+.2f} rad/s  stick {slip['stick']:.0%}"
    (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1)
    cv2.rectangle(panel, (3, h - 11 - th), (9 + tw, h - 3), (40, 40, 40), -1)  # readable on a bright gel too
    cv2.putText(panel, text, (6, h - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.45, _SLIP_COLOUR, 1, cv2.LINE_AA)


def _draw_translation(panel, translation, unit, centre, reach) -> None:
    """An arrow from ``centre`` in the translation's direction in the image, ``reach`` long at
    :data:`_FULL_ARROW`."""
    size = math.hypot(*translation)
    if size > 0:
        length = reach * min(1.0, size / _FULL_ARROW.get(unit or "", 20.0))
        tip = tuple(int(round(c + v / size * length)) for c, v in zip(centre, translation))
        cv2.arrowedLine(panel, centre, tip, _SLIP_COLOUR, 2, cv2.LINE_AA, tipLength=0.25)


def _draw_turn(panel, omega: float, centre, radius: int) -> None:
    """An arc of ``radius`` about ``centre`` from straight above, swept the way the object turns
    (positive omega turns +x towards +y: clockwise on screen, as OpenCV's angles run) and half a turn
    at :data:`_FULL_TURN`, an arrowhead at its end."""
    sweep = 180.0 * math.copysign(min(1.0, abs(omega) / _FULL_TURN), omega)
    if abs(sweep) < 1.0:  # under a degree: no arc to see, the words say it
        return
    start, end = -90.0, -90.0 + sweep
    cv2.ellipse(panel, centre, (radius, radius), 0.0, start, end, _SLIP_COLOUR, 2, cv2.LINE_AA)

    def at(angle: float) -> tuple[int, int]:
        a = math.radians(angle)
        return int(round(centre[0] + radius * math.cos(a))), int(round(centre[1] + radius * math.sin(a)))

    # the head along the arc's last stretch (at most 15 degrees), so that it points the way it turns
    tail = end - math.copysign(min(abs(sweep), 15.0), sweep)
    cv2.arrowedLine(panel, at(tail), at(end), _SLIP_COLOUR, 2, cv2.LINE_AA, tipLength=0.8)
