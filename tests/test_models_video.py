"""Video models: ViViT (factorised encoder, the paper's network) and the 3D ResNet-50 baseline."""

from __future__ import annotations


import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import perturbed, random_clip
from slipsense.errors import ConfigError, InputError
from slipsense.models import available, build, count_parameters
from slipsense.models.resnet3d import PAPER_PARAMETERS


@pytest.fixture(autouse=True)
def _one_thread(one_thread):
    """Every test here on one torch thread (tests/conftest.py)."""


# small ViViT for most tests: 2 x 3 patches of 8 x 8, 3 frames
SMALL = dict(image_size=(16, 24), patch_size=(8, 8), frames=3, dim=8, heads=2, dim_head=16, mlp_dim=8)


# ---------------------------------------------------------------- ViViT


def test_registered_and_config_round_trip():
    assert {"vivit", "resnet3d50"} <= set(available())
    model = build("vivit", **SMALL)
    assert model.input_kind == "video"
    again = build("vivit", **model.config())
    assert again.config() == model.config()
    assert {k: v.shape for k, v in again.state_dict().items()} == {k: v.shape for k, v in model.state_dict().items()}


def test_paper_config_defaults_and_parameter_count():
    model = build("vivit")
    cfg = model.config()
    assert cfg["image_size"] == [240, 320] and cfg["patch_size"] == [40, 40] and cfg["frames"] == 5
    assert (cfg["dim"], cfg["spatial_depth"], cfg["temporal_depth"], cfg["heads"]) == (8, 2, 2, 2)
    assert (cfg["dim_head"], cfg["mlp_dim"], cfg["num_classes"], cfg["pool"]) == (64, 8, 2, "cls")
    n = count_parameters(model)
    print(f"ViViT paper configuration: {n:,} parameters")
    assert n == 67_130  # = vit-pytorch ViViT(frame_patch_size=1) at this size


@pytest.mark.parametrize(
    "bad", [dict(image_size=(250, 320)), dict(pool="max"), dict(dim=0), dict(dropout=1.5), dict(unknown=1)]
)
def test_bad_config_is_config_error(bad):
    with pytest.raises(ConfigError):
        build("vivit", **bad)


def test_shapes_and_split_forward():
    model = build("vivit").eval()
    x = random_clip(2, 5, 3, 240, 320)
    with torch.no_grad():
        tokens = model.encode_frames(x)
        logits = model(x)
        assert tokens.shape == (2, 5, 8)
        assert logits.shape == (2, 2)
        assert torch.equal(model.classify_frames(tokens), logits)
        # streaming: patch tokens cached per frame, finished per clip
        cached = torch.stack([model.embed_patches(x[:, t]) for t in range(5)], dim=1)  # (B, T, P, dim)
        assert cached.shape == (2, 5, 48, 8)
        assert torch.allclose(model.encode_patches(cached), tokens, atol=1e-6)


@pytest.mark.parametrize(
    "shape, fragment",
    [
        ((1, 4, 3, 240, 320), "got (1, 4, 3, 240, 320)"),  # wrong T
        ((1, 5, 3, 200, 320), "(B, 5, 3, 240, 320)"),  # wrong H
        ((1, 5, 3, 240, 300), "(B, 5, 3, 240, 320)"),  # wrong W
        ((1, 5, 1, 240, 320), "channels"),  # wrong C
        ((5, 3, 240, 320), "got (5, 3, 240, 320)"),  # no batch dimension
        ((0, 5, 3, 240, 320), "got (0, 5, 3, 240, 320)"),  # empty batch
    ],
)
def test_check_input_rejects_wrong_shapes(shape, fragment):
    model = build("vivit")
    with pytest.raises(InputError) as info:
        model.check_input(torch.zeros(shape))
    assert fragment in str(info.value)
    assert info.value.path is None
    with pytest.raises(InputError):  # forward checks the shape too
        model(torch.zeros(shape))


def test_check_input_rejects_non_finite_and_non_float():
    model = build("vivit", **SMALL)
    x = random_clip(1, 3, 3, 16, 24)
    model.check_input(x)
    for value in (float("nan"), float("inf")):
        bad = x.clone()
        bad[0, 1, 2, 3, 4] = value
        with pytest.raises(InputError, match="NaN or infinite"):
            model.check_input(bad)
    with pytest.raises(InputError, match="float"):
        model.check_input((x * 255).to(torch.uint8))
    with pytest.raises(InputError, match="torch.Tensor"):
        model.check_input(x.numpy())


