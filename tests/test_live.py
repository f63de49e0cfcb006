"""Live slip detection: streaming detector, replay, watch, early warning and ONNX export."""

from __future__ import annotations

import csv
import importlib.util
import json
import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from conftest import onnx_output
from slipsense.checkpoint import save_checkpoint
from slipsense.cli import app
from studies.__main__ import app as studies_app
from slipsense.paths import gelsight_recordings
from slipsense.errors import ConfigError, InputError
from slipsense.evaluation.replay import RunTrace
from studies.grasp.early_warning import EARLY_WARNING_COLUMNS, early_warning_table
from slipsense.models.streams import slip_probability
from slipsense.streaming.detector import SlipDetector
from slipsense.models import build

VIVIT_SMALL = dict(image_size=(48, 64), patch_size=(16, 16), frames=5, dim=8, heads=2, dim_head=16, mlp_dim=8)
STNET_SMALL = dict(frames=4, markers=20, d_model=32, heads=4, blocks=2, ff_dim=64, codec_channels=4)
RESNET_TINY = dict(width=8, layers=(1, 1, 1, 1), frames=4)
REAL_RUN = gelsight_recordings() / "avocado_real" / "exp_num_1"


@pytest.fixture(autouse=True)
def _one_thread(one_thread):
    """Every test here on one torch thread (tests/conftest.py)."""


def _model(name: str, seed: int = 0, **config):
    torch.manual_seed(seed)
    model = build(name, **config).eval()
    with torch.no_grad():  # move LayerNorm weights etc. off their initial values
        g = torch.Generator().manual_seed(seed + 1)
        for p in model.parameters():
            p.add_(torch.randn(p.shape, generator=g) * 0.05)
    return model


@pytest.fixture(scope="module")
def vivit():
    return _model("vivit", **VIVIT_SMALL)


@pytest.fixture(scope="module")
def vivit_ckpt(tmp_path_factory, vivit):
    return save_checkpoint(tmp_path_factory.mktemp("ck") / "vivit.safetensors", vivit, {})


def _frames(n: int, size=(48, 64), seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (n, *size, 3), dtype=np.uint8)


def _full_forward(model, window: np.ndarray) -> float:
    """P(slip) of one window by the model's ordinary forward: uint8 (T, H, W, 3) or float (T, M, 3)."""
    if window.dtype == np.uint8:
        x = torch.from_numpy(np.moveaxis(window, -1, 1).astype(np.float32) / 255.0)
    else:
        x = torch.from_numpy(window.astype(np.float32))
    with torch.no_grad():
        return float(slip_probability(model(x[None]).numpy())[0])


# ---------------------------------------------------------------------------------------------
# streaming detector
# ---------------------------------------------------------------------------------------------


def test_streaming_vivit_equals_full_forward(vivit):
    det = SlipDetector(vivit, sensors=2)
    a, b = _frames(11, seed=1), _frames(11, seed=2)
    for i in range(11):
        r = det.push(a[i], b[i])
        if i < 4:
            continue
        for s, video in enumerate((a, b)):
            assert abs(r.per_sensor[s] - _full_forward(vivit, video[i - 4 : i + 1])) < 1e-5


def test_factorised_vivit_streams_one_spatial_encoding_per_frame():
    """positions="factorised": a frame's spatial token is the same in every slot, so the frame part
    runs the spatial transformer once per frame, and streaming still equals the full forward."""
    model = _model("vivit", positions="factorised", **VIVIT_SMALL)
    assert model.pos_embedding.shape == (1, 1, 12, 8) and model.temporal_pos_embedding.shape == (1, 5, 8)
    frame_part, _ = model.streaming_parts()
    calls = []
    hook = model.spatial_transformer.register_forward_hook(lambda m, args, out: calls.append(args[0].shape[0]))
    x = torch.rand(3, 3, 48, 64)
    with torch.no_grad():
        tokens = frame_part(x)
    hook.remove()
    assert calls == [3] and tokens.shape == (3, 5, 8)  # 3 sequences, not 3 x 5
    assert torch.equal(tokens[:, 0], tokens[:, 4])
    det = SlipDetector(model)
    video = _frames(9, seed=4)
    for i in range(9):
        r = det.push(video[i])
        if i >= 4:
            assert abs(r.probability - _full_forward(model, video[i - 4 : i + 1])) < 1e-5
    assert np.allclose(
        det.replay(video).probability[4:], [_full_forward(model, video[i - 4 : i + 1]) for i in range(4, 9)], atol=1e-5
    )
    # slot order still matters: the temporal embedding tells the frames apart
    assert abs(_full_forward(model, video[:5]) - _full_forward(model, video[:5][::-1].copy())) > 1e-6
    with pytest.raises(ConfigError, match="positions"):
        build("vivit", positions="tubelet")


