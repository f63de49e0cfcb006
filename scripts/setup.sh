#!/usr/bin/env bash
# Create .venv beside the checkout and install slipsense with pinned dependencies.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -x .venv/bin/python ]; then
    python3 -m venv .venv
fi
# torch first and pinned: an unpinned resolver pass could pull a multi-GB CUDA build.
.venv/bin/python -m pip install --quiet --disable-pip-version-check torch==2.13.0
.venv/bin/python -m pip install --quiet --disable-pip-version-check -e ".[export,test]"
# vit-pytorch only serves the benchmarks as a reference; its package __init__ imports torchvision,
# which does not import beside this torch, so it is installed without dependencies.
.venv/bin/python -m pip install --quiet --disable-pip-version-check --no-deps vit-pytorch==1.26.11
