"""`slipsense adapt`: the shipped detector as is, recalibrated and fine-tuned, judged on objects each
never saw beside the baselines; the best kept only where it beats them, with the reason in words;
too few grasps or nothing better said plainly, and no detector written then; a second run resumes."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from slipsense.adapt import USEFUL, Candidate, advise, best_of, nested_choice
from slipsense.cli import app
from tests.conftest import REAL_RUN, needs_data, sigkill_when
from tests.test_frame_folders import _lift_data

runner = CliRunner()
SLIPPED = np.array([True, True, False, False] * 3)
OBJECTS = np.repeat(["a", "b", "c"], 4)


def _candidate(name: str, caught: int, alarming: int) -> Candidate:
    """A candidate catching ``caught`` of the 6 slips and alarming on ``alarming`` of the 6 held grasps."""
    alarmed = np.zeros(12, bool)
    alarmed[np.flatnonzero(SLIPPED)[:caught]] = True
    alarmed[np.flatnonzero(~SLIPPED)[:alarming]] = True
    return Candidate(name, alarmed.astype(float), alarmed, SLIPPED, OBJECTS)


BASELINE = {"value": 0.6, "interval": [0.5, 0.7]}


def test_the_kept_figure_is_the_choice_made_without_each_object_not_the_best_on_all():
    """Candidates that alarm at random: the best of them on all grasps looks better than chance, but
    choosing without each object in turn scores that object's grasps by a choice made elsewhere, so
    the kept figure is near chance, and nothing is kept."""
    rng = np.random.default_rng(7)
    slipped = np.array([True, False] * 40)
    objects = np.repeat([f"o{i}" for i in range(8)], 10)
    cands = []
    for k in range(12):
        alarmed = rng.random(80) < 0.5
        cands.append(Candidate(f"c{k}", alarmed.astype(float), alarmed, slipped, objects, "random"))
    best = best_of(cands)
    kept, per_object = nested_choice(cands)
    assert best.balanced_accuracy > 0.55  # the maximum over twelve coins flatters the winner
    assert abs(kept.balanced_accuracy - 0.5) < abs(best.balanced_accuracy - 0.5)
    assert kept.balanced_accuracy < USEFUL and set(per_object) == set(objects)
    keep, advice = advise(best, kept, per_object, cands[0], "frame_difference", BASELINE)
    assert not keep and advice[0].startswith("nothing is kept") and "near chance" in advice[0]


def test_a_good_candidate_is_kept_and_every_sentence_agrees_with_its_figures():
    as_is, recal, tuned = _candidate("as is", 0, 0), _candidate("recalibrated", 3, 0), _candidate("fine-tuned", 6, 0)
    cands = [as_is, recal, tuned]
    kept, per_object = nested_choice(cands)
    assert best_of(cands) is tuned and set(per_object.values()) == {"fine-tuned"}
    keep, advice = advise(tuned, kept, per_object, as_is, "frame_difference", BASELINE)
    assert keep and advice[0].startswith("kept fine-tuned")
    _sentences_agree(advice, kept, tuned, as_is)
    # the shipped detector as is the best: kept as it is, nothing written
    good = _candidate("as is", 6, 0)
    cands = [good, recal, tuned]
    kept, per_object = nested_choice(cands)
    keep, advice = advise(best_of(cands), kept, per_object, good, "frame_difference", BASELINE)
    assert keep and advice[0].startswith("keep using the shipped detector as it is")
    # always off and always on are no better than chance: never kept
    off, on = _candidate("recalibrated", 0, 0), _candidate("fine-tuned", 6, 6)
    kept, per_object = nested_choice([as_is, off, on])
    keep, advice = advise(best_of([as_is, off, on]), kept, per_object, as_is, "majority_class", BASELINE)
    assert not keep and off.balanced_accuracy == on.balanced_accuracy == 0.5


def _sentences_agree(advice: list[str], kept, chosen, as_is) -> None:
    """Every percentage a sentence states is the one of the figure it names."""
    import re

    op = kept.measure["operating_point"]
    figures = {
        "balanced accuracy when chosen": op["balanced_accuracy"]["value"],
        "balanced accuracy, right on": op["balanced_accuracy"]["value"],
    }
    first = re.search(r"(\d+)% balanced accuracy against (\d+)%", advice[0])
    if first:
        assert int(first.group(1)) == round(100 * chosen.balanced_accuracy)
        assert int(first.group(2)) == round(100 * as_is.balanced_accuracy)
    second = re.search(r"expect on objects it never saw: (\d+)% .*right on (\d+)% ", advice[1])
    assert second, advice[1]
    assert int(second.group(1)) == round(100 * figures["balanced accuracy, right on"])
    assert int(second.group(2)) == round(100 * op["accuracy"]["value"])
    assert " or " not in " ".join(advice)  # no "A or B" that reads as both


def test_too_few_grasps_say_what_to_record_and_write_no_detector(tmp_path, cache):
    root = _lift_data(tmp_path / "lift", objects=1)
    res = runner.invoke(app, ["adapt", "--recordings", str(root), "--out", str(tmp_path / "mine"), "--no-progress"])
    assert res.exit_code == 0, res.output
    assert "too few" in res.output and "grasps of 2 more object(s)" in res.output
    assert not (tmp_path / "mine" / "detector.safetensors").exists()
    assert json.loads((tmp_path / "mine" / "adapt.json").read_text())["chosen"] is None


@pytest.mark.parametrize("bad", [["--folds", "1"], ["--budget", "1.5"], ["--epochs", "0"]])
def test_bad_settings_end_in_one_line(tmp_path, bad):
    res = runner.invoke(app, ["adapt", "--recordings", str(tmp_path), "--out", str(tmp_path / "o"), *bad])
    assert res.exit_code == 2 and res.output.count("error: ") == 1, res.output


def test_adapt_judges_every_family_that_fits_on_unseen_objects_and_resumes_after_a_kill(tmp_path, cache, one_thread):
    """On made-up grasps without gel markers: the shear family is skipped with its reason, MotionNet
    from scratch wants more grasps, motion-energy and a model registered here (nothing in adapt names
    it) are judged beside the shipped detector; killed after its first training, a rerun finishes
    without redoing it, and a third run trains nothing."""
    from slipsense.models import base, register
    from slipsense.models.motion import MotionEnergy

    @register("tiny-energy")
    class TinyEnergy(MotionEnergy):
        """A made-up family: motion energy under another name, judged before everything else."""

        adapt_cost = 1.0
        adapt_words = "made up for this test"

    try:
        root = _lift_data(tmp_path / "lift")
        out = tmp_path / "mine"
        args = ["adapt", "--recordings", str(root), "--out", str(out), "--epochs", "1", "--folds", "3", "--no-progress"]
        first = out / "folds" / "tiny-energy" / "fold0" / "detector.safetensors"
        sigkill_when(first, args)
        assert first.exists() and not (out / "adapt.json").exists()  # killed mid-run
        stamp = first.stat().st_mtime_ns
        res = runner.invoke(app, args)
        assert res.exit_code == 0, res.output
        assert first.stat().st_mtime_ns == stamp  # the training done before the kill is kept
        for words in (
            "your grasps: 12 (6 slipped, 6 held) of 3 objects",
            "shear-retention, slip-velocity not tried: needs a gel with markers: no marker grid",
            "motionnet        not tried: trained from scratch only on 40+ grasps",
            "best baseline",
            "what to expect on objects it never saw",
        ):
            assert words in res.output, words
        doc = json.loads((out / "adapt.json").read_text())
        names = [c["name"] for c in doc["candidates"]]
        assert names == ["as is", "recalibrated", "tiny-energy", "motion-energy", "fine-tuned"]  # cheap first
        assert all(c["measure"]["grasps"] == 12 for c in doc["candidates"])
        assert set(doc["kept"]["chosen_without_each_object"]) == {"object000", "object001", "object002"}
        assert (out / "detector.safetensors").exists() == (doc["chosen"] not in (None, "as is"))
        if doc["chosen"] not in (None, "as is"):  # one promise: what adapt's table said, in watch and models
            from slipsense.checkpoint import read_info
            from slipsense.measures.promise import promise_text

            chosen = next(c for c in doc["candidates"] if c["name"] == doc["chosen"])
            promise = promise_text(read_info(out / "detector.safetensors")["operating_point"])
            assert f"({chosen['held_alarming']} of 6)" in promise and "objects it never saw" in promise, promise
        folds = sorted(out.glob("folds/*/fold*/detector.safetensors"))
        assert len(folds) == 9
        before = [p.stat().st_mtime_ns for p in folds]
        res = runner.invoke(app, args)  # again: every fold's training is found, none is repeated
        assert res.exit_code == 0 and [p.stat().st_mtime_ns for p in folds] == before
        assert json.loads((out / "adapt.json").read_text())["candidates"] == doc["candidates"]
    finally:
        base._REGISTRY.pop("tiny-energy", None)


def _table(output: str) -> dict[str, tuple[int, int]]:
    """Each candidate line of adapt's printout: name -> (balanced accuracy %, accuracy %)."""
    import re

    rows = {}
    for line in output.splitlines():
        m = re.match(r"  (\S.*?)\s+(\d+)% \(95% range \d+-\d+%\) balanced, right on (\d+)%;", line)
        if m:
            rows[m.group(1)] = (int(m.group(2)), int(m.group(3)))
    return rows


