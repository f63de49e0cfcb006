"""Cache of automatic labels, one verified JSON entry per run (:mod:`slipsense.cache`), whose labels
are checked before use too (:func:`check_run_labels`).

Used by :func:`slipsense.recordings.labels.label_recordings`.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Sequence

from .. import paths
from ..cache import Entry
from .contact import Rule
from .frames import source_stat
from .types import Recording, VideoLabel
from .video import TRUNCATION_TOLERANCE, frame_count

#: Bump whenever the automatic labels (contact.py, labels.py) could change; it keys the label cache.
ALGORITHM_VERSION = "labels-1"


def _inputs(recs: Sequence[Recording], rule: Rule) -> list:
    """What a run's labels are computed from: algorithm, rule and each video's identity."""
    out: list = [ALGORITHM_VERSION, rule]
    for r in sorted(recs, key=lambda r: r.camera):
        size, mtime = source_stat(r.path)
        out.append([r.object, int(r.experiment), r.camera, str(Path(r.path).resolve()), size, mtime, bool(r.slipped)])
    return out


def cache_entry(recs: Sequence[Recording], rule: Rule) -> Entry:
    """The run's entry: ``<cache_root>/labels/<key>.json``, keyed by its inputs (:func:`_inputs`)."""
    return Entry(paths.cache_root() / "labels", _inputs(recs, rule), "label cache", suffix=".json")


def save_labels(entry: Entry, labels: Sequence[VideoLabel]) -> None:
    entry.save(lambda tmp: tmp.write_text(json.dumps([asdict(l) for l in labels], indent=1), encoding="utf-8"))


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


def load_labels(entry: Entry, recs: Sequence[Recording]) -> list[VideoLabel] | None:
    """Labels cached for this run when its entry passes its checks and holds possible labels."""

    def read(path: Path) -> list[VideoLabel]:
        rows = json.loads(path.read_text(encoding="utf-8"))
        if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
            raise ValueError("labels are not a list of records")
        labels = [VideoLabel(**row) for row in rows]
        check_run_labels(labels, recs)
        return labels

    return entry.load(read)
