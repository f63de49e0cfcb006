"""Caches are verified, never trusted (slipsense.cache): an entry that is damaged, half written, made
from other inputs, or whose check file is missing or garbled is rebuilt from its inputs with a
CacheWarning, and what the next read returns is the right data, never the damaged one. One test per
cache: labels, frames, clips, markers, ONNX parts, bag cameras, tracked markers."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

import striped_video
from slipsense.atomic import file_sha256
from slipsense.cache import Entry
from slipsense.errors import CacheWarning
from slipsense.recordings import label_cache
from slipsense.recordings import labels as L
from slipsense.recordings.clips import ClipSpec, load_or_build_clips
from slipsense.recordings.folders import find_recordings
from slipsense.recordings.types import VideoLabel

N = 40


def flip_byte(path: Path, at: float = 0.5) -> None:
    data = bytearray(path.read_bytes())
    data[int(len(data) * at)] ^= 0xFF
    path.write_bytes(bytes(data))


def reseal(path: Path) -> None:
    """Make the check file beside ``path`` hold its (edited) file's sha256: only its contents can
    then tell that the entry is wrong."""
    check = path.with_name(path.name + ".check")
    info = json.loads(check.read_text())
    info["sha256"][path.name] = file_sha256(path)
    check.write_text(json.dumps(info))


def quiet_or_one_warning(call, expect: str | None):
    """``call()``, which warns (CacheWarning) exactly once, with ``expect`` in it, or not at all."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = call()
    msgs = [str(w.message) for w in caught if issubclass(w.category, CacheWarning)]
    assert (msgs == []) if expect is None else (len(msgs) == 1 and expect in msgs[0]), msgs
    return out


# ------------------------------------------------------------------------------------ the helper
DAMAGES = ["flip_byte", "truncate", "garbage", "no_file", "no_check", "garbled_check", "list_check", "other_inputs"]


@pytest.mark.parametrize("damage", DAMAGES)
def test_a_damaged_entry_is_rebuilt_never_used(tmp_path, damage):
    entry = Entry(tmp_path, {"source": 1}, "test cache", suffix=".bin")
    builds = []
    build = lambda: builds.append(1) or b"the right bytes" * 10
    get = lambda: entry.get(lambda f: f.read_bytes(), build, lambda tmp, v: tmp.write_bytes(v))
    assert quiet_or_one_warning(get, None) == b"the right bytes" * 10 and len(builds) == 1
    assert quiet_or_one_warning(get, None) == b"the right bytes" * 10 and len(builds) == 1  # used
    data, check = entry.path, entry.check
    if damage == "flip_byte":
        flip_byte(data)
    elif damage == "truncate":
        data.write_bytes(data.read_bytes()[:7])
    elif damage == "garbage":
        data.write_bytes(b"garbage")
    elif damage == "no_file":
        data.unlink()
    elif damage == "no_check":
        check.unlink()
    elif damage == "garbled_check":
        check.write_text('{"inputs": ')
    elif damage == "list_check":
        check.write_text("[]")
    else:
        check.write_text(json.dumps({**json.loads(check.read_text()), "inputs": {"source": 2}}))
    # no check file: the writing of the entry never finished (rebuilt, nothing to warn about)
    expect = {"no_check": None, "other_inputs": "other inputs"}.get(damage, "rebuilding")
    assert quiet_or_one_warning(get, expect) == b"the right bytes" * 10 and len(builds) == 2
    assert quiet_or_one_warning(get, None) == b"the right bytes" * 10 and len(builds) == 2  # whole again


