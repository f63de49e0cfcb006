"""A folder of image files as one sensor's recording: the frames of a grasp, in the order of the
numbers in their names.

Some sensors' software stores frames, not videos (the GelSight data of Li et al. 2018:
``gelsight_imgw066_60_s09_00007675.jpg``, ...). Every reader of recordings takes such a folder where
it takes a video file: :func:`slipsense.recordings.video.read_video` and ``probe_video`` hand it
here, so labelling, the frame cache, training and replays need nothing else.

A frame folder must be whole: frames of one size, each decodable, numbered without gaps (the last
number in a file name is the frame's number; a gap means frames were lost, and a detector that
counts frames would read the time wrong). Anything else is an
:class:`~slipsense.errors.InputError` naming the file.
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError
from .listing import FolderTree, link_problem

#: Image files read as frames (case-insensitive).
FRAME_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp")

_LAST_NUMBER = re.compile(r"(\d+)(?!.*\d)")


def frame_files(folder: str | Path, tree: FolderTree | None = None) -> list[Path]:
    """The image files of ``folder`` in frame order (by the last number in each name, then by name);
    hidden files are not frames. Empty when the folder holds none. ``tree``: where the folder was
    listed already (:class:`~slipsense.recordings.listing.FolderTree`)."""
    folder = Path(folder)
    try:
        listed = (tree or FolderTree()).files(folder)
        files = [p for p in listed if p.suffix.lower() in FRAME_SUFFIXES and not p.name.startswith(".")]
    except PermissionError:
        raise InputError(folder, "frame folder is not readable (permission denied)") from None

    def order(p: Path):
        m = _LAST_NUMBER.search(p.stem)
        return (int(m.group(1)) if m else -1, p.name)

    return sorted(files, key=order)


def is_frame_folder(path: str | Path) -> bool:
    path = Path(path)
    try:
        return path.is_dir() and bool(frame_files(path))
    except PermissionError:  # cannot be looked into: the video checks word it as a file's problem
        return False


def source_stat(path: str | Path) -> tuple[int, int]:
    """``(bytes, mtime_ns)`` that change when a recording changes: a video file's own; for a frame
    folder the sum of its frames' sizes and, in place of a time, a digest of every frame's name, size
    and modification time (an edited, added, removed or restored frame changes it). What the caches
    key a recording by."""
    path = Path(path)
    st = path.stat()
    if not path.is_dir():
        return int(st.st_size), int(st.st_mtime_ns)
    files = frame_files(path)
    stats = [p.stat() for p in files]
    listing = [[p.name, int(s.st_size), int(s.st_mtime_ns)] for p, s in zip(files, stats)]
    digest = hashlib.sha256(repr(listing).encode()).hexdigest()
    # a folder has no one modification time: a digest of every frame's name, size and time stands in
    return sum(int(s.st_size) for s in stats), int(digest[:15], 16)


def _checked_files(folder: Path, min_frames: int) -> list[Path]:
    tree = FolderTree()
    files = frame_files(folder, tree)
    broken = tree.broken(folder)  # from the one listing: a frame that is a link to nothing, or one that loops
    for p in files:
        if p.name in broken:
            raise InputError(p, link_problem(p) or broken[p.name])
    if not files:
        raise InputError(folder, f"frame folder holds no image files ({', '.join(FRAME_SUFFIXES)})")
    numbers = [_LAST_NUMBER.search(p.stem) for p in files]
    unnumbered = [p for p, m in zip(files, numbers) if m is None]
    if unnumbered and len(unnumbered) < len(files):
        raise InputError(unnumbered[0], "image without a frame number among numbered frames (move it out)")
    if all(numbers):
        values = [int(m.group(1)) for m in numbers]
        for a, b, pa, pb in zip(values, values[1:], files, files[1:]):
            if b == a:
                raise InputError(pb, f"frame number {b} also found as {pa.name}")
            if b != a + 1:
                missing = f"frame {a + 1}" if b == a + 2 else f"frames {a + 1} to {b - 1}"
                raise InputError(folder, f"{missing} missing: the numbering jumps from {pa.name} to {pb.name}")
    if len(files) < min_frames:
        raise InputError(folder, f"only {len(files)} frame{'s' if len(files) != 1 else ''}, need at least {min_frames}")
    return files


def _read_image(path: Path) -> np.ndarray:
    try:
        frame = cv2.imread(str(path), cv2.IMREAD_COLOR)
    except cv2.error:
        frame = None
    if frame is None:
        raise InputError(path, "frame cannot be decoded as an image")
    return frame


def _frame_like(path: Path, first: np.ndarray, first_name: str) -> np.ndarray:
    """The frame at ``path``; InputError unless it is the size of ``first``, the frame ``first_name``."""
    frame = _read_image(path)
    if frame.shape[:2] != first.shape[:2]:
        raise InputError(
            path,
            f"frames of mixed sizes: {first_name} is {first.shape[1]}x{first.shape[0]}, this one "
            f"{frame.shape[1]}x{frame.shape[0]} (width x height)",
        )
    return frame


def check_size(path: Path, height: int, width: int, expected_size: tuple[int, int] | None) -> None:
    """InputError naming ``path`` unless its frames are ``expected_size`` ``(h, w)`` (None: any size)."""
    if expected_size is not None and (height, width) != tuple(expected_size):
        eh, ew = expected_size
        raise InputError(path, f"frames are {width}x{height} pixels (width x height), expected {ew}x{eh}")


def _first_frame(path: Path, expected_size: tuple[int, int] | None) -> np.ndarray:
    frame = _read_image(path)
    check_size(path, *frame.shape[:2], expected_size)
    return frame


def read_frames(folder: str | Path, expected_size: tuple[int, int] | None = None, min_frames: int = 2) -> np.ndarray:
    """Every frame of a frame folder -> uint8 BGR ``(T, H, W, 3)``; InputError naming the file for a
    missing, undecodable or differently sized frame, or a wrong ``expected_size`` ``(h, w)``."""
    files = _checked_files(Path(folder), min_frames)
    first = _first_frame(files[0], expected_size)
    out = np.empty((len(files),) + first.shape, np.uint8)
    out[0] = first
    for i, p in enumerate(files[1:], 1):
        out[i] = _frame_like(p, first, files[0].name)
    return out


def probe_frames(folder: str | Path, expected_size: tuple[int, int] | None = None, min_frames: int = 2):
    """The cheap check of a frame folder (the numbering, the first and last frames decode at one
    size) -> ``(n_frames, height, width)``."""
    files = _checked_files(Path(folder), min_frames)
    first = _first_frame(files[0], expected_size)
    _frame_like(files[-1], first, files[0].name)
    return len(files), int(first.shape[0]), int(first.shape[1])
