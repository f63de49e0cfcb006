"""``python -m studies velocity``: how well the gel gives the object's motion against it
(:mod:`slipsense.sensors.gel_motion`: translation, rotation rate, the share that sticks), where the
truth is known and where it is only implied.

(a) The STNet study's simulator moves objects at known velocities: the settings are chosen on
    sequences of one seed, the speed, direction and stick-share errors measured during gross slip on
    sequences of another; objects that do not slide (stationary, pressing, rolling without sliding)
    say how much slip is read where there is none.
(b) gelsight-lift beside its outside camera (:mod:`studies.lift_reference`): each object left out in
    turn, the settings chosen on the other four by how the per-grasp peak ranks slipped above held
    grasps; on the held-out object the per-grasp ranking (ROC AUC) and the per-frame rank correlation
    (Spearman) between the gel's relative speed and the outside camera's.
(c) The GelSight Mini recordings (the wiggle protocol): each held grasp's peak over its whole wiggle
    against each slipped grasp's peak over its last second before contact is lost (per-grasp AUC),
    with the shipped settings (chosen on no GelSight Mini grasp); and speed over time of two grasps.
(d) The detector family on it (``slip-velocity``) beside the others, from their own reports.
"""

from __future__ import annotations

import json
import math
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from slipsense.atomic import write_text
from slipsense.measures.slipped_or_held import roc_auc
from slipsense.sensors import gel_motion
from slipsense.sensors.gel_motion import CloudMotionStream, GelMotionStream
from slipsense.sensors.spec import GELSIGHT_LIFT, STARTUP_FRAMES
from studies.stnet.sim_model import OBJECTS, SimConfig
from studies.stnet.sim_sequence import simulate_sequence

#: (a) the settings tried on the tuning seed: seconds of fit window, mm of indentation floor.
WINDOWS, FLOORS = (0.2, 0.4), (0.05, 0.15, 0.3)
TUNING_SEED, TEST_SEED = 1, 2
#: (a) mm/s: a reading at or above this is slip (the stick tolerance of a marker sensor).
SLIP_FLOOR_MM_S = gel_motion.STICK_TOLERANCE_MM_S
#: (b) the settings tried on four lift objects: contact floor (grey levels), lag (s), the prior of no
#: motion (grey levels per working px).
CONTACT_FLOORS, LAGS, PRIORS = (6.0, 10.0, 16.0), (0.04, 0.07, 0.1), (0.0, 0.3, 1.0)
#: (b) seconds of contact after which every frame in contact must carry a value.
SETTLE_S = 0.2
#: (c) seconds before the loss of contact a slipped grasp is judged on.
LAST_S = 1.0


