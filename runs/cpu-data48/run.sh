#!/bin/bash
# Fine-tunes the checkpoint shipped before it (runs/cpu-long-p96, trained on the default
# 24 training sequences) on twice the data: data/train with 48 sequences (seeds
# 1000-1047), rendered first by `jnds dataset --out data --split train --train-sequences 48`.
# Same settings as cpu-long-p96 (96x96 native patches, batch 4 x unroll 6, fourth-root
# upsampling, l1+feature loss), alone on both cores. Resumable: run it again.
# Usage: bash runs/cpu-data48/run.sh FP32_STEPS QAT_STEPS
set -e
cd "$(dirname "$0")/../.."
source .venv/bin/activate
n=$(ls -d data/train/*/sequence.json | wc -l)
[ "$n" -ge 48 ] || { echo "data/train has $n finished sequences, expected 48: render them first" >&2; exit 1; }
/usr/bin/time -f "%e s" jnds train --data data --run runs/cpu-data48 --patch 96 --fp32-steps "$1" --qat-steps "$2" \
  --init runs/cpu-long-p96/checkpoint.pt --upsample-root 4 --lr 1.5e-4 --qat-lr 4e-5 \
  --spatial-loss l1+feature --feature-net runs/feature/feature_net.pt --val-every 100000 \
  --threads 2 --seed 2 --quiet --unroll 6
