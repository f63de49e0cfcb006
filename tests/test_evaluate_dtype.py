"""Scoring a checkpoint at reduced inference precision (``slipsense evaluate --dtype``)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from slipsense.checkpoint import save_checkpoint
from slipsense.cli import app
from slipsense.errors import ConfigError
from slipsense.evaluation.checkpoints import evaluate_checkpoint as evaluate_clip_checkpoint
from slipsense.models import build, at_dtype

runner = CliRunner()


@pytest.fixture(scope="module")
def stnet_and_markers(tmp_path_factory):
    root = tmp_path_factory.mktemp("dtype")
    torch.manual_seed(0)
    model = build("stnet", frames=12, markers=10, d_model=32, heads=4, blocks=1, ff_dim=64, codec_channels=4)
    rng = np.random.default_rng(0)
    x = rng.normal(size=(40, 12, 10, 3)).astype(np.float32)
    y = (x[:, -1, :, 0].mean(1) > 0).astype(np.int64)
    np.savez(root / "m.npz", x=x, y=y)
    return save_checkpoint(root / "stnet.safetensors", model, {}), root / "m.npz", root


@pytest.mark.parametrize("dtype", ["int8", "bfloat16"])
def test_reduced_precision_scores_close_to_float32(stnet_and_markers, dtype):
    ckpt, markers, root = stnet_and_markers
    ref = evaluate_clip_checkpoint(ckpt, markers=markers, json_out=root / "f32.json", progress=False)
    low = evaluate_clip_checkpoint(ckpt, markers=markers, json_out=root / f"{dtype}.json", progress=False, dtype=dtype)
    assert ref["inference_dtype"] == "float32" and low["inference_dtype"] == dtype
    assert isinstance(low["precision"], float)  # the metric is not overwritten
    assert low["n_clips"] == ref["n_clips"] == 40
    assert abs(low["accuracy"] - ref["accuracy"]) <= 0.1  # a few borderline windows may flip
    assert json.loads((root / f"{dtype}.json").read_text())["inference_dtype"] == dtype


def test_dtype_errors(stnet_and_markers):
    ckpt, markers, root = stnet_and_markers
    result = runner.invoke(
        app,
        [
            "evaluate",
            "--checkpoint",
            str(ckpt),
            "--markers",
            str(markers),
            "--dtype",
            "float16",
            "--json",
            str(root / "x.json"),
        ],
    )
    assert result.exit_code == 2 and "float16" in result.output
    vivit = build("vivit", image_size=(32, 32), patch_size=(16, 16), frames=2).eval()
    assert at_dtype(vivit, "float32") is vivit
    for dtype in ("bfloat16", "int8"):
        with pytest.raises(ConfigError, match="STNet and TemNet"):
            at_dtype(vivit, dtype)
