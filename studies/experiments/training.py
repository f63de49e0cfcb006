"""Training and scoring helpers the experiments share: build and train a model into ``OUT/runs/<label>``
(:func:`train_model`), score it (:func:`score`), time it (:func:`inference_rate`), plus the clip
datasets, checkpoint info and plot axes every video experiment uses.
"""

from __future__ import annotations

import time
from dataclasses import asdict
from typing import Any, Callable, Sequence

from studies.experiments.report import Report
from studies.experiments.settings import Settings


def _device_of(model):
    try:
        return next(model.parameters()).device
    except StopIteration:  # pragma: no cover
        import torch

        return torch.device("cpu")


def score(model, data, batch_size: int = 32) -> dict[str, Any]:
    """Metrics of ``model`` on ``data`` (on the model's device)."""
    from slipsense.evaluation.predict import predict
    from slipsense.measures.clips import metrics_from

    p, y = predict(model, data, batch_size=batch_size, device=_device_of(model))
    return metrics_from(p, y)


def train_model(
    name: str,
    label: str,
    train_data,
    settings: Settings,
    report: Report,
    data_config: dict[str, Any],
    val_data=None,
    extra_eval: dict[str, Any] | None = None,
    preset: str | None = None,
    info: dict[str, Any] | None = None,
    before_fit: Callable[[Any], None] | None = None,
):
    """Build (seeded) and train one model into ``OUT/runs/<label>``; returns ``(model, history)``."""
    from slipsense.training.clips import build_model, fit, seed_everything

    cfg = settings.train_config(name, preset)
    seed_everything(settings.seed)
    model = build_model(name, preset, settings.model_config(name), data_config)
    if before_fit is not None:
        before_fit(model)
    run_dir = settings.out / "runs" / label
    history = fit(
        model,
        train_data,
        val_data,
        cfg,
        run_dir,
        info={"experiment": report.name, **(info or {})},
        resume=settings.resume,
        extra_eval=extra_eval,
    )
    report.add_model(
        label, model, cfg, preset=preset, run=str(run_dir), train_seconds=sum(r["seconds"] for r in history)
    )
    return model, history


def train_seconds(history: list[dict[str, Any]]) -> float:
    """Seconds spent in the epochs (per-epoch evaluation included when there was any)."""
    return float(sum(r["seconds"] for r in history))


def inference_rate(model, data, n: int = 50, warmup: int = 3, max_seconds: float = 120.0) -> dict[str, Any]:
    """Clips per second at batch 1 (model in eval mode, inputs prepared beforehand, device synced)."""
    import torch

    device = _device_of(model)
    model.eval()
    n = max(1, min(n, len(data)))
    xs = [data[i][0].unsqueeze(0).to(device) for i in range(n)]

    def sync():
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    with torch.inference_mode():
        for x in xs[:warmup]:
            model(x)
        sync()
        done = 0
        t0 = time.perf_counter()
        for x in xs:
            model(x)
            done += 1
            if done >= 5 and time.perf_counter() - t0 > max_seconds:
                break
        sync()
        dt = time.perf_counter() - t0
    return {
        "clips_per_s": done / dt if dt > 0 else float("inf"),
        "ms_per_clip": 1000 * dt / done,
        "timed_clips": done,
        "batch": 1,
        "threads": torch.get_num_threads(),
        "device": str(device),
    }


def clip_datasets(clips, tr, te, settings: Settings):
    from slipsense.datasets import ClipDataset
    from slipsense.recordings.augment import AugmentConfig

    train = ClipDataset(clips.subset(tr), AugmentConfig(enabled=settings.augment), seed=settings.seed)
    test = ClipDataset(clips.subset(te))
    return train, test


def video_info(source, spec, test_objects: Sequence[str], **extra) -> dict[str, Any]:
    """Checkpoint info for a video run: clip settings and held-out objects (as ``slipsense train`` stores)."""
    described = source.describe() if hasattr(source, "describe") else {}
    return {
        "data": {
            "kind": "video",
            "clip_spec": asdict(spec),
            "split": "objects",
            "test_objects": list(test_objects),
            **described,
        },
        **extra,
    }


def epoch_axis(ax) -> None:
    from matplotlib.ticker import MaxNLocator

    ax.set_xlabel("epoch")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.grid(alpha=0.3)


def metric_cols() -> list[str]:
    return ["accuracy", "precision", "recall", "f1"]
