#!/usr/bin/env bash
# One prepared tokenizer training run on a lent accelerator (the `device` tool's H200; docs/training.md,
# "Training on a lent accelerator"): continue a committed run for a fixed wall-clock budget and hand its
# checkpoint back through $OUT.
#
#   bash bench/device_train.sh RUN NAME BUDGET_S [trainer flags...]
#
# RUN: a committed run directory (e.g. checkpoints/vt4d-tiny-1.1-dyn; it travels with the working tree);
# NAME: the new run, trained under runs/device/NAME; BUDGET_S: seconds of training (--time-budget) after
# the scene cache is filled (about 3 min for 512 scenes on 16 cores). The trainer flags are the run's own
# (its state.json "args", as docs/training.md prints them), --steps included; --device, --init, --out,
# --time-budget and --prefill-workers are set here. What comes back in $OUT: the checkpoint's weights in
# parts under 16 MiB (join them with `cat model.safetensors.part-* > model.safetensors`), state.json,
# log.jsonl, samples.png, summary.json and device.txt (GPU, step rate). Keep the whole call inside the
# device tool's 600 s: BUDGET_S <= 360 on a fresh machine.
#
# Environment: DEVICE (default cuda; cpu to try this script here first), PREFILL (workers, default
# 16), SKIP_INSTALL=1 (the package is already installed, as in this repository's .venv). Python packages
# the device image lacks (zstandard, kornia, kornia_rs) are installed from .whl/ when it is carried
# (docs/training.md says how to download them).
set -euo pipefail
cd "$(dirname "$0")/.."
RUN=${1:?usage: device_train.sh RUN NAME BUDGET_S [flags]}
NAME=${2:?usage: device_train.sh RUN NAME BUDGET_S [flags]}
BUDGET=${3:?usage: device_train.sh RUN NAME BUDGET_S [flags]}
shift 3
: "${OUT:?OUT must name the folder the checkpoint is handed back in}"
DEVICE=${DEVICE:-cuda}
PREFILL=${PREFILL:-16}
PY=${PYTHON:-python3}
export PYTHONUNBUFFERED=1
if [ "${SKIP_INSTALL:-0}" != 1 ]; then
    if [ -d .whl ]; then
        "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
        export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
    fi
    "$PY" -m pip install -q --no-index --no-deps --no-build-isolation -e .
fi
DIR=runs/device/$NAME
mkdir -p "$DIR"
{ date -u; "$PY" -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(),
torch.cuda.get_device_name(0) if torch.cuda.is_available() else '')"; } > "$OUT/device.txt"
status=0
"$PY" -m vt4dcodec.model.train.tokenizer "$@" --init "$RUN" --out "$DIR" --device "$DEVICE" \
    --prefill-workers "$PREFILL" --time-budget "$BUDGET" --no-progress 2>&1 | tee "$OUT/train.log" || status=$?
if [ -f "$DIR/checkpoint/state.json" ]; then
    split -b 15M -d "$DIR/checkpoint/model.safetensors" "$OUT/model.safetensors.part-"
    cp "$DIR/checkpoint/state.json" "$DIR/log.jsonl" "$OUT/"
    for f in samples.png summary.json; do [ -f "$DIR/$f" ] && cp "$DIR/$f" "$OUT/"; done
    "$PY" - "$DIR/log.jsonl" >> "$OUT/device.txt" <<'EOF'
import json, sys
rows = [json.loads(line) for line in open(sys.argv[1])]
last = rows[-1]
print(f"step {last['step']} loss {last['loss']:.4f} elapsed {last['elapsed_s']} s")
EOF
fi
exit "$status"
