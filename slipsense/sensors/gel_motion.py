"""What the gel says beyond "slip": the object's slip velocity and the shear field, frame by frame.

The markers ride on the gel's surface. Where the object presses the gel, each marker carries a
*contact weight* ``w >= 0``: the indentation of a marker sensor (``-z``, mm) or, on a camera-in-gel
sensor, how much the gel's shading changed at the marker since the reference frame
(:attr:`~slipsense.sensors.marker_tracking.MarkerTrack.depth`) above its no-contact floor.

Slip velocity
    The footprint's centroid in the gel's *material* coordinates (each marker's reference position,
    weighted by ``w``) is where the object touches the gel's material. While the object sticks, the
    gel's surface moves with it and the centroid stays; when the object slides, its footprint moves
    across the material at the object's speed relative to the gel. The slip velocity ``[vx, vy]`` is
    that centroid's rate of change: the least-squares slope over the last ``window_s`` seconds
    (causal), in image axes (x right, y down), in mm/s where the sensor states its pixel size and
    px/s otherwise. A rolling object moves its footprint too, without sliding: it reads as slip here.
    ``None``: not in contact (at least :data:`MIN_CONTACT` markers touched) through the whole window:
    a footprint that is still appearing or leaving moves its centroid without any sliding.
Shear field
    ``displacement``: the contact markers' mean displacement since the reference (how far the object
    has dragged the gel); ``divergence`` and ``curl`` of the least-squares affine fit of displacement
    over position, weighted by contact (unitless; divergence > 0: the gel spreads, as under pressing;
    curl: twice the rotation angle, as under a twist); ``contact``: the share of tracked markers
    touched.

The first frame pushed is the reference: reset at the start of each grasp, before contact.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import cv2
import numpy as np

from slipsense.sensors.marker_detection import _as_gray, _closing_kernel, _detect_scaled, order_markers
from slipsense.sensors.marker_tracking import MarkerFollower, _background, _sample

#: Fewest markers in contact for a footprint.
MIN_CONTACT = 3
#: Fewest markers found on the reference frame for the gel to count as carrying markers.
MIN_MARKERS = 8
#: Shading change (unitless, as :attr:`MarkerTrack.depth`) below which a marker counts as untouched:
#: twice the floor lighting flicker and codec noise give without contact.
SHADING_FLOOR = 0.02
#: Indentation (mm) below which a marker of a marker sensor counts as untouched (chosen on simulated
#: sequences of seed 1; the figures are on seed 2: ``python -m studies velocity simulated``).
INDENT_FLOOR_MM = 0.15
#: Seconds of footprint positions a velocity is fitted over (chosen with the floor above).
WINDOW_S = 0.4


@dataclass(frozen=True)
class GelMotion:
    """One finger's gel at one frame (see the module notes). Lengths in ``unit`` (``"mm"`` or ``"px"``).

    ``translation``: the object's in-plane velocity against the gel's surface ``(vx, vy)`` in ``unit``
    per second (image axes: x right, y down); ``omega``: its rotation rate against the gel about the
    contact's centre, rad/s (positive: from +x towards +y, i.e. clockwise as the image is drawn);
    ``stick``: the share of the contact (0-1) where the object still moves with the gel. All three
    None only where there is no contact."""

    translation: tuple[float, float] | None
    omega: float | None
    stick: float | None
    displacement: tuple[float, float]
    divergence: float
    curl: float
    contact: float
    unit: str

    @property
    def speed(self) -> float | None:
        """``|translation|`` in ``unit`` per second (None without contact)."""
        return None if self.translation is None else float(np.hypot(*self.translation))

    def to_dict(self) -> dict:
        """JSON-ready (rounded) form: what a reading's ``shear`` list holds per finger."""
        r = lambda v: round(float(v), 4)  # noqa: E731
        return {
            "displacement": [r(v) for v in self.displacement],
            "divergence": r(self.divergence),
            "curl": r(self.curl),
            "contact": r(self.contact),
        }

    def slip_dict(self) -> dict | None:
        """JSON-ready (rounded) slip: ``{"translation": [vx, vy], "omega": w, "stick": s}``; None without contact."""
        if self.translation is None:
            return None
        r = lambda v: round(float(v), 4)  # noqa: E731
        return {"translation": [r(v) for v in self.translation], "omega": r(self.omega), "stick": r(self.stick)}