@needs_data
def test_two_finger_frames_of_the_shared_grasps_get_the_two_finger_detector_and_true_sentences(
    tmp_path, cache, one_thread, monkeypatch
):
    """3 objects of the shared wiggle grasps as two-finger frame folders (two of each object's slips
    and two of its held grasps, to stay quick): adapt judges the two-finger detector and every figure
    its advice states is one its table or adapt.json holds."""
    import re
    import shutil

    from slipsense import adapt as adapt_module
    from studies.grasp.derive import two_finger_frame_folders

    frames = tmp_path / "frames"
    two_finger_frame_folders(
        REAL_RUN.parents[1], frames, ["blue_mug", "ball_white_thread", "pattern_cotton_cloth"], ".jpg"
    )
    for obj in sorted(p for p in frames.iterdir() if p.is_dir()):
        grasps = sorted(obj.iterdir(), key=lambda g: int(g.name.split("_")[-1]))
        labels = {g: (g / "slip.txt").exists() for g in grasps}
        for slipped in (True, False):
            for g in [g for g in grasps if labels[g] == slipped][2:]:
                shutil.rmtree(g)
    real = adapt_module.families
    monkeypatch.setattr(adapt_module, "families", lambda g: (["motion-energy"], real(g)[1]))  # the cheap family
    out = tmp_path / "mine"
    args = ["adapt", "--recordings", frames, "--out", out, "--epochs", "1", "--folds", "3", "--no-progress"]
    res = runner.invoke(app, [str(a) for a in args])
    assert res.exit_code == 0, res.output
    doc = json.loads((out / "adapt.json").read_text())
    assert doc["shipped"] == "motionnet-gelsight.safetensors"  # the two-finger detector
    assert "your grasps: 12 (6 slipped, 6 held) of 3 objects, 320x240 px, 2 camera(s) a grasp" in res.output
    rows = _table(res.output)
    assert set(rows) >= {"as is", "recalibrated", "motion-energy", "fine-tuned"}
    for c in doc["candidates"]:  # the table is adapt.json's
        op = c["measure"]["operating_point"]
        assert rows[c["name"]] == (round(100 * op["balanced_accuracy"]["value"]), round(100 * op["accuracy"]["value"]))
    advice = doc["advice"]
    assert all(line in res.output for line in advice)
    kept = doc["kept"]["measure"]["operating_point"]
    m = re.search(r"expect on objects it never saw: (\d+)% .* right on (\d+)% ", advice[1])
    assert m and (int(m.group(1)), int(m.group(2))) == (
        round(100 * kept["balanced_accuracy"]["value"]),
        round(100 * kept["accuracy"]["value"]),
    )
    m = re.search(r"kept (\S+) .*?(\d+)% balanced accuracy against (\d+)% for the shipped detector as is", advice[0])
    if m:  # a detector kept: its figure and the shipped one's are their rows'
        assert (int(m.group(2)), int(m.group(3))) == (rows[m.group(1)][0], rows["as is"][0])
    else:
        assert advice[0].startswith(("nothing is kept", "keep using the shipped detector"))
    assert " or " not in " ".join(advice)


