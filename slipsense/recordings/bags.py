"""ROS 2 bags in: image topics, one per finger, paired by header time; and a bag as a recording.

A bag is a rosbag2 folder (``metadata.yaml`` beside ``.db3`` or ``.mcap`` files) or one ``.db3`` /
``.mcap`` file; it is read with the pure-Python ``rosbags`` package, so no ROS installation is
needed. Each named topic holds ``sensor_msgs/msg/Image`` (``bgr8``, ``rgb8``, ``mono8``, ``bgra8``,
``rgba8``) or ``sensor_msgs/msg/CompressedImage`` (JPEG, PNG: whatever OpenCV decodes) messages of one
sensor. Frames of two or more topics are paired by their header stamps: each frame of the first topic
takes the nearest frame of every other topic within ``tolerance`` (half a frame period of the sensor
by default), partners in order; frames left without a partner are dropped, counted and warned about
(:class:`UnpairedFramesWarning`). Dropped frames before the first pair or after the last change
nothing else; a gap inside the stream (paired frames more than 1.5 frame periods apart) is refused,
as a model's lags would span other times than it was trained on.

:func:`write_recording` turns a bag into the recordings layout (``camera_*.avi`` in a lossless codec,
``slip.txt`` when a label says the object slipped), so every command that takes recordings takes
converted bags; and a recordings folder may hold bags in place of experiment folders
(``<object>/exp_num_<N>/`` a bag folder, with ``slip.txt`` in it when the object slipped): every image
topic of the bag is a sensor, in topic order, converted once into the cache (:func:`bag_cameras`).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Sequence

import cv2
import numpy as np

from slipsense.atomic import atomic_path, write_text
from slipsense.cache import Entry
from slipsense.paths import cache_root
from slipsense.errors import ConfigError, InputError
from slipsense.sensors.spec import check_fps

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
#: channels of the raw encodings read, and how to turn them into BGR
ENCODINGS = {"bgr8": 3, "rgb8": 3, "mono8": 1, "8UC1": 1, "8UC3": 3, "bgra8": 4, "rgba8": 4}
#: paired frames further apart than this many frame periods: a frame is missing inside the stream
MAX_GAP_PERIODS = 1.5


class UnpairedFramesWarning(UserWarning):
    """Frames of a bag's topic found no partner on the other topics and were left out (at the start
    or end of the bag: inside it they are refused)."""


def check_timing(fps: float, tolerance_s: float | None = None) -> None:
    """ConfigError unless ``fps`` is a frame rate (:func:`~slipsense.sensors.spec.check_fps`) and
    ``tolerance_s`` (if given) finite and >= 0."""
    check_fps(fps, "--fps")
    t = tolerance_s
    if t is not None and (isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or t < 0):
        raise ConfigError(f"--tolerance must be a number of seconds >= 0, got {tolerance_s!r}")


def is_bag(path: str | Path) -> bool:
    """A rosbag2 folder (with ``metadata.yaml``) or a ``.db3`` / ``.mcap`` file."""
    p = Path(path)
    return (p.is_dir() and (p / "metadata.yaml").is_file()) or (p.is_file() and p.suffix in (".db3", ".mcap"))


@dataclass
class BagFrames:
    """Paired frames of a bag's image topics.

    ``frames``: per step, one BGR uint8 ``(H, W, 3)`` image per topic; ``stamps``: ``(N, S)`` int64
    header stamps in ns; ``dropped``: per topic, frames left without a partner."""

    path: Path
    topics: list[str]
    frames: list[list[np.ndarray]]
    stamps: np.ndarray
    dropped: dict[str, int] = field(default_factory=dict)

    @property
    def fps(self) -> float:
        """Frames per second from the first topic's stamps (NaN below two frames)."""
        t = self.stamps[:, 0]
        return float((len(t) - 1) / ((t[-1] - t[0]) * 1e-9)) if len(t) > 1 and t[-1] > t[0] else float("nan")


