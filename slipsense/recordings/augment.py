"""Training-set augmentation as in the paper: one transformed copy per clip, appended (as
:class:`~slipsense.datasets.ClipDataset` reads the clips: the copies are never held in memory).

The copy is made in three fixed steps: (1) add Gaussian noise (std 15 on the 0..255 scale,
rounded and clipped back to uint8), (2) swap the red and blue channels, (3) flip horizontally.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError, InputError

# Noise is generated in blocks of this many values so a whole clip set never needs a float copy
# (a full-resolution set is ~0.5 GB of uint8, 2 GB as float32).
_NOISE_BLOCK = 1 << 22


def _is_std(std) -> bool:
    """A noise standard deviation: a finite number >= 0 (not a bool)."""
    numeric = isinstance(std, (int, float, np.integer, np.floating)) and not isinstance(std, bool)
    return numeric and math.isfinite(std) and std >= 0


@dataclass(frozen=True)
class AugmentConfig:
    """Which steps make the transformed copy.

    Attributes:
        noise_std: standard deviation of the added Gaussian noise, in 0..255 intensity units
            (0 disables the step).
        swap_red_blue: exchange the red and blue channels.
        hflip: mirror each frame left-right.
        enabled: False: no copies (:class:`~slipsense.datasets.ClipDataset` appends none).
    """

    noise_std: float = 15.0
    swap_red_blue: bool = True
    hflip: bool = True
    enabled: bool = True

    def __post_init__(self) -> None:
        std = self.noise_std
        if not _is_std(std):
            raise ConfigError(f"noise_std must be a finite number >= 0, got {std!r}")
        for name in ("swap_red_blue", "hflip", "enabled"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ConfigError(f"{name} must be true or false, got {getattr(self, name)!r}")
        object.__setattr__(self, "noise_std", float(std))


def add_noise(x: np.ndarray, std: float, rng: np.random.Generator) -> np.ndarray:
    """Add zero-mean Gaussian noise to uint8 images.

    Args:
        x: uint8 array of any shape (pixel intensities 0..255).
        std: noise standard deviation in intensity units (>= 0; 0 returns a copy).
        rng: the noise source (the same generator state gives the same noise).

    Returns:
        uint8 array shaped like ``x``: ``clip(round(x + N(0, std^2)), 0, 255)``; ``x`` is untouched.
    """
    x = np.asarray(x)
    if x.dtype != np.uint8:
        raise InputError(None, f"add_noise needs uint8 images, got {x.dtype}")
    if not _is_std(std):
        raise InputError(None, f"noise std must be a finite number >= 0, got {std!r}")
    out = np.array(x, copy=True, order="C")
    if std == 0 or out.size == 0:
        return out
    flat = out.reshape(-1)
    buf = np.empty(min(_NOISE_BLOCK, flat.size), dtype=np.float32)
    for lo in range(0, flat.size, _NOISE_BLOCK):
        hi = min(lo + _NOISE_BLOCK, flat.size)
        b = buf[: hi - lo]
        rng.standard_normal(out=b, dtype=np.float32)
        b *= np.float32(std)
        b += flat[lo:hi]
        np.rint(b, out=b)
        np.clip(b, 0, 255, out=b)
        flat[lo:hi] = b
    return out


def transform_clip(x: np.ndarray, cfg: AugmentConfig, rng: np.random.Generator) -> np.ndarray:
    """The augmented copy of one clip.

    Args:
        x: uint8 ``(T, H, W, 3)`` BGR clip.
        cfg: which steps to apply (noise, then red/blue swap, then horizontal flip).
        rng: noise source.

    Returns:
        New uint8 ``(T, H, W, 3)`` array; ``x`` is untouched. With ``cfg.enabled`` False, a copy.
    """
    x = np.asarray(x)
    if x.dtype != np.uint8 or x.ndim != 4 or x.shape[-1] != 3:
        raise InputError(None, f"a clip must be uint8 (T, H, W, 3), got {x.dtype} {x.shape}")
    if not cfg.enabled:
        return x.copy()
    out = add_noise(x, cfg.noise_std, rng) if cfg.noise_std > 0 else x
    if cfg.swap_red_blue:
        out = out[..., ::-1]  # BGR -> RGB order: blue and red exchange, green stays
    if cfg.hflip:
        out = out[:, :, ::-1]
    return np.ascontiguousarray(out) if out is not x else x.copy()


__all__ = ["AugmentConfig", "add_noise", "transform_clip"]
