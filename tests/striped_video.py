"""Synthetic XVID videos whose frames say their own index, for decoding and clip tests.

Each frame carries its index as 8 vertical stripes (bright = bit set): robust to XVID's losses, so
a test can check which source frame ended up where after decoding, windowing and caching.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

BITS = 8


def frame_for(i: int, size: tuple[int, int] = (240, 320)) -> np.ndarray:
    """(H, W, 3) uint8 frame showing index ``i`` (0..255) as 8 stripes."""
    h, w = size
    f = np.full((h, w, 3), 60, np.uint8)
    for b in range(BITS):
        if (i >> b) & 1:
            f[:, b * w // BITS : (b + 1) * w // BITS] = 220
    return f


def index_of(frame: np.ndarray) -> int:
    """The index a (decoded, possibly resized) frame from :func:`frame_for` shows."""
    h, w = frame.shape[:2]
    return sum(int(frame[h // 2, b * w // BITS + w // (2 * BITS)].mean() > 140) << b for b in range(BITS))


def write_video(path: Path, n: int, size: tuple[int, int] = (240, 320), fps: float = 25.0) -> Path:
    """Write frames 0..n-1 of :func:`frame_for` as an XVID AVI at ``path`` (folders created)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    h, w = size
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"XVID"), fps, (w, h))
    assert vw.isOpened(), f"OpenCV cannot write XVID to {path}"
    for i in range(n):
        vw.write(frame_for(i, size))
    vw.release()
    return path