def open_reader(path: Path):
    # here, not at the top: rosbags takes ~0.3 s to import and only bags need it
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    return AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))


def bag_error(path: Path, exc: BaseException) -> InputError:
    text = " ".join(str(exc).split())[:200]
    return InputError(path, f"not a readable ROS 2 bag ({type(exc).__name__}: {text})")


def image_topics(path: str | Path) -> dict[str, str]:
    """``{topic: message type}`` of every topic of the bag (InputError naming ``path`` if unreadable)."""
    path = Path(path)
    if not path.exists():
        raise InputError(path, "bag not found")
    try:
        with open_reader(path) as reader:
            return {c.topic: c.msgtype for c in reader.connections}
    except InputError:
        raise
    except Exception as exc:  # rosbags raises its own errors, sqlite's and yaml's for damaged bags
        raise bag_error(path, exc) from None


def decode_image(msg, msgtype: str, where: str) -> np.ndarray:
    """A ``sensor_msgs`` Image or CompressedImage -> BGR uint8 ``(H, W, 3)``; InputError naming ``where``."""
    if msgtype == COMPRESSED:
        img = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_COLOR)
        if img is None:
            raise InputError(where, f"a CompressedImage ({msg.format!r}) that OpenCV cannot decode")
        return img
    channels = ENCODINGS.get(msg.encoding)
    if channels is None:
        raise InputError(where, f"image encoding {msg.encoding!r} is not read (read: {', '.join(ENCODINGS)})")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    raw = msg.data
    data = (
        np.frombuffer(raw, np.uint8) if isinstance(raw, (bytes, bytearray, memoryview)) else np.asarray(raw, np.uint8)
    )
    if h * w == 0 or step < w * channels or data.size < h * step:
        raise InputError(where, f"image of {h}x{w} {msg.encoding} holds {data.size} bytes (step {step})")
    img = data[: h * step].reshape(h, step)[:, : w * channels].reshape(h, w, channels)
    if channels == 1:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if msg.encoding.startswith("rgb"):
        return cv2.cvtColor(img, cv2.COLOR_RGBA2BGR if channels == 4 else cv2.COLOR_RGB2BGR)
    return np.ascontiguousarray(img[:, :, :3])


def _messages(path: Path, topics: Sequence[str]) -> Iterator[tuple[str, int, np.ndarray]]:
    """``(topic, header stamp ns, BGR image)`` of every message on ``topics``, in bag order."""
    try:
        with open_reader(path) as reader:
            kinds = {c.topic: c.msgtype for c in reader.connections}
            for t in topics:
                if t not in kinds:
                    found = sorted(k for k, v in kinds.items() if v in (IMAGE, COMPRESSED))
                    raise InputError(path, f"no topic {t}; image topics in the bag: {', '.join(found) or 'none'}")
                if kinds[t] not in (IMAGE, COMPRESSED):
                    raise InputError(path, f"topic {t} holds {kinds[t]}, not {IMAGE} or {COMPRESSED}")
            conns = [c for c in reader.connections if c.topic in topics]
            for conn, _, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
                yield conn.topic, stamp, decode_image(msg, conn.msgtype, f"{path} ({conn.topic})")
    except InputError:
        raise
    except Exception as exc:
        raise bag_error(path, exc) from None


def pair_by_time(stamps: Sequence[np.ndarray], tolerance_ns: int) -> np.ndarray:
    """``(K, S)`` indices of frames paired across ``S`` sorted stamp arrays: each frame of the first
    takes the nearest frame of every other within ``tolerance_ns``, partners strictly in order."""
    ref = np.asarray(stamps[0], dtype=np.int64)
    keep = np.ones(len(ref), bool)
    cols = [np.arange(len(ref))]
    for other in stamps[1:]:
        other = np.asarray(other, dtype=np.int64)
        if len(other) == 0:
            return np.zeros((0, len(stamps)), np.int64)
        right = np.clip(np.searchsorted(other, ref), 0, len(other) - 1)
        left = np.clip(right - 1, 0, len(other) - 1)
        best = np.where(np.abs(other[left] - ref) <= np.abs(other[right] - ref), left, right)
        keep &= np.abs(other[best] - ref) <= tolerance_ns
        cols.append(best)
    idx = np.stack(cols, 1)[keep]
    if len(idx) > 1:  # a partner used twice keeps its first frame only
        fresh = np.ones(len(idx), bool)
        fresh[1:] = (np.diff(idx[:, 1:], axis=0) > 0).all(axis=1)
        idx = idx[fresh]
    return idx


