"""Label CSV files and hand-made overrides: :func:`write_labels_csv`, :func:`read_overrides_csv` and
:func:`apply_overrides`.
"""

from __future__ import annotations

import csv
import io
import re
from dataclasses import asdict, fields, replace
from pathlib import Path
from typing import Iterable, Mapping, Sequence

from .. import atomic
from ..errors import InputError
from .types import VideoLabel

#: Override value that leaves a video out of the clips altogether.
EXCLUDE = "exclude"

Key = tuple[str, int, str]

#: Columns of a labels CSV, in order: the fields of a VideoLabel (object, experiment, camera, n_frames,
#: slipped, moment_of_slip, contact_start, contact_end, source).
LABEL_COLUMNS = tuple(f.name for f in fields(VideoLabel))


def apply_overrides(
    labels: Mapping[Key, VideoLabel], overrides: Mapping[tuple[str, int, str | None], int | None]
) -> dict[Key, VideoLabel]:
    """Replace the moment of slip of the labels the overrides name; those get ``source="override"``.

    A camera-specific override wins over a whole-run one (camera None). A moment sets
    ``slipped=True`` and ``contact_end`` to it (``contact_start`` is moved back to it when it was
    later); None sets ``slipped=False`` and keeps the automatic contact phase; :data:`EXCLUDE`
    keeps ``slipped`` and leaves the video without a moment and with an empty contact phase, so it
    gives no clip.

    Raises:
        InputError: an override names a run or camera without a label, or a moment outside
            ``0 .. n_frames-1``.
    """
    out = dict(labels)
    runs: dict[tuple[str, int], list[Key]] = {}
    for key in labels:
        runs.setdefault(key[:2], []).append(key)
    # Whole-run overrides first so that camera-specific ones, applied after, win.
    ordered = sorted(overrides.items(), key=lambda kv: kv[0][2] is not None)
    for (obj, exp, cam), moment in ordered:
        # the file and "line N: " of a row read from a CSV, else (None, "")
        path, line = getattr(overrides, "path", None), getattr(overrides, "lines", {}).get((obj, exp, cam))
        line = f"line {line}: " if path is not None and line is not None else ""
        keys = runs.get((obj, exp))
        if not keys:
            raise InputError(path, f"{line}override for {obj} experiment {exp}: no such run among the recordings")
        if cam is not None:
            keys = [k for k in keys if k[2] == cam]
            if not keys:
                raise InputError(path, f"{line}override for {obj} experiment {exp}: no camera {cam!r} in that run")
        for key in keys:
            label = out[key]
            if moment == EXCLUDE:
                change = dict(moment_of_slip=None, contact_end=label.contact_start)
            elif moment is None:
                change = dict(slipped=False, moment_of_slip=None)
            elif 0 <= moment < label.n_frames:
                m = int(moment)
                change = dict(slipped=True, moment_of_slip=m, contact_start=min(label.contact_start, m), contact_end=m)
            else:
                raise InputError(
                    path,
                    f"{line}override for {obj} experiment {exp} {key[2]}: moment {moment} is outside "
                    f"0..{label.n_frames - 1} (the video has {label.n_frames} frames)",
                )
            out[key] = replace(label, **change, source="override")
    return out


def write_labels_csv(labels: Mapping[Key, VideoLabel] | Iterable[VideoLabel], path: str | Path) -> None:
    """Write labels as CSV (atomically), one row per video, sorted by (object, experiment, camera).

    Columns: ``object,experiment,camera,n_frames,slipped,moment_of_slip,contact_start,
    contact_end,source``; ``slipped`` is ``true``/``false``, ``moment_of_slip`` is empty when
    the run did not slip (or no moment was found).
    """
    items = list(labels.values()) if isinstance(labels, Mapping) else list(labels)
    items.sort(key=lambda l: l.key)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(LABEL_COLUMNS)
    for l in items:
        row = {**asdict(l), "slipped": "true" if l.slipped else "false"}
        writer.writerow(["" if row[c] is None else row[c] for c in LABEL_COLUMNS])  # None: no moment
    atomic.write_text(path, buf.getvalue())


_EXPERIMENT_RE = re.compile(r"^(?:exp_num_)?(\d+)$")


class Overrides(dict):
    """``{(object, experiment, camera or None): moment or None}`` read from a CSV file, which also
    remembers the file (``path``) and each row's line (``lines``) so later errors can name them."""

    def __init__(self, items=(), path: Path | None = None, lines: Mapping | None = None):
        super().__init__(items)
        self.path = path
        self.lines = dict(lines or {})


