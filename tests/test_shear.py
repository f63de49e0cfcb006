"""Shear retention (slipsense.models.shear) on synthetic marker gels: a grasp whose markers shift and
stay is held, one whose markers shift and spring back is a slip, and a gel that never moves or only
moves a little stays quiet."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from slipsense.errors import ConfigError
from slipsense.models import build
from slipsense.models.shear import running_max

H, W = 60, 80


def _gel(shifts, seed: int = 0) -> np.ndarray:
    """uint8 ``(N, H, W)``: dark square markers every 10 pixels on a light shaded gel, the markers
    displaced by ``shifts[t]`` = ``(dx, dy)`` pixels in frame ``t`` (subpixel, drawn by area)."""
    rng = np.random.default_rng(seed)
    shade = 180 + 30 * np.linspace(0, 1, W)[None] + rng.normal(0, 2, (H, W))
    yy, xx = np.mgrid[0 : H * 4, 0 : W * 4] / 4.0  # 4x supersampled
    frames = []
    for dx, dy in shifts:
        u, v = (xx - dx - 5) % 10, (yy - dy - 5) % 10
        dots = ((np.abs(u - 5) < 1.5) & (np.abs(v - 5) < 1.5)).astype(float)
        dots = dots.reshape(H, 4, W, 4).mean(axis=(1, 3))
        frames.append(np.clip(shade * (1 - 0.7 * dots), 0, 255))
    return np.round(np.stack(frames)).astype(np.uint8)


def _peak(model, gray: np.ndarray) -> float:
    x = torch.from_numpy(gray).float()[None, None] / 255.0
    with torch.no_grad():
        return float(torch.softmax(model(x)[0], dim=-1)[:, 1].max())


@pytest.fixture(scope="module")
def model():
    return build("shear-retention", sensors=1, image_size=(H, W), patch=10).eval()


def test_shear_held_is_quiet_and_shear_given_up_alarms(model):
    lift = [(0.0, 0.0)] * 3 + [(0.0, 0.7 * k) for k in range(1, 5)]  # the lift shears the gel 2.8 px
    held = _gel(lift + [(0.0, 2.8)] * 8)
    slipped = _gel(lift + [(0.0, 2.8 - 0.35 * k) for k in range(1, 9)])  # it springs back as the object slides
    still = _gel([(0.0, 0.0)] * 15)
    assert _peak(model, slipped) > 0.9
    assert _peak(model, held) < 0.1
    assert _peak(model, still) < 0.1


def test_stream_pushes_like_the_whole_run_and_reset_starts_a_grasp(model):
    gray = _gel([(0.0, 0.0)] * 2 + [(0.5 * k, 0.3 * k) for k in range(6)] + [(1.0, 0.5)] * 4, seed=1)
    x = torch.from_numpy(gray).float()[None, None] / 255.0
    with torch.no_grad():
        whole = torch.softmax(model(x)[0], dim=-1)[:, 1].numpy()
    stream = model.stream()
    for _ in range(2):  # a second grasp after reset() answers as the first did
        stream.reset()
        pushed = [stream.push_gray(g[None]) for g in gray]
        np.testing.assert_allclose(pushed, whole, atol=1e-5)


def test_running_max_is_the_cumulative_maximum():
    x = torch.randn(300, 3)
    torch.testing.assert_close(running_max(x, dim=0), torch.cummax(x, dim=0).values)


def test_settings_outside_the_contract_are_refused():
    with pytest.raises(ConfigError, match="divisible"):
        build("shear-retention", image_size=(65, 80), patch=10)
    with pytest.raises(ConfigError, match="iterations"):
        build("shear-retention", iterations=0)
    with pytest.raises(ConfigError, match="softness"):
        build("shear-retention", softness=-1)


def test_sharp_steps_count_the_cells_exactly():
    """softness 0 (numbers chosen, not learned): the score is the share of moved cells that let go,
    over the moved cells plus one; the soft steps of training leak from cells that barely moved."""
    sharp = build("shear-retention", sensors=1, image_size=(H, W), softness=0, gate=0.5, letgo=0.4, bias=0.0)
    soft = build("shear-retention", sensors=1, image_size=(H, W), gate=0.5, letgo=0.4, bias=0.0)
    cells = sharp.cells
    peak = torch.zeros(1, 1, cells)
    peak[..., :4] = 2.0  # four cells moved 2 px ...
    shift = peak.clone()
    shift[..., :3] = 0.5  # ... three of them gave up 75% of it
    with torch.no_grad():
        logit = sharp.logits_of(shift, peak)[0, 1]
        leaky = soft.logits_of(shift + 0.01, peak + 0.3)[0, 1]  # untouched cells "moved" 0.3 px
    assert float(logit) == pytest.approx(float(sharp.slope) * 3 / 5)
    assert float(leaky) != pytest.approx(float(logit), rel=0.05)


def test_sharp_steps_export_to_onnx(tmp_path):
    """The shipped gelsight-lift detector has sharp steps: its ONNX files answer as PyTorch does."""
    pytest.importorskip("onnxruntime")
    from slipsense.streaming.export import export_onnx

    sharp = build("shear-retention", sensors=1, image_size=(H, W), softness=0).eval()
    result = export_onnx(sharp, tmp_path / "sharp.onnx")
    assert set(result.paths) == {"model", "frame", "step"} and max(result.max_abs_diff.values()) <= 1e-4


def test_tracked_shifts_are_read_back_from_disk_and_never_written_while_training(cache, monkeypatch):
    """A grasp tracked once is read back (another process, or after this one forgot it), the same
    numbers; gradient training's frames (flipped, at another gain every epoch) stay off the disk."""
    from slipsense.models import tracking

    for name in ("shear-retention", "slip-velocity"):
        model = build(name, sensors=1, image_size=[H, W]).eval()
        gray = torch.from_numpy(_gel([(0.2 * t, 0.0) for t in range(12)])).float()[None, None] / 255.0
        with torch.no_grad():
            first = model(gray)
        written = sorted((cache / "tracked").glob("*.safetensors"))

        def untracked(*_):
            raise AssertionError("tracked again")

        with monkeypatch.context() as m:
            m.setattr(tracking, "_MEMO", {})
            m.setattr(type(model), "_track", untracked)
            with torch.no_grad():
                assert torch.equal(model(gray), first)
        with torch.no_grad():
            model.train()(gray.flip(-1))
        assert sorted((cache / "tracked").glob("*.safetensors")) == written
    assert len(written) == 2
