"""How many objects to record: a family made for a user's sensor from the grasps of ``k`` objects,
judged on the grasps of the objects it never saw, for every ``k`` (``python -m studies grasp
learning-curve``). What ``docs/new-sensor.md`` says about how much to record comes from here.

Each point trains the family with its own recipe (``slipsense train --model NAME``; ``adapt``
chooses the kept one's operating point on inner folds instead) on the grasps of ``k`` objects drawn from the set and judges it at its own operating point on
all the others' grasps; up to ``draws`` draws of objects a point, each object drawn as evenly as the
combinations allow.
"""

from __future__ import annotations

import itertools
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from slipsense.api import fit
from slipsense.evaluation.judge import judge
from slipsense.measures import slipped_or_held
from slipsense.progress import progress_bar
from slipsense.recordings.folders import find_recordings
from studies.pages import curve_table  # noqa: F401  (the report's table: written with the pages)


def learning_curve(
    sensor: Path, family: str, work: Path, draws: int = 5, seed: int = 0, progress: bool = True
) -> dict[str, Any]:
    """Per number of objects trained on: accuracy and balanced accuracy on the other objects' grasps
    (pooled over the draws, with each draw's own), the grasps trained on. Trainings are kept under
    ``work`` (a second run resumes)."""
    recs = find_recordings(sensor)
    objects = sorted({r.object for r in recs})
    grasps = {o: len({r.experiment for r in recs if r.object == o}) for o in objects}
    rng = np.random.default_rng(seed)
    points = []
    for k in range(1, len(objects)):
        combos = list(itertools.combinations(objects, k))
        picked = [combos[i] for i in sorted(rng.permutation(len(combos))[:draws])]
        rows, alarmed, slipped = [], [], []
        for d, train in enumerate(progress_bar(picked, progress, f"{family}, {k} object(s)")):
            out = Path(work) / f"k{k}" / f"draw{d}"
            ckpt = out / "detector.safetensors"
            held = [o for o in objects if o not in train]
            if not ckpt.is_file():
                fit(sensor, out, model=family, held_out=held, seed=seed + d, progress=False)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                ev = judge(ckpt, sensor, objects=held, progress=False)
            a = ev.peak_scores() >= ev.threshold
            y = np.array([r.slipped for r in ev.runs], bool)
            rows.append(
                {
                    "objects": list(train),
                    "grasps": sum(grasps[o] for o in train),
                    "accuracy": slipped_or_held.accuracy(a, y),
                    "balanced_accuracy": slipped_or_held.balanced_accuracy(a, y),
                }
            )
            alarmed.append(a)
            slipped.append(y)
        a, y = np.concatenate(alarmed), np.concatenate(slipped)
        points.append(
            {
                "objects": k,
                "grasps": float(np.mean([r["grasps"] for r in rows])),
                "accuracy": slipped_or_held.accuracy(a, y),
                "balanced_accuracy": slipped_or_held.balanced_accuracy(a, y),
                "draws": rows,
            }
        )
    return {
        "sensor": str(sensor),
        "family": family,
        "objects": len(objects),
        "grasps": sum(grasps.values()),
        "points": points,
    }