def test_streaming_resizes_frames(vivit):
    det = SlipDetector(vivit)
    big = _frames(6, size=(96, 128), seed=3)
    small = np.stack([cv2.resize(f, (64, 48), interpolation=cv2.INTER_AREA) for f in big])
    readings = [det.push(f) for f in big]
    assert abs(readings[-1].probability - _full_forward(vivit, small[1:6])) < 1e-5


def test_window_fill_and_reset(vivit):
    det = SlipDetector(vivit, threshold=0.0)
    frames = _frames(7)
    readings = [det.push(f) for f in frames]
    assert [r.index for r in readings] == list(range(7))
    assert all(r.probability is None and r.per_sensor is None and not r.alarm for r in readings[:4])
    assert all(isinstance(r.probability, float) and r.alarm for r in readings[4:])  # threshold 0: always
    det.reset()
    r = det.push(frames[0])
    assert (r.index, r.probability, r.per_sensor, r.alarm) == (0, None, None, False)


def test_two_sensor_combine(vivit):
    a, b = _frames(5, seed=4), _frames(5, seed=5)
    for combine, fn in (("max", max), ("mean", lambda x, y: (x + y) / 2)):
        det = SlipDetector(vivit, sensors=2, combine=combine)
        r = [det.push(a[i], b[i]) for i in range(5)][-1]
        assert r.probability == pytest.approx(fn(*r.per_sensor), abs=1e-12)
        # each sensor alone gives the same per-sensor probability: the batch does not mix sensors
        single = SlipDetector(vivit)
        assert [single.push(f) for f in b][-1].probability == pytest.approx(r.per_sensor[1], abs=1e-6)
    # the alarm follows the combined probability: max reaches the larger sensor's value, mean does not
    top = max(r.per_sensor)
    assert min(r.per_sensor) < top
    det = SlipDetector(vivit, sensors=2, combine="max", threshold=top)
    assert [det.push(a[i], b[i]) for i in range(5)][-1].alarm
    det = SlipDetector(vivit, sensors=2, combine="mean", threshold=top)
    assert not [det.push(a[i], b[i]) for i in range(5)][-1].alarm


def test_stnet_streaming_and_replay_equal_full_forward():
    model = _model("stnet", **STNET_SMALL)
    det = SlipDetector(model, sensors=2)
    rng = np.random.default_rng(0)
    clouds = [rng.normal(size=(9, 20, 3)).astype(np.float32) for _ in range(2)]
    readings = [det.push(clouds[0][i], clouds[1][i]) for i in range(9)]
    trace = det.replay(*clouds)
    for i in range(3, 9):
        for s in range(2):
            ref = _full_forward(model, clouds[s][i - 3 : i + 1])
            assert abs(readings[i].per_sensor[s] - ref) < 1e-5
            assert abs(trace.per_sensor[i, s] - ref) < 1e-5
    assert np.isnan(trace.probability[:3]).all()
    sal = det.heatmap(0)
    assert sal.shape == (20,) and sal.max() == pytest.approx(1.0)
    clouds[1][6, 3, 2] = np.inf
    with pytest.raises(InputError, match="frame 6, sensor 1: marker 3"):
        det.replay(*clouds)


@pytest.mark.parametrize("name", ["vivit", "resnet3d50"])
def test_replay_equals_streaming(vivit, name):
    """The batched replay used by early-warning gives the numbers pushing frame by frame gives."""
    model = vivit if name == "vivit" else _model("resnet3d50", **RESNET_TINY)
    det = SlipDetector(model, sensors=2, info={"data": {"clip_spec": {"size": [48, 64]}}})
    a, b = _frames(13, seed=6), _frames(13, seed=7)
    pushed = [det.push(a[i], b[i]) for i in range(13)]
    trace = det.replay(a, b)
    t = det.frames
    assert np.isnan(trace.probability[: t - 1]).all()
    got = np.array([r.per_sensor for r in pushed[t - 1 :]])
    assert np.abs(trace.per_sensor[t - 1 :] - got).max() < 1e-6
    assert [bool(v) for v in trace.alarm] == [r.alarm for r in pushed]


