"""Markers on a grid: the layout is found, moves mirror and shift the displacement field exactly, and
the marker dataset's moved copies are fixed, labelled like their originals and absent off a grid."""

import numpy as np
import pytest
import torch

from slipsense.datasets import MarkerDataset
from slipsense.errors import ConfigError
from slipsense.sensors.marker_grid import GridMove, grid_layout


def lattice(rows=5, cols=6, pitch=1.0):
    xs, ys = np.meshgrid(np.arange(cols) * pitch, np.arange(rows) * pitch)
    return np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1) - [(cols - 1) / 2, (rows - 1) / 2, 0]


def test_the_grid_of_the_simulated_sensor_is_found_and_scattered_markers_have_none():
    from studies.stnet.sim_model import rest_grid
    from studies.stnet.simulator import SimConfig

    rest = rest_grid(SimConfig())
    assert grid_layout(rest) == (23, 24)
    assert grid_layout(rest + np.random.default_rng(0).normal(0, 0.05, rest.shape)) == (23, 24)  # tracking noise
    assert grid_layout(rest[np.random.default_rng(1).permutation(len(rest))]) is None
    assert grid_layout(np.random.default_rng(2).uniform(-10, 10, (32, 3))) is None
    assert grid_layout(rest[:-1]) is None  # one marker short of a lattice


def test_a_mirror_moves_a_marker_to_its_mirror_slot_and_turns_its_displacement():
    rest = lattice()
    w = np.repeat(rest[None], 2, axis=0)
    w[:, 6 + 1] += [0.3, 0.2, -0.1]  # row 1, column 1
    out = GridMove(flip_x=True).apply(w, rest, (5, 6))
    d = (out - rest).reshape(2, 5, 6, 3)
    assert np.allclose(d[:, 1, 4], [-0.3, 0.2, -0.1]) and np.abs(d).sum() == pytest.approx(2 * 0.6)
    out = GridMove(flip_y=True).apply(w, rest, (5, 6))
    assert np.allclose((out - rest).reshape(2, 5, 6, 3)[:, 3, 1], [0.3, -0.2, -0.1])
    both = GridMove(True, True).apply(GridMove(True, True).apply(w, rest, (5, 6)), rest, (5, 6))
    assert np.allclose(both, w)


def test_a_shift_moves_the_field_and_leaves_uncovered_gel_at_rest():
    rest = lattice()
    w = rest[None] + np.random.default_rng(0).normal(0, 0.1, (3, 30, 3))
    out = GridMove(shift_rows=1, shift_cols=-2).apply(w, rest, (5, 6))
    d, d0 = (out - rest).reshape(3, 5, 6, 3), (w - rest).reshape(3, 5, 6, 3)
    assert np.allclose(d[:, 1:, :4], d0[:, :4, 2:])
    assert np.all(d[:, 0] == 0) and np.all(d[:, :, 4:] == 0)
    assert np.all(GridMove(shift_rows=5).apply(w, rest, (5, 6)) == rest)  # moved off the gel
    assert out.dtype == w.dtype


def test_marker_copies_are_fixed_labelled_like_their_originals_and_only_on_a_grid():
    rest = lattice().astype(np.float32)
    rng = np.random.default_rng(0)
    x = rest[None, None] + rng.normal(0, 0.1, (4, 3, 30, 3)).astype(np.float32)
    y = np.array([0, 1, 1, 0])
    data = MarkerDataset(x, y, copies=3, seed=5)
    assert len(data) == 12 and data.grid == (5, 6)
    assert torch.equal(data[1][0], torch.from_numpy(x[1])) and int(data[1][1]) == 1
    for i in range(4, 12):
        a, b = data[i], data[i]
        assert torch.equal(a[0], b[0]) and int(a[1]) == y[i % 4]
    assert any(not torch.allclose(data[i][0], data[i % 4][0]) for i in range(4, 12))
    assert not torch.equal(data[6][0], MarkerDataset(x, y, copies=3, seed=6)[6][0])  # the seed draws the moves
    scattered = x[:, :, rng.permutation(30)]
    assert len(MarkerDataset(scattered, y, copies=3)) == 4  # no grid: no copies
    assert len(MarkerDataset(x, y)) == 4
    with pytest.raises(ConfigError, match="copies"):
        MarkerDataset(x, y, copies=0)


