"""The configuration tree (slipsense/config_tree.py): every configs/*.yaml is valid, layers override in
order, the resolved tree is stored whole in checkpoints and repeats a run, bad files get one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from slipsense.checkpoint import read_info
from slipsense.cli import app
from slipsense.errors import ConfigError, InputError
from slipsense.config_tree import empty_tree, given, load_tree, merge, parse_sets

CONFIGS = sorted((Path(__file__).resolve().parent.parent / "configs").glob("*.yaml"))
runner = CliRunner()


def test_the_shipped_configs_exist():
    names = {p.stem for p in CONFIGS}
    assert {"motionnet", "vivit-paper", "vivit-quick", "stnet-paper"} <= names


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.stem)
def test_every_shipped_config_builds(path):
    """Each file names a registered model, settings it takes and training keys that exist; the run it
    describes, written as a tree (what checkpoints keep), is the same run again."""
    import torch

    from slipsense.training.clips import build_model
    from slipsense.training.settings import RunConfig
    from slipsense.training.grasps import GraspTrainConfig

    run = RunConfig.from_tree(load_tree(path))  # a grasp detector's model is built there
    assert RunConfig.from_tree(run.to_tree()) == run
    if isinstance(run.train, GraspTrainConfig):
        return
    with torch.device("meta"):  # no weights allocated (the paper STNet is 0.5 GB)
        model = build_model(run.name, run.preset, run.settings, {"frames": run.data.frames})
    assert model.model_name == run.name


def test_layers_win_in_order_and_bare_keys_go_to_model():
    tree = merge(
        {"model": {"name": "vivit", "dim": 8}, "train": {"epochs": 75}},
        given({"train": {"epochs": None, "lr": 0.1}}),  # an option not given (None) changes nothing
        parse_sets(["train.epochs=3", "dim=16", "model.patch_size=[20,20]", "data.split=clips", "x.y=z"]),
    )
    assert tree["train"] == {"epochs": 3, "lr": 0.1}
    assert tree["model"] == {"name": "vivit", "dim": 16, "patch_size": [20, 20], "x.y": "z"}
    assert tree["data"] == {"split": "clips"}
    with pytest.raises(ConfigError, match="section.key=value"):
        parse_sets(["novalue"])


@pytest.mark.parametrize(
    "text, problem",
    [
        ("model: [1, 2]\n", "must map names"),
        ("optimiser: {lr: 1}\n", "unknown section 'optimiser'"),
        ("- a\n- b\n", "expected sections"),
        ("model: {name: vivit\n", "not valid YAML"),
        ("!!python/object/apply:os.system ['echo hi']\n", "not valid YAML"),  # safe_load: no objects
    ],
)
def test_bad_files_name_the_file(tmp_path, text, problem):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(InputError, match=problem) as info:
        load_tree(path)
    assert "bad.yaml" in str(info.value)


def _markers(path: Path) -> Path:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(24, 4, 5, 3)).astype(np.float32)
    np.savez(path, x=x, y=np.arange(24) % 2, groups=np.arange(24) // 2)
    return path


TINY_TREE = """model:
  name: temnet
  d_model: 8
  heads: 2
  blocks: 1
  ff_dim: 8
  head_hidden: 0
data:
  test_fraction: 0.25
train:
  epochs: 3
  batch_size: 4
  lr: 0.001
