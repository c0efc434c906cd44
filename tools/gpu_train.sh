#!/usr/bin/env bash
# Render a training set and fine-tune checkpoints on a lent GPU machine (the library's
# `device` tool), where nothing can be downloaded: Mitsuba, Dr.Jit, OpenEXR and
# flip-evaluator travel in .gpu/ (git-ignored; how to make it: docs/gpu-training.md).
#
#   bash tools/gpu_train.sh start OUT SECONDS   render data, start the runs in the
#                                                  background, copy results to OUT after SECONDS
#   bash tools/gpu_train.sh wait OUT SECONDS    same machine, later call: wait, copy again
#
# The runs go on between two calls while the machine is held; each call copies every
# run's checkpoint.pt and log.jsonl to OUT/<run>/ so nothing is lost if it goes back.
set -uo pipefail
cd "$(dirname "$0")/.."
mode=$1 out=$2 seconds=$3
t_end=$(( $(date +%s) + seconds ))
export PYTHONUNBUFFERED=1
if [ ! -d /tmp/site/mitsuba ]; then
  mkdir -p /tmp/site && tar xJf .gpu/mi.tar.xz -C /tmp/site &&
    python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .gpu/*.whl || exit 1
fi
export PYTHONPATH=/tmp/site:$PWD
DATA=/tmp/data RUNS=/tmp/runs
TRAIN_SEQUENCES=${TRAIN_SEQUENCES:-16} MOVING_SEQUENCES=${MOVING_SEQUENCES:-4} JOBS=${JOBS:-20}
mkdir -p "$RUNS" "$out"

if [ "$mode" = start ]; then
  t0=$(date +%s)
  # the training split only (the first TRAIN_SEQUENCES default seeds and MOVING_SEQUENCES with
  # moving objects), all at once: Mitsuba's Python-side tracing sets the pace, so the GPU's
  # throughput is the same at 16 or 20 processes; validation is done on the CPU afterwards
  python3 -m jnds_deploy dataset --out $DATA --split train --train-sequences "$TRAIN_SEQUENCES" \
    --moving-sequences "$MOVING_SEQUENCES" --jobs "$JOBS" --variant cuda_ad_rgb 2>&1 | tr '\r' '\n' |
    grep -v "frame/s\|frame\]" > "$out/render.log"
  mkdir -p $DATA/val
  echo "rendered in $(( $(date +%s) - t0 )) s: $(ls $DATA/train | wc -l) train"
  # the shipped checkpoint's recipe (its model card: fixed upsample, fourth roots, firefly clamp,
  # diffuse fill, albedo at holes, the augmentations, cross-cut windows, the low-frequency loss)
  # without the feature loss, whose network would have to be trained here first
  common="--data $DATA --preset large --init jnds_deploy/checkpoints/jnds.pt --fixed-upsample --upsample-root 4
          --firefly-clamp 16 --diffuse-fill --albedo-at-holes --cross-cuts --exposure -4 8 --rotate-normals --flips
          --patch 64 --unroll 6 --batch ${BATCH:-48} --fp32-steps ${FP32_STEPS:-200} --qat-steps ${QAT_STEPS:-60}
          --lr 1e-4 --qat-lr 2e-5 --warmup-steps 20 --spatial-loss l1 --lowfreq-loss 2.0 --device cuda
          --val-every 100000 --val-sequences 0 --checkpoint-every 20 --threads 2 --quiet --seed 59"
  start_run() {  # name, then train arguments
    local name=$1; shift
    setsid nohup python3 -m jnds_deploy train $common --run "$RUNS/$name" "$@" > "$RUNS/$name.log" 2>&1 &
  }
  # issue 25: the output block's convolution at 16 channels (MLAS's AVX2 int8 kernel works in
  # blocks of 16, so the shipped 24 cost as 32; docs/performance.md, "Speed") against the same
  # fine-tune at 24, the control
  start_run gpu-out16 --output-width 16
  start_run gpu-out24
fi

while [ "$(date +%s)" -lt "$t_end" ] && pgrep -f "jnds_deploy train" >/dev/null; do sleep 5; done
for log in "$RUNS"/*.log; do
  name=$(basename "$log" .log)
  mkdir -p "$out/$name"
  cp "$RUNS/$name/checkpoint.pt" "$RUNS/$name/log.jsonl" "$out/$name/" 2>/dev/null
  echo "$name: $(grep -c '"event": "train"' "$RUNS/$name/log.jsonl" 2>/dev/null) log lines, last:" \
       "$(tail -1 "$RUNS/$name/log.jsonl" 2>/dev/null | cut -c1-160)"
  tail -2 "$log" | cut -c1-300
done
nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv
