"""The model contract (slipsense.models.base), checked for every registered model: a new model is
covered by registering it (build -> forward shape -> streaming == full forward -> ONNX parity ->
checkpoint round trip)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import onnx_output
from slipsense.checkpoint import load_model, save_checkpoint
from slipsense.streaming.detector import SlipDetector
from slipsense.models import SlipModel, available, build, model_class, window_geometry

BUILT_IN = [name for name in available() if not name.startswith("test-")]


def _model(name: str) -> SlipModel:
    torch.manual_seed(0)
    model = build(name, **model_class(name).small_config()).eval()
    with torch.no_grad():  # move norms and biases off their initial values so parts must really agree
        g = torch.Generator().manual_seed(1)
        for p in model.parameters():
            p.add_(torch.randn(p.shape, generator=g) * 0.05)
    return model


#: What a checkpoint states for a model that fixes no frame size itself (ResNet3D): its training clips' size.
INFO = {"data": {"clip_spec": {"size": [60, 80]}}}


def _window_inputs(model: SlipModel, batch: int = 2, seed: int = 0):
    """(uint8 or float per-frame inputs (B, T, ...) for pushing, float model input (B, T, ...))."""
    geo = window_geometry(model, INFO)
    rng = np.random.default_rng(seed)
    if geo["kind"] == "video":
        frames = rng.integers(0, 256, (batch, geo["frames"], *geo["image_size"], 3), dtype=np.uint8)
        x = torch.from_numpy(np.moveaxis(frames, -1, 2).astype(np.float32) / 255.0)
        return frames, x
    clouds = rng.normal(0.0, 3.0, (batch, geo["frames"], geo["markers"], 3)).astype(np.float32)
    return clouds, torch.from_numpy(clouds)


def _grasp_input(model: SlipModel, frames: int = 40, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(1, model.sensors, frames, *model.image_size, generator=g)


@pytest.mark.parametrize("name", BUILT_IN)
def test_contract_build_and_forward_shape(name):
    model = _model(name)
    assert isinstance(model, SlipModel) and model.model_name == name
    assert model.input_kind in ("video", "markers", "grasp")
    rebuilt = build(name, **model.config())  # config() rebuilds the same network
    assert {k: v.shape for k, v in rebuilt.state_dict().items()} == {k: v.shape for k, v in model.state_dict().items()}
    with torch.no_grad():
        if model.input_kind == "grasp":
            out = model(_grasp_input(model))
            assert out.shape == (1, 40, 2)
        else:
            out = model(_window_inputs(model)[1])
            assert out.shape == (2, 2)
    assert torch.isfinite(out).all()


@pytest.mark.parametrize("name", BUILT_IN)
def test_contract_streaming_equals_full_forward(name):
    model = _model(name)
    if model.input_kind == "grasp":
        x = _grasp_input(model, frames=40)
        with torch.no_grad():
            full = torch.softmax(model(x)[0], dim=-1)[:, 1].numpy()
        stream = model.stream()
        gray = (x[0].numpy() * 255.0).round().astype(np.uint8)  # the stream takes uint8 grey frames
        pushed = np.array([stream.push_gray(gray[:, t]) for t in range(gray.shape[1])])
        with torch.no_grad():
            requant = torch.softmax(model(torch.from_numpy(gray[None]).float() / 255.0)[0], dim=-1)[:, 1].numpy()
        np.testing.assert_allclose(pushed, requant, atol=1e-5)
        assert np.abs(requant - full).max() < 0.05  # only the uint8 rounding differs
        return
    per_frame, x = _window_inputs(model, batch=1)
    det = SlipDetector(model, info=INFO)
    readings = [det.push(per_frame[0, t]) for t in range(per_frame.shape[1])]
    assert all(r.probability is None for r in readings[:-1])
    with torch.no_grad():
        full = float(torch.softmax(model(x), dim=-1)[0, 1])
    assert abs(readings[-1].probability - full) < 1e-5


@pytest.mark.parametrize("name", [n for n in BUILT_IN if model_class(n).input_kind == "grasp"])
def test_contract_chunk_logits_equal_whole_run_forward(name):
    """What grasp training computes (chunks of runs, shared frames encoded once) is the whole-run
    forward at those frames; frames before a run's start repeat frame 0."""
    model = _model(name)
    runs = [_grasp_input(model, frames=n, seed=n)[0] for n in (40, 25)]
    ends = [[39, 5, 20, 20], [24]]  # overlapping chunks, one reaching before the start, a repeat
    with torch.no_grad():
        got = model.chunk_logits(list(zip(runs, ends)), 8)
        full = [model(r[None])[0] for r in runs]
    assert got.shape == (5, 8, 2)
    k = 0
    for f, es in zip(full, ends):
        for e in es:
            frames = torch.arange(e - 7, e + 1)
            ok = frames >= 0
            torch.testing.assert_close(got[k][ok], f[frames[ok]], atol=1e-5, rtol=1e-5)
            k += 1


