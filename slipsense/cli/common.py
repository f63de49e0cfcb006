"""What every command shares: one-line errors (exit code 2) and warnings, and the checks of common options."""

from __future__ import annotations

import functools
import math
import shlex
import sys
from typing import Optional

import typer

from slipsense.errors import ConfigError, SlipsenseError
from slipsense.config_tree import check_seed  # noqa: F401  (the commands' seed check)


def one_line_warning(message, category, filename, lineno, file=None, line=None) -> str:
    """Skipped videos and cache rebuilds reach users as one line each, not with source lines: the
    command line's ``warnings.formatwarning`` (set by :func:`slipsense.cli.main`, not on import)."""
    return f"warning: {message}\n"


#: Exit code after Ctrl-C (SIGINT), as shells report a command that SIGINT ended: 128 + 2.
INTERRUPTED = 130


def friendly(fn):
    """Print SlipsenseErrors as ``error: <file>: <problem>`` and exit 2 instead of a traceback; end
    on Ctrl-C with one line and exit code 130 (worker processes end with the command:
    :mod:`slipsense.parallel`)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except SlipsenseError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2)
        except KeyboardInterrupt:
            typer.echo("interrupted: stopped with its worker processes (what was saved is kept)", err=True)
            raise typer.Exit(INTERRUPTED)

    return wrapper


def parse_hw(text: Optional[str], option: str = "--size") -> Optional[tuple[int, int]]:
    """``"240x320"`` -> ``(240, 320)`` (height, width); None stays None."""
    if text is None:
        return None
    try:
        h, w = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ConfigError(f"{option} must look like 240x320 (height x width), got {text!r}") from None
    if h < 1 or w < 1:
        raise ConfigError(f"{option} must be positive, got {text!r}")
    return (h, w)


def check_nonnegative(value: float, option: str) -> float:
    """``value`` if it is a finite number >= 0, else ConfigError."""
    if not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise ConfigError(f"{option} must be a finite number >= 0, got {value!r}")
    return value


#: How the running program is called in :func:`command_line` (``python -m studies`` sets its own).
PROG = "slipsense"


def command_line() -> str:
    """The command as it was typed (stored beside what it wrote, so a report names how it was made)."""
    return " ".join([PROG, *(shlex.quote(a) for a in sys.argv[1:])])


def record_provenance(started: float, commands: Optional[set[str]] = None) -> None:
    """After a command that succeeded: ``provenance.json`` in the folder its ``--out`` names
    (:mod:`slipsense.provenance`), for the commands of ``commands`` (None: every command)."""
    import time

    from slipsense.provenance import out_folder, write_provenance

    folder = out_folder(sys.argv[2:])
    if folder is not None and len(sys.argv) > 1 and (commands is None or sys.argv[1] in commands):
        write_provenance(folder, command_line(), started, time.time())
