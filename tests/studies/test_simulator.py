"""Binocular-sensor simulator: shapes, seeding, labels, the physics of each pattern, the npz format."""

from __future__ import annotations

import numpy as np
import pytest

from slipsense.errors import ConfigError, InputError
from studies.stnet.simulator import (
    OBJECTS,
    PATTERNS,
    SimConfig,
    displacement_field,
    load_marker_npz,
    make_dataset,
    plot_patterns,
    rest_grid,
    save_dataset,
    simulate_sequence,
)

QUIET = dict(noise_mm=(0.0, 0.0), pixel_noise_px=0.0)  # isolate the deformation model


def _sim(obj, pattern, seed, **kw):
    cfg = SimConfig(seq_len=40, **kw)
    seq, info = simulate_sequence(obj, pattern, np.random.default_rng(seed), cfg, return_info=True)
    return cfg, seq, info, displacement_field(seq, rest_grid(cfg))


def _near_contact(cfg, info, t, within=3.0):
    """Markers outside the contact at frame t, at most ``within`` mm from a contact marker."""
    X = rest_grid(cfg)[:, :2]
    c = info["contact"][t]
    dist = np.linalg.norm(X[:, None] - X[None, c], axis=-1).min(axis=1)
    return (~c) & (dist <= within), X - info["centre"][t]


# ----------------------------------------------------------------------------- shapes, seeds, labels


def test_rest_grid_matches_the_paper_sensor():
    cfg = SimConfig()
    X = rest_grid(cfg)
    assert X.shape == (552, 3) and cfg.n_markers == 552
    assert np.all(X[:, 2] == 0)
    np.testing.assert_allclose(X[:, 0].max() - X[:, 0].min(), 22.0)
    np.testing.assert_allclose(X[:, 1].max() - X[:, 1].min(), 21.0)
    assert X[1, 0] > X[0, 0] and X[1, 1] == X[0, 1]  # x fastest


def test_dataset_shapes_labels_and_groups():
    cfg = SimConfig(objects=("cherry_tomato", "pen"), n_sequences=1, seq_len=14)
    ds = make_dataset(cfg, progress=False)
    n_seq = 2 * len(PATTERNS)
    assert ds.x.shape == (n_seq * 3, 12, 552, 3) and ds.x.dtype == np.float32
    assert ds.y.dtype == np.int64 and ds.groups.dtype == np.int64
    assert np.isfinite(ds.x).all()
    slip = np.array(PATTERNS)[ds.pattern] == "slipping"
    np.testing.assert_array_equal(ds.y, slip.astype(int))  # the paper's rule: by motion pattern
    assert len(np.unique(ds.groups)) == n_seq
    for g in np.unique(ds.groups):  # one sequence: one pattern, one object, overlapping windows
        sel = ds.groups == g
        assert len(np.unique(ds.pattern[sel])) == 1 and len(np.unique(ds.object[sel])) == 1
        w = ds.x[sel]
        np.testing.assert_array_equal(w[0, 1:], w[1, :-1])  # stride 1
    assert set(np.array(OBJECTS)[ds.object]) == {"cherry_tomato", "pen"}


def test_seeded_and_reproducible():
    kw = dict(objects=("earphone",), patterns=("slipping", "pressing"), n_sequences=1, seq_len=(12, 16))
    a = make_dataset(SimConfig(seed=3, **kw), progress=False)
    b = make_dataset(SimConfig(seed=3, **kw), progress=False)
    c = make_dataset(SimConfig(seed=4, **kw), progress=False)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.y, b.y)
    assert a.x.shape != c.x.shape or not np.array_equal(a.x, c.x)
    # a sequence does not depend on which other objects are simulated
    d = make_dataset(SimConfig(seed=3, **{**kw, "objects": ("cherry_tomato", "earphone")}), progress=False)
    np.testing.assert_array_equal(d.x[d.object == OBJECTS.index("earphone")], a.x)


def test_gross_slip_label_rule():
    cfg = SimConfig(
        objects=("cherry_tomato",),
        patterns=("slipping",),
        n_sequences=2,
        seq_len=30,
        partial_slip_s=(0.9, 1.0),
        label_rule="gross_slip",
    )
    ds = make_dataset(cfg, progress=False)
    for g in np.unique(ds.groups):
        y = ds.y[ds.groups == g]
        assert y[0] == 0 and y[-1] == 1  # onset at 0.9-1 s = frame 18-20; windows end at 11 .. 29
        assert np.all(np.diff(y) >= 0)


def test_config_errors():
    with pytest.raises(ConfigError, match="indent_mm"):
        SimConfig(indent_mm=(1.0, 0.5))
    with pytest.raises(ConfigError, match="objects"):
        SimConfig(objects=("banana",))
    with pytest.raises(ConfigError, match="window"):
        SimConfig(seq_len=8)
    with pytest.raises(ConfigError, match="unknown pattern"):
        simulate_sequence("pen", "twisting", np.random.default_rng(0), SimConfig())


