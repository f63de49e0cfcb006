"""Refraction-aware binocular reconstruction of marker positions (STNet paper, section II.A, eqs. 1-3).

Geometry (all lengths in mm, pixel coordinates in pixels)
---------------------------------------------------------
World frame ``C_w``: origin midway between the two camera centres; ``x`` along the baseline
(left camera -> right camera), ``y`` along the image rows (downwards in the image), ``z`` along
both optical axes, from the cameras towards the elastomer (right-handed, as in OpenCV). The cameras
form a rectified pair with identical intrinsics:

* left camera centre ``(-d/2, 0, 0)``, right camera centre ``(+d/2, 0, 0)``, ``d = baseline_mm``;
* pixel ``(u, v)`` (column, row) sees along ``((u - cx)/fx, (v - cy)/fy, 1)``.

Along ``+z`` there are two media::

    z = 0                 camera centres (air, index n1)
    z = h_v - h_c         flat air / acrylic interface   <- refraction happens here (normal v = +z)
    h_v - h_c < z         acrylic supporting plate + elastomer (index n2, n_r = n2 / n1)
    z = h_v               shading layer = elastomer contact surface, where the markers sit at rest

``h_v`` (paper: distance from camera to shading layer) and ``h_c`` (paper: thickness of elastomer
plus supporting plate) are the paper's symbols; plate and elastomer are taken to share one index
(the paper does the same: one interface, one ``n_r``). A deformed marker moves off ``z = h_v``;
any point with ``z > h_v - h_c`` can be reconstructed.

Reconstruction (paper eqs. 1-3): a marker pixel gives a unit ray ``e`` from its camera centre ``C``;
it meets the interface at ``C + g`` with ``g = (h_v - h_c) / |e_z| e`` (eq. 1a), refracts to the unit
direction ``w`` by Snell's law (eq. 1b), and the marker lies on ``A + lambda w``. The two rays of a
marker are skew in practice (pixel noise), so the marker is the midpoint of their common
perpendicular ``P_l P_r``: ``lambda_l, lambda_r`` solve ``(P_l - P_r) . w_l = 0`` and
``(P_l - P_r) . w_r = 0`` (eq. 3; solved here as the equivalent 2 x 2 system, in closed form,
vectorised over markers).

The simulator uses the *gel frame* (origin on the contact surface at the gel centre, same axes);
:func:`gel_to_camera` / :func:`camera_to_gel` convert between the two (a shift of ``h_v`` in z).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slipsense.errors import ConfigError, InputError

_PARALLEL_EPS = 1e-12  # 1 - cos^2 of the angle between the rays; below this they are parallel


@dataclass(frozen=True)
class SensorGeometry:
    """Intrinsics and refraction geometry of the binocular visuo-tactile sensor.

    Defaults describe a plausible build of the paper's sensor (22 x 21 mm gel): 640 x 480 px
    board cameras with ``fx = fy = 400`` px (about 77 deg horizontal field of view), a 10 mm
    baseline, the shading layer 25 mm from the cameras and 6 mm of acrylic plate + elastomer
    (``n_r = 1.41``, silicone against air). With these, every marker of the gel, indented up to
    3 mm, is seen by both cameras.

    Attributes: ``fx, fy`` focal lengths (pixels); ``cx, cy`` principal point (pixels);
    ``width_px, height_px`` image size (pixels); ``baseline_mm`` camera centre distance ``d``;
    ``h_v_mm`` camera to shading layer; ``h_c_mm`` elastomer + supporting plate thickness;
    ``n_r`` refractive ratio ``n2 / n1``.
    """

    fx: float = 400.0
    fy: float = 400.0
    cx: float = 320.0
    cy: float = 240.0
    width_px: int = 640
    height_px: int = 480
    baseline_mm: float = 10.0
    h_v_mm: float = 25.0
    h_c_mm: float = 6.0
    n_r: float = 1.41

    def __post_init__(self):
        for name in ("fx", "fy", "baseline_mm", "h_v_mm", "h_c_mm", "n_r", "width_px", "height_px"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ConfigError(f"SensorGeometry.{name} must be a positive number, got {value!r}")
        for name in ("cx", "cy"):
            if not np.isfinite(getattr(self, name)):
                raise ConfigError(f"SensorGeometry.{name} must be finite")
        if self.h_c_mm >= self.h_v_mm:
            raise ConfigError(
                f"SensorGeometry.h_c_mm ({self.h_c_mm}) must be below h_v_mm ({self.h_v_mm}): "
                "the interface must lie in front of the cameras"
            )

    @property
    def interface_z_mm(self) -> float:
        """z of the air / plate interface in the world frame (mm): ``h_v - h_c``."""
        return self.h_v_mm - self.h_c_mm

    def camera_centre(self, camera: str) -> np.ndarray:
        """Camera centre ``(3,)`` in the world frame (mm)."""
        if camera == "left":
            return np.array([-self.baseline_mm / 2, 0.0, 0.0])
        if camera == "right":
            return np.array([self.baseline_mm / 2, 0.0, 0.0])
        raise InputError(None, f"camera must be 'left' or 'right', got {camera!r}")


# ----------------------------------------------------------------------------- validation


def _points(arr, name: str, ncols: int) -> np.ndarray:
    """``arr`` as a finite float64 ``(N, ncols)`` array, else InputError naming ``name``."""
    try:
        a = np.asarray(arr, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(None, f"{name} must be a numeric array of shape (N, {ncols})") from None
    if a.ndim != 2 or a.shape[1] != ncols:
        raise InputError(None, f"{name} has shape {a.shape}; expected (N, {ncols})")
    bad = ~np.isfinite(a).all(axis=1)
    if bad.any():
        raise InputError(None, f"{name} has {int(bad.sum())} non-finite row(s) (first at index {int(np.argmax(bad))})")
    return a


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ----------------------------------------------------------------------------- frames


def gel_to_camera(geom: SensorGeometry, points) -> np.ndarray:
    """Gel-frame points ``(N, 3)`` mm (origin on the contact surface) -> world frame ``(N, 3)`` mm."""
    return _points(points, "points", 3) + np.array([0.0, 0.0, geom.h_v_mm])


def camera_to_gel(geom: SensorGeometry, points) -> np.ndarray:
    """World-frame points ``(N, 3)`` mm -> gel frame ``(N, 3)`` mm (rest surface at z = 0)."""
    return _points(points, "points", 3) - np.array([0.0, 0.0, geom.h_v_mm])


# ----------------------------------------------------------------------------- rays


def pixel_rays(geom: SensorGeometry, uv, camera: str = "left") -> tuple[np.ndarray, np.ndarray]:
    """Rays in air through pixels ``uv (N, 2)`` (column, row; pixels) of one camera.

    Returns ``(origins (N, 3) mm, dirs (N, 3) unit)`` in the world frame; every origin is the
    camera centre and every direction has ``dir_z > 0``.
    """
    centre = geom.camera_centre(camera)
    uv = _points(uv, "uv", 2)
    d = np.stack([(uv[:, 0] - geom.cx) / geom.fx, (uv[:, 1] - geom.cy) / geom.fy, np.ones(len(uv))], axis=1)
    return np.broadcast_to(centre, d.shape).copy(), _unit(d)


def refract(dirs, normal, n_r: float) -> np.ndarray:
    """Refract unit directions ``dirs (N, 3)`` at a plane with normal ``normal`` ((3,) or (N, 3)).

    Paper eq. (1b): ``w = (e + (n_r cos t2 - cos t1) v) / |...|`` with ``v`` the unit normal
    oriented along the propagation (``e . v > 0``; either orientation of ``normal`` is accepted),
    ``cos t1 = e . v`` and ``n_r sin t2 = sin t1`` (Snell), ``n_r = n2 / n1`` the ratio of the
    index after the interface to the index before it. Returns unit directions ``(N, 3)``.
    Raises InputError on total internal reflection (only possible with ``n_r < 1``).
    """
    e = _unit(_points(dirs, "dirs", 3))
    v = np.asarray(normal, dtype=np.float64)
    if v.shape not in {(3,), e.shape} or not np.isfinite(v).all():
        raise InputError(None, f"normal must be finite with shape (3,) or {e.shape}, got {v.shape}")
    v = np.broadcast_to(_unit(v), e.shape)
    if not (np.isfinite(n_r) and n_r > 0):
        raise InputError(None, f"n_r must be positive, got {n_r!r}")
    cos1 = np.einsum("ij,ij->i", e, v)
    v = v * np.sign(np.where(cos1 == 0, 1.0, cos1))[:, None]  # orient v along the ray, as in the paper
    cos1 = np.abs(cos1)
    sin2_sq = (1.0 - cos1**2) / n_r**2
    if (sin2_sq > 1.0).any():
        raise InputError(None, f"total internal reflection for {int((sin2_sq > 1).sum())} ray(s) (n_r={n_r})")
    cos2 = np.sqrt(1.0 - sin2_sq)
    return _unit(e + (n_r * cos2 - cos1)[:, None] * v)


def refracted_rays(geom: SensorGeometry, uv, camera: str = "left") -> tuple[np.ndarray, np.ndarray]:
    """Rays inside the plate/elastomer for pixels ``uv (N, 2)``.

    Returns ``(A (N, 3) mm, w (N, 3) unit)``: ``A = C + g`` is where the ray crosses the interface
    (eq. 1a) and ``w`` its refracted direction (eq. 1b); the marker lies on ``A + lambda w``.
    """
    origins, e = pixel_rays(geom, uv, camera)
    g = (geom.interface_z_mm / np.abs(e[:, 2]))[:, None] * e  # eq. (1a)
    return origins + g, refract(e, np.array([0.0, 0.0, 1.0]), geom.n_r)


def _closest_midpoint(a_l, w_l, a_r, w_r, what: str):
    """Midpoint of the common perpendicular of lines ``a_l + s w_l`` and ``a_r + t w_r`` (unit w).

    Returns ``(midpoint (N, 3), gap (N,), s (N,), t (N,))``. Perpendicularity of ``P_l - P_r`` to
    both directions gives the 2 x 2 system ``[1, -b; b, -1] [s, t] = [-w_l.r, -w_r.r]`` with
    ``r = a_l - a_r`` and ``b = w_l . w_r``.
    """
    r = a_l - a_r
    b = np.einsum("ij,ij->i", w_l, w_r)
    p = np.einsum("ij,ij->i", w_l, r)
    q = np.einsum("ij,ij->i", w_r, r)
    den = 1.0 - b**2
    parallel = den < _PARALLEL_EPS
    if parallel.any():
        raise InputError(
            None,
            f"{what}: the two rays of {int(parallel.sum())} marker(s) are near parallel "
            f"(first at index {int(np.argmax(parallel))}); the pixel pair has no usable "
            "disparity and cannot be triangulated",
        )
    s = (b * q - p) / den
    t = (q - b * p) / den
    p_l = a_l + s[:, None] * w_l
    p_r = a_r + t[:, None] * w_r
    return 0.5 * (p_l + p_r), np.linalg.norm(p_l - p_r, axis=1), s, t


def _check_pair(uv_left, uv_right):
    uv_l = _points(uv_left, "uv_left", 2)
    uv_r = _points(uv_right, "uv_right", 2)
    if len(uv_l) != len(uv_r):
        raise InputError(None, f"uv_left has {len(uv_l)} points but uv_right has {len(uv_r)}")
    return uv_l, uv_r


def reconstruct(geom: SensorGeometry, uv_left, uv_right, return_gap: bool = False):
    """3D marker positions ``(N, 3)`` mm (world frame) from matched pixels ``uv_left/right (N, 2)``.

    Refraction-aware (paper eqs. 1-3): each pixel ray is refracted at the interface and the marker
    is the midpoint of the common perpendicular of the two refracted rays. With
    ``return_gap=True`` also returns the length of that perpendicular ``(N,)`` mm (0 for a
    consistent pair; a matching-quality check). Raises InputError for non-finite input, wrong
    shapes, near-parallel rays, or rays that meet before the interface (swapped cameras).
    """
    uv_l, uv_r = _check_pair(uv_left, uv_right)
    a_l, w_l = refracted_rays(geom, uv_l, "left")
    a_r, w_r = refracted_rays(geom, uv_r, "right")
    mid, gap, s, t = _closest_midpoint(a_l, w_l, a_r, w_r, "reconstruct")
    behind = (s < 0) | (t < 0)
    if behind.any():
        raise InputError(
            None,
            f"reconstruct: the rays of {int(behind.sum())} marker(s) meet in front of the "
            f"interface (first at index {int(np.argmax(behind))}); are left and right swapped?",
        )
    return (mid, gap) if return_gap else mid


def reconstruct_without_refraction(geom: SensorGeometry, uv_left, uv_right, return_gap: bool = False):
    """Plain pinhole triangulation ignoring refraction (for comparison): ``(N, 3)`` mm, world frame.

    Same midpoint rule on the straight pixel rays. Markers come out too close to the cameras
    (the plate and elastomer make them look shallower), by about 1.7 mm with the defaults.
    """
    uv_l, uv_r = _check_pair(uv_left, uv_right)
    o_l, e_l = pixel_rays(geom, uv_l, "left")
    o_r, e_r = pixel_rays(geom, uv_r, "right")
    mid, gap, _, _ = _closest_midpoint(o_l, e_l, o_r, e_r, "reconstruct_without_refraction")
    return (mid, gap) if return_gap else mid


# ----------------------------------------------------------------------------- forward model


def _interface_offset(rho: np.ndarray, a: float, b: np.ndarray, n_r: float) -> np.ndarray:
    """Horizontal offset ``s`` (mm) of the refraction point from the camera, ``0 <= s <= rho``.

    In the vertical plane through the camera centre and the point: the camera is ``a`` above the
    interface, the point ``b`` below it and ``rho`` away horizontally. Snell's law reads
    ``f(s) = s / hypot(s, a) - n_r (rho - s) / hypot(rho - s, b) = 0``; ``f`` rises strictly from
    ``f(0) <= 0`` to ``f(rho) >= 0``, so Newton's method is safeguarded by that bracket (bisection
    whenever a Newton step leaves it) and iterated to machine precision.
    """
    lo = np.zeros_like(rho)
    hi = rho.copy()
    s = rho * a / (a + n_r * b)  # paraxial solution: a good start
    for _ in range(100):
        ha = np.hypot(s, a)
        hb = np.hypot(rho - s, b)
        f = s / ha - n_r * (rho - s) / hb
        df = a**2 / ha**3 + n_r * b**2 / hb**3
        lo = np.where(f < 0, s, lo)
        hi = np.where(f > 0, s, hi)
        step = f / df
        new = s - step
        outside = (new < lo) | (new > hi)  # a step that stays put (converged) is not "outside"
        new = np.where(outside, 0.5 * (lo + hi), new)
        done = np.abs(new - s) <= 4 * np.finfo(float).eps * np.maximum(rho, 1.0)
        s = new
        if done.all():
            break
    return s


def project(geom: SensorGeometry, points) -> tuple[np.ndarray, np.ndarray]:
    """Pixels ``(uv_left (N, 2), uv_right (N, 2))`` at which world points ``(N, 3)`` mm are seen.

    Forward model of :func:`reconstruct`: for each camera, finds the point on the interface where
    the ray to the marker refracts (1-D root find of Snell's law in the vertical plane through the
    camera centre and the marker, see :func:`_interface_offset`) and projects the air segment with
    the pinhole model. Points must lie beyond the interface (``z > h_v - h_c``). Pixels outside
    the image are returned as computed (see :func:`in_image`).
    """
    pts = _points(points, "points", 3)
    a = geom.interface_z_mm
    b = pts[:, 2] - a
    if (b <= 0).any():
        raise InputError(
            None,
            f"project: {int((b <= 0).sum())} point(s) lie in front of the interface "
            f"(z <= h_v - h_c = {a} mm; first at index {int(np.argmax(b <= 0))})",
        )
    out = []
    for camera in ("left", "right"):
        c = geom.camera_centre(camera)
        dxy = pts[:, :2] - c[:2]
        rho = np.linalg.norm(dxy, axis=1)
        s = _interface_offset(rho, a, b, geom.n_r)
        # direction in air: horizontal offset s along dxy / rho, vertical a
        scale = np.divide(s, rho, out=np.zeros_like(rho), where=rho > 0)
        ex, ey = dxy[:, 0] * scale, dxy[:, 1] * scale
        out.append(np.stack([geom.cx + geom.fx * ex / a, geom.cy + geom.fy * ey / a], axis=1))
    return out[0], out[1]


def in_image(geom: SensorGeometry, uv) -> np.ndarray:
    """``(N,)`` bool: pixel ``uv (N, 2)`` falls inside the ``width_px x height_px`` image."""
    uv = _points(uv, "uv", 2)
    return (uv[:, 0] >= 0) & (uv[:, 0] <= geom.width_px - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= geom.height_px - 1)
