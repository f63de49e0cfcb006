"""The learnability baseline of the simulated marker windows (experiment marker-baseline)."""

import numpy as np
import pytest
from typer.testing import CliRunner

from studies.__main__ import app
from slipsense.errors import ConfigError
from studies.experiments.marker_baseline import FEATURES, REST_FEATURES, fit_and_score, window_features


def _grid(rows=4, cols=5):
    gx, gy = np.meshgrid(np.arange(cols, dtype=float), np.arange(rows, dtype=float))
    return np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)


def test_features_tell_a_translation_from_opposite_lobes():
    rest = _grid()
    t = np.linspace(0, 1, 6)[:, None, None]
    slide = rest[None] + t * np.array([0.5, 0.0, 0.0])  # every marker moves together
    lobes = rest[None] + t * np.where(rest[:, 1:2] < 2, 1.0, -1.0) * np.array([0.5, 0.0, 0.0])  # opposite halves
    f = window_features(np.stack([slide, lobes]), (4, 5), rest=rest)
    names = FEATURES + REST_FEATURES
    assert f.shape == (2, len(names)) and np.isfinite(f).all()
    coherence = f[:, names.index("coherence")]
    assert coherence[0] == pytest.approx(1.0) and coherence[1] < 0.1
    with pytest.raises(ConfigError, match="4 x 4 marker grid"):
        window_features(np.stack([slide]), (4, 4))


def test_fit_and_score_separates_what_is_separable():
    rng = np.random.default_rng(0)
    rest = _grid()
    x, y = [], []
    for k in range(80):
        moving = k % 2
        step = rng.normal(0, 0.01, (6, 20, 3)) + (np.linspace(0, 1, 6)[:, None, None] * [0.4, 0, 0] if moving else 0)
        x.append(rest[None] + step)
        y.append(moving)
    x, y = np.array(x), np.array(y)
    res = fit_and_score(x, y, np.arange(60), np.arange(60, 80), (4, 5))
    assert res["metrics"]["f1"] == 1.0 and set(res["importance"]) == set(FEATURES)


def test_marker_baseline_command_quick(tmp_path):
    res = CliRunner().invoke(app, ["experiment", "marker-baseline", "--quick", "--out", str(tmp_path), "--no-progress"])
    assert res.exit_code == 0, res.output
    text = (tmp_path / "marker-baseline.md").read_text()
    assert "shear against rest" in text and (tmp_path / "marker-baseline.png").is_file()