@pytest.mark.parametrize("name", BUILT_IN)
def test_contract_onnx_parity(name, tmp_path):
    from slipsense.streaming.export import export_onnx

    model = _model(name)
    result = export_onnx(model, tmp_path / "m.onnx", info=INFO)
    assert result.max_abs_diff and max(result.max_abs_diff.values()) <= 1e-4
    if model.input_kind == "grasp":
        assert set(result.paths) == {"model", "frame", "step"}
        x = _grasp_input(model, frames=57)  # another length than the export's example: frames are free
        with torch.no_grad():
            ref = model(x).numpy()
        assert np.abs(onnx_output(result.paths["model"], x) - ref).max() <= 1e-4
        return
    assert ("frame" in result.paths) == (model.streaming_parts()[0] is not None)


@pytest.mark.parametrize("name", BUILT_IN)
def test_contract_onnx_stream_equals_torch_stream(name, tmp_path):
    """Every model streams on ONNX Runtime with the probabilities it gives on PyTorch."""
    model = _model(name)
    sensors = getattr(model, "sensors", 1) if model.input_kind == "grasp" else 1
    dets = [
        SlipDetector(model, sensors=sensors, backend=b, onnx_dir=tmp_path / "onnx", info=INFO)
        for b in ("torch", "onnx")
    ]
    rng = np.random.default_rng(0)
    geo = dets[0].geometry
    if geo["kind"] == "markers":
        frames = [[rng.normal(0, 3, (geo["markers"], 3)).astype(np.float32)] * sensors for _ in range(8)]
    else:
        size = geo.get("image_size") or (24, 32)
        frames = [[rng.integers(0, 256, (*size, 3), dtype=np.uint8) for _ in range(sensors)] for _ in range(20)]
    got = np.array([[d.push(*f).probability for d in dets] for f in frames], dtype=float)
    answered = ~np.isnan(got[:, 0])
    assert answered.any() and np.array_equal(answered, ~np.isnan(got[:, 1]))
    np.testing.assert_allclose(got[answered, 1], got[answered, 0], atol=1e-5)


@pytest.mark.parametrize("name", BUILT_IN)
def test_contract_checkpoint_round_trip(name, tmp_path):
    model = _model(name)
    path = save_checkpoint(tmp_path / "m.safetensors", model, {"contract": True})
    loaded, info = load_model(path, expect_model=name)
    assert info["contract"] is True and type(loaded) is type(model)
    x = _grasp_input(model) if model.input_kind == "grasp" else _window_inputs(model)[1]
    with torch.no_grad():
        assert torch.equal(loaded(x), model(x))


def test_register_refuses_a_class_outside_the_contract():
    from slipsense.models import register

    with pytest.raises(TypeError, match="must subclass"):
        register("test-not-a-model")(torch.nn.Linear)


