"""What ``slipsense watch`` streams: video files, recordings experiment folders, ROS 2 bags, marker
arrays and live cameras, each as a :class:`Source` of timestamped steps.

A step holds, per sensor, the picture to show and the model's input, and the time the frames were
taken (seconds): the bag's header stamps, the capture clock of a live camera, ``index / fps`` for
files that carry no time.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np

from slipsense.errors import InputError
from slipsense.recordings.bags import check_timing, is_bag, read_bag
from slipsense.recordings.folders import CAMERA_GLOB
from slipsense.recordings.frames import is_frame_folder
from slipsense.recordings.video import read_video
from slipsense.streaming.capture import CaptureThread, open_camera, paired


@dataclass
class Step:
    """One push: ``display`` (a BGR image or None per sensor), ``inputs`` (what
    :meth:`~slipsense.streaming.detector.SlipDetector.push` takes, one per sensor), ``stamp`` (s)."""

    display: list
    inputs: list
    stamp: float


@dataclass
class Source:
    """Steps to stream. ``sensors``: streams per step; ``name``: for messages; ``stats``: what the
    source knows of its own delivery (a live camera's achieved rate, dropped and repeated frames);
    ``converted``: the inputs are not the pictures shown (markers tracked in them, a saved stream)."""

    name: str
    sensors: int
    steps: Iterator[Step]
    closer: Callable[[], None] | None = None
    stats: Callable[[], dict[str, Any]] = field(default=lambda: {})
    #: the inputs are not the pictures shown (markers tracked in them, or a saved stream)
    converted: bool = False

    def frames(self) -> Iterator[Step]:
        return self.steps

    def close(self) -> None:
        if self.closer is not None:
            self.closer()


def open_source(
    source: str,
    model: Any = None,
    camera_glob: str | None = None,
    geometry: Mapping[str, Any] | None = None,
    topics: Sequence[str] = (),
    fps: float = 25.0,
    tolerance_s: float | None = None,
    capture_format: str | None = None,
    frame_size: tuple[int, int] | None = None,
) -> Source:
    """A video file, a folder of one sensor's frames (:mod:`slipsense.recordings.frames`), a recordings
    experiment folder (its ``camera_*.avi`` videos as sensors), a ROS 2
    bag (``topics``: one image topic per sensor), a marker ``.npy`` (``(T, M, 3)`` or
    ``(S, T, M, 3)`` mm) or a camera index (``0``, ``1``, ...; several as ``0,2``).

    ``model`` (a :class:`~slipsense.models.base.SlipModel`) turns what is read into its inputs
    (:meth:`~slipsense.models.base.SlipModel.inputs_from_videos`: pictures as they are, or markers
    tracked first, in the layout of the checkpoint's ``geometry``; a ``.npy`` holds them already); None
    pushes the pictures as they are. ``fps``: the
    sensor's rate (stamps of files without time, the pairing tolerance of bags); ``capture_format`` /
    ``frame_size``: what a camera is asked for (:class:`~slipsense.streaming.capture.CaptureThread`).
    """
    camera_glob = camera_glob or CAMERA_GLOB  # the sensor's camera files (the GelSight study's by default)
    path = Path(source)
    if topics and not is_bag(path):
        raise InputError(path, "--topic names image topics of a ROS 2 bag; this is not a bag")
    if is_bag(path):
        bag = read_bag(path, topics, fps=fps, tolerance_s=tolerance_s)
        videos = [np.stack([step[k] for step in bag.frames]) for k in range(len(topics))]
        stamps = bag.stamps[:, 0] * 1e-9
        name = f"{path} ({', '.join(topics)})"
        src = _array_source(name, videos, [Path(f"{path}:{t}") for t in topics], model, stamps, geometry)
        src.stats = lambda: {"dropped_unpaired": dict(bag.dropped)}
        return src
    if path.is_dir() and is_frame_folder(path):  # one sensor's frames, read as its video
        video = read_video(path, expected_size=None, min_frames=1)
        return _array_source(str(path), [video], [path], model, np.arange(len(video)) / fps, geometry)
    if path.is_dir():
        cams = sorted(p for p in path.glob(camera_glob) if p.is_file())
        if not cams:
            raise InputError(path, f"folder holds no {camera_glob} videos (expected a recordings experiment folder)")
        videos = [read_video(p, expected_size=None, min_frames=1) for p in cams]
        if len({len(v) for v in videos}) != 1:
            raise InputError(path, f"the camera videos differ in frame count: {[len(v) for v in videos]}")
        return _array_source(str(path), videos, cams, model, np.arange(len(videos[0])) / fps, geometry)
    if path.is_file():
        if path.suffix.lower() == ".npy":
            return _npy_source(path, model, fps)
        video = read_video(path, expected_size=None, min_frames=1)
        return _array_source(str(path), [video], [path], model, np.arange(len(video)) / fps, geometry)
    indices = source.replace(" ", "").split(",")
    if all(i.isdigit() for i in indices):
        if model is not None:
            model.check_live_cameras(source)
        return camera_source([int(i) for i in indices], fps, capture_format, frame_size, tolerance_s)
    raise InputError(path, "no such file or folder (nor a camera index)")


def _array_source(name: str, videos: list, paths: list[Path], model: Any, stamps: np.ndarray, geometry=None) -> Source:
    inputs = videos if model is None else model.inputs_from_videos(videos, paths, geometry)
    steps = (Step(list(fr), list(x), float(t)) for fr, x, t in zip(zip(*videos), zip(*inputs), stamps))
    return Source(name, len(videos), steps, converted=any(x is not v for x, v in zip(inputs, videos)))


def _npy_source(path: Path, model: Any, fps: float) -> Source:
    try:
        x = np.load(path, allow_pickle=False)
    except Exception as exc:
        raise InputError(path, f"not a readable .npy file ({type(exc).__name__}: {exc})") from None
    if model is None:
        raise InputError(path, "a marker .npy needs a marker model (stnet, temnet): give its --checkpoint")
    x = model.inputs_from_array(x, path)
    steps = (Step([None] * len(x), [x[s, t] for s in range(len(x))], t / fps) for t in range(x.shape[1]))
    return Source(str(path), len(x), steps, converted=True)


def capture_source(name: str, threads: Sequence[CaptureThread], fps: float, tolerance_s: float | None = None):
    """A :class:`Source` over running capture threads, paired by time
    (``tolerance_s``: half a frame period by default); its ``stats`` are the threads'."""
    check_timing(fps, tolerance_s)
    tol = 0.5 / fps if tolerance_s is None else tolerance_s
    steps = (Step(list(frames), list(frames), stamps[0]) for frames, stamps in paired(threads, tol))

    def close():
        for th in threads:
            th.close()

    return Source(name, len(threads), steps, closer=close, stats=lambda: {"cameras": [th.stats() for th in threads]})


def camera_source(indices, fps, capture_format=None, frame_size=None, tolerance_s=None):
    """Live cameras (one per sensor) behind capture threads."""
    threads = []
    try:
        for i in indices:
            cap = open_camera(i, fps, capture_format, frame_size)
            threads.append(CaptureThread(cap.read, f"camera {i}", release=cap.release))
    except BaseException:
        for th in threads:
            th.close()
        raise
    return capture_source(f"camera {','.join(map(str, indices))}", threads, fps, tolerance_s)
