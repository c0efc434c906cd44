#!/bin/bash
# Fine-tunes the checkpoint shipped before it (runs/cpu-data48, trained on 48 sequences)
# on more data: data/train with 80 sequences (seeds 1000-1079), rendered first by
# `jnds dataset --out data --split train --train-sequences 80` (the session that rendered
# them asked for 96 and stopped the renderer at 80 to leave time for training).
# Same settings as cpu-data48 (96x96 native patches, batch 4 x unroll 6, fourth-root
# upsampling, l1+feature loss), another seed, alone on both cores. Resumable: run it again.
# Usage: bash runs/cpu-data80/run.sh FP32_STEPS QAT_STEPS
set -e
cd "$(dirname "$0")/../.."
source .venv/bin/activate
n=$(ls -d data/train/*/sequence.json | wc -l)
[ "$n" -ge 80 ] || { echo "data/train has $n finished sequences, expected 80: render them first" >&2; exit 1; }
/usr/bin/time -f "%e s" jnds train --data data --run runs/cpu-data80 --patch 96 --fp32-steps "$1" --qat-steps "$2" \
  --init runs/cpu-data48/checkpoint.pt --upsample-root 4 --lr 1.5e-4 --qat-lr 4e-5 \
  --spatial-loss l1+feature --feature-net runs/feature/feature_net.pt --val-every 100000 \
  --threads 2 --seed 3 --quiet --unroll 6
