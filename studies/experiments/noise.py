"""Experiment ``noise`` (ViViT paper, Fig. 8): a ViViT (a checkpoint, or one trained here) on the
held-out objects under Gaussian noise of several standard deviations."""

from __future__ import annotations

import math
from dataclasses import asdict
from pathlib import Path
from typing import Any, Sequence

from slipsense.errors import ConfigError, InputError
from studies.experiments.report import Report
from studies.experiments.settings import Settings
from studies.experiments.source import DataSource, clip_spec, held_out_objects, object_split
from studies.experiments.training import clip_datasets, metric_cols, score, train_model, video_info

DEFAULT_NOISE_STDS = (0.0, 5.0, 10.0, 15.0, 20.0, 30.0, 50.0)


def run_noise(
    settings: Settings, source=None, checkpoint: str | Path | None = None, stds: Sequence[float] = DEFAULT_NOISE_STDS
) -> dict[str, Any]:
    """A ViViT (``checkpoint``, or one trained here on the training objects) on the held-out objects
    with Gaussian noise of each std (0..255 scale) added to every frame."""
    from slipsense.datasets import ClipDataset

    if any((not math.isfinite(s)) or s < 0 for s in stds):
        raise ConfigError("noise stds must be finite numbers >= 0")
    source = source or DataSource(progress=settings.progress)
    rep = Report("noise", settings, source)
    if checkpoint is not None:
        from slipsense.checkpoint import load_model
        from slipsense.data import clip_spec_from

        model, info = load_model(checkpoint)
        if not model.clip_reader.pictures:
            raise InputError(checkpoint, f"noise needs a video model, this checkpoint holds {info['model']!r}")
        data = info.get("data", {})
        spec = clip_spec_from(data) if "clip_spec" in data else clip_spec(settings)
        ck_objects = data.get("test_objects") or []
        test_objects = sorted(ck_objects) if ck_objects else held_out_objects(source, settings)
        if not ck_objects:
            rep.notes.append(
                "The checkpoint does not name its held-out objects: make sure it never trained on "
                "the ones evaluated here."
            )
        clips = source.clips(spec)
        _, te, present = object_split(clips, test_objects)
        rep.add_model(model.model_name, model, checkpoint=str(checkpoint))  # whichever video model it holds
        rep.config.update(checkpoint=str(checkpoint), trained_here=False, checkpoint_train=info.get("train"))
        trained = info.get("train", {})
        rep.notes.append(
            f"Model: checkpoint {checkpoint} ({info['model']}, clips {spec.size[0]}x{spec.size[1]}, "
            f"{spec.frames} frames, trained {info.get('epoch', trained.get('epochs', '?'))} epochs); "
            f"the setting line above describes this command, the model's training is the checkpoint's."
        )
        import torch

        dev = settings.device if settings.device != "auto" else ("cuda" if torch.cuda.is_available() else "cpu")
        model.to(dev)
    else:
        test_objects = held_out_objects(source, settings)
        spec = clip_spec(settings)
        clips = source.clips(spec)
        tr, te, present = object_split(clips, test_objects)
        train, _ = clip_datasets(clips, tr, te, settings)
        model, _ = train_model(
            "vivit",
            "vivit",
            train,
            settings,
            rep,
            {"frames": spec.frames, "image_size": tuple(clips.x.shape[2:4])},
            info=video_info(source, spec, present),
        )
        rep.config.update(checkpoint=str(settings.out / "runs" / "vivit" / "last.safetensors"), trained_here=True)
    held = clips.subset(te)
    rep.config.update(clip_spec=asdict(spec), test_objects=present, stds=list(stds), n_heldout=len(held))
    rows = []
    for s in stds:
        m = score(model, ClipDataset(held, noise_std=float(s), seed=settings.seed))
        rows.append(
            {"noise_std": float(s), **{k: m[k] for k in metric_cols()}, "loss": m["loss"], "n_clips": m["n_clips"]}
        )
    rep.notes.append(
        f"Held-out objects: {', '.join(present)}. Noise: N(0, std^2) per pixel and channel on the "
        f"0..255 scale, rounded and clipped (the training augmentation uses std 15)."
    )

    def figure(plt):
        fig, ax = plt.subplots(figsize=(6.5, 4))
        xs = [r["noise_std"] for r in rows]
        for key in ("accuracy", "f1"):
            ax.plot(xs, [r[key] for r in rows], marker="o", label=key)
        ax.set_xlabel("noise std (0..255 scale)")
        ax.set_ylim(0, 1)
        ax.grid(alpha=0.3)
        ax.legend()
        return fig

    paths = rep.write(rows, None, figure, models_in_setting=() if checkpoint else ("vivit",))
    return {"rows": rows, "paths": paths}
