"""STNet / TemNet: shapes, configs, parameter counts, input checks, gradients, heat maps, fast paths."""

from __future__ import annotations

import math

import numpy as np

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from slipsense.errors import ConfigError, InputError
from slipsense.models import available, build, count_parameters
from slipsense.models.stnet import PRESETS, STNet, TemNet
from slipsense.models.stnet_fast import optimize_for_inference, quantize_dynamic_int8

# small but complete: codecs, fusion, frame embedding, 2 blocks, flatten head
SMALL = dict(frames=4, markers=10, d_model=16, heads=4, blocks=2, ff_dim=24, dropout=0.0, codec_channels=4)


def _x(b=2, cfg=SMALL, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.randn(b, cfg["frames"], cfg["markers"], 3, generator=g)


@pytest.fixture(scope="module")
def small():
    torch.manual_seed(0)
    return STNet(**SMALL).eval()


def test_registered():
    assert {"stnet", "temnet"} <= set(available())
    assert STNet.input_kind == "markers" and TemNet.input_kind == "markers"


@pytest.mark.parametrize("name", ["stnet", "temnet"])
@pytest.mark.parametrize("pool", ["flatten", "mean", "last"])
def test_forward_shape_and_config_round_trip(name, pool):
    torch.manual_seed(0)
    model = build(name, **SMALL, pool=pool).eval()
    x = _x()
    out = model(x)
    assert out.shape == (2, 2) and out.dtype == torch.float32
    again = build(name, **model.config())
    again.load_state_dict(model.state_dict())
    again.eval()
    torch.testing.assert_close(again(x), out)
    assert again.config() == model.config()


def test_d_model_defaults_to_flattened_markers():
    model = STNet(frames=2, markers=8, heads=4, blocks=1, ff_dim=8)
    assert model.config()["d_model"] == 24
    assert isinstance(TemNet(frames=2, markers=8, heads=4, blocks=1, ff_dim=8).fuse, torch.nn.Identity)


def test_temnet_smaller_than_stnet():
    assert count_parameters(build("temnet", **SMALL)) < count_parameters(build("stnet", **SMALL))


def test_preset_overrides_and_errors():
    model = build("temnet", **{**PRESETS["compact"], "blocks": 1, "markers": 20})
    assert model.config()["blocks"] == 1 and model.config()["markers"] == 20
    with pytest.raises(ConfigError):
        build("temnet", **{**PRESETS["compact"], "colour": "red"})


@pytest.mark.parametrize(
    "bad",
    [
        dict(d_model=18),
        dict(pool="max"),
        dict(codec_kernel=4),
        dict(dropout=1.0),
        dict(blocks=0),
        dict(activation="tanh"),
        dict(num_classes=1),
        dict(head_hidden=-1),
    ],
)
def test_bad_config_raises_config_error(bad):
    with pytest.raises(ConfigError):
        build("stnet", **{**SMALL, **bad})


def test_temnet_rejects_use_codecs():
    with pytest.raises(ConfigError):
        build("temnet", **SMALL, use_codecs=True)


def test_xavier_normal_init():
    torch.manual_seed(0)
    model = STNet(frames=12, markers=100, d_model=256, heads=8, blocks=1, ff_dim=512, head_hidden=0)
    w = model.blocks[0].ff[0].weight
    assert w.std().item() == pytest.approx(math.sqrt(2 / (256 + 512)), rel=0.05)
    assert torch.all(model.blocks[0].ff[0].bias == 0)


# check_input


@pytest.mark.parametrize(
    "shape, words",
    [
        ((2, 5, 10, 3), "got shape (2, 5, 10, 3)"),  # wrong T
        ((2, 4, 11, 3), "got shape (2, 4, 11, 3)"),  # wrong M
        ((2, 4, 10, 2), "got shape (2, 4, 10, 2)"),  # wrong last dim
        ((4, 10, 3), "3-D"),
        ((0, 4, 10, 3), "got shape (0, 4, 10, 3)"),
    ],
)
def test_check_input_shape_errors(small, shape, words):
    with pytest.raises(InputError) as err:
        small.check_input(torch.zeros(shape))
    assert words in str(err.value) and "(B, 4, 10, 3)" in str(err.value)
    assert err.value.path is None and "\n" not in str(err.value)


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -float("inf")])
def test_check_input_reports_first_non_finite(small, value):
    x = _x(3)
    x[1, 2, 7, 1] = value
    x[2, 0, 0, 0] = value
    with pytest.raises(InputError, match=r"sample 1, frame 2, marker 7"):
        small.check_input(x)


