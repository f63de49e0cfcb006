"""MotionNet: causal, streams equal to the whole-run forward, trains on runs, detector integration."""

import numpy as np
import pytest
import torch

from slipsense.errors import ConfigError, InputError
from slipsense.measures.operating_points import choose_operating_point
from slipsense.training.grasps import GraspTrainConfig, fit_runs, frame_targets, predict_runs
from slipsense.streaming.detector import SlipDetector
from slipsense.models import build
from slipsense.recordings.runs import GraspRun


def _model(**kw):
    torch.manual_seed(0)
    return build(
        "motionnet", image_size=(16, 20), width=4, features=8, temporal=8, lags=(1, 5, 10), dilations=(1, 2, 4), **kw
    ).eval()


def test_causal_and_stream_equals_forward():
    m = _model()
    g = torch.randint(0, 256, (1, 2, 50, 16, 20)).float() / 255
    with torch.no_grad():
        full = torch.softmax(m(g), -1)[0, :, 1].numpy()
        g2 = g.clone()
        g2[:, :, 30:] = torch.rand_like(g2[:, :, 30:])  # the future must not change the past
        assert np.allclose(torch.softmax(m(g2), -1)[0, :30, 1].numpy(), full[:30], atol=1e-6)
    st = m.stream()
    pushed = [st.push_gray((g[0, :, t] * 255).round().byte().numpy()) for t in range(50)]
    assert np.allclose(pushed, full, atol=1e-5)


def test_config_bounds_refused():
    with pytest.raises(ConfigError):
        build("motionnet", width=10**9)
    with pytest.raises(ConfigError):
        build("motionnet", lags=[0])


def _runs(n_runs=8, n=70, size=(16, 20), seed=0):
    """Made-up grasps: still noise; slip runs get a moving stripe in the 8 frames up to the moment."""
    rng = np.random.default_rng(seed)
    runs = []
    for i in range(n_runs):
        gray = rng.integers(100, 104, (2, n, *size), dtype=np.uint8)
        slipped = i % 2 == 0
        m = 50 if slipped else None
        if slipped:
            for t in range(m - 8, m + 1):
                gray[:, t, :, (t * 2) % size[1]] = 250
        runs.append(
            GraspRun(f"obj{i % 4}", i, slipped, m, gray, np.zeros((2, n), np.float32), ("camera_0", "camera_2"))
        )
    return runs


#: a small model and training for made-up runs
TINY = dict(
    model_config={"image_size": [16, 20], "width": 4, "features": 8, "temporal": 8},
    lr=1e-2,
    batch_size=8,
    chunk=16,
    negatives=2,
    hard_negatives=1,
    inner_folds=0,
)


def test_frame_targets():
    y = frame_targets(100, 60, onset=5, horizon=20)
    assert (y[55:61] == 1).all() and (y[40:55] == -1).all() and (y[:40] == 0).all() and (y[61:] == -1).all()
    assert (frame_targets(10, None, 5, 20) == 0).all()


def test_fit_learns_a_moving_stripe():
    runs = _runs()
    cfg = GraspTrainConfig(**TINY, epochs=25)
    model, hist = fit_runs(runs, cfg, progress=False)
    assert len(hist) == 25 and hist[-1]["train_loss"] < hist[0]["train_loss"]
    probs = predict_runs(model, runs, cfg.startup)
    assert np.isnan(probs[0][:10]).all()
    slip_peak = np.mean([np.nanmax(p[40:51]) for p, r in zip(probs, runs) if r.slipped])
    calm_peak = np.mean([np.nanmax(p[:40]) for p, r in zip(probs, runs)])
    assert slip_peak > calm_peak
    op = choose_operating_point(
        probs, [r.moment_of_slip for r in runs], horizon=cfg.horizon, startup=cfg.startup, fps=25.0
    )
    assert 0 < op["threshold"] < 1 and op["debounce"] >= 1


def test_fit_refuses_runs_without_slip():
    runs = [r for r in _runs() if not r.slipped]
    with pytest.raises(ConfigError):
        fit_runs(runs, GraspTrainConfig(model_config={"image_size": [16, 20]}, epochs=1), progress=False)


def test_detector_pushes_like_replay_and_guards_input(tmp_path):
    from slipsense.checkpoint import save_checkpoint

    m = _model()
    path = save_checkpoint(
        tmp_path / "m.safetensors", m, {"operating_point": {"threshold": 0.3, "debounce": 2, "startup": 10}}
    )
    det = SlipDetector.from_checkpoint(path, sensors=2)
    assert det.threshold == 0.3 and det.debounce == 2
    rng = np.random.default_rng(1)
    vids = [rng.integers(0, 255, (30, 48, 64, 3), dtype=np.uint8) for _ in range(2)]
    trace = det.replay(*vids)
    readings = [det.push(vids[0][i], vids[1][i]) for i in range(30)]
    assert all(r.probability is None and not r.alarm for r in readings[:10])
    assert np.allclose([r.probability for r in readings[10:]], trace.probability[10:], atol=1e-5)
    assert [r.alarm for r in readings] == trace.alarm.tolist()
    with pytest.raises(InputError, match="earlier frames"):
        det.push(vids[0][0][:40], vids[1][0])
    with pytest.raises(InputError, match="m.safetensors: .*2 sensor"):
        SlipDetector.from_checkpoint(path, sensors=1)