def test_vivit_heatmap(vivit):
    det = SlipDetector(vivit)
    assert det.heatmap() is None
    for f in _frames(5):
        det.push(f)
    heat = det.heatmap()
    assert heat.shape == (3, 4) and heat.sum() == pytest.approx(1.0, abs=1e-5)


def test_bad_frames_raise_input_error(vivit):
    det = SlipDetector(vivit, sensors=2)
    good = _frames(1)[0]
    with pytest.raises(InputError, match="sensor 1.*shape"):
        det.push(good, np.zeros((48, 64, 2), np.uint8))  # 2 channels: no resize can fix it
    with pytest.raises(InputError, match="uint8"):
        det.push(good, good.astype(np.float32))
    with pytest.raises(InputError, match="numpy"):
        det.push(good, "frame.png")
    with pytest.raises(InputError, match="2 frame"):
        det.push(good)
    assert not det._stream._cache  # nothing was pushed by the failed calls
    assert det.push(good, good).index == 0

    stnet = SlipDetector(_model("stnet", **STNET_SMALL))
    cloud = np.zeros((20, 3), np.float32)
    cloud[7, 1] = np.nan
    with pytest.raises(InputError, match="marker 7.*non-finite"):
        stnet.push(cloud)
    with pytest.raises(InputError, match=r"\(20, 3\)"):
        stnet.push(np.zeros((19, 3), np.float32))
    with pytest.raises(InputError, match="dtype"):
        stnet.push(np.zeros((20, 3), bool))
    message = str(pytest.raises(InputError, stnet.push, cloud).value)
    assert "\n" not in message


def test_settings_are_checked(vivit):
    for kwargs in (
        dict(threshold=1.5),
        dict(sensors=0),
        dict(combine="min"),
        dict(backend="tensorrt"),
        dict(dtype="int4"),
        dict(dtype="int8"),
    ):  # int8 needs the onnx backend
        with pytest.raises(ConfigError):
            SlipDetector(vivit, **kwargs)


# ---------------------------------------------------------------------------------------------
# early-warning metrics
# ---------------------------------------------------------------------------------------------


def _run(prob, slipped, moment=None):
    prob = np.asarray(prob, float)
    return RunTrace("o", 1, slipped, moment, len(prob), prob, fps=25.0)


def test_early_warning_table_per_grasp():
    nan = math.nan
    pre = [nan] * 10
    slip_a = _run(pre + [0.2, 0.6, 0.9, 0.9, 0.2], True, moment=13)  # 0.5: first alarm 11 -> lead 2
    slip_b = _run(pre + [0.9] + [0.1] * 60 + [0.95], True, moment=70)  # 0.5: alarm at 10, 60 frames early
    calm = _run(pre + [0.1, 0.1, 0.7, 0.1], False)
    rows = early_warning_table([slip_a, slip_b, calm], [0.5, 0.8], horizon=50, fps=25.0)
    r5, r8 = rows
    assert (r5["slip_runs"], r5["warned"], r5["premature"], r5["missed"]) == (2, 1, 1, 0)
    assert r5["median_lead_frames"] == 2 and r5["median_lead_ms"] == 80.0
    assert r5["false_positive_grasps"] == 1 and r8["false_positive_grasps"] == 0
    assert (r8["warned"], r8["premature"]) == (1, 1)  # slip_a at 12 (lead 1); slip_b still premature
    assert list(r5) == list(EARLY_WARNING_COLUMNS)
    empty = early_warning_table([calm], [0.5])[0]
    assert math.isnan(empty["warned_rate"]) and math.isnan(empty["median_lead_ms"])


def test_always_on_detector_scores_badly_in_early_warning():
    runs = [_run([np.nan] * 10 + [0.99] * 90, True, moment=80), _run([np.nan] * 10 + [0.99] * 90, False)]
    row = early_warning_table(runs, [0.5])[0]
    assert row["warned"] == 0 and row["premature"] == 1 and row["false_positive_rate"] == 1.0 and row["score"] == -1


# ---------------------------------------------------------------------------------------------
# watch and early-warning commands on synthetic recordings
# ---------------------------------------------------------------------------------------------


