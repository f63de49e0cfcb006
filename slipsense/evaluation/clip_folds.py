"""Pool the held-out evaluations of a clip model's cross-validation folds
(:func:`slipsense.training.recipe.cross_validate`, ``slipsense train --cross-validate``).

Each run folder holds ``evaluation.json`` (written by ``slipsense train``); the pooled scores come
from the summed confusion matrices, so every held-out clip counts once.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from slipsense.errors import InputError
from slipsense.evaluation.metrics import scores


def pool(run_dirs: list[Path]) -> dict:
    folds, total = [], np.zeros((2, 2), np.int64)
    for run in run_dirs:
        path = Path(run) / "evaluation.json"
        if not path.is_file():
            raise InputError(path, "no evaluation.json (did the run finish?)")
        m = json.loads(path.read_text())
        total += np.asarray(m["confusion"], np.int64)
        folds.append(
            {
                "run": Path(run).name,
                "test_objects": m.get("test_objects"),
                **{k: m[k] for k in ("accuracy", "precision", "recall", "f1", "n_clips", "n_slip", "n_wiggle")},
            }
        )
    pooled = {
        **scores(total),
        "n_clips": int(total.sum()),
        "n_slip": int(total[1].sum()),
        "n_wiggle": int(total[0].sum()),
        "confusion": total.tolist(),
    }
    mean = {k: float(np.mean([f[k] for f in folds])) for k in ("accuracy", "precision", "recall", "f1")}
    return {"folds": folds, "pooled": pooled, "mean_over_folds": mean}
