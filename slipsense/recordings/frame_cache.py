"""Decoded frames, kept once per video: labelling, training and replay never decode a video twice.

A 450-frame recording takes tens of milliseconds to decode and its 240 x 320 colour frames are
100 MB, but what the commands read of it is small:

* ``"blocks"``: uint8 ``(T, H/8, W/8, 3)`` 8 x 8 pixel block averages, what the contact signal and
  so the automatic labels and the "gel at rest" masks are computed from
  (:func:`slipsense.recordings.contact.signal_of_blocks`), 1.6 MB;
* ``"contact"``: float32 ``(T,)``, the contact signal itself
  (:func:`slipsense.recordings.contact.contact_signal`), which training and replays read to score
  alarms while no gel is touched;
* ``"gray:HxW"``: uint8 ``(T, h, w)`` grey frames at the size a grasp detector reads
  (:func:`slipsense.recordings.runs.gray_frames`), 0.5 MB at 30 x 40;
* ``"markers:M"`` / ``"markers:RxC"``: float32 ``(T, M, 3)`` the video's tracked markers as a
  marker model reads them, x, y in mm and the depth proxy: the ``M`` nearest the image centre
  (:func:`slipsense.recordings.markers.marker_sequences`) or every marker resampled onto an ``R x C``
  grid (:func:`slipsense.recordings.markers.grid_sequences`); served from
  the marker track cache (:func:`slipsense.recordings.markers.track_recordings`), which real marker
  training windows are cut from too: a replay and those windows see the same numbers.

:func:`video_products` returns the ones asked for; whatever is missing is computed from a single
decode of the video and kept under ``<cache root>/frames/`` as a verified ``.npy`` entry
(:mod:`slipsense.cache`: keyed by the product and the video's resolved path, size and mtime; read
back memory-mapped).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Sequence

import numpy as np

from .. import paths
from ..cache import Entry
from ..errors import InputError
from ..parallel import run_jobs
from .markers import marker_clouds, track_recordings
from .contact import signal_of_blocks, video_blocks
from .frames import source_stat
from .video import gray_frames

#: Bump when what a product holds could change (the block or grey conversion).
FRAMES_VERSION = "frames-1"

_GRAY = re.compile(r"^gray:(\d+)x(\d+)$")
_MARKERS = re.compile(r"^markers:([1-9]\d*)(?:x([1-9]\d*))?$")


def _entry(path: Path, product: str) -> Entry:
    size, mtime = source_stat(path)
    inputs = [FRAMES_VERSION, product, {"path": str(path.resolve()), "bytes": size, "mtime_ns": mtime}]
    return Entry(paths.cache_root() / "frames", inputs, "frame cache", suffix=".npy")


def _compute(video: np.ndarray, product: str, made: dict) -> np.ndarray:
    """``product`` of a decoded video; ``made`` keeps what one decode's products share (the blocks
    the contact signal is made of: computed once, a third of labelling's resizing)."""
    if product in ("blocks", "contact"):
        if "blocks" not in made:
            made["blocks"] = video_blocks(video)
        blocks = made["blocks"]
        if product == "blocks":
            return blocks
        # one frame has no contact signal (it needs the gel at rest to compare with): none is read
        return signal_of_blocks(blocks).astype(np.float32) if len(blocks) > 1 else np.zeros(len(blocks), np.float32)

    h, w = (int(v) for v in _GRAY.match(product).groups())
    return gray_frames(video, (h, w))


def video_products(path: str | Path, products: Sequence[str], min_frames: int = 2) -> dict[str, np.ndarray]:
    """``{product: array}`` of one video (see the module notes), decoding it at most once for the
    frame products (tracked markers come from the marker track cache, which decodes on its own).

    Raises :class:`~slipsense.errors.InputError` naming ``path`` when it must be decoded and cannot
    be (:func:`slipsense.recordings.video.read_video`), or has fewer than ``min_frames`` frames.
    """
    from .video import read_video  # looked up per call: tests/test_frame_cache.py counts decodes through it

    path = Path(path)
    if not products:
        return {}
    for p in products:
        if p not in ("blocks", "contact") and not _GRAY.match(p) and not _MARKERS.match(p):
            raise ValueError(f"unknown frame product {p!r} (blocks, contact, gray:HxW, markers:M or markers:RxC)")
    try:
        entries = {p: _entry(path, p) for p in products if not _MARKERS.match(p)}
    except OSError as exc:
        read_video(path, expected_size=None, min_frames=min_frames)  # raises its own one-line error
        raise InputError(path, f"cannot read ({exc.strerror or exc})") from None
    out: dict[str, np.ndarray] = {}
    for p in products:
        if _MARKERS.match(p):
            track = track_recordings([path], progress=False)[0]  # decodes the video itself when not cached
            out[p] = marker_clouds(track, p.split(":", 1)[1])
            continue
        arr = entries[p].load(lambda f: np.load(f, mmap_mode="r", allow_pickle=False))
        if arr is not None:
            out[p] = arr
    missing = [p for p in products if p not in out]
    if missing:
        video = read_video(path, expected_size=None, min_frames=min_frames)
        made: dict = {}
        for p in missing:
            out[p] = arr = np.ascontiguousarray(_compute(video, p, made))
            entries[p].save(lambda tmp: np.save(tmp, arr, allow_pickle=False))
    if len(next(iter(out.values()))) < min_frames:
        raise InputError(path, f"only {len(next(iter(out.values())))} frame(s), need at least {min_frames}")
    return out


def _is_cached(path: Path, products: Sequence[str]) -> bool:
    try:
        return all(_entry(path, p).check.exists() for p in products)
    except OSError:
        return False


def _prefetch_one(products: Sequence[str], path: Path, tick) -> str | None:
    try:
        video_products(path, products)
    except (InputError, ValueError) as exc:  # the caller's own pass reports it, with its on_error rules
        return str(exc)
    finally:
        tick(1)
    return None


def prefetch(
    paths: Sequence[str | Path], products: Sequence[str], workers: int | None = None, progress: bool = True
) -> int:
    """Decode the videos among ``paths`` whose ``products`` are not cached yet, on ``workers``
    processes (default one per core; :mod:`slipsense.parallel`), so that what reads them next finds
    them cached. Videos that cannot be decoded are left for that reader to report. Returns how many
    were decoded."""
    missing = [Path(p) for p in paths if not _is_cached(Path(p), products)]
    if len(missing) >= 4:  # fewer: starting workers costs more than decoding here
        run_jobs(_prefetch_one, missing, list(products), workers, progress=progress, desc="decoding videos")
    return len(missing)