def test_check_input_rejects_non_tensor_and_ints(small):
    with pytest.raises(InputError):
        small.check_input([[0.0]])
    with pytest.raises(InputError, match="dtype"):
        small.check_input(torch.zeros(1, 4, 10, 3, dtype=torch.int64))
    small.check_input(_x(1))
    small.check_input(_x(1).double())


@settings(max_examples=60, deadline=None)
@given(shape=st.lists(st.integers(0, 12), min_size=0, max_size=6))
def test_check_input_property(small, shape):
    x = torch.zeros(shape)
    ok = len(shape) == 4 and shape[0] >= 1 and shape[1:] == [4, 10, 3]
    if ok:
        small.check_input(x)
    else:
        with pytest.raises(InputError):
            small.check_input(x)


# training and interpretation


@pytest.mark.parametrize("name", ["stnet", "temnet"])
def test_gradient_reaches_every_parameter(name):
    torch.manual_seed(0)
    model = build(name, **{**SMALL, "dropout": 0.1}).train()
    loss = torch.nn.functional.cross_entropy(model(_x(4)), torch.tensor([0, 1, 1, 0]))
    loss.backward()
    for pname, p in model.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), pname
        assert p.grad.abs().sum() > 0, pname


def test_a_few_steps_learn_a_toy_task():
    """Slip = markers drift over the frames; static = they don't. Adam learns it in a few steps."""
    torch.manual_seed(0)
    model = build("stnet", **SMALL)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    x = torch.randn(32, 1, 10, 3).repeat(1, 4, 1, 1)
    y = torch.arange(32) % 2
    drift = torch.linspace(0, 1, 4).view(1, 4, 1, 1) * torch.tensor([1.0, 0, 0])
    x = x + y.view(-1, 1, 1, 1) * drift
    for _ in range(60):
        opt.zero_grad()
        loss = torch.nn.functional.cross_entropy(model(x), y)
        loss.backward()
        opt.step()
    assert loss.item() < 0.1


def test_marker_saliency(small):
    x = _x(2)
    x[:, :, 3] += torch.linspace(0, 2, 4).view(1, 4, 1)  # marker 3 moves
    sal = small.marker_saliency(x)
    assert sal.shape == (2, SMALL["markers"])
    assert (sal >= 0).all() and torch.allclose(sal.amax(1), torch.ones(2))
    assert small.training is False
    still = x[:, :1].repeat(1, 4, 1, 1)  # no displacement -> no relevance
    assert small.marker_saliency(still).abs().max() == 0
    assert small.marker_saliency(x, baseline="zero").shape == (2, SMALL["markers"])
    with pytest.raises(ConfigError):
        small.marker_saliency(x, baseline="mean")
    with pytest.raises(InputError):
        small.marker_saliency(x[:, :3])


def test_saliency_restores_training_mode():
    model = build("stnet", **SMALL).train()
    model.marker_saliency(_x(1))
    assert model.training


# fast and reduced-precision inference


@pytest.mark.parametrize("name", ["stnet", "temnet"])
def test_optimize_for_inference_matches(name):
    torch.manual_seed(0)
    model = build(name, **{**SMALL, "d_model": 32}).eval()
    x = _x(3)
    fast = optimize_for_inference(model)
    with torch.inference_mode():
        ref = model(x)
        torch.testing.assert_close(fast(x), ref, atol=1e-4, rtol=1e-4)
        torch.testing.assert_close(fast(x[:1]), ref[:1], atol=1e-4, rtol=1e-4)  # other batch size
        bf = optimize_for_inference(model, torch.bfloat16)(x)
    assert bf.dtype == torch.float32
    assert (bf - ref).abs().max() < 0.1 * ref.abs().max() + 0.05
    with pytest.raises(ConfigError, match="gradients"):
        fast.marker_saliency(x)
    assert next(model.parameters()).dtype == torch.float32  # the original is untouched
    with pytest.raises(ConfigError):
        optimize_for_inference(model, torch.float16)


