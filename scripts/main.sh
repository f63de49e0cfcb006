#!/usr/bin/env bash
# The main job on the shared recordings: set up, label every video, train ViViT with 6 objects held
# out (fold 0 of 5 by object), and evaluate it on those unseen objects. Outputs: reports/main/.
# Paper model sizes at half resolution (120x160 frames, 20x20 patches: the same 6x8 patch grid) so
# that it finishes in minutes on 2 CPU cores; pass e.g. `--size 240x320 --set patch_size=[40,40]` to
# run at the paper's full resolution. Extra arguments go to `slipsense train`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
out=reports/main
mkdir -p "$out"
.venv/bin/slipsense label --csv "$out/labels.csv" --overrides configs/gelsight-label-overrides.csv --no-progress
.venv/bin/slipsense train --model vivit --fold 0 --folds 5 --size 120x160 --set 'patch_size=[20,20]' \
    --overrides configs/gelsight-label-overrides.csv --out "$out/vivit-fold0" --no-progress "$@"
.venv/bin/slipsense evaluate --checkpoint "$out/vivit-fold0/last.safetensors" \
    --split "$out/vivit-fold0/split.json" --json "$out/held_out_objects.json" --no-progress
echo "reports in $out: labels.csv, vivit-fold0/ (curves.png, metrics.csv), held_out_objects.json/.png"
