"""The object's motion against the fingers, frame by frame, seen by the outside camera of gelsight-lift.

A reference from outside the gel (``gelsight-lift-external``, see docs/lift-reference.md): the camera
rides with the gripper, so the fingers hold still in its image and an object that slips moves
against them. For one grasp this gives, between each frame and the one before it, the object's
translation (px/s), its rotation in the image plane (rad/s) and one relative speed (px/s), from dense
optical flow on the object between the fingers less the flow on the fingers themselves.

    python -m studies.lift_reference [--root DATA] [--json OUT.json]

prints every grasp's peak relative speed and how well it ranks slipped above held grasps (ROC AUC).
Nothing here was tuned on the GelSight frames.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from slipsense.measures.slipped_or_held import roc_auc
from slipsense.paths import data_root
from slipsense.recordings.frame_folders import RESULT_SUFFIX, read_result_file
from slipsense.sensors.gel_motion import rigid_fit as weighted_rigid_fit
from slipsense.sensors.spec import GELSIGHT_LIFT

FRAME_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp")

# The left (GelSight) finger is teal, lit by the sensor's LEDs; OpenCV HSV (hue 0-180).
TEAL_HUE, TEAL_MIN_SAT, TEAL_MIN_VAL = (75, 105), 90, 60
MIN_FINGER_AREA = 500  # px: a finger, not a teal speck on the object
TIP_WIDTH = 10  # px: the columns of the teal finger's tip whose rows give the pad's height
# The right finger is black: the first run of this many mostly dark columns right of the gap.
DARK_MAX_VAL, DARK_RUN, DARK_FILL = 60, 25, 0.6
# The object's box stops short of the fingers: the GelSight's elastomer on the left, the black
# finger's white pad on the right (by eye on the external frames).
LEFT_MARGIN, RIGHT_MARGIN = 6, 9
FINGER_BOX = 30  # px of each finger beside the gap whose flow is the fingers' own motion
FINGER_INSET = 3  # px back from its tip: a finger that shifts a little leaves no gap in its box
HUBER_PX = 1.0  # px/frame: flow farther than this from the rigid fit counts less (background, glare)
FIT_ROUNDS = 5
_ARRAYS = ("translation", "speed", "omega", "relative_speed", "finger_motion", "residual")
_VECTORS = ("translation", "finger_motion")  # (n, 2); the others (n,)


@dataclass(frozen=True)
class Region:
    """Where one grasp's object and fingers are in its external frames (px, boxes [x0, x1) x [y0, y1))."""

    object_box: tuple[int, int, int, int]  # x0, y0, x1, y1: the object between the pads
    left_finger_box: tuple[int, int, int, int]
    right_finger_box: tuple[int, int, int, int]
    left_tip: int  # x of the teal finger's tip
    right_tip: int  # x of the black finger's inner edge
    lever: float  # px: RMS distance of the object box's pixels from its centre


class LiftGrasp(NamedTuple):
    object: str
    grasp: str  # the grasp's folder name, e.g. 068_00_mm
    slipped: bool
    gelsight: Path
    external: Path


def lift_grasps(root: str | Path | None = None) -> list[LiftGrasp]:
    """Every grasp named by the ``gelsight-lift/*_result.dat`` files under ``root`` (the data folder,
    default :func:`slipsense.paths.data_root`), read with the project's own reader."""
    root = Path(root) if root is not None else data_root()
    lift, external = root / "gelsight-lift", root / "gelsight-lift-external"
    grasps = []
    for result in sorted(lift.glob(f"*{RESULT_SUFFIX}")):
        obj = result.name[: -len(RESULT_SUFFIX)]
        for name, slipped in read_result_file(result).items():
            # column 7 names the folder without its "_mm" (068_00 for 068_00_mm); accept either
            folder = name if (lift / obj / name).is_dir() else f"{name}_mm"
            grasps.append(LiftGrasp(obj, folder, slipped, lift / obj / folder, external / obj / folder))
    return grasps


def read_frames(folder: str | Path) -> list[np.ndarray]:
    """A folder's frames (BGR), in the order of their names (the names carry zero-padded numbers)."""
    files = sorted(p for p in Path(folder).iterdir() if p.suffix.lower() in FRAME_SUFFIXES)
    if len(files) < 2:
        raise ValueError(f"{folder}: needs at least 2 frames, found {len(files)}")
    frames = []
    for f in files:
        img = cv2.imread(str(f), cv2.IMREAD_COLOR)
        if img is None:
            raise ValueError(f"{f}: not a readable image")
        frames.append(img)
    if len({f.shape for f in frames}) != 1:
        raise ValueError(f"{folder}: frames differ in size")
    return frames


