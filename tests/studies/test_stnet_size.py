"""STNet's and TemNet's analytic size (studies/stnet/size.py) against the built networks."""

from __future__ import annotations

import pytest
import torch

from slipsense.models import build, count_parameters
from slipsense.models.stnet import PRESETS, STNet
from studies.stnet.size import count_parameters_for, flops_per_sample

# small but complete: codecs, fusion, frame embedding, 2 blocks, flatten head
SMALL = dict(frames=4, markers=10, d_model=16, heads=4, blocks=2, ff_dim=24, dropout=0.0, codec_channels=4)


@pytest.mark.parametrize("name", ["stnet", "temnet"])
@pytest.mark.parametrize(
    "extra",
    [
        {},
        dict(pool="mean"),
        dict(d_model=None, heads=2),
        dict(num_classes=3),
        dict(head_hidden=0),
        dict(head_hidden=7, pool="last"),
    ],
)
def test_count_parameters_for_matches_built_model(name, extra):
    cfg = {**SMALL, **extra}
    assert count_parameters_for(cfg, name) == count_parameters(build(name, **cfg))


@pytest.mark.parametrize("name", ["stnet", "temnet"])
def test_compact_preset_count(name):
    model = build(name, **PRESETS["compact"])
    assert count_parameters(model) == count_parameters_for(PRESETS["compact"], name)
    assert count_parameters(model) < 1_000_000


@pytest.mark.parametrize("preset, exact, gflop", [("paper", 127_268_027, 2.35), ("paper-ff4096", 128_319_891, 3.10)])
def test_paper_presets_are_about_129M(preset, exact, gflop):
    """The direct port of the authors' network had ~129 M parameters; ours within 2 % (see stnet.py)."""
    n = count_parameters_for(PRESETS[preset], "stnet")
    assert n == exact
    assert abs(n - 129e6) / 129e6 < 0.02
    assert count_parameters_for(PRESETS[preset], "temnet") < n
    # the FLOPs the speed bounds in bench/bench_stnet.py are computed from
    assert flops_per_sample(PRESETS[preset]) / 1e9 == pytest.approx(gflop, abs=0.01)


def test_paper_preset_builds_with_the_analytic_count():
    """Build the 127 M network once (~0.5 GB, a few seconds) and check it against the analytic count."""
    model = STNet(**PRESETS["paper"])
    assert count_parameters(model) == count_parameters_for(PRESETS["paper"]) == 127_268_027
    with torch.inference_mode():
        assert model.eval()(torch.randn(1, 12, 552, 3)).shape == (1, 2)


def test_class_defaults_are_the_paper_preset():
    assert count_parameters_for({}) == count_parameters_for(PRESETS["paper"])


def test_temnet_smaller_than_stnet():
    assert count_parameters_for(PRESETS["compact"], "temnet") < count_parameters_for(PRESETS["compact"], "stnet")