def read_bag(path: str | Path, topics: Sequence[str], fps: float = 25.0, tolerance_s: float | None = None) -> BagFrames:
    """The frames of ``topics`` (one per sensor, in that order), paired by header stamp.

    ``tolerance_s``: the largest stamp difference of a pair (default half a frame period at ``fps``).
    InputError naming the bag for a missing bag or topic, a topic of another message type, an image
    that cannot be decoded, frames of different sizes on one topic, a damaged or truncated bag,
    topics whose stamps do not pair (fewer than half of the frames of the shorter topic), a topic whose
    header stamps go backwards in the order it was recorded, or paired
    frames more than 1.5 frame periods apart (a frame missing inside the stream). Frames left without
    a partner at the start or end are counted in ``dropped`` and warned about
    (:class:`UnpairedFramesWarning`, one per topic)."""
    check_timing(fps, tolerance_s)
    path = Path(path)
    topics = list(topics)
    if not topics:
        raise InputError(path, "name the image topics to read (--topic, one per sensor)")
    if len(set(topics)) != len(topics):
        raise InputError(path, f"a topic is named twice: {topics}")
    if not path.exists():
        raise InputError(path, "bag not found")
    per: dict[str, list[tuple[int, np.ndarray]]] = {t: [] for t in topics}
    for topic, stamp, img in _messages(path, topics):
        if per[topic] and img.shape != per[topic][0][1].shape:
            raise InputError(path, f"topic {topic}: frames of {per[topic][0][1].shape} and {img.shape}")
        per[topic].append((stamp, img))
    for t in topics:
        if not per[t]:
            raise InputError(path, f"topic {t} holds no messages")
        back = next((k for k in range(1, len(per[t])) if per[t][k][0] < per[t][k - 1][0]), None)
        if back is not None:  # a camera's clock that runs backwards: no order of its frames can be trusted
            a, b = per[t][back][0] * 1e-9, per[t][back - 1][0] * 1e-9
            raise InputError(
                path, f"topic {t}: header stamps go backwards at message {back} ({a:.6f} s after {b:.6f} s)"
            )
    stamps = [np.array([s for s, _ in per[t]], np.int64) for t in topics]
    tol = int(round((tolerance_s if tolerance_s is not None else 0.5 / fps) * 1e9))
    idx = pair_by_time(stamps, tol)
    shortest = min(len(s) for s in stamps)
    if len(idx) < max(1, shortest / 2):
        raise InputError(
            path,
            f"the stamps of {' and '.join(topics)} do not pair: {len(idx)} of {shortest} frames within "
            f"{tol / 1e6:g} ms (--tolerance sets it)",
        )
    paired = np.stack([stamps[k][idx[:, k]] for k in range(len(topics))], 1)
    dropped = {t: len(stamps[k]) - len(idx) for k, t in enumerate(topics)}
    within = f"found no partner within {tol / 1e6:g} ms"
    unpaired = [f"{n} of {len(stamps[k])} frames of {t} {within}" for k, (t, n) in enumerate(dropped.items()) if n]
    _check_spacing(path, paired, fps, unpaired)
    for line in unpaired:
        warnings.warn(f"{path}: {line}; left out", UnpairedFramesWarning, stacklevel=2)
    frames = [[per[t][i][1] for t, i in zip(topics, row)] for row in idx]
    return BagFrames(path, topics, frames, paired, dropped)


