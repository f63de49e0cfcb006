#!/usr/bin/env bash
# The main job on the shared recordings: set up, label every video, train the slip detector with the
# objects of fold 0 of 5 held out (its alarm threshold chosen on the training objects only), and judge
# it on those unseen objects per grasp (every run replayed from its first frame, both sensors) and per
# clip (the paper's protocol), beside the non-learned baselines. Outputs: runs/main/ (ignored by git: the
# tests hold reports/ to the pipeline's stages, and this is not one). Extra arguments go to
# `slipsense train`.
set -euo pipefail
cd "$(dirname "$0")/.."
# Python keeps the bytecode of what it imports where the machine says not to: otherwise every process
# compiles torch from source again (measured: import torch 4 s -> 2.7 s, torch._dynamo 9 s -> 3 s).
unset PYTHONDONTWRITEBYTECODE
bash scripts/setup.sh core
out=runs/main
mkdir -p "$out"
overrides=configs/gelsight-label-overrides.csv
.venv/bin/slipsense label --csv "$out/labels.csv" --overrides "$overrides" --no-progress
.venv/bin/slipsense train --config configs/motionnet.yaml --fold 0 --folds 5 \
    --out "$out/motionnet-fold0" --no-progress "$@"
# the same detector as a gripper would run it, on the held-out objects' recordings only
held=$(.venv/bin/python -c "import json,sys; print(' '.join(json.load(open(sys.argv[1]))['objects']))" \
    "$out/motionnet-fold0/held_out.json")
rm -rf "$out/held-out-recordings" && mkdir -p "$out/held-out-recordings"
data=$(.venv/bin/python -c "from slipsense.paths import gelsight_recordings; print(gelsight_recordings())")
for o in $held; do ln -s "$data/$o" "$out/held-out-recordings/$o"; done
.venv/bin/slipsense evaluate --checkpoint "$out/motionnet-fold0/detector.safetensors" \
    --recordings "$out/held-out-recordings" --json "$out/held-out-evaluation.json" --no-progress
echo "reports in $out: labels.csv, motionnet-fold0/ (detector, metrics.csv, curves.png, held_out.json), held-out-evaluation.json"
