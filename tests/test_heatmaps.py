"""Heat-map figures: ViViT attention over frames, STNet marker relevance over the displacement field."""

import numpy as np
import pytest
import torch

from slipsense.errors import InputError
from slipsense.heatmaps import marker_saliency_figure, video_attention_figure
from slipsense.models import build


def test_video_attention_figure(tmp_path):
    torch.manual_seed(0)
    model = build("vivit", image_size=(48, 64), patch_size=(16, 16), frames=3).eval()
    clip = np.random.default_rng(0).integers(0, 255, (3, 48, 64, 3), dtype=np.uint8)
    out = video_attention_figure(model, clip, tmp_path / "att.png")
    assert out.stat().st_size > 1000


def test_marker_saliency_figure(tmp_path):
    torch.manual_seed(0)
    model = build("stnet", frames=4, markers=9, d_model=16, heads=2, blocks=1, ff_dim=16, codec_channels=2).eval()
    grid = np.stack(np.meshgrid(np.arange(3.0), np.arange(3.0)), -1).reshape(9, 2)
    window = np.concatenate([np.repeat(grid[None], 4, 0), np.zeros((4, 9, 1))], -1).astype(np.float32)
    window[:, 4, 0] += np.linspace(0, 0.5, 4)
    out = marker_saliency_figure(model, window, grid, tmp_path / "sal.png")
    assert out.stat().st_size > 1000


def test_attention_figure_needs_a_model_with_attention(tmp_path):
    model = build("resnet3d50", width=2, layers=[1, 1, 1, 1]).eval()
    with pytest.raises(InputError, match="no spatial attention"):
        video_attention_figure(model, np.zeros((2, 32, 32, 3), np.uint8), tmp_path / "x.png")
