"""Record grasps from live cameras into the recordings layout, so that every command reads them.

    <out>/<object>/exp_num_<N>/camera_<i>.avi   one video per camera (i: its place in the order given)
    <out>/<object>/exp_num_<N>/slip.txt         when the grasp was marked as slipped

``N`` is the next number free in the object's folder (from 1), so recording again adds grasps. A grasp starts
and stops by command or, with ``by_contact``, when the gels are touched and let go: the labeller's
rule (:mod:`slipsense.recordings.contact`), the mean of the most changed 8 x 8 pixel blocks against
the gel at rest (the median of the first frames) above ``REST_TOLERANCE + MIN_CONTACT`` grey levels for
``MIN_CONTACT_FRAMES`` frames in a row on any camera, and below it as long to stop. Commands
(``slipsense record`` reads them as lines on its standard input): ``""`` (Enter) starts or stops a
grasp, ``"s"`` marks the current grasp (or, between grasps, the last one) as slipped, ``"q"`` quits.

A grasp is written into a hidden folder (``.exp_num_<N>.partial``) renamed into place when it ends,
``slip.txt`` included: a recording killed in the middle of a grasp leaves nothing any command reads.
A grasp started by contact begins :data:`PRE_ROLL` frames before it (the gel at rest, which labelling
and the detectors take as the grasp's start).
"""

from __future__ import annotations

import re
from collections import deque
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np

from slipsense.errors import InputError, OutputError
from slipsense.recordings import contact

#: Codec of the written videos (the shared recordings' own).
FOURCC = "XVID"
#: Frames kept from before a contact starts a grasp: the camera start-up frames labelling skips
#: (:data:`~slipsense.recordings.contact.STARTUP_FRAMES`) and the frames the contact rule waits.
PRE_ROLL = contact.STARTUP_FRAMES + contact.MIN_CONTACT_FRAMES + 5


def check_object_name(obj: str) -> None:
    if not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.-]*", obj):
        raise InputError(None, f"object name {obj!r}: use letters, digits, _ . - (it names a folder)")


def next_grasp_folder(out: Path, obj: str) -> Path:
    """``<out>/<obj>/exp_num_<N>`` with ``N`` one above the largest there (1 in a new folder, as the
    shared recordings number their runs)."""
    check_object_name(obj)
    folder = Path(out) / obj
    # a grasp cut short by a kill keeps its number (its hidden .exp_num_<N>.partial is left as it was)
    names = [p.name for p in folder.glob("*exp_num_*")]
    numbers = [int(m.group(1)) for n in names if (m := re.fullmatch(r"\.?exp_num_(\d+)(\.partial)?", n))]
    return folder / f"exp_num_{max(numbers) + 1 if numbers else 1}"


class GraspWriter:
    """One grasp's videos, one per camera, in a hidden folder renamed into place by :meth:`finish`."""

    def __init__(self, folder: Path, cameras: int, fps: float):
        self.folder, self.fps, self.cameras = Path(folder), float(fps), cameras
        self.partial = self.folder.with_name(f".{self.folder.name}.partial")
        self._writers: list[cv2.VideoWriter] = []
        self.frames = 0

    def add(self, frames: Sequence[np.ndarray]) -> None:
        if any(f is None for f in frames):
            raise InputError(None, "this source holds no pictures to record (a marker stream?)")
        if not self._writers:
            try:
                self.partial.mkdir(parents=True, exist_ok=False)
            except OSError as exc:
                raise OutputError(self.partial, f"cannot create the grasp folder ({exc.strerror or exc})") from None
            for i, f in enumerate(frames):
                h, w = f.shape[:2]
                path = self.partial / f"camera_{i}.avi"
                writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*FOURCC), self.fps, (w, h))
                if not writer.isOpened():
                    raise OutputError(path, f"cannot write a {FOURCC} video here")
                self._writers.append(writer)
        for writer, f in zip(self._writers, frames):
            writer.write(f if f.ndim == 3 else cv2.cvtColor(f, cv2.COLOR_GRAY2BGR))
        self.frames += 1

    def finish(self, slipped: bool) -> Path | None:
        """Close the videos and give them their final names (and ``slip.txt``); None if no frame came."""
        for w in self._writers:
            w.release()
        if not self._writers:
            return None
        if slipped:
            (self.partial / "slip.txt").write_text("")
        self.partial.rename(self.folder)
        return self.folder


