"""Contact signal of one GelSight video, and the contact phase and moment of slip found in it.

Steps 1-3 of the labelling pipeline of :mod:`slipsense.recordings.labels` (all frame indices
are 0-based indices into the decoded video):

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
   cameras by its ``rule``: the earliest per-camera loss (``"either"``) or the latest (``"both"``).

Thresholds are in 8-bit intensity units of the block-averaged difference. They were set on the
shared GelSight Mini recordings, where the rest level of the signal is about 1.5 and contacts
reach 5 to 60.
"""

from __future__ import annotations

from typing import Literal, Sequence

import cv2
import numpy as np

from slipsense.sensors.spec import STARTUP_FRAMES

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
#: Frames before / after a candidate drop whose median gives the level before / after it.
LEVEL_BEFORE = 5
LEVEL_AFTER = 5

Rule = Literal["either", "both"]


def video_blocks(frames: np.ndarray) -> np.ndarray:
    """Area-average uint8 ``(T, H, W[, C])`` frames into BLOCK_PX blocks: uint8 ``(T, H//8, W//8, C)``
    (what the frame cache keeps of a video for the contact signal)."""
    t, h, w = frames.shape[:3]
    size = (max(1, w // BLOCK_PX), max(1, h // BLOCK_PX))
    # One frame at a time: converting a whole 450-frame video to float first would take ~400 MB.
    out = np.stack([cv2.resize(np.ascontiguousarray(f), size, interpolation=cv2.INTER_AREA) for f in frames])
    return out if out.ndim == 4 else out[..., None]


def signal_of_blocks(blocks: np.ndarray, reference: Literal["tail", "head"] = "tail") -> np.ndarray:
    """:func:`contact_signal` from a video's :func:`video_blocks` (``T >= 2``)."""
    return _signal(np.asarray(blocks, dtype=np.float32), reference)[0]


def _score(blocks: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Mean of the TOP_FRACTION largest block differences to ``ref`` per frame: float32 ``(T,)``."""
    a = np.abs(blocks - ref)
    # the channel mean written out: numpy's reduce over a last axis of 3 took most of labelling's numpy time
    d = (a[..., 0] + a[..., 1] + a[..., 2] if a.shape[-1] == 3 else a.sum(axis=-1)) / np.float32(a.shape[-1])
    d = d.reshape(len(blocks), -1)
    k = max(1, int(round(TOP_FRACTION * d.shape[1])))
    return np.partition(d, d.shape[1] - k, axis=1)[:, -k:].mean(axis=1)


def block_score(blocks: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """How far each frame's blocks ``(T, h, w, C)`` are from the gel at rest ``reference`` ``(h, w, C)``:
    the mean of the TOP_FRACTION most changed blocks, 8-bit grey levels, ``(T,)`` (what the contact
    signal is made of; ``slipsense record`` starts and stops grasps on it)."""
    return _score(np.asarray(blocks, np.float32), np.asarray(reference, np.float32))


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
    return _signal(video_blocks(frames).astype(np.float32), reference)[0]


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
    return _running_medians(np.pad(s, width // 2, mode="edge"), width)


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
    before_full, after_full = _running_medians(s, LEVEL_BEFORE), _running_medians(s, LEVEL_AFTER)
    for t in range(begin, n - 1):
        first = t - LEVEL_BEFORE + 1
        pre = float(before_full[first] if first >= begin else np.median(s[begin : t + 1]))
        if t + 2 + LEVEL_AFTER <= n:
            post = float(after_full[t + 2])
        else:
            post = float(np.median(s[t + 2 :])) if t + 2 < n else float(s[n - 1])
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


def _running_medians(s: np.ndarray, k: int) -> np.ndarray:
    """``out[i]`` = the median of ``s[i : i + k]`` for every whole window (one call instead of one per
    frame: labelling spent a fifth of its time in per-frame medians)."""
    return np.median(np.lib.stride_tricks.sliding_window_view(s, k), axis=1) if len(s) >= k else np.empty(0, s.dtype)


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
            # jitter: the mean absolute deviation from the 5-frame running median (smooth trends drop out)
            if len(rest) >= MIN_CONTACT_FRAMES and np.mean(np.abs(rest - _running_median(rest))) > ACTIVE_CHANGE:
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
    return int(min(losses) if rule == "either" else max(losses)) if losses else None


def rest_mask(contact: np.ndarray, margin: float = MIN_CONTACT) -> np.ndarray:
    """``(S, N)`` contact strength per sensor -> ``(N,)`` bool, True where no sensor is touched:
    every sensor within ``margin`` of its own rest floor (lowest 5-frame median after start-up)."""
    c = np.asarray(contact, dtype=np.float64)
    rest = np.ones(c.shape[1], dtype=bool)
    for s in c:
        tail = s[STARTUP_FRAMES:] if len(s) > STARTUP_FRAMES + 5 else s
        rest &= s < float(_running_median(tail).min()) + margin
    return rest
