"""torch Datasets over prepared data: GelSight clips and marker-cloud sequences.

Both yield ``(x, y)`` with ``x`` float32 in the layout the models take and ``y`` an int64 label
(1 = slip / onset of slip, 0 = no slip / wiggle).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch.utils.data import Dataset

from slipsense.errors import ConfigError
from slipsense.recordings.augment import add_noise, transform_clip
from slipsense.sensors.marker_grid import GridMove, grid_layout, rest_estimate


def clip_to_tensor(clip: np.ndarray) -> torch.Tensor:
    """uint8 ``(T, H, W, 3)`` BGR -> float32 ``(T, 3, H, W)`` in [0, 1] (the video models' input)."""
    return torch.from_numpy(np.ascontiguousarray(clip)).permute(0, 3, 1, 2).float().div_(255.0)


class ClipDataset(Dataset):
    """Clips of a :class:`~slipsense.recordings.clips.ClipSet`, optionally with the paper's
    augmentation appended: indices ``N..2N-1`` are the transformed copies of ``0..N-1``.

    A copy's random noise is seeded by ``(seed, index)``, so it is the same every epoch and on every
    rank — a fixed augmented dataset as in the paper, without holding the copies in memory.
    """

    def __init__(self, clips, augment=None, seed: int = 0, noise_std: float = 0.0):
        if not isinstance(noise_std, (int, float)) or not math.isfinite(noise_std) or noise_std < 0:
            raise ConfigError(f"noise_std must be a finite number >= 0, got {noise_std!r}")
        self.clips = clips
        self.augment = augment if (augment is not None and augment.enabled) else None
        self.seed = seed
        self.noise_std = noise_std  # evaluation-time noise (robustness experiments)

    def __len__(self) -> int:
        n = len(self.clips)
        return 2 * n if self.augment is not None else n

    def __getitem__(self, index: int):
        n = len(self.clips)
        clip = self.clips.x[index % n]
        if index >= n:
            clip = transform_clip(clip, self.augment, np.random.default_rng([self.seed, index]))
        if self.noise_std > 0:
            clip = add_noise(clip, self.noise_std, np.random.default_rng([self.seed, 1, index]))
        return clip_to_tensor(clip), torch.tensor(int(self.clips.y[index % n]))


def check_marker_copies(value, option: str = "marker copies") -> int:
    """``value`` as a count of times each marker window is seen (itself and its moved copies);
    ConfigError naming ``option`` unless an integer >= 1."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigError(f"{option} must be an integer >= 1, got {value!r}")
    return value


class MarkerDataset(Dataset):
    """Marker-cloud sequences: ``x`` float32 ``(N, T, M, 3)``, ``y`` int ``(N,)``.

    ``copies > 1`` appends ``copies - 1`` moved copies of every window when the markers lie on a grid
    (:mod:`slipsense.sensors.marker_grid`): index ``k N + i`` is window ``i`` mirrored and shifted
    by a move drawn from ``(seed, k N + i)``, so the same every epoch and on every rank (a fixed
    augmented set, as the video clips' augmentation). The gel at rest is estimated from the windows'
    first frames (:func:`~slipsense.sensors.marker_grid.rest_estimate`). Markers off a grid get no
    copies: ``copies`` says how many each window is seen, ``windows`` how many originals there are
    (indices ``0..windows-1``)."""

    def __init__(self, x: np.ndarray, y: np.ndarray, copies: int = 1, seed: int = 0, max_shift: int = 3):
        check_marker_copies(copies)
        self.x = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))
        self.y = torch.from_numpy(np.asarray(y, dtype=np.int64))
        self.copies, self.seed, self.max_shift = 1, seed, max_shift
        self.grid = None
        if copies > 1 and len(self.y):
            self.rest = rest_estimate(self.x[:, 0].numpy())
            self.grid = grid_layout(self.rest)
            self.copies = copies if self.grid is not None else 1

    @property
    def windows(self) -> int:
        return len(self.y)

    def __len__(self) -> int:
        return len(self.y) * self.copies

    def __getitem__(self, index: int):
        n = len(self.y)
        x = self.x[index % n]
        if index >= n:
            move = GridMove.draw(np.random.default_rng([self.seed, index]), self.max_shift)
            x = torch.from_numpy(move.apply(x.numpy(), self.rest, self.grid))
        return x, self.y[index % n]
