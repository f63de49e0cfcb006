"""Fixtures shared by the test modules: one torch thread, a private cache, made-up grasp recordings,
and the shared GelSight data when it is there."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from slipsense.paths import gelsight_recordings

#: one run of the shared recordings that the tests read a few frames of
REAL_RUN = gelsight_recordings() / "avocado_real" / "exp_num_1"
#: `slipsense train` options for a tiny TemNet on made-up marker data (seconds per run)
TINY_TRAIN_ARGS = [
    "--model",
    "temnet",
    "--set",
    "d_model=8",
    "--set",
    "heads=2",
    "--set",
    "blocks=1",
    "--set",
    "ff_dim=8",
    "--set",
    "head_hidden=0",
    "--batch-size",
    "4",
    "--no-progress",
]

needs_data = pytest.mark.skipif(not (REAL_RUN / "camera_0.avi").is_file(), reason="shared GelSight data not present")


@pytest.fixture
def one_thread():
    """One intra-op thread: the models under test are tiny, and on a busy machine every parallel
    operation waits for a descheduled worker (10x slower); restored afterwards."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


class FolderOpens:
    """Every folder listed while recording (``os.listdir`` / ``os.scandir`` audit events, by path)."""

    _active: list["FolderOpens"] = []
    _hooked = False

    def __init__(self) -> None:
        self.listed: list[Path] = []

    @classmethod
    def _audit(cls, event: str, args) -> None:
        if cls._active and event in ("os.listdir", "os.scandir"):
            path = Path(args[0] if args and args[0] is not None else ".")
            for rec in cls._active:
                rec.listed.append(path)

    def __enter__(self) -> "FolderOpens":
        if not FolderOpens._hooked:  # an audit hook stays for the process: one, idle unless recording
            import sys

            sys.addaudithook(FolderOpens._audit)
            FolderOpens._hooked = True
        self.listed.clear()
        FolderOpens._active.append(self)
        return self

    def __exit__(self, *exc) -> None:
        FolderOpens._active.remove(self)

    def count(self, folder: Path) -> int:
        return sum(p == Path(folder) for p in self.listed)


@pytest.fixture
def folder_opens() -> FolderOpens:
    """Counts the listings of each folder inside ``with folder_opens:``."""
    return FolderOpens()


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    """A private ``SLIPSENSE_CACHE`` for the test."""
    monkeypatch.setenv("SLIPSENSE_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache"


def write_grasp_video(path: Path, n: int, contact: tuple[int, int], slide: bool, seed: int) -> None:
    """A 48 x 64 XVID video: a bright pressed square during ``contact`` (first, last frame) that
    slides sideways over its last 8 frames when ``slide``."""
    rng = np.random.default_rng(seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"XVID"), 25, (64, 48))
    for t in range(n):
        f = np.full((48, 64, 3), 110, np.uint8) + rng.integers(0, 4, (48, 64, 3), dtype=np.uint8)
        if contact[0] <= t <= contact[1]:
            x = 16 + (max(0, t - contact[1] + 8) * 2 if slide else 0)
            f[12:36, x : x + 24] = 200
        w.write(f)
    w.release()


@pytest.fixture(scope="session")
def grasp_recordings(tmp_path_factory) -> Path:
    """4 objects, each one run that slips (the pressed square slides, then leaves) and one that holds,
    two cameras per run, in the GelSight folder layout."""
    root = tmp_path_factory.mktemp("grasps")
    for i in range(4):
        for exp, slip in ((1, True), (2, False)):
            for cam in (0, 2):
                write_grasp_video(
                    root / f"obj{i}" / f"exp_num_{exp}" / f"camera_{cam}.avi",
                    70,
                    (20, 50 if slip else 69),
                    slip,
                    seed=100 * i + 10 * exp + cam,
                )
            if slip:
                (root / f"obj{i}" / f"exp_num_{exp}" / "slip.txt").write_text("")
    return root


def _cli(args) -> None:
    import sys

    import torch

    from slipsense.cli import main

    torch.set_num_threads(1)
    sys.argv = ["slipsense", *args]
    main()


def sigkill_when(path: Path, args) -> None:
    """Run ``slipsense ARGS`` in a forked process (torch already imported: seconds saved per model) and
    SIGKILL it as soon as ``path`` exists (or it ends, or 120 s pass)."""
    import multiprocessing
    import os
    import signal
    import time

    proc = multiprocessing.get_context("fork").Process(target=_cli, args=([str(a) for a in args],))
    proc.start()
    deadline = time.time() + 120
    while not path.exists() and proc.is_alive() and time.time() < deadline:
        time.sleep(0.002)
    os.kill(proc.pid, signal.SIGKILL)
    proc.join()


def killed_once(state, args) -> int:
    """:func:`sigkill_when` ``state`` (its resume state after the first epoch) exists; returns the
    epochs it had saved."""
    sigkill_when(state, args)
    assert state.exists(), f"no resume state at {state}"
    from slipsense.checkpoint import load_resume_state

    return load_resume_state(state)["epoch"]


def onnx_output(path, *x):
    """The first output of the ONNX file ``path`` on ONNX Runtime for its inputs ``x`` in order
    (tensors or arrays)."""
    from slipsense.models.onnx import onnx_session

    session = onnx_session(path)
    arrays = [v.detach().cpu().numpy() if isinstance(v, torch.Tensor) else v for v in x]
    feed = {i.name: np.ascontiguousarray(a) for i, a in zip(session.get_inputs(), arrays)}
    return session.run(None, feed)[0]


def perturbed(model: torch.nn.Module, seed: int = 0, scale: float = 0.1) -> torch.nn.Module:
    """Move every parameter off its initial value (LayerNorm weights != 1 etc.), so that folded fast
    paths are exercised and a weight that fails to load shows."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(torch.randn(p.shape, generator=g) * scale)
    return model


def random_clip(*shape: int, seed: int = 0) -> torch.Tensor:
    """Uniform [0, 1) values of ``shape``, seeded (a video clip ``(B, T, 3, H, W)``)."""
    return torch.rand(*shape, generator=torch.Generator().manual_seed(seed))