#: The places outside slipsense/models that ask how a model trains: the recipe's tables of trainers,
#: folds and evaluators and the run configuration's table of training settings, keyed by the model's
#: ``training_task``. Data is read by the model's own ``clip_reader``.
ASKS_HOW_IT_TRAINS = {"training/recipe.py": 2, "training/settings.py": 1, "evaluation/checkpoints.py": 1}


@pytest.mark.parametrize("name", BUILT_IN)
def test_contract_training_defaults_are_the_recipe_and_what_the_grasps_are(name):
    """What `train --model NAME` starts from: the class's recipe; for a grasp model also one sensor
    per one-camera grasp and no camera start-up for grasps labelled as a whole; from a checkpoint
    (train.init) no recipe and no model setting. A model without a recipe on the two-finger video
    recordings keeps the trainer's defaults."""
    from slipsense.models.base import RecordingsShape, settings_of

    cls = model_class(name)
    video, frames = RecordingsShape(cameras=2, per_grasp=False), RecordingsShape(cameras=1, per_grasp=True)
    assert cls.training_defaults(None) == cls.recipe and cls.training_defaults(video, init=True) == {}
    if "sensors" not in settings_of(cls):  # a clip model: its recipe alone
        assert cls.training_defaults(frames) == cls.recipe
        return
    assert cls.training_defaults(video) == cls.recipe  # 2 sensors: every grasp model's own default
    assert cls.training_defaults(frames) == {**cls.recipe, "model.sensors": 1, "startup": 0}
    assert cls.training_defaults(frames, init=True) == {"startup": 0}


def test_the_run_takes_the_recipe_under_what_the_tree_gives(grasp_recordings, tmp_path):
    """RunConfig.from_tree: the model's recipe and the data's cameras under every setting given;
    motionnet on two-finger videos is the run it always was; recordings that are not there leave the
    trainer's defaults (reading them names the problem)."""
    from slipsense.measures.pergrasp import STARTUP
    from slipsense.training.settings import RunConfig

    run = RunConfig.from_tree({"model": {"name": "motionnet"}, "data": {"recordings": str(grasp_recordings)}})
    assert run.model == {"name": "motionnet"} and run.train.startup == STARTUP and run.train.epochs == 20
    tree = {"model": {"name": "shear-retention", "gate": 1.0}, "train": {"inner_folds": 2}}
    run = RunConfig.from_tree({**tree, "data": {"recordings": str(grasp_recordings)}})
    assert run.model == {"name": "shear-retention", "softness": 0.0, "gate": 1.0}  # 2 cameras: its default
    assert run.train.epochs == 0 and run.train.inner_folds == 2 and run.train.startup == STARTUP
    assert run.train.choose == model_class("shear-retention").recipe["choose"]
    assert RunConfig.from_tree(run.to_tree()) == run
    run = RunConfig.from_tree({**tree, "data": {"recordings": str(tmp_path / "none")}})
    assert "sensors" not in run.model and run.train.epochs == 0


def test_nothing_outside_models_asks_the_kind():
    """Outside slipsense/models code never asks a model's kind or its name, and asks how it trains (``training_task``) only in those tables (:data:`ASKS_HOW_IT_TRAINS`)."""
    import ast
    from pathlib import Path

    import slipsense

    root = Path(slipsense.__file__).parent
    found, asks = [], {}
    for path in sorted(root.rglob("*.py")):
        if "models" in path.relative_to(root).parts[:1]:
            continue
        name = path.relative_to(root).as_posix()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and node.attr == "input_kind":
                found.append(f"{name}:{node.lineno} .input_kind")
            if isinstance(node, ast.Attribute) and node.attr == "training_task":
                asks[name] = asks.get(name, 0) + 1
            if isinstance(node, ast.Compare):  # a name may be printed or stored, not tested
                for part in ast.walk(node):
                    if isinstance(part, ast.Attribute) and part.attr == "model_name":
                        found.append(f"{name}:{node.lineno} compares .model_name")
    assert not found, found
    assert asks == ASKS_HOW_IT_TRAINS