def _grasps_of(root, kinds: dict[str, tuple[bool, ...]]):
    """Frame-folder grasps in the gelsight-lift layout: ``{object: (slipped?, ...)}``."""
    from tests.test_frame_folders import _grasp

    for i, (obj, slips) in enumerate(kinds.items()):
        lines = []
        for g, slipped in enumerate(slips):
            name = f"06{g}_{i}0"
            _grasp(root / obj / f"{name}_mm", slipped, seed=10 * i + g)
            lines.append(f"6{g}.{i} {'fail 0' if slipped else 'ok 1'} 100 300 200 {name} _s09_")
        (root / f"{obj}_result.dat").write_text("\n".join(lines))
    return root


def test_adapt_at_its_minimum_with_objects_that_only_slipped_or_only_held(tmp_path, cache, one_thread):
    """3 objects, one with 3 slipped and 3 held grasps, one that only held, one that only slipped:
    at the documented minimum, every fold trains (inner folds that would train on no slip choose the
    operating point on the training runs themselves, and say so); adapt ends with its table."""
    root = _grasps_of(
        tmp_path / "set", {"object000": (True, False) * 3, "object001": (False,) * 3, "object002": (True,) * 3}
    )
    out = tmp_path / "mine"
    args = ["adapt", "--recordings", str(root), "--out", str(out), "--epochs", "1", "--folds", "3", "--no-progress"]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    assert "your grasps: 12 (6 slipped, 6 held) of 3 objects" in res.output
    assert "hold no slip" not in res.output
    doc = json.loads((out / "adapt.json").read_text())
    assert all(c["measure"]["grasps"] == 12 for c in doc["candidates"])


def test_adapt_refuses_when_one_object_alone_slipped(tmp_path, cache):
    """3 slipped and 6 held grasps of 3 objects, but every slip on one object: leaving it out leaves
    nothing to learn a slip from. Said in a true sentence, no detector written."""
    root = _grasps_of(
        tmp_path / "set", {"object000": (True,) * 3, "object001": (False,) * 3, "object002": (False,) * 3}
    )
    out = tmp_path / "mine"
    res = runner.invoke(app, ["adapt", "--recordings", str(root), "--out", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    assert "too few" in res.output and "slipped grasps of 1 more object" in res.output, res.output
    assert not (out / "detector.safetensors").exists()
