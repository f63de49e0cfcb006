"""How the object moves against the gel, frame by frame: translation, turn and the share that sticks.

Slip is the object moving against the gel's surface; while it sticks, the gel's surface moves with it.
A camera-in-gel sensor sees both: the object's *imprint* in the gel's shading moves with the object,
the markers move with the gel's surface. Per finger and frame (:class:`GelMotionStream`):

* the frame at :data:`WORK_WIDTH` px wide; a closing fills the dark markers and leaves the shading;
  its change since the reference frame is the imprint, and where it exceeds :data:`CONTACT_FLOOR`
  the contact;
* the imprint's rigid motion ``(tx, ty, omega)`` over the last :data:`LAG_S` seconds, fitted directly
  on the brightness over the contact (a rigid Lucas-Kanade: only textured parts of the imprint
  speak, a featureless one says nothing);
* the gel's surface motion over the same time: dense optical flow (OpenCV's DIS) from the reference,
  its change at the contact's points, fitted with the same rigid model;
* **the object's motion against the gel** = the imprint's minus the gel's: ``translation`` ``(vx, vy)``
  at the contact's centre (image axes: x right, y down; mm/s where the sensor states its pixel size,
  px/s of the frame otherwise) and ``omega`` (rad/s, from +x towards +y), a causal median over
  :data:`SMOOTH_S` seconds; **stick**: the share of contact points where the gel's surface kept up
  with the object's rigid motion (within :data:`STICK_TOLERANCE_PX`).

All three are None only where there is no contact (or less than :data:`LAG_S` of it), and the whole
reading is None on a gel without a marker grid: nothing there says how the gel's surface moves.
A marker sensor (``(M, 3)`` clouds) shows no imprint texture: :class:`CloudMotionStream` says what it
reads instead. The shear field rides along: ``displacement`` (the contact's mean displacement since
the reference), ``divergence`` and ``curl`` of its affine fit (unitless; divergence > 0: the gel
spreads, as under pressing; curl: twice the rotation angle), ``contact`` (the share of the gel touched).

The first frame pushed (after any start-up) is the reference: reset at the start of each grasp, before
contact. How well it follows the object: ``python -m studies velocity`` (docs/gel-motion.md).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import cv2
import numpy as np

from slipsense.sensors.marker_detection import _as_gray, _blob_diameter, _detect, _odd

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
#: A footprint's motion counts as sliding where the contact's mean shear points with it (cosine) and is
#: at least this long (mm): Coulomb friction drags the gel along a sliding object, not a rolling one.
COULOMB_COSINE, SHEAR_FLOOR_MM = 0.5, 0.05
#: mm/s by which a contact marker may differ from the object's motion and still stick.
STICK_TOLERANCE_MM_S = 1.0
#: A footprint whose second moments differ by less than this ratio is round: it shows no turn.
ROUND_RATIO = 1.5
#: Camera-in-gel frames are measured at this width (px): the shading and the gel's flow vary over
#: several of these pixels on a GelSight Mini (320 px) and the lift's GelSight (640 px) alike.
WORK_WIDTH = 160
#: Marker diameter (working px) looked for first: a GelSight Mini's and the lift GelSight's are 4-6.
MARKER_GUESS_PX = 5.0
#: Blur (working px) of the marker-free shading: smooth enough for a rigid fit to converge.
IMPRINT_BLUR = 1.0
#: Change of the marker-free shading (grey levels) where the object touches the gel.
CONTACT_FLOOR = 10.0
#: Grey levels by which a marker is darker than the shading the closing fills in (markers' rims included).
MARKER_LEVEL = 6
#: Fewest working pixels in contact for a motion.
MIN_CONTACT_PX = 30
#: Seconds between the two frames a motion is measured over (at least one frame), and how long the
#: readings' causal median runs.
LAG_S, SMOOTH_S = 0.07, 0.07
#: The fits read every this many working pixels along each axis.
STRIDE = 2
#: Seconds a contact must have lasted before its motion is read (a forming footprint's imprint moves).
SETTLE_S = 0.1
#: Grey levels per working px: the imprint gradient that weighs as much as the prior of no motion.
PRIOR_GRADIENT = 0.3
#: About the most contact points a fit reads.
MAX_POINTS = 300
#: Gauss-Newton steps of the imprint's rigid fit per pyramid level.
ITERATIONS = 3
#: Working px over the lag by which the gel may lag the object's motion and still stick.
STICK_TOLERANCE_PX = 0.35


def _rounded(v) -> float:
    """A reading's number as JSON carries it: four decimals."""
    return round(float(v), 4)


