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
pip_install() {
    .venv/bin/python -m pip install --quiet --disable-pip-version-check --no-compile "$@"
}
# uv (from the package registry) installs the same pins in about a third of pip's time (measured: 6.5 s
# against 20 s for the library); it reads no pip configuration, so the places pip is set to find wheels
# in are handed to it. Where uv cannot be had or fails, pip does it all. SLIPSENSE_PIP=1: pip only.
install() {
    if [ -z "${SLIPSENSE_PIP:-}" ] && { [ -x .venv/bin/uv ] || pip_install uv >/dev/null 2>&1; }; then
        local links=() place
        for place in $(.venv/bin/python -m pip config get global.find-links 2>/dev/null || true); do
            links+=(--find-links "$place")
        done
        if .venv/bin/uv pip install --quiet --python .venv/bin/python "${links[@]}" "$@"; then
            return 0
        fi
        echo "setup: uv could not install it; pip instead" >&2
    fi
    pip_install "$@"
}
# torch pinned and in the same resolver pass: an unpinned one could pull a multi-GB CUDA build.
# No bytecode up front: Python compiles the modules it imports on first use, not torch's thousands.
install torch==2.13.0 -e ".${extras}"
# the bytecode of what commands import, written now where PYTHONDONTWRITEBYTECODE is set (else every
# command compiles torch again: `slipsense models` 4.6 s instead of 2.2 s). Where it is not set, each
# command writes what it imports itself on first use, and writing all of it up front cost the main
# job 15 s (scripts/main.sh unsets it).
if [ -n "${PYTHONDONTWRITEBYTECODE:-}" ]; then
    .venv/bin/python scripts/compile_imports.py
fi
if [ -z "$extras" ]; then
    exit 0
fi
# vit-pytorch only serves the benchmarks as a reference; its package __init__ imports torchvision,
# which does not import beside this torch, so it is installed without dependencies.
install --no-deps vit-pytorch==1.26.11
