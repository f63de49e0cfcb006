"""Pinned figures: what training and judging produce, end to end on a few shared recordings, held to
numbers kept in the repository (``tests/pinned/figures.json``).

Any change of what the shipped families' training (MotionNet with the shipped recipe, shear retention
with its own) or the judge produces fails these tests until the pins are written again in the same
commit, with the reason in the commit message::

    SLIPSENSE_UPDATE_PINS=1 OMP_NUM_THREADS=1 .venv/bin/python -m pytest -q tests/test_pinned_figures.py

The perturbation tests show the pins catch what matters: the recipe's learning rate, the warning
horizon and the frame levelling each move the figures.

Each run is small (5 objects of 2 runs, 2 epochs; 3 gelsight-lift objects) and seeded; the figures are
compared within a relative tolerance of :data:`RELATIVE` (a change of recipe moves them far more).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import pytest
import yaml

from conftest import needs_data
from slipsense.paths import data_root, gelsight_recordings

ROOT = Path(__file__).resolve().parent.parent
PINS = Path(__file__).resolve().parent / "pinned" / "figures.json"
UPDATE = os.environ.get("SLIPSENSE_UPDATE_PINS") == "1"
#: figures agree when within this share of each other (or 1e-6 apart near zero)
RELATIVE = 1e-3

#: GelSight Mini runs: one slipped and one held grasp of each object (short slips, few frames)
GELSIGHT_RUNS = {
    "blue_mug": ("exp_num_9", "exp_num_1"),
    "cellotape": ("exp_num_3", "exp_num_1"),
    "avocado_real": ("exp_num_2", "exp_num_4"),
    "rubber_pear": ("exp_num_6", "exp_num_1"),
    "blue_box": ("exp_num_2", "exp_num_3"),
}
GELSIGHT_HELD_OUT = "blue_box"
#: the objects the shipped detector is judged on (a slipped and a held grasp each)
JUDGED_OBJECTS = ("blue_box", "blue_mug")
LIFT_OBJECTS = ("object002", "object003", "object004")
LIFT_HELD_OUT = "object004"
#: the shipped recipe at a test's scale: fewer epochs and inner folds, everything else as shipped
SCALE = {"epochs": 2, "inner_folds": 2}
#: one change each that must move the pinned figures
CHANGES = {
    "learning rate": {"lr": 0.003},
    "warning horizon": {"horizon": 40},
    "frame levelling": {"level": False},
}

pytestmark = needs_data


# ---- the small recordings -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def gelsight(tmp_path_factory) -> Path:
    """The runs of :data:`GELSIGHT_RUNS`, linked into a recordings folder of their own."""
    root = tmp_path_factory.mktemp("gelsight")
    for obj, runs in GELSIGHT_RUNS.items():
        for run in runs:
            (root / obj).mkdir(exist_ok=True)
            (root / obj / run).symlink_to((gelsight_recordings() / obj / run).resolve())
    return root


@pytest.fixture(scope="module")
def lift(tmp_path_factory) -> Path:
    """The gelsight-lift objects of :data:`LIFT_OBJECTS` with their result files."""
    root = tmp_path_factory.mktemp("lift")
    src = (data_root() / "gelsight-lift").resolve()
    for obj in LIFT_OBJECTS:
        (root / obj).symlink_to(src / obj)
        (root / f"{obj}_result.dat").symlink_to(src / f"{obj}_result.dat")
    return root


def linked(tmp_path_factory, src: Path, names: tuple[str, ...]) -> Path:
    """A folder of links to ``names`` in ``src`` (objects and their result files)."""
    root = tmp_path_factory.mktemp(src.name + "-part")
    for name in names:
        if (src / name).exists():
            (root / name).symlink_to(src / name)
    return root


@pytest.fixture(scope="module")
def gelsight_held_out(tmp_path_factory, gelsight) -> Path:
    return linked(tmp_path_factory, gelsight, (GELSIGHT_HELD_OUT,))


@pytest.fixture(scope="module")
def judged_set(tmp_path_factory, gelsight) -> Path:
    """Two objects' runs (4): what the judge replays the shipped detector on."""
    return linked(tmp_path_factory, gelsight, JUDGED_OBJECTS)


