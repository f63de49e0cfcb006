"""Find the moment of slip and the contact phase in GelSight recordings.

The recordings carry no frame index of the slip, so we recover it from the video: while an
object presses on the gel, the image differs from the gel at rest; when the object lets go, that
difference collapses within one or two frames.

Pipeline (all frame indices are 0-based indices into the decoded video):

1. :func:`contact_signal` turns one video ``uint8 (T, H, W, 3)`` into ``float32 (T,)``: how far
   each frame is from a *rest* reference (the gel with nothing on it), in 8-bit intensity units.
   Frames are area-averaged into 8 x 8 pixel blocks (which removes the codec's per-pixel flicker
   at key frames, every 12 frames in these files) and the score is the mean of the 10 % most
   changed blocks (so a small contact, a pen tip or a thread, is not diluted by the untouched
   gel). The reference is the median of the rest frames at the end of the video (or, with
   ``reference="head"``, right after the start-up transient); the median over up to three
   key-frame intervals averages the flicker out. The first :data:`STARTUP_FRAMES` frames are
   not the scene (a start-up transient of the camera stream) and take the value of the first
   frame after them.
2. :func:`contact_phase` finds the main contact phase in one signal (first sustained contact
   after the transient, to its end), used to draw "wiggle" windows from runs that did not slip.
3. :func:`find_moment_of_slip` finds, for each camera, the frame where its contact is finally
   lost: a sharp drop (within one or two frames) to near rest. Not every sharp drop is a loss:
   a dip that recovers within :data:`REGAIN_WINDOW` frames is the wiggle; a *partial* drop
   (the object shifting) is followed by the complete one within :data:`PARTIAL_WINDOW` frames,
   or leaves a level that still jitters with the arm's motion (:data:`ACTIVE_CHANGE`), whereas
   a gel the object has left keeps at most a still residual deformation. It then combines the
   cameras: the moment of slip is the last frame before the object loses contact with either
   sensor (``rule="either"``, the earliest per-camera loss), or, with ``rule="both"``, the last
   frame before it has lost contact with both (the latest per-camera loss).
4. :func:`label_run` / :func:`label_recordings` turn recordings into :class:`VideoLabel`\\ s
   (for runs that did not slip and stop while still holding the object, the rest reference is
   taken from the start), cache them, and apply hand-made overrides read by
   :func:`read_overrides_csv`; :func:`write_labels_csv` writes them out.

Thresholds are in 8-bit intensity units of the block-averaged difference. They were set on the
shared GelSight Mini recordings, where the rest level of the signal is about 1.5 and contacts
reach 5 to 60.
"""
from __future__ import annotations

import csv
import hashlib
import io
import json
import re
from dataclasses import asdict, replace
from pathlib import Path
from typing import Iterable, Literal, Mapping, Sequence

import cv2
import numpy as np

from .. import atomic, config
from ..errors import CacheWarning, InputError
from .types import Recording, VideoLabel

#: Override value that leaves a video out of the clips altogether.
EXCLUDE = "exclude"

#: Bump whenever the labels this module produces could change; it keys the label cache.
ALGORITHM_VERSION = "labels-1"