def test_an_entry_that_cannot_be_written_only_warns_unless_it_is_the_value(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    entry = Entry(blocker / "sub", [1], "test cache", suffix=".bin")
    with pytest.warns(CacheWarning, match="cannot write the test cache"):
        assert entry.get(lambda f: f.read_bytes(), lambda: b"x", lambda tmp, v: tmp.write_bytes(v)) == b"x"
    with pytest.raises(OSError):  # a folder entry's files are what the caller asked for
        Entry(blocker / "sub", [1], "test cache", names=["a"]).save(lambda folder: (folder / "a").write_text("a"))


# ---------------------------------------------------------------------------------------- labels
@pytest.fixture
def run(tmp_path, monkeypatch):
    """One slip run of two 40-frame striped videos; the cache in tmp_path/cache."""
    monkeypatch.setenv("SLIPSENSE_CACHE", str(tmp_path / "cache"))
    folder = tmp_path / "rec" / "cup" / "exp_num_1"
    for cam in ("camera_0", "camera_2"):
        striped_video.write_video(folder / f"{cam}.avi", N, size=(96, 128))
    (folder / "slip.txt").write_text("")
    return find_recordings(tmp_path / "rec")


def _edit_rows(path: Path, **changes) -> None:
    rows = json.loads(path.read_text())
    for row in rows:
        row.update(changes)
    path.write_text(json.dumps(rows))


def test_label_cache_entry_damaged_or_impossible_is_relabelled(run, tmp_path):
    first = L.label_recordings(run, progress=False)
    (data,) = (tmp_path / "cache" / "labels").glob("*.json")
    good = data.read_bytes()
    again = lambda expect: quiet_or_one_warning(lambda: L.label_recordings(run, progress=False), expect)
    assert again(None) == first  # a good entry is used

    flip_byte(data)
    assert again("checksum mismatch") == first
    assert data.read_bytes() == good  # rewritten
    # labels the videos cannot have, with a matching checksum: the labels themselves are refused
    _edit_rows(data, moment_of_slip=N + 10)
    reseal(data)
    assert again("not inside") == first
    _edit_rows(data, n_frames=N + 5)
    reseal(data)
    assert again("states") == first
    assert again(None) == first


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


# ---------------------------------------------------------------------------------------- frames
def test_frame_cache_entry_damaged_is_decoded_again(run, tmp_path, monkeypatch):
    from slipsense.recordings import video as video_mod
    from slipsense.recordings.frame_cache import video_products

    decodes = []
    real = video_mod.read_video
    monkeypatch.setattr(video_mod, "read_video", lambda p, *a, **k: decodes.append(p) or real(p, *a, **k))
    path = run[0].path
    first = np.array(video_products(path, ["gray:16x20"])["gray:16x20"])
    (entry,) = (tmp_path / "cache" / "frames").glob("*.npy")
    flip_byte(entry, at=0.99)  # one grey level of the last frame
    again = quiet_or_one_warning(lambda: video_products(path, ["gray:16x20"])["gray:16x20"], "checksum mismatch")
    np.testing.assert_array_equal(again, first)
    assert len(decodes) == 2
    again = quiet_or_one_warning(lambda: video_products(path, ["gray:16x20"])["gray:16x20"], None)
    assert isinstance(again, np.memmap) and np.array_equal(again, first) and len(decodes) == 2


# ----------------------------------------------------------------------------------------- clips
SPEC = ClipSpec(frames=4, size=(48, 64))


def test_clip_cache_entry_damaged_or_with_other_windows_is_rebuilt(run, tmp_path):
    labels = {r.key: VideoLabel(r.object, r.experiment, r.camera, N, True, 30, 10, 30) for r in run}
    folder = tmp_path / "clips"
    get = lambda: load_or_build_clips(run, labels, SPEC, cache_dir=folder, progress=False)
    first = get()
    (npz,) = folder.glob("clips-*.npz")
    assert quiet_or_one_warning(get, None).meta == first.meta

    flip_byte(npz)
    again = quiet_or_one_warning(get, "checksum mismatch")
    np.testing.assert_array_equal(again.x, first.x)
    # windows and labels edited, checksum made to match: the windows the labels give are checked
    with np.load(npz) as z:
        x, y, meta = z["x"], z["y"], json.loads(str(z["meta"]))
    meta[0]["start"] += 1
    np.savez(npz, x=x, y=1 - y, meta=np.array(json.dumps(meta)))
    reseal(npz)
    again = quiet_or_one_warning(get, "windows differ")
    np.testing.assert_array_equal(again.y, first.y)
    assert again.meta == first.meta
    quiet_or_one_warning(get, None)


# --------------------------------------------------------------------------------------- markers
def test_marker_cache_entry_damaged_or_inconsistent_is_tracked_again(tmp_path, monkeypatch):
    from test_markers import shifted_video, write_avi

    from slipsense.recordings import markers as M

    frames, _ = shifted_video((0.5, 0.25), n_frames=14)
    video = tmp_path / "obj" / "exp_num_1" / "camera_0.avi"
    video.parent.mkdir(parents=True)
    write_avi(video, frames)
    folder = tmp_path / "markers"
    (first,) = M.track_recordings([video], progress=False, cache_dir=folder)
    (npz,) = folder.glob("obj-exp_num_1-camera_0-*.npz")
    calls = []
    real = M.track_recording
    monkeypatch.setattr(M, "track_recording", lambda *a, **k: calls.append(a) or real(*a, **k))

    def again(expect):
        (track,) = quiet_or_one_warning(lambda: M.track_recordings([video], progress=False, cache_dir=folder), expect)
        np.testing.assert_array_equal(track.positions, first.positions)

    again(None)
    assert calls == []
    arrays = dict(np.load(npz))
    np.savez(npz, **{**arrays, "positions": arrays["positions"] + 1.0})
    again("checksum mismatch")
    # arrays that do not fit together, with a matching checksum
    np.savez(npz, **{**dict(np.load(npz)), "reference_index": np.int64(99)})
    reseal(npz)
    again("reference index")
    assert len(calls) == 2
    again(None)


# ------------------------------------------------------------------------------------ ONNX parts
def test_onnx_parts_damaged_or_of_another_model_are_exported_again(tmp_path, monkeypatch):
    pytest.importorskip("onnxruntime")
    from slipsense.models import build
    from slipsense.models import onnx as export
    from slipsense.streaming.detector import window_geometry

    model = build("temnet", frames=4, markers=5, d_model=8, heads=2, blocks=1, ff_dim=8, head_hidden=0).eval()
    geometry = window_geometry(model)
    calls = []
    real = export.export_parts
    monkeypatch.setattr(export, "export_parts", lambda *a, **k: calls.append(1) or real(*a, **k))
    folder = tmp_path / "parts"
    paths = export.cached_streaming_parts(model, folder, geometry)
    window = paths["window"]
    good = window.read_bytes()
    assert quiet_or_one_warning(lambda: export.cached_streaming_parts(model, folder, geometry), None) == paths
    assert calls == [1]  # verified and reused

    window.write_bytes(good[:-10])  # damaged
    assert quiet_or_one_warning(lambda: export.cached_streaming_parts(model, folder, geometry), "window.onnx")
    assert calls == [1, 1] and window.read_bytes() == good
    other = build("temnet", frames=4, markers=5, d_model=8, heads=2, blocks=1, ff_dim=16, head_hidden=0).eval()
    quiet_or_one_warning(lambda: export.cached_streaming_parts(other, folder, window_geometry(other)), "other inputs")
    assert len(calls) == 3


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


# ----------------------------------------------------------------------------------- bag cameras
def test_bag_camera_damaged_in_the_cache_is_converted_again(tmp_path, cache):
    pytest.importorskip("rosbags")
    from test_bags import write_bag

    from slipsense.recordings.video import read_video

    rng = np.random.default_rng(3)
    v = [rng.integers(0, 255, (6, 24, 32, 3), dtype=np.uint8) for _ in range(2)]
    write_bag(tmp_path / "bags" / "cup" / "exp_num_1", v, ["/a/image", "/b/image"])
    recs = find_recordings(tmp_path / "bags")
    assert [r.path.parent.parent for r in recs] == [cache / "bags"] * 2
    flip_byte(recs[1].path, at=0.7)
    again = quiet_or_one_warning(lambda: find_recordings(tmp_path / "bags"), "camera_1.avi: checksum mismatch")
    assert [r.path for r in again] == [r.path for r in recs]
    assert np.array_equal(read_video(again[1].path, expected_size=None), v[1])  # the bag's frames, not the damage
    recs[0].path.unlink()
    quiet_or_one_warning(lambda: find_recordings(tmp_path / "bags"), "camera_0.avi")
    assert np.array_equal(read_video(recs[0].path, expected_size=None), v[0])
    quiet_or_one_warning(lambda: find_recordings(tmp_path / "bags"), None)


# ---------------------------------------------------------------------------------------- tracked markers
def test_tracked_markers_damaged_are_tracked_again(cache, monkeypatch):
    import torch

    from slipsense.models import build, tracking

    model = build("shear-retention", sensors=1, image_size=[40, 60]).eval()
    gray = torch.rand(1, 1, 6, 40, 60, generator=torch.Generator().manual_seed(0))
    calls = []
    real = type(model)._track
    monkeypatch.setattr(type(model), "_track", lambda self, g: calls.append(1) or real(self, g))
    first = model.tracked(gray)
    (entry,) = (cache / "tracked").glob("*.safetensors")
    flip_byte(entry, at=0.99)
    monkeypatch.setattr(tracking, "_MEMO", {})  # as another process finds it
    again = quiet_or_one_warning(lambda: model.tracked(gray), "checksum mismatch")
    assert torch.equal(again, first) and len(calls) == 2
    monkeypatch.setattr(tracking, "_MEMO", {})
    assert torch.equal(quiet_or_one_warning(lambda: model.tracked(gray), None), first) and len(calls) == 2