def find_region(image: np.ndarray) -> Region | None:
    """The object's box between the fingers in a BGR image of the external camera, from the fingers'
    positions; None where a finger is not found. The box spans the columns between the pads and the
    rows of the GelSight's pad: the object's points at the contact. (Rows above it let background in
    where the object is narrower than the grip, and the gripper's lift moves the background.)"""
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    h, s, v = (hsv[..., i].astype(np.int32) for i in range(3))
    teal = (h >= TEAL_HUE[0]) & (h <= TEAL_HUE[1]) & (s > TEAL_MIN_SAT) & (v > TEAL_MIN_VAL)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(teal.astype(np.uint8))
    if n < 2 or stats[1:, cv2.CC_STAT_AREA].max() < MIN_FINGER_AREA:
        return None
    ys, xs = np.nonzero(labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA])))
    left = int(np.percentile(xs, 99.5))  # not the max: a stray pixel would move the tip
    tip = xs >= left - TIP_WIDTH
    top, bottom = (int(r) for r in np.percentile(ys[tip], [2, 98]))
    # The black finger is widest and darkest just below its hooked tip, level with the pad's bottom;
    # the object's own dark parts (a bottle's band, a barcode, a tube's end) are narrower than it.
    band = slice(max(bottom - 20, 0), min(bottom + 20, image.shape[0]))
    dark_cols = (v[band] < DARK_MAX_VAL).mean(axis=0) > DARK_FILL
    runs = np.convolve(dark_cols, np.ones(DARK_RUN), "valid")
    starts = [c for c in range(left + TIP_WIDTH, len(runs)) if runs[c] == DARK_RUN]
    if not starts:
        return None
    right = starts[0]
    x0, x1 = left + LEFT_MARGIN, right - RIGHT_MARGIN
    if x1 - x0 < 10 or bottom - top < 20:
        return None
    yy, xx = np.mgrid[top:bottom, x0:x1]
    lever = float(np.sqrt(((xx - xx.mean()) ** 2 + (yy - yy.mean()) ** 2).mean()))
    return Region(
        object_box=(x0, top, x1, bottom),
        left_finger_box=(max(left - FINGER_INSET - FINGER_BOX, 0), top, left - FINGER_INSET, bottom),
        right_finger_box=(
            right + FINGER_INSET,
            band.start,
            min(right + FINGER_INSET + FINGER_BOX, image.shape[1]),
            band.stop,
        ),
        left_tip=left,
        right_tip=right,
        lever=lever,
    )


