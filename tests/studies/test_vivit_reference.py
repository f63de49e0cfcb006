"""slipsense's ViViT computes vit-pytorch's ViViT (frame_patch_size=1) with the same weights
(studies/experiments/vivit_reference.py)."""

from __future__ import annotations

import pytest
import torch

from conftest import perturbed, random_clip
from slipsense.errors import ConfigError
from slipsense.models import count_parameters
from studies.experiments.vivit_reference import from_vit_pytorch, vit_pytorch_vivit


@pytest.fixture(autouse=True)
def _one_thread(one_thread):
    """Every test here on one torch thread (tests/conftest.py)."""


def test_matches_vit_pytorch_reference():
    try:
        RefViViT = vit_pytorch_vivit()
    except ModuleNotFoundError:
        pytest.skip("vit_pytorch not installed")
    torch.manual_seed(0)
    ref = RefViViT(
        image_size=(240, 320),
        image_patch_size=(40, 40),
        frames=5,
        frame_patch_size=1,
        num_classes=2,
        dim=8,
        spatial_depth=2,
        temporal_depth=2,
        heads=2,
        mlp_dim=8,
    ).eval()
    perturbed(ref)
    ours = from_vit_pytorch(ref).eval()
    assert count_parameters(ours) == count_parameters(ref)
    x = random_clip(2, 5, 3, 240, 320, seed=5)
    with torch.no_grad():
        expected = ref(x.permute(0, 2, 1, 3, 4))  # vit-pytorch takes (B, C, T, H, W)
        assert (ours(x) - expected).abs().max() < 1e-5
        ours.fused = False
        assert (ours(x) - expected).abs().max() < 1e-5
    ref_mean = RefViViT(
        image_size=(16, 24),
        image_patch_size=(8, 8),
        frames=3,
        frame_patch_size=1,
        num_classes=2,
        dim=8,
        spatial_depth=1,
        temporal_depth=2,
        heads=1,
        dim_head=8,
        mlp_dim=4,
        pool="mean",
    ).eval()
    ours_mean = from_vit_pytorch(ref_mean, image_size=(16, 24)).eval()
    x = random_clip(2, 3, 3, 16, 24, seed=6)
    with torch.no_grad():
        assert (ours_mean(x) - ref_mean(x.permute(0, 2, 1, 3, 4))).abs().max() < 1e-5
    tubelet = RefViViT(
        image_size=(16, 24),
        image_patch_size=(8, 8),
        frames=4,
        frame_patch_size=2,
        num_classes=2,
        dim=8,
        spatial_depth=1,
        temporal_depth=1,
        heads=1,
        mlp_dim=4,
    )
    with pytest.raises(ConfigError, match="frame_patch_size"):
        from_vit_pytorch(tubelet, image_size=(16, 24))
