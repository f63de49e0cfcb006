#!/usr/bin/env bash
# Leave-objects-out evaluation of ViViT: 5 folds by object (each fold's objects never seen in
# training), paper training settings at 120x160. Writes reports/vivit-folds/folds.json (per-fold and
# pooled metrics; REPORT=... elsewhere). Extra arguments go to every `slipsense train`.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${OUT:-runs/vivit-folds}
report=${REPORT:-reports/vivit-folds/folds.json}
for k in 0 1 2 3 4; do
    .venv/bin/slipsense train --config configs/vivit-folds.yaml --fold "$k" --out "$out/fold$k" --no-progress "$@"
done
.venv/bin/python -m slipsense.evaluation.clip_folds "$out"/fold* --json "$report"
