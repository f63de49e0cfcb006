"""A source's frames on the model's clock.

A detector is trained at its sensor's rate (the GelSight Mini recordings: 25 frames/s), and its
temporal features (frame differences over lags, windows, debounce) count frames of that rate. A
camera that delivers 15 frames/s, drops frames or jitters would otherwise be read as if its frames
were 40 ms apart. So the detector runs on its own clock: ticks ``1 / fps`` apart from the first
frame's stamp, and each tick gets the source frame taken at that moment, blended linearly from the
two frames around it where none was taken exactly then. At the model's own rate with regular stamps
every tick falls on a frame, and the frames pass through untouched.

    >>> clock = ModelClock(25.0)
    >>> [len(clock.ticks(t, [frame])) for t in (0.0, 0.08, 0.12)]   # doctest: +SKIP
    [1, 2, 1]
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from slipsense.errors import InputError
from slipsense.sensors.spec import MAX_FPS, MIN_FPS, check_fps  # the one range of frame rates

#: A pause longer than this (seconds) is not filled with blended frames: the clock restarts after it.
MAX_GAP_S = 0.5
#: Stamps closer than this (seconds) are the same moment (float rounding of ``k / fps``).
SAME_MOMENT_S = 1e-6


def blend(a: np.ndarray, b: np.ndarray, w: float) -> np.ndarray:
    """``(1 - w) a + w b`` in ``a``'s dtype (uint8 pictures rounded; marker clouds as floats)."""
    mixed = (1.0 - w) * a.astype(np.float32) + w * b.astype(np.float32)
    if np.issubdtype(a.dtype, np.integer):
        return np.clip(np.rint(mixed), 0, np.iinfo(a.dtype).max).astype(a.dtype)
    return mixed.astype(a.dtype)


class ModelClock:
    """The ticks of a model's clock between a source's frames (one list of frames per sensor a tick).

    Args:
        fps: the model's rate (its checkpoint's sensor).
        name: the source, for errors (stamps that go backwards).
    """

    def __init__(self, fps: float, name: str | None = None):
        self.fps, self.name = check_fps(fps, "the model's frame rate"), name
        self.reset()

    def reset(self) -> None:
        self._last: tuple[float, Sequence[np.ndarray]] | None = None
        self._next = 0.0  # stamp of the next tick
        self.gaps = 0  # pauses longer than MAX_GAP_S, where the clock restarted

    def ticks(self, stamp: float, frames: Sequence[np.ndarray]) -> list[list[np.ndarray]]:
        """The frames to push at each tick due by ``stamp`` (s, the source's clock), oldest first: none
        when the source is faster than the model and no tick fell since its last frame."""
        stamp = float(stamp)
        if not math.isfinite(stamp):
            raise InputError(self.name, f"frame stamp {stamp!r} is not a time")
        if self._last is None or stamp - self._last[0] > MAX_GAP_S:
            if self._last is not None:
                self.gaps += 1
            self._last, self._next = (stamp, frames), stamp + 1.0 / self.fps
            return [list(frames)]
        before, previous = self._last
        if stamp < before - SAME_MOMENT_S:
            raise InputError(self.name, f"frame stamps go backwards: {stamp:.6f} s after {before:.6f} s")
        due = []
        while self._next <= stamp + SAME_MOMENT_S:
            t = self._next
            if abs(t - stamp) <= SAME_MOMENT_S:
                due.append(list(frames))
            else:
                w = (t - before) / (stamp - before)
                due.append([blend(a, b, w) for a, b in zip(previous, frames)])
            self._next = t + 1.0 / self.fps
        self._last = (stamp, frames)
        return due


def slower_camera_frames(n: int, fraction: float) -> np.ndarray:
    """``(K,)`` indices of the frames of an ``n``-frame recording that a camera at ``fraction`` of its
    rate takes over the same span: the recorded frame at or just before each of its moments (its
    frame ``k`` is the moment ``k / (fraction * rate)``)."""
    k = np.arange(int(np.floor((n - 1) * fraction)) + 1)
    return np.floor(k / fraction + 1e-9).astype(np.int64)


def resample(streams: Sequence[np.ndarray], stamps: np.ndarray, fps: float) -> tuple[list[np.ndarray], np.ndarray]:
    """Whole recordings on the model's clock: what :class:`ModelClock` gives frame by frame.

    Args:
        streams: one per sensor, ``(N, ...)`` frames taken at ``stamps``.
        stamps: ``(N,)`` seconds, not decreasing.
        fps: the model's rate.

    Returns:
        ``(ticks, last_tick)``: the streams at the model's ticks, ``(K, ...)`` each, and ``(N,)`` the
        index of the latest tick at or before each source frame (what a reading of that frame shows).
    """
    clock = ModelClock(fps)
    out: list[list[np.ndarray]] = [[] for _ in streams]
    last_tick = np.empty(len(stamps), dtype=np.int64)
    for i, t in enumerate(stamps):
        for frames in clock.ticks(t, [s[i] for s in streams]):
            for k, f in enumerate(frames):
                out[k].append(f)
        last_tick[i] = len(out[0]) - 1
    return [np.stack(o) for o in out], last_tick


__all__ = ["MAX_FPS", "MIN_FPS", "ModelClock", "blend", "check_fps", "resample", "slower_camera_frames"]
