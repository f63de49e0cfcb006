"""The frame cache: a video is decoded once across labelling and loading whole runs; what it holds
equals what decoding gives (a damaged entry: tests/test_verified_cache.py)."""

from __future__ import annotations


import numpy as np
import pytest

from conftest import REAL_RUN, needs_data

from slipsense.errors import ConfigError, InputError
from slipsense.recordings import video as video_mod
from slipsense.recordings.contact import contact_signal, signal_of_blocks, video_blocks
from slipsense.recordings.folders import find_recordings
from slipsense.recordings.frame_cache import video_products
from slipsense.recordings.labels import label_recordings
from slipsense.recordings.runs import load_runs
from slipsense.recordings.video import gray_frames


@pytest.fixture
def decodes(monkeypatch):
    """Counts full decodes of videos."""
    calls: list[str] = []
    real = video_mod.read_video

    def counting(path, *a, **kw):
        calls.append(str(path))
        return real(path, *a, **kw)

    monkeypatch.setattr(video_mod, "read_video", counting)
    return calls


def test_products_equal_decoding(grasp_recordings, cache):
    path = grasp_recordings / "obj0" / "exp_num_1" / "camera_0.avi"
    video = video_mod.read_video(path, expected_size=None)
    got = video_products(path, ["blocks", "gray:16x20", "contact"])
    np.testing.assert_array_equal(got["contact"], contact_signal(video))
    np.testing.assert_array_equal(got["blocks"], video_blocks(video))
    np.testing.assert_array_equal(got["gray:16x20"], gray_frames(video, (16, 20)))
    np.testing.assert_array_equal(signal_of_blocks(got["blocks"]), contact_signal(video))
    again = video_products(path, ["gray:16x20"])["gray:16x20"]  # from the cache, memory-mapped
    assert isinstance(again, np.memmap) and np.array_equal(again, got["gray:16x20"])


def test_label_then_load_runs_decodes_each_video_once(grasp_recordings, cache, decodes):
    recs = find_recordings(grasp_recordings)
    labels = label_recordings(recs, progress=False, workers=1)  # here, where the decodes are counted
    assert sorted(decodes) == sorted(str(r.path) for r in recs)
    decodes.clear()
    runs = load_runs(recs, labels, (30, 40), progress=False)  # the size labelling caches too
    assert decodes == [] and len(runs) == 8 and runs[0].gray.shape[2:] == (30, 40)
    load_runs(recs, labels, (12, 16), progress=False)  # another size: one decode per video, then none
    assert len(decodes) == len(recs)
    load_runs(recs, labels, (12, 16), progress=False)
    assert len(decodes) == len(recs)


def test_bad_video_names_the_file(tmp_path, cache):
    bad = tmp_path / "camera_0.avi"
    bad.write_bytes(b"not a video")
    with pytest.raises(InputError, match="camera_0.avi"):
        video_products(bad, ["blocks"])
    with pytest.raises(InputError, match="missing.avi"):
        video_products(tmp_path / "missing.avi", ["blocks"])


def test_replay_from_cached_grey_equals_replay_of_videos(grasp_recordings, cache):
    import torch

    from slipsense.streaming.detector import SlipDetector
    from slipsense.models import build

    torch.manual_seed(0)
    model = build("motionnet", image_size=(16, 20), width=4, features=8, temporal=8, lags=(1, 5), dilations=(1, 2))
    det = SlipDetector(model.eval())
    run = grasp_recordings / "obj2" / "exp_num_1"
    paths = [run / f"camera_{c}.avi" for c in (0, 2)]
    videos = [video_mod.read_video(p, expected_size=None) for p in paths]
    gray = np.stack([video_products(p, ["gray:16x20"])["gray:16x20"] for p in paths])
    np.testing.assert_array_equal(det.replay_gray(gray).probability, det.replay(*videos).probability)
    with pytest.raises(InputError, match="replay_gray takes uint8"):
        det.replay_gray(gray[:, :, :8])


@needs_data
def test_marker_model_replays_a_real_run_from_its_tracked_markers(cache, one_thread):
    """A marker model is judged per grasp like the video models: each camera's markers are tracked
    (once, cached) and the clouds its real training windows are cut from are replayed."""
    import torch

    from slipsense.evaluation.replay import replay_recordings
    from slipsense.models import build
    from slipsense.recordings.labels import label_runs
    from slipsense.recordings.recording_set import Recordings
    from slipsense.recordings.markers import marker_sequences, track_recording
    from slipsense.streaming.detector import SlipDetector

    torch.manual_seed(0)
    model = build("temnet", frames=6, markers=40, d_model=8, heads=2, blocks=1, ff_dim=8, head_hidden=0)
    det = SlipDetector(model.eval(), sensors=2, info={"data": {"clip_spec": {"marker_layout": "40"}}})
    assert det.cache_product == "markers:40"
    held = REAL_RUN.parent / "exp_num_4"  # a grasp that held (REAL_RUN's slip has no moment)
    data = Recordings.open(REAL_RUN.parent.parent)
    recs = data.only([r for r in data.listed if r.path.parent == held])
    labels = label_runs(recs.listed, progress=False)
    (trace,) = replay_recordings(det, recs, labels, progress=False)
    assert not trace.slipped and trace.cameras == ("camera_0", "camera_2")
    clouds = [marker_sequences(track_recording(held / f"{c}.avi"), 40, normalise=False) for c in trace.cameras]
    assert clouds[0].shape == (trace.n_frames, 40, 3)
    expected = det.replay(*clouds).probability
    assert np.isfinite(expected[5:]).all() and np.isnan(expected[:5]).all()
    np.testing.assert_allclose(trace.probability, expected, rtol=0, atol=1e-6)
    # every marker on a 7 x 9 grid, as the experiment's real row trains on it
    from slipsense.recordings.markers import grid_sequences

    on_grid = build("temnet", frames=6, markers=63, d_model=8, heads=2, blocks=1, ff_dim=8, head_hidden=0)
    det = SlipDetector(on_grid.eval(), sensors=2, info={"data": {"clip_spec": {"marker_layout": "7x9"}}})
    assert det.cache_product == "markers:7x9"
    (trace,) = replay_recordings(det, recs, labels, progress=False)
    clouds = [grid_sequences(track_recording(held / f"{c}.avi"), (7, 9)) for c in trace.cameras]
    np.testing.assert_allclose(trace.probability, det.replay(*clouds).probability, rtol=0, atol=1e-6)
    with pytest.raises(ConfigError, match="marker layout '7x8' holds 56 markers"):
        SlipDetector(on_grid.eval(), info={"data": {"clip_spec": {"marker_layout": "7x8"}}})
    with pytest.raises(ValueError, match="markers:M"):
        video_products(REAL_RUN / "camera_0.avi", ["markers:0"])
