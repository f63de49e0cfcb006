"""Set-up leaves commands fast whatever the environment sets: with PYTHONDONTWRITEBYTECODE, a command
reads bytecode written by scripts/compile_imports.py (set-up runs it) instead of compiling again."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

LIST_UNCOMPILED = """
import importlib.util, sys
project = sys.argv[1]
sys.argv = ["slipsense", "models"]
from slipsense.cli import main
try:
    main()
except SystemExit:
    pass
for name, module in list(sys.modules.items()):
    source = getattr(module, "__file__", None) or ""
    installed = "site-packages" in source or source.startswith(project)  # not the stdlib: Python ships its bytecode
    if installed and source.endswith(".py") and not __import__("os").path.exists(importlib.util.cache_from_source(source)):
        print("UNCOMPILED", name)
"""


def test_a_command_finds_the_bytecode_of_all_it_imports_where_writing_it_is_forbidden(tmp_path):
    # an empty bytecode folder of its own: as a fresh set-up with pip --no-compile leaves it
    env = {**os.environ, "PYTHONPYCACHEPREFIX": str(tmp_path / "pyc"), "PYTHONDONTWRITEBYTECODE": "1"}
    subprocess.run([sys.executable, str(ROOT / "scripts" / "compile_imports.py")], env=env, check=True, timeout=300)
    done = subprocess.run(
        [sys.executable, "-c", LIST_UNCOMPILED, str(ROOT)],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    uncompiled = [line.split()[1] for line in done.stdout.splitlines() if line.startswith("UNCOMPILED")]
    assert uncompiled == [], f"compiled again on every command: {uncompiled[:10]} ({len(uncompiled)})"