#: Frames 0 .. STARTUP_FRAMES-1 are a start-up transient of the camera stream (frame 0 differs
#: strongly, frames 1..~9 form a plateau that ends abruptly), not the scene.
STARTUP_FRAMES = 10
#: Side of the square pixel blocks frames are averaged into before comparing them.
BLOCK_PX = 8
#: Fraction of blocks (the most changed ones) averaged into the per-frame score.
TOP_FRACTION = 0.10
#: The rest reference is the median of at most this many frames: three key-frame intervals.
REF_MAX_FRAMES = 36
#: ... and of at least this many (even when the rest phase looks shorter).
REF_MIN_FRAMES = 3
#: Frames whose score against the last (or first) frames is below this belong to the same rest
#: state; the codec flicker between key-frame intervals stays below about 2.5.
REST_TOLERANCE = 3.0
#: A camera is in contact when its signal exceeds the rest floor by at least this much.
MIN_CONTACT = 3.0
#: A contact has to last this many frames to count (shorter blips are bumps, not grasps).
MIN_CONTACT_FRAMES = 5
#: A drop is a loss of contact when the level after it, above the floor, is at most this
#: fraction of the level before it. Larger fractions are partial drops (the object shifting).
LOSS_FRACTION = 0.5
#: A loss followed within this many frames by a further loss, with the signal staying clearly
#: above rest in between, was a partial drop: the moment is the later loss.
PARTIAL_WINDOW = 25
#: A drop after which contact returns (for MIN_CONTACT_FRAMES frames) within this many frames
#: is a dip during the wiggle, not a loss.
REGAIN_WINDOW = 12
#: Mean absolute deviation of the signal from its 5-frame running median above which a level
#: is "alive": an object still touching the gel while the arm moves. After the object is gone
#: the gel can keep a residual deformation (a sheared marker grid) until the gripper opens, but
#: that residual is static or relaxes smoothly (0.002-0.02 on the shared recordings) while a
#: touching object jitters (0.05-0.3).
ACTIVE_CHANGE = 0.03
#: Frames after a drop looked at to tell a static residual from a moving contact.
ACTIVE_WINDOW = 50
#: In runs that did not slip, a contact starting within this many frames after the transient
#: is the grasp seen from the gel at rest (see :func:`label_run`).
GRASP_WINDOW = 30
#: ... and final frames holding still for fewer frames than this are not the gel at rest but
#: the object still held (and moved) when the recording stopped.
STILL_END_FRAMES = 24
#: Frames before / after a candidate drop whose median gives the level before / after it.
LEVEL_BEFORE = 5
LEVEL_AFTER = 5

Rule = Literal["either", "both"]
Key = tuple[str, int, str]

#: Columns of a labels CSV, in order.
LABEL_COLUMNS = (
    "object",
    "experiment",
    "camera",
    "n_frames",
    "slipped",
    "moment_of_slip",
    "contact_start",
    "contact_end",
    "source",
)


# --------------------------------------------------------------------------------------------
# Contact signal
# --------------------------------------------------------------------------------------------


