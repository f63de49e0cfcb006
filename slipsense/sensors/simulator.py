"""Simulated binocular visuo-tactile sensor: 3D marker clouds for four motion patterns.

Reproduces the setting of the STNet paper (section III.A): a 22 x 21 mm elastomer with 23 x 24
markers (552 markers, 1656 values per frame) filmed at 20 Hz while one of six objects (cherry
tomato, earphone, screw, tape, pen, bottle) is stationary, pressed, rolled or slipped on it.
Samples are windows of 12 consecutive frames, stride 1. See ``docs/simulator.md`` for the model
and pictures.

Frames and units
----------------
Positions are in the *gel frame*, in mm: origin on the rest contact surface at the gel centre,
``x`` along the 22 mm side, ``y`` along the 21 mm side, ``z`` along the surface normal pointing
away from the cameras, towards the object. At rest every marker has ``z = 0``; **pressing moves
markers towards the cameras, so indentation is negative z.** (The camera frame of
:mod:`slipsense.sensors.stereo` has the same axes, shifted by ``h_v``.) Markers are ordered row
by row: index ``iy * markers_x + ix``, ``x`` fastest.

Deformation model (per frame, on the rest marker positions ``X``; details in docs/simulator.md)
--------------------------------------------------------------------------------------------
* The object is a height profile ``h(local xy) >= 0`` (0 at its lowest point) pressed ``delta``
  into the gel at contact centre ``c``: the penetration is ``p = max(0, delta - h(X - c))``,
  evaluated at the markers and on 4 x 4 sub-samples of each marker's cell (the surface load).
* Loads spread through the layer with ``C(r) = exp(-r / L) / sqrt(1 + (r / pitch)^2)`` (a
  half-space ``1/r`` response cut off by the thin layer), normalised per frame so that a uniform
  load over the contact displaces its middle by exactly the load: big contacts reach further.
* Normal: inside the contact the gel conforms, outside the dent spreads (``L = normal_decay_mm``):
  ``u_z = -max(p, C_n * p)``.
* Pressing squeezes the gel outwards: ``u_xy = press_gain * sum_j p_j C_l(X - X_j) (X - X_j)/|X - X_j|``
  (``L = lateral_decay_mm``): zero at the contact centre, largest at its edge, decaying outside.
* Rolling (footprint moves, no net tangential traction): an extra squeeze perpendicular to the
  rolling direction ``e`` (the same outward kernel projected on ``e_perp``, ``roll_gain``): two
  opposite, symmetric displacement lobes beside the contact (paper Fig. 6b).
* Slipping (tangential load along ``e``), a brush model: each contact point follows the object's
  tangential displacement ``s(t)`` until it reaches its friction limit ``kappa p`` (local pressure
  proxy), then slips. Low-pressure points at the contact edge slip first and the stick region
  shrinks inwards as ``s`` grows (Cattaneo-Mindlin partial slip); once ``s`` exceeds the limit of
  the deepest point the object slides (gross slip) and the footprint moves across the gel. The
  tangential load spreads with an *asymmetric* kernel (distances along ``e`` shrunk by
  ``trail_factor`` behind the contact, ``lead_factor`` ahead) and relaxes viscoelastically
  (``relax_s``) after the object has passed, leaving a wake: the trailing (tension) side shows
  larger displacements and more moving markers (paper Fig. 6c).
* Vibration noise: AR(1) in time (``noise_corr``) of a spatially smooth field (low-order cosine
  modes) plus per-marker jitter, standard deviation ``noise_mm`` per axis; multiplied by
  ``motion_noise_gain`` when something moves. With ``pixel_noise_px > 0`` every frame is then
  projected into both cameras with the refraction model (:mod:`slipsense.sensors.stereo`), pixel
  noise is added and the markers are reconstructed again: the depth-dominated error of a real
  binocular sensor.

Labels: the paper labels by motion pattern, so with ``label_rule="pattern"`` every window of a
slipping sequence is slip (1) and every other window is 0. Simulated slipping sequences start with
the tangential load already rising (partial slip at the contact edge from frame 0), so every
slipping window contains slip. ``label_rule="gross_slip"`` labels a slipping window 1 only if it
reaches the gross-slip frame.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from slipsense.atomic import write_with
from slipsense.errors import ConfigError, InputError
from slipsense.sensors.stereo import SensorGeometry, camera_to_gel, gel_to_camera, project, reconstruct

OBJECTS: tuple[str, ...] = ("cherry_tomato", "earphone", "screw", "tape", "pen", "bottle")
PATTERNS: tuple[str, ...] = ("stationary", "pressing", "rolling", "slipping")
SLIP_PATTERN = "slipping"
_SUPERSAMPLE = 4  # sub-samples per marker cell side for the cell-averaged penetration

Range = tuple[float, float]


@dataclass
class SimConfig:
    """Everything the simulator draws from. Ranges are ``(low, high)``, sampled uniformly per sequence.

    Sensor: ``markers_x x markers_y`` markers spanning ``gel_x_mm x gel_y_mm`` (edge markers on the
    gel border), ``fps`` frames per second, ``geometry`` the stereo rig used when
    ``pixel_noise_px > 0``.
    Dataset: ``n_sequences`` per (object, pattern); ``seq_len`` frames per sequence (int, or an
    inclusive ``(low, high)`` range); windows of ``window`` frames every ``stride`` frames;
    ``seed`` makes everything reproducible (each sequence has its own stream, so adding objects or
    sequences does not change the others); ``label_rule`` ``"pattern"`` or ``"gross_slip"``.
    Objects (mm): ``sphere_radius_mm`` cherry tomato; ``pen_radius_mm``, ``bottle_radius_mm``
    cylinders; ``ring_radius_mm``/``ring_tube_mm`` tape roll lying flat (a torus: centre-line and
    rim radii); ``screw_*`` a threaded cylinder (radius, thread pitch, thread depth, length);
    ``blob_radius_mm``/``blob_irregularity`` earphone (irregular ellipsoidal blob).
    Motion: ``indent_mm`` indentation depth; ``press_min_fraction`` lowest depth of a dynamic press
    as a fraction of the deepest, ``press_freq_hz`` its frequency; ``roll_speed_mm_s``,
    ``slip_speed_mm_s`` footprint speeds; ``shear_limit_ratio`` tangential displacement at which the
    most loaded contact point slips, as a fraction of the indentation depth (friction limit grows
    with normal load); ``partial_slip_s`` time from the first frame to gross slip;
    ``slip_start_fraction`` tangential load at frame 0 as a fraction of the gross-slip load;
    ``static_shear_fraction`` steady tangential load of a held (stationary) object, same units;
    ``p_empty`` probability that a stationary sequence has no object at all.
    Elastomer: ``normal_decay_mm``/``lateral_decay_mm`` decay lengths of the normal and in-plane
    response; ``press_gain``, ``roll_gain`` outward and sideways squeeze gains; ``trail_factor``/
    ``lead_factor`` stretch of the shear response behind/ahead of the contact; ``relax_s``
    viscoelastic relaxation time of the wake a sliding object leaves.
    Noise: ``noise_mm`` vibration std per axis; ``noise_corr`` AR(1) coefficient per frame;
    ``noise_smooth_fraction`` share of variance in the smooth field; ``motion_noise_gain``;
    ``pixel_noise_px`` std of tracking noise in both images (0 skips the stereo round trip).
    """

    seed: int = 0
    n_sequences: int = 4
    seq_len: int | tuple[int, int] = (32, 48)
    window: int = 12
    stride: int = 1
    fps: float = 20.0
    markers_x: int = 24
    markers_y: int = 23
    gel_x_mm: float = 22.0
    gel_y_mm: float = 21.0
    objects: tuple[str, ...] = OBJECTS
    patterns: tuple[str, ...] = PATTERNS
    label_rule: str = "pattern"
    geometry: SensorGeometry = field(default_factory=SensorGeometry)
    # objects
    sphere_radius_mm: Range = (9.0, 13.0)
    pen_radius_mm: Range = (3.5, 5.5)
    bottle_radius_mm: Range = (30.0, 45.0)
    ring_radius_mm: Range = (6.0, 8.5)
    ring_tube_mm: Range = (1.5, 3.0)
    tape_roll_radius_mm: Range = (15.0, 25.0)
    tape_width_mm: Range = (9.0, 15.0)
    screw_radius_mm: Range = (2.0, 3.0)
    screw_pitch_mm: Range = (1.4, 2.2)
    screw_thread_mm: Range = (0.15, 0.35)
    screw_length_mm: Range = (12.0, 20.0)
    blob_radius_mm: Range = (4.0, 7.0)
    blob_irregularity: Range = (0.1, 0.3)
    # motion
    indent_mm: Range = (0.4, 1.2)
    press_min_fraction: Range = (0.15, 0.5)
    press_freq_hz: Range = (0.3, 1.0)
    roll_speed_mm_s: Range = (2.0, 6.0)
    slip_speed_mm_s: Range = (2.0, 8.0)
    shear_limit_ratio: Range = (0.6, 1.0)
    partial_slip_s: Range = (0.2, 0.8)
    slip_start_fraction: Range = (0.05, 0.3)
    static_shear_fraction: Range = (0.0, 0.5)
    p_empty: float = 0.25
    # elastomer
    normal_decay_mm: float = 1.5
    lateral_decay_mm: float = 2.5
    press_gain: float = 0.6
    roll_gain: float = 1.8
    trail_factor: float = 3.0
    lead_factor: float = 0.5
    relax_s: Range = (0.1, 0.4)
    # noise
    noise_mm: Range = (0.005, 0.02)
    noise_corr: float = 0.7
    noise_smooth_fraction: float = 0.6
    motion_noise_gain: float = 1.5
    pixel_noise_px: float = 0.05

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """Raise ConfigError naming the first bad setting."""
        def need(cond, msg):
            if not cond:
                raise ConfigError(f"SimConfig.{msg}")

        for f in fields(self):
            if f.type != "Range":  # annotations are strings (from __future__ import annotations)
                continue
            v = getattr(self, f.name)
            try:
                ok = len(v) == 2 and bool(np.all(np.isfinite(np.asarray(v, dtype=float)))) and 0 <= v[0] <= v[1]
            except (TypeError, ValueError):
                ok = False
            need(ok, f"{f.name} must be a range (low, high) with 0 <= low <= high, got {v!r}")
        need(self.markers_x >= 2 and self.markers_y >= 2, "markers_x and markers_y must be >= 2")
        need(self.gel_x_mm > 0 and self.gel_y_mm > 0, "gel_x_mm and gel_y_mm must be positive")
        need(self.fps > 0, "fps must be positive")
        lo, hi = self.seq_len_range
        need(1 <= self.window <= lo and lo <= hi, f"seq_len {self.seq_len!r} must be >= window ({self.window})")
        need(self.stride >= 1, "stride must be >= 1")
        need(self.n_sequences >= 0, "n_sequences must be >= 0")
        unknown = [o for o in self.objects if o not in OBJECTS]
        need(not unknown, f"objects: unknown {unknown}; known: {list(OBJECTS)}")
        unknown = [p for p in self.patterns if p not in PATTERNS]
        need(not unknown, f"patterns: unknown {unknown}; known: {list(PATTERNS)}")
        need(self.label_rule in ("pattern", "gross_slip"), "label_rule must be 'pattern' or 'gross_slip'")
        need(0 <= self.p_empty <= 1, "p_empty must be in [0, 1]")
        need(self.normal_decay_mm > 0 and self.lateral_decay_mm > 0, "normal/lateral_decay_mm must be positive")
        need(self.trail_factor > 0 and self.lead_factor > 0, "trail_factor and lead_factor must be positive")
        need(0 <= self.noise_corr < 1, "noise_corr must be in [0, 1)")
        need(0 <= self.noise_smooth_fraction <= 1, "noise_smooth_fraction must be in [0, 1]")
        need(self.pixel_noise_px >= 0 and self.motion_noise_gain >= 0, "noise gains must be >= 0")
        need(self.indent_mm[1] < self.geometry.h_c_mm, "indent_mm must stay inside the elastomer (< h_c_mm)")

    @property
    def seq_len_range(self) -> tuple[int, int]:
        if isinstance(self.seq_len, (int, np.integer)):
            return int(self.seq_len), int(self.seq_len)
        lo, hi = self.seq_len
        return int(lo), int(hi)

    @property
    def n_markers(self) -> int:
        return self.markers_x * self.markers_y

    @property
    def pitch_mm(self) -> tuple[float, float]:
        """Marker spacing ``(x, y)`` in mm (about 0.96 x 0.95 mm by default)."""
        return self.gel_x_mm / (self.markers_x - 1), self.gel_y_mm / (self.markers_y - 1)


# ----------------------------------------------------------------------------- grid and fields

def rest_grid(cfg: SimConfig) -> np.ndarray:
    """Rest marker positions ``(M, 3)`` float64 mm in the gel frame (z = 0), ``x`` fastest."""
    xs = np.linspace(-cfg.gel_x_mm / 2, cfg.gel_x_mm / 2, cfg.markers_x)
    ys = np.linspace(-cfg.gel_y_mm / 2, cfg.gel_y_mm / 2, cfg.markers_y)
    gx, gy = np.meshgrid(xs, ys)  # (ny, nx): row iy, column ix
    return np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)


def displacement_field(seq, rest) -> np.ndarray:
    """Displacement of each marker from rest: ``seq (T, M, 3) - rest (M, 3)`` -> ``(T, M, 3)`` mm."""
    seq = np.asarray(seq)
    rest = np.asarray(rest)
    if seq.ndim != 3 or seq.shape[-1] != 3:
        raise InputError(None, f"seq has shape {seq.shape}; expected (T, M, 3)")
    if rest.shape != seq.shape[1:]:
        raise InputError(None, f"rest has shape {rest.shape}; expected {seq.shape[1:]} to match seq")
    dtype = seq.dtype if np.issubdtype(seq.dtype, np.floating) else np.float64
    return (seq - rest[None]).astype(dtype, copy=False)


def _compliance(dx: np.ndarray, dy: np.ndarray, decay_mm: float, core_mm: float) -> np.ndarray:
    """Surface response (unnormalised) at offset ``(dx, dy)`` mm from a unit surface load.

    ``exp(-r / decay) / sqrt(1 + (r / core)^2)``: the ``1/r`` fall-off of an elastic half-space
    (Boussinesq/Cerruti) cut off exponentially beyond ``decay`` (a thin layer on a rigid plate
    localises deformation); ``core`` (one marker pitch) removes the point-load singularity.
    """
    r = np.hypot(dx, dy)
    return np.exp(-r / decay_mm) / np.sqrt(1.0 + (r / core_mm) ** 2)


def _offsets(cfg: SimConfig) -> tuple[np.ndarray, np.ndarray]:
    """Target-minus-source offsets ``(M, M)`` in x and y (mm) between rest markers."""
    X = rest_grid(cfg)
    return X[:, None, 0] - X[None, :, 0], X[:, None, 1] - X[None, :, 1]


@functools.lru_cache(maxsize=8)
def _isotropic_kernels(markers_x, markers_y, gel_x_mm, gel_y_mm, normal_decay_mm, lateral_decay_mm):
    """``(Cn, Cl, Gx, Gy)`` each ``(M, M)``: normal and lateral responses, outward lateral kernels.

    ``G = Cl * (X_i - X_j) / |X_i - X_j|`` (regularised): a load at ``X_j`` pushes the gel at
    ``X_i`` away from itself (incompressible layer squeezed out from under the indenter).
    """
    cfg = SimConfig(markers_x=markers_x, markers_y=markers_y, gel_x_mm=gel_x_mm, gel_y_mm=gel_y_mm, seq_len=12)
    core = min(cfg.pitch_mm)
    dx, dy = _offsets(cfg)
    cn = _compliance(dx, dy, normal_decay_mm, core)
    cl = _compliance(dx, dy, lateral_decay_mm, core)
    r = np.sqrt(dx**2 + dy**2 + core**2)
    return cn, cl, cl * dx / r, cl * dy / r


def _shear_kernel(cfg: SimConfig, direction: np.ndarray) -> np.ndarray:
    """``(M, M)`` asymmetric response to a tangential load along unit ``direction`` (2,).

    Distances along ``e`` are shrunk by ``trail_factor`` for targets behind the load
    (``(X_i - X_j) . e < 0``: the trailing side, stretched, in tension) and by ``lead_factor``
    ahead of it (compressed side), so the tension side reaches further.
    """
    dx, dy = _offsets(cfg)
    e = direction
    par = dx * e[0] + dy * e[1]
    ort = -dx * e[1] + dy * e[0]
    par = par / np.where(par < 0, cfg.trail_factor, cfg.lead_factor)
    return _compliance(par, ort, cfg.lateral_decay_mm, min(cfg.pitch_mm))


def _spread(kernel: np.ndarray, source: np.ndarray, norm: np.ndarray) -> np.ndarray:
    """Response ``(T, M)`` to per-frame surface loads ``source (T, M)``, normalised per frame.

    ``norm (T,)`` is the largest response to the contact's coverage, so a uniform load over the
    contact displaces its middle by exactly that load's value and the outside decays with the
    contact's size (a large contact reaches further, like ``a / r`` in a half-space).
    """
    return (source @ kernel.T) / np.maximum(norm, 1e-12)[:, None]


def _coverage_norm(kernel: np.ndarray, coverage: np.ndarray) -> np.ndarray:
    return (coverage @ kernel.T).max(axis=1)


# ----------------------------------------------------------------------------- objects

def _u(rng: np.random.Generator, r: Range) -> float:
    return float(rng.uniform(r[0], r[1]))


def _sample_object(name: str, rng: np.random.Generator, cfg: SimConfig) -> dict[str, Any]:
    """Shape parameters (mm) and in-plane axis angle (rad) of one object instance."""
    obj: dict[str, Any] = {"name": name, "angle": float(rng.uniform(0, np.pi))}
    if name == "cherry_tomato":
        obj["radius"] = _u(rng, cfg.sphere_radius_mm)
    elif name == "pen":
        obj["radius"] = _u(rng, cfg.pen_radius_mm)
    elif name == "bottle":
        obj["radius"] = _u(rng, cfg.bottle_radius_mm)
    elif name == "tape":
        obj["ring"] = _u(rng, cfg.ring_radius_mm)
        obj["tube"] = _u(rng, cfg.ring_tube_mm)
        obj["roll_radius"] = _u(rng, cfg.tape_roll_radius_mm)
        obj["width"] = _u(rng, cfg.tape_width_mm)
        obj["on_edge"] = False  # lying flat; set for rolling, where the roll stands on its rim
    elif name == "screw":
        obj["radius"] = _u(rng, cfg.screw_radius_mm)
        obj["pitch"] = _u(rng, cfg.screw_pitch_mm)
        obj["thread"] = _u(rng, cfg.screw_thread_mm)
        obj["length"] = _u(rng, cfg.screw_length_mm)
        obj["phase"] = float(rng.uniform(0, 2 * np.pi))
    elif name == "earphone":
        obj["radius"] = _u(rng, cfg.blob_radius_mm)
        obj["aspect"] = float(rng.uniform(0.6, 1.0))
        irr = _u(rng, cfg.blob_irregularity)
        amps = rng.normal(size=3)
        obj["harmonics"] = (irr * amps / np.linalg.norm(amps)).tolist()  # orders 2, 3, 4
        obj["phases"] = rng.uniform(0, 2 * np.pi, size=3).tolist()
    else:  # pragma: no cover - validated in SimConfig
        raise ConfigError(f"unknown object {name!r}")
    return obj


def _round_profile(q: np.ndarray, radius: float) -> np.ndarray:
    """Height (mm) of a circle of ``radius`` at distance ``q`` from its lowest point; huge outside."""
    inside = np.abs(q) < radius
    return np.where(inside, radius - np.sqrt(np.maximum(radius**2 - q**2, 0.0)), 1e3)


def _height(obj: dict[str, Any], dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """Object surface height above its lowest point (mm) at offsets ``(dx, dy)`` from the contact centre."""
    ca, sa = math.cos(obj["angle"]), math.sin(obj["angle"])
    s = dx * ca + dy * sa  # along the object's axis
    q = -dx * sa + dy * ca  # across it
    name = obj["name"]
    if name == "cherry_tomato":
        return _round_profile(np.hypot(s, q), obj["radius"])
    if name in ("pen", "bottle"):
        return _round_profile(q, obj["radius"])
    if name == "tape":
        if obj["on_edge"]:  # outer face of the roll: a short wide cylinder with rounded rims
            beyond = np.maximum(np.abs(s) - obj["width"] / 2, 0.0)
            return _round_profile(q, obj["roll_radius"]) + 4.0 * beyond**2
        return _round_profile(np.hypot(s, q) - obj["ring"], obj["tube"])
    if name == "screw":
        # thread crests touch first; the valleys sit ``thread`` mm higher; the shank ends at +-length/2
        thread = obj["thread"] * (0.5 - 0.5 * np.cos(2 * np.pi * s / obj["pitch"] + obj["phase"]))
        beyond = np.maximum(np.abs(s) - obj["length"] / 2, 0.0)
        return _round_profile(q, obj["radius"]) + thread + 4.0 * beyond**2
    if name == "earphone":
        theta = np.arctan2(q, s)
        r_theta = obj["radius"] * (1 + sum(a * np.cos((k + 2) * theta + ph)
                                           for k, (a, ph) in enumerate(zip(obj["harmonics"], obj["phases"]))))
        rr = np.hypot(s, q / obj["aspect"])
        return rr**2 / (2 * r_theta)  # paraxial (parabolic) cap with a direction-dependent radius
    raise ConfigError(f"unknown object {name!r}")  # pragma: no cover


def _penetration(obj, delta: np.ndarray, centres: np.ndarray, X: np.ndarray, cfg: SimConfig):
    """Per-frame penetration (mm): at the markers ``(T, M)`` and at sub-samples ``(T, M, S*S)``.

    ``delta (T,)`` indentation depth, ``centres (T, 2)`` contact centre in gel coordinates, ``X``
    ``(M, 2)`` rest markers. The ``S = _SUPERSAMPLE`` sub-samples per side tile each marker's cell,
    so thin contacts (pen edge, screw thread crests) that fall between markers still load the gel.
    """
    px, py = cfg.pitch_mm
    off = (np.arange(_SUPERSAMPLE) + 0.5) / _SUPERSAMPLE - 0.5
    ox, oy = np.meshgrid(off * px, off * py)
    ox, oy = ox.ravel(), oy.ravel()
    dx = X[None, :, 0] - centres[:, None, 0]  # (T, M)
    dy = X[None, :, 1] - centres[:, None, 1]
    point = np.maximum(delta[:, None] - _height(obj, dx, dy), 0.0)
    sub = np.maximum(delta[:, None, None] - _height(obj, dx[..., None] + ox, dy[..., None] + oy), 0.0)
    return point, sub


# ----------------------------------------------------------------------------- motion

def _unit_angle(theta: float) -> np.ndarray:
    return np.array([math.cos(theta), math.sin(theta)])


def _path(rng, cfg: SimConfig, direction: np.ndarray, travel: float) -> np.ndarray:
    """Start centre (2,) so that a ``travel`` mm path along ``direction`` stays well inside the gel."""
    half = np.array([cfg.gel_x_mm, cfg.gel_y_mm]) / 2
    mid = rng.uniform(-0.35, 0.35, size=2) * half
    start = mid - direction * travel / 2
    end = mid + direction * travel / 2
    lim = half - 2.0  # keep the contact centre 2 mm from the border
    lo, hi = np.minimum(start, end), np.maximum(start, end)
    shift = np.maximum(-lim - lo, 0.0) - np.maximum(hi - lim, 0.0)  # slide the whole path back inside
    return start + shift


def _noise(rng, cfg: SimConfig, T: int, X: np.ndarray, sigma: float) -> np.ndarray:
    """Vibration noise ``(T, M, 3)`` mm: AR(1) in time of smooth low-order modes plus jitter."""
    M = len(X)
    xn = X[:, 0] / cfg.gel_x_mm + 0.5
    yn = X[:, 1] / cfg.gel_y_mm + 0.5
    modes = np.stack([np.cos(np.pi * kx * xn) * np.cos(np.pi * ky * yn) for kx in range(3) for ky in range(3)], 1)
    modes /= np.sqrt((modes**2).sum(1).mean())  # unit mean variance per marker
    fs = cfg.noise_smooth_fraction
    innov = (math.sqrt(fs) * np.einsum("mk,tkc->tmc", modes, rng.normal(size=(T, modes.shape[1], 3)))
             + math.sqrt(1 - fs) * rng.normal(size=(T, M, 3)))
    out = np.empty_like(innov)
    rho = cfg.noise_corr
    out[0] = innov[0]
    for t in range(1, T):
        out[t] = rho * out[t - 1] + math.sqrt(1 - rho**2) * innov[t]  # stationary unit variance
    return sigma * out


def simulate_sequence(obj_name: str, pattern: str, rng: np.random.Generator, cfg: SimConfig,
                      return_info: bool = False, allow_empty: bool = True):
    """One sequence of absolute marker positions ``(T, M, 3)`` float32 mm in the gel frame.

    ``T`` is drawn from ``cfg.seq_len``; ``M = markers_x * markers_y`` (552 by default); rest
    surface at z = 0, indentation negative z. With ``return_info=True`` also returns a dict:
    ``object``, ``pattern``, ``params`` (drawn values), ``direction`` (2,) unit motion direction,
    ``centre`` (T, 2) contact centre (mm, material coordinates), ``depth`` (T,) mm, ``contact``
    (T, M) bool, ``stick`` (T, M) bool (contact points not slipping), ``gross_slip_frame`` (first
    frame of gross slip; -1 if none). ``allow_empty=False`` forces an object onto stationary
    sequences (used for figures).
    """
    if obj_name not in OBJECTS:
        raise ConfigError(f"unknown object {obj_name!r}; known: {list(OBJECTS)}")
    if pattern not in PATTERNS:
        raise ConfigError(f"unknown pattern {pattern!r}; known: {list(PATTERNS)}")
    lo, hi = cfg.seq_len_range
    T = int(rng.integers(lo, hi + 1))
    dt = 1.0 / cfg.fps
    t = np.arange(T) * dt
    X = rest_grid(cfg)
    M = len(X)
    obj = _sample_object(obj_name, rng, cfg)
    depth = _u(rng, cfg.indent_mm)
    params: dict[str, Any] = {"object": obj, "T": T}
    theta = float(rng.uniform(0, 2 * np.pi))
    direction = _unit_angle(theta)
    delta = np.full(T, depth)
    shear = np.zeros(T)  # object tangential displacement s(t) along direction (mm)
    # s at which the deepest point slips (mm): a Coulomb proxy, proportional to the normal load
    kappa_limit = _u(rng, cfg.shear_limit_ratio) * depth
    relax = _u(rng, cfg.relax_s)
    gross = -1
    empty = False
    roll = False

    if pattern == "stationary":
        empty = allow_empty and rng.random() < cfg.p_empty
        centres = np.repeat(_path(rng, cfg, direction, 0.0)[None], T, 0)
        shear[:] = _u(rng, cfg.static_shear_fraction) * kappa_limit
        if empty:
            delta[:] = 0.0
    elif pattern == "pressing":
        lo_frac = _u(rng, cfg.press_min_fraction)
        freq = _u(rng, cfg.press_freq_hz)
        phase = float(rng.uniform(0, 2 * np.pi))
        delta = depth * (lo_frac + (1 - lo_frac) * (0.5 - 0.5 * np.cos(2 * np.pi * freq * t + phase)))
        centres = np.repeat(_path(rng, cfg, direction, 0.0)[None], T, 0)
        params.update(press_freq_hz=freq, press_min_fraction=lo_frac)
    elif pattern == "rolling":
        roll = True
        if obj_name == "tape":
            obj["on_edge"] = True  # a tape roll rolls on its outer face
        if obj_name in ("pen", "bottle", "screw", "tape"):  # cylinders roll across their axis
            sign = 1.0 if rng.random() < 0.5 else -1.0
            direction = _unit_angle(obj["angle"] + sign * np.pi / 2)
        speed = _u(rng, cfg.roll_speed_mm_s)
        travel = min(speed * t[-1], min(cfg.gel_x_mm, cfg.gel_y_mm) - 6.0)
        start = _path(rng, cfg, direction, travel)
        centres = start + np.outer(t / max(t[-1], dt) * travel, direction)
        params.update(speed_mm_s=travel / max(t[-1], dt))
    else:  # slipping
        t_gross = _u(rng, cfg.partial_slip_s)
        s0 = _u(rng, cfg.slip_start_fraction)
        speed = _u(rng, cfg.slip_speed_mm_s)
        slide_t = np.clip(t - t_gross, 0.0, None)
        travel = min(speed * slide_t[-1], min(cfg.gel_x_mm, cfg.gel_y_mm) - 6.0)
        speed = travel / max(slide_t[-1], dt)
        start = _path(rng, cfg, direction, travel)
        centres = start + np.outer(speed * slide_t, direction)
        # load ramps from s0 * limit at frame 0 to the limit at t_gross, then the object slides
        shear = kappa_limit * (s0 + (1 - s0) * np.minimum(t / t_gross, 1.0)) + speed * slide_t
        hit = np.flatnonzero(t >= t_gross)
        gross = int(hit[0]) if len(hit) else -1
        params.update(t_gross_s=t_gross, speed_mm_s=speed, start_fraction=s0)
    params.update(depth_mm=depth, shear_limit_mm=kappa_limit, relax_s=relax, direction=direction.tolist(),
                  empty=bool(empty))

    point, sub = _penetration(obj, delta, centres, X[:, :2], cfg)
    cell = sub.mean(-1)  # cell-averaged penetration: the normal load on each marker's cell
    coverage = (sub > 0).mean(-1)  # fraction of each cell in contact
    cn, cl, gx, gy = _isotropic_kernels(cfg.markers_x, cfg.markers_y, cfg.gel_x_mm, cfg.gel_y_mm,
                                        cfg.normal_decay_mm, cfg.lateral_decay_mm)
    u = np.zeros((T, M, 3))
    # normal: the gel conforms to the object inside the contact, the dent spreads around it
    u[..., 2] = -np.maximum(point, _spread(cn, cell, _coverage_norm(cn, coverage)))
    # lateral: squeezed outwards from under the indenter
    norm_l = _coverage_norm(cl, coverage)
    u[..., 0] = cfg.press_gain * _spread(gx, cell, norm_l)
    u[..., 1] = cfg.press_gain * _spread(gy, cell, norm_l)
    perp = np.array([-direction[1], direction[0]])
    if roll:
        # rolling kneads the gel sideways: extra squeeze perpendicular to the rolling direction
        side = cfg.roll_gain * _spread(gx * perp[0] + gy * perp[1], cell, norm_l)
        u[..., :2] += side[..., None] * perp
    # brush model: kappa converts penetration (a pressure proxy) into the tangential displacement
    # at which a contact point reaches its friction limit and starts to slip
    kappa = kappa_limit / max(depth, 1e-9)
    stick = (point > 0) & (shear[:, None] < kappa * point)
    if np.any(shear > 0) and not empty:
        d_point = np.minimum(shear[:, None], kappa * point)
        d_cell = np.minimum(shear[:, None, None], kappa * sub).mean(-1)
        # viscoelastic wake: gel the object has just slid off relaxes with time constant tau, so
        # a forward-dragged wake trails the moving contact (tension side)
        decay = math.exp(-dt / relax)
        for i in range(1, T):
            d_cell[i] = np.maximum(d_cell[i], decay * d_cell[i - 1])
        ct = _shear_kernel(cfg, direction)
        tangential = np.maximum(d_point, _spread(ct, d_cell, _coverage_norm(ct, coverage)))
        u[..., :2] += tangential[..., None] * direction

    moving = pattern != "stationary"
    sigma = _u(rng, cfg.noise_mm) * (cfg.motion_noise_gain if moving else 1.0)
    pos = X[None] + u + _noise(rng, cfg, T, X, sigma)
    if cfg.pixel_noise_px > 0:
        pos = _stereo_round_trip(pos, rng, cfg)
    out = pos.astype(np.float32)
    if not return_info:
        return out
    info = {"object": obj_name, "pattern": pattern, "params": params, "direction": direction,
            "centre": centres, "depth": delta, "contact": point > 0, "stick": stick,
            "gross_slip_frame": gross, "noise_mm": sigma}
    return out, info


def _stereo_round_trip(pos: np.ndarray, rng, cfg: SimConfig) -> np.ndarray:
    """Project ``(T, M, 3)`` gel-frame positions into both cameras, add pixel noise, reconstruct."""
    geom = cfg.geometry
    flat = gel_to_camera(geom, pos.reshape(-1, 3))
    uv_l, uv_r = project(geom, flat)
    uv_l = uv_l + rng.normal(scale=cfg.pixel_noise_px, size=uv_l.shape)
    uv_r = uv_r + rng.normal(scale=cfg.pixel_noise_px, size=uv_r.shape)
    return camera_to_gel(geom, reconstruct(geom, uv_l, uv_r)).reshape(pos.shape)


# ----------------------------------------------------------------------------- datasets

@dataclass
class MarkerDataset:
    """Windows of marker clouds with labels (numpy; not the torch Dataset of ``slipsense.datasets``).

    ``x`` float32 ``(N, T, M, 3)`` mm (gel frame); ``y`` int64 ``(N,)`` 1 = slip (None when
    loaded without labels); ``groups`` int64 ``(N,)`` sequence id - overlapping windows of one
    sequence share it, so split by group, never by window; ``pattern``/``object`` int64 ``(N,)``
    indices into ``pattern_names``/``object_names`` (None when unknown); ``fps`` frame rate (Hz).
    """

    x: np.ndarray
    y: np.ndarray | None
    groups: np.ndarray
    pattern: np.ndarray | None = None
    object: np.ndarray | None = None
    pattern_names: tuple[str, ...] = PATTERNS
    object_names: tuple[str, ...] = OBJECTS
    fps: float = 20.0

    def __len__(self) -> int:
        return len(self.x)


def _labels(pattern: str, gross: int, starts: np.ndarray, cfg: SimConfig) -> np.ndarray:
    if pattern != SLIP_PATTERN:
        return np.zeros(len(starts), np.int64)
    if cfg.label_rule == "pattern":
        return np.ones(len(starts), np.int64)
    last = starts + cfg.window - 1
    return ((gross >= 0) & (last >= gross)).astype(np.int64)


def make_dataset(cfg: SimConfig, progress: bool = True) -> MarkerDataset:
    """Simulate ``n_sequences`` per (object, pattern) and cut windows of ``window`` frames.

    Returns a :class:`MarkerDataset` with ``x (N, window, M, 3)`` float32; labels follow
    ``cfg.label_rule``; ``groups`` is the sequence id. Each sequence uses its own random stream
    ``default_rng([seed, object index, pattern index, k])``.
    """
    cfg.validate()
    jobs = [(o, p, k) for o in cfg.objects for p in cfg.patterns for k in range(cfg.n_sequences)]
    try:
        from tqdm import tqdm
        it = tqdm(jobs, desc="simulate", disable=not progress)
    except ImportError:  # pragma: no cover
        it = jobs
    xs, ys, gs, ps, os_ = [], [], [], [], []
    for seq_id, (o, p, k) in enumerate(it):
        rng = np.random.default_rng([cfg.seed, OBJECTS.index(o), PATTERNS.index(p), k])
        seq, info = simulate_sequence(o, p, rng, cfg, return_info=True)
        starts = np.arange(0, len(seq) - cfg.window + 1, cfg.stride)
        win = np.lib.stride_tricks.sliding_window_view(seq, cfg.window, axis=0)  # (n, M, 3, W)
        xs.append(np.ascontiguousarray(win[starts].transpose(0, 3, 1, 2)))
        ys.append(_labels(p, info["gross_slip_frame"], starts, cfg))
        gs.append(np.full(len(starts), seq_id, np.int64))
        ps.append(np.full(len(starts), PATTERNS.index(p), np.int64))
        os_.append(np.full(len(starts), OBJECTS.index(o), np.int64))
    M = cfg.n_markers
    if not xs:
        empty = np.zeros(0, np.int64)
        return MarkerDataset(np.zeros((0, cfg.window, M, 3), np.float32), empty, empty, empty, empty, fps=cfg.fps)
    return MarkerDataset(np.concatenate(xs), np.concatenate(ys), np.concatenate(gs), np.concatenate(ps),
                         np.concatenate(os_), fps=float(cfg.fps))


def save_dataset(ds: MarkerDataset, path: str | Path) -> Path:
    """Write ``ds`` atomically as the documented marker ``.npz`` (see :func:`load_marker_npz`)."""
    path = Path(path)
    if path.suffix != ".npz":
        raise InputError(path, "marker datasets are saved as .npz; give a path ending in .npz")
    arrays: dict[str, np.ndarray] = {"x": np.asarray(ds.x, np.float32), "groups": np.asarray(ds.groups, np.int64),
                                     "fps": np.asarray(ds.fps, np.float64)}
    if ds.y is not None:
        arrays["y"] = np.asarray(ds.y, np.int64)
    if ds.pattern is not None:
        arrays["pattern"] = np.asarray(ds.pattern, np.int64)
        arrays["pattern_names"] = np.asarray(ds.pattern_names, dtype=str)
    if ds.object is not None:
        arrays["object"] = np.asarray(ds.object, np.int64)
        arrays["object_names"] = np.asarray(ds.object_names, dtype=str)
    write_with(path, lambda tmp: np.savez(tmp, **arrays))
    return path


#: Largest marker coordinate accepted, in mm (1 km): beyond it a value is a corrupt number, not a position.
MAX_ABS_MM = 1e6

#: Keys of a marker .npz that are read; any other array in the file is never loaded.
NPZ_KEYS = ("x", "y", "groups", "pattern", "object", "pattern_names", "object_names", "fps")


def validate_marker_array(x, path: str | Path | None, name: str = "x") -> np.ndarray:
    """``x`` as float32 ``(N, T, M, 3)``, or InputError naming ``path`` and where it is wrong."""
    x = np.asarray(x)
    if not (np.issubdtype(x.dtype, np.floating) or np.issubdtype(x.dtype, np.integer)):
        raise InputError(path, f"{name} has dtype {x.dtype}; expected float marker positions (mm)")
    if x.ndim != 4 or x.shape[-1] != 3:
        raise InputError(path, f"{name} has shape {x.shape}; expected (N, T, M, 3): samples, frames, markers, xyz")
    if min(x.shape[:3]) == 0:
        raise InputError(path, f"{name} has shape {x.shape}; no samples, frames or markers")
    x = x.astype(np.float32, copy=False)
    finite = np.isfinite(x)
    if not finite.all():
        bad = np.argwhere(~finite)
        i, t, m, _ = (int(v) for v in bad[0])
        kind = "NaN" if np.isnan(x[i, t, m]).any() else "inf"
        raise InputError(path, f"{name} contains {len(bad)} non-finite value(s); first {kind} at sample {i}, "
                               f"frame {t}, marker {m}")
    big = np.abs(x) > MAX_ABS_MM
    if big.any():
        i, t, m, _ = (int(v) for v in np.argwhere(big)[0])
        raise InputError(path, f"{name} holds {int(big.sum())} value(s) out of range (|value| > {MAX_ABS_MM:g} mm); "
                               f"first {float(x[i, t, m][big[i, t, m]][0]):g} at sample {i}, frame {t}, marker {m}")
    return x


def _names(arr, key: str, path) -> tuple[str, ...]:
    """A 1-D array of names as a tuple of str, or InputError."""
    a = np.asarray(arr)
    if a.ndim != 1 or not (np.issubdtype(a.dtype, np.str_) or np.issubdtype(a.dtype, np.bytes_)):
        raise InputError(path, f"{key} must be a 1-D array of names, got {a.dtype} of shape {a.shape}")
    return tuple(s.decode("utf-8", "replace") if isinstance(s, bytes) else str(s) for s in a.tolist())


def _fps(arr, path) -> float:
    a = np.asarray(arr)
    if a.size != 1 or not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
        raise InputError(path, f"fps must be one number (frames per second), got {a.dtype} of shape {a.shape}")
    fps = float(a.reshape(()))
    if not (np.isfinite(fps) and 0 < fps <= 1e6):
        raise InputError(path, f"fps must be a positive finite number of frames per second, got {fps!r}")
    return fps


def _per_sample(arr, n: int, key: str, path) -> np.ndarray:
    a = np.asarray(arr)
    if a.ndim != 1 or len(a) != n:
        raise InputError(path, f"{key} has shape {a.shape}; expected ({n},), one value per sample of x")
    return a


def load_marker_npz(path: str | Path, require_labels: bool = True) -> MarkerDataset:
    """Read and validate a marker ``.npz``: the user format for marker sequences.

    Keys: ``x`` float ``(N, T, M, 3)`` marker positions in mm (any T >= 1, any M); ``y`` int
    ``(N,)`` 0/1 (1 = slip; required unless ``require_labels=False``); optional ``groups`` ``(N,)``
    int (sequence/recording id for leak-free splits; defaults to one group per sample); optional
    ``pattern`` ``(N,)`` (int indices into ``pattern_names``, or strings), ``object`` likewise,
    ``fps`` (one positive number). Only these keys are read. Raises InputError naming the file for
    a missing file or key, wrong shapes, NaN/inf or values beyond :data:`MAX_ABS_MM` (with sample,
    frame and marker), labels other than 0/1, length mismatches, names that are not a 1-D array of
    strings and an fps that is not one positive number.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "no such file")
    try:
        with np.load(path, allow_pickle=False) as z:
            if not hasattr(z, "files"):
                raise ValueError("a single array (.npy), not an .npz archive")
            data = {}
            present = sorted(z.files)
            for k in NPZ_KEYS:  # only what is used: other arrays (object arrays too) are never read
                if k in z.files:
                    try:
                        data[k] = z[k]
                    except ValueError as exc:
                        raise InputError(path, f"array {k!r} is unreadable ({exc})") from None
    except InputError:
        raise
    except Exception as exc:  # zipfile/pickle/OS errors: all mean "not a usable npz"
        raise InputError(path, f"not a readable .npz file ({type(exc).__name__}: {exc})") from None
    if "x" not in data:
        raise InputError(path, f"missing key 'x' (marker positions (N, T, M, 3)); keys present: {present}")
    x = validate_marker_array(data["x"], path)
    n = len(x)
    y = None
    if "y" in data:
        y_raw = _per_sample(data["y"], n, "y", path)
        if not (np.issubdtype(y_raw.dtype, np.integer) or np.issubdtype(y_raw.dtype, np.bool_)
                or np.issubdtype(y_raw.dtype, np.floating)):
            raise InputError(path, f"y has dtype {y_raw.dtype}; expected integer labels 0/1")
        bad = ~np.isin(y_raw, (0, 1))
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(path, f"y must be 0 (no slip) or 1 (slip); sample {i} has {y_raw[i]!r} "
                                   f"({int(bad.sum())} bad label(s))")
        y = y_raw.astype(np.int64)
    elif require_labels:
        raise InputError(path, f"missing key 'y' (labels (N,), 0/1); keys present: {present}")
    groups = _per_sample(data["groups"], n, "groups", path) if "groups" in data else np.arange(n)
    if not np.issubdtype(groups.dtype, np.integer):
        _, groups = np.unique(groups, return_inverse=True)  # e.g. string recording names
    out = MarkerDataset(x, y, groups.astype(np.int64), fps=_fps(data["fps"], path) if "fps" in data else 20.0)
    for key, names_key, default in (("pattern", "pattern_names", PATTERNS), ("object", "object_names", OBJECTS)):
        if key not in data:
            continue
        a = _per_sample(data[key], n, key, path)
        names = _names(data[names_key], names_key, path) if names_key in data else default
        if np.issubdtype(a.dtype, np.integer):
            if a.size and (a.min() < 0 or a.max() >= len(names)):
                raise InputError(path, f"{key} indices must be in [0, {len(names)}) ({names_key}: {list(names)})")
        else:
            a = a.astype(str)
            names = tuple(dict.fromkeys([*default, *sorted(set(a.tolist()))]))
            a = np.array([names.index(s) for s in a.tolist()], np.int64)
        setattr(out, key, a.astype(np.int64))
        setattr(out, names_key, names)
    return out


