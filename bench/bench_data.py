"""Data throughput against training throughput: does loading starve training?

Loads the (cached) clips of the shared recordings, then measures, side by side in one process,
clips/s delivered by the DataLoader (with the paper's augmentation, 0 and N workers) and clips/s
trained by ViViT (forward + backward + Adam step, batch 16). A ratio above 1 means the loader keeps
up. Usage::

    python bench/bench_data.py [--size 120x160] [--batches 20] [--workers 2]
"""

from __future__ import annotations

import argparse
import time

import torch
from torch.utils.data import DataLoader


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", default="120x160")
    ap.add_argument("--batches", type=int, default=20)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    h, w = (int(v) for v in args.size.split("x"))

    from slipsense.paths import gelsight_recordings
    from slipsense.data import gelsight_clips
    from slipsense.datasets import ClipDataset
    from slipsense.models import build
    from slipsense.recordings.augment import AugmentConfig
    from slipsense.recordings.clips import ClipSpec

    t0 = time.perf_counter()
    clips, _ = gelsight_clips(
        gelsight_recordings(), ClipSpec(size=(h, w)), overrides="configs/gelsight-label-overrides.csv", progress=False
    )
    print(
        f"clip set: {len(clips)} clips of {tuple(clips.x.shape[1:])} prepared/loaded in {time.perf_counter() - t0:.1f} s"
    )
    data = ClipDataset(clips, AugmentConfig(), seed=0)
    # Augmented copies (second half) cost the most: load from there.
    sub = torch.utils.data.Subset(data, range(len(clips), len(data)))
    rows = []
    for workers in sorted({0, args.workers}):
        loader = DataLoader(sub, batch_size=16, shuffle=True, num_workers=workers)
        it = iter(loader)
        next(it)  # start-up (worker spawn) is not throughput
        t = time.perf_counter()
        n = 0
        for _ in range(args.batches):
            try:
                x, _ = next(it)
            except StopIteration:
                break
            n += len(x)
        rows.append((f"load (augmented, {workers} workers)", n / (time.perf_counter() - t)))
    patch = (h // 6, w // 8)
    model = build("vivit", image_size=(h, w), patch_size=patch)
    opt = torch.optim.Adam(model.parameters(), lr=3e-4)
    x = torch.rand(16, 5, 3, h, w)
    y = torch.randint(0, 2, (16,))
    for i in range(args.batches + 2):
        if i == 2:
            t = time.perf_counter()
        loss = torch.nn.functional.cross_entropy(model(x), y)
        opt.zero_grad()
        loss.backward()
        opt.step()
    train_rate = 16 * args.batches / (time.perf_counter() - t)
    print("\n| stage | clips/s | load / train |\n|---|---:|---:|")
    for name, rate in rows:
        print(f"| {name} | {rate:.0f} | {rate / train_rate:.2f} |")
    print(f"| train ViViT {h}x{w} (batch 16) | {train_rate:.0f} | 1.00 |")


if __name__ == "__main__":
    main()