def _grid_npz(path, n=16, rows=3, cols=4):
    rest = lattice(rows, cols).astype(np.float32)
    x = rest[None, None] + np.random.default_rng(0).normal(0, 0.05, (n, 4, rows * cols, 3)).astype(np.float32)
    np.savez(path, x=x, y=np.arange(n) % 2, groups=np.arange(n) // 2)
    return path


@pytest.mark.parametrize("augment, copies, seen", [([], 3, 3), (["--no-augment"], 3, 1)])
def test_slipsense_train_sees_every_marker_window_with_its_copies(tmp_path, augment, copies, seen):
    import csv
    import json

    from conftest import TINY_TRAIN_ARGS
    from typer.testing import CliRunner

    from slipsense.cli import app

    path = _grid_npz(tmp_path / "m.npz")
    args = ["train", *TINY_TRAIN_ARGS, "--markers", str(path), "--out", str(tmp_path / "r"), "--epochs", "1"]
    result = CliRunner().invoke(app, [*args, "--set", f"data.marker_copies={copies}", *augment])
    assert result.exit_code == 0, result.output
    n_train = 16 - len(json.loads((tmp_path / "r" / "split.json").read_text())["test_indices"])
    rows = list(csv.DictReader((tmp_path / "r" / "metrics.csv").open()))
    assert int(rows[0]["train_items"]) == seen * n_train


def test_the_compact_preset_comes_with_its_training_settings():
    from slipsense.training.clips import paper_settings

    assert paper_settings("stnet")["lr"] == 1e-5 and paper_settings("stnet", "paper")["epochs"] == 100
    compact = paper_settings("temnet", "compact")
    assert (compact["lr"], compact["batch_size"], compact["epochs"]) == (1e-4, 32, 5)
    assert compact["weight_decay"] == 0.0  # the paper's, where the preset says nothing


def test_stnet_takes_its_reference_from_the_original_windows_only():
    from slipsense.models import build

    rest = lattice().astype(np.float32)
    x = np.repeat(rest[None, None], 6, axis=0).repeat(2, axis=1)
    x[:, :, 7, 2] -= 0.3  # every window starts pressed in at one marker: not where the gel rests
    model = build("stnet", frames=2, markers=30, d_model=8, heads=2, blocks=1, ff_dim=8, codec_channels=2, centred=True)
    model.prepare(MarkerDataset(x, np.zeros(6, int), copies=4))
    assert torch.allclose(model.reference, torch.from_numpy(x[0, 0]))  # the copies (shifted dents) left out


def test_resuming_with_other_marker_copies_is_refused(tmp_path):
    import json

    from slipsense.errors import InputError
    from slipsense.readers import check_same_split

    info = {"kind": "markers", "markers": "m.npz", "test_indices": [1, 2], "marker_copies": 4}
    (tmp_path / "split.json").write_text(json.dumps(info))
    check_same_split(tmp_path / "split.json", info)
    with pytest.raises(InputError, match="marker_copies"):
        check_same_split(tmp_path / "split.json", {**info, "marker_copies": 1})
    old = {k: v for k, v in info.items() if k != "marker_copies"}  # a run from before the copies
    (tmp_path / "split.json").write_text(json.dumps(old))
    check_same_split(tmp_path / "split.json", {**info, "marker_copies": 1})
    with pytest.raises(InputError, match="marker_copies"):
        check_same_split(tmp_path / "split.json", info)


@pytest.mark.parametrize("bad", ["0", "true", "2.5"])
def test_bad_marker_copies_are_one_line(tmp_path, bad):
    from conftest import TINY_TRAIN_ARGS
    from typer.testing import CliRunner

    from slipsense.cli import app

    path = _grid_npz(tmp_path / "m.npz")
    args = ["train", *TINY_TRAIN_ARGS, "--markers", str(path), "--out", str(tmp_path / "r"), "--no-augment"]
    result = CliRunner().invoke(app, [*args, "--set", f"data.marker_copies={bad}"])
    assert result.exit_code == 2 and "marker_copies" in result.output and "Traceback" not in result.output
