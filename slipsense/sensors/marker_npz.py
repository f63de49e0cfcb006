"""The marker dataset format: :class:`MarkerDataset` in memory, the marker ``.npz`` on disk
(:func:`load_marker_npz`; written by :func:`slipsense.marker_sequences.save_marker_npz`).

The same format holds simulated and real marker windows; every file read is validated and any
problem is an InputError naming the file.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slipsense.errors import InputError
from slipsense.sensors.spec import fps_problem

#: The binocular sensor's objects and motion patterns (the STNet study's; a file may name others).
OBJECTS: tuple[str, ...] = ("cherry_tomato", "earphone", "screw", "tape", "pen", "bottle")
PATTERNS: tuple[str, ...] = ("stationary", "pressing", "rolling", "slipping")


@dataclass
class MarkerDataset:
    """Windows of marker clouds with labels (numpy; not the torch Dataset of ``slipsense.datasets``).

    ``x`` float32 ``(N, T, M, 3)`` mm (gel frame); ``y`` int64 ``(N,)`` 1 = slip (None when
    loaded without labels); ``groups`` int64 ``(N,)`` sequence id - overlapping windows of one
    sequence share it, so split by group, never by window; ``pattern``/``object`` int64 ``(N,)``
    indices into ``pattern_names``/``object_names`` (None when unknown); ``fps`` frame rate (Hz).
    """

    x: np.ndarray
    y: np.ndarray | None
    groups: np.ndarray
    pattern: np.ndarray | None = None
    object: np.ndarray | None = None
    pattern_names: tuple[str, ...] = PATTERNS
    object_names: tuple[str, ...] = OBJECTS
    fps: float = 20.0

    def __len__(self) -> int:
        return len(self.x)


#: Largest marker coordinate accepted, in mm (1 km): beyond it a value is a corrupt number, not a position.
MAX_ABS_MM = 1e6

#: Keys of a marker .npz that are read; any other array in the file is never loaded.
NPZ_KEYS = ("x", "y", "groups", "pattern", "object", "pattern_names", "object_names", "fps")


def validate_marker_array(x, path: str | Path | None, name: str = "x") -> np.ndarray:
    """``x`` as float32 ``(N, T, M, 3)``, or InputError naming ``path`` and where it is wrong."""
    x = np.asarray(x)
    if not (np.issubdtype(x.dtype, np.floating) or np.issubdtype(x.dtype, np.integer)):
        raise InputError(path, f"{name} has dtype {x.dtype}; expected float marker positions (mm)")
    if x.ndim != 4 or x.shape[-1] != 3:
        raise InputError(path, f"{name} has shape {x.shape}; expected (N, T, M, 3): samples, frames, markers, xyz")
    if min(x.shape[:3]) == 0:
        raise InputError(path, f"{name} has shape {x.shape}; no samples, frames or markers")
    x = x.astype(np.float32, copy=False)
    finite = np.isfinite(x)
    if not finite.all():
        bad = np.argwhere(~finite)
        i, t, m, _ = (int(v) for v in bad[0])
        kind = "NaN" if np.isnan(x[i, t, m]).any() else "inf"
        raise InputError(
            path, f"{name} contains {len(bad)} non-finite value(s); first {kind} at sample {i}, frame {t}, marker {m}"
        )
    big = np.abs(x) > MAX_ABS_MM
    if big.any():
        i, t, m, _ = (int(v) for v in np.argwhere(big)[0])
        raise InputError(
            path,
            f"{name} holds {int(big.sum())} value(s) out of range (|value| > {MAX_ABS_MM:g} mm); "
            f"first {float(x[i, t, m][big[i, t, m]][0]):g} at sample {i}, frame {t}, marker {m}",
        )
    return x


def _names(arr, key: str, path) -> tuple[str, ...]:
    """A 1-D array of names as a tuple of str, or InputError."""
    a = np.asarray(arr)
    if a.ndim != 1 or not (np.issubdtype(a.dtype, np.str_) or np.issubdtype(a.dtype, np.bytes_)):
        raise InputError(path, f"{key} must be a 1-D array of names, got {a.dtype} of shape {a.shape}")
    return tuple(s.decode("utf-8", "replace") if isinstance(s, bytes) else str(s) for s in a.tolist())


def _fps(arr, path) -> float:
    a = np.asarray(arr)
    if a.size != 1 or not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
        raise InputError(path, f"fps must be one number (frames per second), got {a.dtype} of shape {a.shape}")
    fps = float(a.reshape(()))
    if fps_problem(fps) is not None:
        raise InputError(path, f"fps: {fps_problem(fps)}")
    return fps


def _per_sample(arr, n: int, key: str, path) -> np.ndarray:
    a = np.asarray(arr)
    if a.ndim != 1 or len(a) != n:
        raise InputError(path, f"{key} has shape {a.shape}; expected ({n},), one value per sample of x")
    return a


def load_marker_npz(path: str | Path, require_labels: bool = True) -> MarkerDataset:
    """Read and validate a marker ``.npz``: the user format for marker sequences.

    Keys: ``x`` float ``(N, T, M, 3)`` marker positions in mm (any T >= 1, any M); ``y`` int
    ``(N,)`` 0/1 (1 = slip; required unless ``require_labels=False``); optional ``groups`` ``(N,)``
    int (sequence/recording id for leak-free splits; defaults to one group per sample); optional
    ``pattern`` ``(N,)`` (int indices into ``pattern_names``, or strings), ``object`` likewise,
    ``fps`` (one positive number). Only these keys are read. Raises InputError naming the file for
    a missing file or key, wrong shapes, NaN/inf or values beyond :data:`MAX_ABS_MM` (with sample,
    frame and marker), labels other than 0/1, length mismatches, names that are not a 1-D array of
    strings and an fps that is not one positive number.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "no such file")
    try:
        with np.load(path, allow_pickle=False) as z:  # a .npy fails here: an array is no archive
            data = {}
            present = sorted(z.files)
            for k in NPZ_KEYS:  # only what is used: other arrays (object arrays too) are never read
                if k in z.files:
                    try:
                        data[k] = z[k]
                    except ValueError as exc:
                        raise InputError(path, f"array {k!r} is unreadable ({exc})") from None
    except InputError:
        raise
    except Exception as exc:  # zipfile/pickle/OS errors: all mean "not a usable npz"
        raise InputError(path, f"not a readable .npz file ({type(exc).__name__}: {exc})") from None
    if "x" not in data:
        raise InputError(path, f"missing key 'x' (marker positions (N, T, M, 3)); keys present: {present}")
    x = validate_marker_array(data["x"], path)
    n = len(x)
    y = None
    if "y" in data:
        y_raw = _per_sample(data["y"], n, "y", path)
        if y_raw.dtype.kind not in "iubf":  # integer, bool or float
            raise InputError(path, f"y has dtype {y_raw.dtype}; expected integer labels 0/1")
        bad = ~np.isin(y_raw, (0, 1))
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(
                path, f"y must be 0 (no slip) or 1 (slip); sample {i} has {y_raw[i]!r} ({int(bad.sum())} bad label(s))"
            )
        y = y_raw.astype(np.int64)
    elif require_labels:
        raise InputError(path, f"missing key 'y' (labels (N,), 0/1); keys present: {present}")
    groups = _per_sample(data["groups"], n, "groups", path) if "groups" in data else np.arange(n)
    if not np.issubdtype(groups.dtype, np.integer):
        _, groups = np.unique(groups, return_inverse=True)  # e.g. string recording names
    out = MarkerDataset(x, y, groups.astype(np.int64), fps=_fps(data["fps"], path) if "fps" in data else 20.0)
    for key, names_key, default in (("pattern", "pattern_names", PATTERNS), ("object", "object_names", OBJECTS)):
        if key not in data:
            continue
        a = _per_sample(data[key], n, key, path)
        names = _names(data[names_key], names_key, path) if names_key in data else default
        if np.issubdtype(a.dtype, np.integer):
            if a.size and (a.min() < 0 or a.max() >= len(names)):
                raise InputError(path, f"{key} indices must be in [0, {len(names)}) ({names_key}: {list(names)})")
        else:
            a = a.astype(str)
            names = tuple(dict.fromkeys([*default, *sorted(set(a.tolist()))]))
            a = np.array([names.index(s) for s in a.tolist()], np.int64)
        setattr(out, key, a.astype(np.int64))
        setattr(out, names_key, names)
    return out