def rigid_fit(flow: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Least-squares rigid motion (vx, vy, omega) of flow vectors (N, 2) at points x, y (N,), the
    points' coordinates from their centre: flow = v + omega * (-y, x). Huber weights (:data:`HUBER_PX`) keep a few wrong
    vectors (background in the box, glare) from pulling the fit."""
    w = np.ones(len(x))
    points = np.stack([x, y], 1)
    for _ in range(FIT_ROUNDS):
        vx, vy, om = weighted_rigid_fit(points, flow, w, (0.0, 0.0))
        r = np.hypot(flow[:, 0] - (vx - om * y), flow[:, 1] - (vy + om * x))
        w = np.minimum(1.0, HUBER_PX / np.maximum(r, 1e-9))
    return float(vx), float(vy), float(om)


def _box(a: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    x0, y0, x1, y1 = box
    return a[y0:y1, x0:x1]


def _nan_arrays(n: int) -> dict[str, np.ndarray]:
    return {k: np.full((n, 2) if k in _VECTORS else n, np.nan) for k in _ARRAYS}


def motion_between(frames: list[np.ndarray], region: Region, fps: float) -> dict:
    """The object's motion against the fingers, per frame, in frames (BGR or grey) and a region.
    Frame 0 has no frame before it: NaN there."""
    grey = [f if f.ndim == 2 else cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f in frames]
    n = len(grey)
    # DIS: dense, fast, and on these frames it ranked slipped above held best of the flows tried
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    x0, y0, x1, y1 = region.object_box
    yy, xx = np.mgrid[y0:y1, x0:x1].astype(float)
    px, py = (xx - xx.mean()).ravel(), (yy - yy.mean()).ravel()
    out = _nan_arrays(n)
    for t in range(1, n):
        flow = dis.calc(grey[t - 1], grey[t], None)
        # each finger's median, averaged: the camera's own motion at the gap between them
        fingers = np.mean(
            [
                np.median(_box(flow, b).reshape(-1, 2), axis=0)
                for b in (region.left_finger_box, region.right_finger_box)
            ],
            axis=0,
        )
        rel = _box(flow, region.object_box).reshape(-1, 2) - fingers
        vx, vy, om = rigid_fit(rel, px, py)
        fitted = np.stack([vx - om * py, vy + om * px], axis=1)
        out["translation"][t] = (vx * fps, vy * fps)
        out["omega"][t] = om * fps
        out["finger_motion"][t] = fingers * fps
        out["residual"][t] = np.sqrt(((rel - fitted) ** 2).sum(1).mean()) * fps
    out["speed"] = np.hypot(out["translation"][:, 0], out["translation"][:, 1])
    # the RMS speed of the box's points under the fitted motion: translation and rotation at the contact
    out["relative_speed"] = np.hypot(out["speed"], out["omega"] * region.lever)
    return out


def reference_motion(external_folder: str | Path, fps: float = GELSIGHT_LIFT.fps) -> dict:
    """One grasp's reference from its external frames.

    Returns ``speed`` (n,) px/s, the object's translation speed against the fingers; ``translation``
    (n, 2) px/s, image axes (x right, y down), at the centre of the object's box; ``omega`` (n,)
    rad/s, in the image plane, positive clockwise as the image is seen; ``relative_speed`` (n,) px/s,
    the RMS speed of the box's points (translation and rotation); ``finger_motion`` (n, 2) px/s, the
    fingers' own motion taken off; ``residual`` (n,) px/s, the flow no rigid motion explains. Frame 0
    is NaN in each. Also ``region`` (a dict of :class:`Region`, None where the fingers are not
    found), ``usable`` (a region was found; otherwise every array is NaN), ``fps`` and ``frames``.
    """
    frames = read_frames(external_folder)
    # the fingers hold still, the object may not: find them in the median of a few frames
    few = frames[:: max(1, len(frames) // 5)]
    region = find_region(np.median(np.stack(few), axis=0).astype(np.uint8))
    arrays = _nan_arrays(len(frames)) if region is None else motion_between(frames, region, fps)
    return {
        **arrays,
        "region": asdict(region) if region else None,
        "usable": region is not None,
        "fps": float(fps),
        "frames": len(frames),
    }


def peak(series: np.ndarray) -> float:
    """A grasp's peak of one per-frame series, e.g. ``relative_speed`` (NaN where it has none)."""
    values = np.asarray(series, float)
    return float(np.nanmax(values)) if np.isfinite(values).any() else float("nan")


def evaluate(root: str | Path | None = None, fps: float = GELSIGHT_LIFT.fps) -> dict:
    """Every grasp's peak relative speed, and its ROC AUC slipped against held, overall and per object."""
    rows = []
    for g in lift_grasps(root):
        started = time.perf_counter()
        if g.external.is_dir():
            m = reference_motion(g.external, fps)
        else:  # a grasp the outside camera did not record: no region, counted as not usable
            m = {"usable": False, **_nan_arrays(1)}
        rows.append(
            {
                "object": g.object,
                "grasp": g.grasp,
                "slipped": g.slipped,
                "usable": m["usable"],
                "peak_relative_speed": peak(m["relative_speed"]),
                "peak_speed": peak(m["speed"]),
                "peak_omega": peak(np.abs(m["omega"])),
                "path": float(np.nansum(m["relative_speed"]) / fps),  # px travelled at the contact
                "seconds": time.perf_counter() - started,
            }
        )
    used = [r for r in rows if r["usable"]]

    def auc(rs: list[dict], key: str) -> float:
        return roc_auc(np.array([r[key] for r in rs]), np.array([r["slipped"] for r in rs]))

    keys = ("peak_relative_speed", "peak_speed", "peak_omega", "path")
    return {
        "grasps": len(rows),
        "usable": len(used),
        "auc": {k: auc(used, k) for k in keys},
        "auc_per_object": {
            o: {k: auc([r for r in used if r["object"] == o], k) for k in keys}
            for o in sorted({r["object"] for r in rows})
        },
        "seconds_per_grasp": float(np.mean([r["seconds"] for r in rows])) if rows else float("nan"),
        "rows": rows,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m studies.lift_reference", description=__doc__.split("\n")[0])
    parser.add_argument("--root", type=Path, default=None, help="data folder (default: $SLIPSENSE_DATA)")
    parser.add_argument("--fps", type=float, default=GELSIGHT_LIFT.fps)
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args(argv)
    result = evaluate(args.root, args.fps)
    if not result["grasps"]:
        print(f"no gelsight-lift grasps under {args.root or data_root()}", file=sys.stderr)
        return 1
    for r in result["rows"]:
        label = "slipped" if r["slipped"] else "held"
        print(
            f"{r['object']} {r['grasp']:<11} {label:<7} peak {r['peak_relative_speed']:6.1f} px/s  "
            f"(translation {r['peak_speed']:6.1f} px/s, |omega| {r['peak_omega']:.2f} rad/s)  "
            f"path {r['path']:5.1f} px{'' if r['usable'] else '  NO REGION'}"
        )
    a = result["auc"]
    print(
        f"\n{result['usable']} of {result['grasps']} grasps with a usable region; "
        f"{result['seconds_per_grasp']:.2f} s per grasp"
    )
    print(
        f"ROC AUC slipped vs held, peak relative speed {a['peak_relative_speed']:.3f} "
        f"(peak translation {a['peak_speed']:.3f}, peak |omega| {a['peak_omega']:.3f}, path {a['path']:.3f})"
    )
    for o, v in result["auc_per_object"].items():
        print(f"  {o}: peak relative speed {v['peak_relative_speed']:.3f}, path {v['path']:.3f}")
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
