"""Experiment ``frames`` (ViViT paper, Fig. 7): ViViT with 5, 4, 3 and 2 frames — per-epoch accuracy
on train, on a random clip-level test split of the training objects and on the held-out objects."""

from __future__ import annotations

from dataclasses import asdict
from typing import Any, Sequence

from studies.experiments.report import Report
from studies.experiments.settings import Settings
from studies.experiments.source import DataSource, clip_spec, held_out_objects, object_split
from studies.experiments.training import clip_datasets, epoch_axis, train_model, train_seconds, video_info

DEFAULT_FRAMES_LIST = (5, 4, 3, 2)


def run_frames(
    settings: Settings, source=None, frames_list: Sequence[int] = DEFAULT_FRAMES_LIST, test_fraction: float = 0.1
) -> dict[str, Any]:
    """ViViT with each clip length: per-epoch accuracy on train, on a random clip-level test split of
    the training objects (the paper's protocol) and on the held-out objects."""
    from slipsense.datasets import ClipDataset
    from slipsense.recordings.clips import split_by_clip

    source = source or DataSource(progress=settings.progress)
    rep = Report("frames", settings, source)
    test_objects = held_out_objects(source, settings)
    rep.config.update(
        frames_list=list(frames_list), test_fraction=test_fraction, test_objects=test_objects, clip_specs={}
    )
    rows, curves = [], []
    for t in frames_list:
        spec = clip_spec(settings, frames=t)
        clips = source.clips(spec)
        size = tuple(clips.x.shape[2:4])
        rest_idx, held_idx, present = object_split(clips, test_objects)
        held = ClipDataset(clips.subset(held_idx))
        rest = clips.subset(rest_idx)
        del clips  # full-resolution clip sets are large: keep one copy at a time
        tr, te = split_by_clip(rest, test_fraction=test_fraction, seed=settings.data_seed)
        train, test = clip_datasets(rest, tr, te, settings)
        del rest
        rep.config["clip_specs"][str(t)] = asdict(spec)
        model, history = train_model(
            "vivit",
            f"frames{t}",
            train,
            settings,
            rep,
            {"frames": t, "image_size": size},
            val_data=test,
            extra_eval={"heldout": held},
            info=video_info(source, spec, present),
        )
        for r in history:
            curves.append(
                {
                    "frames": t,
                    "epoch": r["epoch"],
                    "train_loss": r["train_loss"],
                    "train_accuracy": r["train_accuracy"],
                    "test_loss": r.get("val_loss"),
                    "test_accuracy": r.get("val_accuracy"),
                    "heldout_loss": r.get("heldout_loss"),
                    "heldout_accuracy": r.get("heldout_accuracy"),
                    "heldout_f1": r.get("heldout_f1"),
                }
            )
        last = history[-1]
        rows.append(
            {
                "frames": t,
                "clip_ms": 1000 * t / source.fps,
                "epochs": len(history),
                "train_accuracy": last["train_accuracy"],
                "test_accuracy": last.get("val_accuracy"),
                "test_f1": last.get("val_f1"),
                "heldout_accuracy": last.get("heldout_accuracy"),
                "heldout_precision": last.get("heldout_precision"),
                "heldout_recall": last.get("heldout_recall"),
                "heldout_f1": last.get("heldout_f1"),
                "n_train": len(tr),
                "n_test": len(te),
                "n_heldout": len(held_idx),
                "train_seconds": train_seconds(history),
            }
        )
        del model, train, test, held
    rep.notes.append(
        f"test: a random {int(round(test_fraction * 100))} % of the training objects' clips "
        f"(split by clip, the paper's protocol); held-out: objects never trained on "
        f"({', '.join(test_objects)})."
    )
    rep.notes.append("Final-epoch values; train accuracy is on the augmented training set as it was trained.")

    def figure(plt):
        fig, axes = plt.subplots(1, 3, figsize=(14, 3.9), sharey=True)
        for ax, key, title in zip(
            axes,
            ("train_accuracy", "test_accuracy", "heldout_accuracy"),
            ("train", "test (random clip split)", "held-out objects"),
        ):
            for t in frames_list:
                pts = [(c["epoch"], c[key]) for c in curves if c["frames"] == t and c[key] is not None]
                if pts:
                    ax.plot(*zip(*pts), marker=".", label=f"{t} frames")
            ax.set_title(title)
            epoch_axis(ax)
        axes[0].set_ylabel("accuracy")
        axes[0].legend()
        return fig

    paths = rep.write(rows, None, figure, extra_tables={"curves": (curves, None)}, models_in_setting=("vivit",))
    return {"rows": rows, "curves": curves, "paths": paths}
