"""The experiments of the two studies (and two beyond them), each one command with a report folder.

Every experiment writes into its folder ``OUT``:

* ``<name>.csv``  the result table (one row per model / condition), with a ``setting`` column;
* ``<name>.md``   the same table in Markdown, headed by the setting it ran under;
* ``<name>.png``  the figure;
* ``config.json`` (written last: its presence means the folder is complete) the exact resolved
  configuration (seeds, data, clip settings, every model's config and training settings), the
  command line, the machine (platform, CPU count, torch version, device) and timings;
* ``runs/<label>/`` the training runs behind it (``metrics.csv``, ``curves.png``, checkpoints);
  ``--resume`` continues them after an interruption.

Settings. The default ("full") is the papers' setting: 240 x 320 clips, ViViT patches 40 x 40,
training settings of :func:`slipsense.train.paper_settings` (ViViT 75 epochs, 3D ResNet-50 10,
STNet/TemNet 100). ``quick`` is a documented smaller setting for a CPU: 120 x 160 clips with
20 x 20 patches (the same 6 x 8 patch grid) and each model's ``quick_epochs``; its outputs say "quick" in the
table, the figure title and ``config.json``. ``epochs``, ``size`` (and ``patch``, ``batch_size``,
``lr``, per-model ``train_overrides``/``model_overrides``) override either; any override makes the
setting "full+custom" or "quick+custom" in the outputs, with the overrides listed.

Data. Video experiments use the GelSight recordings (labelled and cut as ``slipsense train`` does, cached
clips) with the shipped hand-label overrides (``configs/gelsight-label-overrides.csv``) when
present. Held-out objects are fixed for every condition of an experiment: fold ``fold`` of
``folds`` object folds (:func:`slipsense.recordings.clips.object_folds`, seeded by ``data_seed``)
of the objects that give clips at 5 frames, horizon 0 — the same objects ``slipsense train --fold
0`` holds out (with its default ``--seed 0``, which seeds its folds). ``data_seed`` also seeds the wiggle windows and the random clip split; ``seed``
seeds model initialisation, batch order and augmentation. Models are scored at their last epoch
(nothing is selected on held-out data).

Data come from a :class:`DataSource`; tests hand in an in-memory one.
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import platform
import subprocess
import time
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from slipsense.atomic import write_text
from slipsense.errors import ConfigError, InputError

#: Experiment names, in report order.
EXPERIMENTS: tuple[str, ...] = ("params", "video-compare", "frames", "noise", "stnet", "horizon", "all-models")

FULL_SIZE = (240, 320)
FULL_PATCH = (40, 40)
QUICK_SIZE = (120, 160)
QUICK_PATCH = (20, 20)
#: Epochs of the quick setting (the paper's: vivit 75, resnet3d50 10, stnet/temnet 100).
#: Simulated sequences per (object, pattern): full and quick.
SIM_SEQUENCES = 4
QUICK_SIM_SEQUENCES = 2

DEFAULT_FRAMES_LIST = (5, 4, 3, 2)
DEFAULT_NOISE_STDS = (0.0, 5.0, 10.0, 15.0, 20.0, 30.0, 50.0)
DEFAULT_HORIZONS = (0, 2, 5, 10)
FPS = 25.0  # GelSight recordings

#: What each experiment reproduces (shown in reports).
TITLES = {
    "params": "Parameter counts at the papers' settings",
    "video-compare": "ViViT vs 3D ResNet-50 on held-out objects (ViViT paper, III-B)",
    "frames": "ViViT with 5, 4, 3 and 2 frames (ViViT paper, Fig. 7)",
    "noise": "ViViT under Gaussian noise on held-out objects (ViViT paper, Fig. 8)",
    "stnet": "STNet vs TemNet on simulated and real marker sequences (STNet paper, Table II and Fig. 7)",
    "horizon": "Predicting slip before it happens: ViViT vs prediction horizon (beyond the papers)",
    "all-models": "All four models on the same held-out windows (beyond the papers)",
}


# =============================================================================== settings

@dataclass
class Settings:
    """What every experiment command accepts (see the module docstring)."""

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

    def train_config(self, name: str):
        """Training settings for model ``name``: paper < quick < --epochs/--batch-size/--lr < per-model."""
        from slipsense.models import model_class
        from slipsense.train import TrainConfig, paper_settings

        values: dict[str, Any] = paper_settings(name)
        if self.quick:
            values["epochs"] = model_class(name).quick_epochs
        for key in ("epochs", "batch_size", "lr", "max_steps_per_epoch"):
            if getattr(self, key) is not None:
                values[key] = getattr(self, key)
        values.update(seed=self.seed, device=self.device, num_workers=self.workers, progress=self.progress)
        values.update(self.train_overrides.get(name, {}))
        return TrainConfig.from_dict(values)

    def describe(self, models: Iterable[str] = ()) -> str:
        """One line naming the setting, for tables and figure titles."""
        models = list(models)
        if self.setting.startswith("quick"):
            text = "QUICK setting (smaller than the papers')"
        else:
            text = "full setting (the papers')"
        if self.customised:
            text += " with overrides (so not exactly the papers')" if not self.quick else " with overrides"
        from slipsense.models import model_class, settings_of

        parts = []
        if any(model_class(m).input_kind == "video" for m in models):
            h, w = self.video_size
            parts.append(f"clips {h}x{w}")
            if any("patch_size" in settings_of(model_class(m)) for m in models):
                parts.append("ViViT patch {}x{}".format(*self.vivit_patch))
        if models:
            parts.append("epochs " + ", ".join(f"{m} {self.train_config(m).epochs}" for m in models))
        if self.customised:
            parts.append("overrides: " + ", ".join(self.customised))
        return text + (": " + "; ".join(parts) if parts else "")

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["out"] = str(self.out)
        return d


def default_overrides() -> Path | None:
    """The shipped hand-label overrides (``configs/gelsight-label-overrides.csv`` of the checkout)."""
    path = Path(__file__).resolve().parent.parent / "configs" / "gelsight-label-overrides.csv"
    return path if path.is_file() else None


# =============================================================================== data

class DataSource:
    """GelSight recordings -> clips, objects and real marker sequences (the experiments' only data door).

    Args:
        recordings: the recordings folder (default ``$SLIPSENSE_DATA/gelsight-slip``).
        overrides: hand-label CSV; ``"default"`` = the shipped one when present, None = none.
        on_error: ``raise`` or ``skip`` bad videos.
    """

    def __init__(self, recordings: str | Path | None = None, overrides: str | Path | None = "default",
                 on_error: str = "raise", progress: bool = True):
        from slipsense.config import gelsight_recordings

        self.root = Path(recordings) if recordings is not None else gelsight_recordings()
        self.overrides = default_overrides() if overrides == "default" else (Path(overrides) if overrides else None)
        self.on_error = on_error
        self.progress = progress
        self._labels = None
        self._recs = None

    def describe(self) -> dict[str, Any]:
        from slipsense.config import portable_path

        return {"recordings": portable_path(self.root), "overrides": portable_path(self.overrides) if self.overrides else None,
                "on_error": self.on_error}

    def recordings(self):
        """The validated recordings (listed once)."""
        if self._recs is None:
            from slipsense.recordings.folders import find_recordings, validate_recordings

            recs = validate_recordings(find_recordings(self.root, on_error=self.on_error), on_error=self.on_error)
            if not recs:
                raise InputError(self.root, "no usable recordings")
            self._recs = recs
        return self._recs

    def override_map(self) -> dict | None:
        """The hand labels. A user's file must fit the recordings exactly; rows of the shipped file
        naming runs this folder does not hold are ignored (it is written for the shared recordings)."""
        if self.overrides is None:
            return None
        from slipsense.recordings.labels import read_overrides_csv

        known: dict[tuple[str, int], list[str]] = {}
        for r in self.recordings():
            known.setdefault((r.object, r.experiment), []).append(r.camera)
        if self.overrides == default_overrides():
            rows = read_overrides_csv(self.overrides)
            return {k: v for k, v in rows.items()
                    if k[:2] in known and (k[2] is None or k[2] in known[k[:2]])} or None
        return read_overrides_csv(self.overrides, known=known)

    def labels(self):
        if self._labels is None:
            from slipsense.recordings.labels import label_recordings

            self._labels = label_recordings(self.recordings(), overrides=self.override_map(), progress=self.progress)
        return self._labels

    def clips(self, spec):
        """Labelled clips (ClipSet) cut with ``spec`` (cached on disk, as ``slipsense train`` caches them)."""
        from slipsense.recordings.clips import load_or_build_clips

        clips = load_or_build_clips(self.recordings(), self.labels(), spec, progress=self.progress)
        if len(clips) == 0:
            raise InputError(self.root, "no clips could be made (no slip moments and no contact phases found)")
        return clips

    def objects(self, spec) -> list[str]:
        """Objects that give at least one clip with ``spec`` (from the labels; no decoding)."""
        from slipsense.recordings.clips import plan_windows

        return sorted({lab.object for lab in self.labels().values() if plan_windows(lab, spec)})

    def markers(self, frames: int, n_markers: int, horizon: int = 0, wiggle_per_video: int = 2,
                seed: int = 0) -> dict[str, np.ndarray]:
        """Real marker windows (:func:`slipsense.sensors.real.real_marker_dataset`), minus the videos
        whose labels the overrides replace (the marker pipeline labels automatically)."""
        from slipsense.sensors.real import real_marker_dataset

        arrays = real_marker_dataset(self.root, frames=frames, n_markers=n_markers, horizon=horizon,
                                     wiggle_per_video=wiggle_per_video, seed=seed, on_error=self.on_error,
                                     progress=self.progress)
        if self.overrides is not None:
            replaced = {k for k, lab in self.labels().items() if lab.source == "override"}
            keep = np.array([(str(g), int(e), str(c)) not in replaced
                             for g, e, c in zip(arrays["groups"], arrays["experiment"], arrays["camera"])])
            arrays = {k: v[keep] for k, v in arrays.items()}
        return arrays


def clip_spec(settings: Settings, frames: int = 5, horizon: int = 0, size: tuple[int, int] | None = None):
    from slipsense.recordings.clips import ClipSpec

    return ClipSpec(frames=frames, horizon=horizon, wiggle_per_video=settings.wiggle_per_video,
                    size=size or settings.video_size, seed=settings.data_seed)


def held_out_objects(source, settings: Settings) -> list[str]:
    """The fixed held-out objects: ``settings.test_objects``, else fold ``fold`` of the objects that
    give clips at 5 frames / horizon 0 (what ``slipsense train --fold`` holds out)."""
    from slipsense.recordings.clips import object_folds

    objects = source.objects(clip_spec(settings))
    if settings.test_objects:
        unknown = sorted(set(settings.test_objects) - set(objects))
        if unknown:
            raise ConfigError(f"--test-objects without clips: {', '.join(unknown)}")
        return sorted(settings.test_objects)
    if len(objects) < settings.folds:
        raise ConfigError(f"{len(objects)} objects cannot make {settings.folds} folds; lower --folds")
    return object_folds(objects, n_folds=settings.folds, seed=settings.data_seed)[settings.fold]


def object_split(clips, test_objects: Sequence[str]) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Indices of the training and held-out clips; the held-out objects present in ``clips``."""
    from slipsense.recordings.clips import split_by_object

    present = sorted(set(test_objects) & set(clips.objects))
    if not present:
        raise ConfigError(f"none of the held-out objects {list(test_objects)} has clips here")
    tr, te = split_by_object(clips, present)
    if len(tr) == 0:
        raise ConfigError("no training clips left after holding objects out")
    return tr, te, present


# =============================================================================== machine and files

def _git_commit() -> dict[str, Any]:
    root = Path(__file__).resolve().parent.parent
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=10)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, timeout=10)
        if head.returncode == 0:
            return {"commit": head.stdout.strip(), "modified": bool(dirty.stdout.strip())}
    except (OSError, subprocess.SubprocessError):
        pass
    return {"commit": None}


