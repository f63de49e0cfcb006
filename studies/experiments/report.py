"""Where and how a result was measured, and the files every experiment writes (:class:`Report`).

Every experiment writes into its folder ``OUT``: ``<name>.csv``, ``<name>.md``, ``<name>.png`` and,
last, ``config.json`` (see :mod:`studies.experiments`); :func:`machine_info` is the machine part
of ``config.json``, :func:`cpu_description` names the CPU in benchmark reports.
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
from dataclasses import asdict
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from slipsense.atomic import write_text
from slipsense.errors import ConfigError
from studies.experiments.settings import EXPERIMENTS, TITLES, Settings

# =============================================================================== machine


def _git_commit() -> dict[str, Any]:
    root = Path(__file__).resolve().parents[2]  # the checkout
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=10)
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=root,
            capture_output=True,
            text=True,
            timeout=10,
        )
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
        "platform": platform.platform(),
        "machine": platform.machine(),
        "python": platform.python_version(),
        "cpu_model": cpu_model(),
        "cpu_isa": torch.backends.cpu.get_cpu_capability(),
        "cpu_count": os.cpu_count(),
        "cpus_usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "numpy": np.__version__,
        "cuda_available": torch.cuda.is_available(),
        "device": resolved,
        "slipsense": __version__,
        **_git_commit(),
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


# =============================================================================== files


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

        entry = {
            "model": model.model_name,
            "model_config": model.config(),
            "parameters": count_parameters(model),
            **extra,
        }
        if train_cfg is not None:
            entry["train"] = asdict(train_cfg)
        self.models[label] = entry

    def write(
        self,
        rows: list[dict[str, Any]],
        columns: Sequence[str] | None,
        figure: Callable[[Any], Any],
        extra_tables: dict[str, tuple[list[dict[str, Any]], Sequence[str] | None]] | None = None,
        models_in_setting: Iterable[str] = (),
    ) -> dict[str, Path]:
        """Write ``<name>.csv``, ``<name>.png``, ``<name>.md`` and, last, ``config.json``. Columns
        ``None``: every key of the rows, in the order they first appear."""
        from slipsense.plots import _plt, save_figure

        s = self.settings
        setting_line = s.describe(models_in_setting, self.config.get("preset"))
        columns = [*(_keys(rows) if columns is None else columns), "setting"]
        rows = [{**r, "setting": s.setting} for r in rows]
        paths = {
            "csv": self.out / f"{self.name}.csv",
            "md": self.out / f"{self.name}.md",
            "png": self.out / f"{self.name}.png",
            "config": self.out / "config.json",
        }
        write_text(paths["csv"], csv_text(rows, columns))
        extra_files = {}
        for stem, (erows, ecols) in (extra_tables or {}).items():
            p = self.out / f"{stem}.csv"
            cols = [*(_keys(erows) if ecols is None else ecols), "setting"]
            write_text(p, csv_text([{**r, "setting": s.setting} for r in erows], cols))
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
        md = [f"# {TITLES[self.name]}", "", f"Setting: **{setting_line}**", "", markdown_table(rows, md_cols), ""]
        if self.notes:
            md += [*(f"* {n}" for n in self.notes), ""]
        md += [f"![{self.name}]({paths['png'].name})", ""]
        write_text(paths["md"], "\n".join(md))
        finished = datetime.now(timezone.utc)
        config = {
            "experiment": self.name,
            "title": TITLES[self.name],
            "setting": s.setting,
            "setting_line": setting_line,
            "command": s.command,
            "started": self.started.isoformat(timespec="seconds"),
            "finished": finished.isoformat(timespec="seconds"),
            "seconds": round(time.perf_counter() - self.t0, 1),
            "seeds": {"seed": s.seed, "data_seed": s.data_seed},
            "settings": s.to_json(),
            "data": self.data,
            "config": self.config,
            "models": self.models,
            "notes": self.notes,
            "machine": machine_info(s.device),
            "files": {k: p.name for k, p in paths.items() if k != "config"},
            "extra_files": extra_files,
            "columns": list(columns),
        }
        write_text(paths["config"], json.dumps(_jsonable(config), indent=2))
        return paths


def _keys(rows: Sequence[dict[str, Any]]) -> list[str]:
    """Every key of ``rows``, in the order they first appear."""
    return list(dict.fromkeys(k for r in rows for k in r))
