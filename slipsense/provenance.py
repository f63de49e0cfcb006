"""Where a report folder came from: ``provenance.json`` beside what a command wrote (the command as
typed, the commit of the code and whether it had changes, the machine, the date and the wall time).

The DVC pipeline (``dvc.yaml``) says which reports today's code would change; this file says what
made the one on disk."""

from __future__ import annotations

import datetime
import functools
import hashlib
import json
import os
import platform
import subprocess
import sys
from pathlib import Path
from typing import Any

from slipsense.atomic import write_text

FILE = "provenance.json"


def _git(*args: str) -> str:
    try:
        done = subprocess.run(["git", *args], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return ""
    return done.stdout.strip() if done.returncode == 0 else ""


def _processor() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown processor"


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """A digest of the library's own source (every ``.py`` under the package): what a stored result
    that code produced (a finished fold, say) is valid for."""
    package = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
        digest.update(path.relative_to(package).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]


def provenance(command: str, started: float, finished: float) -> dict[str, Any]:
    """The record of one run: ``started`` and ``finished`` as :func:`time.time` gives them."""
    import torch

    commit = _git("rev-parse", "--short=7", "HEAD")
    # the code's own changes; the reports and the pipeline's lock change as the pipeline runs
    changed = _git("status", "--porcelain", "--untracked-files=no", "--", ".", ":!reports", ":!dvc.lock")
    return {
        "command": command,
        "commit": commit or "not a git checkout",
        "code_changed_since_commit": bool(changed) if commit else None,
        "machine": f"{platform.system()} {platform.machine()}, {_processor()}, {os.cpu_count()} cores",
        "date": datetime.datetime.fromtimestamp(started, datetime.timezone.utc).isoformat(timespec="seconds"),
        "seconds": round(finished - started, 1),
        "versions": {
            "python": platform.python_version(),
            "torch": torch.__version__,
            "slipsense": sys.modules["slipsense"].__version__,
        },
    }


def write_provenance(folder: str | Path, command: str, started: float, finished: float) -> Path:
    """``folder/provenance.json`` (atomically), the last file a command writes there."""
    path = Path(folder) / FILE
    write_text(path, json.dumps(provenance(command, started, finished), indent=1) + "\n")
    return path


def out_folder(argv: list[str]) -> Path | None:
    """The existing folder an ``--out DIR`` (or ``--out=DIR``) of ``argv`` names, else None."""
    for i, arg in enumerate(argv):
        value = argv[i + 1] if arg == "--out" and i + 1 < len(argv) else arg[6:] if arg.startswith("--out=") else None
        if value is not None and Path(value).is_dir():
            return Path(value)
    return None
