"""Live capture that keeps the sensor's rate: one thread per camera always holding the newest frame.

A plain ``while True: cap.read(); detect()`` loop reads a frame only when the detector is done with
the last one, so a camera sold at 25 frames/s delivers 15-18 (users of the GelSight Mini report it) and
the frames it does deliver are stale: they waited in the driver's buffer. Here a thread per camera
reads as fast as the camera gives (the pattern gs_sdk uses), stamps each frame with the capture
clock, and keeps only the newest; the consumer takes the newest frame it has not seen. A consumer
slower than the camera skips frames, and the skipped ones are counted (``dropped``), as are frames the
camera sent twice (``repeated``: identical to the one before, what some drivers send when asked for
more frames than they have).
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from typing import Any, Callable, Iterator, Sequence

import cv2
import numpy as np

from slipsense.errors import InputError

#: seconds a consumer waits for a camera's next frame before the stream is taken as ended
FRAME_TIMEOUT = 2.0


class CaptureThread:
    """Reads ``read() -> (ok, frame)`` on its own thread until it fails or :meth:`close`.

    :meth:`next` hands out the newest frame newer than the one the consumer had, as
    ``(sequence number, capture time s, frame)``; sequence numbers count every frame read, from 1."""

    def __init__(self, read: Callable[[], tuple[bool, Any]], name: str = "camera", clock=time.monotonic, release=None):
        self.name, self._read, self._clock, self._release = name, read, clock, release
        self._cond = threading.Condition()
        self._latest: tuple[int, float, np.ndarray] | None = None
        self._ended = False
        self._stop = False
        self.grabbed = self.delivered = self.dropped = self.repeated = 0
        self._handed = 0  # sequence number of the last frame handed out
        self._first: float | None = None  # capture times of the first and the latest frame
        self._last: float | None = None
        self._thread = threading.Thread(target=self._run, name=f"slipsense-capture-{name}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        previous = None
        try:
            while not self._stop:
                ok, frame = self._read()
                stamp = self._clock()
                if not ok or frame is None:
                    break
                with self._cond:
                    self.grabbed += 1
                    if previous is not None and previous.shape == frame.shape and np.array_equal(previous, frame):
                        self.repeated += 1
                    self._first = stamp if self._first is None else self._first
                    self._last = stamp
                    self._latest = (self.grabbed, stamp, frame)
                    self._cond.notify_all()
                previous = frame
        finally:
            with self._cond:
                self._ended = True
                self._cond.notify_all()
            if self._stop:
                self._release_once()  # closed while this thread was still reading: it lets go here

    def next(self, after: int = 0, timeout: float = FRAME_TIMEOUT) -> tuple[int, float, np.ndarray] | None:
        """The newest frame with a sequence number above ``after`` (waiting up to ``timeout`` s for
        one), or None when the camera has ended or sent nothing in that time."""
        with self._cond:
            ok = self._cond.wait_for(
                lambda: (self._latest is not None and self._latest[0] > after) or self._ended, timeout
            )
            if not ok or self._latest is None or self._latest[0] <= after:
                return None
            seq = self._latest[0]
            self.dropped += seq - self._handed - 1  # read, then replaced before anyone took them
            self.delivered += 1
            self._handed = seq
            return self._latest

    def stats(self) -> dict[str, Any]:
        """``grabbed``, ``delivered``, ``dropped`` (read but never handed out), ``repeated`` and the
        achieved capture rate ``fps`` (frames read per second between the first and the last)."""
        with self._cond:
            span = (self._last - self._first) if self._first is not None and self._last is not None else 0.0
            fps = (self.grabbed - 1) / span if span > 0 else float("nan")
            counts = {k: getattr(self, k) for k in ("grabbed", "delivered", "dropped", "repeated")}
            return {"camera": self.name, **counts, "fps": fps}

    def give_back(self) -> None:
        """The frame :meth:`next` handed out last was replaced before use (a camera catching up with
        another): it counts as dropped, not delivered."""
        with self._cond:
            self.delivered -= 1
            self.dropped += 1

    def close(self) -> None:
        self._stop = True
        self._thread.join(timeout=1.0)
        if not self._thread.is_alive():  # never release a camera another thread is reading
            self._release_once()

    def _release_once(self) -> None:
        with self._cond:
            release, self._release = self._release, None
        if release is not None:
            release()


class PacedReader:
    """``read()`` of recorded frames at a set rate, as a camera delivers them: frame ``k`` is handed
    out at ``start + k / fps`` (a reader that falls behind catches up, as a camera's clock does not
    wait). What the capture path is tested with, and ``slipsense watch FILE --realtime`` plays."""

    def __init__(self, frames: Sequence[np.ndarray], fps: float, clock=time.monotonic, sleep=time.sleep):
        self.frames, self.fps, self._clock, self._sleep = frames, float(fps), clock, sleep
        self._k = 0
        self._start: float | None = None

    def read(self) -> tuple[bool, np.ndarray | None]:
        if self._k >= len(self.frames):
            return False, None
        if self._start is None:
            self._start = self._clock()
        wait = self._start + self._k / self.fps - self._clock()
        if wait > 0:
            self._sleep(wait)
        frame = self.frames[self._k]
        self._k += 1
        return True, frame


def paired(threads: Sequence[CaptureThread], tolerance_s: float, timeout: float = FRAME_TIMEOUT):
    """Steps of the newest frames of every camera, paired by capture time: while the stamps differ by
    more than ``tolerance_s`` the camera behind gives its next frame (at most 3 times a step).
    Yields ``(frames, stamps, numbers)``, ``numbers`` each frame's 1-based number in its camera's
    sequence (a gap: frames the camera gave that were never pushed); ends when a camera ends."""
    seen = [0] * len(threads)
    while True:
        got = []
        for k, th in enumerate(threads):
            item = th.next(seen[k], timeout)
            if item is None:
                return
            got.append(item)
        for _ in range(3):
            stamps = [g[1] for g in got]
            if max(stamps) - min(stamps) <= tolerance_s:
                break
            k = int(np.argmin(stamps))
            item = threads[k].next(got[k][0], timeout)
            if item is None:
                return
            threads[k].give_back()  # the frame replaced was never pushed
            got[k] = item
        seen = [g[0] for g in got]
        yield [g[2] for g in got], [g[1] for g in got], [g[0] for g in got]


@contextlib.contextmanager
def quiet_opencv() -> Iterator[None]:
    """OpenCV's own log silenced for the duration: opening a camera index that is not there makes
    each backend it tries print a line ("[ WARN:0@0.1] global cap_v4l.cpp:914 open VIDEOIO(V4L2:
    /dev/video0): can't open camera by index", "... should be configured with libavdevice ...") and a
    camera that refuses a setting prints another, all of which would drown the one line slipsense
    prints for it. A level the user chose (``OPENCV_LOG_LEVEL``, to debug a camera) is kept."""
    logging = getattr(getattr(cv2, "utils", None), "logging", None)
    if logging is None or os.environ.get("OPENCV_LOG_LEVEL"):
        yield
        return
    level = logging.getLogLevel()
    logging.setLogLevel(logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        logging.setLogLevel(level)


def open_camera(index: int, fps: float, capture_format: str | None, frame_size: tuple[int, int] | None):
    """An OpenCV camera asked for the sensor's format, frame size (height, width) and rate; InputError
    if it cannot be opened (OpenCV's own messages about it silenced: :func:`quiet_opencv`). What the
    camera grants is its business: :meth:`CaptureThread.stats` reports the rate achieved."""
    with quiet_opencv():
        cap = cv2.VideoCapture(index)
        if not cap.isOpened():
            cap.release()
            raise InputError(None, f"camera {index}: cannot be opened")
        if capture_format:
            cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*capture_format))
        if frame_size:
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, frame_size[0])
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, frame_size[1])
        cap.set(cv2.CAP_PROP_FPS, fps)
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # the thread keeps the newest anyway; older ones only go stale
    return cap
