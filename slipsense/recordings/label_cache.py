"""Cache of automatic labels, one JSON file per run, checked before use (:func:`check_run_labels`).

Used by :func:`slipsense.recordings.labels.label_recordings`.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from dataclasses import asdict
from pathlib import Path
from typing import Sequence

from .. import atomic, config
from ..errors import CacheWarning, InputError
from .contact import Rule
from .frames import source_stat
from .types import Recording, VideoLabel
from .video import TRUNCATION_TOLERANCE, frame_count

#: Bump whenever the automatic labels (contact.py, labels.py) could change; it keys the label cache.
ALGORITHM_VERSION = "labels-1"

#: Layout of a label cache entry; bumped when it changes (old entries are then not even looked at).
CACHE_FORMAT = 2


def _inputs(recs: Sequence[Recording], rule: Rule) -> list:
    """What a run's labels are computed from: algorithm, rule and each video's identity."""
    out: list = [ALGORITHM_VERSION, rule]
    for r in sorted(recs, key=lambda r: r.camera):
        size, mtime = source_stat(r.path)
        out.append(
            [
                r.object,
                int(r.experiment),
                r.camera,
                str(Path(r.path).resolve()),
                size,
                mtime,
                bool(r.slipped),
            ]
        )
    return out


def _cache_file(recs: Sequence[Recording], rule: Rule) -> Path:
    """Cache path for one run: a hash of the cache format and the run's inputs (:func:`_inputs`)."""
    payload = json.dumps([CACHE_FORMAT, _inputs(recs, rule)], sort_keys=True)
    digest = hashlib.sha256(payload.encode()).hexdigest()[:32]
    return config.cache_root() / "labels" / f"{digest}.json"


def _sidecar(path: Path) -> Path:
    """Beside each cached ``<hash>.json`` (the labels, a list of rows): ``<hash>.check``, its
    sha256 and the inputs it was made from, written last."""
    return path.with_suffix(".check")


def _write_cache(path: Path, recs: Sequence[Recording], rule: Rule, labels: Sequence[VideoLabel]) -> None:
    data = json.dumps([asdict(l) for l in labels], indent=1).encode("utf-8")
    atomic.write_bytes(path, data)
    check = {"format": CACHE_FORMAT, "sha256": hashlib.sha256(data).hexdigest(), "inputs": _inputs(recs, rule)}
    atomic.write_text(_sidecar(path), json.dumps(check, indent=1))


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def check_run_labels(labels: Sequence[VideoLabel], recs: Sequence[Recording]) -> None:
    """Raise ValueError unless ``labels`` are possible automatic labels of the run ``recs``:
    one per video, the same frame count for every camera (and the one its container states),
    ``slipped`` as slip.txt says, a moment of slip and contact phase inside the video."""
    if sorted(l.key for l in labels) != sorted(r.key for r in recs):
        raise ValueError("labels are not those of the run's videos")
    by_key = {r.key: r for r in recs}
    if len({l.n_frames for l in labels}) != 1:
        raise ValueError("cameras of one run with different frame counts")
    for l in labels:
        rec = by_key[l.key]
        for name in ("n_frames", "contact_start", "contact_end"):
            if not _is_int(getattr(l, name)):
                raise ValueError(f"{l.camera}: {name} is not an integer")
        n = l.n_frames
        if n < 2:
            raise ValueError(f"{l.camera}: n_frames {n}")
        if l.slipped is not rec.slipped:
            raise ValueError(
                f"{l.camera}: slipped={l.slipped!r} but slip.txt is {'present' if rec.slipped else 'absent'}"
            )
        if l.source != "auto":
            raise ValueError(f"{l.camera}: source {l.source!r}")
        if not 0 <= l.contact_start <= l.contact_end < n:
            raise ValueError(f"{l.camera}: contact phase {l.contact_start}..{l.contact_end} is not inside 0..{n - 1}")
        m = l.moment_of_slip
        if m is not None and (not l.slipped or not _is_int(m) or not 0 <= m < n):
            raise ValueError(f"{l.camera}: moment of slip {m!r} is not inside 0..{n - 1} of a run that slipped")
        stated = frame_count(rec.path)
        if stated is not None and not stated - TRUNCATION_TOLERANCE <= n <= stated:
            raise ValueError(f"{l.camera}: {n} frames but the video states {stated}")


def _load_cached(path: Path, recs: Sequence[Recording], rule: Rule = "either") -> list[VideoLabel] | None:
    """Labels cached for this run, or None when absent; an entry that fails its checksum, was made
    from other inputs or holds impossible labels is reported (:class:`CacheWarning`) and None
    returned, so the run is labelled again."""
    if not path.exists() and not _sidecar(path).exists():
        return None
    try:
        data = path.read_bytes()
        check = json.loads(_sidecar(path).read_text(encoding="utf-8"))
        if not isinstance(check, dict) or check.get("format") != CACHE_FORMAT:
            raise ValueError(f"check file format is not {CACHE_FORMAT}")
        if check.get("sha256") != hashlib.sha256(data).hexdigest():
            raise ValueError("checksum mismatch")
        if check.get("inputs") != _inputs(recs, rule):
            raise ValueError("made from other videos or settings")
        rows = json.loads(data.decode("utf-8"))
        if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
            raise ValueError("labels are not a list of records")
        labels = [VideoLabel(**row) for row in rows]
        check_run_labels(labels, recs)
    except (OSError, ValueError, TypeError, InputError) as exc:  # FileNotFoundError: half an entry
        return _unusable(path, str(exc))
    return labels


def _unusable(path: Path, why: str) -> None:
    warnings.warn(f"{path}: label cache entry unusable ({why}); relabelling", CacheWarning, stacklevel=3)
    return None