def footprint(material: np.ndarray, weight: np.ndarray, displacement: np.ndarray):
    """``(centroid (2,), mean displacement (2,), divergence, curl, contact share)`` of one frame, or
    None with fewer than :data:`MIN_CONTACT` markers touched.

    ``material`` ``(N, 2)``: the markers' reference positions; ``weight`` ``(N,)`` >= 0: their contact
    weights (0: untouched or not tracked); ``displacement`` ``(N, 2)``: since the reference."""
    touched = weight > 0
    if touched.sum() < MIN_CONTACT:
        return None
    w = weight[touched] / weight[touched].sum()
    x, d = material[touched], displacement[touched]
    centroid = w @ x
    mean = w @ d
    # weighted least squares d = A (x - centroid) + b: the field's gradient A
    xc = x - centroid
    sw = np.sqrt(w)[:, None]
    try:
        grad, *_ = np.linalg.lstsq(sw * xc, sw * (d - mean), rcond=None)  # (2, 2): grad[j, i] = d d_i / d x_j
    except np.linalg.LinAlgError:
        grad = np.zeros((2, 2))
    divergence = grad[0, 0] + grad[1, 1]
    curl = grad[0, 1] - grad[1, 0]
    return centroid, mean, float(divergence), float(curl), float(touched.mean())


class VelocityWindow:
    """The slope of the footprint's centroid over the last ``window_s`` seconds, frame by frame."""

    def __init__(self, fps: float, window_s: float = WINDOW_S):
        self.fps = float(fps)
        self.frames = max(2, int(round(window_s * self.fps)) + 1)
        self.reset()

    def reset(self) -> None:
        self._seen: deque = deque(maxlen=self.frames)
        self._index = 0

    def push(self, centroid: np.ndarray | None, stamp: float | None = None) -> tuple[float, float] | None:
        """The velocity at this frame (None: no contact now, or too little of it in the window);
        ``stamp``: when the frame was taken (s), else its number over ``fps``."""
        if centroid is not None:
            self._seen.append((self._index, self._index / self.fps if stamp is None else float(stamp), centroid))
        self._index += 1
        recent = [(t, c) for i, t, c in self._seen if i > self._index - 1 - self.frames]
        if len(recent) < self.frames:
            return None  # contact in part of the window only: a footprint coming or going is no slip
        t = np.array([t for t, _ in recent], np.float64)
        c = np.array([c for _, c in recent], np.float64)
        t = t - t.mean()
        if not t @ t > 0:
            return None
        slope = (t @ (c - c.mean(axis=0))) / (t @ t)
        return float(slope[0]), float(slope[1])