@pytest.fixture(scope="module")
def lift_held_out(tmp_path_factory, lift) -> Path:
    return linked(tmp_path_factory, lift, (LIFT_HELD_OUT, f"{LIFT_HELD_OUT}_result.dat"))


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """One private cache for the module: the runs are decoded and labelled once."""
    path = tmp_path_factory.mktemp("cache")
    before = os.environ.get("SLIPSENSE_CACHE")
    os.environ["SLIPSENSE_CACHE"] = str(path)
    yield path
    if before is None:
        os.environ.pop("SLIPSENSE_CACHE", None)
    else:
        os.environ["SLIPSENSE_CACHE"] = before


# ---- the figures ------------------------------------------------------------------------------------


def shipped_recipe(**change: Any) -> dict[str, Any]:
    """``configs/motionnet.yaml`` as settings by name, at :data:`SCALE`, with ``change`` on top."""
    recipe = yaml.safe_load((ROOT / "configs" / "motionnet.yaml").read_text())
    settings = {k: v for k, v in recipe["model"].items() if k != "name"} | recipe["train"]
    return settings | SCALE | change


def judged(checkpoint: Path, recordings: Path) -> dict[str, Any]:
    """Every registered measure of ``checkpoint`` replayed on ``recordings``, and each run's peak
    alarm score (what the measures rank by)."""
    import warnings

    import slipsense

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the shipped detector saw these objects: known, and not the point
        evaluation = slipsense.evaluate(checkpoint, recordings, progress=False)
    peaks = evaluation.peak_scores()
    runs = {f"{r.object}/{r.experiment}": float(p) for r, p in zip(evaluation.runs, peaks)}
    return {"measures": evaluation.measures(), "peak_score": runs}


def motionnet_figures(gelsight: Path, held_out: Path, out: Path, **change: Any) -> dict[str, Any]:
    """The shipped recipe trained on 4 objects, its operating point chosen on inner folds, judged on
    the fifth."""
    import slipsense

    trained = slipsense.fit(gelsight, out, held_out=[GELSIGHT_HELD_OUT], progress=False, **shipped_recipe(**change))
    keep = ("train_loss", "train_accuracy", "train_items", "onset_frames", "other_frames")
    return {
        "history": [{k: row[k] for k in keep} for row in trained.history],
        "operating_point": {k: trained.operating_point[k] for k in ("threshold", "debounce", "horizon")},
        "held_out": judged(trained.checkpoint, held_out),
    }


def shear_figures(lift: Path, held_out: Path, out: Path) -> dict[str, Any]:
    """Shear retention made with its recipe (settings and threshold chosen on two objects' grasps)
    and judged on the third."""
    import slipsense

    trained = slipsense.fit(lift, out, model="shear-retention", held_out=[LIFT_HELD_OUT], progress=False, sensors=1)
    point = trained.operating_point
    return {
        "operating_point": {"threshold": point["threshold"], "settings": point["settings"], "tried": point["tried"]},
        "held_out": judged(trained.checkpoint, held_out),
    }


def judging_figures(gelsight: Path) -> dict[str, Any]:
    """The shipped two-finger detector judged on a few GelSight runs: every measure."""
    from slipsense.resources import shipped_model

    return judged(shipped_model(), gelsight)


# ---- comparing ---------------------------------------------------------------------------------------


def flatten(value: Any, prefix: str = "") -> dict[str, Any]:
    """``{"a.b.0.c": leaf}`` of nested dicts and lists."""
    if isinstance(value, dict):
        return {k: v for key, item in value.items() for k, v in flatten(item, f"{prefix}{key}.").items()}
    if isinstance(value, (list, tuple)):
        return {k: v for i, item in enumerate(value) for k, v in flatten(item, f"{prefix}{i}.").items()}
    return {prefix.rstrip("."): value}


