"""The experiments' data door (studies.experiments.source.DataSource) on made-up recordings: labels come
through slipsense.recordings.labels.label_runs, the path ``slipsense train`` uses (hand labels, --on-error skip)."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

import striped_video

from slipsense.errors import InputError
from studies.experiments.source import DataSource, default_overrides
from slipsense.recordings.folders import SkippedInputWarning

N_FRAMES = 60


@pytest.fixture(scope="module")
def recordings(tmp_path_factory) -> Path:
    """apple and pear: a slip run (1) and a wiggle run (2), two cameras each; plum run 1's cameras
    differ in frame count, so it cannot be labelled."""
    root = tmp_path_factory.mktemp("recordings")
    for obj in ("apple", "pear", "plum"):
        for exp in (1, 2) if obj != "plum" else (1,):
            d = root / obj / f"exp_num_{exp}"
            for cam, n in (("camera_0", N_FRAMES), ("camera_2", N_FRAMES - 10 if obj == "plum" else N_FRAMES)):
                striped_video.write_video(d / f"{cam}.avi", n)
            if exp == 1:
                (d / "slip.txt").write_text("")
    return root


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SLIPSENSE_CACHE", str(tmp_path / "cache"))


def test_unlabelable_run_raises_or_is_skipped_like_train(recordings, monkeypatch):
    with pytest.raises(InputError, match="differ in frame count"):
        DataSource(recordings, overrides=None, progress=False).labels()
    source = DataSource(recordings, overrides=None, on_error="skip", progress=False)
    with pytest.warns(SkippedInputWarning, match="run skipped"):
        labels = source.labels()
    assert {k[:2] for k in labels} == {("apple", 1), ("apple", 2), ("pear", 1), ("pear", 2)}
    assert set(source.objects(_spec())) <= {"apple", "pear"}

    # clips are cut from the labelled runs only
    seen = {}

    def fake_clips(recs, labs, spec, progress=True):
        seen["keys"] = [r.key for r in recs]
        return [0]

    import slipsense.recordings.clips as clips_mod

    monkeypatch.setattr(clips_mod, "load_or_build_clips", fake_clips)
    source.clips(_spec())
    assert seen["keys"] and all(k in labels for k in seen["keys"])


def test_user_overrides_are_read_against_the_recordings(recordings, tmp_path):
    good = tmp_path / "good.csv"
    good.write_text("object,experiment,camera,moment_of_slip\napple,1,,30\n")
    labels = DataSource(recordings, overrides=good, on_error="skip", progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkippedInputWarning)
        got = labels.labels()
    assert {k: (lab.source, lab.moment_of_slip) for k, lab in got.items() if k[:2] == ("apple", 1)} == {
        ("apple", 1, "camera_0"): ("override", 30),
        ("apple", 1, "camera_2"): ("override", 30),
    }
    bad = tmp_path / "bad.csv"
    bad.write_text("object,experiment,camera,moment_of_slip\nkiwi,1,,30\n")
    with pytest.raises(InputError, match="unknown object 'kiwi'") as err:
        DataSource(recordings, overrides=bad, on_error="skip", progress=False).labels()
    assert "bad.csv" in str(err.value)


def test_shipped_overrides_keep_only_rows_of_these_recordings(recordings):
    if default_overrides() is None:
        pytest.skip("the shipped overrides file is not there")
    source = DataSource(recordings, overrides="default", on_error="skip", progress=False)
    assert source.overrides == default_overrides()
    assert source.label_overrides() is None  # every shipped row names a run of the shared recordings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkippedInputWarning)
        assert all(lab.source != "override" for lab in source.labels().values())


def _spec():
    from slipsense.recordings.clips import ClipSpec

    return ClipSpec(frames=5, size=(48, 64))
