"""The shipped detectors say today what they said when they shipped: per-frame P(slip) and alarms of
``slipsense watch --jsonl`` on four shared runs (one per shipped checkpoint), against the readings
recorded by tests/support/shipped_outputs.py before the library was reorganised."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from conftest import needs_data
from slipsense.paths import gelsight_recordings
from slipsense.resources import shipped_model

SUPPORT = Path(__file__).parent / "support"


@needs_data
@pytest.mark.slow
def test_the_shipped_detectors_give_the_recorded_outputs():
    import sys

    sys.path.insert(0, str(SUPPORT))
    from shipped_outputs import outputs

    recorded = json.loads((SUPPORT / "shipped_outputs.json").read_text())
    now = outputs(gelsight_recordings().parent, shipped_model("motionnet-gelsight").parent)
    assert sorted(now) == sorted(recorded)
    for case, was in recorded.items():
        assert now[case]["alarm"] == was["alarm"], case
        diffs = [abs(a - b) for a, b in zip(now[case]["p"], was["p"]) if a is not None and b is not None]
        assert [a is None for a in now[case]["p"]] == [b is None for b in was["p"]], case
        assert max(diffs) <= 2e-6, (case, max(diffs))