def test_int8_close_to_float():
    torch.manual_seed(0)
    model = STNet(**{**PRESETS["compact"], "markers": 40}).eval()
    x = torch.randn(16, 12, 40, 3)
    q = quantize_dynamic_int8(model)
    with torch.inference_mode():
        ref, out = model(x), q(x)
    assert out.shape == ref.shape
    err = (out - ref).abs().max() / ref.abs().max()
    assert err < 0.1, float(err)
    assert (out.argmax(1) == ref.argmax(1)).float().mean() >= 0.8
    assert any("Quantized" in type(m).__name__ or "quantized" in type(m).__module__ for m in q.modules())


def test_upsample_conv_equals_upsample_then_conv1d():
    from slipsense.models.stnet import UpsampleConv1d

    torch.manual_seed(0)
    fast = UpsampleConv1d(6, 16, 3)
    torch.nn.init.normal_(fast.weight)
    torch.nn.init.normal_(fast.bias)
    conv = torch.nn.Conv1d(6, 1, 3, padding=1)
    conv.load_state_dict(fast.state_dict())
    z = torch.randn(5, 6, 13)
    ref = conv(torch.nn.Upsample(scale_factor=16)(z))
    torch.testing.assert_close(fast(z), ref, atol=1e-5, rtol=1e-5)


def test_frame_sum_head_matches_flat_linear():
    from slipsense.models.stnet_fast import FrameSumLinear

    torch.manual_seed(0)
    model = build("stnet", **{**SMALL, "head_hidden": 64}).eval()
    fast = optimize_for_inference(model)
    assert isinstance(fast.to_logits[0], FrameSumLinear)
    with torch.inference_mode():
        for b in (1, 5):
            torch.testing.assert_close(fast(_x(b)), model(_x(b)), atol=1e-4, rtol=1e-4)


def test_relative_input_ignores_where_the_window_starts():
    """relative=True sees displacements from the window's first frame: a rigid shift of the whole
    window changes nothing; the paper's absolute input does change."""
    import torch

    from slipsense.models import build

    torch.manual_seed(0)
    kw = dict(frames=4, markers=9, d_model=16, heads=2, blocks=1, ff_dim=16, codec_channels=2, dropout=0.0)
    rel = build("stnet", relative=True, **kw).eval()
    x = torch.randn(2, 4, 9, 3)
    shifted = x + torch.tensor([1.5, -2.0, 0.3])
    with torch.no_grad():
        torch.testing.assert_close(rel(x), rel(shifted))
        absolute = build("stnet", **kw).eval()
        assert not torch.allclose(absolute(x), absolute(shifted))
    assert rel.config()["relative"] is True and "relative" not in absolute.config()


def test_centred_stnet_takes_its_reference_from_the_training_windows_and_streams_alike():
    from slipsense.datasets import MarkerDataset
    from slipsense.models import build
    from slipsense.models.stnet_parts import MarkerFramePart, MarkerWindowPart

    torch.manual_seed(0)
    cfg = {**STNet.small_config(), "centred": True}
    model = build("stnet", **cfg).eval()
    rng = np.random.default_rng(0)
    rest = rng.normal(0, 5, (24, 3)).astype(np.float32)
    x = rest[None, None] + rng.normal(0, 0.03, (40, 4, 24, 3)).astype(np.float32)
    model.prepare(MarkerDataset(x, np.zeros(40, np.int64)))
    # within the noise (z is an upper quantile of the first frames: 1.3 noise deviations above rest)
    assert torch.allclose(model.reference, torch.from_numpy(rest), atol=0.1)
    window = torch.from_numpy(x[:2])
    with torch.no_grad():
        full = model(window)
        tokens = MarkerFramePart(model)(window.reshape(-1, 24, 3)).reshape(2, 4, -1)
        assert torch.allclose(MarkerWindowPart(model)(tokens), full, atol=1e-5)
    with pytest.raises(ConfigError, match="choose one"):
        build("stnet", **{**cfg, "relative": True})
