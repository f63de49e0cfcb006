"""Heat-map figures: ViViT attention over frames, STNet marker relevance over the displacement field."""

import numpy as np
import pytest
import torch

from slipsense.errors import InputError
from studies.experiments.heatmaps import marker_saliency_figure, video_attention_figure
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


def test_a_centred_model_attributes_a_standing_displacement_from_rest_not_from_the_first_frame():
    torch.manual_seed(0)
    model = build(
        "stnet", frames=4, markers=9, d_model=16, heads=2, blocks=1, ff_dim=16, codec_channels=2, centred=True
    ).eval()
    window = torch.zeros(1, 4, 9, 3)
    window[:, :, 4, 0] = 0.5  # marker 4 displaced from rest all window long: no motion within the window
    assert model.marker_saliency(window, baseline="first").abs().sum() == 0
    rest = model.marker_saliency(window, baseline="rest")[0]
    assert rest[4] == 1 and (rest[torch.arange(9) != 4] == 0).all()


def test_relevance_in_contact_measures_where_the_model_looks():
    from studies.experiments.heatmaps import relevance_in_contact

    class Looks(torch.nn.Module):  # relevance 3 on marker 0, 1 on marker 1, 0 elsewhere
        def __init__(self):
            super().__init__()
            self.weight = torch.nn.Parameter(torch.zeros(1))

        def marker_saliency(self, x, baseline="rest"):
            rel = torch.zeros(x.shape[0], x.shape[2])
            rel[:, 0], rel[:, 1] = 3.0, 1.0
            return rel

    rest = np.zeros((8, 3), np.float32)
    x = np.zeros((3, 2, 8, 3), np.float32)
    x[:, -1, 0, 2] = -0.3  # marker 0 pressed in: the contact
    x[2] = 0  # no contact: left out
    out = relevance_in_contact(Looks(), x, rest)
    assert out["windows"] == 2
    assert out["relevance_in_contact"] == pytest.approx(0.75) and out["markers_in_contact"] == pytest.approx(1 / 8)
    assert out["concentration"] == pytest.approx(6.0)
    none = relevance_in_contact(Looks(), np.zeros((2, 2, 8, 3), np.float32), rest)
    assert none["windows"] == 0 and np.isnan(none["concentration"])