def cpu_model() -> str | None:
    """The processor's model name (Linux /proc/cpuinfo, else platform), None if unknown."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


def cpu_description() -> str:
    """The processor and the widest vector instruction set PyTorch uses on it, e.g.
    ``AMD EPYC, AVX512``: machines that share a model name can differ in AVX-512 and bf16 support,
    which changes every CPU timing."""
    import torch

    return f"{cpu_model() or 'unknown CPU'}, {torch.backends.cpu.get_cpu_capability()}"


def machine_info(device: str = "auto") -> dict[str, Any]:
    """Where a result was measured: platform, CPUs, torch/numpy versions, accelerator."""
    import torch

    from slipsense import __version__

    resolved = device if device != "auto" else ("cuda" if torch.cuda.is_available() else "cpu")
    info: dict[str, Any] = {
        "platform": platform.platform(), "machine": platform.machine(), "python": platform.python_version(),
        "cpu_model": cpu_model(), "cpu_isa": torch.backends.cpu.get_cpu_capability(), "cpu_count": os.cpu_count(),
        "cpus_usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "torch": torch.__version__, "torch_threads": torch.get_num_threads(), "numpy": np.__version__,
        "cuda_available": torch.cuda.is_available(), "device": resolved, "slipsense": __version__, **_git_commit(),
    }
    if resolved.startswith("cuda") and torch.cuda.is_available():
        info["gpu"] = torch.cuda.get_device_name(torch.device(resolved))
    return info


def machine_line(m: dict[str, Any]) -> str:
    """One line: ``Linux-..., 2 CPUs (model), torch 2.x, device cpu``."""
    cpus = m.get("cpus_usable") or m.get("cpu_count")
    text = f"{m.get('platform')}, {cpus} CPUs"
    if m.get("cpu_model"):
        text += f" ({m['cpu_model']})"
    text += f", torch {m.get('torch')} ({m.get('torch_threads')} threads), device {m.get('device')}"
    if m.get("gpu"):
        text += f" ({m['gpu']})"
    return text


def _fmt(v: Any) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return f"{int(v):,d}"
    if isinstance(v, (float, np.floating)):
        v = float(v)
        if v != 0 and (abs(v) >= 1e4 or abs(v) < 1e-3):
            return f"{v:.3g}"
        return f"{v:.3f}" if abs(v) < 100 else f"{v:.1f}"
    return str(v).replace("|", "\\|")


def markdown_table(rows: Sequence[dict[str, Any]], columns: Sequence[str]) -> str:
    lines = ["| " + " | ".join(columns) + " |", "|" + "|".join("---" for _ in columns) + "|"]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(r.get(c)) for c in columns) + " |")
    return "\n".join(lines)


def csv_text(rows: Sequence[dict[str, Any]], columns: Sequence[str]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(columns), extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({c: ("" if r.get(c) is None else r.get(c)) for c in columns})
    return buf.getvalue()


def _jsonable(v: Any) -> Any:
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, Path):
        return str(v)
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating,)):
        return float(v)
    if isinstance(v, np.ndarray):
        return v.tolist()
    return v


class Report:
    """Collects an experiment's configuration and writes its four files atomically."""

    def __init__(self, name: str, settings: Settings, source: Any = None):
        if name not in EXPERIMENTS:
            raise ConfigError(f"unknown experiment {name!r}")
        self.name, self.settings = name, settings
        self.out = Path(settings.out)
        self.out.mkdir(parents=True, exist_ok=True)
        (self.out / "config.json").unlink(missing_ok=True)  # present again only once this run has finished
        self.started = datetime.now(timezone.utc)
        self.t0 = time.perf_counter()
        self.config: dict[str, Any] = {}
        self.models: dict[str, dict[str, Any]] = {}
        self.notes: list[str] = []
        self.data = source.describe() if hasattr(source, "describe") else None

    def add_model(self, label: str, model, train_cfg=None, **extra) -> None:
        from slipsense.models import count_parameters

        entry = {"model": model.model_name, "model_config": model.config(),
                 "parameters": count_parameters(model), **extra}
        if train_cfg is not None:
            entry["train"] = asdict(train_cfg)
        self.models[label] = entry

    def write(self, rows: list[dict[str, Any]], columns: Sequence[str], figure: Callable[[Any], Any],
              extra_tables: dict[str, tuple[list[dict[str, Any]], Sequence[str]]] | None = None,
              models_in_setting: Iterable[str] = ()) -> dict[str, Path]:
        """Write ``<name>.csv``, ``<name>.png``, ``<name>.md`` and, last, ``config.json``."""
        from slipsense.plots import _plt, save_figure

        s = self.settings
        setting_line = s.describe(models_in_setting)
        rows = [{**r, "setting": s.setting} for r in rows]
        columns = [*columns, "setting"]
        paths = {"csv": self.out / f"{self.name}.csv", "md": self.out / f"{self.name}.md",
                 "png": self.out / f"{self.name}.png", "config": self.out / "config.json"}
        write_text(paths["csv"], csv_text(rows, columns))
        extra_files = {}
        for stem, (erows, ecols) in (extra_tables or {}).items():
            p = self.out / f"{stem}.csv"
            write_text(p, csv_text([{**r, "setting": s.setting} for r in erows], [*ecols, "setting"]))
            extra_files[stem] = p.name
        plt = _plt()
        fig = figure(plt)
        fig.set_layout_engine("constrained")
        label = "QUICK setting" if s.setting.startswith("quick") else "full setting"
        if s.customised:
            label += " + overrides"
        fig.suptitle(f"{TITLES[self.name]}\n[{label}]", fontsize=10)
        save_figure(fig, paths["png"])
        md_cols = [c for c in columns if c != "setting"]
        md = [f"# {TITLES[self.name]}", "", f"Setting: **{setting_line}**", "",
              markdown_table(rows, md_cols), ""]
        if self.notes:
            md += [*(f"* {n}" for n in self.notes), ""]
        md += [f"![{self.name}]({paths['png'].name})", ""]
        write_text(paths["md"], "\n".join(md))
        finished = datetime.now(timezone.utc)
        config = {
            "experiment": self.name, "title": TITLES[self.name], "setting": s.setting, "setting_line": setting_line,
            "command": s.command, "started": self.started.isoformat(timespec="seconds"),
            "finished": finished.isoformat(timespec="seconds"),
            "seconds": round(time.perf_counter() - self.t0, 1),
            "seeds": {"seed": s.seed, "data_seed": s.data_seed},
            "settings": s.to_json(), "data": self.data, "config": self.config, "models": self.models,
            "notes": self.notes, "machine": machine_info(s.device),
            "files": {k: p.name for k, p in paths.items() if k != "config"}, "extra_files": extra_files,
            "columns": list(columns),
        }
        write_text(paths["config"], json.dumps(_jsonable(config), indent=2))
        return paths