"""


def test_train_from_config_stores_the_whole_tree_and_repeats(tmp_path, cache, one_thread):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(TINY_TREE)
    data = _markers(tmp_path / "m.npz")
    out = tmp_path / "run"
    args = ["train", "--config", str(cfg), "--markers", str(data), "--out", str(out), "--no-progress"]
    res = runner.invoke(app, [*args, "--epochs", "2", "--set", "train.lr=0.01", "--set", "data.test_fraction=0.5"])
    assert res.exit_code == 0, res.output
    tree = read_info(out / "last.safetensors")["config"]
    assert tree["model"]["name"] == "temnet" and tree["model"]["d_model"] == 8
    assert tree["train"]["epochs"] == 2 and tree["train"]["lr"] == 0.01 and tree["train"]["batch_size"] == 4
    assert tree["train"]["step_size"] == 1000  # TemNet's paper setting, stored although nobody set it
    assert tree["data"]["test_fraction"] == 0.5 and tree["data"]["markers"].endswith("m.npz")
    again = tmp_path / "again"
    res = runner.invoke(app, ["train", "--config", str(out / "config.yaml"), "--out", str(again), "--no-progress"])
    assert res.exit_code == 0, res.output
    assert read_info(again / "last.safetensors")["config"] == tree
    assert (out / "split.json").read_text() == (again / "split.json").read_text()


@pytest.mark.parametrize(
    "tree, word",
    [
        ("model: {name: temnet}\ntrain: {epochz: 3}\n", "train.epochz is not a setting"),
        ("model: {name: temnet}\ndata: {frame: 3}\n", "data.frame is not a setting"),
        ("model: {name: nonet}\n", "unknown model 'nonet'"),
    ],
)
def test_bad_config_is_one_line_exit_2(tmp_path, cache, tree, word):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text(tree)
    res = runner.invoke(
        app,
        [
            "train",
            "--config",
            str(cfg),
            "--markers",
            str(_markers(tmp_path / "m.npz")),
            "--out",
            str(tmp_path / "run"),
            "--no-progress",
        ],
    )
    assert res.exit_code == 2 and word in res.output and "Traceback" not in res.output
    assert len(res.output.strip().splitlines()) == 1


def test_grasp_train_from_config_stores_the_tree(tmp_path, grasp_recordings, cache, one_thread):
    cfg = tmp_path / "g.yaml"
    cfg.write_text(
        "model: {name: motionnet, width: 4, features: 8, temporal: 8, lags: [1, 5, 10], "
        "dilations: [1, 2, 4], image_size: [12, 16]}\n"
        "train: {epochs: 3, chunk: 16, negatives: 1, hard_negatives: 1, inner_folds: 0}\n"
    )
    out = tmp_path / "det"
    res = runner.invoke(
        app,
        [
            "train",
            "--config",
            str(cfg),
            "--recordings",
            str(grasp_recordings),
            "--out",
            str(out),
            "--set",
            "epochs=2",
            "--set",
            "model.width=3",
            "--no-progress",
            "--threads",
            "1",
        ],
    )
    assert res.exit_code == 0, res.output
    info = read_info(out / "detector.safetensors")
    tree = info["config"]
    assert tree["train"]["epochs"] == 2 and tree["model"]["width"] == 3 and tree["model"]["name"] == "motionnet"
    assert info["model_config"]["width"] == 3 and info["train_config"]["epochs"] == 2
    assert load_tree(out / "config.yaml")["model"]["width"] == 3  # repeats the run with --config


def test_empty_tree_has_the_three_sections():
    assert set(empty_tree()) == {"model", "data", "train"}


def test_set_null_clears_and_yaml_spellings_are_typed(monkeypatch, tmp_path):
    from slipsense.paths import DATA_ENV
    from slipsense.training.clips import TrainConfig
    from slipsense.training.settings import RunConfig

    tree = merge({"data": {"fold": 2}}, parse_sets(["data.fold=null"]))
    assert tree["data"]["fold"] is None
    monkeypatch.setenv(DATA_ENV, str(tmp_path))
    tree = {"model": {"name": "vivit"}, "data": {"recordings": "$SLIPSENSE_DATA/gelsight-slip", "frames": None}}
    run = RunConfig.from_tree(tree)
    assert run.data.recordings == tmp_path / "gelsight-slip" and run.data.frames == 5  # as checkpoints write paths
    assert TrainConfig.from_dict({"lr": "3e-4"}).lr == 3e-4  # YAML reads 3e-4 as a string
    with pytest.raises(ConfigError, match="epochs must be a whole number"):
        TrainConfig.from_dict({"epochs": "10"})


def test_a_bare_training_key_goes_to_train_and_grasp_models_refuse_clip_settings():
    from slipsense.training.settings import RunConfig

    run = RunConfig.from_tree({"model": {"name": "motionnet", "width": 4, "epochs": 2}, "data": {"size": [12, 16]}})
    assert run.train.epochs == 2 and run.model == {"name": "motionnet", "width": 4, "image_size": [12, 16]}
    assert RunConfig.from_tree({"model": {"name": "temnet", "epochs": 2}}).train.epochs == 2
    with pytest.raises(ConfigError, match="frames, train.device only apply to clip models"):
        RunConfig.from_tree({"model": {"name": "motionnet"}, "data": {"frames": 5}, "train": {"device": "cpu"}})
    with pytest.raises(ConfigError, match="data.size must be"):
        RunConfig.from_tree({"model": {"name": "motionnet"}, "data": {"size": [12]}})


def test_the_run_and_its_tree_are_left_as_they_were_given(tmp_path):
    import copy
    import dataclasses

    from slipsense.errors import SlipsenseError
    from slipsense.training.recipe import RunConfig, cross_validate, fit

    tree = {
        "model": {"name": "motionnet", "width": 4},
        "data": {"recordings": str(tmp_path / "none"), "test_objects": "mug", "size": [12, 16]},
        "train": {"epochs": 1, "inner_folds": 0},
    }
    before = copy.deepcopy(tree)
    run = RunConfig.from_tree(tree)
    assert tree == before
    with pytest.raises(dataclasses.FrozenInstanceError):
        run.data = None
    same = copy.deepcopy(run)
    with pytest.raises(SlipsenseError):  # no recordings there: after the trainer has read the settings
        fit(run, tmp_path / "out", progress=False)
    assert run == same
    run = RunConfig.from_tree({**tree, "data": {k: v for k, v in tree["data"].items() if k != "test_objects"}})
    same = copy.deepcopy(run)
    with pytest.raises(SlipsenseError):
        cross_validate(run, tmp_path / "folds", 2, progress=False)
    assert run == same
