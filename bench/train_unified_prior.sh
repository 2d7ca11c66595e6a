#!/usr/bin/env bash
# The unified-token prior of the paper's Co4DGen comparison, on vt4d-tiny 1.0.0's unified-token ablation:
#
#   bash bench/train_unified_prior.sh [THREADS]
#
# 1. the unified ablation (checkpoints/vt4d-tiny-1.1-dyn-unified: the same lineage, steps and data as 1.0.0)
#    with 1.0.0's ship-time renderer setting dynamic_gate_copies=true -> runs/models/vt4d-tiny-unified;
# 2. its tokens of the same 192 train events x 10 cameras as co4dgen-tiny 1.0.0 and of the 16 test events;
# 3. the prior with co4dgen-tiny 1.0.0's architecture, data, steps, batch and learning rate
#    -> checkpoints/co4dgen-tiny-unified/prior (commit it: bench_prior.py then re-runs without training);
# 4. bench/bench_prior.py on the held-out events -> docs/results/co4dgen_unified_1.0.0.json and its figure.
# Every step is skipped when its output exists, so the command resumes. About 35 min on one thread.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python}
THREADS=${1:-1}
UNI=runs/models/vt4d-tiny-unified
if [ ! -f "$UNI/config.json" ]; then
  "$PYTHON" - "$UNI" <<'PY'
import sys
from vt4dcodec.eval.command import resolve_model
from vt4dcodec.model.train.common import parse_overrides
from vt4dcodec.model.train.ship import reconfigure
from vt4dcodec.model.weights_io import save_pretrained
model = reconfigure(resolve_model("checkpoints/vt4d-tiny-1.1-dyn-unified"), parse_overrides(["dynamic_gate_copies=true"]))
save_pretrained(model, sys.argv[1], model_id="vt4d-tiny-unified", model_version="1.0.0", decode_steps=1)
PY
fi
[ -f data/co4dgen-unified-1.0.0/train-00002.vt4da ] || "$PYTHON" -m vt4dcodec.model.train.tokenize_scenes \
  --tokenizer "$UNI" --out data/co4dgen-unified-1.0.0 --split train --scenes 192 --cameras 10 --per-shard 64 \
  --cache runs/scene_cache --threads "$THREADS" --quiet
[ -f data/co4dgen-unified-1.0.0-test/test-00000.vt4da ] || "$PYTHON" -m vt4dcodec.model.train.tokenize_scenes \
  --tokenizer "$UNI" --out data/co4dgen-unified-1.0.0-test --split test --scenes 16 --cameras 10 --per-shard 16 \
  --cache runs/scene_cache_test --threads "$THREADS" --quiet
PRIOR=checkpoints/co4dgen-tiny-unified
[ -f "$PRIOR/prior/prior.json" ] || "$PYTHON" -m vt4dcodec.model.train.prior --shards data/co4dgen-unified-1.0.0 \
  --out "$PRIOR" --steps 1000 --batch-size 16 --lr 5e-4 --threads "$THREADS" --no-progress \
  --model-id co4dgen-tiny-unified --model-version 1.0.0
"$PYTHON" bench/bench_prior.py --shards data/co4dgen-unified-1.0.0-test --prior "$PRIOR/prior" --tokenizer "$UNI" \
  --events 8 --render-steps 1 --threads "$THREADS" --results docs/results/co4dgen_unified_1.0.0.json \
  --figure docs/figures/co4dgen_unified_1.0.0.png