def test_checkpoint_without_threshold_warns(tmp_path):
    from slipsense.checkpoint import save_checkpoint

    path = save_checkpoint(tmp_path / "m.safetensors", _model(), {})
    with pytest.warns(UserWarning, match="no alarm threshold"):
        det = SlipDetector.from_checkpoint(path, sensors=2)
    assert det.threshold == 0.5


def test_nan_probability_raises_the_alarm():
    det = SlipDetector(_model(), sensors=2, threshold=0.5)
    det._stream.push_gray = lambda gray: float("nan")
    frame = np.zeros((16, 20, 3), np.uint8)
    readings = [det.push(frame, frame) for _ in range(12)]
    assert readings[-1].alarm


def test_motion_energy_baseline_streams_and_trains():
    torch.manual_seed(0)
    m = build("motion-energy", image_size=(16, 20), lags=(1, 5, 10)).eval()
    assert sum(p.numel() for p in m.parameters()) == 8
    g = torch.randint(0, 256, (1, 2, 30, 16, 20)).float() / 255
    with torch.no_grad():
        full = torch.softmax(m(g), -1)[0, :, 1].numpy()
    st = m.stream()
    assert np.allclose([st.push_gray((g[0, :, t] * 255).round().byte().numpy()) for t in range(30)], full, atol=1e-5)
    cfg = GraspTrainConfig(
        **{
            **TINY,
            "model": "motion-energy",
            "model_config": {"image_size": [16, 20], "lags": [1, 5, 10]},
            "epochs": 30,
            "lr": 5e-2,
            "hard_negatives": 0,
        }
    )
    model, hist = fit_runs(_runs(), cfg, progress=False)
    assert hist[-1]["train_loss"] < hist[0]["train_loss"]


def test_build_refuses_huge_settings_before_allocating():
    with pytest.raises(ConfigError, match="beyond"):
        build("vivit", dim=10**9)
    with pytest.raises(ConfigError, match="parameters is beyond"):
        build("vivit", dim=50_000, mlp_dim=50_000)


class _Killed(Exception):
    pass


def test_grasp_training_resumed_after_a_kill_equals_an_uninterrupted_one(tmp_path):
    """The state written after each epoch (weights, optimizer, schedule, both generators, mined hard
    negatives) makes a resumed training bit-identical, hard-negative mining and dropout included."""
    cfg = GraspTrainConfig(
        model_config={"image_size": [16, 20], "width": 4, "features": 8, "temporal": 8, "lags": [1, 5, 10]},
        epochs=5,
        batch_size=4,
        chunk=12,
        negatives=2,
        hard_negatives=1,
        mine_every=1,
        inner_folds=0,
    )
    runs = _runs()
    whole, hist = fit_runs(runs, cfg, progress=False)

    state = tmp_path / "job0.state"

    def kill_after_two(row):
        if row["epoch"] == 2:
            raise _Killed

    with pytest.raises(_Killed):
        fit_runs(runs, cfg, progress=False, on_epoch=kill_after_two, state_path=state)
    epochs_after = []
    resumed, hist2 = fit_runs(runs, cfg, progress=False, on_epoch=epochs_after.append, state_path=state)
    assert [r["epoch"] for r in epochs_after] == [3, 4, 5]  # only the epochs not done before
    for key, value in whole.state_dict().items():
        assert torch.equal(value, resumed.state_dict()[key]), key
    assert [r["train_loss"] for r in hist2] == [r["train_loss"] for r in hist]

    other = GraspTrainConfig(**{**cfg.to_dict(), "lr": 1e-3})
    with pytest.raises(InputError, match="another training"):
        fit_runs(runs, other, progress=False, state_path=state)


def test_anchor_lag_zero_streams_like_the_whole_run_and_trains():
    """Lag 0 compares every frame with the grasp's first: the same numbers pushed or whole, and in
    chunks of runs (training) as in the whole-run forward."""
    torch.manual_seed(0)
    m = build(
        "motionnet", image_size=(16, 20), width=4, features=8, temporal=8, lags=(0, 1, 5), dilations=(1, 2)
    ).eval()
    g = torch.randint(0, 256, (1, 2, 40, 16, 20)).float() / 255
    with torch.no_grad():
        full = torch.softmax(m(g), -1)[0, :, 1].numpy()
        chunks = torch.softmax(m.chunk_logits([(g[0], [39, 25])], 6), -1)[:, :, 1].numpy()
    st = m.stream()
    pushed = [st.push_gray((g[0, :, t] * 255).round().byte().numpy()) for t in range(40)]
    assert np.allclose(pushed, full, atol=1e-5)
    assert np.allclose(chunks[0], full[34:40], atol=1e-5) and np.allclose(chunks[1], full[20:26], atol=1e-5)
    with pytest.raises(ConfigError):
        build("motionnet", lags=(0,))


