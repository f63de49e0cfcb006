"""One simulated marker sequence: object motion per pattern, the gel's response, noise
(:func:`simulate_sequence`).

Deformation model (per frame, on the rest marker positions ``X``; details in studies/docs/simulator.md)
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
  projected into both cameras with the refraction model (:mod:`studies.stnet.stereo`), pixel
  noise is added and the markers are reconstructed again: the depth-dominated error of a real
  binocular sensor.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from slipsense.errors import ConfigError
from studies.stnet.sim_model import (
    OBJECTS,
    PATTERNS,
    SimConfig,
    _coverage_norm,
    _isotropic_kernels,
    _penetration,
    _sample_object,
    _shear_kernel,
    _spread,
    _u,
    rest_grid,
)
from studies.stnet.stereo import camera_to_gel, gel_to_camera, project, reconstruct


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
    innov = math.sqrt(fs) * np.einsum("mk,tkc->tmc", modes, rng.normal(size=(T, modes.shape[1], 3))) + math.sqrt(
        1 - fs
    ) * rng.normal(size=(T, M, 3))
    out = np.empty_like(innov)
    rho = cfg.noise_corr
    out[0] = innov[0]
    for t in range(1, T):
        out[t] = rho * out[t - 1] + math.sqrt(1 - rho**2) * innov[t]  # stationary unit variance
    return sigma * out


def simulate_sequence(
    obj_name: str,
    pattern: str,
    rng: np.random.Generator,
    cfg: SimConfig,
    return_info: bool = False,
    allow_empty: bool = True,
):
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
    params.update(
        depth_mm=depth, shear_limit_mm=kappa_limit, relax_s=relax, direction=direction.tolist(), empty=bool(empty)
    )

    point, sub = _penetration(obj, delta, centres, X[:, :2], cfg)
    cell = sub.mean(-1)  # cell-averaged penetration: the normal load on each marker's cell
    coverage = (sub > 0).mean(-1)  # fraction of each cell in contact
    cn, cl, gx, gy = _isotropic_kernels(
        cfg.markers_x, cfg.markers_y, cfg.gel_x_mm, cfg.gel_y_mm, cfg.normal_decay_mm, cfg.lateral_decay_mm
    )
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
    info = {
        "object": obj_name,
        "pattern": pattern,
        "params": params,
        "direction": direction,
        "centre": centres,
        "depth": delta,
        "contact": point > 0,
        "stick": stick,
        "gross_slip_frame": gross,
        "noise_mm": sigma,
    }
    return out, info


def _stereo_round_trip(pos: np.ndarray, rng, cfg: SimConfig) -> np.ndarray:
    """Project ``(T, M, 3)`` gel-frame positions into both cameras, add pixel noise, reconstruct."""
    geom = cfg.geometry
    flat = gel_to_camera(geom, pos.reshape(-1, 3))
    uv_l, uv_r = project(geom, flat)
    uv_l = uv_l + rng.normal(scale=cfg.pixel_noise_px, size=uv_l.shape)
    uv_r = uv_r + rng.normal(scale=cfg.pixel_noise_px, size=uv_r.shape)
    return camera_to_gel(geom, reconstruct(geom, uv_l, uv_r)).reshape(pos.shape)
