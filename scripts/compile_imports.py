"""Write the bytecode of every module a slipsense command imports, whatever the environment says.

Set-up installs with ``pip --no-compile`` (compiling torch's thousands of files up front would cost a
minute). Python then writes each module's bytecode on its first import, unless the environment sets
``PYTHONDONTWRITEBYTECODE``: then every command compiles what it imports again, about 5 s each time.
Here every slipsense module is imported once with writing allowed, so torch, numpy, typer, ONNX
Runtime and slipsense itself have their bytecode on disk; a later command reads it even where the
environment forbids writing. Run by ``scripts/setup.sh``; a module whose optional extra is not
installed (the ROS node without rclpy) is passed over.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import pkgutil
import py_compile
import sys

sys.dont_write_bytecode = False  # PYTHONDONTWRITEBYTECODE set this; writing is the point here

import slipsense  # noqa: E402

skipped = []
for module in pkgutil.walk_packages(slipsense.__path__, "slipsense."):
    try:
        importlib.import_module(module.name)
    except ImportError as exc:  # an optional extra not installed
        skipped.append(f"{module.name} ({exc.name or exc})")
# what commands import on the way: typer's parameter parsing (pydantic), the plots, ONNX Runtime
for name in ("matplotlib.pyplot", "onnxruntime", "onnx", "safetensors.torch", "yaml", "scipy.stats"):
    try:
        importlib.import_module(name)
    except ImportError as exc:
        skipped.append(f"{name} ({exc.name or exc})")
from slipsense.cli import app  # noqa: E402
from typer.testing import CliRunner  # noqa: E402

CliRunner().invoke(app, ["models"])
if skipped:
    print(f"bytecode: passed over {', '.join(skipped)}")

# and what Python imported before writing was allowed here (the .pth hooks of site-packages)
for name, module in list(sys.modules.items()):
    source = getattr(module, "__file__", None) or ""
    if source.endswith(".py") and not os.path.exists(importlib.util.cache_from_source(source)):
        try:
            py_compile.compile(source, cfile=importlib.util.cache_from_source(source), doraise=True)
        except (OSError, py_compile.PyCompileError):  # a read-only installation: nothing to gain there
            pass
