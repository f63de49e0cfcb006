"""Caches are verified, never trusted: an entry whose checksum, inputs or contents do not hold is
rebuilt from its inputs with a CacheWarning (labels, clips, markers, ONNX parts)."""

from __future__ import annotations

import hashlib
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

import striped_video
from slipsense.errors import CacheWarning
from slipsense.recordings import label_cache
from slipsense.recordings import labels as L
from slipsense.recordings.clips import ClipSpec, load_or_build_clips
from slipsense.recordings.folders import find_recordings
from slipsense.recordings.types import VideoLabel

N = 40


@pytest.fixture
def run(tmp_path, monkeypatch):
    """One slip run of two 40-frame striped videos; the cache in tmp_path/cache."""
    monkeypatch.setenv("SLIPSENSE_CACHE", str(tmp_path / "cache"))
    folder = tmp_path / "rec" / "cup" / "exp_num_1"
    for cam in ("camera_0", "camera_2"):
        striped_video.write_video(folder / f"{cam}.avi", N, size=(96, 128))
    (folder / "slip.txt").write_text("")
    return find_recordings(tmp_path / "rec")


def _entry(cache: Path) -> tuple[Path, Path]:
    (data,) = (cache / "labels").glob("*.json")
    return data, data.with_suffix(".check")


def _label_again(recs, expect_warning: str | None):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        labels = L.label_recordings(recs, progress=False)
    msgs = [str(w.message) for w in caught if issubclass(w.category, CacheWarning)]
    if expect_warning is None:
        assert msgs == []
    else:
        assert len(msgs) == 1 and expect_warning in msgs[0], msgs
    return labels


def _edit_rows(path: Path, **changes) -> None:
    rows = json.loads(path.read_text())
    for row in rows:
        row.update(changes)
    path.write_text(json.dumps(rows))


def test_edited_label_cache_entry_is_rebuilt(run, tmp_path):
    first = L.label_recordings(run, progress=False)
    data, check = _entry(tmp_path / "cache")
    assert _label_again(run, None) == first  # a good entry is used

    # a moment of slip past the video's end: the checksum no longer matches
    _edit_rows(data, moment_of_slip=N + 10, contact_end=N + 10)
    assert _label_again(run, "checksum mismatch") == first
    assert json.loads(data.read_text())[0]["moment_of_slip"] != N + 10  # rewritten

    # the same edit with its checksum recomputed: the labels themselves are refused
    _edit_rows(data, moment_of_slip=N + 10)
    info = json.loads(check.read_text())
    info["sha256"] = hashlib.sha256(data.read_bytes()).hexdigest()
    check.write_text(json.dumps(info))
    assert _label_again(run, "not inside") == first

    # a frame count the video does not have, checksum recomputed
    _edit_rows(data, n_frames=N + 5)
    info["sha256"] = hashlib.sha256(data.read_bytes()).hexdigest()
    check.write_text(json.dumps(info))
    assert _label_again(run, "states") == first

    # inputs of another video; a missing check file; garbage
    info = json.loads(check.read_text())
    info["inputs"][2][5] += 1  # another size
    check.write_text(json.dumps(info))
    assert _label_again(run, "other videos") == first
    check.unlink()
    assert _label_again(run, "check") == first
    data.write_text("[{]")
    assert _label_again(run, "checksum") == first
    assert _label_again(run, None) == first


def test_label_check_refuses_impossible_labels(run):
    good = L.label_run(run)
    label_cache.check_run_labels(good, run)
    bad = [
        [VideoLabel(**{**l.__dict__, "slipped": False}) for l in good],
        [VideoLabel(**{**l.__dict__, "contact_start": 30, "contact_end": 20}) for l in good],
        [VideoLabel(**{**l.__dict__, "n_frames": True}) for l in good],
        good[:1],
    ]
    for labels in bad:
        with pytest.raises(ValueError):
            label_cache.check_run_labels(labels, run)


# ---------------------------------------------------------------------------------------- clips
SPEC = ClipSpec(frames=4, size=(48, 64))


def _labels(recs):
    return {r.key: VideoLabel(r.object, r.experiment, r.camera, N, True, 30, 10, 30) for r in recs}


def _clips_again(recs, labels, folder, expect: str | None):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        clips = load_or_build_clips(recs, labels, SPEC, cache_dir=folder, progress=False)
    msgs = [str(w.message) for w in caught if issubclass(w.category, CacheWarning)]
    assert (msgs == []) if expect is None else (len(msgs) == 1 and expect in msgs[0]), msgs
    return clips