def load_marker_npy(path: str | Path) -> np.ndarray:
    """Read a plain ``.npy`` of marker positions ``(N, T, M, 3)`` mm (no labels; for inference)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "no such file")
    try:
        x = np.load(path, allow_pickle=False)
    except Exception as exc:
        raise InputError(path, f"not a readable .npy file ({type(exc).__name__}: {exc})") from None
    return validate_marker_array(x, path)


# ----------------------------------------------------------------------------- figures

#: Object shown for each pattern in the figures (small contacts make the lobes visible).
FIGURE_OBJECTS = {"stationary": "tape", "pressing": "cherry_tomato", "rolling": "cherry_tomato",
                  "slipping": "cherry_tomato"}


def _draw_field(ax, X: np.ndarray, disp: np.ndarray, shape: tuple[int, int], vlim: float, arrow_scale: float):
    """z displacement as a coloured background, xy displacement as arrows (magnified)."""
    ny, nx = shape
    mesh = ax.pcolormesh(X[:, 0].reshape(ny, nx), X[:, 1].reshape(ny, nx), disp[:, 2].reshape(ny, nx),
                         cmap="RdBu_r", vmin=-vlim, vmax=vlim, shading="nearest", alpha=0.8)
    ax.quiver(X[:, 0], X[:, 1], disp[:, 0] * arrow_scale, disp[:, 1] * arrow_scale, angles="xy",
              scale_units="xy", scale=1.0, width=0.005, headwidth=3.5, color="k")
    ax.set_aspect("equal")
    ax.set_xlim(X[:, 0].min() - 0.6, X[:, 0].max() + 0.6)
    ax.set_ylim(X[:, 1].min() - 0.6, X[:, 1].max() + 0.6)
    return mesh


def plot_patterns(cfg: SimConfig, out_dir: str | Path, frames: int = 4, arrow_scale: float = 4.0) -> list[Path]:
    """One figure per pattern (``sim_<pattern>.png``) plus ``sim_objects.png``; returns the paths.

    Each pattern figure shows ``frames`` time points of one simulated sequence in a 2-column grid:
    background colour = z displacement (mm; blue = towards the cameras = indentation), arrows = xy
    displacement magnified ``arrow_scale`` times, red arrow = motion direction, green outline =
    contact. ``sim_objects.png`` shows the static footprint of each object. Written atomically.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    X = rest_grid(cfg)
    written: list[Path] = []
    shape = (cfg.markers_y, cfg.markers_x)
    gx_, gy_ = X[:, 0].reshape(shape), X[:, 1].reshape(shape)
    for pi, pattern in enumerate(PATTERNS):
        obj = FIGURE_OBJECTS[pattern]
        rng = np.random.default_rng([cfg.seed, 99, pi])
        seq, info = simulate_sequence(obj, pattern, rng, cfg, return_info=True, allow_empty=False)
        disp = displacement_field(seq, X)
        T = len(seq)
        idx = np.linspace(0, T - 1, frames).round().astype(int)
        vlim = max(float(np.abs(disp[..., 2]).max()), 0.05)
        ncol = 2
        nrow = int(math.ceil(frames / ncol))
        fig, axes = plt.subplots(nrow, ncol, figsize=(5.2 * ncol + 1.0, 5.0 * nrow), constrained_layout=True,
                                 squeeze=False)
        for ax, ti in zip(axes.ravel(), idx):
            mesh = _draw_field(ax, X, disp[ti], shape, vlim, arrow_scale)
            mask = info["contact"][ti].reshape(shape).astype(float)
            if mask.any() and not mask.all():
                ax.contour(gx_, gy_, mask, levels=[0.5], colors="limegreen", linewidths=1.5)
            if pattern in ("rolling", "slipping"):
                c = info["centre"][ti]
                e = info["direction"] * 3.0
                ax.annotate("", xy=(c[0] + e[0], c[1] + e[1]), xytext=(c[0], c[1]),
                            arrowprops=dict(arrowstyle="-|>", color="red", lw=2.5))
            title = f"t = {ti / cfg.fps:.2f} s"
            if pattern == "slipping":
                g = info["gross_slip_frame"]
                stick = info["stick"][ti].sum() / max(info["contact"][ti].sum(), 1)
                title += (" gross slip" if 0 <= g <= ti else " partial slip") + f", stick {100 * stick:.0f}%"
            ax.set_title(title, fontsize=11)
            ax.set_xlabel("x (mm)")
            ax.set_ylabel("y (mm)")
        for ax in axes.ravel()[len(idx):]:
            ax.set_visible(False)
        fig.colorbar(mesh, ax=axes, label="z displacement (mm)", shrink=0.85)
        fig.suptitle(f"{pattern}: {obj.replace('_', ' ')} (arrows: xy displacement x{arrow_scale:g})")
        path = out_dir / f"sim_{pattern}.png"
        write_with(path, lambda tmp: fig.savefig(tmp, dpi=72))
        plt.close(fig)
        written.append(path)

    fig, axes = plt.subplots(2, 3, figsize=(12, 7.6), constrained_layout=True)
    vlim = 0.0
    fields_ = []
    for oi, obj in enumerate(OBJECTS):
        rng = np.random.default_rng([cfg.seed, 98, oi])
        seq = simulate_sequence(obj, "stationary", rng, cfg, allow_empty=False)
        fields_.append(displacement_field(seq, X)[-1])
        vlim = max(vlim, float(np.abs(fields_[-1][:, 2]).max()))
    for ax, obj, disp in zip(axes.ravel(), OBJECTS, fields_):
        mesh = _draw_field(ax, X, disp, shape, vlim, arrow_scale)
        ax.set_title(obj.replace("_", " "))
    fig.colorbar(mesh, ax=axes, label="z displacement (mm)", shrink=0.8)
    fig.suptitle(f"static contact of each object (arrows x{arrow_scale:g})")
    path = out_dir / "sim_objects.png"
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=72))
    plt.close(fig)
    written.append(path)
    return written


def main(argv: list[str] | None = None) -> None:
    """``python -m slipsense.sensors.simulator --figures docs/img [--seed N]`` regenerates the figures."""
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--figures", type=Path, default=Path("docs/img"), help="folder for sim_*.png")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    for p in plot_patterns(SimConfig(seed=args.seed), args.figures):
        print(p)


if __name__ == "__main__":
    main()
