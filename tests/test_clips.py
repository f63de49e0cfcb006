"""Clip cutting, caching, splits (slipsense.recordings.clips) and augmentation (slipsense.recordings.augment)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import striped_video
from striped_video import index_of

from slipsense import paths
from slipsense.errors import CacheWarning, ConfigError, InputError
from slipsense.recordings import clips as clips_mod
from slipsense.recordings.augment import AugmentConfig, add_noise, transform_clip
from slipsense.recordings.clips import (
    ClipSet,
    ClipSpec,
    build_clips,
    cache_key,
    load_or_build_clips,
    object_folds,
    plan_windows,
    split_by_clip,
    split_by_object,
    wiggle_starts,
)
from slipsense.recordings.folders import SkippedInputWarning, find_recordings
from slipsense.recordings.types import Recording, VideoLabel

N_FRAMES = 60
SIZE = (96, 128)  # small frames keep the suite fast; stripes stay 16 px wide


def frame_for(i: int, size=SIZE) -> np.ndarray:
    return striped_video.frame_for(i, size)


def write_video(path: Path, n: int, size=SIZE) -> Path:
    return striped_video.write_video(path, n, size)


# object -> {experiment -> slipped}
TREE = {"apple": {1: True, 2: False}, "pear": {1: True, 2: False}, "plum": {1: False, 2: True}, "fig": {1: False}}
MOMENT = 40
CONTACT = (10, 50)


def label_for(rec: Recording, moment: int = MOMENT, n_frames: int = N_FRAMES) -> VideoLabel:
    return VideoLabel(
        object=rec.object,
        experiment=rec.experiment,
        camera=rec.camera,
        n_frames=n_frames,
        slipped=rec.slipped,
        moment_of_slip=moment if rec.slipped else None,
        contact_start=CONTACT[0],
        contact_end=moment if rec.slipped else CONTACT[1],
    )


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("recordings")
    for obj, exps in TREE.items():
        for num, slipped in exps.items():
            d = root / obj / f"exp_num_{num}"
            for cam in ("camera_0", "camera_2"):
                write_video(d / f"{cam}.avi", N_FRAMES)
            if slipped:
                (d / "slip.txt").write_text("")
    recs = find_recordings(root)
    labels = {r.key: label_for(r) for r in recs}
    return root, recs, labels


SPEC = ClipSpec(frames=5, size=SIZE, seed=3)


@pytest.fixture(scope="module")
def built(dataset):
    _, recs, labels = dataset
    return build_clips(recs, labels, SPEC, progress=False)


def clip_indices(clip: np.ndarray) -> list[int]:
    return [index_of(f) for f in clip]


# ------------------------------------------------------------------------------------------ spec


@pytest.mark.parametrize(
    "kwargs",
    [
        {"frames": 1},
        {"frames": 13},
        {"frames": 5.0},
        {"frames": True},
        {"horizon": -1},
        {"wiggle_per_video": -1},
        {"size": (0, 10)},
        {"size": (10,)},
        {"size": "small"},
        {"seed": 1.5},
    ],
)
def test_clip_spec_rejects(kwargs):
    with pytest.raises(ConfigError):
        ClipSpec(**kwargs)


@given(
    frames=st.integers(-5, 20),
    horizon=st.integers(-5, 50),
    wiggle=st.integers(-3, 10),
    h=st.integers(-2, 400),
    w=st.integers(-2, 400),
)
def test_clip_spec_validation_property(frames, horizon, wiggle, h, w):
    valid = 2 <= frames <= 12 and horizon >= 0 and wiggle >= 0 and h > 0 and w > 0
    if valid:
        spec = ClipSpec(frames=frames, horizon=horizon, wiggle_per_video=wiggle, size=[h, w])
        assert spec.size == (h, w) and hash(spec) == hash(ClipSpec(frames, horizon, wiggle, (h, w)))
    else:
        with pytest.raises(ConfigError):
            ClipSpec(frames=frames, horizon=horizon, wiggle_per_video=wiggle, size=(h, w))


# --------------------------------------------------------------------------------------- windows


@st.composite
def label_and_spec(draw):
    n = draw(st.integers(2, 500))
    cs = draw(st.integers(0, n - 1))
    ce = draw(st.integers(cs, n - 1))
    slipped = draw(st.booleans())
    moment = draw(st.integers(0, n - 1)) if slipped else None
    label = VideoLabel(
        "obj", draw(st.integers(1, 20)), draw(st.sampled_from(["camera_0", "camera_2"])), n, slipped, moment, cs, ce
    )
    spec = ClipSpec(
        frames=draw(st.integers(2, 12)),
        horizon=draw(st.integers(0, 30)),
        wiggle_per_video=draw(st.integers(0, 8)),
        seed=draw(st.integers(0, 2**32)),
    )
    return label, spec


@settings(max_examples=300, deadline=None)
@given(label_and_spec())
def test_windows_property(ls):
    label, spec = ls
    windows = plan_windows(label, spec)
    assert windows == plan_windows(label, spec)  # reproducible
    for w in windows:
        assert w.end - w.start + 1 == spec.frames
        assert label.contact_start <= w.start and w.end < label.n_frames
    if label.slipped:
        m = label.moment_of_slip
        fits = m - spec.horizon - spec.frames >= label.contact_start
        assert len(windows) == int(fits)
        if fits:
            (w,) = windows
            assert (w.y, w.end) == (1, m - spec.horizon - 1)
    else:
        room = (label.contact_end - label.contact_start + 1) // spec.frames
        assert len(windows) == min(spec.wiggle_per_video, room)
        ends = [w.end for w in windows]
        assert all(w.y == 0 and w.end <= label.contact_end for w in windows)
        starts = [w.start for w in windows]
        assert starts == sorted(starts)
        assert all(s > e for s, e in zip(starts[1:], ends[:-1]))  # non-overlapping


def test_wiggle_placements_are_uniform():
    # 2 windows of 3 frames in 8 frames: C(2 + 2, 2) = 6 placements, each should be drawn.
    rng = np.random.default_rng(0)
    seen = {}
    for _ in range(3000):
        key = tuple(wiggle_starts(0, 7, 3, 2, rng))
        seen[key] = seen.get(key, 0) + 1
    assert len(seen) == 6
    assert max(seen.values()) / min(seen.values()) < 1.3


# ------------------------------------------------------------------------------------ build_clips


def test_build_clips_shapes_and_counts(built):
    n_slip_videos = 2 * sum(s for exps in TREE.values() for s in exps.values())
    n_wiggle_videos = 2 * sum(not s for exps in TREE.values() for s in exps.values())
    assert built.x.shape == (n_slip_videos + 2 * n_wiggle_videos, 5, *SIZE, 3)
    assert built.x.dtype == np.uint8 and built.y.dtype == np.int64
    assert built.counts() == {
        "clips": len(built),
        "slip": n_slip_videos,
        "wiggle": 2 * n_wiggle_videos,
        "augmented": 0,
        "objects": 4,
    }
    assert built.objects == ["apple", "fig", "pear", "plum"]
    keys = [(m["object"], m["experiment"], m["camera"], m["start"]) for m in built.meta]
    assert keys == sorted(keys)


def test_slip_clips_end_right_before_moment(built):
    slips = np.flatnonzero(built.y == 1)
    assert len(slips)
    for i in slips:
        m = built.meta[i]
        assert (m["start"], m["end"], m["moment_of_slip"]) == (MOMENT - 5, MOMENT - 1, MOMENT)
        assert clip_indices(built.x[i]) == list(range(MOMENT - 5, MOMENT))


def test_wiggle_clips_match_their_frames(built):
    for i in np.flatnonzero(built.y == 0):
        m = built.meta[i]
        assert CONTACT[0] <= m["start"] and m["end"] <= CONTACT[1] and m["moment_of_slip"] is None
        assert clip_indices(built.x[i]) == list(range(m["start"], m["end"] + 1))


def test_horizon_shifts_the_slip_window(dataset):
    _, recs, labels = dataset
    recs = [r for r in recs if r.slipped][:1]
    clips = build_clips(recs, labels, ClipSpec(frames=4, horizon=7, size=SIZE), progress=False)
    assert clip_indices(clips.x[0]) == list(range(MOMENT - 7 - 4, MOMENT - 7))
    assert (clips.meta[0]["start"], clips.meta[0]["end"]) == (MOMENT - 11, MOMENT - 8)


def test_downscale(dataset):
    _, recs, labels = dataset
    recs = [r for r in recs if r.slipped][:1]
    clips = build_clips(recs, labels, ClipSpec(frames=3, size=(48, 64)), progress=False)
    assert clips.x.shape == (1, 3, 48, 64, 3)
    assert clip_indices(clips.x[0]) == [MOMENT - 3, MOMENT - 2, MOMENT - 1]


def test_reproducible_and_seeded(dataset, built):
    _, recs, labels = dataset
    wiggle = [r for r in recs if not r.slipped]
    a = build_clips(wiggle, labels, SPEC, progress=False)
    assert [m["start"] for m in a.meta] == [m["start"] for m in built.meta if m["moment_of_slip"] is None]
    b = build_clips(wiggle, labels, ClipSpec(frames=5, size=SIZE, seed=4), progress=False)
    assert [m["start"] for m in a.meta] != [m["start"] for m in b.meta]


def test_too_early_slip_is_skipped_with_warning(dataset):
    _, recs, labels = dataset
    rec = next(r for r in recs if r.slipped)
    early = {rec.key: label_for(rec, moment=CONTACT[0] + 3)}
    with pytest.warns(SkippedInputWarning, match="too early") as record:
        clips = build_clips([rec], early, SPEC, progress=False)
    assert len(clips) == 0 and clips.x.shape == (0, 5, *SIZE, 3)
    assert str(rec.path) in str(record[0].message)


def test_short_contact_phase_draws_fewer_with_warning(dataset):
    _, recs, labels = dataset
    rec = next(r for r in recs if not r.slipped)
    label = VideoLabel(rec.object, rec.experiment, rec.camera, N_FRAMES, False, None, 20, 26)
    with pytest.warns(SkippedInputWarning, match="holds only 1 of the 2"):
        clips = build_clips([rec], {rec.key: label}, SPEC, progress=False)
    assert len(clips) == 1 and 20 <= clips.meta[0]["start"] <= 22


def test_label_problems_raise(dataset):
    _, recs, labels = dataset
    rec = next(r for r in recs if r.slipped)
    with pytest.raises(InputError, match="no label"):
        build_clips([rec], {}, SPEC, progress=False)
    with pytest.raises(InputError, match="label is for 61 frames but the video has 60"):
        build_clips([rec], {rec.key: label_for(rec, n_frames=61)}, SPEC, progress=False)
    wrong = VideoLabel(rec.object, rec.experiment, rec.camera, N_FRAMES, False, None, 10, 50)
    with pytest.raises(InputError, match="slip.txt is present"):
        build_clips([rec], {rec.key: wrong}, SPEC, progress=False)
    bad = VideoLabel(rec.object, rec.experiment, rec.camera, N_FRAMES, True, 70, 10, 50)
    with pytest.raises(InputError) as exc:
        build_clips([rec], {rec.key: bad}, SPEC, progress=False)
    assert str(exc.value).startswith(f"{rec.path}: ")
    with pytest.raises(InputError, match="listed twice"):
        build_clips([rec, rec], labels, SPEC, progress=False)


def test_unreadable_video_raises_input_error(tmp_path, dataset):
    _, recs, labels = dataset
    rec = next(r for r in recs if r.slipped)
    broken = tmp_path / "camera_0.avi"
    broken.write_bytes(rec.path.read_bytes()[:1000])
    moved = Recording(rec.object, rec.experiment, rec.camera, broken, rec.slipped)
    with pytest.raises(InputError) as exc:
        build_clips([moved], labels, SPEC, progress=False)
    assert str(exc.value).startswith(f"{broken}: ")


def test_clipset_subset_and_checks(built):
    sub = built.subset([0, 2])
    assert len(sub) == 2 and np.array_equal(sub.x[1], built.x[2]) and sub.meta[1] == built.meta[2]
    assert len(built.subset(np.flatnonzero(built.y == 1))) == int((built.y == 1).sum())
    with pytest.raises(InputError):
        built.subset([len(built)])
    with pytest.raises(InputError):
        ClipSet(built.x[:2], built.y[:3], built.meta[:2])
    with pytest.raises(InputError):
        ClipSet(built.x[:2].astype(np.float32), built.y[:2], built.meta[:2])


# ------------------------------------------------------------------------------------------ cache


def counting_reader(monkeypatch):
    calls = []
    real = clips_mod.read_video

    def reader(path, *a, **k):
        calls.append(path)
        return real(path, *a, **k)

    monkeypatch.setattr(clips_mod, "read_video", reader)
    return calls


def forbid_reading(monkeypatch):
    def reader(path, *a, **k):
        raise AssertionError(f"decoded {path} although the cache should have been used")

    monkeypatch.setattr(clips_mod, "read_video", reader)


def assert_same(a: ClipSet, b: ClipSet):
    assert np.array_equal(a.x, b.x) and np.array_equal(a.y, b.y) and a.meta == b.meta


def test_cache_hit_avoids_decoding(tmp_path, dataset, monkeypatch):
    _, recs, labels = dataset
    recs = recs[:6]
    calls = counting_reader(monkeypatch)
    first = load_or_build_clips(recs, labels, SPEC, cache_dir=tmp_path, progress=False)
    assert len(calls) == 6
    files = sorted(p.name for p in tmp_path.iterdir())
    assert len(files) == 2 and files[0].endswith(".npz") and files[1].endswith(".npz.check")
    forbid_reading(monkeypatch)
    second = load_or_build_clips(recs, labels, SPEC, cache_dir=tmp_path, progress=False)
    assert_same(first, second)
    assert second.spec == SPEC


def test_default_cache_location(tmp_path, dataset, monkeypatch):
    _, recs, labels = dataset
    monkeypatch.setenv("SLIPSENSE_CACHE", str(tmp_path / "c"))
    load_or_build_clips(recs[:1], labels, SPEC, progress=False)
    assert len(list((paths.cache_root() / "clips").glob("clips-*.npz"))) == 1


def test_cache_key_tracks_inputs(tmp_path, dataset):
    _, recs, labels = dataset
    rec = recs[0]
    copy = tmp_path / "camera_0.avi"
    copy.write_bytes(rec.path.read_bytes())
    moved = [Recording(rec.object, rec.experiment, rec.camera, copy, rec.slipped)]
    key = cache_key(moved, labels, SPEC)
    assert key == cache_key(moved, labels, SPEC)
    assert key != cache_key(moved, labels, ClipSpec(frames=6, size=SIZE, seed=3))
    relabelled = dict(labels)
    relabelled[rec.key] = label_for(rec, moment=MOMENT + 1)
    assert key != cache_key(moved, relabelled, SPEC)
    st_ = copy.stat()
    os.utime(copy, ns=(st_.st_atime_ns, st_.st_mtime_ns + 1_000_000_000))
    assert key != cache_key(moved, labels, SPEC)


def test_cache_write_failure_only_warns(tmp_path, dataset):
    _, recs, labels = dataset
    blocker = tmp_path / "not_a_dir"
    blocker.write_text("")
    with pytest.warns(CacheWarning, match="cannot write"):
        clips = load_or_build_clips(recs[:1], labels, SPEC, cache_dir=blocker / "sub", progress=False)
    assert len(clips) == 1


# ----------------------------------------------------------------------------------------- splits


def test_split_by_object_has_no_overlap(built):
    train, test = split_by_object(built, ["pear", "fig"])
    assert set(built.clip_objects[test]) == {"pear", "fig"}
    assert not set(built.clip_objects[train]) & {"pear", "fig"}
    assert sorted(np.concatenate([train, test]).tolist()) == list(range(len(built)))
    with pytest.raises(ConfigError, match="banana"):
        split_by_object(built, ["banana"])
    with pytest.raises(ConfigError):
        split_by_object(built, [])


def test_object_folds_partition_and_determinism():
    names = [f"obj{i:02d}" for i in range(29)]
    folds = object_folds(names, n_folds=5, seed=1)
    assert len(folds) == 5 and sorted(n for f in folds for n in f) == names
    assert sorted(len(f) for f in folds) == [5, 6, 6, 6, 6]
    assert object_folds(list(reversed(names)) + names[:3], 5, seed=1) == folds
    assert object_folds(names, 5, seed=2) != folds
    for bad in (1, 30, 2.5):
        with pytest.raises(ConfigError):
            object_folds(names, bad)


def test_object_folds_give_disjoint_clip_splits(built):
    for fold in object_folds(built.objects, n_folds=2, seed=0):
        train, test = split_by_object(built, fold)
        assert not set(built.clip_objects[train]) & set(built.clip_objects[test])


def test_split_by_clip(built):
    train, test = split_by_clip(built, test_fraction=0.25, seed=5)
    again = split_by_clip(built, test_fraction=0.25, seed=5)
    assert np.array_equal(train, again[0]) and np.array_equal(test, again[1])
    assert not set(train.tolist()) & set(test.tolist())
    assert len(train) + len(test) == len(built)
    for c in (0, 1):  # stratified: each class split in proportion
        n_c = int((built.y == c).sum())
        assert int((built.y[test] == c).sum()) == round(0.25 * n_c)
    other = split_by_clip(built, test_fraction=0.25, seed=6)
    assert not np.array_equal(test, other[1])
    with pytest.raises(ConfigError):
        split_by_clip(built, test_fraction=1.0)


# ------------------------------------------------------------------------------------ augmentation


def test_transform_without_noise_is_swap_then_flip():
    rng = np.random.default_rng(0)
    x = rng.integers(0, 256, size=(3, 4, 5, 3), dtype=np.uint8)
    before = x.copy()
    out = transform_clip(x, AugmentConfig(noise_std=0.0), rng)
    assert out.dtype == np.uint8 and out.shape == x.shape and out.flags["C_CONTIGUOUS"]
    t, r, c = np.meshgrid(range(3), range(4), range(5), indexing="ij")
    for ch in range(3):
        assert np.array_equal(out[t, r, c, ch], x[t, r, 4 - c, 2 - ch])
    assert np.array_equal(x, before)
    assert np.array_equal(transform_clip(x, AugmentConfig(noise_std=0, hflip=False), rng), x[..., ::-1])
    assert np.array_equal(transform_clip(x, AugmentConfig(noise_std=0, swap_red_blue=False), rng), x[:, :, ::-1])
    assert np.array_equal(transform_clip(x, AugmentConfig(enabled=False), rng), x)


def test_transform_is_noise_then_swap_then_flip():
    x = np.random.default_rng(1).integers(0, 256, size=(2, 6, 7, 3), dtype=np.uint8)
    out = transform_clip(x, AugmentConfig(), np.random.default_rng(9))
    noisy = add_noise(x, 15.0, np.random.default_rng(9))
    assert np.array_equal(out, noisy[..., ::-1][:, :, ::-1])


def test_add_noise_statistics_and_clipping():
    rng = np.random.default_rng(0)
    x = np.full((4, 64, 64, 3), 128, np.uint8)
    noisy = add_noise(x, 15.0, rng)
    d = noisy.astype(np.float64) - 128
    assert noisy.dtype == np.uint8 and abs(d.mean()) < 0.2 and abs(d.std() - 15.0) < 0.3
    assert np.array_equal(d, np.rint(d))
    low = add_noise(np.zeros((1000,), np.uint8), 15.0, rng)
    high = add_noise(np.full((1000,), 255, np.uint8), 15.0, rng)
    assert low.min() == 0 and (low == 0).mean() > 0.4 and high.max() == 255 and (high == 255).mean() > 0.4
    assert np.array_equal(add_noise(x, 0.0, rng), x)
    with pytest.raises(InputError):
        add_noise(x.astype(np.float32), 15.0, rng)
    with pytest.raises(InputError):
        add_noise(x, -1.0, rng)


@pytest.mark.parametrize(
    "kwargs", [{"noise_std": -1}, {"noise_std": float("nan")}, {"noise_std": "15"}, {"hflip": "yes"}]
)
def test_augment_config_rejects(kwargs):
    with pytest.raises(ConfigError):
        AugmentConfig(**kwargs)


def test_transform_rejects_bad_clip():
    with pytest.raises(InputError):
        transform_clip(np.zeros((4, 5, 3), np.uint8), AugmentConfig(), np.random.default_rng(0))


# -------------------------------------------------------------------------------------- real data

REAL = paths.gelsight_recordings()


@pytest.mark.skipif(not REAL.is_dir(), reason="shared GelSight recordings not present")
def test_real_recordings_to_clips():
    recs = find_recordings(REAL)
    slipped = next(r for r in recs if r.slipped)
    calm = next(r for r in recs if not r.slipped)
    from slipsense.recordings.video import probe_video

    labels = {}
    for r in (slipped, calm):
        n = probe_video(r.path).n_frames
        # Stand-in labels: the real ones come from the labeller; here only the plumbing is tested.
        labels[r.key] = VideoLabel(
            r.object, r.experiment, r.camera, n, r.slipped, n - 20 if r.slipped else None, 12, n - 20
        )
    spec = ClipSpec(frames=5, size=(120, 160), wiggle_per_video=2)
    clips = build_clips([slipped, calm], labels, spec, progress=False)
    assert clips.x.shape == (3, 5, 120, 160, 3) and sorted(clips.y.tolist()) == [0, 0, 1]
    slip_meta = clips.meta[int(np.flatnonzero(clips.y == 1)[0])]
    n = labels[slipped.key].n_frames
    assert (slip_meta["start"], slip_meta["end"]) == (n - 25, n - 21)