# =============================================================================== training helpers

def _device_of(model):
    try:
        return next(model.parameters()).device
    except StopIteration:  # pragma: no cover
        import torch

        return torch.device("cpu")


def score(model, data, batch_size: int = 32) -> dict[str, Any]:
    """Metrics of ``model`` on ``data`` (on the model's device)."""
    from slipsense.evaluate import predict
    from slipsense.metrics import metrics_from

    p, y = predict(model, data, batch_size=batch_size, device=_device_of(model))
    return metrics_from(p, y)


def _quick_epochs_text() -> str:
    """``"resnet3d50 2, stnet 30, ..."``: the quick setting's epochs of the papers' models."""
    from slipsense.models import available, model_class

    return ", ".join(f"{n} {model_class(n).quick_epochs}" for n in available() if model_class(n).paper_training)


def _accepted(name: str, data_config: dict[str, Any]) -> dict[str, Any]:
    """The data-implied sizes model ``name`` takes (3D ResNet-50 has no image_size: any size works)."""
    from slipsense.models import model_class, settings_of

    params = settings_of(model_class(name))
    return {k: v for k, v in data_config.items() if k in params}


def train_model(name: str, label: str, train_data, settings: Settings, report: Report, data_config: dict[str, Any],
                val_data=None, extra_eval: dict[str, Any] | None = None, preset: str | None = None,
                info: dict[str, Any] | None = None, before_fit: Callable[[Any], None] | None = None):
    """Build (seeded) and train one model into ``OUT/runs/<label>``; returns ``(model, history)``."""
    from slipsense.train import build_model, fit, seed_everything

    cfg = settings.train_config(name)
    seed_everything(settings.seed)
    model = build_model(name, preset, settings.model_config(name), _accepted(name, data_config))
    if before_fit is not None:
        before_fit(model)
    run_dir = settings.out / "runs" / label
    history = fit(model, train_data, val_data, cfg, run_dir, info={"experiment": report.name, **(info or {})},
                  resume=settings.resume, extra_eval=extra_eval)
    report.add_model(label, model, cfg, preset=preset, run=str(run_dir),
                     train_seconds=sum(r["seconds"] for r in history))
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
    return {"clips_per_s": done / dt if dt > 0 else float("inf"), "ms_per_clip": 1000 * dt / done,
            "timed_clips": done, "batch": 1, "threads": torch.get_num_threads(), "device": str(device)}


def _clip_datasets(clips, tr, te, settings: Settings):
    from slipsense.datasets import ClipDataset
    from slipsense.recordings.augment import AugmentConfig

    train = ClipDataset(clips.subset(tr), AugmentConfig(enabled=settings.augment), seed=settings.seed)
    test = ClipDataset(clips.subset(te))
    return train, test


def _video_info(source, spec, test_objects: Sequence[str], **extra) -> dict[str, Any]:
    """Checkpoint info for a video run: clip settings and held-out objects (as ``slipsense train`` stores)."""
    described = source.describe() if hasattr(source, "describe") else {}
    return {"data": {"kind": "video", "clip_spec": asdict(spec), "split": "objects", "test_objects": list(test_objects),
                     **described}, **extra}


def _epoch_axis(ax) -> None:
    from matplotlib.ticker import MaxNLocator

    ax.set_xlabel("epoch")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.grid(alpha=0.3)


def _metric_cols() -> list[str]:
    return ["accuracy", "precision", "recall", "f1"]


# =============================================================================== 1. params

