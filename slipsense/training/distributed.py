"""torchrun DDP plumbing: the process group, and a step plan that makes any world size train alike.

``torchrun --nproc_per_node N -m slipsense.cli train ...`` runs N processes (gloo on CPU, NCCL on
GPU); :func:`setup` joins them. :class:`StepPlan` gives every world size the same micro-batches,
and :func:`micro_batch_rng` the same dropout masks, so N processes train like one process with
``accumulate = N`` (tests/test_reliability_ddp.py).
"""

from __future__ import annotations

import contextlib
import gc
import os
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.distributed as dist


@dataclass
class Dist:
    rank: int = 0
    world: int = 1
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))

    @property
    def main(self) -> bool:
        return self.rank == 0


def setup(device: str = "auto") -> Dist:
    """Join the torchrun process group when launched by torchrun, else a 1-process world."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    if world > 1:
        local = int(os.environ.get("LOCAL_RANK", "0"))
        if device.startswith("cuda"):
            torch.cuda.set_device(local)
            device = f"cuda:{local}"
        if not dist.is_initialized():
            dist.init_process_group(backend="nccl" if device.startswith("cuda") else "gloo")
        return Dist(dist.get_rank(), dist.get_world_size(), torch.device(device))
    return Dist(0, 1, torch.device(device))


def finish(wait: bool = True) -> None:
    """Leave the torchrun process group, if one was joined: after a barrier (``wait``, when every rank
    got here alike), so no rank tears down its connections while another still uses them. A rank that
    exits with the group up, or leaves it before the others, can abort at exit ("terminate called
    without an active exception", exit -6; 7 of 15 two-rank gloo runs without the barrier). The
    garbage collection first frees a finished DistributedDataParallel wrapper (its reducer holds the
    group through reference cycles), which otherwise dies during interpreter shutdown and aborts there
    too: 5 of 16 runs beside two busy processes without it, 0 of 32 with it. Call it at the end of a
    script that trained under torchrun; the CLI does."""
    if dist.is_available() and dist.is_initialized():
        gc.collect()
        if wait:
            dist.barrier()
        dist.destroy_process_group()
        gc.collect()


def all_sum(values: torch.Tensor, d: Dist) -> torch.Tensor:
    if d.world > 1:
        values = values.clone()
        dist.all_reduce(values, op=dist.ReduceOp.SUM)
    return values


class StepPlan:
    """Which items every micro-batch of every training step holds; the same for any world size.

    Epoch ``e`` shuffles the ``n`` items with ``torch.randperm`` seeded ``seed + e`` (the order a
    one-replica DistributedSampler gives). Step ``s`` takes the next ``world x batch x accumulate``
    items of that order and cuts them into ``world x accumulate`` micro-batches of ``batch`` items
    (the last step's may be short or empty); micro-batch ``m`` runs on rank ``m // accumulate``.
    """

    def __init__(self, n: int, batch: int, world: int = 1, accumulate: int = 1, seed: int = 0):
        self.n, self.batch, self.world, self.accumulate, self.seed = n, batch, world, accumulate, seed

    @property
    def global_batch(self) -> int:
        return self.world * self.batch * self.accumulate

    def steps(self, epoch: int) -> list[list[list[int]]]:
        order = torch.randperm(self.n, generator=torch.Generator().manual_seed(self.seed + epoch)).tolist()
        b, parts = self.batch, range(self.world * self.accumulate)
        return [[order[a + m * b : a + (m + 1) * b] for m in parts] for a in range(0, self.n, self.global_batch)]


class RankBatches:
    """Batch sampler: this rank's non-empty micro-batches of an epoch, in order."""

    def __init__(self, plan: StepPlan, rank: int):
        self.plan, self.rank, self.epoch = plan, rank, 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def _mine(self) -> list[list[int]]:
        a = self.plan.accumulate
        return [m for micro in self.plan.steps(self.epoch) for m in micro[self.rank * a : (self.rank + 1) * a] if m]

    def __iter__(self):
        return iter(self._mine())

    def __len__(self) -> int:
        return len(self._mine())


@contextlib.contextmanager
def micro_batch_rng(seed: int, epoch: int, step: int, micro: int, device: torch.device):
    """Run a micro-batch with torch's generator seeded from ``(seed, epoch, step, micro)`` only.

    Dropout masks (and any other random draw of the forward pass) then depend on which items are
    computed together, never on which process computes them or on what ran before, so a torchrun
    world and one process with ``accumulate = world`` draw the same masks, and a resumed run the
    masks of an uninterrupted one. The generator state outside is left as it was.
    """
    key = int(np.random.SeedSequence([seed, epoch, step, micro]).generate_state(1, np.uint64)[0])
    cuda = device.type == "cuda"
    with torch.random.fork_rng(devices=[device] if cuda else [], device_type="cuda"):
        torch.manual_seed(key)
        yield
