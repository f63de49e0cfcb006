"""Making the detectors ``slipsense adapt`` judges and keeps: a family trained on some objects' grasps with
its own recipe, the shipped weights fine-tuned, the kept detector's promise written into it. Choosing
among them is :mod:`slipsense.adapt.choice`.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Sequence

from slipsense.api import fit
from slipsense.checkpoint import read_info, update_info
from slipsense.measures.promise import held_alarm_promise
from slipsense.models import model_class
from slipsense.recordings.recording_set import Recordings

from .choice import Candidate

#: Inner object folds on which every family's operating point is chosen (its threshold, and the settings
#: a recipe chooses among): on grasps of objects the model in question never saw, for the detectors
#: judged and for the one kept alike.
INNER_FOLDS = 2


def _train(data: Recordings, out: Path, name: str, seed: int, held_out: Sequence[str], **settings) -> Path:
    """Family ``name`` trained on ``data``'s grasps but ``held_out``'s into ``out``, with ``settings``
    where given, else with its own recipe, its operating point chosen on :data:`INNER_FOLDS` inner folds
    (over a recipe that chooses it on the grasps themselves), then the family's own ``adapt_settings``.
    The detector a finished training left in ``out`` is kept where it never saw ``held_out``; a half-done
    one's folder, or one trained on a held-out object, is cleared."""
    done = out / "detector.safetensors"
    if done.is_file():
        trained = {o.rsplit("/", 1)[-1] for o in (read_info(done).get("data") or {}).get("objects") or ()}
        if not trained & set(held_out):
            return done
        # a fold cut otherwise before (adapt once cut contiguous chunks): it saw the objects it would be judged on
    if out.exists():
        shutil.rmtree(out)  # a training killed half-way (its folder holds no checkpoint yet), or another fold's
    settings = settings or {"inner_folds": INNER_FOLDS, **model_class(name).adapt_settings}
    return fit(data, out, model=name, held_out=list(held_out), seed=seed, progress=False, **settings).checkpoint


def _fine_tune(data: Recordings, out: Path, shipped: Path, epochs: int, seed: int, held_out: Sequence[str]) -> Path:
    """The shipped weights trained further on ``data``'s grasps but ``held_out``'s into ``out``."""
    tuning = {"init": str(shipped), "epochs": epochs, "inner_folds": 0}
    return _train(data, out, read_info(shipped)["model"], seed, held_out, **tuning)


def _promise_unseen(path: Path, chosen: Candidate, folds: int) -> None:
    """The kept detector's promise, in its checkpoint: what its family did on the held grasps of objects
    it never saw (adapt's table), not what its operating point measured on the objects it was chosen on,
    so ``watch`` and ``models`` state the figure adapt printed (:func:`~slipsense.measures.promise.promise_text`)."""
    held = ~chosen.slipped
    promise = held_alarm_promise(chosen.alarmed[held], chosen.objects[held])
    promise["measured_on"] = f"objects it never saw ({folds} object folds of these grasps, slipsense adapt)"
    op = dict(read_info(path).get("operating_point") or {})
    update_info(path, {"operating_point": {**op, "held_alarm_unseen": promise}})