def run_params(settings: Settings) -> dict[str, Any]:
    """Parameter count of every model at the papers' settings (built on the meta device: no memory)."""
    import torch

    from slipsense.models import build, count_parameters
    from slipsense.models import resnet3d, stnet

    rep = Report("params", settings)
    rows: list[dict[str, Any]] = []
    specs = [
        ("vivit", "paper", {}, None,
         "240x320 clips, 40x40 patches, 5 frames, dim 8, 2+2 layers, 2 heads, mlp 8 (factorised encoder)",
         "no paper count entered here; the layout is vit-pytorch's ViViT with the paper's arguments"),
        ("vivit", "positions=factorised", {"positions": "factorised"}, None,
         "paper sizes; position embedding split into spatial (48 x 8) and temporal (5 x 8)",
         "beyond the paper: a frame's spatial token no longer depends on its slot (streaming)"),
        ("vivit", "quick (120x160)", {"image_size": [120, 160], "patch_size": [20, 20]}, None,
         "120x160 clips, 20x20 patches: the quick setting",
         "same 6x8 patch grid; the patch embedding is 4x smaller"),
        ("resnet3d50", "paper", {}, resnet3d.PAPER_PARAMETERS,
         "pytorchvideo create_resnet(model_depth=50, 2 classes) layout, trained from scratch",
         "identical to the paper's count"),
        ("stnet", "paper", dict(stnet.PRESETS["paper"]), 129_000_000,
         "12 frames x 552 markers, d 1656, 5 blocks, ff 2048, classifier 19872->1656->2",
         "~129 M is the size of a direct port of the authors' network; the paper leaves the feed-forward "
         "width and classifier open (see slipsense/models/stnet.py)"),
        ("stnet", "paper-ff4096", dict(stnet.PRESETS["paper-ff4096"]), 129_000_000,
         "the other reading reaching ~129 M: ff 4096, one FC classifier", "alternative reading of the paper"),
        ("temnet", "paper", dict(stnet.PRESETS["paper"]), None,
         "STNet paper preset without the S codecs and the fusion layer",
         "no paper count entered here for the ablation"),
        ("stnet", "compact", dict(stnet.PRESETS["compact"]), None,
         "d 128, 4 heads, 2 blocks, ff 256: trains on 2 CPU cores", "not a paper setting"),
        ("temnet", "compact", dict(stnet.PRESETS["compact"]), None, "compact preset without codecs",
         "not a paper setting"),
    ]
    if settings.size is not None or settings.patch is not None:
        h, w = settings.video_size
        ph, pw = settings.vivit_patch
        specs.insert(2, ("vivit", f"--size {h}x{w}", {"image_size": [h, w], "patch_size": [ph, pw]}, None,
                         f"{h}x{w} clips, {ph}x{pw} patches", "the size asked for on the command line"))
    for name, setting, cfg, paper, desc, note in specs:
        cfg = {**cfg, **settings.model_overrides.get(name, {})}
        try:
            with torch.device("meta"):
                model = build(name, **cfg)
        except Exception:  # a model that cannot be built on meta: build it for real
            model = build(name, **cfg)
        n = count_parameters(model)
        rows.append({"model": name, "preset": setting, "parameters": n, "paper_parameters": paper,
                     "difference": None if paper is None else n - paper,
                     "relative_difference": None if paper is None else (n - paper) / paper,
                     "configuration": desc, "note": note})
        rep.models[f"{name}/{setting}"] = {"model": name, "model_config": model.config(), "parameters": n}
        del model
    rep.notes.append("Counts are of trainable parameters (BatchNorm running statistics excluded).")
    rep.notes.append("Paper counts: 31,657,410 for the 3D ResNet-50 (ViViT paper); ~129 M for STNet "
                     "(entered as 129,000,000; the difference column is only indicative there).")

    def figure(plt):
        fig, ax = plt.subplots(figsize=(8, 0.45 * len(rows) + 1.2))
        labels = [f"{r['model']} ({r['preset']})" for r in rows]
        ax.barh(labels, [r["parameters"] for r in rows], color="tab:blue", label="slipsense")
        paper = [(r["paper_parameters"], lab) for r, lab in zip(rows, labels) if r["paper_parameters"]]
        if paper:
            ax.scatter(*zip(*paper), color="tab:red", marker="|", s=300, zorder=3, label="paper")
        ax.set_xscale("log")
        ax.set_xlabel("trainable parameters")
        ax.invert_yaxis()
        ax.grid(axis="x", alpha=0.3)
        ax.legend(loc="lower right")
        return fig

    cols = ["model", "preset", "parameters", "paper_parameters", "difference", "relative_difference",
            "configuration", "note"]
    paths = rep.write(rows, cols, figure)
    return {"rows": rows, "paths": paths}


# =============================================================================== 2. video-compare

def run_video_compare(settings: Settings, source=None, resnet_weights: str | Path | None = None,
                      inference_clips: int = 50) -> dict[str, Any]:
    """ViViT vs 3D ResNet-50 (from scratch, or from ``resnet_weights``) trained on the training
    objects, scored on the held-out objects: parameters, training time, batch-1 inference rate,
    accuracy/precision/recall/F1."""
    source = source or DataSource(progress=settings.progress)
    rep = Report("video-compare", settings, source)
    test_objects = held_out_objects(source, settings)
    spec = clip_spec(settings)
    clips = source.clips(spec)
    tr, te, present = object_split(clips, test_objects)
    train, test = _clip_datasets(clips, tr, te, settings)
    size = tuple(clips.x.shape[2:4])
    del clips
    rep.config.update(clip_spec=asdict(spec), test_objects=present, n_train_clips=len(tr), n_test_clips=len(te),
                      n_train_items=len(train), resnet_weights=str(resnet_weights) if resnet_weights else None,
                      inference_clips=inference_clips)
    rows = []
    histories = {}
    for name in ("vivit", "resnet3d50"):
        before = None
        if name == "resnet3d50" and resnet_weights is not None:
            def before(model, path=Path(resnet_weights)):
                try:
                    model.load_weights(path)
                except InputError:
                    model.load_weights(path, skip_head=True)  # e.g. Kinetics-400 weights: keep a 2-class head
        model, history = train_model(name, name, train, settings, rep, {"frames": spec.frames, "image_size": size},
                                     before_fit=before, info=_video_info(source, spec, present))
        histories[name] = history
        m = score(model, test)
        rate = inference_rate(model, test, n=inference_clips)
        rep.models[name]["inference"] = rate
        rows.append({"model": name, "parameters": rep.models[name]["parameters"], "epochs": len(history),
                     "train_seconds": train_seconds(history), "inference_clips_per_s": rate["clips_per_s"],
                     **{k: m[k] for k in _metric_cols()}, "n_test": m["n_clips"], "n_test_slip": m["n_slip"],
                     "initialisation": ("user weights" if name == "resnet3d50" and resnet_weights else "random")})
        del model
    rep.notes.append(f"Held-out objects (fold {settings.fold} of {settings.folds}): {', '.join(present)}.")
    rep.notes.append("3D ResNet-50 is trained from scratch unless --resnet-weights is given (no pretrained video "
                     "weights are available here).")
    rep.notes.append("Inference rate: clips per second at batch 1 with the trained model, inputs already in memory.")

    def figure(plt):
        fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
        x = np.arange(4)
        for i, r in enumerate(rows):
            axes[0].bar(x + (i - 0.5) * 0.38, [r[k] for k in _metric_cols()], 0.38, label=r["model"])
        axes[0].set_xticks(x, _metric_cols())
        axes[0].set_ylim(0, 1)
        axes[0].set_title("held-out objects")
        axes[0].legend()
        names = [r["model"] for r in rows]
        axes[1].bar(names, [r["train_seconds"] / 60 for r in rows], color=["tab:blue", "tab:orange"])
        axes[1].set_ylabel("training time (min)")
        axes[2].bar(names, [r["inference_clips_per_s"] for r in rows], color=["tab:blue", "tab:orange"])
        axes[2].set_yscale("log")
        axes[2].set_ylabel("clips / s (batch 1)")
        for ax in axes:
            ax.grid(axis="y", alpha=0.3)
        return fig

    curves = [{"model": n, **r} for n, h in histories.items() for r in h]
    curve_cols = ["model", "epoch", "lr", "train_loss", "train_accuracy", "seconds"]
    cols = ["model", "parameters", "epochs", "train_seconds", "inference_clips_per_s", *_metric_cols(),
            "n_test", "n_test_slip", "initialisation"]
    paths = rep.write(rows, cols, figure, extra_tables={"curves": (curves, curve_cols)},
                      models_in_setting=("vivit", "resnet3d50"))
    return {"rows": rows, "paths": paths}


# =============================================================================== 3. frames

