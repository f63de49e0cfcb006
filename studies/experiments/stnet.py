"""Experiment ``stnet`` (STNet paper, Table II and Fig. 7): STNet vs TemNet on simulated marker
sequences (split by sequence) and on real tracked GelSight markers (held-out objects)."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from slipsense.errors import ConfigError
from slipsense.recordings.splits import ObjectHoldOut
from studies.experiments.report import Report
from studies.experiments.settings import Settings
from studies.experiments.source import DataSource, held_out_objects
from studies.experiments.training import epoch_axis, score, train_model, train_seconds

#: Simulated sequences per (object, pattern): full and quick.
SIM_SEQUENCES = 24
QUICK_SIM_SEQUENCES = 2


def simulated_dataset(
    settings: Settings,
    sequences: int | None = None,
    overrides: dict[str, Any] | None = None,
    test_fraction: float = 0.2,
):
    """The simulated :class:`~slipsense.sensors.marker_npz.MarkerDataset` and a split by sequence:
    ``test_fraction`` of the sequences of each motion pattern are held out (all windows of a sequence
    on one side; every pattern on both). Returns ``(dataset, train indices, test indices, info)``."""
    from studies.stnet.simulator import SimConfig, make_dataset

    n = sequences if sequences is not None else (QUICK_SIM_SEQUENCES if settings.quick else SIM_SEQUENCES)
    cfg = SimConfig(seed=settings.data_seed, n_sequences=n, **(overrides or {}))
    ds = make_dataset(cfg, progress=settings.progress)
    groups = np.asarray(ds.groups)
    # each pattern's sequences held out on their own (the pattern as the stratum), as the clips' split does
    tr, te = next(ObjectHoldOut(test_fraction, settings.data_seed).split(groups, ds.pattern))
    sim_info = {
        "n_sequences": n,
        "seed": settings.data_seed,
        "test_fraction": test_fraction,
        "n_test_sequences": len(np.unique(groups[te])),
        **(overrides or {}),
    }
    return ds, tr, te, sim_info


def _where_it_looks(model, x, y, te, rest, rep, label: str, n: int = 256) -> dict[str, float]:
    """The paper's Fig. 8 claim, measured on simulated windows ``x`` (``rest``: where the simulator's
    markers sit at rest): the share of the slip class's
    marker relevance on the markers in contact, over up to ``n`` held-out slip windows, against the
    share of markers in contact; and the heat map of one of them (``saliency-<label>.png``)."""
    from studies.experiments.heatmaps import marker_saliency_figure, relevance_in_contact

    slips = te[y[te] == 1]
    if len(slips) == 0:
        return {}
    pick = slips[np.linspace(0, len(slips) - 1, min(n, len(slips))).round().astype(int)]
    out = relevance_in_contact(model, x[pick], rest)
    marker_saliency_figure(model, x[slips[len(slips) // 2]], rest[:, :2], rep.out / f"saliency-{label}.png", label)
    return {k: out[k] for k in ("relevance_in_contact", "markers_in_contact")}


def _per_grasp(model, info, source, train_objects: Sequence[str], test_objects: Sequence[str]) -> dict[str, Any]:
    """A real-marker model judged as the default detector is: every run of the held-out objects
    replayed from its first frame, both fingers (alarm when either camera's window says slip), at
    the operating point chosen on the training objects' runs replayed the same way (best warned
    rate minus false-positive rate, as for the papers' clip models)."""
    from slipsense.measures import pergrasp
    from slipsense.measures import operating_points
    from slipsense.streaming.detector import SlipDetector

    det = SlipDetector(model.eval(), sensors=2, info=info)
    fit_runs = source.replay(det, train_objects)
    fps = fit_runs[0].fps if fit_runs else det.sensor.fps  # the traces count the recordings' frames
    op = operating_points.choose_operating_point(
        [r.probability for r in fit_runs], [r.moment_of_slip for r in fit_runs], fps=fps
    )
    runs = source.replay(det, test_objects)
    s = pergrasp.summarise([r.outcome(op["threshold"], op["debounce"]) for r in runs], [r.fps for r in runs])
    return {
        "grasp_threshold": f"{op['threshold']:g} x{op['debounce']}",
        "warned_in_time": f"{s['warned']}/{s['slip_runs']}",
        "premature": s["premature"],
        "false_positive_grasps": f"{s['false_positive_grasps']}/{s['held_runs']}",
        "runs_alarming_at_rest": s["runs_alarming_at_rest"],
    }


def run_stnet(
    settings: Settings,
    source=None,
    data: Sequence[str] = ("sim", "real"),
    preset: str = "compact",
    sim_sequences: int | None = None,
    sim_overrides: dict[str, Any] | None = None,
    markers: str | int = "7x9",
    frames: int = 12,
) -> dict[str, Any]:
    """STNet vs TemNet (``preset``): precision/recall/F1 and per-epoch accuracy/loss, on simulated
    sequences (split by sequence) and on real marker sequences (held-out objects)."""
    from slipsense.datasets import MarkerDataset
    from slipsense.models import stnet as stnet_mod
    from slipsense.recordings.markers import layout_name, marker_layout
    from studies.stnet.sim_model import rest_grid
    from studies.stnet.simulator import SimConfig

    if preset not in stnet_mod.PRESETS:
        raise ConfigError(f"unknown preset {preset!r}; known: {sorted(stnet_mod.PRESETS)}")
    data = list(data)
    if not data or any(d not in ("sim", "real") for d in data):
        raise ConfigError("--data must name sim, real or both")
    n_markers, grid = marker_layout(markers)
    layout_id = layout_name(markers)
    if "real" in data:
        source = source or DataSource(progress=settings.progress)
    rep = Report("stnet", settings, source if "real" in data else None)
    rep.config.update(preset=preset, preset_config=stnet_mod.PRESETS[preset], data=data)
    rows, curves = [], []
    for kind in data:
        if kind == "sim":
            ds, tr, te, sim_info = simulated_dataset(settings, sim_sequences, sim_overrides)
            x, y = ds.x, ds.y
            rest = rest_grid(SimConfig(**(sim_overrides or {})))
            rep.config["simulation"] = sim_info
            split_note = (
                "20 % of the simulated sequences of each motion pattern (all windows of a sequence on one side)"
            )
        else:
            test_objects = held_out_objects(source, settings)
            arrays = source.markers(
                frames=frames,
                n_markers=layout_id,
                horizon=0,
                wiggle_per_video=settings.wiggle_per_video,
                seed=settings.data_seed,
            )
            x, y, groups = arrays["x"], arrays["y"], np.asarray(arrays["groups"]).astype(str)
            is_test = np.isin(groups, test_objects)
            tr, te = np.flatnonzero(~is_test), np.flatnonzero(is_test)
            if len(te) == 0 or len(tr) == 0:
                raise ConfigError("the real marker windows do not split into training and held-out objects")
            present = sorted(set(groups[te].tolist()))
            rep.config["real"] = {
                "frames": frames,
                "n_markers": n_markers,
                "marker_layout": layout_id,
                "test_objects": present,
            }
            split_note = f"held-out objects {', '.join(present)}"
        rep.config[f"{kind}_split"] = {"n_train": len(tr), "n_test": len(te), "test": split_note}
        train, test = (
            MarkerDataset(x[tr], y[tr], copies=settings.copies_of_markers, seed=settings.seed),
            MarkerDataset(x[te], y[te]),
        )
        data_config = {"frames": int(x.shape[1]), "markers": int(x.shape[2])}
        # the checkpoint says what it read: real markers are taken from a video alike when it is replayed
        info = {"data": {"source": kind, "kind": "markers"}}  # simulated: the binocular sensor
        if kind == "real":
            info = {"data": {"source": kind, "clip_spec": {"marker_layout": layout_id}}}
        for name in ("stnet", "temnet"):
            model, history = train_model(
                name,
                f"{kind}-{name}",
                train,
                settings,
                rep,
                data_config,
                val_data=test,
                preset=preset,
                info=info,
            )
            m = score(model, test)
            looks = _where_it_looks(model, x, y, te, rest, rep, f"{kind}-{name}") if kind == "sim" else {}
            if kind == "real" and hasattr(source, "replay"):
                train_objects = sorted(set(groups[tr].tolist()))
                looks = _per_grasp(model, info, source, train_objects, test_objects)
            rows.append(
                {
                    "data": "simulated" if kind == "sim" else "real",
                    "model": name,
                    "preset": preset,
                    "parameters": rep.models[f"{kind}-{name}"]["parameters"],
                    "epochs": len(history),
                    "precision": m["precision"],
                    "recall": m["recall"],
                    "f1": m["f1"],
                    "accuracy": m["accuracy"],
                    "loss": m["loss"],
                    "n_train": len(tr),
                    "n_test": m["n_clips"],
                    "n_test_slip": m["n_slip"],
                    "train_seconds": train_seconds(history),
                    **looks,
                }
            )
            for r in history:
                curves.append(
                    {
                        "data": rows[-1]["data"],
                        "model": name,
                        "epoch": r["epoch"],
                        "train_loss": r["train_loss"],
                        "train_accuracy": r["train_accuracy"],
                        "test_loss": r.get("val_loss"),
                        "test_accuracy": r.get("val_accuracy"),
                    }
                )
            del model
        del x, y
    cfg = settings.train_config("stnet", preset)
    paper = stnet_mod.STNet.paper_training
    rep.notes.append(
        f"Preset: {preset} ({'the paper-size network' if preset.startswith('paper') else 'not the paper size; --preset paper for it'}); "
        f"STNet trained with Adam, lr {cfg.lr:g}, batch {cfg.batch_size}, {cfg.epochs} epochs "
        f"(the paper: lr {paper['lr']:g}, batch {paper['batch_size']}, {paper['epochs']} epochs); "
        + (
            f"each training window seen with {settings.copies_of_markers - 1} mirrored and shifted copies where the markers lie on a grid."
            if settings.copies_of_markers > 1
            else "no copies of the training windows (as the paper)."
        )
    )
    if "real" in data:
        layout = (
            f"every tracked GelSight marker (35 or 62-80 per pad) resampled onto a {grid[0]} x {grid[1]} grid"
            if grid
            else f"the {n_markers} tracked GelSight markers nearest the image centre"
        )
        rep.notes.append(
            f"Real data: {layout} per frame (x, y in mm, intensity depth proxy), {frames}-frame windows cut "
            f"like the video clips; the paper's sensor has 552 markers with stereo depth."
        )
        if hasattr(source, "replay"):
            rep.notes.append(
                "Real data per grasp: every run of the held-out objects replayed from its first frame, both "
                "fingers (alarm when either camera's latest window says slip), at the threshold and debounce "
                "chosen on the training objects' runs replayed the same way (best warned rate minus "
                "false-positive rate; on runs it trained on, so optimistic); warned in time = first alarm "
                "at most 50 frames before the moment of slip."
            )

    def figure(plt):
        fig, axes = plt.subplots(len(data), 2, figsize=(11, 3.6 * len(data)), squeeze=False)
        for i, kind in enumerate(data):
            dname = "simulated" if kind == "sim" else "real"
            for j, key in enumerate(("accuracy", "loss")):
                ax = axes[i, j]
                for name, color in (("stnet", "tab:blue"), ("temnet", "tab:orange")):
                    cs = [c for c in curves if c["data"] == dname and c["model"] == name]
                    ax.plot(
                        [c["epoch"] for c in cs],
                        [c[f"train_{key}"] for c in cs],
                        color=color,
                        ls="--",
                        label=f"{name} train",
                    )
                    ax.plot([c["epoch"] for c in cs], [c[f"test_{key}"] for c in cs], color=color, label=f"{name} test")
                ax.set_title(f"{dname}: {key}")
                epoch_axis(ax)
                ax.legend(fontsize=8)
        return fig

    cols = [
        "data",
        "model",
        "preset",
        "parameters",
        "epochs",
        "precision",
        "recall",
        "f1",
        "accuracy",
        "loss",
        "n_train",
        "n_test",
        "n_test_slip",
        "train_seconds",
        "relevance_in_contact",
        "markers_in_contact",
        "grasp_threshold",
        "warned_in_time",
        "premature",
        "false_positive_grasps",
        "runs_alarming_at_rest",
    ]
    paths = rep.write(
        rows, cols, figure, extra_tables={"curves": (curves, None)}, models_in_setting=("stnet", "temnet")
    )
    return {"rows": rows, "curves": curves, "paths": paths}
