"""Experiment ``params``: the parameter count of every model at the papers' settings, against the
counts the papers state (models built on the meta device: no memory, no data)."""

from __future__ import annotations

from typing import Any

from studies.experiments.report import Report
from studies.experiments.settings import Settings


def run_params(settings: Settings) -> dict[str, Any]:
    """Parameter count of every model at the papers' settings (built on the meta device: no memory)."""
    import torch

    from slipsense.models import build, count_parameters, resnet3d, stnet

    rep = Report("params", settings)
    rows: list[dict[str, Any]] = []
    specs = [
        (
            "vivit",
            "paper",
            {},
            None,
            "240x320 clips, 40x40 patches, 5 frames, dim 8, 2+2 layers, 2 heads, mlp 8 (factorised encoder)",
            "no paper count entered here; the layout is vit-pytorch's ViViT with the paper's arguments",
        ),
        (
            "vivit",
            "positions=factorised",
            {"positions": "factorised"},
            None,
            "paper sizes; position embedding split into spatial (48 x 8) and temporal (5 x 8)",
            "beyond the paper: a frame's spatial token no longer depends on its slot (streaming)",
        ),
        (
            "vivit",
            "quick (120x160)",
            {"image_size": [120, 160], "patch_size": [20, 20]},
            None,
            "120x160 clips, 20x20 patches: the quick setting",
            "same 6x8 patch grid; the patch embedding is 4x smaller",
        ),
        (
            "resnet3d50",
            "paper",
            {},
            resnet3d.PAPER_PARAMETERS,
            "pytorchvideo create_resnet(model_depth=50, 2 classes) layout, trained from scratch",
            "identical to the paper's count",
        ),
        (
            "stnet",
            "paper",
            dict(stnet.PRESETS["paper"]),
            129_000_000,
            "12 frames x 552 markers, d 1656, 5 blocks, ff 2048, classifier 19872->1656->2",
            "~129 M is the size of a direct port of the authors' network; the paper leaves the feed-forward "
            "width and classifier open (see slipsense/models/stnet.py)",
        ),
        (
            "stnet",
            "paper-ff4096",
            dict(stnet.PRESETS["paper-ff4096"]),
            129_000_000,
            "the other reading reaching ~129 M: ff 4096, one FC classifier",
            "alternative reading of the paper",
        ),
        (
            "temnet",
            "paper",
            dict(stnet.PRESETS["paper"]),
            None,
            "STNet paper preset without the S codecs and the fusion layer",
            "no paper count entered here for the ablation",
        ),
        (
            "stnet",
            "compact",
            dict(stnet.PRESETS["compact"]),
            None,
            "d 128, 4 heads, 2 blocks, ff 256: trains on 2 CPU cores",
            "not a paper setting",
        ),
        (
            "temnet",
            "compact",
            dict(stnet.PRESETS["compact"]),
            None,
            "compact preset without codecs",
            "not a paper setting",
        ),
    ]
    if settings.size is not None or settings.patch is not None:
        h, w = settings.video_size
        ph, pw = settings.vivit_patch
        specs.insert(
            2,
            (
                "vivit",
                f"--size {h}x{w}",
                {"image_size": [h, w], "patch_size": [ph, pw]},
                None,
                f"{h}x{w} clips, {ph}x{pw} patches",
                "the size asked for on the command line",
            ),
        )
    for name, setting, cfg, paper, desc, note in specs:
        cfg = {**cfg, **settings.model_overrides.get(name, {})}
        try:
            with torch.device("meta"):
                model = build(name, **cfg)
        except Exception:  # a model that cannot be built on meta: build it for real
            model = build(name, **cfg)
        n = count_parameters(model)
        rows.append(
            {
                "model": name,
                "preset": setting,
                "parameters": n,
                "paper_parameters": paper,
                "difference": None if paper is None else n - paper,
                "relative_difference": None if paper is None else (n - paper) / paper,
                "configuration": desc,
                "note": note,
            }
        )
        rep.models[f"{name}/{setting}"] = {"model": name, "model_config": model.config(), "parameters": n}
        del model
    rep.notes.append("Counts are of trainable parameters (BatchNorm running statistics excluded).")
    rep.notes.append(
        "Paper counts: 31,657,410 for the 3D ResNet-50 (ViViT paper); ~129 M for STNet "
        "(entered as 129,000,000; the difference column is only indicative there)."
    )

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

    paths = rep.write(rows, None, figure)
    return {"rows": rows, "paths": paths}
