"""Each folder of a recordings tree listed once: what a scan learnt of the tree, kept for whoever reads
it next (a second look at the layout, a rescan with another sensor's layout, a worker process).

A :class:`FolderTree` answers "which folders, which files, does this file exist" from one
``os.scandir`` per folder; a folder it never listed is listed on the first question about it. It holds
names and kinds only, never contents, and pickles with the :class:`~slipsense.recordings.recording_set.Recordings`
that carries it.

A symbolic link that loops, points nowhere or cannot be followed is listed as a broken entry
(:attr:`Entry.problem`), among both the files and the folders a caller asks for: whoever reads it
then names it in one line (:class:`~slipsense.errors.InputError`) instead of the scan either dying
on the ``OSError`` or leaving the recording out without a word. A folder that cannot be listed
raises a :class:`FolderError` naming it, which is an ``InputError`` and also the ``OSError`` (a
``PermissionError`` where permission was denied) that callers handling an unreadable folder expect.
"""

from __future__ import annotations

import errno
import fnmatch
import os
from pathlib import Path
from typing import NamedTuple

from ..errors import InputError

#: What is wrong with a broken entry, in the words the errors use.
LOOP = "a symbolic link that loops"
DENIED = "cannot be read (permission denied)"


def dangling(what: str = "file") -> str:
    return f"a link to a {what} that does not exist"


class FolderError(InputError, OSError):
    """A folder of a recordings tree cannot be listed: one line naming it."""


class FolderPermissionError(FolderError, PermissionError):
    """A folder cannot be listed for want of permission."""


class FolderNotFoundError(FolderError, FileNotFoundError):
    """A folder is a symbolic link to nothing."""


class Entry(NamedTuple):
    name: str
    is_dir: bool  # symlinks followed, as Path.is_dir does
    is_file: bool
    #: None, or why a symbolic link cannot be followed (its words; the entry is neither file nor folder)
    problem: str | None = None


def _read_entry(e: os.DirEntry) -> Entry:
    # DirEntry's is_dir/is_file answer from the folder listing for everything but a symbolic link,
    # which they stat once (cached); only a link that cannot be followed costs more, and only here.
    try:
        is_dir, is_file = e.is_dir(), e.is_file()
    except PermissionError:
        return Entry(e.name, False, False, DENIED)
    except OSError as exc:  # ELOOP, or ENOTDIR for a link through a file
        return Entry(e.name, False, False, _problem(exc))
    if is_dir or is_file or not e.is_symlink():
        return Entry(e.name, is_dir, is_file)
    try:  # a link DirEntry could not stat (it answers False for a missing target), or one to a device/fifo
        e.stat()
    except OSError:
        return Entry(e.name, False, False, dangling())
    return Entry(e.name, False, False)


def _problem(exc: OSError) -> str:
    if exc.errno == errno.ELOOP:
        return LOOP
    if exc.errno in (errno.ENOENT, errno.ENOTDIR):
        return dangling()
    return f"cannot be read ({exc.strerror or exc})"


def link_problem(path: str | Path, what: str = "file") -> str | None:
    """Why ``path`` (a symbolic link) cannot be followed, in plain words; None where it can be, or
    where ``path`` is no link (a missing plain file is its caller's to word)."""
    path = Path(path)
    try:
        os.stat(path)
        return None
    except PermissionError:
        return DENIED
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return LOOP
        if not path.is_symlink():
            return None
    try:
        target = os.readlink(path)
    except OSError:
        return dangling(what)
    return f"{dangling(what)} (it points to {target})"


class FolderTree:
    """The entries of every folder asked about, each folder listed at most once (by name, sorted)."""

    def __init__(self) -> None:
        self._listed: dict[Path, tuple[Entry, ...]] = {}

    def entries(self, folder: str | Path) -> tuple[Entry, ...]:
        """``folder``'s entries by name. A missing folder raises FileNotFoundError / NotADirectoryError
        as ``os.scandir`` does; one that cannot be listed (permission denied, a link that loops or points
        nowhere) a :class:`FolderError` naming it."""
        folder = Path(folder)
        listed = self._listed.get(folder)
        if listed is None:
            try:
                with os.scandir(folder) as it:
                    listed = tuple(sorted(map(_read_entry, it), key=lambda e: e.name))
            except PermissionError:
                raise FolderPermissionError(folder, f"folder {DENIED}") from None
            except (FileNotFoundError, NotADirectoryError):
                if not folder.is_symlink():
                    raise
                raise FolderNotFoundError(folder, link_problem(folder, "folder") or dangling("folder")) from None
            except OSError as exc:
                problem = LOOP if exc.errno == errno.ELOOP else f"folder cannot be read ({exc.strerror or exc})"
                raise FolderError(folder, problem) from None
            self._listed[folder] = listed
        return listed

    def dirs(self, folder: str | Path) -> list[Path]:
        """The sub-folders of ``folder`` by name; hidden ones (.git, .DS_Store, editor folders) are never data.
        Broken links are among them: listing one raises the :class:`FolderError` that names it."""
        folder = Path(folder)
        return [folder / e.name for e in self.entries(folder) if (e.is_dir or e.problem) and not e.name.startswith(".")]

    def files(self, folder: str | Path, pattern: str = "*") -> list[Path]:
        """The files of ``folder`` whose names match ``pattern`` (case-sensitive, as ``Path.glob`` here), by
        name. Broken links that match are among them, for the reader of the file to name
        (:meth:`broken` says which)."""
        folder = Path(folder)
        return [
            folder / e.name
            for e in self.entries(folder)
            if (e.is_file or e.problem) and fnmatch.fnmatchcase(e.name, pattern)
        ]

    def broken(self, folder: str | Path) -> dict[str, str]:
        """``{name: problem}`` of the entries of ``folder`` that are links which cannot be followed."""
        return {e.name: e.problem for e in self.entries(folder) if e.problem}

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