def _blocks(frames: np.ndarray) -> np.ndarray:
    """Area-average ``(T, H, W, C)`` frames into BLOCK_PX blocks: float32 ``(T, H//8, W//8, C)``."""
    t, h, w = frames.shape[:3]
    size = (max(1, w // BLOCK_PX), max(1, h // BLOCK_PX))
    # One frame at a time: converting a whole 450-frame video to float first would take ~400 MB.
    out = np.stack([cv2.resize(np.ascontiguousarray(f), size, interpolation=cv2.INTER_AREA) for f in frames])
    out = out.astype(np.float32)
    return out if out.ndim == 4 else out[..., None]


def _score(blocks: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Mean of the TOP_FRACTION largest block differences to ``ref`` per frame: float32 ``(T,)``."""
    d = np.abs(blocks - ref).mean(axis=-1).reshape(len(blocks), -1)
    k = max(1, int(round(TOP_FRACTION * d.shape[1])))
    return np.partition(d, d.shape[1] - k, axis=1)[:, -k:].mean(axis=1)


def _rest_reference(blocks: np.ndarray, reference: str) -> tuple[np.ndarray, int]:
    """Median of the rest frames at the end (``"tail"``) or after the transient (``"head"``).

    Returns the reference blocks and how many frames in a row, walking in from that end, stay
    within REST_TOLERANCE of the 3 outermost ones (how long the video holds still there).
    """
    t = len(blocks)
    first = min(STARTUP_FRAMES, max(0, t - REF_MIN_FRAMES))
    if reference == "tail":
        seed = np.median(blocks[-REF_MIN_FRAMES:], axis=0)
        close = _score(blocks[first:], seed)[::-1] < REST_TOLERANCE  # walking back from the end
    else:
        seed = np.median(blocks[first : first + REF_MIN_FRAMES], axis=0)
        close = _score(blocks[first:], seed) < REST_TOLERANCE
    still = int(np.argmin(close)) if not close.all() else len(close)
    n = int(np.clip(still, REF_MIN_FRAMES, REF_MAX_FRAMES))
    n = min(n, t - first) if t - first > 0 else t
    chosen = blocks[t - n :] if reference == "tail" else blocks[first : first + n]
    return np.median(chosen, axis=0), still


def _signal(blocks: np.ndarray, reference: str) -> tuple[np.ndarray, int]:
    """:func:`contact_signal` from block-averaged frames, plus the still-frame count."""
    ref, still = _rest_reference(blocks, reference)
    signal = _score(blocks, ref).astype(np.float32)
    if len(signal) > STARTUP_FRAMES:
        signal[:STARTUP_FRAMES] = signal[STARTUP_FRAMES]
    return signal, still


def contact_signal(frames: np.ndarray, reference: Literal["tail", "head"] = "tail") -> np.ndarray:
    """Per-frame contact strength of one sensor video against the gel at rest.

    Args:
        frames: ``(T, H, W, 3)`` (or ``(T, H, W)``) video, uint8 intensities, ``T >= 2``.
        reference: where the rest state is taken from: ``"tail"`` (default) the final frames,
            which show the gel after the object was released or lost; ``"head"`` the frames
            right after the start-up transient, before the grasp (for videos that end while
            still holding the object).

    Returns:
        float32 ``(T,)``: mean absolute difference (8-bit intensity units, averaged over
        channels) of the 10 % most changed 8 x 8 pixel blocks between each frame and the rest
        reference. About 1-2 at rest, 5-60 in contact. Frames ``0 .. STARTUP_FRAMES-1`` (the
        start-up transient) repeat the value of frame ``STARTUP_FRAMES``.
    """
    frames = np.asarray(frames)
    if frames.ndim not in (3, 4) or frames.shape[0] < 2:
        raise ValueError(f"frames must be (T, H, W[, C]) with T >= 2, got shape {frames.shape}")
    if reference not in ("tail", "head"):
        raise ValueError(f"reference must be 'tail' or 'head', got {reference!r}")
    return _signal(_blocks(frames), reference)[0]


# --------------------------------------------------------------------------------------------
# Contact phase and contact loss in one signal
# --------------------------------------------------------------------------------------------


def _check_signal(signal: np.ndarray) -> np.ndarray:
    s = np.asarray(signal, dtype=np.float64)
    if s.ndim != 1 or len(s) < 2:
        raise ValueError(f"a contact signal must be 1-D with at least 2 frames, got shape {s.shape}")
    if not np.isfinite(s).all():
        raise ValueError("a contact signal must be finite")
    return s


def _first_frame(n: int) -> int:
    """First frame after the start-up transient (0 for videos too short to have one)."""
    return STARTUP_FRAMES if n > STARTUP_FRAMES + 1 else 0


def _running_median(s: np.ndarray, width: int = 5) -> np.ndarray:
    padded = np.pad(s, width // 2, mode="edge")
    return np.median(np.lib.stride_tricks.sliding_window_view(padded, width), axis=1)


def _floor(s: np.ndarray) -> float:
    """Rest level of a signal: the lowest 5-frame running median after the transient.

    (Not a percentile: a video that holds the object almost throughout rests for only a few
    frames, which a percentile would miss.)
    """
    return float(_running_median(s[_first_frame(len(s)) :]).min())


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs of True in ``mask`` as inclusive ``(start, end)`` pairs."""
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2])]


def _contact_start(s: np.ndarray, floor: float, begin: int = 0) -> int | None:
    """First frame >= begin opening MIN_CONTACT_FRAMES frames of contact, or None."""
    lo = max(begin, _first_frame(len(s)))
    for a, b in _runs(s[lo:] > floor + MIN_CONTACT):
        if b - a + 1 >= MIN_CONTACT_FRAMES:
            return lo + a
    return None


