"""Cut labelled videos into short clips for training: slip onsets (y=1) and wiggles (y=0).

Windows, in frame indices of the decoded video (0-based, ``end`` inclusive):

* Slip clip, one per video of a run that slipped: the ``frames`` frames just before
  ``moment_of_slip - horizon``, i.e. ``start = m - horizon - frames``, ``end = m - horizon - 1``.
  With ``horizon = 0`` the clip ends on the frame before the moment of slip (which is excluded);
  a larger horizon asks the model to see the slip coming ``horizon`` frames (``horizon / 25`` s)
  earlier. The window must start at or after the label's ``contact_start``: a window reaching
  back into the no-contact phase or the camera's start-up transient shows no grasp, so such
  videos are skipped with a warning.
* Wiggle clips, from each video of a run that did not slip: ``wiggle_per_video`` windows drawn
  uniformly at random among all placements of non-overlapping ``frames``-long windows inside
  ``[contact_start, contact_end]``. The draw for a video depends only on ``ClipSpec.seed`` and the
  video's key, so adding or removing other videos does not move its windows.
"""

from __future__ import annotations

import json
import warnings
import zlib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
from tqdm.auto import tqdm

from .. import paths
from ..cache import Entry, key
from ..errors import ConfigError, InputError
from .folders import SkippedInputWarning
from .frames import source_stat
from .splits import ObjectFolds, ObjectHoldOut
from .types import Recording, VideoLabel
from .video import read_video, resize

MIN_CLIP_FRAMES = 2
MAX_CLIP_FRAMES = 12
#: Bumped whenever the cache file layout or the window rules change, so old entries are not reused.
CACHE_VERSION = 2

Key = tuple[str, int, str]


