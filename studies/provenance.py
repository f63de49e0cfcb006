"""Where a report was made: commit, machine and date, in one line for its README."""

from __future__ import annotations

import datetime
import os
import platform
import subprocess


def provenance() -> str:
    """Commit, machine and date of a report, in one line."""
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    except OSError:
        commit = ""
    machine = f"{platform.system()} {platform.machine()}, {os.cpu_count()} cores"
    return f"Commit {commit or 'unknown'}, {machine}, {datetime.date.today().isoformat()}."