def _drops(s: np.ndarray, floor: float, begin: int) -> list[tuple[int, float, float]]:
    """Sharp drops to near rest after frame ``begin``: ``(last frame before, level before, after)``.

    Frame t is part of a drop when the median of the LEVEL_BEFORE frames ending at t stands
    MIN_CONTACT above the floor and the median of the LEVEL_AFTER frames from t+2 (t+1 may be
    half-way down) has fallen to LOSS_FRACTION of it. Neighbouring such frames form one drop;
    its moment is the last of them still clearly above the level after the drop (by MIN_CONTACT
    and by a quarter of the drop), so that a weakening contact counts until it is gone.
    """
    n = len(s)
    found: list[tuple[int, float, float]] = []
    group: list[tuple[int, float, float]] = []
    for t in range(begin, n - 1):
        pre = float(np.median(s[max(begin, t - LEVEL_BEFORE + 1) : t + 1]))
        post = float(np.median(s[t + 2 : t + 2 + LEVEL_AFTER])) if t + 2 < n else float(s[n - 1])
        ok = pre - floor >= MIN_CONTACT and post - floor <= LOSS_FRACTION * (pre - floor)
        if ok:
            group.append((t, pre, post))
        if group and (not ok or t == n - 2):
            before = max(g[1] for g in group)
            after = min(g[2] for g in group)
            clear = after + max(MIN_CONTACT, 0.25 * (before - after))
            high = [g[0] for g in group if s[g[0]] >= clear]
            found.append((max(high) if high else group[0][0], before, after))
            group = []
    return found


def _jitter(s: np.ndarray) -> float:
    """Mean absolute deviation of ``s`` from its 5-frame running median (ignores smooth trends)."""
    return float(np.mean(np.abs(s - _running_median(s))))


def _camera_loss(signal: np.ndarray) -> int | None:
    """The last frame of the main contact phase of one camera before its contact is lost.

    The main contact phase is the first one lasting MIN_CONTACT_FRAMES after the start-up
    transient; later episodes (the gripper touching the dropped object) are ignored. A drop
    followed by regained contact within REGAIN_WINDOW frames is a dip; a drop followed by a
    further drop within PARTIAL_WINDOW frames, without resting in between, was partial.
    Returns None when the camera never makes contact or never loses it.
    """
    s = _check_signal(signal)
    floor = _floor(s)
    start = _contact_start(s, floor)
    if start is None:
        return None
    drops = _drops(s, floor, start)
    i = 0
    while i < len(drops):
        m, before, after = drops[i]
        regain = floor + 0.5 * (before - floor)
        window = s[m + 1 : m + 1 + REGAIN_WINDOW + MIN_CONTACT_FRAMES]
        if any(b - a + 1 >= MIN_CONTACT_FRAMES for a, b in _runs(window >= regain)):
            i += 1  # contact came back: a dip during the wiggle
            continue
        if i + 1 < len(drops) and after - floor > MIN_CONTACT:
            # Not down to rest: a static residual of the gel, or the object still touching it
            # more lightly (a partial drop). Only the latter moves with the arm.
            rest = s[m + 3 : min(drops[i + 1][0], m + 3 + ACTIVE_WINDOW)]
            if len(rest) >= MIN_CONTACT_FRAMES and _jitter(rest) > ACTIVE_CHANGE:
                i += 1
                continue
        # Follow partial drops: a later drop soon after, the signal never resting in between.
        j = i
        while j + 1 < len(drops):
            m2 = drops[j + 1][0]
            between = s[drops[j][0] + 2 : m2 + 1]
            if m2 - drops[j][0] <= PARTIAL_WINDOW and (len(between) == 0 or between.min() > floor + MIN_CONTACT):
                j += 1
            else:
                break
        return drops[j][0]
    return None


def contact_phase(signal: np.ndarray) -> tuple[int, int]:
    """First and last frame (inclusive) of the main contact phase of one camera.

    Args:
        signal: ``(T,)`` output of :func:`contact_signal`.

    Returns:
        ``(start, end)``: ``start`` is the first frame of the first contact lasting
        MIN_CONTACT_FRAMES frames after the start-up transient; ``end`` is the frame before that
        contact is lost (see :func:`find_moment_of_slip`), or the last frame in contact when the
        video ends holding the object. When the signal shows no contact at all, a one-frame
        phase ``(k, k)`` at the first frame after the transient, which holds no clip window.
    """
    s = _check_signal(signal)
    floor = _floor(s)
    first = min(_first_frame(len(s)), len(s) - 1)
    start = _contact_start(s, floor)
    if start is None:
        return first, first
    end = _camera_loss(s)
    if end is None or end < start:
        # Never lost: contact lasts to the last frame still above the contact threshold.
        above = np.flatnonzero(s[start:] > floor + MIN_CONTACT)
        end = start + int(above[-1])
    return int(start), int(end)


