#!/usr/bin/env bash
# Render the dataset and fine-tune checkpoints on a lent GPU machine (the library's
# `device` tool), where nothing can be downloaded: Mitsuba, Dr.Jit, OpenEXR and
# flip-evaluator travel in .gpu/ (git-ignored; how to make it: docs/gpu-training.md).
#
#   bash scripts/gpu_train.sh start OUT SECONDS   render data, start the runs in the
#                                                  background, copy results to OUT after SECONDS
#   bash scripts/gpu_train.sh wait OUT SECONDS    same machine, later call: wait, copy again
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
TRAIN_SEQUENCES=${TRAIN_SEQUENCES:-40}
mkdir -p "$RUNS" "$out"

if [ "$mode" = start ]; then
  t0=$(date +%s)
  python3 -m jnds_deploy dataset --out $DATA --split all --train-sequences "$TRAIN_SEQUENCES" \
    --jobs 16 --variant cuda_ad_rgb 2>&1 | tr '\r' '\n' | grep -v "frame/s\|frame\]" > "$out/render.log"
  echo "rendered in $(( $(date +%s) - t0 )) s: $(ls $DATA/train | wc -l) train, $(ls $DATA/val | wc -l) val"
  common="--data $DATA --batch 64 --fp32-steps ${FP32_STEPS:-650} --qat-steps ${QAT_STEPS:-200}
          --lr 3e-4 --qat-lr 1e-4 --device cuda --val-every 200 --threads 2 --quiet --upsample-root 4"
  # the feature-loss network (Eq. 6) is re-created from the data: training runs are not kept in git
  python3 -m jnds_deploy train-feature-net --data $DATA --out "$RUNS/feature_net.pt" --quiet
  ship=jnds_deploy/checkpoints/jnds.pt feat="--feature-net $RUNS/feature_net.pt"
  start_run() {  # name, then train arguments
    local name=$1; shift
    setsid nohup python3 -m jnds_deploy train $common --run "$RUNS/$name" "$@" > "$RUNS/$name.log" 2>&1 &
  }
  # $ship: the shipped checkpoint (its model card); every run interpolates fourth roots in
  # the upsample filter
  start_run gpu-root4 --init $ship --spatial-loss l1+feature $feat
  start_run gpu-root4-unroll12 --init $ship --spatial-loss l1+feature $feat --unroll 12
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
