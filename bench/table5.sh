#!/usr/bin/env bash
# The paper's Table 5 (ablations) at this scale: four tokenizers trained from scratch with one recipe, the
# full model and three ablations, compared at the same training step (vt4d-tiny 1.0's from-scratch phase,
# 6,000 steps; docs/training.md "Table 5's other ablations"):
#
#   bash bench/table5.sh [THREADS]
#
#   full                    checkpoints/vt4d-tiny-1.0
#   unified tokens          checkpoints/vt4d-tiny-1.0-unified     (unified_tokens=true)
#   w/o motion isolation    checkpoints/vt4d-tiny-1.0-nomotion    (motion_isolation=false)
#   fixed-grid attention    checkpoints/vt4d-tiny-1.0-fixedgrid   (track_attention=false)
#
# 1. refuses unless every checkpoint is at step STEP (default 6000; the ablations train with
#    bench/train_table5_ablation.sh);
# 2. the evaluation protocol of docs/results/eval.json on the four (50 held-out scenes, 3 target cameras,
#    int8 tokens, one renderer step) -> docs/results/table5.json and docs/figures/table5_scenes_*.png;
# 3. bench/paper_tables.py: the paper's orderings with paired differences and standard errors, and
#    docs/figures/table5_ablations.png.
# About 10 min with 2 threads.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python}
THREADS=${1:-2}
STEP=${STEP:-6000}
declare -A RUNS=([full]=checkpoints/vt4d-tiny-1.0 [unified]=checkpoints/vt4d-tiny-1.0-unified
                 [nomotion]=checkpoints/vt4d-tiny-1.0-nomotion [fixedgrid]=checkpoints/vt4d-tiny-1.0-fixedgrid)
for name in full unified nomotion fixedgrid; do
  run=${RUNS[$name]}
  at=$("$PYTHON" -c "import json,sys; print(json.load(open(sys.argv[1]))['step'])" "$run/checkpoint/state.json")
  if [ "$at" != "$STEP" ]; then
    echo "table5.sh: $run is at step $at, not $STEP: train it on (bench/train_table5_ablation.sh) or set STEP" >&2
    exit 2
  fi
done
"$PYTHON" -m vt4dcodec.eval --model "${RUNS[full]}" --unified "${RUNS[unified]}" \
  --no-motion-isolation "${RUNS[nomotion]}" --fixed-grid "${RUNS[fixedgrid]}" \
  --methods ours,unified,no_motion_isolation,fixed_grid --scenes 50 --views 3 --steps 1 \
  --threads "$THREADS" --no-progress --out docs/results/table5.json --figure docs/figures/table5_scenes.png
"$PYTHON" bench/paper_tables.py
