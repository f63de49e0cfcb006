"""Sensor specifications: the facts about a tactile sensor that code would otherwise repeat.

A new sensor is one :class:`SensorSpec` here (and, for a new recording layout, a reader in
:mod:`slipsense.recordings`)::

    >>> from slipsense.sensors.spec import GELSIGHT_MINI
    >>> GELSIGHT_MINI.image_size, GELSIGHT_MINI.fps
    ((240, 320), 25.0)
    >>> GELSIGHT_MINI.frames_to_ms(5)
    200.0
"""

from __future__ import annotations

from dataclasses import dataclass


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
    """

    name: str
    output: str
    fps: float
    image_size: tuple[int, int] | None = None
    markers: int | None = None
    camera_glob: str | None = None
    experiment_pattern: str | None = None
    slip_marker: str | None = None

    def frames_to_ms(self, frames: float) -> float:
        return 1000.0 * float(frames) / self.fps


#: Two GelSight Mini sensors on the fingers of a Franka Panda: the ViViT study's recordings
#: (``<object>/exp_num_<N>/camera_0.avi`` and ``camera_2.avi``, ``slip.txt`` when it slipped).
GELSIGHT_MINI = SensorSpec(
    name="gelsight-mini",
    output="video",
    fps=25.0,
    image_size=(240, 320),
    camera_glob="camera_*.avi",
    experiment_pattern=r"^exp_num_(\d+)$",
    slip_marker="slip.txt",
)

#: The STNet study's binocular visuo-tactile sensor: 24 x 23 markers reconstructed in 3D, 20 Hz
#: (no recordings are public; :mod:`slipsense.sensors.simulator` simulates it).
BINOCULAR_MARKERS = SensorSpec(name="binocular-markers", output="markers", fps=20.0, markers=24 * 23)

SENSORS = {s.name: s for s in (GELSIGHT_MINI, BINOCULAR_MARKERS)}

__all__ = ["BINOCULAR_MARKERS", "GELSIGHT_MINI", "SENSORS", "SensorSpec"]