@given(
    shape=st.lists(st.integers(min_value=0, max_value=6), min_size=3, max_size=6),
    fix=st.lists(st.booleans(), min_size=4, max_size=4),
)
@settings(max_examples=60, deadline=None)
def test_check_input_property(shape, fix):
    """check_input accepts exactly the (B>=1, 3, 3, 16, 24) shapes and raises InputError on all others."""
    model = build("vivit", image_size=(16, 24), patch_size=(8, 8), frames=3, dim=4, dim_head=4, mlp_dim=4)
    if len(shape) == 5:  # bias towards nearly right shapes
        for i, keep in enumerate(fix):
            if keep:
                shape[i + 1] = (3, 3, 16, 24)[i]
    x = torch.zeros(shape)
    ok = len(shape) == 5 and shape[0] >= 1 and tuple(shape[1:]) == (3, 3, 16, 24)
    if ok:
        model.check_input(x)
    else:
        with pytest.raises(InputError):
            model.check_input(x)


def test_fused_patch_embedding_matches_plain():
    model = perturbed(build("vivit")).eval()
    x = random_clip(2, 5, 3, 240, 320, seed=1)
    # smooth, low-contrast frames are the hard case for variance arithmetic
    ramp = torch.linspace(0, 1, 320)
    smooth = 0.45 + 0.02 * ramp + 0.004 * torch.randn(2, 5, 3, 240, 320, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        for clip in (x, smooth.clamp(0, 1)):
            model.fused = True
            fast = model(clip)
            model.fused = False
            plain = model(clip)
            assert (fast - plain).abs().max() < 1e-5
    # in float64 both paths are exact: they must agree to rounding
    model64 = perturbed(build("vivit")).double().eval()
    frames = smooth[0].double()
    with torch.no_grad():
        model64.fused = True
        a = model64.embed_patches(frames)
        model64.fused = False
        b = model64.embed_patches(frames)
    assert (a - b).abs().max() < 1e-9


def test_fused_patch_embedding_gradients_match_plain():
    torch.manual_seed(0)
    model = perturbed(build("vivit", **SMALL)).train()
    x = random_clip(2, 3, 3, 16, 24, seed=3)
    grads = []
    for fused in (True, False):
        model.zero_grad()
        model.fused = fused
        model(x)[:, 1].sum().backward()
        grads.append({k: p.grad.clone() for k, p in model.named_parameters()})
    for k in grads[0]:
        assert torch.allclose(grads[0][k], grads[1][k], atol=1e-5, rtol=1e-4), k


def test_folded_inference_attention_matches_training_path():
    model = perturbed(build("vivit")).eval()
    x = random_clip(1, 5, 3, 240, 320, seed=4)
    with torch.no_grad():  # folded attention (and cached folded weights)
        folded = model(x)
        folded_again = model(x)
    with torch.enable_grad():  # standard q/k/v attention
        standard = model(x)
    assert torch.equal(folded, folded_again)
    assert (folded - standard).abs().max() < 1e-5
    # the cache follows weight updates
    with torch.no_grad():
        model.spatial_transformer.layers[0][0].to_qkv.weight.mul_(1.5)
        updated = model(x)
    with torch.enable_grad():
        assert (updated - model(x)).abs().max() < 1e-5
    assert (updated - folded).abs().max() > 1e-4


def test_gradients_reach_every_parameter():
    for pool in ("cls", "mean"):
        model = build("vivit", pool=pool, **SMALL).train()
        loss = torch.nn.functional.cross_entropy(model(random_clip(2, 3, 3, 16, 24)), torch.tensor([0, 1]))
        loss.backward()
        for name, p in model.named_parameters():
            assert p.grad is not None and torch.isfinite(p.grad).all(), name
            assert p.grad.abs().sum() > 0, name


def test_attention_maps():
    model = perturbed(build("vivit", **SMALL)).eval()
    x = random_clip(2, 3, 3, 16, 24)
    logits, att = model(x, return_attention=True)
    assert torch.allclose(logits, model(x), atol=1e-6)
    assert att["spatial"].shape == (2, 3, 2, 2, 7, 7)  # (B, T, depth, heads, 1 + P, 1 + P)
    assert att["temporal"].shape == (2, 2, 2, 4, 4)  # (B, depth, heads, 1 + T, 1 + T)
    assert torch.allclose(att["spatial"].sum(-1), torch.ones(2, 3, 2, 2, 7))
    with torch.enable_grad():  # the standard attention path gives the same weights
        _, att_std = model(x, return_attention=True)
    assert torch.allclose(att["spatial"], att_std["spatial"].detach(), atol=1e-6)
    heat = model.cls_attention_map(x)
    assert heat.shape == (2, 3, 2, 3)  # (B, T, Hp, Wp)
    assert torch.allclose(heat.sum(dim=(-1, -2)), torch.ones(2, 3), atol=1e-5)
    assert (heat >= 0).all()
    mean_model = build("vivit", pool="mean", **SMALL).eval()
    assert mean_model.attention_maps(x)["spatial"].shape == (2, 3, 2, 2, 6, 6)
    assert mean_model.cls_attention_map(x).shape == (2, 3, 2, 3)


def test_inference_caches_follow_state_dict_and_survive_copies():
    import copy
    import pickle

    model = perturbed(build("vivit", **SMALL)).eval()
    other = perturbed(build("vivit", **SMALL), seed=9).eval()
    x = random_clip(2, 3, 3, 16, 24)
    with torch.no_grad():
        model(x)  # fills the folded-weight caches and the scratch buffer
        model.load_state_dict(other.state_dict())
        assert torch.allclose(model(x), other(x), atol=1e-6)
        for clone in (copy.deepcopy(model), pickle.loads(pickle.dumps(model))):
            assert torch.allclose(clone(x), other(x), atol=1e-6)
        assert torch.equal(x, random_clip(2, 3, 3, 16, 24))  # the input is never written to


def test_onnx_export_matches(tmp_path):
    ort = pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    import warnings

    model = perturbed(build("vivit", **SMALL)).eval()
    x = random_clip(1, 3, 3, 16, 24)
    path = tmp_path / "vivit.onnx"
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model(x)  # caches filled: the export must not bake them or the scratch buffer in
        torch.onnx.export(
            model,
            (x,),
            str(path),
            dynamo=False,
            input_names=["video"],
            output_names=["logits"],
            dynamic_axes={"video": {0: "batch"}},
        )
    session = ort.InferenceSession(str(path))
    for batch in (1, 3):
        clip = random_clip(batch, 3, 3, 16, 24, seed=batch)
        (logits,) = session.run(None, {"video": clip.numpy()})
        with torch.no_grad():
            assert abs(torch.from_numpy(logits) - model(clip)).max() < 1e-5


# ---------------------------------------------------------------- 3D ResNet-50

TINY = dict(width=8)


def test_resnet3d50_parameter_count_matches_paper():
    model = build("resnet3d50")  # no forward: building is about 0.5 s
    slow_r50 = build("resnet3d50", stem_kernel=(1, 7, 7))
    assert model.input_kind == "video"
    assert count_parameters(model) == PAPER_PARAMETERS == 31_657_410
    assert count_parameters(slow_r50) == 31_638_594  # pytorchvideo's hub slow_r50 layout, 2 classes


def test_resnet3d50_tiny_forward_backward_any_frames():
    model = build("resnet3d50", **TINY)
    for t in (1, 3):
        assert model.eval()(random_clip(2, t, 3, 32, 32)).shape == (2, 2)
    model.train()
    loss = torch.nn.functional.cross_entropy(model(random_clip(2, 2, 3, 32, 32)), torch.tensor([0, 1]))
    loss.backward()
    for name, p in model.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
    assert build("resnet3d50", **model.config()).config() == model.config()


def test_resnet3d50_check_input():
    model = build("resnet3d50", **TINY)
    model.check_input(random_clip(1, 2, 3, 32, 32))
    for shape in [(1, 2, 1, 32, 32), (2, 3, 32, 32), (0, 2, 3, 32, 32)]:
        with pytest.raises(InputError, match="shape"):
            model.check_input(torch.zeros(shape))
    bad = random_clip(1, 2, 3, 32, 32)
    bad[0, 0, 0, 0, 0] = float("nan")
    with pytest.raises(InputError, match="NaN"):
        model.check_input(bad)
    fixed = build("resnet3d50", frames=4, **TINY)
    with pytest.raises(InputError, match=r"\(B, 4, 3, H, W\)"):
        fixed.check_input(torch.zeros(1, 2, 3, 32, 32))
    with pytest.raises(ConfigError):
        build("resnet3d50", temporal_kernels=(1, 2, 3, 3))


def test_inference_mode_then_no_grad_reuses_no_inference_buffer():
    from slipsense.models import build

    m = build("vivit", image_size=(48, 64), patch_size=(16, 16), frames=3).eval()
    x = torch.rand(1, 3, 3, 48, 64)
    with torch.inference_mode():
        a = m(x)
    with torch.no_grad():
        b = m(x)
    torch.testing.assert_close(a.clone(), b)
