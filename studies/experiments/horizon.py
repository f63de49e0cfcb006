"""Experiment ``horizon`` (beyond the papers): ViViT trained and scored on held-out objects with slip
clips ending 0, 2, 5, 10 frames before the moment of slip."""

from __future__ import annotations

from dataclasses import asdict
from typing import Any, Sequence

from studies.experiments.report import Report
from studies.experiments.settings import Settings
from studies.experiments.source import DataSource, clip_spec, held_out_objects, object_split
from studies.experiments.training import clip_datasets, metric_cols, score, train_model, train_seconds, video_info

DEFAULT_HORIZONS = (0, 2, 5, 10)


def run_horizon(settings: Settings, source=None, horizons: Sequence[int] = DEFAULT_HORIZONS) -> dict[str, Any]:
    """ViViT trained and scored (held-out objects) with slip clips ending ``h`` frames before the moment of slip."""
    source = source or DataSource(progress=settings.progress)
    rep = Report("horizon", settings, source)
    test_objects = held_out_objects(source, settings)
    rep.config.update(horizons=list(horizons), test_objects=test_objects, clip_specs={})
    rows = []
    for h in horizons:
        spec = clip_spec(settings, horizon=int(h))
        clips = source.clips(spec)
        tr, te, present = object_split(clips, test_objects)
        train, test = clip_datasets(clips, tr, te, settings)
        size = tuple(clips.x.shape[2:4])
        del clips
        rep.config["clip_specs"][str(h)] = asdict(spec)
        model, history = train_model(
            "vivit",
            f"horizon{h}",
            train,
            settings,
            rep,
            {"frames": spec.frames, "image_size": size},
            info=video_info(source, spec, present),
        )
        m = score(model, test)
        rows.append(
            {
                "horizon_frames": int(h),
                "horizon_ms": 1000 * h / source.fps,
                **{k: m[k] for k in metric_cols()},
                "n_train": len(tr),
                "n_test": m["n_clips"],
                "n_test_slip": m["n_slip"],
                "heldout_objects": len(present),
                "train_seconds": train_seconds(history),
            }
        )
        del model, train, test
    rep.notes.append(
        "A slip clip ends `horizon` frames before the frame preceding the moment of slip (25 frames/s); "
        "wiggle clips are the same at every horizon. Videos whose slip comes too early for the "
        "horizon give no slip clip, so n_test_slip can shrink."
    )
    rep.notes.append(f"Held-out objects: {', '.join(test_objects)}.")

    def figure(plt):
        fig, ax = plt.subplots(figsize=(6.5, 4))
        xs = [r["horizon_frames"] for r in rows]
        for key in metric_cols():
            ax.plot(xs, [r[key] for r in rows], marker="o", label=key)
        ax.set_xlabel("horizon (frames before the moment of slip; 1 frame = 40 ms)")
        ax.set_ylim(0, 1)
        ax.grid(alpha=0.3)
        ax.legend()
        return fig

    paths = rep.write(rows, None, figure, models_in_setting=("vivit",))
    return {"rows": rows, "paths": paths}
