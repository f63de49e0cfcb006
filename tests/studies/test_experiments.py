"""Experiment commands (studies.experiments, studies.experiments.commands) on tiny in-memory data."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from conftest import REAL_RUN
from studies.experiments.all_models import match_windows, run_all_models
from studies.experiments.frames import run_frames
from studies.experiments.horizon import run_horizon
from studies.experiments.noise import run_noise
from studies.experiments.params import run_params
from studies.experiments.results import _data_line, collect_results
from studies.experiments.settings import EXPERIMENTS, Settings, TITLES
from studies.experiments.stnet import run_stnet
from studies.experiments.video_compare import run_video_compare
from slipsense.errors import ConfigError
from slipsense.recordings.clips import ClipSet

OBJECTS = ("apple", "fig", "kiwi", "pear", "plum")
SIZE = (16, 16)
MOMENT = 40


class MemorySource:
    """Stands in for the recordings: per object two runs x two cameras, run 1 slips, run 2 gives wiggles.

    Slip clips are brighter, so even a step of training can learn something; windows follow the
    clip rules (a slip clip ends ``horizon`` frames before the frame preceding the moment of slip).
    """

    fps = 25.0  # the rate its made-up recordings state

    def __init__(self, objects=OBJECTS):
        self.objects_ = list(objects)
        self.calls: list = []

    def describe(self):
        return {"recordings": "memory"}

    def objects(self, spec):
        return list(self.objects_)

    def _windows(self, frames, horizon, wiggle):
        out = []
        for obj in self.objects_:
            for exp in (1, 2):
                for cam in ("camera_0", "camera_2"):
                    if exp == 1:
                        out.append((obj, exp, cam, MOMENT - horizon - frames, 1))
                    else:
                        out += [(obj, exp, cam, 10 + 8 * k, 0) for k in range(wiggle)]
        return out

    def clips(self, spec):
        self.calls.append(("clips", spec.frames, spec.horizon))
        wins = self._windows(spec.frames, spec.horizon, spec.wiggle_per_video)
        rng = np.random.default_rng(spec.frames * 100 + spec.horizon)
        x = rng.integers(0, 120, (len(wins), spec.frames, *spec.size, 3), dtype=np.uint8)
        y = np.array([w[4] for w in wins], np.int64)
        x[y == 1] += 120
        meta = [
            {
                "object": o,
                "experiment": e,
                "camera": c,
                "start": s,
                "end": s + spec.frames - 1,
                "moment_of_slip": MOMENT if lab else None,
                "augmented": False,
            }
            for o, e, c, s, lab in wins
        ]
        return ClipSet(x, y, meta, spec)

    def markers(self, frames, n_markers, horizon=0, wiggle_per_video=2, seed=0):
        from slipsense.recordings.markers import marker_layout

        self.calls.append(("markers", frames, n_markers))
        n_markers, _ = marker_layout(n_markers)  # a layout: a count or ROWSxCOLS
        wins = self._windows(frames, horizon, wiggle_per_video)
        wins.append(("apple", 3, "camera_0", 5, 0))  # a window without a clip: must not be matched
        rng = np.random.default_rng(7)
        y = np.array([w[4] for w in wins], np.int64)
        x = rng.normal(size=(len(wins), frames, n_markers, 3)).astype(np.float32)
        x[y == 1] += 1.0
        self.marker_count = n_markers
        return {
            "x": x,
            "y": y,
            "groups": np.array([w[0] for w in wins]),
            "experiment": np.array([w[1] for w in wins]),
            "camera": np.array([w[2] for w in wins]),
            "start": np.array([w[3] for w in wins]),
        }

    def replay(self, detector, objects):
        """Per object a run that slips (its markers jump at frame 25, moment 30) and one that holds,
        both cameras, through the detector as the real source replays them."""
        from slipsense.evaluation.replay import RunTrace

        self.calls.append(("replay", tuple(objects)))
        rng = np.random.default_rng(3)
        runs = []
        for obj in objects:
            for exp, moment in ((1, 30), (2, None)):
                clouds = rng.normal(size=(2, 40, self.marker_count, 3)).astype(np.float32)
                if moment:
                    clouds[:, 25:] += 1.0
                p = detector.replay(*clouds).probability
                runs.append(RunTrace(obj, exp, moment is not None, moment, 40, p, fps=detector.sensor.fps))
        return runs


TINY_MODELS = {
    "resnet3d50": {"width": 2, "layers": [1, 1, 1, 1]},
    "stnet": {"d_model": 16, "heads": 2, "blocks": 1, "ff_dim": 16, "codec_channels": 2},
    "temnet": {"d_model": 16, "heads": 2, "blocks": 1, "ff_dim": 16},
}
SIM = {"markers_x": 4, "markers_y": 4, "seq_len": 13, "objects": ("pen", "tape")}


def tiny(out: Path, **kw) -> Settings:
    values = dict(
        out=out,
        size=SIZE,
        patch=(8, 8),
        epochs=2,
        batch_size=8,
        lr=1e-3,
        progress=False,
        model_overrides=TINY_MODELS,
        max_steps_per_epoch=2,
        command="slipsense experiment test",
    )
    values.update(kw)
    return Settings(**values)


def read_csv(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with open(path, newline="") as fh:
        r = csv.DictReader(fh)
        return list(r.fieldnames), list(r)


def check_outputs(out: Path, name: str, columns: list[str], n_rows: int) -> dict:
    for suffix in ("csv", "md", "png"):
        assert (out / f"{name}.{suffix}").stat().st_size > 0
    assert (out / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    cols, rows = read_csv(out / f"{name}.csv")
    assert cols == [*columns, "setting"]
    assert len(rows) == n_rows
    md = (out / f"{name}.md").read_text()
    assert "| " + " | ".join(columns) + " |" in md and f"![{name}]({name}.png)" in md
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["experiment"] == name and cfg["columns"] == [*columns, "setting"]
    assert cfg["seeds"] == {"seed": 0, "data_seed": 0}
    for key in ("platform", "cpu_count", "torch", "device"):
        assert key in cfg["machine"]
    assert cfg["settings"]["size"] == list(SIZE) and cfg["command"] == "slipsense experiment test"
    return cfg


@pytest.fixture(scope="module")
def source():
    return MemorySource()


@pytest.fixture(autouse=True)
def _one_thread(one_thread):
    """Every test here on one torch thread (tests/conftest.py)."""


def test_params_counts_table(tmp_path):
    from slipsense.models import resnet3d
    from slipsense.models.stnet import PRESETS
    from studies.stnet.size import count_parameters_for

    res = run_params(Settings(out=tmp_path, command="x"))
    cols, rows = read_csv(tmp_path / "params.csv")
    assert cols[:4] == ["model", "preset", "parameters", "paper_parameters"] and cols[-1] == "setting"
    by = {(r["model"], r["preset"]): r for r in rows}
    assert int(by["resnet3d50", "paper"]["parameters"]) == resnet3d.PAPER_PARAMETERS
    assert int(by["resnet3d50", "paper"]["difference"]) == 0
    assert int(by["stnet", "paper"]["parameters"]) == count_parameters_for(PRESETS["paper"])
    assert int(by["temnet", "paper"]["parameters"]) == count_parameters_for(PRESETS["paper"], model="temnet")
    assert 120e6 < int(by["stnet", "paper"]["parameters"]) < 130e6
    assert {("vivit", "paper"), ("stnet", "compact"), ("temnet", "compact")} <= set(by)
    # factorised positions: (5 - 1) x 48 x 8 fewer spatial, 5 x 8 more temporal
    assert (
        int(by["vivit", "paper"]["parameters"]) - int(by["vivit", "positions=factorised"]["parameters"])
        == 4 * 48 * 8 - 5 * 8
    )
    assert all(r["setting"] == "full" for r in rows)
    cfg = json.loads((tmp_path / "config.json").read_text())
    assert cfg["models"]["vivit/paper"]["model_config"]["patch_size"] == [40, 40]
    assert res["paths"]["png"].exists()


def test_video_compare(tmp_path, source):
    cols = [
        "model",
        "parameters",
        "epochs",
        "train_seconds",
        "inference_clips_per_s",
        "accuracy",
        "precision",
        "recall",
        "f1",
        "n_test",
        "n_test_slip",
        "initialisation",
    ]
    res = run_video_compare(tiny(tmp_path), source, inference_clips=3)
    cfg = check_outputs(tmp_path, "video-compare", cols, 2)
    assert [r["model"] for r in res["rows"]] == ["vivit", "resnet3d50"]
    assert all(r["inference_clips_per_s"] > 0 and r["epochs"] == 2 for r in res["rows"])
    held = cfg["config"]["test_objects"]
    assert len(held) == 1 and res["rows"][0]["n_test"] == 6  # one object: 2 slip + 4 wiggle clips
    assert cfg["models"]["resnet3d50"]["model_config"]["width"] == 2
    assert cfg["models"]["vivit"]["train"]["epochs"] == 2 and cfg["setting"] == "full+custom"
    assert "overrides" in (tmp_path / "video-compare.md").read_text()
    assert (tmp_path / "runs" / "vivit" / "last.safetensors").exists()
    assert read_csv(tmp_path / "curves.csv")[0][:3] == ["model", "epoch", "lr"]


def test_video_compare_of_one_model_trains_that_one_and_refuses_others(tmp_path, source):
    res = run_video_compare(tiny(tmp_path), source, inference_clips=3, models=["vivit"])
    assert [r["model"] for r in res["rows"]] == ["vivit"]
    assert not (tmp_path / "runs" / "resnet3d50").exists()
    with pytest.raises(ConfigError, match="--models takes vivit and/or resnet3d50, got resnet"):
        run_video_compare(tiny(tmp_path / "x"), source, models=["resnet"])


def test_frames_curves(tmp_path, source):
    cols = [
        "frames",
        "clip_ms",
        "epochs",
        "train_accuracy",
        "test_accuracy",
        "test_f1",
        "heldout_accuracy",
        "heldout_precision",
        "heldout_recall",
        "heldout_f1",
        "n_train",
        "n_test",
        "n_heldout",
        "train_seconds",
    ]
    res = run_frames(tiny(tmp_path), source, frames_list=(3, 2))
    check_outputs(tmp_path, "frames", cols, 2)
    ccols, curves = read_csv(tmp_path / "curves.csv")
    assert ccols[:6] == ["frames", "epoch", "train_loss", "train_accuracy", "test_loss", "test_accuracy"]
    assert len(curves) == 4 and all(c["heldout_accuracy"] != "" for c in curves)
    assert [r["frames"] for r in res["rows"]] == [3, 2]
    # the held-out objects never reach training or the clip-level test split
    assert all(r["n_heldout"] == 6 for r in res["rows"])


def test_noise_trains_then_reuses_its_checkpoint(tmp_path, source):
    cols = ["noise_std", "accuracy", "precision", "recall", "f1", "loss", "n_clips"]
    res = run_noise(tiny(tmp_path / "a"), source, stds=(0, 20, 50))
    check_outputs(tmp_path / "a", "noise", cols, 3)
    ck = tmp_path / "a" / "runs" / "vivit" / "last.safetensors"
    again = run_noise(tiny(tmp_path / "b"), source, checkpoint=ck, stds=(0, 20))
    assert again["rows"][0]["accuracy"] == pytest.approx(res["rows"][0]["accuracy"])
    assert again["rows"][1]["loss"] == pytest.approx(res["rows"][1]["loss"], rel=1e-4)
    cfg = json.loads((tmp_path / "b" / "config.json").read_text())
    assert (
        cfg["config"]["trained_here"] is False
        and cfg["config"]["test_objects"]
        == json.loads((tmp_path / "a" / "config.json").read_text())["config"]["test_objects"]
    )
    with pytest.raises(ConfigError):
        run_noise(tiny(tmp_path / "c"), source, checkpoint=ck, stds=(-1,))


def test_stnet_sim_and_real(tmp_path, source):
    cols = [
        "data",
        "model",
        "preset",
        "parameters",
        "epochs",
        "precision",
        "recall",
        "f1",
        "accuracy",
        "loss",
        "n_train",
        "n_test",
        "n_test_slip",
        "train_seconds",
    ]
    cols += ["relevance_in_contact", "markers_in_contact"]
    cols += ["grasp_threshold", "warned_in_time", "premature", "false_positive_grasps", "runs_alarming_at_rest"]
    res = run_stnet(tiny(tmp_path), source, sim_sequences=1, sim_overrides=SIM, markers=5, frames=4)
    check_outputs(tmp_path, "stnet", cols, 4)
    for r in res["rows"]:  # where it looks: measured on the simulator, which says where the contact is
        assert (r["data"] == "simulated") == ("relevance_in_contact" in r)
        if r["data"] == "real":  # per grasp: the held-out object's runs, threshold from the others'
            assert r["warned_in_time"].endswith("/1") and r["false_positive_grasps"].endswith("/1")
    replays = [c[1] for c in source.calls if c[0] == "replay"]
    held = json.loads((tmp_path / "config.json").read_text())["config"]["real"]["test_objects"]
    assert len(replays) == 4 and all(set(r) == set(held) for r in replays[1::2])
    assert all(not set(r) & set(held) for r in replays[::2]) and all(len(r) == len(OBJECTS) - 1 for r in replays[::2])
    assert (tmp_path / "saliency-sim-stnet.png").is_file() and (tmp_path / "saliency-sim-temnet.png").is_file()
    assert [(r["data"], r["model"]) for r in res["rows"]] == [
        ("simulated", "stnet"),
        ("simulated", "temnet"),
        ("real", "stnet"),
        ("real", "temnet"),
    ]
    ccols, curves = read_csv(tmp_path / "curves.csv")
    assert ccols[:3] == ["data", "model", "epoch"] and len(curves) == 8
    cfg = json.loads((tmp_path / "config.json").read_text())
    assert cfg["config"]["preset"] == "compact" and len(cfg["config"]["real"]["test_objects"]) == 1
    assert cfg["models"]["sim-stnet"]["model_config"]["markers"] == 16
    assert cfg["models"]["real-temnet"]["model_config"]["markers"] == 5
    from slipsense.streaming.detector import SlipDetector

    ckpt = tmp_path / "runs" / "real-temnet" / "last.safetensors"  # its checkpoint runs live as it was judged
    assert SlipDetector.from_checkpoint(ckpt, threshold=0.5, sensors=2).cache_product == "markers:5"
    with pytest.raises(ConfigError):
        run_stnet(tiny(tmp_path / "x"), source, data=("sim",), preset="huge")


def test_stnet_real_row_on_a_grid_makes_checkpoints_that_replay_on_it(tmp_path, source):
    from slipsense.streaming.detector import SlipDetector

    res = run_stnet(tiny(tmp_path), source, data=("real",), markers="2x3", frames=4)
    assert [r["model"] for r in res["rows"]] == ["stnet", "temnet"]
    assert json.loads((tmp_path / "config.json").read_text())["config"]["real"]["marker_layout"] == "2x3"
    from slipsense.recordings.frame_cache import video_products
    from slipsense.recordings.video import read_video

    video = REAL_RUN / "camera_0.avi"
    for name in ("stnet", "temnet"):
        det = SlipDetector.from_checkpoint(tmp_path / "runs" / f"real-{name}" / "last.safetensors", threshold=0.5)
        assert det.cache_product == "markers:2x3" and det.sensor.name == "gelsight-mini"
        if name == "stnet" and video.is_file():  # the shared recordings beside the checkout
            # what `watch VIDEO` pushes is what it trained on and what replays read: its layout, in mm
            (watched,) = det.model.inputs_from_videos([read_video(video)], [video], det.geometry)
            np.testing.assert_allclose(watched, video_products(video, ["markers:2x3"])["markers:2x3"], atol=1e-5)


def test_marker_layout_of_the_real_row():
    from slipsense.recordings.markers import marker_layout

    assert marker_layout("7x9") == (63, (7, 9)) and marker_layout(" 2X3 ") == (6, (2, 3))
    assert marker_layout(32) == (32, None) and marker_layout("5") == (5, None)
    for bad in ("0", "7x0", "x9", "seven", "7x9x2", -3):
        with pytest.raises(ConfigError, match="ROWSxCOLS"):
            marker_layout(bad)


def test_horizon(tmp_path, source):
    cols = [
        "horizon_frames",
        "horizon_ms",
        "accuracy",
        "precision",
        "recall",
        "f1",
        "n_train",
        "n_test",
        "n_test_slip",
        "heldout_objects",
        "train_seconds",
    ]
    res = run_horizon(tiny(tmp_path), source, horizons=(0, 3))
    check_outputs(tmp_path, "horizon", cols, 2)
    assert [r["horizon_ms"] for r in res["rows"]] == [0.0, 120.0]
    assert ("clips", 5, 3) in source.calls


def test_match_windows_pairs_same_window_and_drops_disagreements(source):
    from slipsense.recordings.clips import ClipSpec

    clips = source.clips(ClipSpec(frames=5, size=SIZE))
    arrays = source.markers(5, 4)
    ci, mi, dropped = match_windows(clips.meta, arrays, clips.y)
    assert len(ci) == len(clips) and dropped == 0
    for i, j in zip(ci, mi):
        m = clips.meta[i]
        assert (m["object"], m["experiment"], m["camera"], m["start"]) == (
            arrays["groups"][j],
            arrays["experiment"][j],
            arrays["camera"][j],
            arrays["start"][j],
        )
    flipped = dict(arrays, y=1 - arrays["y"])
    flipped["y"][mi[0]] = clips.y[ci[0]]
    ci2, _, dropped2 = match_windows(clips.meta, flipped, clips.y)
    assert len(ci2) == 1 and dropped2 == len(clips) - 1


def test_all_models_same_windows(tmp_path, source):
    cols = [
        "model",
        "input",
        "preset",
        "parameters",
        "epochs",
        "accuracy",
        "precision",
        "recall",
        "f1",
        "n_test",
        "n_test_slip",
        "train_seconds",
    ]
    res = run_all_models(tiny(tmp_path), source, frames=4, n_markers=3)
    cfg = check_outputs(tmp_path, "all-models", cols, 4)
    assert [r["model"] for r in res["rows"]] == ["vivit", "resnet3d50", "stnet", "temnet"]
    assert len({r["n_test"] for r in res["rows"]}) == 1  # every model scored on the same windows
    assert cfg["config"]["matched_windows"] == cfg["config"]["clip_windows"] == 30
    assert cfg["config"]["marker_windows"] == 31


def test_quick_setting_is_labelled(tmp_path):
    s = Settings(out=tmp_path, quick=True)
    assert s.video_size == (120, 160) and s.vivit_patch == (20, 20)
    assert s.train_config("vivit").epochs == 20
    assert s.train_config("resnet3d50").epochs == 2
    assert s.setting == "quick" and "QUICK" in s.describe(["vivit"])
    assert Settings(out=tmp_path).train_config("vivit").epochs == 75
    custom = Settings(out=tmp_path, quick=True, epochs=3, size=(60, 80))
    assert custom.setting == "quick+custom" and custom.train_config("stnet").epochs == 3
    assert custom.vivit_patch == (10, 10)
    with pytest.raises(ConfigError):
        Settings(out=tmp_path, size=(50, 70))
    with pytest.raises(ConfigError):
        Settings(out=tmp_path, train_overrides={"vivit": {"bogus": 1}})
    run_params(Settings(out=tmp_path / "q", quick=True))
    assert "QUICK setting" in (tmp_path / "q" / "params.md").read_text()
    assert json.loads((tmp_path / "q" / "config.json").read_text())["setting"] == "quick"
    assert {r["setting"] for r in read_csv(tmp_path / "q" / "params.csv")[1]} == {"quick"}


def test_results_collects_latest_reports(tmp_path):
    reports = tmp_path / "reports"
    run_params(Settings(out=reports / "params", command="slipsense experiment params --out reports/params"))
    out = collect_results(reports, tmp_path / "docs" / "results.md")
    text = out.read_text()
    assert "slipsense experiment params --out reports/params" in text
    assert "![params](../reports/params/params.png)" in text
    assert text.count("**Not yet run** —") == len(EXPERIMENTS) - 1
    assert "Machine: " in text and "torch" in text
    for i, name in enumerate(EXPERIMENTS, 1):
        assert f"## {i}. {TITLES[name]}" in text
    # a second condition of the same experiment gets its own subsection; both stay on the page
    run_params(Settings(out=reports / "params-quick", quick=True))
    text = collect_results(reports, tmp_path / "docs" / "results.md").read_text()
    assert "### `params-quick`" in text and "### `params`" in text
    assert text.index("### `params-quick`") < text.index("### `params`")  # newest first
    assert "![params](../reports/params-quick/params.png)" in text


def test_results_link_benchmarks_and_early_warning(tmp_path):
    reports, out = tmp_path / "reports", tmp_path / "docs" / "results.md"
    assert "No early-warning replay or benchmark report yet" in collect_results(reports, out).read_text()
    (tmp_path / "bench" / "results" / "avx2").mkdir(parents=True)
    (tmp_path / "bench" / "results" / "avx2" / "stream-1thread.md").write_text("# Streaming\n")
    warn = reports / "early-warning-fold0"
    warn.mkdir(parents=True)
    (warn / "early_warning.json").write_text(
        json.dumps({"checkpoint": "/somewhere/last.safetensors", "model": "vivit", "recordings": "/data/gelsight-slip"})
    )
    (warn / "early_warning.png").write_bytes(b"png")
    text = collect_results(reports, out).read_text()
    assert (
        "| [`results/avx2/stream-1thread.md`](../bench/results/avx2/stream-1thread.md) | `python bench/bench_stream.py` |"
        in text
    )
    assert "![early warning](../reports/early-warning-fold0/early_warning.png)" in text
    assert "Model `last.safetensors` (vivit)" in text and "/somewhere" not in text
    assert "## Other measurements" not in text
    (reports / "stnet-precision").mkdir()
    (reports / "stnet-precision" / "README.md").write_text("# STNet at int8\n\nslipsense evaluate ...\n")
    text = collect_results(reports, out).read_text()
    assert "- [STNet at int8](../reports/stnet-precision/README.md) (`stnet-precision`)" in text


def test_cli_params_and_one_line_errors(tmp_path):
    from studies.__main__ import app

    runner = CliRunner()
    r = runner.invoke(app, ["experiment", "params", "--out", str(tmp_path / "p"), "--no-progress"])
    assert r.exit_code == 0, r.output
    cfg = json.loads((tmp_path / "p" / "config.json").read_text())
    assert cfg["command"].split()[0] in ("slipsense", "python")  # the program, then what it was given
    r = runner.invoke(app, ["experiment", "frames", "--out", str(tmp_path / "f"), "--size", "12"])
    assert r.exit_code == 2 and "--size must look like" in r.output and "Traceback" not in r.output
    r = runner.invoke(app, ["experiment", "horizon", "--out", str(tmp_path / "h"), "--set", "novalue"])
    assert r.exit_code == 2 and "MODEL.KEY=VALUE" in r.output
    r = runner.invoke(app, ["experiment", "results", "--reports", str(tmp_path), "--out", str(tmp_path / "r.md")])
    assert r.exit_code == 0 and (tmp_path / "r.md").exists()


def test_resume_reuses_finished_runs(tmp_path, source):
    first = run_horizon(tiny(tmp_path), source, horizons=(0,))
    again = run_horizon(tiny(tmp_path, resume=True), source, horizons=(0,))
    assert again["rows"][0]["accuracy"] == first["rows"][0]["accuracy"]
    assert again["rows"][0]["train_seconds"] == first["rows"][0]["train_seconds"]  # nothing retrained


def test_data_line_knows_the_default_recordings_in_portable_form(tmp_path):
    assert "not the default" not in _data_line({"recordings": "$SLIPSENSE_DATA/gelsight-slip"})
    assert "not the default" in _data_line({"recordings": str(tmp_path / "gelsight-slip")})
