#!/usr/bin/env bash
# Train one of Table 5's ablations from scratch with vt4d-tiny 1.0's first-phase recipe, resumably:
#
#   bash bench/train_table5_ablation.sh NAME FLAG BUDGET_S [PREFILL_WORKERS]
#   bash bench/train_table5_ablation.sh nomotion motion_isolation=false 3600
#   bash bench/train_table5_ablation.sh fixedgrid track_attention=false 3600
#
# Trains checkpoints/vt4d-tiny-1.0-NAME for at most BUDGET_S seconds of wall time, then stops with a
# checkpoint (commit its model.safetensors, state.json and log.jsonl; the same command resumes anywhere).
# As the vt4d-tiny 1.0 pair was run (docs/training.md, "After 0.13.0"): steps 0-600 without the Z_d diversity
# hinge, stopped at the step-600 checkpoint (--stop-at 600) and resumed with --dynamic-diversity 1.0, to step 6,000.
# Run two ablations side by side on two cores (one thread each); PREFILL_WORKERS > 0 fills the scene cache
# first (a fresh machine: ~15 min with 2). THREADS=2 gives a run both cores once the other has finished
# (torch threads only; the recipe and its data order are unchanged, as the pair itself ran on two).
set -uo pipefail
cd "$(dirname "$0")/.."
NAME=${1:?usage: train_table5_ablation.sh NAME FLAG BUDGET_S [PREFILL]}; FLAG=${2:?FLAG, e.g. motion_isolation=false}
BUDGET=${3:?BUDGET_S}; PREFILL=${4:-0}
DEADLINE=$(( $(date +%s) + BUDGET ))
PYTHON=${PYTHON:-python}
OUT=checkpoints/vt4d-tiny-1.0-$NAME
CMD=("$PYTHON" -m vt4dcodec.model.train.tokenizer --autoencoder-from vt4d-tiny --out "$OUT"
  --steps 6000 --warmup 200 --lr 3e-4 --scenes 512 --cameras 10 --cache runs/scene_cache --batch-size 8
  --workers 1 --threads "${THREADS:-1}" --cache-latents --recon-share 0.3 --neighbour-sigma 45 --tau-one 1.0
  --saturation-weight 0.05 --drop-static 0.1 --multi-share 0.6 --multi-views 2,4,5,5,5 --cell-weight 0.25
  --ssim-weight 0.5 --ckpt-every 100 --log-every 25 --no-progress
  --model-id "vt4d-tiny-$NAME" --model-version 1.0.0
  --set latent_channels=8 prediction=x0 locality_sigma=0.35 patch_size=2 query_from_grid=true
        project_anchors=true anchor_views=true token_splat=true token_from_cell=true n_static=320
        frame_copies=true frame_gate_deg=8 spread_views=true view_gate_deg=40 pixel_splat=true
        patch_gate_deg=5 "$FLAG")
step() { "$PYTHON" -c "import json; print(json.load(open('$OUT/checkpoint/state.json'))['step'])" 2>/dev/null || echo 0; }
left() { echo $(( DEADLINE - $(date +%s) )); }
if [ "$(step)" -lt 600 ]; then
  EXTRA=(); [ "$PREFILL" -gt 0 ] && EXTRA=(--prefill-workers "$PREFILL")
  "${CMD[@]}" "${EXTRA[@]}" --stop-at 600 --time-budget "$(left)"
fi
echo "$(date) $NAME at step $(step)"
if [ "$(step)" -ge 600 ] && [ "$(left)" -gt 120 ]; then
  "${CMD[@]}" --dynamic-diversity 1.0 --time-budget "$(left)"
fi
echo "$(date) $NAME stopped at step $(step)"