# ----------------------------------------------------------------------------- physics of each pattern


def test_stationary_without_object_is_just_noise():
    cfg, seq, info, d = _sim("pen", "stationary", 0, p_empty=1.0, pixel_noise_px=0.0)
    assert not info["contact"].any()
    sigma = info["noise_mm"]
    assert 0.5 * sigma < d.std() < 1.5 * sigma
    assert np.abs(d).max() < 8 * sigma


def test_stationary_with_object_does_not_move():
    cfg, seq, info, d = _sim("cherry_tomato", "stationary", 1, p_empty=0.0, pixel_noise_px=0.0)
    assert info["contact"].all(axis=0).any()
    assert d[..., 2].min() < -0.3  # held indentation
    sigma = info["noise_mm"]
    wobble = seq - seq.mean(axis=0)
    assert wobble.std() < 1.5 * sigma  # only vibration changes from frame to frame


@pytest.mark.parametrize("obj", ["cherry_tomato", "earphone"])
def test_pressing_indents_and_pushes_outwards(obj):
    cfg, seq, info, d = _sim(obj, "pressing", 2, **QUIET)
    assert np.ptp(info["depth"]) > 0.1  # dynamic press
    t = int(np.argmax(info["depth"]))
    inside = info["contact"][t]
    assert d[t, inside, 2].mean() < -0.1  # indentation is negative z
    assert (d[t, inside, 2] <= 0).all()
    near, rel = _near_contact(cfg, info, t)
    radial = np.einsum("ij,ij->i", d[t, near, :2], rel[near] / np.linalg.norm(rel[near], axis=1, keepdims=True))
    assert radial.mean() > 0.01 and (radial > 0).mean() > 0.8
    # deeper press, larger dent
    t_lo = int(np.argmin(info["depth"]))
    assert d[t, :, 2].sum() < d[t_lo, :, 2].sum()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rolling_gives_symmetric_opposite_side_lobes(seed):
    cfg, seq, info, d = _sim("cherry_tomato", "rolling", seed, **QUIET)
    e = info["direction"]
    perp = np.array([-e[1], e[0]])
    assert np.linalg.norm(info["centre"][-1] - info["centre"][0]) > 2.0  # the contact travels
    for t in (5, 20, 35):
        near, rel = _near_contact(cfg, info, t)
        beside = near & (np.abs(rel @ e) < 2.5)
        left = d[t, beside & (rel @ perp > 0), :2] @ perp
        right = d[t, beside & (rel @ perp < 0), :2] @ perp
        assert left.mean() > 0.03 and right.mean() < -0.03  # opposite, pointing away from the track
        assert 0.7 < left.mean() / -right.mean() < 1.4  # and symmetric