def _write_video(path: Path, n: int = 40, contact=(12, 30), size=(48, 64), seed: int = 0) -> Path:
    """A small XVID AVI: grey gel at rest, a bright square pressed on during ``contact`` (inclusive)."""
    rng = np.random.default_rng(seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"XVID"), 25, (size[1], size[0]))
    assert writer.isOpened()
    for t in range(n):
        f = np.full((*size, 3), 110, np.uint8) + rng.integers(0, 4, (*size, 3), dtype=np.uint8)
        if contact[0] <= t <= contact[1]:
            f[12:36, 16:48] = 200
        writer.write(f)
    writer.release()
    return path


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """obj/exp_num_1 slips (contact 20..50, lost after), obj/exp_num_2 does not (contact 20..60)."""
    root = tmp_path_factory.mktemp("recordings")
    for exp, end in ((1, 50), (2, 60)):
        for cam in (0, 1):
            _write_video(
                root / "obj" / f"exp_num_{exp}" / f"camera_{cam}.avi", n=70, contact=(20, end), seed=10 * exp + cam
            )
    (root / "obj" / "exp_num_1" / "slip.txt").write_text("")
    return root


def test_watch_writes_gif(tmp_path, vivit_ckpt):
    video = _write_video(tmp_path / "clip.avi", n=12)
    out = tmp_path / "annotated.gif"
    res = CliRunner().invoke(
        app, ["watch", str(video), "--checkpoint", str(vivit_ckpt), "--out", str(out), "--threshold", "0.3"]
    )
    assert res.exit_code == 0, res.output
    lines = [l for l in res.output.splitlines() if l.startswith("frame")]
    assert len(lines) == 12 and "filling window" in lines[0] and "p=0." in lines[4]
    from PIL import Image

    with Image.open(out) as gif:
        assert gif.n_frames == 12
        assert gif.size[0] >= 64


def test_watch_experiment_folder_two_sensors_mp4(tmp_path, vivit_ckpt, recordings):
    out = tmp_path / "run.mp4"
    res = CliRunner().invoke(
        app,
        [
            "watch",
            str(recordings / "obj" / "exp_num_1"),
            "--checkpoint",
            str(vivit_ckpt),
            "--out",
            str(out),
            "--max-frames",
            "8",
            "--combine",
            "mean",
        ],
    )
    assert res.exit_code == 0, res.output
    assert res.output.count("[") == 4  # frames 4..7 show two per-sensor probabilities
    assert out.stat().st_size > 0


