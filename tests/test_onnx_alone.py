"""The exported ONNX files run alone: a program with ONNX Runtime, OpenCV and numpy but not slipsense
(what a C++ or embedded user writes) reads the operating point from the files' metadata, runs the
shipped detector's two streaming parts frame by frame and raises the same alarms as `slipsense watch`."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from conftest import needs_data
from slipsense.cli import app
from slipsense.paths import gelsight_recordings

runner = CliRunner()
RUN = gelsight_recordings() / "blue_mug" / "exp_num_9"  # it slips, and the shipped detector warns


def _alone(frame_onnx, step_onnx, videos) -> tuple[list[float | None], list[bool]]:
    """The shipped MotionNet's streaming protocol (docs/streaming.md, "The ONNX files alone"), written
    from the files' metadata only."""
    import onnxruntime as ort

    frame_part, step_part = (
        ort.InferenceSession(str(p), providers=["CPUExecutionProvider"]) for p in (frame_onnx, step_onnx)
    )
    meta = {
        k.removeprefix("slipsense."): json.loads(v) for k, v in frame_part.get_modelmeta().custom_metadata_map.items()
    }
    cfg, op, fps = meta["config"], meta["operating_point"], meta["fps"]
    h, w = cfg["image_size"]
    lags, max_lag = cfg["lags"], max(cfg["lags"])
    states = [np.zeros([d if d else 1 for d in i.shape], np.float32) for i in step_part.get_inputs()[2:]]
    caps = [cv2.VideoCapture(str(v)) for v in videos]
    history, first, probs = [], None, []
    while True:
        grabbed = [c.read() for c in caps]
        if not all(ok for ok, _ in grabbed):
            break
        gray = np.stack(
            [cv2.resize(cv2.cvtColor(f, cv2.COLOR_BGR2GRAY), (w, h), interpolation=cv2.INTER_AREA) for _, f in grabbed]
        )
        if len(probs) < op["startup"]:  # the camera's start-up frames are not the grasp
            probs.append(None)
            continue
        x = gray.astype(np.float32) / np.float32(255.0)
        if cfg["level"]:
            x *= np.float32(0.5) / np.maximum(x.mean(axis=(1, 2), keepdims=True, dtype=np.float32), np.float32(1 / 255))
        fresh = first is None
        if fresh:
            first, history = x, [x] * (max_lag + 1)
        else:
            history = [*history[1:], x]
        diffs = np.stack([x - (first if lag == 0 else history[-1 - lag]) for lag in lags], axis=1)[None]
        (feat,) = frame_part.run(None, {meta["inputs"][0]: (diffs * np.float32(cfg["diff_scale"])).astype(np.float32)})
        names = [i.name for i in step_part.get_inputs()]
        logits, *states = step_part.run(None, dict(zip(names, [feat, np.array([float(fresh)], np.float32), *states])))
        z = logits[0].astype(np.float64)
        probs.append(float(np.exp(z[1] - z.max()) / np.exp(z - z.max()).sum()))
    hold = int(round(op["hold_s"] * fps))
    alarms, run, last_on = [], 0, None
    for t, p in enumerate(probs):
        run = run + 1 if p is not None and p >= op["threshold"] else 0
        if run >= op["debounce"]:
            last_on = t
        alarms.append(last_on is not None and t - last_on <= hold)
    return probs, alarms


@needs_data
def test_the_onnx_files_alone_raise_the_alarms_watch_raises(tmp_path):
    res = runner.invoke(app, ["export", "--out", str(tmp_path / "d.onnx"), "--no-verify"])
    assert res.exit_code == 0, res.output
    from slipsense.models.onnx import onnx_metadata

    for part in ("model", "frame", "step"):
        meta = onnx_metadata(tmp_path / ("d.onnx" if part == "model" else f"d.{part}.onnx"))
        assert meta["part"] == part and meta["operating_point"]["threshold"] == pytest.approx(0.998)
        assert meta["model"] == "motionnet" and meta["fps"] == 25 and "promise" in meta
    res = runner.invoke(app, ["watch", str(RUN), "--jsonl", str(tmp_path / "r.jsonl"), "--quiet"])
    assert res.exit_code == 0, res.output
    watched = [json.loads(line) for line in (tmp_path / "r.jsonl").read_text().splitlines()]
    probs, alarms = _alone(tmp_path / "d.frame.onnx", tmp_path / "d.step.onnx", sorted(RUN.glob("camera_*.avi")))
    assert len(probs) == len(watched)
    assert [r["probability"] is None for r in watched] == [p is None for p in probs]
    both = [(r["probability"], p) for r, p in zip(watched, probs) if p is not None]
    assert np.allclose([a for a, _ in both], [b for _, b in both], atol=1e-5)
    assert [r["alarm"] for r in watched] == alarms and any(alarms)  # this run slips: the alarm is raised