def run_frames(settings: Settings, source=None, frames_list: Sequence[int] = DEFAULT_FRAMES_LIST,
               test_fraction: float = 0.1) -> dict[str, Any]:
    """ViViT with each clip length: per-epoch accuracy on train, on a random clip-level test split of
    the training objects (the paper's protocol) and on the held-out objects."""
    from slipsense.datasets import ClipDataset
    from slipsense.recordings.clips import split_by_clip

    source = source or DataSource(progress=settings.progress)
    rep = Report("frames", settings, source)
    test_objects = held_out_objects(source, settings)
    rep.config.update(frames_list=list(frames_list), test_fraction=test_fraction, test_objects=test_objects,
                      clip_specs={})
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
        train, test = _clip_datasets(rest, tr, te, settings)
        del rest
        rep.config["clip_specs"][str(t)] = asdict(spec)
        model, history = train_model("vivit", f"frames{t}", train, settings, rep,
                                     {"frames": t, "image_size": size}, val_data=test,
                                     extra_eval={"heldout": held}, info=_video_info(source, spec, present))
        for r in history:
            curves.append({"frames": t, "epoch": r["epoch"], "train_loss": r["train_loss"],
                           "train_accuracy": r["train_accuracy"], "test_loss": r.get("val_loss"),
                           "test_accuracy": r.get("val_accuracy"), "heldout_loss": r.get("heldout_loss"),
                           "heldout_accuracy": r.get("heldout_accuracy"), "heldout_f1": r.get("heldout_f1")})
        last = history[-1]
        rows.append({"frames": t, "clip_ms": 1000 * t / FPS, "epochs": len(history),
                     "train_accuracy": last["train_accuracy"], "test_accuracy": last.get("val_accuracy"),
                     "test_f1": last.get("val_f1"), "heldout_accuracy": last.get("heldout_accuracy"),
                     "heldout_precision": last.get("heldout_precision"), "heldout_recall": last.get("heldout_recall"),
                     "heldout_f1": last.get("heldout_f1"), "n_train": len(tr), "n_test": len(te),
                     "n_heldout": len(held_idx), "train_seconds": train_seconds(history)})
        del model, train, test, held
    rep.notes.append(f"test: a random {int(round(test_fraction * 100))} % of the training objects' clips "
                     f"(split by clip, the paper's protocol); held-out: objects never trained on "
                     f"({', '.join(test_objects)}).")
    rep.notes.append("Final-epoch values; train accuracy is on the augmented training set as it was trained.")

    def figure(plt):
        fig, axes = plt.subplots(1, 3, figsize=(14, 3.9), sharey=True)
        for ax, key, title in zip(axes, ("train_accuracy", "test_accuracy", "heldout_accuracy"),
                                  ("train", "test (random clip split)", "held-out objects")):
            for t in frames_list:
                pts = [(c["epoch"], c[key]) for c in curves if c["frames"] == t and c[key] is not None]
                if pts:
                    ax.plot(*zip(*pts), marker=".", label=f"{t} frames")
            ax.set_title(title)
            _epoch_axis(ax)
        axes[0].set_ylabel("accuracy")
        axes[0].legend()
        return fig

    cols = ["frames", "clip_ms", "epochs", "train_accuracy", "test_accuracy", "test_f1", "heldout_accuracy",
            "heldout_precision", "heldout_recall", "heldout_f1", "n_train", "n_test", "n_heldout", "train_seconds"]
    curve_cols = ["frames", "epoch", "train_loss", "train_accuracy", "test_loss", "test_accuracy", "heldout_loss",
                  "heldout_accuracy", "heldout_f1"]
    paths = rep.write(rows, cols, figure, extra_tables={"curves": (curves, curve_cols)}, models_in_setting=("vivit",))
    return {"rows": rows, "curves": curves, "paths": paths}


# =============================================================================== 4. noise

def run_noise(settings: Settings, source=None, checkpoint: str | Path | None = None,
              stds: Sequence[float] = DEFAULT_NOISE_STDS) -> dict[str, Any]:
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
        if model.input_kind != "video":
            raise InputError(checkpoint, f"noise needs a video model, this checkpoint holds {info['model']!r}")
        data = info.get("data", {})
        spec = clip_spec_from(data) if "clip_spec" in data else clip_spec(settings)
        ck_objects = data.get("test_objects") or []
        test_objects = sorted(ck_objects) if ck_objects else held_out_objects(source, settings)
        if not ck_objects:
            rep.notes.append("The checkpoint does not name its held-out objects: make sure it never trained on "
                             "the ones evaluated here.")
        clips = source.clips(spec)
        _, te, present = object_split(clips, test_objects)
        rep.add_model("vivit", model, checkpoint=str(checkpoint))
        rep.config.update(checkpoint=str(checkpoint), trained_here=False, checkpoint_train=info.get("train"))
        trained = info.get("train", {})
        rep.notes.append(f"Model: checkpoint {checkpoint} ({info['model']}, clips {spec.size[0]}x{spec.size[1]}, "
                         f"{spec.frames} frames, trained {info.get('epoch', trained.get('epochs', '?'))} epochs); "
                         f"the setting line above describes this command, the model's training is the checkpoint's.")
        import torch

        dev = settings.device if settings.device != "auto" else ("cuda" if torch.cuda.is_available() else "cpu")
        model.to(dev)
    else:
        test_objects = held_out_objects(source, settings)
        spec = clip_spec(settings)
        clips = source.clips(spec)
        tr, te, present = object_split(clips, test_objects)
        train, _ = _clip_datasets(clips, tr, te, settings)
        model, _ = train_model("vivit", "vivit", train, settings, rep,
                               {"frames": spec.frames, "image_size": tuple(clips.x.shape[2:4])},
                               info=_video_info(source, spec, present))
        rep.config.update(checkpoint=str(settings.out / "runs" / "vivit" / "last.safetensors"), trained_here=True)
    held = clips.subset(te)
    rep.config.update(clip_spec=asdict(spec), test_objects=present, stds=list(stds), n_heldout=len(held))
    rows = []
    for s in stds:
        m = score(model, ClipDataset(held, noise_std=float(s), seed=settings.seed))
        rows.append({"noise_std": float(s), **{k: m[k] for k in _metric_cols()}, "loss": m["loss"],
                     "n_clips": m["n_clips"]})
    rep.notes.append(f"Held-out objects: {', '.join(present)}. Noise: N(0, std^2) per pixel and channel on the "
                     f"0..255 scale, rounded and clipped (the training augmentation uses std 15).")

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

    paths = rep.write(rows, ["noise_std", *_metric_cols(), "loss", "n_clips"], figure,
                      models_in_setting=() if checkpoint else ("vivit",))
    return {"rows": rows, "paths": paths}


# =============================================================================== 5. stnet

def simulated_markers(settings: Settings, sequences: int | None = None, overrides: dict[str, Any] | None = None,
                      test_fraction: float = 0.2):
    """Simulated marker windows and a split by sequence: ``test_fraction`` of the sequences of each
    motion pattern are held out (all windows of a sequence on one side; every pattern on both)."""
    from slipsense.sensors.simulator import SimConfig, make_dataset

    n = sequences if sequences is not None else (QUICK_SIM_SEQUENCES if settings.quick else SIM_SEQUENCES)
    cfg = SimConfig(seed=settings.data_seed, n_sequences=n, **(overrides or {}))
    ds = make_dataset(cfg, progress=settings.progress)
    groups = np.asarray(ds.groups)
    rng = np.random.default_rng(settings.data_seed)
    test_groups: list[int] = []
    for p in np.unique(ds.pattern):
        members = np.unique(groups[ds.pattern == p])
        k = int(round(test_fraction * len(members)))
        k = min(max(k, 1), len(members) - 1) if len(members) >= 2 else 0
        test_groups += rng.permutation(members)[:k].tolist()
    is_test = np.isin(groups, test_groups)
    sim_info = {"n_sequences": n, "seed": settings.data_seed, "test_fraction": test_fraction,
                "n_test_sequences": len(test_groups), **(overrides or {})}
    return ds.x, ds.y, np.flatnonzero(~is_test), np.flatnonzero(is_test), sim_info