def _angle(v: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Signed angle (degrees, -180..180) from direction ``d`` to each velocity ``v`` (n, 2)."""
    a = np.degrees(np.arctan2(v[:, 1], v[:, 0]) - math.atan2(d[1], d[0]))
    return (a + 180.0) % 360.0 - 180.0


def _spread(values) -> dict:
    v = np.asarray(values, np.float64)
    if not len(v):
        return {"mean": None, "mean_abs": None, "p2.5": None, "p97.5": None, "n": 0}
    return {
        "mean": float(v.mean()),
        "mean_abs": float(np.abs(v).mean()),
        "p2.5": float(np.percentile(v, 2.5)),
        "p97.5": float(np.percentile(v, 97.5)),
        "n": int(len(v)),
    }


def spearman(a, b) -> float:
    """Spearman's rank correlation of two equal-length series (average ranks for ties); NaN under 3."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if len(a) < 3:
        return float("nan")

    def ranks(x):
        order = np.argsort(x, kind="mergesort")
        r = np.empty(len(x))
        r[order] = np.arange(len(x))
        _, tie, counts = np.unique(x, return_inverse=True, return_counts=True)
        return (np.bincount(tie, r) / counts)[tie]  # tied values share their mean rank

    ra, rb = ranks(a), ranks(b)
    ra, rb = ra - ra.mean(), rb - rb.mean()
    den = math.sqrt(float(ra @ ra) * float(rb @ rb))
    return float(ra @ rb / den) if den > 0 else float("nan")


# ---- (a) the simulator ----------------------------------------------------------------------------


def _simulated(seed: int, per_object: int, window_s: float, floor_mm: float, patterns=("slipping",)) -> dict:
    """Per pattern: errors during gross slip (slipping) or the slip read where nothing slides."""
    cfg = SimConfig(seed=seed)
    rng = np.random.default_rng(seed)
    out: dict = {
        p: {"speed_error": [], "angle_error": [], "stick_error": [], "speed": [], "by_object": {}} for p in patterns
    }
    for obj in OBJECTS:
        for pattern in patterns:
            errors = []
            for _ in range(per_object):
                clouds, info = simulate_sequence(obj, pattern, rng, cfg, return_info=True)
                stream = CloudMotionStream(cfg.fps, window_s, floor_mm)
                motions = [stream.push(c) for c in clouds]
                v = np.array([[np.nan, np.nan] if m.translation is None else m.translation for m in motions])
                if pattern != "slipping":
                    out[pattern]["speed"] += [m.speed for m in motions if m.speed is not None]
                    continue
                gross = info["gross_slip_frame"]
                if gross < 0:
                    continue
                # from the first frame whose whole window lies in gross slip
                first = gross + int(round(window_s * cfg.fps))
                after = v[first:]
                keep = ~np.isnan(after[:, 0])
                truth, direction = info["params"]["speed_mm_s"], np.asarray(info["direction"])
                err = np.linalg.norm(after[keep], axis=1) - truth
                errors += err.tolist()
                out[pattern]["speed_error"] += err.tolist()
                out[pattern]["angle_error"] += _angle(after[keep], direction).tolist()
                # the stick share against the simulator's: contact points not slipping
                contact, stick = info["contact"], info["stick"]
                for i, m in enumerate(motions[first:], start=first):
                    if m.stick is not None and contact[i].any():
                        out[pattern]["stick_error"].append(m.stick - float(stick[i][contact[i]].mean()))
            if pattern == "slipping":
                out[pattern]["by_object"][obj] = float(np.mean(np.abs(errors))) if errors else None
    return out


def simulated_study(per_object: int = 8) -> dict:
    """(a): the settings chosen on the tuning seed by mean absolute speed error, figures on the test seed."""
    tried = []
    for w in WINDOWS:
        for f in FLOORS:
            r = _simulated(TUNING_SEED, max(2, per_object // 2), w, f)["slipping"]
            tried.append(
                {"window_s": w, "floor_mm": f, "mean_abs_speed_error": float(np.mean(np.abs(r["speed_error"])))}
            )
    best = min(tried, key=lambda t: t["mean_abs_speed_error"])
    test = _simulated(
        TEST_SEED, per_object, best["window_s"], best["floor_mm"], ("slipping", "stationary", "pressing", "rolling")
    )
    slip = test["slipping"]
    still = {p: np.asarray(test[p]["speed"]) for p in ("stationary", "pressing", "rolling")}
    return {
        "tuning_seed": TUNING_SEED,
        "test_seed": TEST_SEED,
        "tried": tried,
        "chosen": best,
        "speed_error_mm_s": _spread(slip["speed_error"]),
        "angle_error_deg": _spread(np.abs(slip["angle_error"])),
        "stick_share_error": _spread(slip["stick_error"]),
        "mean_abs_speed_error_by_object": slip["by_object"],
        "speed_seen_mm_s": {p: _spread(v) for p, v in still.items()},
        "slip_floor_mm_s": SLIP_FLOOR_MM_S,
        "below_slip_floor": {p: float((v < SLIP_FLOOR_MM_S).mean()) if len(v) else None for p, v in still.items()},
        "sequences_per_object": per_object,
    }


# ---- (b) gelsight-lift beside its outside camera -------------------------------------------------


def _lift_traces(gelsight: Path, settings: list[tuple[float, float]]) -> dict:
    """One grasp's gel speed per frame (NaN without a value) and contact share, for each setting."""
    from studies.lift_reference import read_frames

    frames = read_frames(gelsight)
    out = {}
    for floor, lag, prior in settings:
        stream = GelMotionStream(GELSIGHT_LIFT.fps, None, lag_s=lag, contact_floor=floor, prior_gradient=prior)
        motions = [stream.push(f) for f in frames]
        out[(floor, lag, prior)] = (
            np.array([np.nan if m is None or m.speed is None else m.speed for m in motions]),
            np.array([0.0 if m is None else m.contact for m in motions]),
        )
    return out


def _peak(x: np.ndarray) -> float:
    return float(np.nanmax(x)) if np.isfinite(x).any() else 0.0  # no value at all: no slip seen


def _aligned(reference: np.ndarray, lag: int) -> np.ndarray:
    """The outside camera's per-frame speed averaged over the frames a gel reading at that frame spans."""
    out = np.full(len(reference), np.nan)
    for i in range(len(reference)):
        window = reference[max(1, i - lag + 1) : i + 1]
        if len(window) and np.isfinite(window).any():
            out[i] = np.nanmean(window)
    return out


def lift_study(root: Path) -> dict:
    """(b): leave-objects-out settings, per-grasp ranking, per-frame agreement with the outside camera."""
    from studies.lift_reference import lift_grasps, reference_motion

    grasps = lift_grasps(root)
    settings = [(f, lag, prior) for f in CONTACT_FLOORS for lag in LAGS for prior in PRIORS]
    traces = [_lift_traces(g.gelsight, settings) for g in grasps]
    refs = [reference_motion(g.external, GELSIGHT_LIFT.fps) for g in grasps]
    slipped = np.array([g.slipped for g in grasps])
    objects = np.array([g.object for g in grasps])
    peaks = {s: np.array([_peak(t[s][0]) for t in traces]) for s in settings}
    folds, held_out_peak, frames_gel, frames_ref = [], np.zeros(len(grasps)), [], []
    missing, in_contact = 0, 0
    for obj in sorted(set(objects)):
        test = objects == obj
        # the setting that ranks the other objects' grasps best; ties to the shipped one, then the first
        shipped = (gel_motion.CONTACT_FLOOR, gel_motion.LAG_S, gel_motion.PRIOR_GRADIENT)
        score = {s: roc_auc(peaks[s][~test], slipped[~test]) for s in settings}
        best = max(settings, key=lambda s: (round(score[s], 6), s == shipped))
        held_out_peak[test] = peaks[best][test]
        # a reading spans its lag and its median's frames: the reference is averaged over as many
        lag = max(1, int(round(best[1] * GELSIGHT_LIFT.fps))) + int(round(gel_motion.SMOOTH_S * GELSIGHT_LIFT.fps))
        fold_gel, fold_ref = [], []
        for i in np.flatnonzero(test):
            speed, contact = traces[i][best]
            ref = _aligned(np.asarray(refs[i]["relative_speed"], float), lag)
            keep = np.isfinite(speed) & np.isfinite(ref)
            fold_gel += speed[keep].tolist()
            fold_ref += ref[keep].tolist()
            touching = np.flatnonzero(contact > 0)
            if len(touching):
                settled = touching[touching >= touching[0] + int(round(SETTLE_S * GELSIGHT_LIFT.fps))]
                in_contact += len(settled)
                missing += int(np.isnan(speed[settled]).sum())
        frames_gel += fold_gel
        frames_ref += fold_ref
        folds.append(
            {
                "object": obj,
                "contact_floor": best[0],
                "lag_s": best[1],
                "prior_gradient": best[2],
                "training_auc": score[best],
                "auc": roc_auc(held_out_peak[test], slipped[test]) if len(set(slipped[test])) == 2 else None,
                "spearman": spearman(fold_gel, fold_ref),
                "frames": len(fold_gel),
            }
        )
    ref_peaks = np.array([np.nan_to_num(np.nanmax(r["relative_speed"]) if r["usable"] else 0.0) for r in refs])
    return {
        "grasps": len(grasps),
        "unit": "px/s",
        "auc": roc_auc(held_out_peak, slipped),
        "spearman": spearman(frames_gel, frames_ref),
        "frames_compared": len(frames_gel),
        "reference_auc": roc_auc(ref_peaks, slipped),
        "reference_usable": int(sum(r["usable"] for r in refs)),
        "settled_frames_in_contact": in_contact,
        "settled_frames_without_value": missing,
        "median_peak_px_s": {
            "slipped": float(np.median(held_out_peak[slipped])),
            "held": float(np.median(held_out_peak[~slipped])),
        },
        # the shipped settings were chosen on all five objects: in-sample, shown beside, never the figure
        "shipped_setting_auc_in_sample": roc_auc(
            peaks[(gel_motion.CONTACT_FLOOR, gel_motion.LAG_S, gel_motion.PRIOR_GRADIENT)], slipped
        ),
        "folds": folds,
        "per_grasp": [
            {"object": g.object, "grasp": g.grasp, "slipped": bool(g.slipped), "peak_px_s": float(p)}
            for g, p in zip(grasps, held_out_peak)
        ],
    }


# ---- (c) the GelSight Mini ------------------------------------------------------------------------


def _mini_trace(path: str, sensor) -> np.ndarray:
    """``(T, 2)``: one finger's speed (mm/s, NaN without a value) and stick share per frame."""
    import cv2

    from slipsense.recordings.video import read_video
    from slipsense.sensors.gel_motion import motion_stream

    cv2.setNumThreads(1)
    frames = read_video(path, expected_size=None)
    stream = motion_stream(sensor, frames[0], STARTUP_FRAMES)
    out = []
    for f in frames:
        m = stream.push(f)
        out.append((np.nan, np.nan) if m is None or m.speed is None else (m.speed, m.stick))
    return np.asarray(out, np.float64)


def mini_study(root: Path, out: Path, workers: int = 2) -> dict:
    """(c): per grasp, held wiggles against the slipped grasps' last second; a figure of two grasps."""
    from functools import partial

    from slipsense.recordings.recording_set import Recordings

    data = Recordings.open(root).labelled(whole_runs=False, progress=False)  # as the sensor the data states
    labels, runs, fps = data.labels, data.runs(), data.sensor.fps
    paths = [str(r.path) for recs in runs.values() for r in recs]
    # spawned, not forked: OpenCV's threads of the sections before would deadlock a forked worker
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        traces = dict(zip(paths, pool.map(partial(_mini_trace, sensor=data.sensor), paths, chunksize=4)))
    last = int(round(LAST_S * fps))
    rows = []
    for key, recs in sorted(runs.items()):
        label = labels[(recs[0].object, recs[0].experiment, recs[0].camera)]
        speed = np.stack([traces[str(r.path)][:, 0] for r in recs])  # (fingers, T)
        fastest = np.where(np.isfinite(speed).any(0), np.nanmax(np.where(np.isfinite(speed), speed, -1), 0), np.nan)
        moment = label.moment_of_slip
        if moment is not None:  # the last second before contact is lost
            seen = fastest[max(STARTUP_FRAMES, moment - last) : moment + 1]
        else:  # the whole wiggle: the contact phase the labeller found
            start = STARTUP_FRAMES if label.contact_start is None else max(STARTUP_FRAMES, label.contact_start)
            seen = fastest[start : (len(fastest) if label.contact_end is None else label.contact_end + 1)]
        rows.append(
            {
                "object": recs[0].object,
                "experiment": recs[0].experiment,
                "slipped": moment is not None,
                "peak_mm_s": _peak(seen),
                "frames_with_value": int(np.isfinite(seen).sum()),
            }
        )
    y = np.array([r["slipped"] for r in rows])
    p = np.array([r["peak_mm_s"] for r in rows])
    figure = _mini_figure(runs, labels, traces, fps, out)
    return {
        "runs": len(rows),
        "slipped": int(y.sum()),
        "held": int((~y).sum()),
        "auc": roc_auc(p, y),
        "median_peak_mm_s": {"slipped": float(np.median(p[y])), "held": float(np.median(p[~y]))},
        "figure": figure,
        "per_grasp": rows,
    }


def _mini_figure(runs, labels, traces, fps: float, out: Path, slipped=("blue_mug", 9), held_object="blue_mug") -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    picked = {
        "slipped": next(recs for k, recs in sorted(runs.items()) if (recs[0].object, recs[0].experiment) == slipped)
    }
    picked["held"] = next(
        recs for k, recs in sorted(runs.items()) if recs[0].object == held_object and not recs[0].slipped
    )
    fig, axes = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
    shown = {}
    for ax, (what, recs) in zip(axes, picked.items()):
        for rec in recs:
            v = traces[str(rec.path)][:, 0]
            ax.plot(np.arange(len(v)) / fps, v, label=rec.camera)
        moment = labels[(recs[0].object, recs[0].experiment, recs[0].camera)].moment_of_slip
        if moment is not None:
            ax.axvline(moment / fps, color="k", ls="--", label="contact lost")
        ax.set_title(f"{what}: {recs[0].object}, experiment {recs[0].experiment}")
        ax.set_ylabel("speed against the gel (mm/s)")
        ax.legend(loc="upper left")
        shown[what] = {"object": recs[0].object, "experiment": recs[0].experiment, "moment_of_slip": moment}
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(out / "gelsight-mini-speed.png", dpi=90)
    plt.close(fig)
    return shown


# ---- (d) the family ---------------------------------------------------------------------------------

#: The reports section (d) reads: the family's and the shipped recipe's 5 folds, and the adaptation study.
FAMILY_REPORT, SHIPPED_REPORT, ADAPTATION_REPORT = (
    "reports/grasp-slip-velocity",
    "reports/grasp-motionnet-k5",
    "reports/adaptation",
)


def family_study(root: Path) -> dict:
    """(d): what the family's reports and the shipped detector's say, side by side."""

    def pooled(report: str) -> dict:
        g = json.loads((root / report / "folds.json").read_text())["pooled"]["per_grasp"]
        keys = ("warned", "slip_runs", "premature", "missed", "false_positive_grasps", "held_runs")
        return {k: g[k] for k in keys}

    rows = json.loads((root / ADAPTATION_REPORT / "adaptation.json").read_text())["rows"]

    def row(prefix: str) -> dict:
        r = next(r for r in rows if r["row"].startswith(prefix))
        return {"accuracy": r["operating_point"]["accuracy"]["value"], "roc_auc": r["roc_auc"]["value"]}

    return {
        "gelsight_mini": {"slip-velocity": pooled(FAMILY_REPORT), "motionnet (shipped)": pooled(SHIPPED_REPORT)},
        "gelsight_lift": {"slip-velocity": row("slip velocity"), "shear-retention (shipped)": row("shear retention")},
    }


def _family_markdown(d: dict) -> list[str]:
    mini = d["gelsight_mini"]
    lines = [
        "## (d) The detector family `slip-velocity` beside the shipped detectors",
        "",
        f"From the family's own reports, made with the footprint's speed over the gel that this report's "
        f"motion replaces (GelSight Mini, 5 folds by object at the shipped rule: `{FAMILY_REPORT}`, "
        f"`{SHIPPED_REPORT}`; gelsight-lift, each object left out: `{ADAPTATION_REPORT}`):",
        "",
        "| detector | slips warned in time | premature | missed | held grasps alarming |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, g in mini.items():
        lines.append(
            f"| `{name}` | {g['warned']} of {g['slip_runs']} | {g['premature']} | {g['missed']} "
            f"| {g['false_positive_grasps']} of {g['held_runs']} |"
        )
    lift = d["gelsight_lift"]
    lines += [
        "",
        "gelsight-lift, each object held out: "
        + "; ".join(f"`{k}` {v['accuracy']:.1%} balanced accuracy, ROC AUC {v['roc_auc']:.3f}" for k, v in lift.items())
        + ".",
    ]
    return lines


# ---- the report -------------------------------------------------------------------------------------


def _f(x, digits: int = 2) -> str:
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def markdown(doc: dict) -> str:
    sim, lift, mini = doc["simulated"], doc["lift"], doc["mini"]
    e, a, k = sim["speed_error_mm_s"], sim["angle_error_deg"], sim["stick_share_error"]
    c = sim["chosen"]
    lines = [
        "## (a) Simulated marker sensor: known velocities",
        "",
        f"Settings chosen on seed {sim['tuning_seed']} (window {c['window_s']:g} s, indentation floor "
        f"{c['floor_mm']:g} mm, by mean absolute speed error); figures on seed {sim['test_seed']}, "
        f"{sim['sequences_per_object']} sequences per object and pattern, during gross slip (object speeds 2-8 mm/s).",
        "",
        "| during gross slip | mean | mean absolute | 95% range | readings |",
        "|---|---:|---:|---:|---:|",
        f"| speed error (mm/s) | {_f(e['mean'])} | {_f(e['mean_abs'])} | {_f(e['p2.5'])} to {_f(e['p97.5'])} | {e['n']} |",
        f"| direction error (degrees) | | {_f(a['mean_abs'], 1)} | {_f(a['p2.5'], 1)} to {_f(a['p97.5'], 1)} | {a['n']} |",
        f"| stick share error | {_f(k['mean'])} | {_f(k['mean_abs'])} | {_f(k['p2.5'])} to {_f(k['p97.5'])} | {k['n']} |",
        "",
        "Mean absolute speed error by object (mm/s): "
        + ", ".join(f"{o} {_f(v)}" for o, v in sim["mean_abs_speed_error_by_object"].items())
        + ". Long objects (pen, bottle, tape) touch along a line longer than the gel: sliding along it moves "
        "no footprint the gel can see, and a marker sensor sees no texture of the object.",
        "",
        f"Where nothing slides: speed read (mm/s; mean, 97.5th percentile) and the share of readings below the "
        f"slip floor of {_f(sim['slip_floor_mm_s'], 1)} mm/s:",
        "",
        "| pattern | mean | 97.5th percentile | below the floor | readings |",
        "|---|---:|---:|---:|---:|",
        *[
            f"| {p} | {_f(s['mean'])} | {_f(s['p97.5'])} | {_f(100 * (sim['below_slip_floor'][p] or 0), 1)}% | {s['n']} |"
            for p, s in sim["speed_seen_mm_s"].items()
        ],
        "",
        "## (b) gelsight-lift beside its outside camera",
        "",
        f"{lift['grasps']} grasps; each object left out in turn, the contact floor, lag and prior chosen on the other four "
        f"(lengths in px/s: the sensor states no pixel size). The per-grasp peak of the gel's relative speed "
        f"ranks a slipped grasp above a held one at ROC AUC **{_f(lift['auc'], 3)}** (median peak "
        f"{_f(lift['median_peak_px_s']['slipped'], 1)} slipped, {_f(lift['median_peak_px_s']['held'], 1)} held); "
        f"per frame it agrees with the outside camera's relative speed (averaged over the same frames) at "
        f"Spearman **{_f(lift['spearman'], 2)}** over {lift['frames_compared']} frames. The outside camera alone "
        f"ranks the grasps at AUC {_f(lift['reference_auc'], 3)} ({lift['reference_usable']} of {lift['grasps']} "
        f"grasps with the fingers found; docs/lift-reference.md). The shipped settings, chosen on all five "
        f"objects (in-sample, not a figure of unseen objects): AUC {_f(lift['shipped_setting_auc_in_sample'], 3)}. Frames in contact after its first "
        f"{SETTLE_S:g} s without a value: {lift['settled_frames_without_value']} of {lift['settled_frames_in_contact']}.",
        "",
        "| held-out object | contact floor | lag (s) | prior | AUC on the other four | AUC | Spearman | frames |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
        *[
            f"| {f['object']} | {f['contact_floor']:g} | {f['lag_s']:g} | {f['prior_gradient']:g} | "
            f"{_f(f['training_auc'], 3)} | "
            f"{_f(f['auc'], 3)} | {_f(f['spearman'])} | {f['frames']} |"
            for f in lift["folds"]
        ],
        "",
        "## (c) GelSight Mini: held wiggles against the last second of a slip",
        "",
        f"{mini['runs']} grasps ({mini['slipped']} slipped, {mini['held']} held), the shipped settings (chosen on no "
        f"GelSight Mini grasp). Each held grasp's peak speed against the gel over its whole wiggle (the contact "
        f"phase the labeller found) against each slipped grasp's peak over its last {LAST_S:g} s before contact is lost, "
        f"the faster finger: per-grasp ROC AUC **{_f(mini['auc'], 3)}** (median peak "
        f"{_f(mini['median_peak_mm_s']['slipped'])} mm/s slipped, {_f(mini['median_peak_mm_s']['held'])} mm/s held).",
        "",
        "![speed against the gel of a slipped and a held grasp](gelsight-mini-speed.png)",
        "",
        "Slipped: {object}, experiment {experiment}; held: {h[object]}, experiment {h[experiment]}.".format(
            **mini["figure"]["slipped"], h=mini["figure"]["held"]
        ),
        "",
        *_family_markdown(doc["family"]),
    ]
    return "\n".join(lines)


def velocity_study(data: Path, out: Path, per_object: int = 8, workers: int = 2) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    doc = {"simulated": simulated_study(per_object), "lift": lift_study(data)}
    doc["mini"] = mini_study(data / "gelsight-slip", out, workers)
    doc["family"] = family_study(Path.cwd())
    write_text(out / "velocity.json", json.dumps(doc, indent=1))
    return doc