@pytest.mark.parametrize("obj, seed", [("cherry_tomato", 0), ("cherry_tomato", 1), ("earphone", 2)])
def test_slipping_is_asymmetric_and_spreads_inwards(obj, seed):
    cfg, seq, info, d = _sim(obj, "slipping", seed, **QUIET)
    g = info["gross_slip_frame"]
    assert 0 < g < len(seq) - 1
    contact = info["contact"].sum(1)
    stick = info["stick"].sum(1) / np.maximum(contact, 1)
    assert stick[0] > 0.5 and np.all(np.diff(stick[: g + 1]) <= 1e-12) and stick[g:].max() == 0
    slipping = (info["contact"] & ~info["stick"]).sum(1)
    assert slipping[g] > slipping[0]  # slip region grows from the contact edge inwards
    # the stick region is the high-pressure core: its markers are deeper than the slipping ones
    t = max(g // 2, 1)
    st_, sl_ = info["stick"][t], info["contact"][t] & ~info["stick"][t]
    if st_.any() and sl_.any():
        assert d[t, st_, 2].mean() < d[t, sl_, 2].mean()
    e = info["direction"]
    t = len(seq) - 1
    near, rel = _near_contact(cfg, info, t)
    mag = np.linalg.norm(d[t, :, :2], axis=1)
    trail, lead = near & (rel @ e < 0), near & (rel @ e > 0)
    assert mag[trail].mean() > 1.3 * mag[lead].mean()  # tension (trailing) side moves more
    out = ~info["contact"][t]
    moving = mag > 0.05
    assert (moving & out & (rel @ e < 0)).sum() > (moving & out & (rel @ e > 0)).sum()  # ... and more markers
    # the tangential displacement follows the motion direction
    assert (d[t, info["contact"][t], :2] @ e).mean() > 0.1


def test_every_object_and_pattern_runs_with_stereo_noise():
    cfg = SimConfig(seq_len=12)
    for i, obj in enumerate(OBJECTS):
        for j, pattern in enumerate(PATTERNS):
            seq = simulate_sequence(obj, pattern, np.random.default_rng([i, j]), cfg)
            assert seq.shape == (12, 552, 3) and seq.dtype == np.float32 and np.isfinite(seq).all()
            assert np.abs(seq[..., 2]).max() < 3.0


def test_displacement_field_checks_shapes():
    X = rest_grid(SimConfig())
    np.testing.assert_allclose(displacement_field(X[None] + 1.0, X), 1.0)
    with pytest.raises(InputError, match=r"\(T, M, 3\)"):
        displacement_field(X, X)
    with pytest.raises(InputError, match="rest"):
        displacement_field(X[None], X[:10])


# ----------------------------------------------------------------------------- npz format


@pytest.fixture(scope="module")
def tiny_ds():
    return make_dataset(SimConfig(objects=("screw",), n_sequences=1, seq_len=13), progress=False)


def test_save_load_round_trip(tiny_ds, tmp_path):
    path = save_dataset(tiny_ds, tmp_path / "sim.npz")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sim.npz"]  # no temporary left behind
    ds = load_marker_npz(path)
    np.testing.assert_array_equal(ds.x, tiny_ds.x)
    np.testing.assert_array_equal(ds.y, tiny_ds.y)
    np.testing.assert_array_equal(ds.groups, tiny_ds.groups)
    np.testing.assert_array_equal(ds.pattern, tiny_ds.pattern)
    assert ds.pattern_names == PATTERNS and ds.object_names == OBJECTS and ds.fps == 20.0
    with pytest.raises(InputError, match=".npz"):
        save_dataset(tiny_ds, tmp_path / "sim.npy")


def _write(tmp_path, name="m.npz", **arrays):
    path = tmp_path / name
    np.savez(path, **arrays)
    return path


def _x(n=3, t=4, m=5):
    return np.zeros((n, t, m, 3), np.float32)


def test_minimal_user_file(tmp_path):
    ds = load_marker_npz(_write(tmp_path, x=_x(), y=np.array([0, 1, 1])))
    np.testing.assert_array_equal(ds.groups, [0, 1, 2])  # one group per sample by default
    assert ds.pattern is None
    ds = load_marker_npz(
        _write(
            tmp_path,
            x=_x(),
            y=np.array([0, 1, 1]),
            groups=np.array(["a", "b", "a"]),
            pattern=np.array(["slipping", "rolling", "slipping"]),
        )
    )
    np.testing.assert_array_equal(ds.groups, [0, 1, 0])
    assert [ds.pattern_names[i] for i in ds.pattern] == ["slipping", "rolling", "slipping"]
    ds = load_marker_npz(_write(tmp_path, x=_x()), require_labels=False)
    assert ds.y is None


@pytest.mark.parametrize(
    "arrays, match",
    [
        (dict(y=np.zeros(3)), "missing key 'x'"),
        (dict(x=_x()), "missing key 'y'"),
        (dict(x=np.zeros((3, 4, 5)), y=np.zeros(3)), r"expected \(N, T, M, 3\)"),
        (dict(x=np.zeros((3, 4, 5, 2)), y=np.zeros(3)), r"expected \(N, T, M, 3\)"),
        (dict(x=_x(), y=np.array([0, 1, 2])), "0 .no slip. or 1"),
        (dict(x=_x(), y=np.array([0, 1])), "one value per sample"),
        (dict(x=_x(), y=np.array([0, 1, 1]), groups=np.arange(4)), "groups"),
        (dict(x=_x(), y=np.array([0, 1, 1]), pattern=np.array([0, 1, 9])), "pattern indices"),
        (dict(x=np.array(["a"] * 12).reshape(1, 1, 4, 3), y=np.zeros(1)), "dtype"),
    ],
)
def test_loader_errors_name_the_file(tmp_path, arrays, match):
    path = _write(tmp_path, **arrays)
    with pytest.raises(InputError, match=match) as exc:
        load_marker_npz(path)
    assert str(path) in str(exc.value)


def test_loader_reports_where_nan_is(tmp_path):
    x = _x()
    x[2, 3, 1, 0] = np.nan
    x[2, 3, 4, 2] = np.inf
    with pytest.raises(InputError, match="2 non-finite.*NaN at sample 2, frame 3, marker 1"):
        load_marker_npz(_write(tmp_path, x=x, y=np.zeros(3)))


def test_unreadable_and_missing_files(tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(InputError, match="not a readable"):
        load_marker_npz(bad)
    with pytest.raises(InputError, match="no such file"):
        load_marker_npz(tmp_path / "nope.npz")


def test_figures_are_written(tmp_path):
    paths = plot_patterns(SimConfig(seq_len=12, pixel_noise_px=0.0), tmp_path, frames=2)
    assert [p.name for p in paths] == [f"sim_{p}.png" for p in PATTERNS] + ["sim_objects.png"]
    for p in paths:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