def _is_int(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


@dataclass(frozen=True)
class ClipSpec:
    """How clips are cut.

    Attributes:
        frames: frames per clip, 2..12 (5 = 0.2 s at 25 frames/s).
        horizon: frames between a slip clip's last frame and the frame before the moment of slip,
            >= 0 (0: the clip ends right before the moment of slip).
        wiggle_per_video: wiggle windows drawn from each video of a run that did not slip, >= 0.
        size: output frame size ``(height, width)`` in pixels; frames of another size are resized
            (``cv2.INTER_AREA``, the right filter for shrinking, e.g. to (120, 160)). None: not stated
            (windows are planned, but no clip is cut: the size comes from the data's sensor or the user).
        seed: seed of the wiggle-window draw.
    """

    frames: int = 5
    horizon: int = 0
    wiggle_per_video: int = 2
    size: tuple[int, int] | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        if not _is_int(self.frames) or not MIN_CLIP_FRAMES <= self.frames <= MAX_CLIP_FRAMES:
            raise ConfigError(
                f"clip frames must be an integer in {MIN_CLIP_FRAMES}..{MAX_CLIP_FRAMES}, got {self.frames!r}"
            )
        if not _is_int(self.horizon) or self.horizon < 0:
            raise ConfigError(f"clip horizon must be an integer >= 0, got {self.horizon!r}")
        if not _is_int(self.wiggle_per_video) or self.wiggle_per_video < 0:
            raise ConfigError(f"wiggle_per_video must be an integer >= 0, got {self.wiggle_per_video!r}")
        size = self.size
        if size is not None and not (
            isinstance(size, (tuple, list)) and len(size) == 2 and all(_is_int(v) and v > 0 for v in size)
        ):
            raise ConfigError(f"clip size must be (height, width) positive integers, got {size!r}")
        if not _is_int(self.seed):
            raise ConfigError(f"clip seed must be an integer, got {self.seed!r}")
        # Plain ints and a tuple keep the spec hashable and its JSON (cache key) stable.
        for name in ("frames", "horizon", "wiggle_per_video", "seed"):
            object.__setattr__(self, name, int(getattr(self, name)))
        if size is not None:
            object.__setattr__(self, "size", (int(size[0]), int(size[1])))


@dataclass(frozen=True)
class Window:
    """One clip's frames in its video: ``start`` .. ``end`` inclusive; ``y`` 1 = slip onset, 0 = wiggle."""

    start: int
    end: int
    y: int


def wiggle_starts(contact_start: int, contact_end: int, frames: int, count: int, rng: np.random.Generator) -> list[int]:
    """Draw ``count`` non-overlapping ``frames``-long windows inside ``[contact_start, contact_end]``.

    Every placement of the windows is equally likely (stars and bars: choose ``count`` distinct
    slots among ``slack + count``, slack being the frames no window covers).

    Returns:
        The windows' first frame indices, ascending; fewer than ``count`` (as many as fit) when
        the interval is too short.
    """
    length = contact_end - contact_start + 1
    count = min(count, max(length, 0) // frames)
    if count <= 0:
        return []
    slack = length - count * frames
    slots = np.sort(rng.choice(slack + count, size=count, replace=False))
    return [int(contact_start + s + i * (frames - 1)) for i, s in enumerate(slots)]


def check_label(label: VideoLabel, path: Path | str | None = None) -> None:
    """Raise InputError (naming ``path``) when the label's frame indices are inconsistent."""
    n = label.n_frames
    if not _is_int(n) or n < 1:
        raise InputError(path, f"label n_frames must be a positive integer, got {n!r}")
    if not (0 <= label.contact_start <= label.contact_end < n):
        raise InputError(
            path, f"label contact phase {label.contact_start}..{label.contact_end} is not inside 0..{n - 1}"
        )
    m = label.moment_of_slip
    if m is not None:
        if not label.slipped:
            raise InputError(path, f"label has a moment of slip ({m}) but says the run did not slip")
        if not (_is_int(m) and 0 <= m < n):
            raise InputError(path, f"label moment of slip {m!r} is not inside 0..{n - 1}")


def _plan(label: VideoLabel, spec: ClipSpec) -> tuple[list[Window], str | None]:
    """Windows for one video, plus why some or all were left out (None when nothing was)."""
    f = spec.frames
    if label.slipped:
        m = label.moment_of_slip
        if m is None:
            return [], "run slipped but the label has no moment of slip"
        end = m - spec.horizon - 1
        start = end - f + 1
        if start < label.contact_start:
            return [], (
                f"moment of slip {m} is too early for a {f}-frame clip with horizon {spec.horizon} "
                f"(it would start at frame {start}, before contact starts at {label.contact_start})"
            )
        return [Window(start, end, 1)], None
    want, k = spec.wiggle_per_video, label.key
    # crc32 rather than hash(): Python salts str hashes per process, which would break reproducibility.
    rng = np.random.default_rng([spec.seed, zlib.crc32(f"{k[0]}/{k[1]}/{k[2]}".encode())])
    starts = wiggle_starts(label.contact_start, label.contact_end, f, want, rng)
    note = None
    if len(starts) < want:
        note = (
            f"contact phase {label.contact_start}..{label.contact_end} holds only {len(starts)} of the "
            f"{want} requested {f}-frame wiggle windows"
        )
    return [Window(s, s + f - 1, 0) for s in starts], note


def plan_windows(label: VideoLabel, spec: ClipSpec) -> list[Window]:
    """The clip windows :func:`build_clips` cuts from the video ``label`` describes (see module notes)."""
    check_label(label)
    return _plan(label, spec)[0]


@dataclass
class ClipSet:
    """Clips with labels and provenance.

    Attributes:
        x: uint8 ``(N, T, H, W, 3)``, BGR frames.
        y: int64 ``(N,)``, 1 = onset of slip, 0 = wiggle.
        meta: N dicts with ``object`` (str), ``experiment`` (int), ``camera`` (str), ``start`` and
            ``end`` (first and last frame index in the video, inclusive), ``moment_of_slip``
            (int or None) and ``augmented`` (False: the training data augments clips as it reads
            them, :class:`~slipsense.datasets.ClipDataset`).
        spec: the ClipSpec the clips were cut with, when known.
    """

    x: np.ndarray
    y: np.ndarray
    meta: list[dict[str, Any]]
    spec: ClipSpec | None = field(default=None)

    def __post_init__(self) -> None:
        self.x = np.asarray(self.x)
        self.y = np.asarray(self.y, dtype=np.int64)
        if self.x.dtype != np.uint8 or self.x.ndim != 5 or self.x.shape[-1] != 3:
            raise InputError(None, f"clips must be uint8 (N, T, H, W, 3), got {self.x.dtype} {self.x.shape}")
        if self.y.shape != (self.x.shape[0],) or len(self.meta) != self.x.shape[0]:
            raise InputError(
                None, f"clip count mismatch: x has {self.x.shape[0]}, y {self.y.shape}, meta {len(self.meta)}"
            )

    def __len__(self) -> int:
        return int(self.x.shape[0])

    def subset(self, indices: Sequence[int] | np.ndarray) -> "ClipSet":
        """A new ClipSet of the clips at the int positions ``indices``, copied."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        if idx.size and (idx.min() < -len(self) or idx.max() >= len(self)):
            raise InputError(None, f"clip indices out of range for {len(self)} clips")
        return ClipSet(self.x[idx], self.y[idx], [dict(self.meta[i]) for i in idx], self.spec)

    @property
    def objects(self) -> list[str]:
        """Sorted unique object names."""
        return sorted({m["object"] for m in self.meta})

    @property
    def clip_objects(self) -> np.ndarray:
        """Object name of each clip, str array ``(N,)``."""
        return np.array([m["object"] for m in self.meta], dtype=str)

    def counts(self) -> dict[str, int]:
        """``{"clips", "slip", "wiggle", "augmented", "objects"}`` counts."""
        augmented = int(sum(bool(m.get("augmented", False)) for m in self.meta))
        counts = dict(clips=len(self), slip=int((self.y == 1).sum()), wiggle=int((self.y == 0).sum()))
        return {**counts, "augmented": augmented, "objects": len(self.objects)}


def build_clips(
    recordings: Iterable[Recording],
    labels: Mapping[Key, VideoLabel],
    spec: ClipSpec = ClipSpec(),
    progress: bool = True,
) -> ClipSet:
    """Decode each video that yields a clip once and cut its windows.

    Args:
        recordings: the videos, e.g. from :func:`~slipsense.recordings.folders.find_recordings`.
        labels: ``Recording.key -> VideoLabel`` for every recording.
        spec: window rules and output size.
        progress: show a tqdm bar over the videos being decoded.

    Returns:
        ClipSet with x uint8 ``(N, spec.frames, *spec.size, 3)``, clips ordered by
        (object, experiment, camera, start). Reproducible for a given ``spec.seed``.

    Raises:
        InputError: a recording has no label, is listed twice, its label disagrees with the
            folder (slip.txt) or with the decoded frame count, or its video cannot be read.

    Videos left without clips (slip too early, contact phase too short, no moment of slip)
    are reported with a :class:`~slipsense.recordings.folders.SkippedInputWarning`.
    """
    if spec.size is None:
        raise ConfigError(
            "a clip's frame size is not stated: give the clip spec a size (the data's sensor's, or --size)"
        )
    plans = _plans(recordings, labels, spec, warn=True)
    n_clips = sum(len(w) for _, _, w in plans)
    h, w = spec.size
    x = np.empty((n_clips, spec.frames, h, w, 3), dtype=np.uint8)
    y = np.empty(n_clips, dtype=np.int64)
    meta: list[dict[str, Any]] = []
    i = 0
    for rec, label, windows in tqdm(plans, desc="decoding videos", unit="video", disable=not progress):
        # Size is enforced on the output (resize); per-video size checks belong to validate_recordings.
        video = read_video(rec.path, expected_size=None, min_frames=spec.frames)
        if len(video) != label.n_frames:
            raise InputError(
                rec.path, f"label is for {label.n_frames} frames but the video has {len(video)}; relabel it"
            )
        for win in windows:
            x[i] = [resize(frame, spec.size) for frame in video[win.start : win.end + 1]]
            y[i] = win.y
            meta.append(_meta(rec, label, win))
            i += 1
        del video
    return ClipSet(x, y, meta, spec)


def _meta(rec: Recording, label: VideoLabel, win: Window) -> dict[str, Any]:
    m = None if label.moment_of_slip is None else int(label.moment_of_slip)
    meta = dict(object=rec.object, experiment=int(rec.experiment), camera=rec.camera, start=int(win.start))
    return {**meta, "end": int(win.end), "moment_of_slip": m, "augmented": False}


def _plans(
    recordings: Iterable[Recording], labels: Mapping[Key, VideoLabel], spec: ClipSpec, warn: bool
) -> list[tuple[Recording, VideoLabel, list[Window]]]:
    """The videos that give clips, with their label and windows, in clip order (checks labels)."""
    plans: list[tuple[Recording, VideoLabel, list[Window]]] = []
    seen: set[Key] = set()
    for rec in sorted(recordings, key=lambda r: r.key):
        if rec.key in seen:
            raise InputError(rec.path, "recording listed twice")
        seen.add(rec.key)
        label = labels.get(rec.key)
        if label is None:
            raise InputError(rec.path, "no label for this video")
        # A hand label (override) is the user's truth and may contradict slip.txt; an automatic one may not.
        if label.slipped != rec.slipped and label.source != "override":
            raise InputError(
                rec.path,
                f"label says slipped={label.slipped} but slip.txt is {'present' if rec.slipped else 'absent'}",
            )
        check_label(label, rec.path)
        windows, note = _plan(label, spec)
        if note is not None and warn:
            warnings.warn(
                f"{rec.path}: {note}; {'skipped' if not windows else 'using fewer'}", SkippedInputWarning, stacklevel=3
            )
        if windows:
            plans.append((rec, label, windows))
    return plans


def _inputs(recordings: Iterable[Recording], labels: Mapping[Key, VideoLabel], spec: ClipSpec) -> dict[str, Any]:
    """What clips are cut from: cache version, spec, each video's path/size/mtime/slipped and label."""
    videos = []
    for rec in sorted(recordings, key=lambda r: r.key):
        try:
            size, mtime = source_stat(rec.path)
        except OSError:
            raise InputError(rec.path, "video file does not exist") from None
        label = labels.get(rec.key)
        path = str(Path(rec.path).resolve())
        videos.append([list(rec.key), path, size, mtime, rec.slipped, None if label is None else asdict(label)])
    return {"version": CACHE_VERSION, "spec": asdict(spec), "videos": videos}


def cache_key(recordings: Iterable[Recording], labels: Mapping[Key, VideoLabel], spec: ClipSpec) -> str:
    """The key of the clips' cache entry: any edit to a video (size or modification time), its label
    or the spec gives a new one."""
    return key(_inputs(recordings, labels, spec))


def _save_npz(path: Path, clips: ClipSet) -> None:
    # Uncompressed: loading ~500 MB of clips is disk-bound, compression would make it CPU-bound.
    with open(path, "wb") as fh:
        np.savez(fh, x=clips.x, y=clips.y, meta=np.array(json.dumps(clips.meta)))


def _read_entry(npz: Path, recordings, labels, spec: ClipSpec) -> ClipSet:
    """Load a cache entry, raising ValueError on any inconsistency or where it holds other clip windows
    and labels than the inputs give (:func:`_plans`)."""
    plans = _plans(recordings, labels, spec, warn=False)
    want_meta = [_meta(rec, label, win) for rec, label, windows in plans for win in windows]
    want_y = np.array([win.y for _, _, windows in plans for win in windows], np.int64)
    with np.load(npz, allow_pickle=False) as data:
        if set(data.files) != {"x", "y", "meta"}:
            raise ValueError(f"unexpected arrays {sorted(data.files)}")
        x, y, meta = data["x"], data["y"], json.loads(str(data["meta"]))
    if x.dtype != np.uint8 or x.ndim != 5 or x.shape[1:] != (spec.frames, *spec.size, 3):
        raise ValueError(f"clip array {x.dtype} {x.shape} does not match the spec")
    if y.ndim != 1 or len(y) != len(x) or not isinstance(meta, list) or len(meta) != len(x):
        raise ValueError("clip, label and provenance counts differ")
    if meta != want_meta:
        raise ValueError("clip windows differ from those the labels give")
    if not np.array_equal(y, want_y):
        raise ValueError("clip labels differ from those the labels give")
    return ClipSet(x, y, meta, spec)


def load_or_build_clips(
    recordings: Iterable[Recording],
    labels: Mapping[Key, VideoLabel],
    spec: ClipSpec = ClipSpec(),
    cache_dir: str | Path | None = None,
    progress: bool = True,
) -> ClipSet:
    """:func:`build_clips`, cached on disk.

    The cache entry is ``<cache_dir>/clips-<key>.npz`` (uncompressed; ``cache_dir`` defaults to
    ``paths.cache_root() / "clips"``), verified (:mod:`slipsense.cache`) and keyed by
    :func:`cache_key`'s inputs. An entry that fails its checks, holds other windows or labels than
    the labels give, or cannot be loaded is rebuilt with a :class:`CacheWarning`; a failure to write
    the cache only warns, since the clips are in hand.

    Returns:
        As :func:`build_clips`.
    """
    recordings = list(recordings)
    folder = Path(cache_dir) if cache_dir is not None else paths.cache_root() / "clips"
    return Entry(folder, _inputs(recordings, labels, spec), "clip cache", prefix="clips-", suffix=".npz").get(
        lambda npz: _read_entry(npz, recordings, labels, spec),
        lambda: build_clips(recordings, labels, spec, progress=progress),
        _save_npz,
    )


def split_by_clip(clips: ClipSet, test_fraction: float = 0.1, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Random clip-level split (the paper's protocol; objects and runs occur on both sides).

    Each class is split in the same proportion: :class:`~slipsense.recordings.splits.ObjectHoldOut`
    with every clip its own group and the class as the stratum (a class of one clip stays in training).

    Returns:
        ``(train_idx, test_idx)``: sorted int64 index arrays into ``clips``, disjoint, covering all.
    """
    return next(ObjectHoldOut(test_fraction, seed).split(np.arange(len(clips)), clips.y))


def split_by_object(clips: ClipSet, test_objects: Iterable[str]) -> tuple[np.ndarray, np.ndarray]:
    """Leave-objects-out split: clips of ``test_objects`` form the test side.

    Returns:
        ``(train_idx, test_idx)``: sorted int64 index arrays; no object occurs on both sides.

    Raises:
        ConfigError: ``test_objects`` is empty or names an object that has no clips.
    """
    test = set(test_objects)
    if not test:
        raise ConfigError("test_objects is empty")
    unknown = sorted(test - set(clips.objects))
    if unknown:
        raise ConfigError(f"test objects without clips: {', '.join(unknown)}")
    is_test = np.isin(clips.clip_objects, sorted(test))
    return np.flatnonzero(~is_test).astype(np.int64), np.flatnonzero(is_test).astype(np.int64)


def object_folds(objects: Iterable[str], n_folds: int = 5, seed: int = 0) -> list[list[str]]:
    """Object names in ``n_folds`` folds for leave-objects-out cross-validation: the test objects of
    :class:`~slipsense.recordings.splits.ObjectFolds`'s folds, in fold order.

    Deterministic for a given set of names and seed (order and duplicates in ``objects`` do not
    matter); fold sizes differ by at most one.

    Returns:
        ``n_folds`` sorted lists of names; every name is in exactly one.
    """
    return ObjectFolds(n_folds, seed).test_objects(objects)