def test_clip_cache_checks_inputs_and_windows(run, tmp_path):
    labels = _labels(run)
    folder = tmp_path / "clips"
    first = load_or_build_clips(run, labels, SPEC, cache_dir=folder, progress=False)
    (npz,) = folder.glob("*.npz")
    sidecar = npz.with_suffix(".json")
    _clips_again(run, labels, folder, None)

    # sidecar of another key
    info = json.loads(sidecar.read_text())
    info["key"] = "0" * 64
    sidecar.write_text(json.dumps(info))
    again = _clips_again(run, labels, folder, "other videos")
    np.testing.assert_array_equal(again.x, first.x)

    # an entry whose windows were edited (and its checksum made to match)
    with np.load(npz) as z:
        x, y, meta = z["x"], z["y"], json.loads(str(z["meta"]))
    meta[0]["start"] += 1
    np.savez(npz, x=x, y=1 - y, meta=np.array(json.dumps(meta)))
    info = json.loads(sidecar.read_text())
    info["sha256"] = hashlib.sha256(npz.read_bytes()).hexdigest()
    sidecar.write_text(json.dumps(info))
    again = _clips_again(run, labels, folder, "windows differ")
    np.testing.assert_array_equal(again.y, first.y)
    assert again.meta == first.meta
    _clips_again(run, labels, folder, None)


# -------------------------------------------------------------------------------------- markers
def test_marker_cache_checks_checksum_inputs_and_arrays(tmp_path, monkeypatch):
    from test_markers import shifted_video, write_avi

    from slipsense.sensors import markers as M

    frames, _ = shifted_video((0.5, 0.25), n_frames=14)
    video = tmp_path / "obj" / "exp_num_1" / "camera_0.avi"
    video.parent.mkdir(parents=True)
    write_avi(video, frames)
    folder = tmp_path / "markers"
    (first,) = M.track_recordings([video], progress=False, cache_dir=folder)
    (npz,) = folder.glob("*.npz")
    sidecar = npz.with_suffix(".json")
    calls = []
    real = M.track_recording
    monkeypatch.setattr(M, "track_recording", lambda *a, **k: calls.append(a) or real(*a, **k))

    def again(expect):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            (track,) = M.track_recordings([video], progress=False, cache_dir=folder)
        msgs = [str(w.message) for w in caught if issubclass(w.category, CacheWarning)]
        assert (msgs == []) if expect is None else (len(msgs) == 1 and expect in msgs[0]), msgs
        np.testing.assert_array_equal(track.positions, first.positions)

    again(None)
    assert calls == []
    arrays = dict(np.load(npz))
    arrays["positions"] = arrays["positions"] + 1.0
    np.savez(npz, **arrays)
    again("checksum")
    # arrays that do not fit together, with a matching checksum
    arrays = dict(np.load(npz))
    arrays["reference_index"] = np.int64(99)
    np.savez(npz, **arrays)
    info = json.loads(sidecar.read_text())
    info["sha256"] = hashlib.sha256(npz.read_bytes()).hexdigest()
    sidecar.write_text(json.dumps(info))
    again("reference index")
    sidecar.unlink()
    again("No such file")
    assert len(calls) == 3
    again(None)


# ------------------------------------------------------------------------------------ ONNX parts
def test_onnx_parts_cache_is_verified(tmp_path, monkeypatch):
    pytest.importorskip("onnxruntime")
    from slipsense.models import onnx as export
    from slipsense.streaming.detector import window_geometry
    from slipsense.models import build

    model = build("temnet", frames=4, markers=5, d_model=8, heads=2, blocks=1, ff_dim=8, head_hidden=0).eval()
    geometry = window_geometry(model)
    calls = []
    real = export.export_parts
    monkeypatch.setattr(export, "export_parts", lambda *a, **k: calls.append(1) or real(*a, **k))
    folder = tmp_path / "parts"
    paths = export.cached_streaming_parts(model, folder, geometry)
    frame, window = paths["frame"], paths["window"]
    assert frame.is_file() and window.is_file() and calls == [1]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert export.cached_streaming_parts(model, folder, geometry) == paths
    assert calls == [1]  # verified and reused

    window.write_bytes(window.read_bytes()[:-10])  # damaged
    with pytest.warns(CacheWarning, match="window.onnx: checksum mismatch"):
        export.cached_streaming_parts(model, folder, geometry)
    assert calls == [1, 1]
    other = build("temnet", frames=4, markers=5, d_model=8, heads=2, blocks=1, ff_dim=16, head_hidden=0).eval()
    with pytest.warns(CacheWarning, match="another model"):
        export.cached_streaming_parts(other, folder, window_geometry(other))
    assert len(calls) == 3
    assert (
        export.check_parts(
            folder, ["frame.onnx", "window.onnx"], export._parts_key(other, window_geometry(other), "float32")
        )
        is None
    )


def test_cached_parts_of_a_model_whose_code_changed_are_exported_again(tmp_path, monkeypatch):
    """Parts exported before a change to the model's own file (its parts' inputs, its maths) are stale."""
    import inspect

    from slipsense.models import build, window_geometry
    from slipsense.models import onnx as export

    model = build("temnet", frames=4, markers=5, d_model=8, heads=2, blocks=1, ff_dim=16, head_hidden=0).eval()
    key = export._parts_key(model, window_geometry(model), "float32")
    source = tmp_path / "edited.py"
    source.write_text(Path(inspect.getfile(type(model))).read_text() + "\n# edited\n")
    monkeypatch.setattr(inspect, "getfile", lambda obj: str(source))
    assert export._parts_key(model, window_geometry(model), "float32") != key
