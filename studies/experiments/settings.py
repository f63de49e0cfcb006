"""What every experiment command accepts: :class:`Settings`, the experiment names and titles.

The default ("full") is the papers' setting: 240 x 320 clips, ViViT patches 40 x 40, training
settings of :func:`slipsense.training.clips.paper_settings` (ViViT 75 epochs, 3D ResNet-50 10, STNet/TemNet
100). ``quick`` is a documented smaller setting for a CPU: 120 x 160 clips with 20 x 20 patches (the
same 6 x 8 patch grid) and each model's :data:`QUICK_EPOCHS`; its outputs say "quick" in the table, the
figure title and ``config.json``. ``epochs``, ``size`` (and ``patch``, ``batch_size``, ``lr``,
per-model ``train_overrides``/``model_overrides``) override either; any override makes the setting
"full+custom" or "quick+custom" in the outputs, with the overrides listed.

``seed`` seeds model initialisation, batch order and augmentation; ``data_seed`` the object folds,
the wiggle windows and the random clip split (see :mod:`studies.experiments.source`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Iterable

from slipsense.errors import ConfigError

#: Experiment names, in report order.
EXPERIMENTS: tuple[str, ...] = (
    "params",
    "video-compare",
    "frames",
    "noise",
    "stnet",
    "marker-baseline",
    "horizon",
    "all-models",
)

FULL_SIZE = (240, 320)  # the paper's clips: its frames whole, as ViViT's default image_size is
FULL_PATCH = (40, 40)
QUICK_SIZE = (120, 160)
QUICK_PATCH = (20, 20)
#: Epochs of the quick setting, per model (10 for any other).
QUICK_EPOCHS = {"vivit": 20, "resnet3d50": 2, "stnet": 30, "temnet": 30}

#: What each experiment reproduces (shown in reports).
TITLES = {
    "params": "Parameter counts at the papers' settings",
    "video-compare": "ViViT vs 3D ResNet-50 on held-out objects (ViViT paper, III-B)",
    "frames": "ViViT with 5, 4, 3 and 2 frames (ViViT paper, Fig. 7)",
    "noise": "ViViT under Gaussian noise on held-out objects (ViViT paper, Fig. 8)",
    "stnet": "STNet vs TemNet on simulated and real marker sequences (STNet paper, Table II and Fig. 7)",
    "marker-baseline": "Is slip learnable in the simulated marker windows? Gradient boosting on displacement-field features",
    "horizon": "Predicting slip before it happens: ViViT vs prediction horizon (beyond the papers)",
    "all-models": "All four models on the same held-out windows (beyond the papers)",
}


@dataclass
class Settings:
    """What every experiment command accepts (see this module's docstring)."""

    out: Path = Path("reports/latest")
    seed: int = 0
    data_seed: int = 0
    quick: bool = False
    epochs: int | None = None
    size: tuple[int, int] | None = None
    patch: tuple[int, int] | None = None
    batch_size: int | None = None
    lr: float | None = None
    device: str = "auto"
    workers: int = 0
    fold: int = 0
    folds: int = 5
    test_objects: list[str] = field(default_factory=list)
    wiggle_per_video: int = 2
    augment: bool = True
    marker_copies: int = 4  # with augment: each marker window and its mirrored, shifted copies (datasets.MarkerDataset)
    max_steps_per_epoch: int | None = None
    model_overrides: dict[str, dict[str, Any]] = field(default_factory=dict)
    train_overrides: dict[str, dict[str, Any]] = field(default_factory=dict)
    resume: bool = False
    progress: bool = True
    command: str | None = None

    def __post_init__(self):
        self.out = Path(self.out)
        for name in ("size", "patch"):
            v = getattr(self, name)
            if v is not None:
                if len(v) != 2 or any(int(a) < 1 for a in v):
                    raise ConfigError(f"{name} must be (height, width) positive integers, got {v!r}")
                setattr(self, name, (int(v[0]), int(v[1])))
        if self.epochs is not None and self.epochs < 1:
            raise ConfigError("--epochs must be >= 1")
        if not 0 <= self.fold < self.folds:
            raise ConfigError(f"--fold must be in 0..{self.folds - 1}")
        if self.folds < 2:
            raise ConfigError("--folds must be >= 2")
        from slipsense.datasets import check_marker_copies

        check_marker_copies(self.marker_copies, "--marker-copies")
        if self.size is not None or self.patch is not None:
            _ = self.vivit_patch  # fail now, not after the data are loaded
        from slipsense.models import available

        for option, d in (("--set", self.model_overrides), ("--train-set", self.train_overrides)):
            unknown = sorted(set(d) - set(available()))
            if unknown:
                raise ConfigError(f"{option}: unknown model {unknown[0]!r}; models: {', '.join(available())}")
        for name in self.train_overrides:
            self.train_config(name)  # unknown keys or bad values fail now

    # ---- resolved values
    @property
    def copies_of_markers(self) -> int:
        """How many times each training marker window is seen (itself and moved copies)."""
        return self.marker_copies if self.augment else 1

    @property
    def video_size(self) -> tuple[int, int]:
        return self.size or (QUICK_SIZE if self.quick else FULL_SIZE)

    @property
    def vivit_patch(self) -> tuple[int, int]:
        if self.patch is not None:
            p = self.patch
        elif self.video_size == FULL_SIZE:
            p = FULL_PATCH
        elif self.video_size == QUICK_SIZE:
            p = QUICK_PATCH
        else:  # keep the paper's 6 x 8 patch grid
            h, w = self.video_size
            if h % 6 or w % 8:
                raise ConfigError(f"size {h}x{w} does not split into the paper's 6x8 patch grid; give --patch")
            p = (h // 6, w // 8)
        h, w = self.video_size
        if h % p[0] or w % p[1]:
            raise ConfigError(f"patch {p[0]}x{p[1]} does not divide the clip size {h}x{w}")
        return p

    @property
    def customised(self) -> list[str]:
        """The overrides in force, as ``key=value`` strings."""
        out = []
        for key in ("epochs", "size", "patch", "batch_size", "lr", "max_steps_per_epoch"):
            v = getattr(self, key)
            if v is not None:
                out.append(f"{key}={'x'.join(map(str, v)) if isinstance(v, tuple) else v}")
        if not self.augment:
            out.append("augment=false")
        if self.marker_copies != 4:
            out.append(f"marker_copies={self.marker_copies}")
        for kind, d in (("model", self.model_overrides), ("train", self.train_overrides)):
            for model, kv in sorted(d.items()):
                out += [f"{model}.{kind}.{k}={v}" for k, v in sorted(kv.items())]
        return out

    @property
    def setting(self) -> str:
        base = "quick" if self.quick else "full"
        return f"{base}+custom" if self.customised else base

    def model_config(self, name: str) -> dict[str, Any]:
        """Per-model config overrides; a patch-based model (ViViT) gets the setting's patch size."""
        from slipsense.models import model_class, settings_of

        cfg: dict[str, Any] = {}
        if "patch_size" in settings_of(model_class(name)):
            cfg["patch_size"] = list(self.vivit_patch)
        cfg.update(self.model_overrides.get(name, {}))
        return cfg

    def train_config(self, name: str, preset: str | None = None):
        """Training settings for model ``name``: paper (and ``preset``'s) < quick < --epochs/--batch-size/--lr
        < per-model."""
        from slipsense.training.clips import TrainConfig, paper_settings

        values: dict[str, Any] = paper_settings(name, preset)
        if self.quick:  # fewer epochs, never more than a preset comes with
            values["epochs"] = min(QUICK_EPOCHS.get(name, 10), values["epochs"])
        for key in ("epochs", "batch_size", "lr", "max_steps_per_epoch"):
            if getattr(self, key) is not None:
                values[key] = getattr(self, key)
        values.update(seed=self.seed, device=self.device, num_workers=self.workers, progress=self.progress)
        values.update(self.train_overrides.get(name, {}))
        return TrainConfig.from_dict(values)

    def describe(self, models: Iterable[str] = (), preset: str | None = None) -> str:
        """One line naming the setting, for tables and figure titles (``preset``: the models'
        preset; one that comes with its own training settings is not the papers' setting)."""
        from slipsense.models import model_class

        models = list(models)
        if self.setting.startswith("quick"):
            text = "QUICK setting (smaller than the papers')"
        elif preset is not None and models and all(preset in model_class(m).preset_training for m in models):
            text = f"full setting with the {preset} preset (not the papers' network size and training)"
        else:
            text = "full setting (the papers')"
        if self.customised:
            text += " with overrides (so not exactly the papers')" if not self.quick else " with overrides"
        from slipsense.models import settings_of

        parts = []
        if any(model_class(m).clip_reader.pictures for m in models):
            h, w = self.video_size
            parts.append(f"clips {h}x{w}")
            if any("patch_size" in settings_of(model_class(m)) for m in models):
                parts.append("ViViT patch {}x{}".format(*self.vivit_patch))
        if models:
            parts.append("epochs " + ", ".join(f"{m} {self.train_config(m, preset).epochs}" for m in models))
        if self.customised:
            parts.append("overrides: " + ", ".join(self.customised))
        return text + (": " + "; ".join(parts) if parts else "")

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["out"] = str(self.out)
        return d


def quick_epochs_text() -> str:
    """``"resnet3d50 2, stnet 30, ..."``: the quick setting's epochs of the papers' models."""
    from slipsense.models import available, model_class

    return ", ".join(f"{n} {QUICK_EPOCHS.get(n, 10)}" for n in available() if model_class(n).paper_training)