def find_moment_of_slip(signals_per_camera: Sequence[np.ndarray], rule: Rule = "either") -> int | None:
    """The moment of slip of one run from the contact signals of its cameras.

    Args:
        signals_per_camera: one ``(T,)`` :func:`contact_signal` per camera of the run, all the
            same length (the cameras of a run record the same frames).
        rule: ``"either"`` (default): the last frame before the object loses contact with
            either sensor, i.e. the earliest per-camera loss, the last frame still in contact
            on both. ``"both"``: the last frame before it has lost contact with both sensors
            (the latest per-camera loss; the paper's Fig. 4 shows one sensor already free at
            its moment of slip, which reads this way).

    Returns:
        The frame index, or None when no camera shows a contact that is then lost (no grasp in
        the video, or the video ends while still holding the object).
    """
    if rule not in ("either", "both"):
        raise ValueError(f"rule must be 'either' or 'both', got {rule!r}")
    signals = [_check_signal(s) for s in signals_per_camera]
    if not signals:
        raise ValueError("need the signal of at least one camera")
    if len({len(s) for s in signals}) != 1:
        raise ValueError(f"the cameras' signals differ in length: {[len(s) for s in signals]}")
    losses = [m for m in (_camera_loss(s) for s in signals) if m is not None]
    if not losses:
        return None
    return int(min(losses) if rule == "either" else max(losses))


# --------------------------------------------------------------------------------------------
# Labelling recordings
# --------------------------------------------------------------------------------------------


def _run_labels(
    recordings: Sequence[Recording], signals: Sequence[np.ndarray], rule: Rule
) -> list[VideoLabel]:
    """VideoLabels for one run from its recordings and their tail-referenced signals."""
    n = len(signals[0])
    slipped = any(r.slipped for r in recordings)
    out: list[VideoLabel] = []
    if slipped:
        moment = find_moment_of_slip(signals, rule=rule)
        starts = [contact_phase(s)[0] for s in signals]
        first = min(_first_frame(n), n - 1)
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
    for rec, s in zip(recordings, signals):
        start, end = contact_phase(s)
        out.append(VideoLabel(rec.object, rec.experiment, rec.camera, n, False, None, start, end))
    return out


def _phase_length(phase: tuple[int, int]) -> int:
    return phase[1] - phase[0] + 1


def _ends_holding(tails: Sequence[tuple[int, int]], heads: Sequence[tuple[int, int]],
                  still_ends: Sequence[int], n: int) -> bool:
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
    from .video import read_video  # imported here so this module imports without the decoder

    recs = sorted(recordings_of_one_experiment, key=lambda r: r.camera)
    if not recs:
        raise ValueError("label_run needs at least one recording")
    if len({(r.object, r.experiment) for r in recs}) != 1:
        raise ValueError("label_run takes the recordings of one (object, experiment)")
    if len({r.camera for r in recs}) != len(recs):
        raise InputError(recs[0].path.parent, "two recordings of this run have the same camera name")
    blocks = []
    for r in recs:
        # Keep only the block averages: the decoded video is ~100 MB, its blocks ~1.6 MB.
        blocks.append(_blocks(read_video(r.path, expected_size=None, min_frames=2)))
    counts = {r.camera: len(b) for r, b in zip(recs, blocks)}
    if len(set(counts.values())) != 1:
        raise InputError(recs[0].path.parent, f"the cameras of this run differ in frame count: {counts}")
    tails = [_signal(b, "tail") for b in blocks]
    labels = _run_labels(recs, [s for s, _ in tails], rule)
    if any(r.slipped for r in recs):
        return labels
    heads = [contact_phase(_signal(b, "head")[0]) for b in blocks]
    tail_phases = [(l.contact_start, l.contact_end) for l in labels]
    if not _ends_holding(tail_phases, heads, [still for _, still in tails], len(blocks[0])):
        return labels
    return [
        replace(l, contact_start=h[0], contact_end=h[1]) if _phase_length(h) > 1 else l
        for l, h in zip(labels, heads)
    ]


