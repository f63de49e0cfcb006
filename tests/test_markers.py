"""Marker detection and tracking: synthetic marker grids with known motion, plus one real video."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slipsense.errors import InputError
from slipsense.recordings import markers as M
from slipsense.recordings.markers import (
    MarkerTrack,
    detect_markers,
    marker_sequences,
    order_markers,
    select_markers,
    track_markers,
    track_recordings,
)

H, W = 240, 320
RADIUS = 6.0  # px, marker radius of the synthetic gel
SPACING = 30.0  # px


def grid(rows: int = 8, cols: int = 10, x0: float = 25.3, y0: float = 14.7) -> np.ndarray:
    """(rows*cols, 2) row-major (x, y) centres of a regular marker grid, in px."""
    ys, xs = np.mgrid[0:rows, 0:cols].astype(np.float64)
    return np.stack([x0 + xs.ravel() * SPACING, y0 + ys.ravel() * SPACING], axis=1)


def render(centres: np.ndarray, seed: int = 0, noise: float = 1.5) -> np.ndarray:
    """uint8 (H, W, 3) BGR tactile-like frame: anti-aliased dark discs on smooth coloured shading.

    Disc coverage is the exact-ish area fraction of each pixel inside the circle (a linear ramp
    over one pixel at the rim), so centroids move with sub-pixel shifts of ``centres``.
    """
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    shade = 150 + 25 * np.sin(xx / 70.0) + 15 * np.cos(yy / 50.0)
    cover = np.zeros((H, W), np.float32)
    for cx, cy in centres:
        x0, x1 = int(max(cx - RADIUS - 3, 0)), int(min(cx + RADIUS + 4, W))
        y0, y1 = int(max(cy - RADIUS - 3, 0)), int(min(cy + RADIUS + 4, H))
        if x0 >= x1 or y0 >= y1:
            continue
        r = np.hypot(xx[y0:y1, x0:x1] - cx, yy[y0:y1, x0:x1] - cy)
        cover[y0:y1, x0:x1] = np.maximum(cover[y0:y1, x0:x1], np.clip(RADIUS + 0.5 - r, 0, 1))
    grey = shade * (1 - 0.75 * cover)
    bgr = np.stack([grey * 1.0, grey * 0.85, grey * 0.7], axis=-1)
    bgr = cv2.GaussianBlur(bgr, (0, 0), 0.7)  # lens blur
    bgr += np.random.default_rng(seed).normal(0, noise, bgr.shape)
    return np.clip(np.rint(bgr), 0, 255).astype(np.uint8)


def match(found: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Distance (px) from each true centre to the nearest found one."""
    return np.linalg.norm(truth[:, None, :] - found[None, :, :], axis=-1).min(axis=1)


# --- detection -------------------------------------------------------------------------------


def test_detects_every_marker_with_subpixel_centres():
    truth = grid()
    found = detect_markers(render(truth))
    assert found.shape == (80, 2) and found.dtype == np.float32
    assert match(found, truth).max() < 0.1


def test_detection_output_is_row_major():
    truth = grid()
    found = detect_markers(render(truth))
    # Row-major: matching found[i] to its true marker gives indices 0, 1, 2, ...
    nearest = np.linalg.norm(found[:, None] - truth[None], axis=-1).argmin(axis=1)
    assert nearest.tolist() == list(range(80))


def test_rejects_markers_cut_by_the_image_border():
    truth = grid(x0=2.0, y0=20.0)  # first column cut by the left edge
    found = detect_markers(render(truth))
    assert len(found) == 72  # 9 whole columns of 8
    assert found[:, 0].min() > 20


def test_frame_without_markers_is_a_clear_error():
    blank = np.full((H, W, 3), 128, np.uint8)
    noisy = render(np.zeros((0, 2)), noise=3.0)
    for frame in (blank, noisy):
        with pytest.raises(InputError, match="found 0 markers"):
            detect_markers(frame, source="clip.avi")
    with pytest.raises(InputError, match="reference frame 10"):
        track_markers(np.stack([blank] * 12), source="clip.avi")


def test_bad_frame_types_are_refused():
    with pytest.raises(InputError, match="uint8"):
        detect_markers(np.zeros((H, W, 3), np.float32))
    with pytest.raises(InputError, match="uint8"):
        track_markers(np.zeros((3, H, W, 4), np.uint8))
    with pytest.raises(InputError, match="outside"):
        track_markers(np.stack([render(grid())] * 3), reference_index=5)