class ContactTrigger:
    """In contact or at rest, from the frames of every camera (see the module notes); ``None`` while
    the first ``rest_frames`` frames teach it the gel at rest."""

    def __init__(self, rest_frames: int = contact.REF_MIN_FRAMES * 2):
        self.rest_frames = rest_frames
        self._seen: list[list[np.ndarray]] = []
        self._rest: list[np.ndarray] | None = None
        self._run = 0
        self.touching = False

    def update(self, frames: Sequence[np.ndarray]) -> bool | None:
        blocks = [contact.video_blocks(np.asarray(f)[None]).astype(np.float32)[0] for f in frames]
        if self._rest is None:
            self._seen.append(blocks)
            if len(self._seen) < self.rest_frames:
                return None
            self._rest = [np.median(np.stack(b), axis=0) for b in zip(*self._seen)]
            return False
        level = max(float(contact.block_score(b[None], r)[0]) for b, r in zip(blocks, self._rest))
        touching = level > contact.REST_TOLERANCE + contact.MIN_CONTACT
        self._run = self._run + 1 if touching != self.touching else 0
        if self._run >= contact.MIN_CONTACT_FRAMES:
            self.touching, self._run = touching, 0
        return self.touching


def record(
    steps,
    out: str | Path,
    obj: str,
    fps: float,
    commands: Callable[[int], Sequence[str]] = lambda index: (),
    by_contact: bool = False,
    max_grasps: int | None = None,
    echo: Callable[[str], None] = print,
    source_slipped: bool = False,
) -> list[Path]:
    """Record grasps from ``steps`` (one list of frames, one per camera, per step: a
    :class:`~slipsense.streaming.sources.Source`'s) into ``out`` (see the module notes).

    ``commands(index)``: the commands given since the last step (``""``, ``"s"``, ``"q"``).
    ``source_slipped``: the frames come from a recording labelled slipped (its ``slip.txt``), so every
    grasp cut from it is labelled slipped too; nobody is there to type ``s``.
    Returns the grasp folders written; a grasp still open when the frames end is kept."""
    check_object_name(obj)
    trigger = ContactTrigger() if by_contact else None
    before: deque = deque(maxlen=PRE_ROLL)  # the latest frames while no grasp is written
    writer: GraspWriter | None = None
    slipped, done = False, []

    def close():
        nonlocal writer
        folder = writer.finish(slipped)
        writer = None
        if folder is not None:
            done.append(folder)
            echo(f"grasp {len(done)}: {folder} ({'slipped' if slipped else 'held'})")

    for index, frames in enumerate(steps):
        cmds = list(commands(index))
        if "q" in cmds:
            break
        state = trigger.update(frames) if trigger is not None else None
        start = (writer is None) and ("" in cmds or state is True)
        stop = (writer is not None) and ("" in cmds or (trigger is not None and state is False))
        if "s" in cmds:
            if writer is not None:
                slipped = True
            elif done:
                (done[-1] / "slip.txt").write_text("")
                echo(f"grasp {len(done)} marked as slipped")
        if stop:
            close()
            if max_grasps is not None and len(done) >= max_grasps:
                break
            continue
        if start:
            writer, slipped = GraspWriter(next_grasp_folder(Path(out), obj), len(frames), fps), source_slipped
            echo(f"recording grasp {len(done) + 1} into {writer.folder}")
            for earlier in before if state is True else ():  # started by contact: from the gel at rest
                writer.add(earlier)
            before.clear()
        if writer is not None:
            writer.add(frames)
        else:
            before.append(frames)
    if writer is not None:
        close()
    return done