def _group_runs(recordings: Iterable[Recording]) -> dict[tuple[str, int], list[Recording]]:
    runs: dict[tuple[str, int], list[Recording]] = {}
    for r in recordings:
        runs.setdefault((r.object, r.experiment), []).append(r)
    return dict(sorted(runs.items()))


#: Layout of a label cache entry; bumped when it changes (old entries are then not even looked at).
CACHE_FORMAT = 2


def _inputs(recs: Sequence[Recording], rule: Rule) -> list:
    """What a run's labels are computed from: algorithm, rule and each video's identity."""
    out: list = [ALGORITHM_VERSION, rule]
    for r in sorted(recs, key=lambda r: r.camera):
        st = Path(r.path).stat()
        out.append([r.object, int(r.experiment), r.camera, str(Path(r.path).resolve()), int(st.st_size),
                    int(st.st_mtime_ns), bool(r.slipped)])
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
    from .video import TRUNCATION_TOLERANCE, frame_count

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
            raise ValueError(f"{l.camera}: slipped={l.slipped!r} but slip.txt is {'present' if rec.slipped else 'absent'}")
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
    import warnings

    warnings.warn(f"{path}: label cache entry unusable ({why}); relabelling", CacheWarning, stacklevel=3)
    return None


def label_recordings(
    recordings: Iterable[Recording],
    overrides: Mapping[tuple[str, int, str | None], int | None] | str | Path | None = None,
    progress: bool = True,
    cache: bool = True,
    rule: Rule = "either",
) -> dict[Key, VideoLabel]:
    """Label all recordings, run by run, then apply hand-made overrides.

    Args:
        recordings: e.g. from :func:`slipsense.recordings.folders.find_recordings`; grouped by
            (object, experiment) and labelled with :func:`label_run`.
        overrides: ``{(object, experiment, camera or None): moment or None}`` (camera None: every
            camera of the run; moment None: the run did not slip), or a CSV path read with
            :func:`read_overrides_csv`. Overridden labels get ``source="override"``.
        progress: show a progress bar (tqdm) over the runs.
        cache: read and write automatic labels under ``<cache_root>/labels``, one JSON file per
            run (and a ``.check`` file beside it), keyed by algorithm version, rule and each
            video's path, size and mtime. An entry is used only when its sha256 matches, the
            inputs its ``.check`` records are this run's, and its
            labels are possible for the videos (:func:`check_run_labels`); otherwise the run is
            labelled again with a :class:`~slipsense.errors.CacheWarning`.
        rule: see :func:`find_moment_of_slip`.

    Returns:
        ``{(object, experiment, camera): VideoLabel}`` sorted by key.

    Raises:
        InputError: a video cannot be decoded; an override names a run or camera not among
            ``recordings`` or a moment outside the video.
    """
    runs = _group_runs(recordings)
    known = {key: [r.camera for r in recs] for key, recs in runs.items()}
    if isinstance(overrides, (str, Path)):
        overrides = read_overrides_csv(overrides, known=known)
    items = list(runs.items())
    if progress:
        from tqdm import tqdm

        items = tqdm(items, desc="labelling runs", unit="run")
    labels: dict[Key, VideoLabel] = {}
    for _key, recs in items:
        cached_path = _cache_file(recs, rule) if cache else None
        run_labels = _load_cached(cached_path, recs, rule) if cached_path is not None else None
        if run_labels is None:
            run_labels = label_run(recs, rule=rule)
            if cached_path is not None:
                try:
                    _write_cache(cached_path, recs, rule, run_labels)
                except OSError as exc:
                    import warnings

                    warnings.warn(f"{cached_path}: cannot write the label cache ({exc}); continuing without it",
                                  CacheWarning, stacklevel=2)
        for label in run_labels:
            labels[label.key] = label
    if overrides:
        labels = apply_overrides(labels, overrides)
    return dict(sorted(labels.items()))


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
        path, line = _where(overrides, (obj, exp, cam))
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
                out[key] = replace(label, moment_of_slip=None, contact_end=label.contact_start, source="override")
                continue
            if moment is None:
                out[key] = replace(label, slipped=False, moment_of_slip=None, source="override")
                continue
            if not (0 <= moment < label.n_frames):
                raise InputError(
                    path,
                    f"{line}override for {obj} experiment {exp} {key[2]}: moment {moment} is outside "
                    f"0..{label.n_frames - 1} (the video has {label.n_frames} frames)",
                )
            out[key] = replace(
                label,
                slipped=True,
                moment_of_slip=int(moment),
                contact_start=min(label.contact_start, int(moment)),
                contact_end=int(moment),
                source="override",
            )
    return out


