"""Experiment ``all-models`` (beyond the papers): ViViT, 3D ResNet-50, STNet and TemNet trained and
scored on the same windows — video clips for the video models, the matching tracked-marker
sequences (:func:`match_windows`) for the others."""

from __future__ import annotations

from dataclasses import asdict
from typing import Any, Sequence

import numpy as np

from slipsense.errors import ConfigError
from slipsense.models import model_class
from studies.experiments.report import Report
from studies.experiments.settings import Settings
from studies.experiments.source import DataSource, clip_spec, held_out_objects, object_split
from studies.experiments.training import clip_datasets, metric_cols, score, train_model, train_seconds, video_info


def match_windows(
    meta: Sequence[dict[str, Any]], arrays: dict[str, np.ndarray], y: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, int]:
    """Pair clips with marker sequences of the same window: same (object, experiment, camera, start).

    Args:
        meta: the clips' metadata (``ClipSet.meta``).
        arrays: marker windows as :func:`slipsense.marker_sequences.real_marker_dataset` returns them.
        y: the clips' labels; pairs whose labels disagree with the marker window's are dropped.

    Returns:
        ``(clip indices, marker indices, number of pairs dropped for disagreeing labels)``.
    """
    where = {}
    for j, key in enumerate(
        zip(
            np.asarray(arrays["groups"]).astype(str).tolist(),
            np.asarray(arrays["experiment"]).tolist(),
            np.asarray(arrays["camera"]).astype(str).tolist(),
            np.asarray(arrays["start"]).tolist(),
        )
    ):
        where[(key[0], int(key[1]), key[2], int(key[3]))] = j
    ci, mi = [], []
    for i, m in enumerate(meta):
        j = where.get((str(m["object"]), int(m["experiment"]), str(m["camera"]), int(m["start"])))
        if j is not None:
            ci.append(i)
            mi.append(j)
    ci, mi = np.asarray(ci, np.int64), np.asarray(mi, np.int64)
    dropped = 0
    if y is not None and len(ci):
        same = np.asarray(y)[ci] == np.asarray(arrays["y"])[mi]
        dropped = int((~same).sum())
        ci, mi = ci[same], mi[same]
    return ci, mi, dropped


def run_all_models(
    settings: Settings, source=None, frames: int = 5, n_markers: int = 32, preset: str = "compact"
) -> dict[str, Any]:
    """ViViT, 3D ResNet-50, STNet and TemNet trained on the same training windows and scored on the
    same held-out windows (video clips for the video models, marker sequences for the others)."""
    from slipsense.datasets import MarkerDataset

    source = source or DataSource(progress=settings.progress)
    rep = Report("all-models", settings, source)
    test_objects = held_out_objects(source, settings)
    spec = clip_spec(settings, frames=frames)
    clips = source.clips(spec)
    arrays = source.markers(
        frames=frames,
        n_markers=n_markers,
        horizon=0,
        wiggle_per_video=settings.wiggle_per_video,
        seed=settings.data_seed,
    )
    ci, mi, n_disagree = match_windows(clips.meta, arrays, clips.y)
    if len(ci) == 0:
        raise ConfigError("no window has both a video clip and a marker sequence")
    clips_m = clips.subset(ci)
    n_clip_windows = len(clips)
    mx, my = arrays["x"][mi], np.asarray(arrays["y"])[mi]
    del clips
    tr, te, present = object_split(clips_m, test_objects)
    vtrain, vtest = clip_datasets(clips_m, tr, te, settings)
    mtrain, mtest = (
        MarkerDataset(mx[tr], my[tr], copies=settings.copies_of_markers, seed=settings.seed),
        MarkerDataset(mx[te], my[te]),
    )
    rep.config.update(
        clip_spec=asdict(spec),
        n_markers=n_markers,
        preset=preset,
        test_objects=present,
        matched_windows=int(len(ci)),
        clip_windows=int(n_clip_windows),
        marker_windows=int(len(arrays["y"])),
        label_disagreements=n_disagree,
        n_train=int(len(tr)),
        n_test=int(len(te)),
    )
    rows = []
    size = tuple(clips_m.x.shape[2:4])
    for name, train, test, dcfg, pre in (
        ("vivit", vtrain, vtest, {"frames": frames, "image_size": size}, None),
        ("resnet3d50", vtrain, vtest, {"frames": frames, "image_size": size}, None),
        ("stnet", mtrain, mtest, {"frames": frames, "markers": n_markers}, preset),
        ("temnet", mtrain, mtest, {"frames": frames, "markers": n_markers}, preset),
    ):
        model, history = train_model(
            name,
            name,
            train,
            settings,
            rep,
            dcfg,
            preset=pre,
            info=video_info(source, spec, present, windows="matched clip/marker windows"),
        )
        m = score(model, test)
        rows.append(
            {
                "model": name,
                "input": model_class(name).clip_reader.describes,
                "preset": pre or "paper",
                "parameters": rep.models[name]["parameters"],
                "epochs": len(history),
                **{k: m[k] for k in metric_cols()},
                "n_test": m["n_clips"],
                "n_test_slip": m["n_slip"],
                "train_seconds": train_seconds(history),
            }
        )
        del model
    rep.notes.append(
        f"{len(ci)} windows have both a clip and a marker sequence (same object, experiment, camera, "
        f"start frame; {frames} frames); {len(tr)} train, {len(te)} held-out "
        f"({', '.join(present)}). Windows of runs whose labels were overridden by hand have no "
        f"marker sequence and are left out."
    )
    rep.notes.append(f"Marker models: {n_markers} tracked GelSight markers, preset {preset}.")

    def figure(plt):
        fig, ax = plt.subplots(figsize=(9, 4))
        x = np.arange(4)
        w = 0.8 / len(rows)
        for i, r in enumerate(rows):
            ax.bar(x + (i - (len(rows) - 1) / 2) * w, [r[k] for k in metric_cols()], w, label=r["model"])
        ax.set_xticks(x, metric_cols())
        ax.set_ylim(0, 1)
        ax.grid(axis="y", alpha=0.3)
        ax.legend()
        return fig

    paths = rep.write(rows, None, figure, models_in_setting=("vivit", "resnet3d50", "stnet", "temnet"))
    return {"rows": rows, "paths": paths}