def test_order_markers_handles_small_rotation():
    truth = grid()
    c, s = np.cos(np.radians(3)), np.sin(np.radians(3))
    rotated = (truth - truth.mean(0)) @ np.array([[c, -s], [s, c]]).T + truth.mean(0)
    shuffled = np.random.default_rng(1).permutation(80)
    order = order_markers(rotated[shuffled])
    assert shuffled[order].tolist() == list(range(80))


# --- tracking --------------------------------------------------------------------------------


def shifted_video(step: tuple[float, float], n_frames: int = 14, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Frames whose whole grid moves by ``step`` px per frame; returns (frames, true offsets (T, 2))."""
    base = grid(rows=7, cols=9, x0=35.0, y0=30.0)
    offsets = np.arange(n_frames)[:, None] * np.asarray(step)[None]
    frames = np.stack([render(base + off, seed=seed + t) for t, off in enumerate(offsets)])
    return frames, offsets


@pytest.mark.parametrize("step", [(0.37, -0.23), (1.5, 1.0), (-2.6, 0.4)])
def test_tracks_known_shift_within_0_2_px(step):
    frames, offsets = shifted_video(step)
    track = track_markers(frames, reference_index=0)
    assert track.n_markers == 63
    err = np.linalg.norm(track.displacement() - offsets[:, None, :], axis=-1)
    truth = track.reference_positions[None] + offsets[:, None, :]
    margin = np.minimum(truth.min(axis=-1), np.minimum(W - 1 - truth[..., 0], H - 1 - truth[..., 1]))
    whole = margin > RADIUS + 1
    assert track.valid[whole].all()
    assert err[whole].max() < 0.2
    # A marker partly cut by the edge stays roughly right; a mostly cut one is lost.
    assert err[track.valid].max() < 1.0
    assert not track.valid[margin < RADIUS / 2 - 1].any()


@settings(max_examples=6, deadline=None)
@given(dx=st.floats(-3.0, 3.0), dy=st.floats(-3.0, 3.0))
def test_any_subpixel_shift_is_recovered(dx, dy):
    base = grid(rows=7, cols=9, x0=35.0, y0=30.0)
    frames = np.stack([render(base), render(base + [dx, dy], seed=1)])
    track = track_markers(frames, reference_index=0)
    assert track.valid.all()
    assert np.abs(track.displacement()[1] - [dx, dy]).max() < 0.2


def test_middle_reference_tracks_backward_too():
    frames, offsets = shifted_video((0.8, -0.5), n_frames=9)
    track = track_markers(frames, reference_index=4)
    assert track.valid.all()
    err = np.linalg.norm(track.displacement() - (offsets - offsets[4])[:, None, :], axis=-1)
    assert err.max() < 0.2


def test_vanishing_marker_is_lost_then_reacquired():
    base = grid(rows=7, cols=9, x0=35.0, y0=30.0)
    gone = 31  # a central marker
    frames = []
    for t in range(12):
        pts = base + [0.5 * t, 0.3 * t]
        if 4 <= t < 8:
            pts = np.delete(pts, gone, axis=0)
        frames.append(render(pts, seed=t))
    track = track_markers(np.stack(frames), reference_index=0)
    idx = int(np.linalg.norm(track.reference_positions - base[gone], axis=1).argmin())
    assert not track.valid[4:8, idx].any()
    assert track.valid[8:, idx].all()  # back once the dot reappears
    others = np.delete(np.arange(track.n_markers), idx)
    assert track.valid[:, others].all()
    # While lost, the estimate follows the neighbours' motion.
    truth = base[gone] + np.array([0.5, 0.3]) * np.arange(12)[:, None]
    assert np.abs(track.positions[:, idx] - truth).max() < 0.5


def test_depth_proxy_rises_where_shading_changes():
    base = grid(rows=7, cols=9, x0=35.0, y0=30.0)
    f0, f1 = render(base), render(base, seed=1)
    # Brighten a patch of the gel (as an indentation would change its shading) around one marker.
    yy, xx = np.mgrid[0:H, 0:W]
    bump = 40 * np.exp(-((xx - base[31, 0]) ** 2 + (yy - base[31, 1]) ** 2) / (2 * 20.0**2))
    f1 = np.clip(f1.astype(np.float32) + bump[..., None], 0, 255).astype(np.uint8)
    track = track_markers(np.stack([f0, f1]), reference_index=0)
    i = int(np.linalg.norm(track.reference_positions - base[31], axis=1).argmin())
    assert track.depth.dtype == np.float32 and track.depth.shape == (2, 63)
    assert np.abs(track.depth[0]).max() < 1e-6
    assert track.depth[1, i] > 0.1
    assert np.median(track.depth[1]) < 0.03


# --- outputs for models ----------------------------------------------------------------------


def toy_track(n_frames: int = 3) -> MarkerTrack:
    ref = grid(rows=3, cols=4, x0=100.0, y0=90.0).astype(np.float32)
    disp = np.zeros((n_frames, len(ref), 2), np.float32)
    disp[:, :, 0] = np.arange(n_frames)[:, None]
    valid = np.ones((n_frames, len(ref)), bool)
    valid[1, 5] = False
    return MarkerTrack(
        positions=ref[None] + disp,
        valid=valid,
        depth=np.full((n_frames, len(ref)), 0.05, np.float32),
        reference_positions=ref,
        reference_index=0,
        frame_size=(H, W),
        spacing=SPACING,
        diameter=2 * RADIUS,
    )


def test_cloud_units():
    track = toy_track()
    cloud = track.to_cloud()
    assert cloud.shape == (3, 12, 3) and cloud.dtype == np.float32
    centre = np.array([(W - 1) / 2, (H - 1) / 2])
    np.testing.assert_allclose(cloud[..., :2], (track.positions - centre) / (W / 2), atol=1e-6)
    np.testing.assert_allclose(cloud[..., 2], 0.05)
    mm = track.to_cloud(normalise=False, mm_per_px=0.1)
    np.testing.assert_allclose(mm[..., :2], (track.positions - centre) * 0.1, atol=1e-5)


def test_marker_sequences_fixed_count_order_and_padding():
    track = toy_track()
    seq = marker_sequences(track, 6)
    assert seq.shape == (3, 6, 3)
    idx = select_markers(track, 6)
    # Kept: the 6 markers nearest the image centre, listed row-major.
    centre = np.array([(W - 1) / 2, (H - 1) / 2])
    dist = np.linalg.norm(track.reference_positions - centre, axis=1)
    assert sorted(idx.tolist()) == sorted(np.argsort(dist, kind="stable")[:6].tolist())
    assert order_markers(track.reference_positions[idx]).tolist() == list(range(6))
    np.testing.assert_allclose(seq, track.to_cloud()[:, idx])

    padded = marker_sequences(track, 20)
    assert padded.shape == (3, 20, 3)
    assert (padded[:, 12:] == 0).all()


# --- recordings, cache, figure ---------------------------------------------------------------


def write_avi(path: Path, frames: np.ndarray) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (W, H))
    if not writer.isOpened():
        pytest.skip("no MJPG encoder in this OpenCV build")
    for f in frames:
        writer.write(f)
    writer.release()


class Rec:
    def __init__(self, path: Path):
        self.path = path


def test_track_recordings_caches_per_video(tmp_path, monkeypatch):
    frames, _ = shifted_video((0.5, 0.25), n_frames=14)
    video = tmp_path / "obj" / "exp_num_1" / "camera_0.avi"
    video.parent.mkdir(parents=True)
    write_avi(video, frames)
    monkeypatch.setenv("SLIPSENSE_CACHE", str(tmp_path / "cache"))

    (first,) = track_recordings([Rec(video)], progress=False)
    files = list((tmp_path / "cache" / "markers").glob("*.npz"))
    assert len(files) == 1 and files[0].name.startswith("obj-exp_num_1-camera_0-")
    assert first.n_markers == 63 and first.reference_index == 10

    calls = []
    real = M.track_recording
    monkeypatch.setattr(M, "track_recording", lambda *a, **k: calls.append(a) or real(*a, **k))
    (again,) = track_recordings([video], progress=False)  # plain paths work too
    assert calls == []  # served from the cache
    np.testing.assert_array_equal(again.positions, first.positions)
    np.testing.assert_array_equal(again.valid, first.valid)
    assert again.frame_size == first.frame_size and again.spacing == pytest.approx(first.spacing)

    track_recordings([video], progress=False, fb_threshold=0.5)  # other parameters: new entry
    assert len(calls) == 1
    st_ = video.stat()
    os.utime(video, ns=(st_.st_atime_ns, st_.st_mtime_ns + 10**9))  # edited video: recomputed
    track_recordings([video], progress=False)
    assert len(calls) == 2
    assert len(list((tmp_path / "cache" / "markers").glob("*.npz"))) == 3

    files = sorted((tmp_path / "cache" / "markers").glob("*.npz"))
    files[0].write_bytes(b"garbage")  # a damaged cache file is recomputed, not fatal
    track_recordings([video], progress=False)
    track_recordings([video], progress=False, fb_threshold=0.5)


def test_track_recordings_reports_missing_video(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        track_recordings([tmp_path / "nope.avi"], progress=False, cache_dir=tmp_path)


# --- one real recording ------------------------------------------------------------------------


def real_video() -> Path:
    from slipsense.paths import gelsight_recordings

    return gelsight_recordings() / "cellotape" / "exp_num_2" / "camera_0.avi"


@pytest.mark.skipif(not real_video().is_file(), reason="shared GelSight recordings not available")
def test_real_recording():
    from slipsense.recordings.markers import track_recording

    track = track_recording(real_video())
    assert track.n_markers >= 60
    assert track.n_frames == 450
    # Frames 10-60 are before the grasp: markers barely move and almost none is lost.
    assert 1.0 - track.valid[10:60].mean() < 0.02
    assert np.median(np.abs(track.displacement()[10:60])) < 1.0
    assert np.isfinite(track.depth).all() and (track.depth >= 0).all()


def _uniform_track(rows: int, cols: int, spacing: float, shift=(3.0, -2.0), n_frames: int = 4) -> MarkerTrack:
    """A track of a ``rows x cols`` pad whose every marker moves by ``shift`` px from frame 1 on."""
    ref = grid(rows, cols, x0=spacing / 2, y0=spacing / 2)
    ref[:, 0] *= spacing / SPACING
    ref[:, 1] *= spacing / SPACING
    pos = np.repeat(ref[None], n_frames, 0).astype(np.float32)
    pos[1:] += np.asarray(shift, np.float32)
    depth = np.zeros((n_frames, len(ref)), np.float32)
    depth[1:] = 0.25
    return MarkerTrack(pos, np.ones(pos.shape[:2], bool), depth, ref.astype(np.float32), 0, (H, W), spacing, 8.0)


def test_grid_sequences_give_one_layout_for_pads_of_any_marker_count():
    from slipsense.recordings.markers import grid_sequences

    fine, coarse = _uniform_track(7, 10, 32.0), _uniform_track(5, 7, 44.0)
    a, b = grid_sequences(fine, (3, 4)), grid_sequences(coarse, (3, 4))
    assert a.shape == b.shape == (4, 12, 3) and a.dtype == np.float32
    tiles = np.meshgrid((np.arange(4) + 0.5) * W / 4 - 0.5, (np.arange(3) + 0.5) * H / 3 - 0.5)
    centres = np.stack(tiles, -1).reshape(-1, 2)  # tile centres in pixel-centre coordinates
    expect_rest = (centres - [(W - 1) / 2, (H - 1) / 2]) * M.DEFAULT_MM_PER_PX
    for seq in (a, b):  # at rest the virtual markers sit at the tile centres, whatever the pad
        np.testing.assert_allclose(seq[0, :, :2], expect_rest, atol=1e-4)
        np.testing.assert_allclose(
            seq[1:, :, :2] - seq[0, :, :2],
            np.broadcast_to(np.array([3.0, -2.0]) * M.DEFAULT_MM_PER_PX, (3, 12, 2)),
            atol=1e-5,
        )
        np.testing.assert_allclose(seq[:, :, 2], np.repeat([[0.0], [0.25], [0.25], [0.25]], 12, 1), atol=1e-6)
    local = _uniform_track(7, 10, 32.0, shift=(0.0, 0.0))
    local.positions[1:, 0] += 5.0  # only the top-left marker moves: only virtual markers near it follow
    moved = np.abs(grid_sequences(local, (3, 4))[1, :, :2] - grid_sequences(local, (3, 4))[0, :, :2]).sum(1)
    assert moved[0] > 0 and (moved[[3, 8, 11]] == 0).all()
    with pytest.raises(ValueError, match="grid"):
        grid_sequences(fine, (0, 4))
    with pytest.raises(ValueError, match="neighbours"):
        grid_sequences(fine, (3, 4), neighbours=0)
