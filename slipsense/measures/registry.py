"""The registry of measures: what a measure is, what it reads (:class:`Judged`), and every one registered."""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from slipsense.errors import ConfigError

#: The warning horizon: a first alarm at most this long before the moment of slip is in time.
HORIZON_S = 2.0
#: The camera's start-up transient at the head of every stream (frame 0 differs from the scene): never scored.
STARTUP_S = 0.4


def to_frames(seconds: float, fps: float) -> int:
    """``seconds`` as a whole number of frames at ``fps`` frames/s (the nearest): 2 s is 50 frames at
    25 frames/s, 100 at 50 frames/s."""
    return int(round(float(seconds) * float(fps)))


def horizon_frames(fps: float, seconds: float = HORIZON_S) -> int:
    """The warning horizon in frames at ``fps`` (at least one: a horizon of no frame warns of nothing);
    ConfigError for a horizon that is no positive time."""
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not 0 < seconds < math.inf:
        raise ConfigError(f"the warning horizon must be a positive number of seconds, got {seconds!r}")
    return max(1, to_frames(seconds, fps))


def startup_frames(fps: float, seconds: float = STARTUP_S) -> int:
    """The start-up frames at ``fps`` that are never scored."""
    return to_frames(seconds, fps)


@dataclass
class Judged:
    """What every measure reads: replayed runs, each at its operating point.

    Attributes:
        runs: one :class:`~slipsense.measures.pergrasp.RunTrace` per grasp (P(slip) per frame).
        points: per run ``(threshold, debounce frames, hold seconds)``: one for all runs of an
            evaluation, each fold's own where folds are pooled.
        horizon, startup: frames at the detector's rate (a warning in time; never scored): from
            :data:`HORIZON_S` and :data:`STARTUP_S` at that rate (:func:`horizon_frames`, :func:`startup_frames`).
        baselines: ``{name: (runs,) scores}`` of the non-learned baselines, where the frames were read.
        clips: ``(p, y)`` of the papers' short clips cut from these runs, where their labels were there.
    """

    runs: Sequence[Any]  # RunTrace
    points: Sequence[tuple[float, int, float]]
    horizon: int
    startup: int
    baselines: Mapping[str, np.ndarray] | None = None
    clips: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)


@dataclass(frozen=True)
class Measure:
    """One registered measure.

    Attributes:
        key: its key in the JSON and the reports.
        compute: ``Judged -> dict`` (None where it does not apply to these runs).
        words: ``(its dict, context) -> lines`` of plain text for the printed summary and the reports;
            ``context`` holds the evaluation's ``threshold``, ``debounce``, ``horizon`` and ``fps``.
        pools: computed again on the runs of every fold pooled (each at its own operating point) in a
            cross-validation report.
        reads: what it needs of :class:`Judged` beyond the runs (``"baselines"``, ``"clips"``): the
            judge reads those frames and labels only for a measure that asks.
        rank: ``its dict -> the one value detectors are ranked by`` (a float; NaN where it cannot
            say), shown as the measure's column in the fold tables and adapt's table; None: not ranked.
        label: that value's name in a table's heading.
        lower_is_better: the value is a cost (false alarms), not a score.
    """

    key: str
    compute: Callable[[Judged], dict[str, Any] | None]
    words: Callable[[Mapping[str, Any], Mapping[str, Any]], list[str]]
    pools: bool = True
    reads: tuple[str, ...] = ()
    rank: Callable[[Mapping[str, Any]], float] | None = None
    label: str = ""
    lower_is_better: bool = False

    def value(self, result: Mapping[str, Any] | None) -> float:
        """The value this measure ranks by in ``result`` (NaN where there is none)."""
        if self.rank is None or result is None:
            return math.nan
        v = self.rank(result)
        return math.nan if v is None else float(v)

    def better_first(self, result: Mapping[str, Any] | None) -> float:
        """:meth:`value` turned so that larger is better (NaN last): what ``max`` ranks by."""
        v = self.value(result)
        return -math.inf if math.isnan(v) else (-v if self.lower_is_better else v)


#: key -> measure, in the order the summary says them
MEASURES: dict[str, Measure] = {}


def register(
    key: str,
    words: Callable,
    pools: bool = True,
    reads: tuple[str, ...] = (),
    rank: Callable[[Mapping[str, Any]], float] | None = None,
    label: str = "",
    lower_is_better: bool = False,
) -> Callable:
    """Decorator: ``@register("key", words, rank=..., label=...)`` on a ``Judged -> dict`` function adds
    it to :data:`MEASURES`: its result reaches the JSON, the printed summary and (where it ranks) the
    fold tables and adapt's table."""

    def add(compute: Callable) -> Callable:
        MEASURES[key] = Measure(key, compute, words, pools, reads, rank, label or key, lower_is_better)
        return compute

    return add


def ranked(results: Mapping[str, Any]) -> dict[str, float]:
    """``{key: value}``: the value each registered measure that ranks gives for ``results`` (as
    :func:`measure_all` gives them), in the registry's order."""
    return {k: m.value(results[k]) for k, m in MEASURES.items() if m.rank is not None and k in results}


def ranked_columns(rows: Sequence[Mapping[str, float]]) -> list[str]:
    """The registered measures that rank and have a value in any of ``rows`` (:func:`ranked`), in order."""
    return [k for k, m in MEASURES.items() if m.rank is not None and any(k in r for r in rows)]


def cell(key: str, value: float) -> str:
    """A ranked value as a table shows it: a fraction in percent, a cost or count as a number."""
    if value is None or math.isnan(value):
        return "-"
    return f"{value:.2f}" if MEASURES[key].lower_is_better or abs(value) > 1 else pct(value)


def measure_all(judged: Judged, only: Sequence[str] | None = None) -> dict[str, Any]:
    """``{key: result}`` of every registered measure (or of ``only``) that applies to ``judged``."""
    results = {key: m.compute(judged) for key, m in MEASURES.items() if only is None or key in only}
    return {key: result for key, result in results.items() if result is not None}


def measure_lines(results: Mapping[str, Any], context: Mapping[str, Any]) -> list[str]:
    """The registered measures' sentences for ``results`` (as :func:`measure_all` gives them)."""
    return [line for key, m in MEASURES.items() if key in results for line in m.words(results[key], context)]


def pct(value: float) -> str:
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{100 * value:.0f}%"


def with_range(m: Mapping[str, Any] | None) -> str:
    """``{"value", "interval"}`` -> ``"83% (95% range 70-95%)"``."""
    if not m or m["value"] is None or math.isnan(m["value"]):
        return "n/a"
    v, (lo, hi) = m["value"], m["interval"]
    if math.isnan(lo) or math.isnan(hi):
        return pct(v)
    return f"{pct(v)} (95% range {100 * lo:.0f}-{100 * hi:.0f}%)"


def plural(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"
