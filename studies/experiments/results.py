"""``python -m studies experiment results``: studies/docs/results.md from the report folders under ``reports`` — one
section per experiment (its command lines, what it needs, each report's table, figure, command and
machine), then the early-warning replays, the benchmark reports (with the script that writes each)
and the hand-written reports."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from slipsense.atomic import write_text
from slipsense.paths import gelsight_recordings, resolve_path
from studies.experiments.report import machine_line
from studies.experiments.settings import EXPERIMENTS, TITLES, quick_epochs_text
from studies.experiments.stnet import QUICK_SIM_SEQUENCES


def command_lines(name: str) -> tuple[str, str]:
    """The documented full and quick command lines of experiment ``name``."""
    full = f"python -m studies experiment {name} --out reports/{name}"
    quick = f"python -m studies experiment {name} --quick --out reports/{name}-quick"
    if name == "video-compare":  # the 3D ResNet-50 at the paper's setting needs an accelerator
        full += " --models vivit"
    return full, quick


#: What each experiment needs beyond its training (shown with the commands).
REQUIREMENTS = {
    "params": "no data; seconds",
    "video-compare": "clips at 5 frames (cached after the first run); trains ViViT and the 3D ResNet-50 "
    "(`--models vivit` or `resnet3d50` for one: the 3D ResNet-50 at the paper's setting needs an accelerator)",
    "frames": "clips at 5, 4, 3, 2 frames (each length is decoded once, then cached); trains 4 ViViTs",
    "noise": "trains a ViViT without the held-out objects (or `--checkpoint` one trained so)",
    "stnet": "simulates the sensor; real part tracks the markers of every video once (cached)",
    "marker-baseline": "simulates the sensor as stnet does; gradient boosting, no network (about 20 s; scikit-learn)",
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
    if rec and Path(resolve_path(rec)).resolve() != gelsight_recordings().resolve():
        text += " (not the default recordings folder)"
    ov = data.get("overrides")
    return text + (f", hand labels `{Path(ov).name}`" if ov else ", automatic labels only")


def _report_section(
    name: str, folder: Path, cfg: dict[str, Any], out: Path, heading: bool, label: str | None = None
) -> list[str]:
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
    lines = [f"### `{label or folder.name}`", ""] if heading else []
    lines += [
        f"Report: [`{rel_dir}`]({rel_dir}) — finished {cfg.get('finished')}, took {cfg.get('seconds')} s  ",
        f"Command: `{cfg.get('command') or '(called from Python)'}`  ",
        f"Machine: {machine_line(m)}  ",
        *([f"Data: {_data_line(cfg['data'])}  "] if cfg.get("data") else []),
        f"Code: slipsense {m.get('slipsense')}, commit {m.get('commit')}"
        + (" (with local modifications)" if m.get("modified") else ""),
        "",
    ]
    return lines + [*body, ""]


def collect_results(reports: str | Path = "reports", out: str | Path = "studies/docs/results.md") -> Path:
    """Write ``out``: one section per experiment with the table and figure of each of its reports under ``reports``
    (links relative to ``out``), the command and the machine it came from; "not yet run" otherwise."""
    out = Path(out)
    found = find_reports(reports)
    lines = [
        "# Results",
        "",
        "Measured by the `python -m studies experiment` commands; this page is regenerated by "
        "`python -m studies experiment results --reports reports --out studies/docs/results.md` from every complete report "
        "folder under `reports/` (several folders of one experiment are different conditions, newest first). Every number below comes from the report folder named in its section "
        "(`config.json` there holds the exact configuration, seeds and machine). Sections marked "
        "**Not yet run** have no measurement.",
        "",
        "Settings: **full** = the papers' settings (240x320 clips, ViViT patch 40x40, paper epochs: ViViT 75, "
        "3D ResNet-50 10, STNet/TemNet 100). **quick** (`--quick`) = 120x160 clips, patch 20x20, epochs "
        f"{quick_epochs_text()}, {QUICK_SIM_SEQUENCES} simulated sequences per "
        "object and pattern: smaller than the papers, labelled QUICK wherever it appears. Held-out objects: fold 0 "
        "of 5 object folds (`--fold`, `--data-seed`). Models are scored at their last epoch.",
        "",
        "## Commands",
        "",
        "The pipeline (`dvc.yaml`, `dvc repro -s STAGE`) runs the stages that this page shows; "
        "`studies/README.md` lists them with their times.",
        "",
        "| # | experiment | full setting | quick setting | needs |",
        "|---|---|---|---|---|",
        *(
            f"| {i} | {name} | `{command_lines(name)[0]}` | `{command_lines(name)[1]}` | {REQUIREMENTS[name]} |"
            for i, name in enumerate(EXPERIMENTS, 1)
        ),
        "",
        "Every command also takes `--epochs N`, `--size HxW` (`--patch HxW`), `--seed`, `--data-seed`, `--fold`, "
        "`--device`, `--resume` (continue interrupted training under `OUT/runs`) and `--help`. Then "
        "`python -m studies experiment results --reports reports --out studies/docs/results.md` rewrites this page.",
        "",
    ]
    for i, name in enumerate(EXPERIMENTS, 1):
        lines += [f"## {i}. {TITLES[name]}", ""]
        if name not in found:
            full, quick = command_lines(name)
            lines += ["**Not yet run** — no measurement yet.", "", f"Full: `{full}`  ", f"Quick: `{quick}`", ""]
            continue
        if len(found[name]) > 1:
            lines += [
                f"{len(found[name])} reports (conditions), newest first: "
                + ", ".join(f"`{folder.relative_to(reports).as_posix()}`" for folder, _ in found[name])
                + ".",
                "",
            ]
        for folder, cfg in found[name]:
            label = folder.relative_to(reports).as_posix()  # nested conditions (fold0, ...) keep their parent
            lines += _report_section(name, folder, cfg, out, heading=len(found[name]) > 1, label=label)
    lines += _live_and_speed_section(Path(reports), out)
    lines += _written_reports_section(Path(reports), out)
    text = "\n".join(lines).rstrip() + "\n"
    write_text(out, text)
    return out


#: benchmark report name prefix -> the script that writes it
BENCH_SCRIPTS = {
    "vivit": "bench/bench_vivit.py",
    "stnet": "bench/bench_stnet.py",
    "stream": "bench/bench_stream.py",
    "data": "bench/bench_data.py",
}


def _live_and_speed_section(reports: Path, out: Path) -> list[str]:
    """Links to the early-warning replays (``python -m studies grasp early-warning``) and the benchmark reports
    beside ``reports`` (``bench/results/<machine>/<name>.md``: timings of this machine, not pipeline stages),
    for the end of the results page."""
    lines = ["## Live detection and speed", ""]
    warnings = sorted(p.parent for p in reports.rglob("early_warning.json"))
    bench_root = reports.parent / "bench" / "results"
    bench = sorted(bench_root.rglob("*.md")) if bench_root.is_dir() else []
    if not warnings and not bench:
        return lines + [
            "No early-warning replay or benchmark report yet: `slipsense early-warning --checkpoint CKPT --recordings DIR --out "
            "reports/early-warning` and `python bench/bench_*.py --out bench/results/MACHINE/NAME.md`.",
            "",
        ]
    for folder in warnings:
        try:
            meta = json.loads((folder / "early_warning.json").read_text())
        except (OSError, json.JSONDecodeError, UnicodeDecodeError):
            continue
        rel = Path(os.path.relpath(folder, out.parent)).as_posix()
        lines += [
            f"### Early warning: `{folder.name}`",
            "",
            f"Model `{Path(str(meta.get('checkpoint', '?'))).name}` ({meta.get('model', '?')}) replayed through the "
            f"streaming detector on recordings `{Path(str(meta.get('recordings', '?'))).name}` "
            f"(`slipsense early-warning`); table: [`early_warning.csv`]({rel}/early_warning.csv).",
            "",
        ]
        lines += [f"![early warning]({rel}/{png.name})" for png in sorted(folder.glob("*.png"))] + [""]
    if bench:
        lines += [
            "### Benchmarks",
            "",
            "Written by the scripts in `bench/` with `--out`; the folder names the CPU's vector instruction set "
            "(timings differ between machines of one model name with and without AVX-512).",
            "",
            "| report | script |",
            "|---|---|",
        ]
        for md in bench:
            rel = Path(os.path.relpath(md, out.parent)).as_posix()
            script = BENCH_SCRIPTS.get(md.stem.split("-")[0], "bench/")
            lines.append(f"| [`{md.relative_to(bench_root.parent).as_posix()}`]({rel}) | `python {script}` |")
        lines.append("")
    return lines


def _written_reports_section(reports: Path, out: Path) -> list[str]:
    """Links to reports written by hand around a few commands (a folder under ``reports`` holding a
    ``README.md`` whose first line is its title and which names its commands), for the end of the page."""
    readmes = sorted(reports.rglob("README.md"))
    if not readmes:
        return []
    lines = [
        "## Other measurements",
        "",
        "Reports that run a few commands by hand (each names its commands and machine):",
        "",
    ]
    for md in readmes:
        try:
            first = md.read_text(encoding="utf-8").splitlines()[0].lstrip("# ").strip()
        except (OSError, UnicodeDecodeError, IndexError):
            continue
        rel = Path(os.path.relpath(md, out.parent)).as_posix()
        lines.append(f"- [{first or md.parent.name}]({rel}) (`{md.parent.relative_to(reports).as_posix()}`)")
    return lines + [""]