def test_a_refused_push_leaves_the_stream_as_it_was():
    """A push refused for sensor 1 must not fix sensor 0's frame size (nor count a frame)."""
    det = SlipDetector(_model(), sensors=2, threshold=0.5)
    ok, other = np.zeros((16, 20, 3), np.uint8), np.zeros((32, 40, 3), np.uint8)
    with pytest.raises(InputError):
        det.push(other, "not a frame")
    readings = [det.push(ok, ok) for _ in range(12)]  # another size than the refused push: accepted
    assert readings[0].index == 0 and readings[-1].probability is not None


def test_fit_without_random_negatives_trains():
    """negatives=0: held runs get chunks only once hard negatives are mined."""
    cfg = GraspTrainConfig(
        model_config={"image_size": [16, 20], "width": 4, "features": 8, "temporal": 8},
        epochs=3,
        batch_size=8,
        chunk=16,
        negatives=0,
        hard_negatives=1,
        mine_every=1,
        inner_folds=0,
    )
    _, hist = fit_runs(_runs(), cfg, progress=False)
    assert len(hist) == 3 and hist[0]["other_frames"] < hist[1]["other_frames"]
    with pytest.raises(ConfigError, match="positive_weight"):
        GraspTrainConfig(positive_weight=0)


def test_the_training_benchmark_still_times_both_steps():
    """bench/bench_training.py times the shipped training step beside the step before it; it once
    called a helper that had been removed and failed at its first line of work."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parent.parent / "bench" / "bench_training.py"
    spec = importlib.util.spec_from_file_location("bench_training", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    runs, cfg = _runs(), GraspTrainConfig(**TINY)
    res = bench.grasp_throughput(runs, cfg, seconds=0.01)
    assert res["current"]["frames"] > 0 and res["reference"]["frames"] > 0 and res["ratio"] > 0
    assert {"operator", "self_percent", "calls"} <= set(bench.grasp_profile(runs, cfg)[0])


def test_training_across_rates_sees_runs_as_a_slower_camera_and_the_live_detector_would():
    """``train.slower``: a run as a camera at 0.6 of the recorded rate takes it, resampled to the
    model's clock, is exactly what the live detector builds from such a camera's stamped frames."""
    from slipsense.streaming.clock import ModelClock
    from slipsense.training.grasps import as_slower_camera

    gray = np.random.default_rng(1).integers(0, 256, (2, 40, 6, 8), dtype=np.uint8)
    slow = as_slower_camera(gray, 0.6)
    clock, live = ModelClock(25.0), []
    for k in range(int(39 * 0.6) + 1):  # the slower camera: 15 frames/s, the recorded frame at each moment
        live += clock.ticks(k / 15.0, [gray[s, int(np.floor(k / 0.6 + 1e-9))] for s in range(2)])
    assert slow.shape[1] == len(live) <= 40
    assert all(np.array_equal(slow[:, t], np.stack(f)) for t, f in enumerate(live))
    runs = _runs()
    model, hist = fit_runs(runs, GraspTrainConfig(**TINY, epochs=2, slower=[0.6, 0.5]), progress=False)
    assert len(hist) == 2 and np.isfinite(hist[-1]["train_loss"])
    with pytest.raises(ConfigError, match="slower"):
        GraspTrainConfig(slower=[1.5])
    model, hist = fit_runs(runs, GraspTrainConfig(**TINY, epochs=1, gain=[0.7, 1.3]), progress=False)
    assert np.isfinite(hist[-1]["train_loss"])
    for bad in ([1.3, 0.7], [0.7], [0, 1]):
        with pytest.raises(ConfigError, match="gain"):
            GraspTrainConfig(gain=bad)


def test_levelled_frames_stream_like_the_whole_run_and_take_out_exposure():
    """``level``: each frame scaled to a mean grey of 0.5 -- pushed, whole and in training chunks alike,
    and a unit with 0.7x the exposure gives (up to uint8 rounding) the same probabilities."""
    m = _model(level=True)
    g = torch.randint(60, 200, (1, 2, 40, 16, 20)).float() / 255
    with torch.no_grad():
        full = torch.softmax(m(g), -1)[0, :, 1].numpy()
        chunks = torch.softmax(m.chunk_logits([(g[0], [39])], 6), -1)[0, :, 1].numpy()
        dim = torch.softmax(m(g * 0.7), -1)[0, :, 1].numpy()
        plain = torch.softmax(_model()(g * 0.7), -1)[0, :, 1].numpy()
    st = m.stream()
    pushed = [st.push_gray((g[0, :, t] * 255).round().byte().numpy()) for t in range(40)]
    assert np.allclose(pushed, full, atol=1e-5) and np.allclose(chunks, full[34:], atol=1e-5)
    assert np.allclose(dim, full, atol=1e-5)
    assert not np.allclose(plain, torch.softmax(_model()(g), -1)[0, :, 1].detach().numpy(), atol=1e-3)
    with pytest.raises(ConfigError, match="level"):
        build("motionnet", level="yes")
    black = m.stream()
    assert np.isfinite(black.push_gray(np.zeros((2, 16, 20), np.uint8)))