# --------------------------------------------------------------------------------------------
# CSV files
# --------------------------------------------------------------------------------------------


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
        writer.writerow([
            l.object, l.experiment, l.camera, l.n_frames, "true" if l.slipped else "false",
            "" if l.moment_of_slip is None else l.moment_of_slip, l.contact_start, l.contact_end, l.source,
        ])
    atomic.write_text(path, buf.getvalue())


_EXPERIMENT_RE = re.compile(r"^(?:exp_num_)?(\d+)$")


class Overrides(dict):
    """``{(object, experiment, camera or None): moment or None}`` read from a CSV file, which also
    remembers the file (``path``) and each row's line (``lines``) so later errors can name them."""

    def __init__(self, items=(), path: Path | None = None, lines: Mapping | None = None):
        super().__init__(items)
        self.path = path
        self.lines = dict(lines or {})

    def without_runs(self, runs) -> "Overrides":
        """The rows of runs other than ``runs`` (``{(object, experiment)}``), lines kept."""
        runs = set(runs)
        return Overrides({k: v for k, v in self.items() if k[:2] not in runs}, self.path, self.lines)


def _where(overrides, key) -> tuple[Path | None, str]:
    """``(file, "line N: ")`` of an override row when it was read from a CSV, else ``(None, "")``."""
    path = getattr(overrides, "path", None)
    line = getattr(overrides, "lines", {}).get(key)
    return path, (f"line {line}: " if path is not None and line is not None else "")


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
                path, f"line {line}: mixes a whole-run and a per-camera override of {obj} experiment {exp} "
                f"(line {seen[clash[0]]})"
            )
        seen[key] = line
        out[key] = moment
        out.lines[key] = line
    return out


def read_labels_csv(path: str | Path) -> dict[Key, VideoLabel]:
    """Read a file written by :func:`write_labels_csv` back into ``{key: VideoLabel}``.

    Raises:
        InputError: naming the file and line, for missing columns or malformed values.
    """
    path = Path(path)
    header, rows = _open_csv(path)
    missing = [c for c in LABEL_COLUMNS if c not in header]
    if missing:
        raise InputError(path, f"line 1: missing column(s) {', '.join(missing)}")
    out: dict[Key, VideoLabel] = {}
    for line, row in rows:
        slipped = row["slipped"].lower()
        if slipped not in ("true", "false"):
            raise InputError(path, f"line {line}: slipped must be true or false, got {row['slipped']!r}")
        moment = row["moment_of_slip"]
        label = VideoLabel(
            object=row["object"],
            experiment=_parse_int(path, line, "experiment", row["experiment"]),
            camera=row["camera"],
            n_frames=_parse_int(path, line, "n_frames", row["n_frames"], lo=1),
            slipped=slipped == "true",
            moment_of_slip=None if moment == "" else _parse_int(path, line, "moment_of_slip", moment),
            contact_start=_parse_int(path, line, "contact_start", row["contact_start"]),
            contact_end=_parse_int(path, line, "contact_end", row["contact_end"]),
            source=row["source"] or "auto",
        )
        if label.key in out:
            raise InputError(path, f"line {line}: repeats {label.object} experiment {label.experiment} {label.camera}")
        out[label.key] = label
    return out
