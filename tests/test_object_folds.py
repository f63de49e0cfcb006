"""One object splitter (:mod:`slipsense.recordings.splits`): its contract (every object tested once,
deterministic in the seed, blind to the items' order, clear errors), and that every split of the
library and the studies is cut by it: training's cross-validation and inner folds, ``slipsense adapt``,
the clip and marker data and the studies' held-out objects and simulated sequences."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from slipsense.errors import ConfigError
from slipsense.recordings.runs import GraspRun
from slipsense.recordings.splits import ObjectFolds, ObjectHoldOut

NAMES = [f"obj{i:02d}" for i in range(13)]


def _items(names=NAMES, repeat=3, seed=0):
    """Every name ``repeat`` times, shuffled: the object of each item."""
    items = np.repeat(np.array(names), repeat)
    return items[np.random.default_rng(seed).permutation(len(items))]


def _tested(split, groups) -> list[list[str]]:
    return [sorted(set(groups[test].tolist())) for _, test in split]


# ---- the folds ----------------------------------------------------------------------------------------


def test_each_object_is_tested_in_exactly_one_fold_and_trained_on_in_the_others():
    groups = _items()
    folds = list(ObjectFolds(4, seed=1).split(groups))
    assert len(folds) == 4
    tested = _tested(folds, groups)
    assert sorted(n for fold in tested for n in fold) == NAMES
    assert sorted(len(f) for f in tested) == [3, 3, 3, 4]  # sizes differ by one at most, none empty
    for train, test in folds:
        assert train.dtype == test.dtype == np.int64
        assert np.array_equal(np.sort(np.concatenate([train, test])), np.arange(len(groups)))
        assert not set(groups[train].tolist()) & set(groups[test].tolist())


def test_the_folds_depend_on_the_set_of_objects_and_the_seed_alone():
    groups = _items()
    folds = ObjectFolds(5, seed=3).test_objects(groups)
    assert ObjectFolds(5, seed=3).test_objects(groups) == folds
    assert ObjectFolds(5, seed=3).test_objects(_items(seed=9)) == folds  # another order of the items
    assert ObjectFolds(5, seed=3).test_objects(list(reversed(NAMES))) == folds  # names once each
    assert ObjectFolds(5, seed=4).test_objects(groups) != folds
    assert folds == _tested(ObjectFolds(5, seed=3).split(groups), groups)


def test_the_folds_deal_the_shuffled_objects_out_in_turn():
    """The cut that the pinned figures and the shipped reports were made with: the sorted objects
    shuffled by the seed, fold k taking places k, k + n_folds, ..."""
    order = np.random.default_rng(7).permutation(len(NAMES))
    dealt = [sorted(NAMES[j] for j in order[k::5]) for k in range(5)]
    assert ObjectFolds(5, seed=7).test_objects(NAMES) == dealt


@pytest.mark.parametrize("bad", [1, 0, -2, 2.5, True, "3", None])
def test_a_fold_count_that_is_not_an_integer_of_two_or_more_is_refused(bad):
    with pytest.raises(ConfigError, match="n_folds"):
        ObjectFolds(bad)


def test_more_folds_than_objects_is_refused_saying_how_many_objects_there_are():
    with pytest.raises(ConfigError, match=r"2\.\.13 \(the number of objects\)"):
        list(ObjectFolds(14).split(NAMES))
    assert len(ObjectFolds(13).test_objects(NAMES)) == 13  # one object a fold


def test_split_reads_like_a_scikit_learn_group_splitter():
    groups = _items()
    X = np.zeros((len(groups), 2))
    folds = ObjectFolds(3, seed=2)
    assert folds.get_n_splits() == 3
    by_groups = list(folds.split(X, None, groups))
    assert all(
        np.array_equal(a, c) and np.array_equal(b, d)
        for (a, b), (c, d) in zip(by_groups, folds.split(groups), strict=True)
    )
    with pytest.raises(ConfigError, match="groups has"):
        list(folds.split(X[:-1], groups=groups))
    with pytest.raises(ConfigError, match="1-D"):
        list(folds.split(X))


# ---- the hold-out -------------------------------------------------------------------------------------


def test_a_fraction_of_the_objects_is_held_out_whole_and_both_sides_keep_one():
    groups = _items()
    train, test = next(ObjectHoldOut(0.3, seed=1).split(groups))
    held = set(groups[test].tolist())
    assert len(held) == round(0.3 * 13) and not held & set(groups[train].tolist())
    assert np.array_equal(np.sort(np.concatenate([train, test])), np.arange(len(groups)))
    assert ObjectHoldOut(0.3, seed=1).get_n_splits() == 1
    for fraction in (0.01, 0.99):  # rounded to none or all: one object stays on each side
        train, test = next(ObjectHoldOut(fraction, seed=1).split(groups))
        assert len(train) and len(test)


def test_the_hold_out_takes_the_head_of_the_folds_shuffled_order():
    """One shuffle for both: with one object a fold, holding out k objects holds out folds 0..k-1."""
    folds = ObjectFolds(len(NAMES), seed=5).test_objects(NAMES)
    _, test = next(ObjectHoldOut(4 / len(NAMES), seed=5).split(NAMES))
    assert sorted(np.array(NAMES)[test].tolist()) == sorted(n for f in folds[:4] for n in f)


def test_the_hold_out_is_blind_to_the_items_order():
    a, b = _items(seed=1), _items(seed=2)
    _, ta = next(ObjectHoldOut(0.25, seed=8).split(a))
    _, tb = next(ObjectHoldOut(0.25, seed=8).split(b))
    assert set(a[ta].tolist()) == set(b[tb].tolist())


def test_a_stratified_hold_out_splits_each_class_on_its_own():
    y = np.array([0] * 10 + [1] * 6 + [2])
    train, test = next(ObjectHoldOut(0.25, seed=0).split(np.arange(len(y)), y))
    assert [int((y[test] == c).sum()) for c in (0, 1, 2)] == [round(2.5), round(1.5), 0]  # a lone one trains
    assert np.array_equal(np.sort(np.concatenate([train, test])), np.arange(len(y)))


@pytest.mark.parametrize("bad", [0, 0.0, 1, 1.0, -0.1, "0.2", True, None])
def test_a_fraction_outside_zero_one_is_refused(bad):
    with pytest.raises(ConfigError, match="test_fraction"):
        ObjectHoldOut(bad)


def test_a_hold_out_of_one_object_is_refused():
    with pytest.raises(ConfigError, match="at least 2 groups"):
        next(ObjectHoldOut(0.5).split(["mug", "mug"]))


# ---- every split comes from it --------------------------------------------------------------------------


@pytest.fixture
def calls(monkeypatch):
    """Every ``split`` of either splitter, recorded as ``(splitter, sorted groups)``."""
    seen: list[tuple[object, list]] = []
    for cls in (ObjectFolds, ObjectHoldOut):
        original = cls.split

        def recorded(self, X, y=None, groups=None, _original=original):
            seen.append((self, sorted(set(np.asarray(X if groups is None else groups).tolist()))))
            return _original(self, X, y, groups)

        monkeypatch.setattr(cls, "split", recorded)
    return seen


class Stop(Exception):
    """Raised where a test has seen what it needs (before any training)."""


def _runs(objects: int = 7) -> list[GraspRun]:
    """A slipped and a held run of each of ``objects`` objects (tiny frames: nothing is trained)."""
    gray, contact = np.zeros((1, 4, 2, 2), np.uint8), np.zeros((1, 4), np.float32)
    return [
        GraspRun(f"o{i}", e, e == 0, 2 if e == 0 else None, gray, contact, ("c",))
        for i in range(objects)
        for e in (0, 1)
    ]


def test_grasp_trainings_inner_folds_come_from_the_splitter(calls):
    from slipsense.training.grasp_detector import plan_training
    from slipsense.training.grasps import GraspTrainConfig

    runs = _runs()
    cfg = GraspTrainConfig(inner_folds=3, seed=4)
    jobs = plan_training(runs, ["o6"], cfg)
    trained = sorted({r.object for r in runs} - {"o6"})
    assert [(type(s), g) for s, g in calls] == [(ObjectFolds, trained)]
    expected = ObjectFolds(3, cfg.folds_seed).test_objects(trained)
    assert [sorted({runs[i].object for i in j.predict}) for j in jobs[1:]] == expected


def test_grasp_cross_validation_folds_come_from_the_splitter(calls, monkeypatch, tmp_path):
    import slipsense.training.folds as cv
    from slipsense.training.grasps import GraspTrainConfig

    def stop(cfg, folds, usable):
        raise Stop

    monkeypatch.setattr(cv, "_config_key", stop)  # right after the folds are cut
    cfg = GraspTrainConfig(seed=2)
    with pytest.raises(Stop):
        cv.run_folds(_runs(), {}, cfg, tmp_path, folds=4, meta={"sensor": {"fps": 25.0}}, progress=False)
    ((splitter, groups),) = calls
    assert isinstance(splitter, ObjectFolds) and (splitter.n_folds, splitter.seed) == (4, cfg.folds_seed)
    assert groups == [f"o{i}" for i in range(7)]


class _Clips:
    """What a clip split reads of a clip set: its length and classes."""

    def __init__(self, y):
        self.y = y

    def __len__(self):
        return len(self.y)


def test_clip_and_marker_data_splits_come_from_the_splitter(calls):
    from slipsense.data import split_groups
    from slipsense.recordings.clips import object_folds, split_by_clip

    assert object_folds(NAMES, 4, seed=6) == ObjectFolds(4, 6).test_objects(NAMES)
    clips = _Clips(np.array([0, 1] * 10))
    tr, te = split_by_clip(clips, 0.2, seed=3)
    etr, ete = next(ObjectHoldOut(0.2, 3).split(np.arange(20), clips.y))
    assert np.array_equal(tr, etr) and np.array_equal(te, ete)
    groups = _items()
    tr, te = split_groups(groups, 0.3, seed=2)
    etr, ete = next(ObjectHoldOut(0.3, 2).split(groups))
    assert np.array_equal(tr, etr) and np.array_equal(te, ete)
    assert [type(s) for s, _ in calls] == [ObjectFolds] * 2 + [ObjectHoldOut] * 4  # each call and its check


def test_the_studies_held_out_objects_and_sequences_come_from_the_splitter(calls, monkeypatch):
    import studies.stnet.simulator as simulator
    from studies.experiments.settings import Settings
    from studies.experiments.source import held_out_objects
    from studies.experiments.stnet import simulated_dataset

    settings = Settings(folds=4, fold=2, data_seed=5, progress=False)
    source = SimpleNamespace(objects=lambda spec: list(NAMES))
    assert held_out_objects(source, settings) == ObjectFolds(4, 5).test_objects(NAMES)[2]

    groups = np.repeat(np.arange(12), 3)  # 12 sequences of 3 windows, each of one motion pattern
    pattern = np.array(["slip", "stick", "roll"])[groups % 3]
    monkeypatch.setattr(
        simulator, "make_dataset", lambda cfg, progress: SimpleNamespace(groups=groups, pattern=pattern)
    )
    _, tr, te, info = simulated_dataset(settings, sequences=12, test_fraction=0.25)
    etr, ete = next(ObjectHoldOut(0.25, 5).split(groups, pattern))
    assert np.array_equal(tr, etr) and np.array_equal(te, ete) and info["n_test_sequences"] == 3
    assert [type(s) for s, _ in calls] == [ObjectFolds, ObjectFolds, ObjectHoldOut, ObjectHoldOut]


@pytest.mark.filterwarnings("ignore:the detector was trained")  # the shipped one saw these names
def test_adapt_judges_on_the_splitters_folds(calls, monkeypatch, tmp_path, cache, one_thread):
    """Six objects in five folds: the folds adapt trains on are the splitter's (one fold of two
    objects), the same as training cuts with the same seed."""
    import slipsense.adapt as adapt_module
    from tests.test_frame_folders import _lift_data

    def stop(keys, parts, train, data, desc, progress):
        raise Stop(parts)

    monkeypatch.setattr(adapt_module, "_out_of_fold", stop)  # before any training
    root = _lift_data(tmp_path / "lift", objects=6)
    with pytest.raises(Stop) as seen:
        adapt_module.adapt(root, tmp_path / "out", folds=5, seed=3, progress=False, echo=lambda line: None)
    objects = [f"object{i:03d}" for i in range(6)]
    parts = seen.value.args[0]
    assert parts == ObjectFolds(5, 3).test_objects(objects)
    assert sorted(len(p) for p in parts) == [1, 1, 1, 1, 2]
    assert (type(calls[-1][0]), calls[-1][1]) == (ObjectFolds, objects)


def test_adapt_does_not_reuse_a_fold_s_detector_that_saw_its_held_out_objects(tmp_path, monkeypatch):
    """An output folder made with other folds (adapt once cut contiguous chunks) holds detectors trained
    on objects the new fold holds out: they are trained again, not judged on what they saw."""
    from types import SimpleNamespace

    from slipsense.adapt import making

    out = tmp_path / "fold0"
    out.mkdir()
    (out / "detector.safetensors").write_bytes(b"")
    trained = {"objects": ["a", "b"]}
    monkeypatch.setattr(making, "read_info", lambda path: {"data": trained})
    calls = []

    def fake_fit(data, to, **kw):
        calls.append(kw["held_out"])
        return SimpleNamespace(checkpoint=to / "detector.safetensors")

    monkeypatch.setattr(making, "fit", fake_fit)
    monkeypatch.setattr(making, "model_class", lambda name: SimpleNamespace(adapt_settings={}))
    assert making._train(None, out, "motionnet", 0, ["c"]) == out / "detector.safetensors" and calls == []
    making._train(None, out, "motionnet", 0, ["b"])  # it saw b: trained again
    assert calls == [["b"]] and not out.exists()  # its folder cleared before the new training