def same(a: Any, b: Any) -> bool:
    if isinstance(a, bool) or isinstance(b, bool) or not isinstance(a, (int, float)) or not isinstance(b, (int, float)):
        return a == b
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return math.isclose(a, b, rel_tol=RELATIVE, abs_tol=1e-6)


def differences(got: dict[str, Any], pinned: dict[str, Any]) -> list[str]:
    """One line per figure that moved, appeared or went away."""
    got, pinned = flatten(json.loads(json.dumps(got))), flatten(pinned)
    lines = [
        f"{k}: {pinned[k]!r} -> {got[k]!r}" for k in sorted(got.keys() & pinned.keys()) if not same(got[k], pinned[k])
    ]
    lines += [f"{k}: new ({got[k]!r})" for k in sorted(got.keys() - pinned.keys())]
    lines += [f"{k}: gone (was {pinned[k]!r})" for k in sorted(pinned.keys() - got.keys())]
    return lines


def pinned(name: str) -> dict[str, Any]:
    return json.loads(PINS.read_text())[name] if PINS.exists() else {}


def check(name: str, got: dict[str, Any]) -> None:
    """Fail on any figure that differs from its pin; with SLIPSENSE_UPDATE_PINS=1 write it instead."""
    got = json.loads(json.dumps(got))  # tuples as lists, as JSON keeps them
    if UPDATE:
        from slipsense.atomic import write_text

        pins = json.loads(PINS.read_text()) if PINS.exists() else {}
        pins[name] = got
        PINS.parent.mkdir(exist_ok=True)
        write_text(PINS, json.dumps(pins, indent=1, sort_keys=True) + "\n")
        return
    moved = differences(got, pinned(name))
    assert not moved, (
        f"{len(moved)} pinned figures of {name} changed (if on purpose: SLIPSENSE_UPDATE_PINS=1, and say why "
        "in the commit message):\n" + "\n".join(moved[:40])
    )


# ---- the tests ---------------------------------------------------------------------------------------


def test_motionnet_recipe_figures_are_pinned(gelsight, gelsight_held_out, cache, tmp_path, one_thread):
    check("motionnet", motionnet_figures(gelsight, gelsight_held_out, tmp_path / "motionnet"))


def test_shear_retention_figures_are_pinned(lift, lift_held_out, cache, tmp_path, one_thread):
    check("shear-retention", shear_figures(lift, lift_held_out, tmp_path / "shear"))


def test_judging_figures_are_pinned(judged_set, cache, one_thread):
    check("judging", judging_figures(judged_set))


@pytest.mark.skipif(UPDATE, reason="writing the pins")
@pytest.mark.parametrize("what", sorted(CHANGES))
def test_the_pins_catch_a_changed_recipe(what, gelsight, gelsight_held_out, cache, tmp_path, one_thread):
    figures = motionnet_figures(gelsight, gelsight_held_out, tmp_path / "changed", **CHANGES[what])
    moved = differences(figures, pinned("motionnet"))
    assert moved, f"the pinned figures did not notice a changed {what}"
    # the figures themselves moved, not only a setting that the figures echo
    assert any(not k.startswith("operating_point.horizon") for k in moved), moved


def test_the_comparison_sees_a_moved_new_or_missing_figure():
    pins = {"a": {"b": 1.0, "c": [0.5, "x"]}}
    assert differences({"a": {"b": 1.0, "c": [0.5, "x"]}}, pins) == []
    assert differences({"a": {"b": 1.0 + 1e-5, "c": [0.5, "x"]}}, pins) == []
    assert differences({"a": {"b": 1.01, "c": [0.5, "x"]}}, pins) == ["a.b: 1.0 -> 1.01"]
    assert differences({"a": {"b": 1.0, "c": [0.5, "y"]}}, pins) == ["a.c.1: 'x' -> 'y'"]
    assert differences({"a": {"b": 1.0, "c": [0.5, "x"], "d": 2}}, pins) == ["a.d: new (2)"]
    assert differences({"a": {"c": [0.5, "x"]}}, pins) == ["a.b: gone (was 1.0)"]
    assert differences({"a": {"b": float("nan")}}, {"a": {"b": float("nan")}}) == []
