"""A tiny training job for the DDP and resume tests, runnable as a script (also under torchrun).

    python tiny_train.py OUT_DIR BATCH_SIZE EPOCHS [KILL_AFTER_ITEMS] [--resume] [--items=N]

Writes ``OUT_DIR/final.pt`` (the state dict) on rank 0. With KILL_AFTER_ITEMS the process
SIGKILLs itself after reading that many training items: a kill mid-epoch, at a point that no
checkpoint write can protect against except by being atomic.
"""

from __future__ import annotations

import os
import signal
import sys

import torch
import torch.nn as nn
from torch.utils.data import Dataset

from slipsense.models import MarkerModel, register
from slipsense.training.clips import TrainConfig, fit, seed_everything


@register("test-tiny")
class TinyNet(MarkerModel):
    def __init__(self, frames: int = 4, markers: int = 6, hidden: int = 16):
        super().__init__()
        self._config = dict(frames=frames, markers=markers, hidden=hidden)
        self.net = nn.Sequential(nn.Flatten(), nn.Linear(frames * markers * 3, hidden), nn.Tanh(), nn.Linear(hidden, 2))

    def config(self):
        return dict(self._config)

    def forward(self, x):
        return self.net(x)


class Toy(Dataset):
    def __init__(self, n=64, kill_after=None):
        g = torch.Generator().manual_seed(123)
        self.x = torch.randn(n, 4, 6, 3, generator=g)
        self.y = (self.x[:, :, :, 0].mean(dim=(1, 2)) > 0).long()
        self.kill_after = kill_after
        self.reads = 0

    def __len__(self):
        return len(self.y)

    def __getitem__(self, i):
        self.reads += 1
        if self.kill_after is not None and self.reads > self.kill_after:
            os.kill(os.getpid(), signal.SIGKILL)
        return self.x[i], self.y[i]


def main(argv):
    resume = "--resume" in argv
    items = next((int(a.split("=", 1)[1]) for a in argv if a.startswith("--items=")), 64)
    args = [a for a in argv if a != "--resume" and not a.startswith("--items=")]
    out, batch, epochs = args[0], int(args[1]), int(args[2])
    kill_after = int(args[3]) if len(args) > 3 else None
    seed_everything(0)
    model = TinyNet()
    cfg = TrainConfig(
        epochs=epochs, batch_size=batch, lr=1e-2, weight_decay=1e-4, step_size=2, gamma=0.5, seed=0, progress=False
    )
    fit(model, Toy(items, kill_after=kill_after), Toy(16), cfg, out, resume=resume)
    if int(os.environ.get("RANK", "0")) == 0:
        torch.save(model.state_dict(), os.path.join(out, "final.pt"))


if __name__ == "__main__":
    from slipsense.training.distributed import finish

    main(sys.argv[1:])
    finish()