def test_watch_marker_stream_gif(tmp_path):
    """A marker model streams a (sensors, T, M, 3) .npy; the GIF shows the marker saliency."""
    ckpt = save_checkpoint(tmp_path / "stnet.safetensors", _model("stnet", **STNET_SMALL), {})
    stream = tmp_path / "markers.npy"
    np.save(stream, np.random.default_rng(0).normal(size=(2, 7, 20, 3)).astype(np.float32))
    out = tmp_path / "markers.gif"
    res = CliRunner().invoke(app, ["watch", str(stream), "--checkpoint", str(ckpt), "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert res.output.count("[") == 4 and "7 frames" in res.output
    from PIL import Image

    with Image.open(out) as gif:
        assert gif.n_frames == 7


def test_watch_bad_source_is_one_line(tmp_path, vivit_ckpt):
    res = CliRunner().invoke(app, ["watch", str(tmp_path / "missing.avi"), "--checkpoint", str(vivit_ckpt)])
    assert res.exit_code == 2
    assert res.output.strip().count("\n") == 0 and "missing.avi" in res.output
    res = CliRunner().invoke(app, ["watch", "0", "--checkpoint", str(vivit_ckpt), "--out", str(tmp_path / "x.png")])
    assert res.exit_code == 2 and ".gif" in res.output


def test_early_warning_on_synthetic_recordings(tmp_path, vivit_ckpt, recordings, monkeypatch):
    monkeypatch.setenv("SLIPSENSE_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "ew"
    res = CliRunner().invoke(
        studies_app,
        [
            "grasp",
            "early-warning",
            "--checkpoint",
            str(vivit_ckpt),
            "--recordings",
            str(recordings),
            "--out",
            str(out),
            "--thresholds",
            "0.2,0.5,0.8",
            "--no-progress",
        ],
    )
    assert res.exit_code == 0, res.output
    with open(out / "early_warning.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == EARLY_WARNING_COLUMNS
    assert [float(r["threshold"]) for r in rows] == [0.2, 0.5, 0.8]
    assert all(r["slip_runs"] == "1" and r["held_runs"] == "1" for r in rows)
    doc = json.loads((out / "early_warning.json").read_text())
    assert [r["threshold"] for r in doc["table"]] == [0.2, 0.5, 0.8]
    slip_run = next(r for r in doc["runs"] if r["slipped"])
    assert slip_run["moment_of_slip"] == 50 and set(slip_run["outcome"]["0.5"].split()) <= {
        "warned",
        "premature",
        "missed",
    }
    assert len(slip_run["probability"]) == 70 and slip_run["probability"][3] is None
    for name in ("early_warning.png",):
        assert (out / name).read_bytes()[:4] == b"\x89PNG"
    # the replay inside early-warning equals streaming the run frame by frame
    from slipsense.recordings.video import read_video

    det = SlipDetector.from_checkpoint(vivit_ckpt, sensors=2)
    cams = [read_video(recordings / "obj" / "exp_num_1" / f"camera_{c}.avi", expected_size=None) for c in (0, 1)]
    pushed = [det.push(cams[0][i], cams[1][i]).probability for i in range(70)]
    assert (
        np.abs(np.array(pushed[4:]) - np.array(slip_run["probability"][4:], float)).max() < 1e-4
    )  # JSON rounds to 1e-5


# ---------------------------------------------------------------------------------------------
# ONNX export and the ONNX Runtime backend
# ---------------------------------------------------------------------------------------------

needs_ort = pytest.mark.skipif(importlib.util.find_spec("onnxruntime") is None, reason="onnxruntime not installed")
needs_data = pytest.mark.skipif(not (REAL_RUN / "camera_0.avi").is_file(), reason="shared GelSight data not present")


@pytest.fixture(scope="module")
def real_clips():
    """Two 12-frame clips (240 x 320) from a shared recording, decoded with read_video."""
    from slipsense.recordings.video import read_video

    video = read_video(REAL_RUN / "camera_0.avi")
    return video[100:112], video[200:212]


def _as_input(clip: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.moveaxis(clip, -1, 1).astype(np.float32) / 255.0)


@needs_ort
@needs_data
def test_onnx_vivit_matches_torch_on_real_clips(tmp_path, real_clips):
    from slipsense.streaming.export import export_onnx

    model = _model("vivit")  # the paper's configuration: 240 x 320, 40 x 40 patches, 5 frames
    res = export_onnx(model, tmp_path / "vivit.onnx", verify=False)  # verified here, on real frames
    assert set(res.paths) == {"model", "frame", "window"}
    x = torch.stack([_as_input(c[:5]) for c in real_clips])  # (2, 5, 3, 240, 320)
    with torch.no_grad():
        ref = model(x).numpy()
    assert np.abs(onnx_output(res.paths["model"], x) - ref).max() <= 1e-4
    tokens = onnx_output(res.paths["frame"], x.flatten(0, 1)).reshape(2, 5, 5, -1)
    window = tokens[:, np.arange(5), np.arange(5)]  # frame k at slot k
    assert np.abs(onnx_output(res.paths["window"], window) - ref).max() <= 1e-4

    # the ONNX Runtime backend of the detector (given these parts) streams the same probabilities as PyTorch
    parts = tmp_path / "parts"
    parts.mkdir()
    for key in ("frame", "window"):
        shutil.copy(res.paths[key], parts / f"{key}.onnx")
    dets = {
        "torch": SlipDetector(model, sensors=2),
        "onnx": SlipDetector(model, sensors=2, backend="onnx", onnx_dir=parts),
    }
    a, b = real_clips
    probs = {k: [d.push(a[i], b[i]).per_sensor for i in range(8)][4:] for k, d in dets.items()}
    assert np.abs(np.array(probs["torch"]) - np.array(probs["onnx"])).max() <= 1e-4
    dets["onnx"].close()


@needs_ort
@needs_data
def test_onnx_stnet_matches_torch_on_real_markers(tmp_path, real_clips):
    from slipsense.streaming.export import export_onnx
    from slipsense.recordings.markers import marker_sequences, track_markers

    clouds = np.stack([marker_sequences(track_markers(c, source="clip"), 20) for c in real_clips])[:, :4]
    model = _model("stnet", **STNET_SMALL)
    res = export_onnx(model, tmp_path / "stnet.onnx", verify=False)
    x = torch.from_numpy(clouds)  # (2, 4, 20, 3)
    with torch.no_grad():
        ref = model(x).numpy()
    assert np.abs(onnx_output(res.paths["model"], x) - ref).max() <= 1e-4
    tokens = onnx_output(res.paths["frame"], x.flatten(0, 1)).reshape(2, 4, -1)
    assert np.abs(onnx_output(res.paths["window"], tokens) - ref).max() <= 1e-4


@needs_ort
@needs_data
def test_onnx_resnet3d_matches_torch_on_real_clips(tmp_path, real_clips):
    from slipsense.streaming.export import export_onnx

    model = _model("resnet3d50", **RESNET_TINY)
    small = [np.stack([cv2.resize(f, (160, 120), interpolation=cv2.INTER_AREA) for f in c[:4]]) for c in real_clips]
    res = export_onnx(
        model, tmp_path / "r3d.onnx", verify=False, info={"data": {"clip_spec": {"size": [120, 160], "frames": 4}}}
    )
    assert set(res.paths) == {"model"}
    x = torch.stack([_as_input(c) for c in small])
    with torch.no_grad():
        ref = model(x).numpy()
    assert np.abs(onnx_output(res.paths["model"], x) - ref).max() <= 1e-4


@needs_ort
def test_onnx_factorised_vivit_parts(tmp_path):
    from slipsense.streaming.export import export_onnx

    model = _model("vivit", positions="factorised", **VIVIT_SMALL)
    res = export_onnx(model, tmp_path / "f.onnx")
    assert set(res.max_abs_diff) == {"model", "frame", "window"}
    assert max(res.max_abs_diff.values()) <= 1e-5, res.max_abs_diff
    parts = tmp_path / "parts"
    parts.mkdir()
    for key in ("frame", "window"):
        shutil.copy(res.paths[key], parts / f"{key}.onnx")
    dets = [SlipDetector(model), SlipDetector(model, backend="onnx", onnx_dir=parts)]
    video = _frames(7, seed=5)
    probs = np.array([[d.push(f).probability for f in video][4:] for d in dets])
    assert np.abs(probs[0] - probs[1]).max() <= 1e-5
    dets[1].close()


@needs_ort
def test_export_command(tmp_path, vivit_ckpt):
    out = tmp_path / "m.onnx"
    res = CliRunner().invoke(app, ["export", "--checkpoint", str(vivit_ckpt), "--out", str(out), "--batch", "1"])
    assert res.exit_code == 0, res.output
    assert out.is_file() and (tmp_path / "m.frame.onnx").is_file() and (tmp_path / "m.window.onnx").is_file()
    assert "max |onnx - torch|" in res.output
    from slipsense.models.onnx import onnx_session

    assert onnx_session(out).get_inputs()[0].shape == [1, 5, 3, 48, 64]


@needs_ort
def test_onnx_backend_from_checkpoint_caches_parts(tmp_path, vivit_ckpt, monkeypatch):
    monkeypatch.setenv("SLIPSENSE_CACHE", str(tmp_path / "cache"))
    det = SlipDetector.from_checkpoint(vivit_ckpt, backend="onnx")
    files = sorted(p.name for p in (tmp_path / "cache" / "onnx").rglob("*.onnx"))
    assert files == ["frame.onnx", "window.onnx"]
    ref = SlipDetector.from_checkpoint(vivit_ckpt)
    frames = _frames(6, seed=9)
    got = [det.push(f).probability for f in frames][4:]
    want = [ref.push(f).probability for f in frames][4:]
    assert np.abs(np.array(got) - np.array(want)).max() <= 1e-5


@needs_ort
def test_onnx_int8_backend_stays_close(tmp_path):
    model = _model("stnet", **STNET_SMALL)
    dets = [SlipDetector(model), SlipDetector(model, backend="onnx", dtype="int8", onnx_dir=tmp_path)]
    assert (tmp_path / "window.int8.onnx").is_file() and (tmp_path / "frame.int8.onnx").is_file()
    rng = np.random.default_rng(1)
    for _ in range(6):
        cloud = rng.normal(size=(20, 3)).astype(np.float32)
        fp32, int8 = (d.push(cloud) for d in dets)
    assert abs(fp32.probability - int8.probability) < 0.05