def run_stnet(settings: Settings, source=None, data: Sequence[str] = ("sim", "real"), preset: str = "compact",
              sim_sequences: int | None = None, sim_overrides: dict[str, Any] | None = None,
              n_markers: int = 32, frames: int = 12) -> dict[str, Any]:
    """STNet vs TemNet (``preset``): precision/recall/F1 and per-epoch accuracy/loss, on simulated
    sequences (split by sequence) and on real marker sequences (held-out objects)."""
    from slipsense.datasets import MarkerDataset
    from slipsense.models import stnet as stnet_mod

    if preset not in stnet_mod.PRESETS:
        raise ConfigError(f"unknown preset {preset!r}; known: {sorted(stnet_mod.PRESETS)}")
    data = list(data)
    if not data or any(d not in ("sim", "real") for d in data):
        raise ConfigError("--data must name sim, real or both")
    if "real" in data:
        source = source or DataSource(progress=settings.progress)
    rep = Report("stnet", settings, source if "real" in data else None)
    rep.config.update(preset=preset, preset_config=stnet_mod.PRESETS[preset], data=data)
    rows, curves = [], []
    for kind in data:
        if kind == "sim":
            x, y, tr, te, sim_info = simulated_markers(settings, sim_sequences, sim_overrides)
            rep.config["simulation"] = sim_info
            split_note = "20 % of the simulated sequences of each motion pattern (all windows of a sequence on one side)"
        else:
            test_objects = held_out_objects(source, settings)
            arrays = source.markers(frames=frames, n_markers=n_markers, horizon=0,
                                    wiggle_per_video=settings.wiggle_per_video, seed=settings.data_seed)
            x, y, groups = arrays["x"], arrays["y"], np.asarray(arrays["groups"]).astype(str)
            is_test = np.isin(groups, test_objects)
            tr, te = np.flatnonzero(~is_test), np.flatnonzero(is_test)
            if len(te) == 0 or len(tr) == 0:
                raise ConfigError("the real marker windows do not split into training and held-out objects")
            present = sorted(set(groups[te].tolist()))
            rep.config["real"] = {"frames": frames, "n_markers": n_markers, "test_objects": present}
            split_note = f"held-out objects {', '.join(present)}"
        rep.config[f"{kind}_split"] = {"n_train": len(tr), "n_test": len(te), "test": split_note}
        train, test = MarkerDataset(x[tr], y[tr]), MarkerDataset(x[te], y[te])
        data_config = {"frames": int(x.shape[1]), "markers": int(x.shape[2])}
        for name in ("stnet", "temnet"):
            model, history = train_model(name, f"{kind}-{name}", train, settings, rep, data_config, val_data=test,
                                         preset=preset, info={"data": kind})
            m = score(model, test)
            rows.append({"data": "simulated" if kind == "sim" else "real", "model": name, "preset": preset,
                         "parameters": rep.models[f"{kind}-{name}"]["parameters"], "epochs": len(history),
                         "precision": m["precision"], "recall": m["recall"], "f1": m["f1"], "accuracy": m["accuracy"],
                         "loss": m["loss"], "n_train": len(tr), "n_test": m["n_clips"], "n_test_slip": m["n_slip"],
                         "train_seconds": train_seconds(history)})
            for r in history:
                curves.append({"data": rows[-1]["data"], "model": name, "epoch": r["epoch"],
                               "train_loss": r["train_loss"], "train_accuracy": r["train_accuracy"],
                               "test_loss": r.get("val_loss"), "test_accuracy": r.get("val_accuracy")})
            del model
        del x, y
    rep.notes.append(f"Preset: {preset} ({'the paper-size network' if preset.startswith('paper') else 'not the paper size; --preset paper for it'}); "
                     f"training settings: the STNet paper's (Adam, lr 1e-5, batch 64) unless overridden.")
    if "real" in data:
        rep.notes.append(f"Real data: {n_markers} tracked GelSight markers per frame (x, y in mm, intensity depth "
                         f"proxy), {frames}-frame windows cut like the video clips; the paper's sensor has 552 "
                         f"markers with stereo depth.")

    def figure(plt):
        fig, axes = plt.subplots(len(data), 2, figsize=(11, 3.6 * len(data)), squeeze=False)
        for i, kind in enumerate(data):
            dname = "simulated" if kind == "sim" else "real"
            for j, key in enumerate(("accuracy", "loss")):
                ax = axes[i, j]
                for name, color in (("stnet", "tab:blue"), ("temnet", "tab:orange")):
                    cs = [c for c in curves if c["data"] == dname and c["model"] == name]
                    ax.plot([c["epoch"] for c in cs], [c[f"train_{key}"] for c in cs], color=color, ls="--",
                            label=f"{name} train")
                    ax.plot([c["epoch"] for c in cs], [c[f"test_{key}"] for c in cs], color=color,
                            label=f"{name} test")
                ax.set_title(f"{dname}: {key}")
                _epoch_axis(ax)
                ax.legend(fontsize=8)
        return fig

    cols = ["data", "model", "preset", "parameters", "epochs", "precision", "recall", "f1", "accuracy", "loss",
            "n_train", "n_test", "n_test_slip", "train_seconds"]
    curve_cols = ["data", "model", "epoch", "train_loss", "train_accuracy", "test_loss", "test_accuracy"]
    paths = rep.write(rows, cols, figure, extra_tables={"curves": (curves, curve_cols)},
                      models_in_setting=("stnet", "temnet"))
    return {"rows": rows, "curves": curves, "paths": paths}


# =============================================================================== 6. horizon

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
        train, test = _clip_datasets(clips, tr, te, settings)
        size = tuple(clips.x.shape[2:4])
        del clips
        rep.config["clip_specs"][str(h)] = asdict(spec)
        model, history = train_model("vivit", f"horizon{h}", train, settings, rep,
                                     {"frames": spec.frames, "image_size": size},
                                     info=_video_info(source, spec, present))
        m = score(model, test)
        rows.append({"horizon_frames": int(h), "horizon_ms": 1000 * h / FPS, **{k: m[k] for k in _metric_cols()},
                     "n_train": len(tr), "n_test": m["n_clips"], "n_test_slip": m["n_slip"],
                     "heldout_objects": len(present), "train_seconds": train_seconds(history)})
        del model, train, test
    rep.notes.append("A slip clip ends `horizon` frames before the frame preceding the moment of slip (25 frames/s); "
                     "wiggle clips are the same at every horizon. Videos whose slip comes too early for the "
                     "horizon give no slip clip, so n_test_slip can shrink.")
    rep.notes.append(f"Held-out objects: {', '.join(test_objects)}.")

    def figure(plt):
        fig, ax = plt.subplots(figsize=(6.5, 4))
        xs = [r["horizon_frames"] for r in rows]
        for key in _metric_cols():
            ax.plot(xs, [r[key] for r in rows], marker="o", label=key)
        ax.set_xlabel("horizon (frames before the moment of slip; 1 frame = 40 ms)")
        ax.set_ylim(0, 1)
        ax.grid(alpha=0.3)
        ax.legend()
        return fig

    cols = ["horizon_frames", "horizon_ms", *_metric_cols(), "n_train", "n_test", "n_test_slip", "heldout_objects",
            "train_seconds"]
    paths = rep.write(rows, cols, figure, models_in_setting=("vivit",))
    return {"rows": rows, "paths": paths}


# =============================================================================== 7. all-models