@dataclass(frozen=True)
class GelMotion:
    """One finger's gel at one frame (see the module notes). Lengths in ``unit`` (``"mm"`` or ``"px"``).

    ``translation``: the object's in-plane velocity against the gel's surface ``(vx, vy)`` in ``unit``
    per second (image axes: x right, y down); ``omega``: its rotation rate against the gel about the
    contact's centre, rad/s (positive: from +x towards +y, i.e. clockwise as the image is drawn);
    ``stick``: the share of the contact (0-1) where the object still moves with the gel; ``speed``:
    how fast the object moves against the gel, on average over the contact (the root mean square of
    the translation and the turn's speed at each contact point, ``sqrt(|v|^2 + omega^2 r^2)``, in
    ``unit`` per second): a pivot about the contact's centre slips as much as a slide. All four None
    only where there is no contact."""

    translation: tuple[float, float] | None
    omega: float | None
    stick: float | None
    speed: float | None
    displacement: tuple[float, float]
    divergence: float
    curl: float
    contact: float
    unit: str

    def to_dict(self) -> dict:
        """JSON-ready (rounded) form: what a reading's ``shear`` list holds per finger."""
        r = _rounded
        return {
            "displacement": [r(v) for v in self.displacement],
            "divergence": r(self.divergence),
            "curl": r(self.curl),
            "contact": r(self.contact),
        }

    def slip_dict(self) -> dict | None:
        """JSON-ready (rounded) slip: ``{"translation": [vx, vy], "omega": w, "stick": s, "speed": v}``; None
        without contact."""
        if self.translation is None:
            return None
        r = _rounded
        return {
            "translation": [r(v) for v in self.translation],
            "omega": r(self.omega),
            "stick": r(self.stick),
            "speed": r(self.speed),
        }


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


