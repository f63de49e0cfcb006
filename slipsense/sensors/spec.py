"""Sensor specifications: the facts about a tactile sensor that code would otherwise repeat.

A new sensor is one :class:`SensorSpec` here (and, for a new recording layout, a reader in
:mod:`slipsense.recordings`)::

    >>> from slipsense.sensors.spec import GELSIGHT_MINI
    >>> GELSIGHT_MINI.image_size, GELSIGHT_MINI.fps
    ((240, 320), 25.0)
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any, Mapping

from slipsense.errors import ConfigError, InputError

#: Frames 0 .. STARTUP_FRAMES-1 are a start-up transient of the camera stream (frame 0 differs
#: strongly, frames 1..~9 form a plateau that ends abruptly), not the scene: never scored.
STARTUP_FRAMES = 10

#: The frame rates a sensor, a recording or an option may state (frames per second): the one range
#: every rate is checked against (:func:`fps_problem`), so every rate message names the same range.
MIN_FPS, MAX_FPS = 1.0, 240.0


def fps_problem(fps: Any) -> str | None:
    """None if ``fps`` is a usable frame rate (a number of frames per second in ``[MIN_FPS, MAX_FPS]``),
    else what is wrong with it, in words: the one rate check, whose words every rate message uses."""
    ok = isinstance(fps, (int, float)) and not isinstance(fps, bool) and math.isfinite(fps)
    if ok and MIN_FPS <= fps <= MAX_FPS:
        return None
    return f"a frame rate must be {MIN_FPS:g} to {MAX_FPS:g} frames per second, got {fps!r}"


def check_fps(fps: Any, where: str | None = None) -> float:
    """``fps`` as a float if :func:`fps_problem` finds nothing wrong; else one error naming ``where``
    (a file: InputError; an option, ``"--fps"``, or nothing: ConfigError)."""
    problem = fps_problem(fps)
    if problem is None:
        return float(fps)
    if where is not None and not where.startswith("--"):
        raise InputError(where, problem)
    raise ConfigError(f"{where or 'fps'}: {problem}")


@dataclass(frozen=True)
class SensorSpec:
    """One kind of tactile sensor.

    Attributes:
        name: short identifier.
        output: ``"video"`` (camera images of the gel) or ``"markers"`` (3D marker clouds per frame).
        fps: frames per second (converts frames to milliseconds).
        image_size: ``(height, width)`` of a video frame in pixels (video sensors).
        markers: markers per frame (marker sensors).
        camera_glob: file names of the sensor videos inside one experiment folder.
        experiment_pattern: regular expression of an experiment folder's name (group 1 = its number).
        slip_marker: file whose presence in an experiment folder says the object slipped.
        capture_format: the FOURCC a live camera is asked for (``"MJPG"``: compressed frames reach
            the full rate over USB where raw YUYV at the same size does not); None: the camera's own.
        gel_markers: the gel carries a grid of markers (video sensors): readings then carry the slip
            velocity and the shear field (:mod:`slipsense.sensors.gel_motion`).
        mm_per_pixel: millimetres of gel per pixel at ``image_size`` (video sensors); None: not
            stated, and lengths stay in pixels.
    """

    name: str
    output: str
    fps: float
    image_size: tuple[int, int] | None = None
    markers: int | None = None
    camera_glob: str | None = None
    experiment_pattern: str | None = None
    slip_marker: str | None = None
    capture_format: str | None = None
    gel_markers: bool = False
    mm_per_pixel: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """The spec as JSON-ready data (what checkpoints keep under ``"sensor"``)."""
        d = asdict(self)
        if self.image_size is not None:
            d["image_size"] = list(self.image_size)
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "SensorSpec":
        """Inverse of :meth:`to_dict`; ValueError naming what is wrong."""
        if not isinstance(d, Mapping):
            raise ValueError(f"sensor spec must be a mapping, got {type(d).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"sensor spec has unknown keys {unknown}")
        if not isinstance(d.get("name"), str) or d.get("output") not in ("video", "markers"):
            raise ValueError("sensor spec needs a name and output 'video' or 'markers'")
        fps = d.get("fps")
        if fps_problem(fps) is not None:
            raise ValueError(f"sensor fps: {fps_problem(fps)}")
        size = d.get("image_size")
        if size is not None and not (
            isinstance(size, (list, tuple))
            and len(size) == 2
            and all(isinstance(v, int) and 0 < v <= 100_000 for v in size)
        ):
            raise ValueError(f"sensor image_size must be [height, width], got {size!r}")
        markers = d.get("markers")
        if markers is not None and (
            isinstance(markers, bool) or not isinstance(markers, int) or not 0 < markers <= 100_000
        ):
            raise ValueError(f"sensor markers must be a positive integer, got {markers!r}")
        for key in ("camera_glob", "experiment_pattern", "slip_marker", "capture_format"):
            if d.get(key) is not None and not isinstance(d[key], str):
                raise ValueError(f"sensor {key} must be text")
        if "gel_markers" in d and not isinstance(d["gel_markers"], bool):
            raise ValueError(f"sensor gel_markers must be true or false, got {d['gel_markers']!r}")
        mm = d.get("mm_per_pixel")
        if mm is not None and (isinstance(mm, bool) or not isinstance(mm, (int, float)) or not 0 < mm < 10):
            raise ValueError(f"sensor mm_per_pixel must be a number of millimetres in (0, 10), got {mm!r}")
        # a spec written before a field existed takes it from the registered sensor of that name
        # (checkpoints of the GelSight Mini written before capture_format ask cameras for MJPG too)
        registered = SENSORS.get(d["name"])
        added = {k: getattr(registered, k) for k in known - set(d)} if registered is not None else {}
        return cls(
            **{**added, **d, "fps": float(fps), "image_size": None if size is None else (int(size[0]), int(size[1]))}
        )


#: The ViViT study's file layout of camera videos (``<object>/exp_num_<N>/camera_0.avi`` and
#: ``camera_2.avi``, ``slip.txt`` when it slipped): a sensor of videos that states no layout of its own
#: is listed with it.
STUDY_LAYOUT = {"experiment_pattern": r"^exp_num_(\d+)$", "camera_glob": "camera_*.avi", "slip_marker": "slip.txt"}

#: Two GelSight Mini sensors on the fingers of a Franka Panda: the ViViT study's recordings, in
#: :data:`STUDY_LAYOUT`.
GELSIGHT_MINI = SensorSpec(
    name="gelsight-mini",
    output="video",
    fps=25.0,
    image_size=(240, 320),
    **STUDY_LAYOUT,
    capture_format="MJPG",
    gel_markers=True,
    # the GelSight Mini's sensing area, 18.6 x 14.3 mm (GelSight Inc., GelSight Mini datasheet), over
    # 320 x 240 px: 0.0581 and 0.0596 mm per px; their mean
    mm_per_pixel=0.0585,
)

#: The STNet study's binocular visuo-tactile sensor: 24 x 23 markers reconstructed in 3D, 20 Hz
#: (no recordings are public; the STNet study's simulator, ``studies/stnet``, stands in).
BINOCULAR_MARKERS = SensorSpec(name="binocular-markers", output="markers", fps=20.0, markers=24 * 23)

#: The GelSight of Li, Dong and Adelson (ICRA 2018; the shared ``gelsight-lift`` data): 640 x 480,
#: a dense grid of black markers, one finger, frames stored as JPEG files per grasp
#: (:mod:`slipsense.recordings.frame_folders`). The data does not state its frame rate: 30 frames/s
#: is assumed (the camera's usual rate); a ``sensor.json`` in the recordings folder states another.
#: Its pixel size is not published with the data: lengths stay in pixels.
GELSIGHT_LIFT = SensorSpec(
    name="gelsight-lift", output="video", fps=30.0, image_size=(480, 640), camera_glob="*.jpg", gel_markers=True
)

SENSORS = {s.name: s for s in (GELSIGHT_MINI, BINOCULAR_MARKERS, GELSIGHT_LIFT)}


def register_sensor(spec: SensorSpec) -> SensorSpec:
    """Make ``spec`` known by its name (``--set data.sensor=NAME``; checkpoints carry the spec itself)."""
    if not isinstance(spec, SensorSpec):
        raise TypeError(f"register_sensor takes a SensorSpec, got {type(spec).__name__}")
    SENSORS[spec.name] = spec
    return spec


def sensor_named(name: str) -> SensorSpec:
    """The registered sensor ``name``; ConfigError listing the known ones otherwise."""
    if name not in SENSORS:
        raise ConfigError(f"unknown sensor {name!r}; known: {', '.join(sorted(SENSORS))}")
    return SENSORS[name]


def sensor_of(info: Mapping[str, Any] | None, path: Any = None) -> SensorSpec:
    """The sensor a checkpoint was trained on (its ``info["sensor"]``). Checkpoints written before
    the sensor travelled with the model get the sensor of their data: the binocular marker sensor for
    marker models, else the GelSight Mini. InputError naming ``path`` for a malformed spec."""
    info = info or {}
    spec = info.get("sensor")
    if spec is None:
        kind = ((info.get("data") or {}).get("kind")) if isinstance(info.get("data"), Mapping) else None
        return BINOCULAR_MARKERS if kind == "markers" else GELSIGHT_MINI
    try:
        return SensorSpec.from_dict(spec)
    except ValueError as exc:
        raise InputError(path, f"checkpoint sensor spec is malformed ({exc})") from None


__all__ = ["BINOCULAR_MARKERS", "GELSIGHT_LIFT", "GELSIGHT_MINI", "MAX_FPS", "MIN_FPS", "SENSORS", "STUDY_LAYOUT"]
__all__ += ["SensorSpec"]
__all__ += ["check_fps", "fps_problem", "register_sensor", "sensor_named", "sensor_of"]