def match_windows(meta: Sequence[dict[str, Any]], arrays: dict[str, np.ndarray],
                  y: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Pair clips with marker sequences of the same window: same (object, experiment, camera, start).

    Args:
        meta: the clips' metadata (``ClipSet.meta``).
        arrays: marker windows as :func:`slipsense.sensors.real.real_marker_dataset` returns them.
        y: the clips' labels; pairs whose labels disagree with the marker window's are dropped.

    Returns:
        ``(clip indices, marker indices, number of pairs dropped for disagreeing labels)``.
    """
    where = {}
    for j, key in enumerate(zip(np.asarray(arrays["groups"]).astype(str).tolist(),
                                np.asarray(arrays["experiment"]).tolist(),
                                np.asarray(arrays["camera"]).astype(str).tolist(),
                                np.asarray(arrays["start"]).tolist())):
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


def run_all_models(settings: Settings, source=None, frames: int = 5, n_markers: int = 32,
                   preset: str = "compact") -> dict[str, Any]:
    """ViViT, 3D ResNet-50, STNet and TemNet trained on the same training windows and scored on the
    same held-out windows (video clips for the video models, marker sequences for the others)."""
    from slipsense.datasets import MarkerDataset

    source = source or DataSource(progress=settings.progress)
    rep = Report("all-models", settings, source)
    test_objects = held_out_objects(source, settings)
    spec = clip_spec(settings, frames=frames)
    clips = source.clips(spec)
    arrays = source.markers(frames=frames, n_markers=n_markers, horizon=0,
                            wiggle_per_video=settings.wiggle_per_video, seed=settings.data_seed)
    ci, mi, n_disagree = match_windows(clips.meta, arrays, clips.y)
    if len(ci) == 0:
        raise ConfigError("no window has both a video clip and a marker sequence")
    clips_m = clips.subset(ci)
    n_clip_windows = len(clips)
    mx, my = arrays["x"][mi], np.asarray(arrays["y"])[mi]
    del clips
    tr, te, present = object_split(clips_m, test_objects)
    vtrain, vtest = _clip_datasets(clips_m, tr, te, settings)
    mtrain, mtest = MarkerDataset(mx[tr], my[tr]), MarkerDataset(mx[te], my[te])
    rep.config.update(clip_spec=asdict(spec), n_markers=n_markers, preset=preset, test_objects=present,
                      matched_windows=int(len(ci)), clip_windows=int(n_clip_windows),
                      marker_windows=int(len(arrays["y"])), label_disagreements=n_disagree,
                      n_train=int(len(tr)), n_test=int(len(te)))
    rows = []
    size = tuple(clips_m.x.shape[2:4])
    for name, train, test, dcfg, pre in (
            ("vivit", vtrain, vtest, {"frames": frames, "image_size": size}, None),
            ("resnet3d50", vtrain, vtest, {"frames": frames, "image_size": size}, None),
            ("stnet", mtrain, mtest, {"frames": frames, "markers": n_markers}, preset),
            ("temnet", mtrain, mtest, {"frames": frames, "markers": n_markers}, preset)):
        model, history = train_model(name, name, train, settings, rep, dcfg, preset=pre,
                                     info=_video_info(source, spec, present, windows="matched clip/marker windows"))
        m = score(model, test)
        rows.append({"model": name, "input": "video clip" if name in ("vivit", "resnet3d50") else "marker sequence",
                     "preset": pre or "paper", "parameters": rep.models[name]["parameters"], "epochs": len(history),
                     **{k: m[k] for k in _metric_cols()}, "n_test": m["n_clips"], "n_test_slip": m["n_slip"],
                     "train_seconds": train_seconds(history)})
        del model
    rep.notes.append(f"{len(ci)} windows have both a clip and a marker sequence (same object, experiment, camera, "
                     f"start frame; {frames} frames); {len(tr)} train, {len(te)} held-out "
                     f"({', '.join(present)}). Windows of runs whose labels were overridden by hand have no "
                     f"marker sequence and are left out.")
    rep.notes.append(f"Marker models: {n_markers} tracked GelSight markers, preset {preset}.")

    def figure(plt):
        fig, ax = plt.subplots(figsize=(9, 4))
        x = np.arange(4)
        w = 0.8 / len(rows)
        for i, r in enumerate(rows):
            ax.bar(x + (i - (len(rows) - 1) / 2) * w, [r[k] for k in _metric_cols()], w, label=r["model"])
        ax.set_xticks(x, _metric_cols())
        ax.set_ylim(0, 1)
        ax.grid(axis="y", alpha=0.3)
        ax.legend()
        return fig

    cols = ["model", "input", "preset", "parameters", "epochs", *_metric_cols(), "n_test", "n_test_slip",
            "train_seconds"]
    paths = rep.write(rows, cols, figure, models_in_setting=("vivit", "resnet3d50", "stnet", "temnet"))
    return {"rows": rows, "paths": paths}


# =============================================================================== 8. results

#: How to run each experiment (full and quick), shown in docs/results.md.
def command_lines(name: str) -> tuple[str, str]:
    """The documented full and quick command lines of experiment ``name``."""
    full = f"slipsense experiment {name} --out reports/{name}"
    quick = f"slipsense experiment {name} --quick --out reports/{name}-quick"
    if name == "noise":  # reuse the ViViT video-compare trained on the same objects
        full += " --checkpoint reports/video-compare/runs/vivit/last.safetensors"
        quick += " --checkpoint reports/video-compare-quick/runs/vivit/last.safetensors"
    return full, quick


#: What each experiment needs beyond its training (shown with the commands).
REQUIREMENTS = {
    "params": "no data; seconds",
    "video-compare": "clips at 5 frames (cached after the first run); trains ViViT and the 3D ResNet-50",
    "frames": "clips at 5, 4, 3, 2 frames (each length is decoded once, then cached); trains 4 ViViTs",
    "noise": "a ViViT checkpoint trained without the held-out objects (drop --checkpoint to train one)",
    "stnet": "simulates the sensor; real part tracks the markers of every video once (cached)",
    "horizon": "clips at horizons 0, 2, 5, 10 (each decoded once, then cached); trains 4 ViViTs",
    "all-models": "clips and tracked markers (cached after stnet); trains all four models",
}


def find_reports(reports: str | Path) -> dict[str, list[tuple[Path, dict[str, Any]]]]:
    """Every complete report folder of each experiment under ``reports``, newest first ->
    ``{name: [(folder, config), ...]}``. Folders of one experiment are different conditions
    (``frames`` and ``frames-quick``, ``stnet-sim-quick`` and ``stnet-real-quick``...)."""
    found: dict[str, list[tuple[Path, dict[str, Any]]]] = {}
    for cfg_path in sorted(Path(reports).rglob("config.json")):
        try:
            cfg = json.loads(cfg_path.read_text())
        except (OSError, json.JSONDecodeError, UnicodeDecodeError):
            continue
        if not isinstance(cfg, dict):
            continue
        name = cfg.get("experiment")
        if name not in EXPERIMENTS:
            continue
        md = cfg_path.parent / cfg.get("files", {}).get("md", f"{name}.md")
        if md.is_file():
            found.setdefault(name, []).append((cfg_path.parent, cfg))
    for folders in found.values():
        # "finished" has one-second resolution; the config file's write time breaks ties
        folders.sort(key=lambda fc: (str(fc[1].get("finished", "")), _mtime_ns(fc[0] / "config.json")), reverse=True)
    return found


def _mtime_ns(path: Path) -> int:
    try:
        return path.stat().st_mtime_ns
    except OSError:
        return 0


def _data_line(data: dict[str, Any]) -> str:
    rec = data.get("recordings")
    text = f"recordings `{Path(rec).name}`" if rec else "in-memory data"
    if rec and _resolved(rec) != _default_recordings().resolve():
        text += " (not the default recordings folder)"
    ov = data.get("overrides")
    return text + (f", hand labels `{Path(ov).name}`" if ov else ", automatic labels only")


def _resolved(stored: str) -> Path:
    from slipsense.config import resolve_path

    return Path(resolve_path(stored)).resolve()


def _default_recordings() -> Path:
    from slipsense.config import gelsight_recordings

    return gelsight_recordings()


def _report_section(name: str, folder: Path, cfg: dict[str, Any], out: Path, heading: bool) -> list[str]:
    """The Markdown of one report folder for the results page (links relative to ``out``)."""
    md_path = folder / cfg.get("files", {}).get("md", f"{name}.md")
    body = md_path.read_text().splitlines()
    if body and body[0].startswith("# "):
        body = body[1:]
    while body and not body[0].strip():
        body = body[1:]
    png = folder / cfg.get("files", {}).get("png", f"{name}.png")
    rel_png = Path(os.path.relpath(png.resolve(), out.resolve().parent)).as_posix()
    rel_dir = Path(os.path.relpath(folder.resolve(), out.resolve().parent)).as_posix()
    # the body's own image link is relative to the report folder: point it at the report
    body = [f"![{name}]({rel_png})" if ln.strip() == f"![{name}]({png.name})" else ln for ln in body]
    m = cfg.get("machine", {})
    lines = [f"### `{folder.name}`", ""] if heading else []
    lines += [f"Report: [`{rel_dir}`]({rel_dir}) — finished {cfg.get('finished')}, took {cfg.get('seconds')} s  ",
              f"Command: `{cfg.get('command') or '(called from Python)'}`  ",
              f"Machine: {machine_line(m)}  ",
              *([f"Data: {_data_line(cfg['data'])}  "] if cfg.get("data") else []),
              f"Code: slipsense {m.get('slipsense')}, commit {m.get('commit')}"
              + (" (with local modifications)" if m.get("modified") else ""), ""]
    return lines + [*body, ""]


def collect_results(reports: str | Path = "reports", out: str | Path = "docs/results.md") -> Path:
    """Write ``out``: one section per experiment with the table and figure of each of its reports under ``reports``
    (links relative to ``out``), the command and the machine it came from; "not yet run" otherwise."""
    out = Path(out)
    found = find_reports(reports)
    lines = [
        "# Results",
        "",
        "Measured by the `slipsense experiment` commands; this page is regenerated by "
        "`slipsense experiment results --reports reports --out docs/results.md` from every complete report "
        "folder under `reports/` (several folders of one experiment are different conditions, newest first). Every number below comes from the report folder named in its section "
        "(`config.json` there holds the exact configuration, seeds and machine). Sections marked "
        "**Not yet run** have no measurement.",
        "",
        "Settings: **full** = the papers' settings (240x320 clips, ViViT patch 40x40, paper epochs: ViViT 75, "
        "3D ResNet-50 10, STNet/TemNet 100). **quick** (`--quick`) = 120x160 clips, patch 20x20, epochs "
        f"{_quick_epochs_text()}, {QUICK_SIM_SEQUENCES} simulated sequences per "
        "object and pattern: smaller than the papers, labelled QUICK wherever it appears. Held-out objects: fold 0 "
        "of 5 object folds (`--fold`, `--data-seed`). Models are scored at their last epoch.",
        "",
        "## Commands",
        "",
        "| # | experiment | full setting | quick setting | needs |",
        "|---|---|---|---|---|",
        *(f"| {i} | {name} | `{command_lines(name)[0]}` | `{command_lines(name)[1]}` | {REQUIREMENTS[name]} |"
          for i, name in enumerate(EXPERIMENTS, 1)),
        "",
        "Every command also takes `--epochs N`, `--size HxW` (`--patch HxW`), `--seed`, `--data-seed`, `--fold`, "
        "`--device`, `--resume` (continue interrupted training under `OUT/runs`) and `--help`. Then "
        "`slipsense experiment results --reports reports --out docs/results.md` rewrites this page.",
        "",
    ]
    for i, name in enumerate(EXPERIMENTS, 1):
        lines += [f"## {i}. {TITLES[name]}", ""]
        if name not in found:
            full, quick = command_lines(name)
            lines += ["**Not yet run** — no measurement yet.", "", f"Full: `{full}`  ", f"Quick: `{quick}`", ""]
            continue
        if len(found[name]) > 1:
            lines += [f"{len(found[name])} reports (conditions), newest first: "
                      + ", ".join(f"`{folder.name}`" for folder, _ in found[name]) + ".", ""]
        for folder, cfg in found[name]:
            lines += _report_section(name, folder, cfg, out, heading=len(found[name]) > 1)
    lines += _live_and_speed_section(Path(reports), out)
    lines += _written_reports_section(Path(reports), out)
    text = "\n".join(lines).rstrip() + "\n"
    write_text(out, text)
    return out


#: benchmark report name prefix -> the script that writes it
BENCH_SCRIPTS = {"vivit": "bench/bench_vivit.py", "stnet": "bench/bench_stnet.py", "stream": "bench/bench_stream.py",
                 "data": "bench/bench_data.py"}


def _live_and_speed_section(reports: Path, out: Path) -> list[str]:
    """Links to the early-warning replays (``slipsense early-warning``) and the benchmark reports under
    ``reports`` (``bench/<machine>/<name>.md``), for the end of the results page."""
    lines = ["## Live detection and speed", ""]
    warnings = sorted(p.parent for p in reports.rglob("early_warning.json"))
    bench = sorted(p for p in reports.rglob("*.md") if "bench" in p.relative_to(reports).parts)
    if not warnings and not bench:
        return lines + ["No early-warning replay or benchmark report yet: `slipsense early-warning --checkpoint CKPT --recordings DIR --out "
                        "reports/early-warning` and `python bench/bench_*.py --out reports/bench/MACHINE/NAME.md`.", ""]
    for folder in warnings:
        try:
            meta = json.loads((folder / "early_warning.json").read_text())
        except (OSError, json.JSONDecodeError, UnicodeDecodeError):
            continue
        rel = Path(os.path.relpath(folder, out.parent)).as_posix()
        lines += [f"### Early warning: `{folder.name}`", "",
                  f"Model `{Path(str(meta.get('checkpoint', '?'))).name}` ({meta.get('model', '?')}) replayed through the "
                  f"streaming detector on recordings `{Path(str(meta.get('recordings', '?'))).name}` "
                  f"(`slipsense early-warning`); table: [`early_warning.csv`]({rel}/early_warning.csv).", ""]
        lines += [f"![early warning]({rel}/{png.name})" for png in sorted(folder.glob("*.png"))] + [""]
    if bench:
        lines += ["### Benchmarks", "",
                  "Written by the scripts in `bench/` with `--out`; the folder names the CPU's vector instruction set "
                  "(timings differ between machines of one model name with and without AVX-512).", "",
                  "| report | script |", "|---|---|"]
        for md in bench:
            rel = Path(os.path.relpath(md, out.parent)).as_posix()
            script = BENCH_SCRIPTS.get(md.stem.split("-")[0], "bench/")
            lines.append(f"| [`{md.relative_to(reports).as_posix()}`]({rel}) | `python {script}` |")
        lines.append("")
    return lines


def _written_reports_section(reports: Path, out: Path) -> list[str]:
    """Links to reports written by hand around a few commands (a folder under ``reports`` holding a
    ``README.md`` whose first line is its title and which names its commands), for the end of the page."""
    readmes = sorted(p for p in reports.rglob("README.md") if "bench" not in p.relative_to(reports).parts)
    if not readmes:
        return []
    lines = ["## Other measurements", "", "Reports that run a few commands by hand (each names its commands and machine):", ""]
    for md in readmes:
        try:
            first = md.read_text(encoding="utf-8").splitlines()[0].lstrip("# ").strip()
        except (OSError, UnicodeDecodeError, IndexError):
            continue
        rel = Path(os.path.relpath(md, out.parent)).as_posix()
        lines.append(f"- [{first or md.parent.name}]({rel}) (`{md.parent.relative_to(reports).as_posix()}`)")
    return lines + [""]


__all__ = [
    "DataSource", "EXPERIMENTS", "Report", "Settings", "collect_results", "find_reports", "held_out_objects",
    "inference_rate", "machine_info", "match_windows", "run_all_models", "run_frames", "run_horizon", "run_noise",
    "run_params", "run_stnet", "run_video_compare",
]
