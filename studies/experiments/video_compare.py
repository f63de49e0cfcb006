"""Experiment ``video-compare`` (ViViT paper, III-B): ViViT vs 3D ResNet-50 on held-out objects —
parameters, training time, batch-1 inference rate and held-out scores."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from slipsense.errors import ConfigError, InputError
from studies.experiments.report import Report
from studies.experiments.resnet_weights import load_weights
from studies.experiments.settings import Settings
from studies.experiments.source import DataSource, clip_spec, held_out_objects, object_split
from studies.experiments.training import (
    clip_datasets,
    inference_rate,
    metric_cols,
    score,
    train_model,
    train_seconds,
    video_info,
)


MODELS = ("vivit", "resnet3d50")


def run_video_compare(
    settings: Settings,
    source=None,
    resnet_weights: str | Path | None = None,
    inference_clips: int = 50,
    models: Sequence[str] = MODELS,
) -> dict[str, Any]:
    """ViViT vs 3D ResNet-50 (from scratch, or from ``resnet_weights``) trained on the training
    objects, scored on the held-out objects: parameters, training time, batch-1 inference rate,
    accuracy/precision/recall/F1. ``models``: which of the two (the 3D ResNet-50 at the paper's
    setting needs an accelerator: each can be run in a report of its own)."""
    unknown = sorted(set(models) - set(MODELS))
    if unknown or not models:
        raise ConfigError(f"--models takes {' and/or '.join(MODELS)}, got {', '.join(models) or 'none'}")
    source = source or DataSource(progress=settings.progress)
    rep = Report("video-compare", settings, source)
    test_objects = held_out_objects(source, settings)
    spec = clip_spec(settings)
    clips = source.clips(spec)
    tr, te, present = object_split(clips, test_objects)
    train, test = clip_datasets(clips, tr, te, settings)
    size = tuple(clips.x.shape[2:4])
    del clips
    rep.config.update(
        clip_spec=asdict(spec),
        test_objects=present,
        n_train_clips=len(tr),
        n_test_clips=len(te),
        n_train_items=len(train),
        resnet_weights=str(resnet_weights) if resnet_weights else None,
        inference_clips=inference_clips,
    )
    rows = []
    histories = {}

    for name in [m for m in MODELS if m in models]:
        before = None
        takes_weights = name == "resnet3d50"  # studies/experiments/resnet_weights.py (pytorchvideo layout)
        if takes_weights and resnet_weights is not None:

            def before(model, path=Path(resnet_weights)):
                try:
                    load_weights(model, path)
                except InputError:
                    load_weights(model, path, skip_head=True)  # e.g. Kinetics-400 weights: keep a 2-class head

        model, history = train_model(
            name,
            name,
            train,
            settings,
            rep,
            {"frames": spec.frames, "image_size": size},
            before_fit=before,
            info=video_info(source, spec, present),
        )
        histories[name] = history
        m = score(model, test)
        rate = inference_rate(model, test, n=inference_clips)
        rep.models[name]["inference"] = rate
        rows.append(
            {
                "model": name,
                "parameters": rep.models[name]["parameters"],
                "epochs": len(history),
                "train_seconds": train_seconds(history),
                "inference_clips_per_s": rate["clips_per_s"],
                **{k: m[k] for k in metric_cols()},
                "n_test": m["n_clips"],
                "n_test_slip": m["n_slip"],
                "initialisation": ("user weights" if takes_weights and resnet_weights else "random"),
            }
        )
        del model
    rep.notes.append(f"Held-out objects (fold {settings.fold} of {settings.folds}): {', '.join(present)}.")
    rep.notes.append(
        "3D ResNet-50 is trained from scratch unless --resnet-weights is given (no pretrained video "
        "weights are available here)."
    )
    rep.notes.append("Inference rate: clips per second at batch 1 with the trained model, inputs already in memory.")

    def figure(plt):
        fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
        x = np.arange(4)
        for i, r in enumerate(rows):
            axes[0].bar(x + (i - 0.5) * 0.38, [r[k] for k in metric_cols()], 0.38, label=r["model"])
        axes[0].set_xticks(x, metric_cols())
        axes[0].set_ylim(0, 1)
        axes[0].set_title("held-out objects")
        axes[0].legend()
        names = [r["model"] for r in rows]
        colours = ["tab:blue", "tab:orange"][: len(rows)]
        axes[1].bar(names, [r["train_seconds"] / 60 for r in rows], color=colours)
        axes[1].set_ylabel("training time (min)")
        axes[2].bar(names, [r["inference_clips_per_s"] for r in rows], color=colours)
        axes[2].set_yscale("log")
        axes[2].set_ylabel("clips / s (batch 1)")
        for ax in axes:
            ax.grid(axis="y", alpha=0.3)
        return fig

    curves = [{"model": n, **r} for n, h in histories.items() for r in h]
    curve_cols = ["model", "epoch", "lr", "train_loss", "train_accuracy", "seconds"]
    paths = rep.write(
        rows, None, figure, extra_tables={"curves": (curves, curve_cols)}, models_in_setting=tuple(histories)
    )
    return {"rows": rows, "paths": paths}
