"""A tiny grasp training for the DDP tests, runnable as a script (also under torchrun).

    python tiny_grasp_train.py OUT_DIR MODEL ACCUMULATE [HARD_NEGATIVES]

Trains ``MODEL`` (motionnet or motion-energy, small) on 7 made-up grasps through
:func:`slipsense.training.grasps.fit_runs` and writes ``OUT_DIR/final.safetensors`` (the state dict)
and ``OUT_DIR/history.json`` on rank 0.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import save_file

from slipsense.recordings.runs import GraspRun
from slipsense.training.grasps import GraspTrainConfig, fit_runs


def runs(n_runs: int = 7, n: int = 60, size=(16, 20)):
    """Still noise; slip runs get a moving stripe in the 8 frames up to the moment of slip."""
    rng = np.random.default_rng(0)
    out = []
    for i in range(n_runs):
        gray = rng.integers(100, 104, (2, n, *size), dtype=np.uint8)
        moment = 45 if i % 2 == 0 else None
        if moment is not None:
            for t in range(moment - 8, moment + 1):
                gray[:, t, :, (t * 2) % size[1]] = 250
        out.append(
            GraspRun(
                f"obj{i % 4}",
                i,
                moment is not None,
                moment,
                gray,
                np.zeros((2, n), np.float32),
                ("camera_0", "camera_2"),
            )
        )
    return out


def main(argv):
    out, model, accumulate = Path(argv[0]), argv[1], int(argv[2])
    hard = int(argv[3]) if len(argv) > 3 else 0
    config = {"image_size": [16, 20]}
    if model == "motionnet":
        config.update(width=4, features=8, temporal=8, lags=[1, 5], dilations=[1, 2])
    cfg = GraspTrainConfig(
        model=model,
        model_config=config,
        epochs=3,
        lr=1e-2,
        batch_size=6,
        chunk=12,
        negatives=2,
        hard_negatives=hard,
        mine_every=1,
        inner_folds=0,
        accumulate=accumulate,
    )
    torch.set_num_threads(1)
    trained, history = fit_runs(runs(), cfg, progress=False)
    if int(__import__("os").environ.get("RANK", "0")) == 0:
        out.mkdir(parents=True, exist_ok=True)
        save_file({k: v.contiguous() for k, v in trained.state_dict().items()}, str(out / "final.safetensors"))
        (out / "history.json").write_text(json.dumps(history))


if __name__ == "__main__":
    from slipsense.training.distributed import finish

    main(sys.argv[1:])
    finish()