def _check_spacing(path: Path, paired: np.ndarray, fps: float, unpaired: Sequence[str]) -> None:
    """InputError naming the bag when paired frames (``(N, S)`` stamps in ns) lie more than
    :data:`MAX_GAP_PERIODS` frame periods apart on any topic: a frame is missing inside the stream
    (no partner there, or never recorded), so the steps a model sees would span other times."""
    if len(paired) < 2:
        return
    period_ns = 1e9 / fps
    gaps = np.diff(paired, axis=0).max(axis=1)
    wide = np.flatnonzero(gaps > MAX_GAP_PERIODS * period_ns)
    if len(wide) == 0:
        return
    i = int(wide[0])
    why = "; ".join(unpaired) if unpaired else "a frame was not recorded"
    raise InputError(
        path,
        f"frames missing inside the stream ({why}): {len(wide)} gap(s) over {MAX_GAP_PERIODS:g} frame periods "
        f"at {fps:g} frames/s, the first {gaps[i] / 1e6:.0f} ms between paired frames {i} and {i + 1} "
        f"({(paired[i, 0] - paired[0, 0]) / 1e9:.2f} s in), so a model's lags would span other times "
        "(--tolerance sets the pairing)",
    )


def write_recording(bag: BagFrames, folder: str | Path, camera_names: Sequence[str], slipped: bool, fps: float) -> Path:
    """Write ``bag`` as one experiment of the recordings layout: ``folder/<camera name>.avi`` per
    topic (FFV1, lossless: decoding gives the bag's frames back exactly) and an empty ``slip.txt``
    when ``slipped``. Files are written beside and renamed into place."""
    check_timing(fps)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if len(camera_names) < len(bag.topics):
        raise InputError(folder, f"{len(bag.topics)} topics but the sensor names {len(camera_names)} cameras")
    written = {f"{n}.avi" for n in camera_names[: len(bag.topics)]}
    for stale in folder.glob("camera_*.avi"):  # another conversion's sensors must not join this one's
        if stale.name not in written:
            stale.unlink()
    for k, name in enumerate(camera_names[: len(bag.topics)]):
        h, w = bag.frames[0][k].shape[:2]
        with atomic_path(folder / f"{name}.avi") as tmp:  # ends in .avi: OpenCV picks the container by it
            writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"FFV1"), float(fps), (w, h))
            if not writer.isOpened():
                raise InputError(folder, "OpenCV cannot write FFV1 video here")
            for step in bag.frames:
                writer.write(step[k])
            writer.release()
    marker = folder / "slip.txt"
    if slipped:
        write_text(marker, "")
    elif marker.exists():
        marker.unlink()
    return folder


def bag_cameras(bag: Path, fps: float) -> list[Path]:
    """The camera videos of a bag used as an experiment folder: every image topic, in topic order,
    paired by time and written once into the cache as ``camera_<k>.avi`` (a verified folder entry
    under ``$SLIPSENSE_CACHE/bags`` keyed by the bag's files, sizes and times: :mod:`slipsense.cache`)."""
    topics = sorted(t for t, kind in image_topics(bag).items() if kind in (IMAGE, COMPRESSED))
    if not topics:
        raise InputError(bag, "bag holds no sensor_msgs Image or CompressedImage topic")
    files = sorted(p for p in Path(bag).iterdir() if p.is_file()) if Path(bag).is_dir() else [Path(bag)]
    ident = [str(Path(bag).resolve()), fps, topics] + [[p.name, p.stat().st_size, p.stat().st_mtime_ns] for p in files]
    names = [f"camera_{k}" for k in range(len(topics))]
    entry = Entry(cache_root() / "bags", ident, "bag cache", names=[f"{n}.avi" for n in names])
    if entry.load(lambda *paths: paths) is None:
        entry.save(lambda to: write_recording(read_bag(bag, topics, fps=fps), to, names, slipped=False, fps=fps))
    return entry.files
