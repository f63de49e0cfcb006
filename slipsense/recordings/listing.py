"""Each folder of a recordings tree listed once: what a scan learnt of the tree, kept for whoever reads
it next (a second look at the layout, a rescan with another sensor's layout, a worker process).

A :class:`FolderTree` answers "which folders, which files, does this file exist" from one
``os.scandir`` per folder; a folder it never listed is listed on the first question about it. It holds
names and kinds only, never contents, and pickles with the :class:`~slipsense.recordings.recording_set.Recordings`
that carries it.
"""

from __future__ import annotations

import fnmatch
import os
from pathlib import Path
from typing import NamedTuple


class Entry(NamedTuple):
    name: str
    is_dir: bool  # symlinks followed, as Path.is_dir does
    is_file: bool


class FolderTree:
    """The entries of every folder asked about, each folder listed at most once (by name, sorted)."""

    def __init__(self) -> None:
        self._listed: dict[Path, tuple[Entry, ...]] = {}

    def entries(self, folder: str | Path) -> tuple[Entry, ...]:
        """``folder``'s entries by name; PermissionError / FileNotFoundError as ``os.scandir`` raises them."""
        folder = Path(folder)
        listed = self._listed.get(folder)
        if listed is None:
            with os.scandir(folder) as it:
                listed = tuple(sorted((Entry(e.name, e.is_dir(), e.is_file()) for e in it), key=lambda e: e.name))
            self._listed[folder] = listed
        return listed

    def dirs(self, folder: str | Path) -> list[Path]:
        """The sub-folders of ``folder`` by name; hidden ones (.git, .DS_Store, editor folders) are never data."""
        folder = Path(folder)
        return [folder / e.name for e in self.entries(folder) if e.is_dir and not e.name.startswith(".")]

    def files(self, folder: str | Path, pattern: str = "*") -> list[Path]:
        """The files of ``folder`` whose names match ``pattern`` (case-sensitive, as ``Path.glob`` here), by name."""
        folder = Path(folder)
        return [folder / e.name for e in self.entries(folder) if e.is_file and fnmatch.fnmatchcase(e.name, pattern)]

    def names(self, folder: str | Path, pattern: str = "*") -> list[Path]:
        """Every entry of ``folder`` (file, folder or other) whose name matches ``pattern``, by name."""
        folder = Path(folder)
        return [folder / e.name for e in self.entries(folder) if fnmatch.fnmatchcase(e.name, pattern)]

    def _entry(self, path: str | Path) -> Entry | None:
        path = Path(path)
        try:
            return next((e for e in self.entries(path.parent) if e.name == path.name), None)
        except (FileNotFoundError, NotADirectoryError):
            return None

    def is_file(self, path: str | Path) -> bool:
        e = self._entry(path)
        return e is not None and e.is_file

    def exists(self, path: str | Path) -> bool:
        return self._entry(path) is not None
