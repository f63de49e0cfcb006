"""torchrun equals one process: no padded repeats for any dataset size, dropout masks that do not
depend on the rank. Also a script, run by the tests once under torchrun and once plainly:

    python test_reliability_ddp.py OUT

It trains small clip jobs on 67 items (not a multiple of any batch here) into OUT/<job>/, and a grasp
model on 7 made-up grasps into OUT/grasp/ (tests/support/tiny_grasp_train.py).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import torch
import torch.nn as nn
from torch.utils.data import Dataset

from slipsense.models import MarkerModel, register
from slipsense.training.clips import StepPlan, TrainConfig, fit, seed_everything

N_ITEMS = 67


@register("test-reliability-dropout")
class DropNet(MarkerModel):
    def __init__(self, frames: int = 4, markers: int = 6, hidden: int = 16, dropout: float = 0.5):
        super().__init__()
        self._config = dict(frames=frames, markers=markers, hidden=hidden, dropout=dropout)
        self.net = nn.Sequential(
            nn.Flatten(), nn.Linear(frames * markers * 3, hidden), nn.Tanh(), nn.Dropout(dropout), nn.Linear(hidden, 2)
        )

    def config(self):
        return dict(self._config)

    def forward(self, x):
        return self.net(x)


class Toy(Dataset):
    def __init__(self, n: int):
        g = torch.Generator().manual_seed(123)
        self.x = torch.randn(n, 4, 6, 3, generator=g)
        self.y = (self.x[:, :, :, 0].mean(dim=(1, 2)) > 0).long()

    def __len__(self):
        return len(self.y)

    def __getitem__(self, i):
        return self.x[i], self.y[i]


#: job -> (dropout, batch per process, accumulate); run with the world size of the launch.
JOBS = {"plain": (0.0, 8, 1), "dropout": (0.5, 8, 1)}
#: the same jobs for one process: 2 x 8 is 1 x 16, or (with dropout) 1 x 8 x accumulate 2
SINGLE = {"plain": (0.0, 16, 1), "dropout": (0.5, 8, 2)}


def main(out: str) -> None:
    world = int(os.environ.get("WORLD_SIZE", "1"))
    for job, (dropout, batch, accumulate) in (JOBS if world > 1 else SINGLE).items():
        seed_everything(0)
        model = DropNet(dropout=dropout)
        cfg = TrainConfig(
            epochs=3,
            batch_size=batch,
            accumulate=accumulate,
            lr=1e-2,
            weight_decay=1e-4,
            step_size=2,
            gamma=0.5,
            seed=0,
            progress=False,
        )
        history = fit(model, Toy(N_ITEMS), Toy(16), cfg, Path(out) / job)
        if int(os.environ.get("RANK", "0")) == 0:
            from safetensors.torch import save_file

            save_file(
                {k: v.contiguous() for k, v in model.state_dict().items()}, str(Path(out) / job / "final.safetensors")
            )
            (Path(out) / job / "history.json").write_text(json.dumps(history))
    # a grasp model on 7 made-up grasps, steps of 2-3 runs (some split unevenly), under the same launch
    sys.path.insert(0, str(Path(__file__).parent / "support"))
    import tiny_grasp_train

    tiny_grasp_train.main([str(Path(out) / "grasp"), "motion-energy", "1"])


def _torchrun(out: Path) -> None:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2", __file__, str(out)]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, f"{cmd} failed:\n{proc.stdout}\n{proc.stderr}"


def test_step_plan_covers_every_item_once_for_any_world():
    for n in (1, 5, 16, 67):
        for world, batch, acc in ((1, 16, 1), (2, 8, 1), (3, 3, 2), (4, 1, 1)):
            plan = StepPlan(n, batch, world, acc, seed=7)
            for epoch in (0, 1):
                steps = plan.steps(epoch)
                flat = [i for micro in steps for m in micro for i in m]
                assert sorted(flat) == list(range(n))  # nothing repeated, nothing dropped
                # the order is the one-process order, whatever the world
                assert flat == [
                    i for micro in StepPlan(n, world * batch * acc, 1, 1, 7).steps(epoch) for m in micro for i in m
                ]
                assert all(len(micro) == world * acc for micro in steps)


def test_torchrun_equals_one_process_with_dropout_and_uneven_data(tmp_path, one_thread, monkeypatch):
    """2 ranks x batch 8 under torchrun (gloo) on 67 items: the last step's items split unevenly between
    the ranks, each rank's loss weighted by its share, no item repeated or dropped; the weights, loss and
    accuracy of one process x batch 16 (x 8 with accumulate 2 where dropout masks must match), and one
    set of files, written by rank 0."""
    from safetensors.torch import load_file

    monkeypatch.delenv("WORLD_SIZE", raising=False)
    main(str(tmp_path / "single"))
    _torchrun(tmp_path / "ddp")
    for job in JOBS:
        a = load_file(str(tmp_path / "single" / job / "final.safetensors"))
        b = load_file(str(tmp_path / "ddp" / job / "final.safetensors"))
        for k in a:
            torch.testing.assert_close(a[k], b[k], atol=1e-5, rtol=0)
        ha = json.loads((tmp_path / "single" / job / "history.json").read_text())
        hb = json.loads((tmp_path / "ddp" / job / "history.json").read_text())
        for ra, rb in zip(ha, hb):
            assert ra["train_items"] == rb["train_items"] == N_ITEMS  # no padded repeats counted
            assert ra["train_accuracy"] == rb["train_accuracy"]
            assert abs(ra["train_loss"] - rb["train_loss"]) < 1e-5
            assert ra["val_accuracy"] == rb["val_accuracy"]
        rows = (tmp_path / "ddp" / job / "metrics.csv").read_text().strip().splitlines()
        assert len(rows) == 4  # header + 3 epochs, written once
    # the grasp model (motion-energy: no batch norm, no dropout) ends with one process's weights
    a, b = (load_file(str(tmp_path / run / "grasp" / "final.safetensors")) for run in ("single", "ddp"))
    for k in a:
        torch.testing.assert_close(a[k], b[k], atol=1e-5, rtol=0)
    ha, hb = (json.loads((tmp_path / run / "grasp" / "history.json").read_text()) for run in ("single", "ddp"))
    for ra, rb in zip(ha, hb):
        assert (
            abs(ra["train_loss"] - rb["train_loss"]) <= 1e-5 * abs(ra["train_loss"])
            and ra["train_items"] == rb["train_items"]
        )


if __name__ == "__main__":
    from slipsense.training.distributed import finish

    main(sys.argv[1])
    finish()  # a rank that exits with the process group up can abort at exit