class GelMotionStream:
    """Slip velocity and shear field of one camera-in-gel sensor, frame by frame (module notes).

    ``fps``: the frames' rate; ``mm_per_pixel``: the pixel size at the frames' size (None: lengths
    in px); ``startup``: frames at the start that are a camera's start-up transient, not the scene
    (never the reference). :meth:`push` takes a uint8 BGR (or grey) frame and returns a
    :class:`GelMotion`, or None while no marker grid has been found (the reference is the first frame
    after the start-up with one)."""

    def __init__(self, fps: float, mm_per_pixel: float | None = None, window_s: float = WINDOW_S, startup: int = 0):
        self.startup = int(startup)
        self.scale = 1.0 if mm_per_pixel is None else float(mm_per_pixel)
        self.unit = "px" if mm_per_pixel is None else "mm"
        self._velocity = VelocityWindow(fps, window_s)
        self.reset()

    def reset(self) -> None:
        self._follow: MarkerFollower | None = None
        self._pushed = 0
        self._velocity.reset()

    def _start(self, frame: np.ndarray, gray: np.ndarray) -> bool:
        blobs, diameter = _detect_scaled(gray, None, 12.0, 1)
        if len(blobs.centres) < MIN_MARKERS:
            return False
        ref = blobs.centres[order_markers(blobs.centres)].astype(np.float32)
        self._follow = MarkerFollower(gray, ref, diameter)
        self._kernel = _closing_kernel(diameter / 2.0)  # backgrounds are at half resolution
        self._ref_bg = _background(frame, self._kernel)
        self._gray, self._pos, self._ok = gray, ref.copy(), np.ones(len(ref), bool)
        return True

    def push(self, frame: np.ndarray, stamp: float | None = None) -> GelMotion | None:
        """This frame's :class:`GelMotion` (``stamp``: when it was taken, s; else its number over fps)."""
        gray = _as_gray(frame, None)
        image = frame if frame.ndim == 3 else cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
        self._pushed += 1
        if self._follow is None:
            if self._pushed <= self.startup or not self._start(image, gray):
                self._velocity.push(None, stamp)
                return None
            ref = self._follow.ref
            weight = np.zeros(len(ref))  # the reference itself: its shading has not changed
        else:
            self._pos, self._ok = self._follow.step(self._gray, self._pos, self._ok, gray)
            self._gray, ref = gray, self._follow.ref
            xy = self._pos / 2.0
            shading = _sample(_background(image, self._kernel), xy) - _sample(self._ref_bg, xy)
            weight = np.where(self._ok, np.maximum(np.linalg.norm(shading, axis=1) / 255.0 - SHADING_FLOOR, 0.0), 0.0)
        return _motion(ref * self.scale, weight, (self._pos - ref) * self.scale, self._velocity, self.unit, stamp)


class CloudMotionStream:
    """The same for a marker sensor: :meth:`push` takes an ``(M, 3)`` cloud in mm (gel frame, rest
    surface at z = 0, indentation negative); the first cloud's ``x, y`` are the material coordinates."""

    unit = "mm"

    def __init__(self, fps: float, window_s: float = WINDOW_S, floor_mm: float = INDENT_FLOOR_MM):
        self._velocity = VelocityWindow(fps, window_s)
        self.floor_mm = float(floor_mm)
        self.reset()

    def reset(self) -> None:
        self._material: np.ndarray | None = None
        self._velocity.reset()

    def push(self, cloud: np.ndarray, stamp: float | None = None) -> GelMotion:
        cloud = np.asarray(cloud, np.float64)
        if self._material is None:
            self._material = cloud[:, :2].copy()
        weight = np.maximum(-cloud[:, 2] - self.floor_mm, 0.0)
        return _motion(self._material, weight, cloud[:, :2] - self._material, self._velocity, self.unit, stamp)


def _motion(material, weight, displacement, velocity: VelocityWindow, unit: str, stamp: float | None) -> GelMotion:
    seen = footprint(material, weight, displacement)
    if seen is None:
        velocity.push(None, stamp)
        return GelMotion(None, None, None, (0.0, 0.0), 0.0, 0.0, 0.0, unit)
    centroid, mean, divergence, curl, contact = seen
    v = velocity.push(centroid, stamp)
    return GelMotion(v, None if v is None else 0.0, None if v is None else 1.0, (float(mean[0]), float(mean[1])), divergence, curl, contact, unit)


def motion_stream(sensor, frame: np.ndarray, startup: int = 0):
    """The stream for one finger of ``sensor`` (a :class:`~slipsense.sensors.spec.SensorSpec`) whose
    first frame is ``frame``: a cloud ``(M, 3)`` of float marker positions in mm, or a camera image,
    whose width scales the sensor's ``mm_per_pixel`` (stated at its ``image_size``). None where the
    gel has no markers. ``startup``: as for :class:`GelMotionStream`."""
    frame = np.asarray(frame)
    if frame.ndim == 2 and frame.shape[-1] == 3 and frame.dtype.kind == "f":
        return CloudMotionStream(sensor.fps)
    if not sensor.gel_markers or frame.ndim < 2:
        return None
    mm = sensor.mm_per_pixel
    if mm is not None and sensor.image_size:
        mm = mm * sensor.image_size[1] / frame.shape[1]
    return GelMotionStream(sensor.fps, mm, startup=startup)


__all__ = ["CloudMotionStream", "GelMotion", "GelMotionStream", "VelocityWindow", "footprint", "motion_stream"]
