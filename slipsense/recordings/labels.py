"""Find the moment of slip and the contact phase in GelSight recordings.

The recordings carry no frame index of the slip, so we recover it from the video: while an
object presses on the gel, the image differs from the gel at rest; when the object lets go, that
difference collapses within one or two frames. :mod:`slipsense.recordings.contact` finds both in
each video's contact signal (frame indices 0-based into the decoded video); :func:`label_run` and
:func:`label_recordings` turn recordings into :class:`VideoLabel`\\ s, cached by
:mod:`slipsense.recordings.label_cache`, with the hand-made overrides of
:mod:`slipsense.recordings.label_csv` applied. :func:`label_runs` labels whole recordings sets
(:meth:`~slipsense.recordings.recording_set.Recordings.labelled` calls it): every run labelled (cached),
the hand labels applied. ``overrides`` means one thing wherever it is taken (``label_runs``, the judge,
``fit``, a run's ``data.overrides``): None (the default) -> the shipped hand labels for runs of the shared
GelSight recordings, none for other folders; ``False`` -> no hand labels at all; a path -> that CSV.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import numpy as np

import warnings

from ..cache import Entry
from ..errors import InputError
from ..parallel import run_jobs
from ..paths import gelsight_recordings
from ..progress import progress_bar
from ..resources import shipped_overrides
from .contact import MIN_CONTACT_FRAMES, Rule, _first_frame, _signal, contact_phase, find_moment_of_slip
from .folders import SkippedInputWarning, check_on_error
from .frame_cache import prefetch, video_products
from .frames import source_stat
from .label_cache import cache_entry, load_labels, save_labels
from .label_csv import Key, Overrides, apply_overrides, read_overrides_csv
from .types import Recording, VideoLabel, by_run

#: What labelling reads of each video through the frame cache: the 8 x 8 blocks of the contact
#: signal, and from the same decode the contact signal and the grey frames the shipped grasp
#: detector reads (30 x 40), so that training it after labelling decodes nothing again.
LABEL_PRODUCTS = ("blocks", "contact", "gray:30x40")

#: In runs that did not slip, a contact starting within this many frames after the transient
#: is the grasp seen from the gel at rest (see :func:`label_run`).
GRASP_WINDOW = 30
#: ... and final frames holding still for fewer frames than this are not the gel at rest but
#: the object still held (and moved) when the recording stopped.
STILL_END_FRAMES = 24


def _run_labels(recordings: Sequence[Recording], signals: Sequence[np.ndarray], rule: Rule) -> list[VideoLabel]:
    """VideoLabels for one run from its recordings and their tail-referenced signals."""
    n = len(signals[0])
    if not any(r.slipped for r in recordings):
        return [
            VideoLabel(r.object, r.experiment, r.camera, n, False, None, *contact_phase(s))
            for r, s in zip(recordings, signals)
        ]
    moment = find_moment_of_slip(signals, rule=rule)
    starts = [contact_phase(s)[0] for s in signals]
    first = min(_first_frame(n), n - 1)
    out: list[VideoLabel] = []
    for rec, s, own in zip(recordings, signals, starts):
        if moment is None:
            # No moment: the clips code skips slipped runs without one; keep a valid phase.
            start, end = contact_phase(s)
        else:
            usable = [x for x in starts if x <= moment]
            start = own if own <= moment else (min(usable) if usable else min(first, moment))
            end = moment
        out.append(VideoLabel(rec.object, rec.experiment, rec.camera, n, True, moment, int(start), int(end)))
    return out


def _phase_length(phase: tuple[int, int]) -> int:
    return phase[1] - phase[0] + 1


def _ends_holding(
    tails: Sequence[tuple[int, int]], heads: Sequence[tuple[int, int]], still_ends: Sequence[int], n: int
) -> bool:
    """Whether a run that did not slip ended while still holding the object.

    Against the final frames of such a run the gel at rest before the grasp looks like contact
    that ends at the grasp, while against its first frames the contact starts at the grasp,
    soon after the transient, and lasts to the end. Seen either way, the whole video is one
    change between two states; which one is the gel at rest decides the contact phase:

    - the contact against the final frames starts at the first frame and ends within
      GRASP_WINDOW frames after the transient (a run that did not slip holds the object for the
      wiggle, much longer), while against the first frames it is longer; or
    - no camera's final frames hold still for STILL_END_FRAMES frames (the object is still moved
      about) and against the first frames some camera's contact starts within GRASP_WINDOW
      frames after the transient.
    """
    first = min(_first_frame(n), n - 1)
    grasp_by = first + GRASP_WINDOW
    for tail, head in zip(tails, heads):
        opening = tail[0] == first and tail[1] <= grasp_by and _phase_length(tail) >= MIN_CONTACT_FRAMES
        if opening and _phase_length(head) > _phase_length(tail):
            return True
    moving_end = max(still_ends) < STILL_END_FRAMES
    return moving_end and any(first < head[0] <= grasp_by for head in heads)


def label_run(recordings_of_one_experiment: Sequence[Recording], rule: Rule = "either") -> list[VideoLabel]:
    """Label every video of one experiment (all its cameras).

    For a run with ``slip.txt`` every video gets the run-level moment of slip
    (:func:`find_moment_of_slip`), ``contact_start`` from its own signal (or the earliest
    camera's, when its own contact starts after the moment) and ``contact_end`` = the moment.
    For a run without slip, ``moment_of_slip`` is None and each video gets its own contact
    phase (:func:`contact_phase`); when the run ended while still holding the object (see
    :func:`_ends_holding`), the gel at rest is the start of the video, not its end, and the
    phase is taken against the first frames after the transient.

    Args:
        recordings_of_one_experiment: the recordings of one (object, experiment), one per camera.
        rule: see :func:`find_moment_of_slip`.

    Returns:
        One :class:`VideoLabel` per recording, in camera order, ``source="auto"``.

    Raises:
        InputError: a video cannot be decoded, or the cameras of the run differ in frame count.
    """
    recs = sorted(recordings_of_one_experiment, key=lambda r: r.camera)
    if not recs:
        raise ValueError("label_run needs at least one recording")
    if len({(r.object, r.experiment) for r in recs}) != 1:
        raise ValueError("label_run takes the recordings of one (object, experiment)")
    if len({r.camera for r in recs}) != len(recs):
        raise InputError(recs[0].path.parent, "two recordings of this run have the same camera name")
    # Keep only the block averages: the decoded video is ~100 MB, its blocks ~1.6 MB. The grey
    # frames grasp detectors read come from the same decode, so training decodes nothing again.
    blocks = [video_products(r.path, LABEL_PRODUCTS, min_frames=2)["blocks"].astype(np.float32) for r in recs]
    counts = {r.camera: len(b) for r, b in zip(recs, blocks)}
    if len(set(counts.values())) != 1:
        raise InputError(recs[0].path.parent, f"the cameras of this run differ in frame count: {counts}")
    if any(r.per_grasp for r in recs):  # labelled as a whole: no moment to find, every frame the grasp
        n = len(blocks[0])
        return [VideoLabel(r.object, r.experiment, r.camera, n, r.slipped, None, 0, n - 1) for r in recs]
    tails = [_signal(b, "tail") for b in blocks]
    labels = _run_labels(recs, [s for s, _ in tails], rule)
    if any(r.slipped for r in recs):
        return labels
    heads = [contact_phase(_signal(b, "head")[0]) for b in blocks]
    tail_phases = [(l.contact_start, l.contact_end) for l in labels]
    if not _ends_holding(tail_phases, heads, [still for _, still in tails], len(blocks[0])):
        return labels
    return [
        replace(l, contact_start=h[0], contact_end=h[1]) if _phase_length(h) > 1 else l for l, h in zip(labels, heads)
    ]


def _label_one(rule: Rule, recs: list[Recording], tick) -> list[VideoLabel]:
    labels = label_run(recs, rule=rule)
    tick(1)
    return labels


def _label_runs(runs: list[list[Recording]], rule: Rule, progress: bool, workers: int | None) -> list[list[VideoLabel]]:
    """:func:`label_run` of every run, on ``workers`` processes (default one per core) when there are
    several runs (decoding and the contact signals are most of a fresh labelling's time)."""
    if len(runs) < 4 or workers == 1:  # fewer runs: starting workers would cost more than it saves
        return [label_run(recs, rule=rule) for recs in runs]
    return run_jobs(_label_one, runs, rule, workers, progress=progress, desc="labelling runs")


def label_recordings(
    recordings: Iterable[Recording],
    overrides: Mapping[tuple[str, int, str | None], int | None] | str | Path | None = None,
    progress: bool = True,
    rule: Rule = "either",
    workers: int | None = None,
) -> dict[Key, VideoLabel]:
    """Label all recordings, run by run, then apply hand-made overrides.

    Automatic labels are cached under ``<cache_root>/labels``, one verified JSON entry per run
    (:mod:`slipsense.cache`) keyed by algorithm version, rule and each video's path, size and mtime,
    used only when its labels are possible for the videos too (:func:`check_run_labels`); otherwise
    the run is labelled again with a :class:`~slipsense.errors.CacheWarning`.

    Args:
        recordings: e.g. from :func:`slipsense.recordings.folders.find_recordings`; grouped by
            (object, experiment) and labelled with :func:`label_run`.
        overrides: ``{(object, experiment, camera or None): moment or None}`` (camera None: every
            camera of the run; moment None: the run did not slip), or a CSV path read with
            :func:`read_overrides_csv`. Overridden labels get ``source="override"``.
        progress: show a progress bar (tqdm) over the runs.
        rule: see :func:`find_moment_of_slip`.
        workers: processes labelling the runs the cache has no labels for (default: one per core;
            :mod:`slipsense.parallel`).

    Returns:
        ``{(object, experiment, camera): VideoLabel}`` sorted by key.

    Raises:
        InputError: a video cannot be decoded; an override names a run or camera not among
            ``recordings`` or a moment outside the video.
    """
    runs = by_run(recordings)
    known = {key: [r.camera for r in recs] for key, recs in runs.items()}
    if isinstance(overrides, (str, Path)):
        overrides = read_overrides_csv(overrides, known=known)
    labels: dict[Key, VideoLabel] = {}
    todo: list[tuple[list[Recording], Entry]] = []  # runs the cache cannot answer
    for recs in runs.values():
        entry = cache_entry(recs, rule)
        run_labels = load_labels(entry, recs)
        if run_labels is None:
            todo.append((recs, entry))
        else:
            labels.update((label.key, label) for label in run_labels)
    for (recs, entry), run_labels in zip(todo, _label_runs([r for r, _ in todo], rule, progress, workers)):
        save_labels(entry, run_labels)
        labels.update((label.key, label) for label in run_labels)
    if overrides:
        labels = apply_overrides(labels, overrides)
    return dict(sorted(labels.items()))


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
