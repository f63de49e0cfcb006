"""Items split by object, so that no object is on both sides: the folds of leave-objects-out
cross-validation (:class:`ObjectFolds`) and a fraction held out (:class:`ObjectHoldOut`).

Every split of the library and the studies comes from these two: training's cross-validation and its
inner folds, ``slipsense adapt``, the clip and marker readers and the studies' held-out objects. One seed
therefore gives the same folds wherever they are cut.

Both work like scikit-learn's group splitters (``GroupKFold``, ``GroupShuffleSplit``):
``split(X, y=None, groups=None)`` yields ``(train, test)`` pairs of sorted int64 index arrays into the
``len(X)`` items, disjoint and together covering every item, with all items of a group on one side.
``groups`` is the object of each item (or whatever must stay on one side: a sequence, a clip); left out,
``X`` itself is taken as the groups, so ``split(objects)`` splits a list of object names.

The groups are deduplicated and sorted, then shuffled with ``numpy.random.default_rng(seed)``: a split
depends on the set of groups and the seed only, never on the items' order. The folds deal that shuffled
order out in turn (fold ``k`` holds positions ``k, k + n_folds, ...``), so their sizes differ by at
most one; the hold-out takes its head.
"""

from __future__ import annotations

from typing import Any, Iterable, Iterator

import numpy as np

from ..errors import ConfigError

Split = tuple[np.ndarray, np.ndarray]


def _is_int(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def _groups(X: Any, groups: Any) -> np.ndarray:
    """The group of each item as a 1-D array (``X`` itself where ``groups`` is None)."""
    g = np.asarray(X if groups is None else groups)
    if g.ndim != 1:
        raise ConfigError(f"groups must be one value per item (1-D), got shape {g.shape}")
    if groups is not None and X is not None and len(X) != len(g):
        raise ConfigError(f"groups has {len(g)} values for {len(X)} items")
    return g


def _sides(groups: np.ndarray, test_groups: np.ndarray) -> Split:
    is_test = np.isin(groups, test_groups)
    return np.flatnonzero(~is_test).astype(np.int64), np.flatnonzero(is_test).astype(np.int64)


class ObjectFolds:
    """``n_folds`` folds by object: each object is tested in exactly one fold, and trained on in the others.

    Args:
        n_folds: at least 2, and at most the number of objects ``split`` is given.
        seed: of the shuffle that deals the objects into folds.

    >>> [test.tolist() for _, test in ObjectFolds(2, seed=0).split(["a", "b", "a", "c"])]
    [[1, 3], [0, 2]]
    """

    def __init__(self, n_folds: int = 5, seed: int = 0):
        if not _is_int(n_folds) or n_folds < 2:
            raise ConfigError(f"n_folds must be an integer of 2 or more, got {n_folds!r}")
        self.n_folds, self.seed = int(n_folds), seed

    def __repr__(self) -> str:
        return f"ObjectFolds(n_folds={self.n_folds}, seed={self.seed!r})"

    def get_n_splits(self, X: Any = None, y: Any = None, groups: Any = None) -> int:
        return self.n_folds

    def split(self, X: Any, y: Any = None, groups: Any = None) -> Iterator[Split]:
        """``(train, test)`` index arrays of each fold in turn (``y`` is not used).

        Raises:
            ConfigError: fewer objects than folds (a fold would test nothing).
        """
        g = _groups(X, groups)
        names = np.unique(g)
        if self.n_folds > len(names):
            raise ConfigError(
                f"n_folds must be an integer in 2..{len(names)} (the number of objects), got {self.n_folds}"
            )
        order = np.random.default_rng(self.seed).permutation(len(names))
        for k in range(self.n_folds):
            yield _sides(g, names[order[k :: self.n_folds]])

    def test_objects(self, objects: Iterable[Any]) -> list[list[Any]]:
        """The objects each fold tests, fold by fold, each list sorted (the folds of :meth:`split`)."""
        g = np.asarray(list(objects))
        return [sorted(set(g[test].tolist())) for _, test in self.split(g)]


class ObjectHoldOut:
    """One split: ``test_fraction`` of the objects held out, the rest trained on.

    Args:
        test_fraction: in (0, 1); the number held out is rounded, and at least one object is on each side.
        seed: of the shuffle whose head is held out.

    ``split(X, y)`` with ``y`` (a class, or any stratum, per item) holds out the fraction of each class's
    groups on its own, classes in sorted order, from one shuffle stream (stratified, as scikit-learn's
    stratified splitters read ``y``): every class with two groups or more is on both sides, a class of
    one group stays in training. A group found in several classes is held out whole if any of them holds
    it out.
    """

    def __init__(self, test_fraction: float, seed: int = 0):
        if isinstance(test_fraction, bool) or not isinstance(test_fraction, (int, float, np.floating)):
            raise ConfigError(f"test_fraction must be a number in (0, 1), got {test_fraction!r}")
        if not 0.0 < test_fraction < 1.0:
            raise ConfigError(f"test_fraction must be in (0, 1), got {test_fraction!r}")
        self.test_fraction, self.seed = float(test_fraction), seed

    def __repr__(self) -> str:
        return f"ObjectHoldOut(test_fraction={self.test_fraction!r}, seed={self.seed!r})"

    def get_n_splits(self, X: Any = None, y: Any = None, groups: Any = None) -> int:
        return 1

    def _count(self, n: int) -> int:
        # neither side empty where it can be avoided
        return min(max(1, int(round(self.test_fraction * n))), n - 1) if n >= 2 else 0

    def split(self, X: Any, y: Any = None, groups: Any = None) -> Iterator[Split]:
        """The one ``(train, test)`` pair of index arrays (``train, test = next(h.split(...))``).

        Raises:
            ConfigError: without ``y``, fewer than 2 objects (one side would be empty).
        """
        g = _groups(X, groups)
        rng = np.random.default_rng(self.seed)
        if y is None:
            names = np.unique(g)
            if len(names) < 2:
                raise ConfigError(
                    f"a split by group needs at least 2 groups, got {len(names)}: one side would be empty"
                )
            yield _sides(g, rng.permutation(names)[: self._count(len(names))])
            return
        strata = np.asarray(y)
        if strata.shape != g.shape:
            raise ConfigError(f"y has {strata.size} values for {len(g)} items")
        held = [
            rng.permutation(m)[: self._count(len(m))] for m in (np.unique(g[strata == c]) for c in np.unique(strata))
        ]
        yield _sides(g, np.concatenate(held) if held else g[:0])


__all__ = ["ObjectFolds", "ObjectHoldOut"]
