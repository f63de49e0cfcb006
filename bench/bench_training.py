"""Training throughput, where the time goes, and the compute bound; replay speed; wall times.

    .venv/bin/python bench/bench_training.py --out bench/results/training.md
    .venv/bin/python bench/bench_training.py --wall main,fold --reference 1e1faa0 --out ...   # + commands

What is measured, on one thread, on the shared recordings (fold 0's training objects):

* **grasp task** (the default detector, `motionnet`, whole grasps): one epoch's chunks of the
  shipped recipe (48 scored frames per chunk), trained step by step (forward, backward, AdamW) two
  ways side by side in one run: *reference*, the step as it was (16 chunks from 16 runs per batch,
  every chunk's 78 frames encoded, planar difference channels, a finite check of the input) and
  *current* (:func:`slipsense.training.grasps.fit_runs`' step: the chunks of ~3 runs per batch, each
  distinct frame encoded once, channels-last differences). Throughput in scored frames per second
  (a frame = both sensors' images at one instant) and their ratio;
* **clip task** (the paper's ViViT on 5-frame 240 x 320 clips, `slipsense train --model vivit`):
  forward, backward and Adam on batches of 32 clips, frames per second;
* **compute bound**: multiply-adds per frame (``torch.utils.flop_counter``), this
  machine's float32 GFLOP/s on one thread (a 1024 x 1024 matrix product), so frames per second
  if training ran at that rate (forward + backward = 3x the forward's work);
* **profile**: the operators of the current grasp step by self time (torch.profiler);
* **replay**: a 450-frame run of both sensors through the shipped detector
  (``SlipDetector.replay``), in multiples of real time (25 frames/s), beside pushing frame by frame;
* ``--wall``: the wall time of commands (each with an empty cache): ``main`` = ``bash
  scripts/main.sh``, ``fold`` = ``slipsense grasp train --config configs/motionnet.yaml --fold 0``
  (one fold with its inner folds), ``folds`` = ``slipsense grasp folds --config
  configs/motionnet.yaml`` (five folds); with ``--reference REV`` the same commands also run in a
  git worktree of REV (its own .venv set up by its scripts) in the same run, for ratios.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from slipsense.training import grasps as G  # noqa: E402
from slipsense.training.grasp_detector import object_folds_of  # noqa: E402
from slipsense.paths import gelsight_recordings  # noqa: E402
from slipsense.models import build  # noqa: E402

FPS = 25.0


# ------------------------------------------------------------------------------ grasp task


def _reference_batches(data, cfg, rng):
    """The step as it was before chunks shared frames: every chunk cut out whole (its 30 frames of
    temporal context and 100 of lag before the scored ones), batches of ``batch_size`` chunks in
    random order."""
    model_context = 30 + 100  # receptive_field - 1 + max_lag of the shipped recipe
    length = model_context + cfg.chunk
    out = []
    for i, ends, targets in data.draw(rng):
        gray = data.items[i][0]
        for e, t in zip(ends, targets):
            out.append((gray[:, np.arange(e - length + 1, e + 1).clip(min=0)], t))
    order = rng.permutation(len(out))
    out = [out[i] for i in order]
    for a in range(0, len(out), cfg.batch_size):
        part = out[a : a + cfg.batch_size]
        yield (
            torch.from_numpy(np.stack([c[0] for c in part])).float().div_(255.0),
            torch.from_numpy(np.stack([c[1] for c in part])),
        )


def _reference_logits(model, gray, n_out):
    """The forward of the last ``n_out`` frames as it was: planar differences, the input checked for finite values."""
    if not bool(torch.isfinite(gray).all()):
        raise ValueError("non-finite input")
    need = n_out + model.receptive_field - 1
    t = gray.shape[2]
    gray = model.levelled(gray)  # the recipe's frame levelling, as the current step does
    cur = gray[:, :, t - need :]
    diffs = torch.stack([cur - gray[:, :, t - need - lag : t - lag] for lag in model.lags], dim=3)
    return model.classify(model.encode(diffs * model.diff_scale))


def _current_batches(data, chunks, cfg, rng):
    """The training step's batches (:class:`~slipsense.training.grasps.GraspTask` without flips):
    whole runs' chunks, about ``batch_size`` per batch, each run's frames once."""
    for part, _ in G._groups(chunks, cfg.batch_size, False, rng):
        x = [(torch.from_numpy(data.items[i][0]).float().div_(255.0), ends) for i, ends, _ in part]
        yield x, torch.from_numpy(np.concatenate([c[2] for c in part]))


def _step(model, opt, logits, y):
    keep = (y == 0) | (y == 1)  # not the ignored frames (-1) nor grasps labelled as a whole
    loss = F.cross_entropy(logits[keep], y[keep])
    opt.zero_grad(set_to_none=True)
    loss.backward()
    opt.step()
    return int(keep.sum())


def grasp_throughput(runs, cfg, seconds: float) -> dict:
    """Scored frames per second, reference vs current step, interleaved in rounds."""
    torch.manual_seed(0)
    base = build(cfg.model, **cfg.model_config).train()
    data = G._Chunks(runs, cfg)
    result = {}
    models = {"reference": base, "current": build(cfg.model, **cfg.model_config).train()}
    models["current"].load_state_dict(base.state_dict())
    opts = {k: torch.optim.AdamW(m.parameters(), lr=cfg.lr) for k, m in models.items()}
    frames = {k: 0 for k in models}
    busy = {k: 0.0 for k in models}
    rng = np.random.default_rng(0)
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline:
        for name, model in models.items():
            if name == "reference":
                batches = _reference_batches(data, cfg, np.random.default_rng(rng.integers(1 << 30)))
            else:
                chunks = data.draw(np.random.default_rng(rng.integers(1 << 30)))
                batches = _current_batches(data, chunks, cfg, rng)
            for k, (x, y) in enumerate(batches):
                t0 = time.perf_counter()
                if name == "reference":
                    logits = _reference_logits(model, x, cfg.chunk)
                else:
                    logits = model.chunk_logits(x, cfg.chunk)
                _step(model, opts[name], logits, y)
                busy[name] += time.perf_counter() - t0
                frames[name] += int(y.numel())
                if k == 7:  # 8 batches per round and way: the two stay interleaved
                    break
    for name in models:
        result[name] = {"frames": frames[name], "seconds": busy[name], "frames_per_s": frames[name] / busy[name]}
    result["ratio"] = result["current"]["frames_per_s"] / result["reference"]["frames_per_s"]
    return result


def grasp_profile(runs, cfg) -> list[dict]:
    from torch.profiler import ProfilerActivity, profile

    torch.manual_seed(0)
    model = build(cfg.model, **cfg.model_config).train()
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr)
    data = G._Chunks(runs, cfg)
    rng = np.random.default_rng(1)
    batches = list(_current_batches(data, data.draw(rng), cfg, rng))[:12]
    for x, y in batches[:2]:
        _step(model, opt, model.chunk_logits(x, cfg.chunk), y)
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for x, y in batches[2:]:
            _step(model, opt, model.chunk_logits(x, cfg.chunk), y)
    rows = sorted(prof.key_averages(), key=lambda e: -e.self_cpu_time_total)
    total = sum(e.self_cpu_time_total for e in rows)
    return [
        {"operator": e.key, "self_percent": 100.0 * e.self_cpu_time_total / total, "calls": e.count} for e in rows[:10]
    ]


# ------------------------------------------------------------------------------ clip task and bound


def count_macs(model, x) -> int:
    """Multiply-adds of one forward of ``x`` (every matrix product and convolution, counted by
    ``torch.utils.flop_counter``: half its FLOPs)."""
    from torch.utils.flop_counter import FlopCounterMode

    with torch.no_grad(), FlopCounterMode(display=False) as counter:
        model(x)
    return counter.get_total_flops() // 2


def machine_gflops(seconds: float = 2.0) -> float:
    a, b = torch.randn(1024, 1024), torch.randn(1024, 1024)
    a @ b
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        a @ b
        n += 1
    return 2 * 1024**3 * n / (time.perf_counter() - t0) / 1e9


def clip_throughput(seconds: float) -> dict:
    torch.manual_seed(0)
    model = build("vivit").train()
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    x = torch.rand(32, model.frames, 3, *model.image_size)
    y = torch.randint(0, 2, (32,))
    n, busy = 0, 0.0
    while busy < seconds:
        t0 = time.perf_counter()
        loss = F.cross_entropy(model(x), y)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        busy += time.perf_counter() - t0
        n += 1
    return {
        "frames_per_s": n * 32 * model.frames / busy,
        "macs_per_frame": count_macs(model.eval(), x[:1]) / model.frames,
    }


# ------------------------------------------------------------------------------ replay


def replay_speed(run_dir: Path) -> dict:
    from slipsense.streaming.detector import SlipDetector
    from slipsense.recordings.video import read_video

    videos = [read_video(run_dir / f"camera_{c}.avi") for c in (0, 2)]
    n = len(videos[0])
    det = SlipDetector.pretrained(sensors=2, backend="torch")
    det.replay(*videos)
    t0 = time.perf_counter()
    for _ in range(3):
        det.replay(*videos)
    replay_s = (time.perf_counter() - t0) / 3
    det.reset()
    t0 = time.perf_counter()
    for a, b in zip(*videos):
        det.push(a, b)
    push_s = time.perf_counter() - t0
    return {
        "frames": n,
        "replay_s": replay_s,
        "replay_x_real_time": n / FPS / replay_s,
        "push_s": push_s,
        "push_x_real_time": n / FPS / push_s,
    }


# ------------------------------------------------------------------------------ wall times


def _wall_commands(which: str, out: Path) -> list[str]:
    cfg = "configs/motionnet.yaml"
    return {
        "main": ["bash", "scripts/main.sh"],
        "fold": [".venv/bin/slipsense", "grasp", "train", "--config", cfg, "--fold", "0", "--out", str(out)],
        "folds": [".venv/bin/slipsense", "grasp", "folds", "--config", cfg, "--out", str(out)],
    }[which]


def wall_time(checkout: Path, which: str) -> float:
    """Seconds of one command in ``checkout``, with an empty cache (its venv set up before)."""
    with tempfile.TemporaryDirectory() as tmp:
        # the data this checkout reads, wherever the other checkout lies
        data = str(gelsight_recordings().resolve().parent)
        env = {**os.environ, "SLIPSENSE_CACHE": str(Path(tmp) / "cache"), "SLIPSENSE_DATA": data}
        cmd = _wall_commands(which, Path(tmp) / "out")
        if which != "main":
            cmd = [*cmd, "--no-progress"]
        t0 = time.perf_counter()
        subprocess.run(cmd, cwd=checkout, env=env, check=True, stdout=subprocess.DEVNULL)
        return time.perf_counter() - t0


def walls(kinds: list[str], reference: str | None) -> list[dict]:
    rows = []
    ref_dir = None
    try:
        if reference:
            ref_dir = Path(tempfile.mkdtemp(prefix="slipsense-ref-"))
            subprocess.run(["git", "worktree", "add", "--detach", str(ref_dir), reference], cwd=ROOT, check=True)
            subprocess.run(["bash", "scripts/setup.sh"], cwd=ref_dir, check=True)
        subprocess.run(["bash", "scripts/setup.sh"], cwd=ROOT, check=True)
        for kind in kinds:
            row = {"command": " ".join(_wall_commands(kind, Path("OUT"))), "current_s": wall_time(ROOT, kind)}
            print(row, flush=True)
            if ref_dir is not None:
                row["reference_s"] = wall_time(ref_dir, kind)
                row["ratio"] = row["reference_s"] / row["current_s"]
            rows.append(row)
            print(row, flush=True)
    finally:
        if ref_dir is not None:
            subprocess.run(["git", "worktree", "remove", "--force", str(ref_dir)], cwd=ROOT, check=False)
            shutil.rmtree(ref_dir, ignore_errors=True)
    return rows


# ------------------------------------------------------------------------------ report


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=40.0, help="timed seconds per throughput measurement")
    parser.add_argument("--wall", default="", help="comma-separated: main, fold, folds")
    parser.add_argument("--reference", help="a git revision to time beside the checkout (--wall)")
    parser.add_argument("--out", type=Path, help="also write the Markdown report here (and .json beside it)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    from studies.experiments.report import cpu_description

    cfg = G.make_config("motionnet", {})  # the shipped recipe's model and training settings
    size = tuple(cfg.model_config.get("image_size") or (30, 40))
    runs, _ = G.load_grasp_data(gelsight_recordings(), None, size, progress=False)
    usable = [r for r in runs if r.usable]
    held = object_folds_of(usable, 5, 0)[0]
    train = [r for r in usable if r.object not in held]
    grasp = grasp_throughput(train, cfg, args.seconds)
    model = build(cfg.model, **cfg.model_config).eval()
    macs = count_macs(model, torch.rand(1, model.sensors, 200, *model.image_size)) / 200
    gflops = machine_gflops()
    clip = clip_throughput(args.seconds / 2)
    prof = grasp_profile(train, cfg)
    replay = replay_speed(gelsight_recordings() / "lemon" / "exp_num_1")
    wall = walls([w for w in args.wall.split(",") if w], args.reference) if args.wall else []
    bound_grasp = gflops * 1e9 / (3 * 2 * macs)
    bound_clip = gflops * 1e9 / (3 * 2 * clip["macs_per_frame"])
    epoch_frames = sum(r.n_frames - cfg.startup for r in train)  # the start-up frames it skips
    lines = [
        "# Training throughput, replay and wall times",
        "",
        f"`python bench/bench_training.py{' --wall ' + args.wall if args.wall else ''}"
        f"{' --reference ' + args.reference if args.reference else ''}` on {cpu_description()}, one thread; "
        f"fold 0's {len(train)} training runs ({epoch_frames} frames after the start-up).",
        "",
        "## Training steps (forward, backward, optimiser)",
        "",
        "| task | way | frames/s | compute bound frames/s | of the bound |",
        "|---|---|---:|---:|---:|",
        f"| grasp (motionnet, 2 sensors) | reference (before) | {grasp['reference']['frames_per_s']:.0f} | "
        f"{bound_grasp:.0f} | {100 * grasp['reference']['frames_per_s'] / bound_grasp:.1f}% |",
        f"| grasp (motionnet, 2 sensors) | current | {grasp['current']['frames_per_s']:.0f} | {bound_grasp:.0f} | "
        f"{100 * grasp['current']['frames_per_s'] / bound_grasp:.1f}% |",
        f"| clip (ViViT, 5 x 240 x 320) | current | {clip['frames_per_s']:.0f} | {bound_clip:.0f} | "
        f"{100 * clip['frames_per_s'] / bound_clip:.1f}% |",
        "",
        f"Grasp step: current / reference = **{grasp['ratio']:.2f}x** (scored frames per second). A grasp frame "
        f"is {macs / 1e6:.2f} M multiply-adds (both sensors' encoders and the temporal part), a ViViT frame "
        f"{clip['macs_per_frame'] / 1e6:.1f} M; this machine multiplies 1024 x 1024 float32 matrices at "
        f"{gflops:.0f} GFLOP/s on one thread, the bound above (3 x the forward's work per frame). The grasp "
        "bound counts scored frames only: a chunk also encodes frames of context, which the current step "
        "shares between a run's chunks.",
        "",
        "## Where the current grasp step spends its time (torch.profiler, self time)",
        "",
        "| operator | self % | calls |",
        "|---|---:|---:|",
        *[f"| `{p['operator']}` | {p['self_percent']:.1f} | {p['calls']} |" for p in prof],
        "",
        "## Replay of a whole run (lemon/exp_num_1, both sensors, shipped detector)",
        "",
        "| way | seconds | x real time (25 frames/s) |",
        "|---|---:|---:|",
        f"| replay (whole run at once) | {replay['replay_s']:.3f} | {replay['replay_x_real_time']:.0f} |",
        f"| push frame by frame | {replay['push_s']:.3f} | {replay['push_x_real_time']:.0f} |",
        "",
    ]
    if wall:
        lines += ["## Wall time of commands (empty cache, venv set up)", ""]
        lines += ["| command | current s | reference s | reference / current |", "|---|---:|---:|---:|"]
        for w in wall:
            ref = f"{w['reference_s']:.0f}" if "reference_s" in w else "-"
            ratio = f"{w['ratio']:.2f}x" if "ratio" in w else "-"
            lines.append(f"| `{w['command']}` | {w['current_s']:.0f} | {ref} | {ratio} |")
        lines.append("")
    text = "\n".join(lines)
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
        doc = {"grasp": grasp, "clip": clip, "profile": prof, "replay": replay, "wall": wall, "gflops": gflops}
        args.out.with_suffix(".json").write_text(json.dumps(doc, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
