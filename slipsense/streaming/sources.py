"""What ``slipsense watch`` streams: video files, recordings experiment folders, ROS 2 bags, marker
arrays and live cameras, each as a :class:`Source` of timestamped steps.

A step holds, per sensor, the picture to show and the model's input, and the time the frames were
taken (seconds) on the source's own clock: a bag's header stamps, a live camera's capture clock,
``index / rate`` for a video at the rate its container states, and for a folder of frames at the rate
its ``sensor.json`` (or ``--fps``) states. A source whose rate cannot be known is refused in one line.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np

from slipsense.errors import InputError
from slipsense.recordings.bags import check_timing, is_bag, read_bag
from slipsense.recordings.folders import CAMERA_GLOB
from slipsense.recordings.frame_folders import CAMERA_FOLDER_PREFIX, data_sensor, grasp_cameras
from slipsense.recordings.frames import is_frame_folder
from slipsense.recordings.video import probe_video, read_video
from slipsense.sensors.spec import check_fps, fps_problem
from slipsense.streaming.capture import CaptureThread, open_camera, paired


@dataclass
class Step:
    """One push: ``display`` (a BGR image or None per sensor), ``inputs`` (what
    :meth:`~slipsense.streaming.detector.SlipDetector.push` takes, one per sensor), ``stamp`` (s),
    ``frame``: the frame's 0-based number in its source, counting frames the source had but never
    pushed (a live camera's frames replaced before they were taken), or None: the push's number."""

    display: list
    inputs: list
    stamp: float
    frame: int | None = None


@dataclass
class Source:
    """Steps to stream. ``sensors``: streams per step; ``name``: for messages; ``stats``: what the
    source knows of its own delivery (a live camera's achieved rate, dropped and repeated frames);
    ``converted``: the inputs are not the pictures shown (markers tracked in them, a saved stream);
    ``fps``: the rate the source delivers at and ``clock``: where that rate was read."""

    name: str
    sensors: int
    steps: Iterator[Step]
    closer: Callable[[], None] | None = None
    stats: Callable[[], dict[str, Any]] = field(default=lambda: {})
    converted: bool = False
    fps: float = 25.0
    clock: str = ""

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
    fps: float | None = None,
    tolerance_s: float | None = None,
    capture_format: str | None = None,
    frame_size: tuple[int, int] | None = None,
    camera_fps: float = 25.0,
) -> Source:
    """A video file, a folder of one sensor's frames (:mod:`slipsense.recordings.frames`), a recordings
    experiment folder (its ``camera_*.avi`` videos as sensors), a grasp folder of ``camera_*`` frame
    folders (each camera a sensor), a ROS 2
    bag (``topics``: one image topic per sensor), a marker ``.npy`` (``(T, M, 3)`` or
    ``(S, T, M, 3)`` mm) or a camera index (``0``, ``1``, ...; several as ``0,2``).

    ``model`` (a :class:`~slipsense.models.base.SlipModel`) turns what is read into its inputs
    (:meth:`~slipsense.models.base.SlipModel.inputs_from_videos`: pictures as they are, or markers
    tracked first, in the layout of the checkpoint's ``geometry``; a ``.npy`` holds them already); None
    pushes the pictures as they are. ``fps``: the source's rate where the user states it (it replaces
    a video's stated rate; a folder of frames or a ``.npy`` holds none of its own); ``camera_fps``:
    the rate asked of cameras and of a ``.npy`` without ``fps`` (the model's sensor's), also the bag
    pairing's default tolerance; ``capture_format`` / ``frame_size``: what a camera is asked for
    (:class:`~slipsense.streaming.capture.CaptureThread`).
    """
    camera_glob = camera_glob or CAMERA_GLOB  # the sensor's camera files (the GelSight study's by default)
    given = None if fps is None else check_fps(fps, "--fps")
    path = Path(source)
    if topics and not is_bag(path):
        raise InputError(path, "--topic names image topics of a ROS 2 bag; this is not a bag")
    if is_bag(path):
        bag = read_bag(path, topics, fps=given or camera_fps, tolerance_s=tolerance_s)
        videos = [np.stack([step[k] for step in bag.frames]) for k in range(len(topics))]
        stamps = bag.stamps[:, 0] * 1e-9
        name = f"{path} ({', '.join(topics)})"
        src = _array_source(name, videos, [Path(f"{path}:{t}") for t in topics], model, stamps, geometry)
        src.stats = lambda: {"dropped_unpaired": dict(bag.dropped)}
        steps = np.diff(stamps)[np.diff(stamps) > 0]  # the rate: one over their median spacing
        src.fps = float(1.0 / np.median(steps)) if len(steps) else float(given or camera_fps)
        src.clock = "the messages' header stamps"
        return src
    if path.is_dir() and is_frame_folder(path):  # one sensor's frames, read as its video
        rate = (given, "--fps") if given else frame_folder_rate(path)
        return _videos_source(path, [path], model, geometry, rate, "")
    if path.is_dir():
        cams = sorted(p for p in path.glob(camera_glob) if p.is_file())
        if not cams and any(p.is_dir() for p in path.glob(f"{CAMERA_FOLDER_PREFIX}*")):
            # a grasp folder of camera_* frame folders: each camera a sensor, at the rate of the data's sensor.json
            cams = [folder for _, folder in grasp_cameras(path)]  # the same frame count, else one line naming it
            rate = (given, "--fps") if given else frame_folder_rate(cams[0])
            return _videos_source(path, cams, model, geometry, rate, "the cameras of this grasp")
        if not cams:
            raise InputError(path, f"folder holds no {camera_glob} videos (expected a recordings experiment folder)")
        rates = {video_rate(p, given) for p in cams}
        if len(rates) != 1:
            raise InputError(path, f"the camera videos state different frame rates: {sorted(r for r, _ in rates)}")
        return _videos_source(path, cams, model, geometry, rates.pop(), "the camera videos")
    if path.is_file():
        if path.suffix.lower() == ".npy":
            return _npy_source(path, model, given or camera_fps, "--fps" if given else "the model's sensor")
        return _videos_source(path, [path], model, geometry, video_rate(path, given), "")
    indices = source.replace(" ", "").split(",")
    if all(i.isdigit() for i in indices):
        if model is not None:
            model.check_live_cameras(source)
        return camera_source([int(i) for i in indices], given or camera_fps, capture_format, frame_size, tolerance_s)
    raise InputError(path, "no such file or folder (nor a camera index)")


#: What to do about a source whose rate cannot be known, where the command takes ``--fps``.
GIVE_FPS = "give --fps"


def video_rate(path: Path, given: float | None = None, fix: str = GIVE_FPS) -> tuple[float, str]:
    """A video's rate and where it was read: ``given`` (``--fps``), else what its container states;
    a container that states none (or one out of range) is refused, naming the file and ``fix``."""
    if given:
        return given, "--fps"
    stated = probe_video(path, expected_size=None, min_frames=1).fps
    problem = fps_problem(stated)
    if problem is not None:
        raise InputError(path, f"the video states no usable frame rate ({problem}): {fix}")
    return float(stated), "the video's stated rate"


def frame_folder_rate(
    folder: Path, fix: str = f'put a sensor.json ({{"fps": 25}}) in its recordings folder or {GIVE_FPS}'
) -> tuple[float, str]:
    """A folder of frames' rate: the ``sensor.json`` of its recordings folder (the folder itself or up
    to two above it: ``<root>/<object>/<grasp>``; three for a camera's folder of a grasp,
    ``<root>/<object>/<grasp>/camera_<i>``), or the known layout of the ``gelsight-lift`` data;
    else refused, naming the folder and ``fix``: frames in a folder carry no time of their own."""
    above = [folder, folder.parent, folder.parent.parent]
    if folder.name.startswith(CAMERA_FOLDER_PREFIX):
        above.append(folder.parent.parent.parent)
    for root in above:
        spec = data_sensor(root)
        if spec is not None:
            where = root / "sensor.json"
            return check_fps(spec.fps, str(where)), str(where) if where.is_file() else f"the {spec.name} layout"
    raise InputError(folder, f"a folder of frames states no frame rate: {fix}")


def _videos_source(path: Path, paths: list[Path], model: Any, geometry, rate: tuple[float, str], what: str) -> Source:
    """The videos (or frame folders) ``paths`` as the sensors of one source, stamped ``index / rate``
    (``rate``: the rate and where it was read); ``what`` they are, for videos of unequal length."""
    videos = [read_video(p, expected_size=None, min_frames=1) for p in paths]
    if len({len(v) for v in videos}) != 1:
        raise InputError(path, f"{what} differ in frame count: {[len(v) for v in videos]}")
    stamps = np.arange(len(videos[0])) / rate[0]
    return _array_source(str(path), videos, paths, model, stamps, geometry, *rate)


def _array_source(
    name: str, videos: list, paths: list[Path], model: Any, stamps: np.ndarray, geometry=None, fps=25.0, clock=""
) -> Source:
    inputs = videos if model is None else model.inputs_from_videos(videos, paths, geometry)
    steps = (Step(list(fr), list(x), float(t)) for fr, x, t in zip(zip(*videos), zip(*inputs), stamps))
    converted = any(x is not v for x, v in zip(inputs, videos))
    return Source(name, len(videos), steps, converted=converted, fps=fps, clock=clock)


def _npy_source(path: Path, model: Any, fps: float, clock: str) -> Source:
    try:
        x = np.load(path, allow_pickle=False)
    except Exception as exc:
        raise InputError(path, f"not a readable .npy file ({type(exc).__name__}: {exc})") from None
    if model is None:
        raise InputError(path, "a marker .npy needs a marker model (stnet, temnet): give its --checkpoint")
    x = model.inputs_from_array(x, path)
    steps = (Step([None] * len(x), [x[s, t] for s in range(len(x))], t / fps) for t in range(x.shape[1]))
    return Source(str(path), len(x), steps, converted=True, fps=fps, clock=clock)


def capture_source(name: str, threads: Sequence[CaptureThread], fps: float, tolerance_s: float | None = None):
    """A :class:`Source` over running capture threads, paired by time
    (``tolerance_s``: half a frame period by default); its ``stats`` are the threads'."""
    check_timing(fps, tolerance_s)
    tol = 0.5 / fps if tolerance_s is None else tolerance_s
    steps = (Step(list(frames), list(frames), stamps[0], seqs[0] - 1) for frames, stamps, seqs in paired(threads, tol))

    def close():
        for th in threads:
            th.close()

    stats = lambda: {"cameras": [th.stats() for th in threads]}  # noqa: E731
    return Source(name, len(threads), steps, closer=close, stats=stats, fps=fps, clock="the capture clock")


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