def _open_csv(path: Path) -> tuple[list[str], list[tuple[int, dict[str, str]]]]:
    """Header and ``(line number, row)`` pairs of a CSV file; InputError when unreadable."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputError(path, "file does not exist") from None
    except UnicodeDecodeError:
        raise InputError(path, "is not a UTF-8 text file") from None
    except OSError as exc:
        raise InputError(path, f"cannot be read ({exc.strerror or exc})") from None
    reader = csv.reader(io.StringIO(text))
    try:
        header = next(reader, None)
        if header is None:
            raise InputError(path, "is empty (expected a header line)")
        header = [h.strip() for h in header]
        rows = []
        for raw in reader:
            if not any(cell.strip() for cell in raw):
                continue  # blank lines are harmless
            if len(raw) > len(header):
                raise InputError(path, f"line {reader.line_num}: {len(raw)} fields but the header has {len(header)}")
            rows.append((reader.line_num, {h: (raw[i].strip() if i < len(raw) else "") for i, h in enumerate(header)}))
    except csv.Error as exc:
        raise InputError(path, f"line {reader.line_num}: malformed CSV ({exc})") from None
    return header, rows


def _parse_int(path: Path, line: int, column: str, value: str, lo: int = 0) -> int:
    try:
        n = int(value)
    except ValueError:
        raise InputError(path, f"line {line}: {column} must be an integer, got {value!r}") from None
    if n < lo:
        raise InputError(path, f"line {line}: {column} must be >= {lo}, got {n}")
    return n


def read_overrides_csv(
    path: str | Path, known: Mapping[tuple[str, int], Sequence[str]] | None = None
) -> dict[tuple[str, int, str | None], int | None]:
    """Read hand-made moment-of-slip overrides.

    The CSV needs the columns ``object``, ``experiment`` (an integer, or ``exp_num_<N>``) and
    ``moment_of_slip`` (a frame index; blank = the run did not slip; ``exclude`` = the video gives
    no clip at all, e.g. a slip run whose object was never really held); ``camera`` is optional
    (missing or blank: the row applies to every camera of the run). Other columns are ignored,
    so a file written by :func:`write_labels_csv` can be edited and read back.

    Args:
        path: the CSV file.
        known: ``{(object, experiment): [camera, ...]}`` of the recordings; when given, rows
            naming an unknown object, experiment or camera are refused.

    Returns:
        ``{(object, experiment, camera or None): moment or None}``.

    Raises:
        InputError: naming the file and line, for a missing column, a non-integer or negative
            experiment or moment, an unknown object/experiment/camera, a row repeating (or
            contradicting, camera blank vs. named) an earlier one, or an unreadable file.
    """
    path = Path(path)
    header, rows = _open_csv(path)
    missing = [c for c in ("object", "experiment", "moment_of_slip") if c not in header]
    if missing:
        raise InputError(path, f"line 1: missing column(s) {', '.join(missing)} (header is {','.join(header)})")
    objects = {k[0] for k in known} if known is not None else None
    out = Overrides(path=path)
    seen: dict[tuple[str, int, str | None], int] = {}
    for line, row in rows:
        obj = row["object"]
        if not obj:
            raise InputError(path, f"line {line}: object is blank")
        m = _EXPERIMENT_RE.match(row["experiment"])
        if not m:
            raise InputError(path, f"line {line}: experiment must be an integer, got {row['experiment']!r}")
        exp = int(m.group(1))
        cam = row.get("camera", "") or None
        value = row["moment_of_slip"]
        if value.strip().lower() == EXCLUDE:
            moment: int | str | None = EXCLUDE
        else:
            moment = None if value == "" else _parse_int(path, line, "moment_of_slip", value)
        if known is not None:
            if obj not in objects:
                raise InputError(path, f"line {line}: unknown object {obj!r}")
            if (obj, exp) not in known:
                raise InputError(path, f"line {line}: object {obj!r} has no experiment {exp}")
            if cam is not None and cam not in known[(obj, exp)]:
                raise InputError(path, f"line {line}: {obj} experiment {exp} has no camera {cam!r}")
        key = (obj, exp, cam)
        if key in seen:
            raise InputError(path, f"line {line}: repeats the override of line {seen[key]}")
        clash = [k for k in seen if k[:2] == (obj, exp) and (k[2] is None) != (cam is None)]
        if clash:
            raise InputError(
                path,
                f"line {line}: mixes a whole-run and a per-camera override of {obj} experiment {exp} "
                f"(line {seen[clash[0]]})",
            )
        seen[key] = line
        out[key] = moment
        out.lines[key] = line
    return out
