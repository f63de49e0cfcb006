"""Errors that reach a user as one line: the file (or setting) and what is wrong with it."""

from __future__ import annotations

from pathlib import Path


class SlipsenseError(Exception):
    """Base class: anything slipsense reports to a user as a one-line error."""


class InputError(SlipsenseError):
    """A file or value a user gave cannot be used.

    ``InputError(path, problem)`` renders as ``"<path>: <problem>"`` so the CLI can print it whole.
    """

    def __init__(self, path: str | Path | None, problem: str):
        self.path = None if path is None else str(path)
        self.problem = problem
        super().__init__(problem if path is None else f"{path}: {problem}")

    def __reduce__(self):  # raised in a worker process, re-raised here whole
        return (type(self), (self.path, self.problem))


class ConfigError(SlipsenseError):
    """A configuration key is unknown or a value is out of range."""


class OutputError(InputError, OSError):
    """A file slipsense was asked to write cannot be written (an existing folder, a read-only place).

    Also an OSError, so code that treats a failed write as recoverable (caches) still catches it.
    """


class CacheWarning(UserWarning):
    """A cache entry failed its checks (checksum, inputs, contents) and is rebuilt from its inputs."""
