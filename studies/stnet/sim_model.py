"""Simulator configuration and the static model of the gel and the objects.

:class:`SimConfig`, the rest marker grid (:func:`rest_grid`), the elastomer's response kernels
and the objects' shapes and penetration into the gel. The model is described in
:mod:`studies.stnet.sim_sequence`, which moves the objects and computes the marker
displacements, and in studies/docs/simulator.md.
"""

# SimConfig.validate recognises range fields by their annotation string "Range", so annotations
# must stay unevaluated here.
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from slipsense.errors import ConfigError, InputError
from slipsense.sensors.marker_npz import OBJECTS, PATTERNS
from slipsense.sensors.spec import fps_problem
from studies.stnet.stereo import SensorGeometry

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
        need(fps_problem(self.fps) is None, f"fps: {fps_problem(self.fps)}")
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
        r_theta = obj["radius"] * (
            1 + sum(a * np.cos((k + 2) * theta + ph) for k, (a, ph) in enumerate(zip(obj["harmonics"], obj["phases"])))
        )
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
