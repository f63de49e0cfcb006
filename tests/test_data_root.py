"""Where the data folder is found (slipsense.paths): SLIPSENSE_DATA, else a shared/data folder beside the
checkout or the working directory; a missing one gets a line saying how to point at it."""

from __future__ import annotations

import pytest

from slipsense import paths
from slipsense.errors import InputError
from slipsense.recordings.folders import find_recordings
from slipsense.recordings.video import read_video


def test_the_environment_variable_comes_first(tmp_path, monkeypatch):
    monkeypatch.setenv(paths.DATA_ENV, str(tmp_path))
    assert paths.data_root() == tmp_path.resolve() and paths.data_candidates() == [tmp_path]


def test_without_it_a_shared_data_folder_in_or_beside_the_working_directory_is_found(tmp_path, monkeypatch):
    monkeypatch.delenv(paths.DATA_ENV, raising=False)
    monkeypatch.setattr(paths, "__file__", str(tmp_path / "site-packages" / "slipsense" / "paths.py"))  # installed
    work = tmp_path / "project" / "work"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    (tmp_path / "project" / "shared" / "data").mkdir(parents=True)  # beside the working directory
    assert paths.data_root() == (tmp_path / "project" / "shared" / "data").resolve()
    (work / "shared" / "data").mkdir(parents=True)  # in it: looked at first
    assert paths.data_root() == (work / "shared" / "data").resolve()


def test_a_missing_data_folder_says_how_to_point_at_it(tmp_path, monkeypatch):
    monkeypatch.delenv(paths.DATA_ENV, raising=False)
    monkeypatch.setattr(paths, "__file__", str(tmp_path / "site-packages" / "slipsense" / "paths.py"))
    monkeypatch.chdir(tmp_path)
    for read in (find_recordings, read_video):
        with pytest.raises(InputError, match=f"no data folder was found .*set {paths.DATA_ENV}"):
            read(paths.gelsight_recordings() / "blue_mug" / "exp_num_9" / "camera_0.avi")
    other = tmp_path / "mine"
    with pytest.raises(InputError) as err:  # a folder of the user's own: no word of the data folder
        find_recordings(other)
    assert paths.DATA_ENV not in str(err.value)