def rigid_fit(points: np.ndarray, flow: np.ndarray, weight: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Least-squares ``(tx, ty, omega)`` of a small rigid motion ``flow = t + omega * k x (points - centre)``
    (``(N, 2)`` each, ``weight`` ``(N,)`` >= 0): the translation at ``centre`` and the rotation (rad)."""
    x, y = points[:, 0] - centre[0], points[:, 1] - centre[1]
    w = weight / max(float(weight.sum()), 1e-12)
    # normal equations of [1 0 -y; 0 1 x] p = flow, weighted
    sxx, syy = float(w @ (x * x)), float(w @ (y * y))
    sx, sy = float(w @ x), float(w @ y)
    h = np.array([[1.0, 0.0, -sy], [0.0, 1.0, sx], [-sy, sx, sxx + syy]])
    fx, fy = flow[:, 0], flow[:, 1]
    b = np.array([float(w @ fx), float(w @ fy), float(w @ (x * fy - y * fx))])
    try:
        return np.linalg.solve(h + 1e-9 * np.eye(3), b)
    except np.linalg.LinAlgError:
        return np.zeros(3)


def _points(mask: np.ndarray, finest: int = 0, most: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of ``mask`` on a grid of every ``finest``-th pixel (default :data:`STRIDE`), or coarser, so that at
    most about :data:`MAX_POINTS` remain: neighbouring pixels of a working frame say nearly the same,
    and a contact covering half the gel costs no more than one covering a tenth."""
    stride = max(finest or STRIDE, math.ceil(math.sqrt(np.count_nonzero(mask) / (most or MAX_POINTS))))
    ys, xs = np.nonzero(mask[::stride, ::stride])
    return ys * stride, xs * stride


def imprint_motion(
    before: np.ndarray, after: np.ndarray, mask: np.ndarray, centre: np.ndarray, prior_gradient: float = 0.0
) -> np.ndarray:
    """``(tx, ty, omega)``: the rigid motion (px, rad; about ``centre``, in px) that carries the imprint
    ``before`` onto ``after`` (float32 images of one size) over ``mask``: direct Gauss-Newton on the
    brightness (Lucas-Kanade with a rigid model; a coarse level first), so texture weighs itself in
    and featureless parts of the contact say nothing. ``prior_gradient`` (grey levels per px): a prior
    of no motion as strong as an imprint with that gradient everywhere (0: none)."""
    ys, xs = np.nonzero(mask)
    y0, y1 = max(ys.min() - 4, 0), min(ys.max() + 5, mask.shape[0])
    x0, x1 = max(xs.min() - 4, 0), min(xs.max() + 5, mask.shape[1])
    a, b, m = before[y0:y1, x0:x1], after[y0:y1, x0:x1], mask[y0:y1, x0:x1]
    c = np.asarray(centre, np.float64) - (x0, y0)
    p = np.zeros(3)
    levels = [(a, b, m, 1.0)]
    if min(a.shape) >= 16:
        levels.insert(0, (cv2.pyrDown(a), cv2.pyrDown(b), None, 0.5))
    for ia, ib, im, s in levels:
        if im is None:
            im = cv2.resize(m.astype(np.uint8), (ia.shape[1], ia.shape[0]), interpolation=cv2.INTER_NEAREST) > 0
        # the coarse level only has to come near: a third of the points there
        yy, xx = _points(im, 1, MAX_POINTS // 3) if s < 1 else _points(im, STRIDE)
        if len(xx) < 6:
            continue
        gx = cv2.Sobel(ia, cv2.CV_32F, 1, 0, ksize=3)[yy, xx] / 8.0
        gy = cv2.Sobel(ia, cv2.CV_32F, 0, 1, ksize=3)[yy, xx] / 8.0
        rx, ry = (xx - c[0] * s).astype(np.float32), (yy - c[1] * s).astype(np.float32)
        jac = np.stack([gx, gy, gy * rx - gx * ry], 1)
        # a prior of no motion, as strong as an imprint whose gradient is PRIOR_GRADIENT everywhere:
        # a faint or featureless imprint, whose fit noise would read as slip, reads as little motion
        lever = float(np.mean(rx * rx + ry * ry)) + 1.0
        prior = prior_gradient**2 * len(xx) * np.diag([1.0, 1.0, lever])
        inverse = np.linalg.inv((jac.T @ jac).astype(np.float64) + prior + 1e-6 * np.eye(3))  # fixed per level
        base = ia[yy, xx]
        for _ in range(ITERATIONS):
            cos, sin = np.float32(np.cos(p[2])), np.float32(np.sin(p[2]))
            mx = cos * rx - sin * ry + np.float32(c[0] * s + p[0] * s)
            my = sin * rx + cos * ry + np.float32(c[1] * s + p[1] * s)
            warped = cv2.remap(ib, mx[:, None], my[:, None], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            grad = (jac.T @ (warped[:, 0] - base)).astype(np.float64) + prior @ (p * np.array([s, s, 1.0]))
            step = -(inverse @ grad)
            p += step / np.array([s, s, 1.0])
            if np.abs(step).max() < 1e-2:  # a hundredth of a px (or rad): well under the noise
                break
    return p if np.all(np.isfinite(p)) else np.zeros(3)  # a degenerate fit says nothing


class GelMotionStream:
    """The object's motion against the gel of one camera-in-gel sensor, frame by frame (module notes).

    ``fps``: the frames' rate; ``mm_per_pixel``: the pixel size at the frames' size (None: lengths in
    px); ``startup``: frames at the start that are a camera's start-up transient, not the scene (never
    the reference). :meth:`push` takes a uint8 BGR (or grey) frame and returns a :class:`GelMotion`, or
    None while the gel shows no marker grid (the reference is the first frame after the start-up with
    one; a gel without markers never gets one: nothing says how its surface moves)."""

    def __init__(
        self,
        fps: float,
        mm_per_pixel: float | None = None,
        startup: int = 0,
        lag_s: float = LAG_S,
        smooth_s: float = SMOOTH_S,
        contact_floor: float = CONTACT_FLOOR,
        settle_s: float = SETTLE_S,
        prior_gradient: float = PRIOR_GRADIENT,
    ):
        self.fps, self.startup = float(fps), int(startup)
        self.lag = max(1, int(round(lag_s * self.fps)))
        self.smooth = max(1, int(round(smooth_s * self.fps)) + 1)
        self.settle = int(round(settle_s * self.fps))
        self.prior_gradient = float(prior_gradient)
        self.contact_floor = float(contact_floor)
        self.mm_per_pixel = mm_per_pixel
        self.unit = "px" if mm_per_pixel is None else "mm"
        self._flow = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST)
        self.reset()

    def reset(self) -> None:
        self._ref = None
        self._pushed = 0
        self._past: deque = deque(maxlen=self.lag)  # (imprint, gel displacement, contact, seen) of the last frames
        self._recent: deque = deque(maxlen=self.smooth)  # the last instant (tx, ty, omega, stick, speed)
        self._touching = 0  # frames in contact since the reset

    def _working(self, image: np.ndarray) -> np.ndarray:
        """``image`` at :data:`WORK_WIDTH` px wide (its aspect kept)."""
        h, w = image.shape[:2]
        self._scale = w / WORK_WIDTH  # frame px per working px
        return cv2.resize(image, (WORK_WIDTH, max(8, int(round(h / self._scale)))), interpolation=cv2.INTER_AREA)

    def _small(self, frame: np.ndarray):
        """The working-size markers (uint8, bright on dark) and marker-free shading ``(h, w, C)`` float32."""
        small = self._working(frame)
        # the closing fills the dark markers: what is left is the shading, and in it the object's
        # imprint, in colour where the lights are coloured (a GelSight's are); what it filled is the
        # markers alone, without the imprint, whose flow is the gel's surface
        closed = cv2.morphologyEx(small, cv2.MORPH_CLOSE, self._kernel)
        filled = cv2.subtract(closed, small)  # the closing only raises pixels: no saturation
        markers = filled if filled.ndim == 2 else cv2.cvtColor(filled, cv2.COLOR_BGR2GRAY)
        return markers, closed.astype(np.float32).reshape(markers.shape + (-1,))

    def _start(self, frame: np.ndarray) -> bool:
        # the markers are looked for at the working size: a third of the time at full size (the
        # reference is one push of the stream, but on a 21-frame grasp it is its slowest)
        small = self._working(_as_gray(frame, None))
        blobs = _detect(small, MARKER_GUESS_PX, 12.0, 1)
        diameter = _blob_diameter(blobs) if len(blobs.areas) else MARKER_GUESS_PX
        if abs(diameter - MARKER_GUESS_PX) > 0.3 * MARKER_GUESS_PX:  # markers of another size: once more at theirs
            blobs = _detect(small, diameter, 12.0, 1)
            diameter = _blob_diameter(blobs) if len(blobs.areas) else diameter
        if len(blobs.centres) < MIN_MARKERS:
            return False
        size = _odd(max(3.0, 1.6 * diameter))
        self._kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
        self._dot = np.ones((3, 3), np.uint8)
        self._ref = self._small(frame)
        return True

    def push(self, frame: np.ndarray, stamp: float | None = None) -> GelMotion | None:
        """This frame's :class:`GelMotion` (``stamp`` is accepted for the stream's interface; the lag
        and smoothing count frames at ``fps``)."""
        self._pushed += 1
        if self._ref is None:
            if self._pushed <= self.startup or not self._start(frame):
                return None
        markers, shading = self._small(frame)
        ref_markers, ref_shading = self._ref
        change = cv2.subtract(shading, ref_shading)
        channels = change.shape[-1]
        # contact: the shading changed (summed over colours); the imprint fitted: its mean over colours
        summed = cv2.transform(cv2.absdiff(shading, ref_shading), np.ones((1, channels), np.float32))
        contact = cv2.blur(summed, (5, 5)).reshape(summed.shape[:2]) > self.contact_floor
        imprint = cv2.transform(change, np.full((1, channels), 1.0 / channels, np.float32)).reshape(summed.shape[:2])
        imprint = cv2.GaussianBlur(imprint, (0, 0), IMPRINT_BLUR)  # smooth enough for the fit to converge
        gel = self._flow.calc(ref_markers, markers, None)  # where each reference point of the gel went
        # where the closing filled a marker the shading is made up, and moves with the gel: not imprint
        seen = cv2.dilate(markers, self._dot) <= MARKER_LEVEL
        past = self._past[0] if len(self._past) == self.lag else None
        self._past.append((imprint, gel, contact, seen))
        touched = np.count_nonzero(contact)
        # counted over the grasp, not in a row: a contact flickering at its floor is still one contact
        self._touching += touched >= MIN_CONTACT_PX
        # a footprint still forming moves its imprint without any sliding: judged once it has settled
        motion = self._slip(imprint, gel, contact, past) if self._touching > self.settle else None
        return self._reading(motion, gel, contact, touched)

    def _slip(self, imprint, gel, contact, past):
        """The instant ``(tx, ty, omega, stick, speed)`` in working px/s, rad/s: the imprint's rigid motion
        over the lag minus the gel's, over the contact of both frames; None without that contact."""
        if past is None:
            return None
        both = contact & past[2]
        if np.count_nonzero(both) < MIN_CONTACT_PX:
            return None
        ys, xs = _points(both)
        textured = both & past[3]
        pts = np.stack([xs, ys], 1).astype(np.float64)
        centre = pts.mean(0)
        dt = self.lag / self.fps
        # an imprint with no texture seen (all of it under markers) shows no motion: the prior's answer
        obj = imprint_motion(past[0], imprint, textured, centre, self.prior_gradient) if textured.any() else np.zeros(3)
        surface = (gel[ys, xs] - past[1][ys, xs]).astype(np.float64)  # each contact point of the gel, moved
        gel_rigid = rigid_fit(pts, surface, np.ones(len(pts)), centre)
        rel = (obj - gel_rigid) / dt
        # stick: where the gel's surface keeps up with the object (the object's rigid motion there)
        r = pts - centre
        carried = np.stack([obj[0] - obj[2] * r[:, 1], obj[1] + obj[2] * r[:, 0]], 1)
        stick = float((np.linalg.norm(carried - surface, axis=1) <= STICK_TOLERANCE_PX).mean())
        speed = float(np.sqrt(rel[0] ** 2 + rel[1] ** 2 + rel[2] ** 2 * (r**2).sum(1).mean()))
        return rel[0], rel[1], rel[2], stick, speed

    def _reading(self, motion, gel, contact, touched: int) -> GelMotion:
        if motion is None:
            self._recent.clear()
        else:
            self._recent.append(motion)
        length = self._scale * (1.0 if self.mm_per_pixel is None else self.mm_per_pixel)
        share = float(touched) / contact.size if touched >= MIN_CONTACT_PX else 0.0  # a speck is no contact
        if touched >= MIN_CONTACT_PX:
            ys, xs = _points(contact)
            r = np.stack([xs, ys], 1).astype(np.float64)
            r -= r.mean(0)
            d = gel[ys, xs].astype(np.float64)
            mean = d.mean(0)
            moments = r.T @ r
            if abs(np.linalg.det(moments)) > 1e-9:
                grad = np.linalg.solve(moments, r.T @ (d - mean))  # grad[j, i] = d d_i / d x_j
            else:  # a contact along a line: no gradient across it
                grad = np.zeros((2, 2))
            divergence, curl = float(grad[0, 0] + grad[1, 1]), float(grad[0, 1] - grad[1, 0])
        else:
            mean, divergence, curl = np.zeros(2), 0.0, 0.0
        shear = ((float(mean[0] * length), float(mean[1] * length)), divergence, curl, share)
        if not self._recent:
            return GelMotion(None, None, None, None, *shear, self.unit)
        # a causal median over the last frames: one frame's bad fit does not make a slip
        tx, ty, omega, stick, speed = np.median(np.asarray(self._recent), axis=0)
        return GelMotion(
            (float(tx * length), float(ty * length)),
            float(omega),
            float(stick),
            float(speed * length),
            *shear,
            self.unit,
        )


class CloudMotionStream:
    """The same for a marker sensor: :meth:`push` takes an ``(M, 3)`` cloud in mm (gel frame, rest
    surface at z = 0, indentation negative); the first cloud's ``x, y`` are the material coordinates.

    A marker sensor shows no texture of the object, only its footprint (the indentation) and the gel's
    surface (the markers). The footprint's centroid over the gel's *material* moves when the object
    slides, and when it rolls; Coulomb friction tells the two apart: a sliding object drags the gel's
    surface along its motion (the contact's mean shear points with it), a rolling one does not. So the
    translation is the footprint's motion over the material where the contact's shear agrees with it
    in direction (cosine at least :data:`COULOMB_COSINE`) and exceeds :data:`SHEAR_FLOOR_MM`, else
    zero (stick, or rolling without sliding); ``omega`` the rate at which the footprint's long axis
    turns over the material (zero for a round footprint, which shows no turn); ``stick`` the share of
    contact markers that move with the object (within :data:`STICK_TOLERANCE_MM_S`)."""

    unit = "mm"

    def __init__(self, fps: float, window_s: float = WINDOW_S, floor_mm: float = INDENT_FLOOR_MM):
        self.fps = float(fps)
        self._velocity = VelocityWindow(fps, window_s)
        self._turn = VelocityWindow(fps, window_s)
        self.floor_mm = float(floor_mm)
        self.reset()

    def reset(self) -> None:
        self._material: np.ndarray | None = None
        self._last: np.ndarray | None = None
        self._angle: float | None = None
        self._velocity.reset()
        self._turn.reset()

    def push(self, cloud: np.ndarray, stamp: float | None = None) -> GelMotion:
        cloud = np.asarray(cloud, np.float64)
        if self._material is None:
            self._material = cloud[:, :2].copy()
        last, self._last = self._last, cloud[:, :2].copy()
        weight = np.maximum(-cloud[:, 2] - self.floor_mm, 0.0)
        displacement = cloud[:, :2] - self._material
        seen = footprint(self._material, weight, displacement)
        if seen is None:
            self._velocity.push(None, stamp)
            self._turn.push(None, stamp)
            self._angle = None
            return GelMotion(None, None, None, None, (0.0, 0.0), 0.0, 0.0, 0.0, self.unit)
        centroid, mean, divergence, curl, contact = seen
        shear = ((float(mean[0]), float(mean[1])), divergence, curl, contact)
        v = self._velocity.push(centroid, stamp)
        w = self._turn.push(self._axis_angle(weight, centroid), stamp)
        if v is None or last is None:
            return GelMotion(None, None, None, None, *shear, self.unit)
        v = np.asarray(v)
        speed, drag = float(np.linalg.norm(v)), float(np.linalg.norm(mean))
        sliding = drag > SHEAR_FLOOR_MM and speed > 0 and float(v @ mean) >= COULOMB_COSINE * speed * drag
        if sliding:
            # friction drags the gel along the slide: the shear gives the direction; the footprint is
            # seen to move only across a contact longer than the gel (the slide's projection on its
            # motion), so its speed over the cosine between the two is the slide's
            along = mean / drag
            translation = along * speed / max(float(v @ along) / speed, COULOMB_COSINE)
        else:
            translation = np.zeros(2)
        omega = float(w[0]) if (w is not None and sliding) else 0.0
        touched = weight > 0
        marker_v = (cloud[touched, :2] - last[touched]) * self.fps
        gel_v = marker_v.mean(0)  # the contact's surface velocity; the object moves at it plus its slip
        moves_with = np.linalg.norm(marker_v - (gel_v + translation), axis=1) <= STICK_TOLERANCE_MM_S
        r2 = float(((self._material[touched] - centroid) ** 2).sum(1).mean())
        speed = float(np.sqrt(translation @ translation + omega**2 * r2))
        return GelMotion(
            (float(translation[0]), float(translation[1])), omega, float(moves_with.mean()), speed, *shear, self.unit
        )

    def _axis_angle(self, weight: np.ndarray, centroid: np.ndarray):
        """The footprint's long axis over the material (rad, unwrapped, as a 1-vector for the slope
        window), None for a footprint too round to have one."""
        touched = weight > 0
        w = weight[touched] / weight[touched].sum()
        r = self._material[touched] - centroid
        cov = (r * w[:, None]).T @ r
        evals, evecs = np.linalg.eigh(cov)
        if evals[1] < ROUND_RATIO * max(evals[0], 1e-12):
            self._angle = None
            return None
        a = float(np.arctan2(evecs[1, 1], evecs[0, 1]))
        if self._angle is not None:  # an axis has no sign: keep the angle continuous mod pi
            a = self._angle + (a - self._angle + np.pi / 2) % np.pi - np.pi / 2
        self._angle = a
        return np.array([a, 0.0])


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
