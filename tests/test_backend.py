"""The live detector's default backend: ONNX Runtime where it is installed (parts exported once and
reused), PyTorch otherwise, and it says which."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from typer.testing import CliRunner

from slipsense.cli import app
from slipsense.models.runners import resolve_backend
from slipsense.streaming.detector import SlipDetector


def _without_onnxruntime(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "onnxruntime" else real(name, *a))


def test_auto_is_onnx_where_installed_else_torch(monkeypatch):
    pytest.importorskip("onnxruntime")
    assert resolve_backend("auto") == "onnx"
    assert resolve_backend("torch") == "torch"
    _without_onnxruntime(monkeypatch)
    assert resolve_backend("auto") == "torch"
    assert resolve_backend("onnx") == "onnx"  # asked for by name: its own error when it is missing


def test_pretrained_runs_on_onnx_runtime_with_parts_exported_once(tmp_path, monkeypatch):
    pytest.importorskip("onnxruntime")
    monkeypatch.setenv("SLIPSENSE_CACHE", str(tmp_path / "cache"))
    first = SlipDetector.pretrained(sensors=2)
    assert first.backend == "onnx"
    parts = sorted((tmp_path / "cache" / "onnx").rglob("*.onnx"))
    assert parts, "the parts are cached beside the checkpoint's hash"
    stamps = [p.stat().st_mtime_ns for p in parts]
    second = SlipDetector.pretrained(sensors=2)  # a second start reuses them
    assert [p.stat().st_mtime_ns for p in parts] == stamps
    torch_det = SlipDetector.pretrained(sensors=2, backend="torch")
    assert torch_det.backend == "torch"
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 255, size=(30, 2, 240, 320, 3), dtype=np.uint8)
    for a, b in frames:
        ra, rb = second.push(a, b), torch_det.push(a, b)
    assert ra.probability == pytest.approx(rb.probability, abs=1e-4)


def test_pretrained_falls_back_to_pytorch_without_onnxruntime(monkeypatch):
    _without_onnxruntime(monkeypatch)
    assert SlipDetector.pretrained(sensors=1).backend == "torch"


def test_watch_says_which_backend_runs(tmp_path, monkeypatch):
    import cv2

    video = tmp_path / "camera_0.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 25, (320, 240))
    for i in range(20):
        writer.write(np.full((240, 320, 3), 40 + i, dtype=np.uint8))
    writer.release()
    _without_onnxruntime(monkeypatch)
    result = CliRunner().invoke(app, ["watch", str(video), "--quiet"])
    assert result.exit_code == 0, result.output
    result = CliRunner().invoke(app, ["watch", str(video)])
    assert result.exit_code == 0, result.output
    assert "motionnet-gelsight-1 on PyTorch, 1 sensor(s)" in result.output.splitlines()[0]
