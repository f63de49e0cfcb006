#!/usr/bin/env bash
# Create .venv beside the checkout and install slipsense with pinned dependencies.
#   bash scripts/setup.sh        everything: the library, ONNX export, the ROS 2 node, the test and lint tools,
#                                DVC (the reports' pipeline, dvc.yaml)
#   bash scripts/setup.sh core   the library alone (what scripts/main.sh needs; seconds less)
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -x .venv/bin/python ]; then
    python3 -m venv .venv
fi
extras="[export,ros,test,pipeline]"
if [ "${1:-}" = "core" ]; then
    extras=""
fi
# torch pinned and in the same resolver pass: an unpinned one could pull a multi-GB CUDA build.
# --no-compile: Python compiles the modules it imports on first use, not torch's thousands up front.
.venv/bin/python -m pip install --quiet --disable-pip-version-check --no-compile torch==2.13.0 -e ".${extras}"
# the bytecode of what commands import, written now even where PYTHONDONTWRITEBYTECODE is set (else
# every command compiles torch again: `slipsense models` 4.6 s instead of 2.2 s)
.venv/bin/python scripts/compile_imports.py
if [ -z "$extras" ]; then
    exit 0
fi
# vit-pytorch only serves the benchmarks as a reference; its package __init__ imports torchvision,
# which does not import beside this torch, so it is installed without dependencies.
.venv/bin/python -m pip install --quiet --disable-pip-version-check --no-compile --no-deps vit-pytorch==1.26.11
