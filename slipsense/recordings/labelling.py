"""Labels of whole recordings sets: every run labelled (cached), the hand labels applied.

``overrides`` means one thing wherever it is taken (``label_runs``, the judge, ``fit``, a run's
``data.overrides``): None (the default) -> the shipped hand labels for runs of the shared GelSight
recordings, none for other folders; ``False`` -> no hand labels at all; a path -> that CSV.
"""

from __future__ import annotations

import warnings
from pathlib import Path

from ..paths import gelsight_recordings
from ..errors import InputError
from ..progress import progress_bar
from ..resources import shipped_overrides
from .folders import SkippedInputWarning, check_on_error
from .frame_cache import prefetch
from .frames import source_stat
from .label_csv import Overrides, apply_overrides, read_overrides_csv
from .labels import LABEL_PRODUCTS, label_recordings
from .types import by_run


def shipped_overrides_for(recordings):
    """The shipped hand labels (:func:`slipsense.resources.shipped_overrides`) of those ``recordings``
    that are the shared GelSight recordings (``$SLIPSENSE_DATA/gelsight-slip``), or None."""
    shared = gelsight_recordings().resolve()
    present: dict[tuple[str, int], set] = {}
    for r in recordings:
        if Path(r.path).resolve().is_relative_to(shared):
            present.setdefault((r.object, r.experiment), set()).add(r.camera)
    if not present:
        return None
    rows = read_overrides_csv(shipped_overrides())
    keep = {k: v for k, v in rows.items() if k[:2] in present and (k[2] is None or k[2] in present[k[:2]])}
    return Overrides(keep, rows.path, rows.lines) if keep else None


def overrides_key(overrides) -> object:
    """What names a labels' overrides argument where labelled sets are kept: a CSV by its path, size
    and modification time (an edited CSV labels again), anything else by its repr."""
    if isinstance(overrides, (str, Path)):
        try:
            return (str(Path(overrides).resolve()), *source_stat(overrides))
        except OSError:  # reading it names the problem
            return str(overrides)
    return repr(overrides)


def label_runs(recordings, overrides=None, on_error: str = "raise", progress: bool = True):
    """Label recordings run by run (:func:`~slipsense.recordings.labels.label_recordings`) and
    apply the overrides (a CSV path, read against the recordings so errors name its file and line).
    ``overrides=None`` (default; ``True`` says the same): runs of the shared recordings get the shipped
    hand labels (:func:`shipped_overrides_for`), other folders none; ``overrides=False``: no hand labels
    at all; a path: that CSV.

    With ``on_error="skip"`` a run that cannot be labelled (a video that does not decode, cameras
    that differ in frame count) is left out with a
    :class:`~slipsense.recordings.folders.SkippedInputWarning`, together with its override rows;
    with ``"raise"`` its InputError stops everything. Returns ``{key: VideoLabel}``.
    """
    check_on_error(on_error)
    runs = by_run(recordings)
    known = {key: [r.camera for r in recs] for key, recs in runs.items()}
    if overrides is None or overrides is True:
        overrides = shipped_overrides_for(recordings)
    elif overrides is False:
        overrides = None
    ov = read_overrides_csv(overrides, known=known) if isinstance(overrides, (str, Path)) else overrides

    if on_error == "raise":  # runs not labelled yet are labelled on every core, decoding as they go
        labels = label_recordings(recordings, overrides=ov, progress=progress)
        prefetch([r.path for r in recordings], LABEL_PRODUCTS, progress=progress)  # labels cached, frames not
        return labels
    prefetch([r.path for r in recordings], LABEL_PRODUCTS, progress=progress)  # decoding on every core
    labels: dict = {}
    skipped: set = set()
    for key, recs in progress_bar(list(runs.items()), progress, "labelling runs"):
        try:
            labels.update(label_recordings(recs, progress=False))
        except InputError as exc:
            warnings.warn(f"{exc}; run skipped", SkippedInputWarning, stacklevel=2)
            skipped.add(key)
    if ov:  # without the rows of the runs skipped
        keep = {k: v for k, v in ov.items() if k[:2] not in skipped}
        labels = apply_overrides(labels, Overrides(keep, ov.path, ov.lines) if isinstance(ov, Overrides) else keep)
    return dict(sorted(labels.items()))
