#!/usr/bin/env bash
# Release a tokenizer version: ship a finished training run as model/weights/vt4d-tiny (float16 weights +
# encoder.onnx), retrain co4dgen-tiny on its tokens and ship it, and re-measure what depends on the tokens.
#
#   bash bench/release_tokenizer.sh RUN VERSION     e.g. bash bench/release_tokenizer.sh checkpoints/vt4d-tiny-1.0 1.0.0
#
# RUN is a tokenizer run directory (its <RUN>/model, written when the run finishes). Outputs: the shipped
# weights under model/weights/, docs/results/real_caliscope*.json and docs/figures/real_caliscope*.png
# rewritten, and the evaluation, rate-distortion and prior logs under runs/release-VERSION/ (copy
# eval50.json to docs/results/eval.json and summarise in docs/RESULTS.md by hand). About 2.5 h on 2
# cores; the prior trains on one core beside the measurements. The codec comparison
# (OMP_NUM_THREADS=1 python bench/bench_codecs.py, ~20 min) is separate.
set -euo pipefail
cd "$(dirname "$0")/.."
RUN=${1:?usage: release_tokenizer.sh RUN VERSION}; VERSION=${2:?usage: release_tokenizer.sh RUN VERSION}
OUT=runs/release-$VERSION; SHARDS=data/co4dgen-$VERSION
mkdir -p "$OUT"
python -m vt4dcodec.model.train.ship --run "$RUN" --id vt4d-tiny --version "$VERSION" --decode-steps 1
rm -rf "$SHARDS"
python -m vt4dcodec.model.train.tokenize_scenes --tokenizer vt4d-tiny --out "$SHARDS" --split train \
    --scenes 192 --cameras 10 --per-shard 64 --cache runs/scene_cache --threads 2 > "$OUT/tokenize.log" 2>&1
( python -m vt4dcodec.model.train.prior --shards "$SHARDS" --out "$OUT/co4dgen" --steps 1000 --batch-size 16 \
      --lr 5e-4 --threads 1 --model-id co4dgen-tiny --model-version "$VERSION" --no-progress \
  && python -m vt4dcodec.model.train.ship_prior "$OUT/co4dgen/prior" ) > "$OUT/prior.log" 2>&1 &
PRIOR=$!
python -m vt4dcodec.eval --model vt4d-tiny --scenes 50 --views 3 --threads 1 --no-progress \
    --out "$OUT/eval50.json" --figure "$OUT/eval_figure.png" > "$OUT/eval.log" 2>&1
python bench/bench_rate_distortion.py --model vt4d-tiny --label "vt4d-tiny $VERSION" --scenes 20 --views 3 \
    --steps 1 --threads 1 > "$OUT/rd.log" 2>&1
REAL="python -m vt4dcodec.eval.real_footage --model vt4d-tiny --threads 1"
$REAL --out docs/results/real_caliscope.json --figure docs/figures/real_caliscope.png > "$OUT/real.log" 2>&1
$REAL --source cam_0,cam_1,cam_2,cam_3 --target all --out docs/results/real_caliscope_multi.json \
    --figure docs/figures/real_caliscope_multi.png >> "$OUT/real.log" 2>&1
$REAL --target source --out docs/results/real_caliscope_source.json \
    --figure docs/figures/real_caliscope_source.png >> "$OUT/real.log" 2>&1
SAMPLE=$(python -c "from vt4dcodec.capture.caliscope import find_sample_capture as f; print(f() or '')")
if [ -n "$SAMPLE" ]; then  # every camera and clip of the capture as a user imports it (docs/captures.md)
  [ -f data/caliscope/capture.json ] || vt4d import "$SAMPLE/camera_array.toml" "$SAMPLE/videos" -o data/caliscope
  $REAL --capture data/caliscope --source cam_0 --target all --out docs/results/real_caliscope_all.json \
      --sheet docs/figures/real_caliscope_all_sheet.png >> "$OUT/real.log" 2>&1
fi
wait "$PRIOR"
echo "released vt4d-tiny $VERSION and co4dgen-tiny $VERSION; logs in $OUT"
